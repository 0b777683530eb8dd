"""``hydropump record``: a recording plan through the real nodes, one bag per experiment.

The plan (:mod:`hydropump_ctrl.plans`), the output folder and the options are
checked here, before any node starts; running the plan needs ROS, which this package never
imports: the runner comes from the ``hydropump.runners`` entry-point group, which the ROS
package ``hydropump_ros`` fills (``record = hydropump_ros.record:run``). Without it, or
without rclpy, the command says so in one line (``--check`` needs neither). SIGTERM stops the
run (the runner raises :class:`~hydropump_ctrl.experiment.Stopped` once the nodes
are stopped and the open bag is closed): one line, exit code 143.
"""

from __future__ import annotations

from importlib import metadata, util
import os
from pathlib import Path
import sys

import yaml

from hydropump_sim.files import write_text

from .options import add_params_option, float_in, plant_file, positive_float, UsageError

#: Where ROS packages register what ``hydropump`` runs through the node graph.
RUNNERS = 'hydropump.runners'
MANIFEST = 'record.yaml'


def register(sub) -> None:
    p = sub.add_parser(
        'record', help='run a recording plan through the nodes: one bag per experiment',
        description='Run a recording plan through the simulator, controller and recorder '
        'nodes (lock-step, the simulator paused between experiments): one bag per experiment '
        'in --out, named after it. PLAN is "standard" (the standard calibration campaign) or '
        'a plan YAML file (docs/recording.md; config/plans/calibration.yaml is the standard '
        'one).')
    p.add_argument('plan', metavar='PLAN', help='"standard" or a plan YAML file')
    add_params_option(p, 'of the simulator started here')
    p.add_argument('--profile', help='sensor profile of the simulator started here (e.g. '
                   'config/bench.yaml; default: ideal sensors)')
    p.add_argument('--out', metavar='DIR', help='folder of the bags (created; needed unless '
                   '--check)')
    # The range of the simulator's publish_rate.
    p.add_argument('--rate', type=float_in(1.0, 1.0e5, 'Hz'), default=RATE, metavar='HZ',
                   help='measurement rate of the simulator started here [Hz]: 1000 sees the '
                   "line pole's 3.5 ms, which a calibration of line.V_l needs; 200 records "
                   'three times faster (default %(default)g)')
    p.add_argument('--attach', action='store_true', help='drive the simulator, controller '
                   'and recorder already running in this ROS domain (and --namespace) '
                   'instead of starting a graph')
    p.add_argument('--namespace', default='', metavar='NS',
                   help='namespace of the nodes (default: the root)')
    p.add_argument('--wait', type=positive_float('s', 3600.0), default=10.0, metavar='S',
                   help='with --attach: how long to look for the nodes [s] (default 10)')
    p.add_argument('--check', action='store_true',
                   help='check the plan and print it; start nothing (needs no ROS)')
    p.set_defaults(func=run)


def _plant(args):
    from hydropump_sim.params import load_params
    from hydropump_sim.sensors import load_profile
    params = load_params(plant_file(args))
    if args.profile:
        if not Path(args.profile).is_file():
            raise UsageError(f'--profile {args.profile}: no such file')
        overrides = load_profile(args.profile).plant_overrides
        if overrides:
            params = params.replace(overrides)
    return params


# Measurements every 1 ms: the line pole (3.5 ms, eq. 9) shows in several samples of each
# load step, which line.V_l is calibrated from (docs/experiment_design.md).
RATE = 1000.0


def _check_options(args) -> None:
    if args.attach and (args.params or args.profile):
        raise UsageError('--params and --profile set up the graph that record starts; with '
                         "--attach the running simulator's plant is used (drop them)")
    if args.attach and args.rate != RATE:
        raise UsageError("--rate sets up the graph that record starts; with --attach the "
                         "running simulator's publish_rate is used (drop it)")
    if args.params and not Path(args.params).is_file():
        raise UsageError(f'--params {args.params}: no such file')
    if not args.out and not args.check:
        raise UsageError('--out DIR is needed: the folder the bags go to')


def check_out(out: str | Path, names) -> Path:
    """The output folder, if it can take the bags ``names``: not a file, writable (or
    creatable), no bag of those names in it (the recorder would add a suffix)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise UsageError(f'--out {out}: is a file; give a folder for the bags')
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise UsageError(f'--out {out}: cannot write in {parent} (no permission)')
    taken = [n for n in names if (out / n).exists()]
    if taken:
        raise UsageError(f'--out {out}: already holds {", ".join(taken)} (bags of an earlier '
                         'run?); give another folder or remove them')
    return out


def runner(name: str = 'record'):
    """The ROS side's ``name`` runner; a :class:`UsageError` in one line without ROS."""
    eps = metadata.entry_points(group=RUNNERS, name=name)
    if not eps:
        raise UsageError(f'hydropump {name} runs the ROS 2 nodes, and the ROS package '
                         'hydropump_ros is not installed here (make installs it; '
                         '--check needs no ROS)')
    if util.find_spec('rclpy') is None:
        raise UsageError(f'hydropump {name} runs the ROS 2 nodes, and ROS 2 (rclpy) is not '
                         'installed here (make installs it from PyPI; --check needs no ROS)')
    return next(iter(eps)).load()


def _table(rows) -> str:
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    return '\n'.join('  ' + '  '.join(c.ljust(w) for c, w in zip(r, widths)).rstrip()
                     for r in rows)


def run(args) -> int:
    from ..experiment import Stopped
    from ..plans import load_plan
    _check_options(args)
    params = _plant(args)
    plan = load_plan(args.plan, params)
    for line in plan.warnings:
        print(f'warning: {line}', file=sys.stderr)
    if args.check:
        print(f'{plan.source}: {len(plan.experiments)} experiments, {plan.duration:g} s '
              'simulated')
        print(_table(plan.rows()))
        return 0
    out = check_out(args.out, [e.name for e in plan.experiments])
    record = runner('record')
    held = ', '.join(plan.held_out) or 'none'
    print(f'hydropump record {plan.source}: {len(plan.experiments)} experiments, '
          f'{plan.duration:g} s simulated -> {out} (held out: {held})', flush=True)
    out.mkdir(parents=True, exist_ok=True)

    def echo(line: str) -> None:
        print(line, flush=True)
    try:
        done = record(plan, params, args, echo)
        bags = [{'name': e.name, 'bag': str(done[e.name]['bag']),
                 'start_time_s': round(done[e.name]['t0_s'], 9), 'duration_s': e.duration,
                 'held_out': e.held_out} for e in plan.experiments]
        write_text(out / MANIFEST, yaml.safe_dump(
            {'plan': plan.source, 'held_out': plan.held_out, 'bags': bags}, sort_keys=False),
            'list of bags')
        print(f'\n{len(bags)} bag{"s" if len(bags) != 1 else ""} in {out.resolve()}:')
        print(_table([[b['name'], f'{b["duration_s"]:g} s', 'held out' if b['held_out']
                       else ''] for b in bags]))
        print(f'held out: {held}')
        print(f'list: {out.resolve() / MANIFEST}')
    except Stopped:
        nodes = ('the open bag closed, the nodes left running' if args.attach else
                 'every node of the run ended, the open bag closed')
        print(f'stopped by SIGTERM: {nodes}; the bags recorded so far are in {out.resolve()}',
              file=sys.stderr)
        return Stopped.EXIT_CODE
    return 0
