"""``hydropump-graph``: start the node graph without ``ros2 launch`` (pip-only setups).

It does what ``hydropump_bringup/launch/closed_loop.launch.py`` does, with the same arguments
(``--namespace pump1 --lock-step --bag /tmp/run1 ...``): simulator, controller and recorder in
one namespace, each the installed executable as ``ros2 run`` starts it. ``--foxglove [PORT]``
adds the ``foxglove`` node beside them (the launch file's ``foxglove:=true
foxglove_port:=PORT``): the suite's topics live over the Foxglove WebSocket protocol. Ctrl-C
(or SIGTERM) stops them all, each with SIGINT as ``ros2 launch`` does; if one node exits, the
others are stopped and its log is named.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from hydropump_ctrl.cli.options import float_in, int_in, Parser, UsageError
from hydropump_ctrl.foxglove import FoxgloveConfig
from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import default_params_path
from hydropump_sim.schema import spec_map

from .command_line import graph_nodes, NODES

#: The foxglove node's address parameters (their defaults and range: one source of truth).
FOXGLOVE = spec_map(FoxgloveConfig)


def graph_commands(args) -> dict[str, list[str]]:
    """The node command lines, from the graph the launch file starts."""
    nodes = graph_nodes(
        params_file=args.params_file, sensor_profile=args.sensor_profile,
        circuit_file=args.circuit_file, scenario_file=args.scenario_file,
        controller_params=args.controller_params, use_sim_time=args.use_sim_time,
        lock_step=args.lock_step, real_time_factor=args.real_time_factor,
        start_paused=args.start_paused, autostart=not args.no_autostart,
        topics=args.topics.split(',') if args.topics else (), bag=args.bag,
        compression=args.compression, foxglove_port=args.foxglove)
    return {n.name: n.command(args.namespace, args.log_level) for n in nodes
            if n.name not in (args.without or [])}


def build_parser() -> argparse.ArgumentParser:
    ap = Parser(prog='hydropump-graph', description=__doc__.splitlines()[0])
    ap.add_argument('--namespace', default='', help='namespace of the suite (e.g. pump1)')
    ap.add_argument('--use-sim-time', action='store_true',
                    help='ROS clock of the nodes on /clock (the suite follows /clock anyway)')
    ap.add_argument('--params-file', default=None, help='plant params (default config/pump.yaml)')
    ap.add_argument('--circuit-file', default=None, help='circuit the pump feeds, e.g. '
                    "config/circuits/fig1.yaml (default: the paper's load)")
    ap.add_argument('--sensor-profile', default=None, help='e.g. config/bench.yaml')
    ap.add_argument('--controller-params', default=None, help='e.g. config/controller.yaml')
    ap.add_argument('--scenario-file', default=None, help='inputs scheduled in simulation time')
    ap.add_argument('--lock-step', action='store_true', help='simulator in lock-step mode')
    # The simulator's real_time_factor range; 0 is its own setting, not a default.
    ap.add_argument('--real-time-factor', type=float_in(0.0, 1000.0), default=1.0,
                    help='simulated s per wall s (default 1; 0 = as fast as possible)')
    ap.add_argument('--start-paused', action='store_true', help='wait for simulator/pause false')
    ap.add_argument('--no-autostart', action='store_true', help='leave the controller '
                    'unconfigured (configure and activate it with its lifecycle services)')
    ap.add_argument('--log-level', default='info', choices=('debug', 'info', 'warn', 'error'))
    ap.add_argument('--topics', default=None, help='recorder topics, comma-separated')
    ap.add_argument('--bag', default=None, help='bag folder of the recorder')
    ap.add_argument('--compression', default='zstd', choices=('zstd', 'none'))
    ap.add_argument('--without', action='append', choices=NODES, help='leave a node out')
    ap.add_argument('--log-dir', default=None, help="write each node's log to <dir>/<node>.log")
    # Port 0 (any free port) is the node's own setting; here the address is printed, so it
    # is one the user can type.
    ap.add_argument('--foxglove', nargs='?', type=int_in(1, FOXGLOVE['port'].range[1]),
                    const=FOXGLOVE['port'].default, default=None, metavar='PORT',
                    help='also start the foxglove node: the topics live on '
                    f'ws://{FOXGLOVE["host"].default}:PORT for Foxglove (default port '
                    "%(const)s; the launch file's foxglove:=true foxglove_port:=PORT)")
    return ap


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)  # a refused number is a UsageError
    except UsageError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    args.params_file = args.params_file or default_params_path()
    for name in ('params_file', 'circuit_file', 'sensor_profile', 'controller_params',
                 'scenario_file'):
        value = getattr(args, name)
        if value and not Path(value).is_file():
            print(f'error: --{name.replace("_", "-")} {value}: no such file', file=sys.stderr)
            return 2
    layout = 'config/foxglove/hydropump.json'
    if args.foxglove and (args.namespace.strip('/') or args.circuit_file):
        # A layout whose plots name this graph's topics: the namespace's, the circuit's.
        from hydropump_ctrl.foxglove import write_layout
        where = Path(args.log_dir) if args.log_dir else Path.cwd()
        try:
            where.mkdir(parents=True, exist_ok=True)
            layout = str(write_layout(where / 'foxglove_layout.json', args.namespace,
                                      args.circuit_file))
        except (OSError, ValueError, HydropumpError) as exc:
            print(f'error: {exc}', file=sys.stderr)
            return 2
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    procs, logs = {}, {}
    log_dir = Path(args.log_dir) if args.log_dir else None
    if log_dir:
        log_dir.mkdir(parents=True, exist_ok=True)
    for name, cmd in graph_commands(args).items():
        out = None
        if log_dir:
            logs[name] = log_dir / f'{name}.log'
            out = open(logs[name], 'w')  # noqa: SIM115 - closed when the child exits
        procs[name] = subprocess.Popen(cmd, env=env, stdout=out, stderr=subprocess.STDOUT
                                       if out else None)
        print(f'started {name} (pid {procs[name].pid})', flush=True)
    if 'foxglove' in procs:
        print(f'live view: ws://{FOXGLOVE["host"].default}:{args.foxglove} (Foxglove; layout '
              f'{layout})', flush=True)
    stopping = []
    signal.signal(signal.SIGINT, lambda *_: stopping.append(True))
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(True))
    rc = 0
    while not stopping:
        for name, p in procs.items():
            if p.poll() is not None:
                where = f'; see {logs[name]}' if name in logs else ''
                print(f'error: node {name} exited with code {p.returncode}{where}',
                      file=sys.stderr)
                rc = 1
                stopping.append(True)
                break
        time.sleep(0.2)
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for name, p in procs.items():
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            print(f'error: node {name} did not end within 10 s of SIGINT: killed',
                  file=sys.stderr)
            p.kill()
            rc = 1
    return rc


if __name__ == '__main__':
    sys.exit(main())
