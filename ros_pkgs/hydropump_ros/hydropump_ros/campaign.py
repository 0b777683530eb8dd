"""``hydropump-demo``: the paper end to end through the real node graph.

1. Identification campaign: nine open-loop experiments (the paper's protocol: growing-flow
   current staircases at the nominal operating point, differing in levels, step sizes and
   noise seeds) through the simulator (bench sensor profile), the controller in
   ``open_loop`` mode and the recorder, in lock-step, into nine bags.
2. Closed loop: EMC and PI on a flow step, a load-aperture step and a margin set-point step.
3. Fitting: eq. 19 on the nine bags (``hydropump fit``), next to the paper's figures and the
   plant's own (a noise-free, delay-free twin of each experiment, and the configured delay).
4. Model analysis: the modal table and the singular-perturbation check.
5. Report: one self-contained HTML page with PNG figures in ``out/<timestamp>/``, the bags
   beside it.

The three nodes are started once and every experiment goes through them
(:mod:`.orchestration`, which ``hydropump record`` uses too): live parameters, the
simulator's ``~/reset`` and ``pause_at``, one bag per experiment from the recorder's
``~/start`` and ``~/stop``. Each node logs to ``<run>/logs/<node>.log`` and is ended by PID.
A node that fails stops the run with a message that names it and its log. The experiments,
the analysis of their bags and the report are pure (:mod:`hydropump_ctrl.demo.campaign`).

The options are checked before anything starts (every number in its range, ``--out`` a folder
this user can write; ``--jobs`` capped at the CPUs, with a note): one ``error:`` line and exit
code 2. SIGTERM stops the run: each graph, in this process or in a worker process, ends its
nodes by PID, and the demo exits with code 143 and one line saying so (Ctrl-C: 130), as
``hydropump record`` does (:func:`.orchestration.stop_on_sigterm`). A stage that fails (a
full disk, a node that exits) ends the run with one line naming the stage and where the bags
recorded before it are, left as they were, and exit code 1; every file the demo writes is
written whole or not at all (:mod:`hydropump_sim.files`).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
import contextlib
from datetime import datetime
import os
from pathlib import Path
import signal
import sys
import tempfile
import time
from typing import TYPE_CHECKING

from hydropump_ctrl.cli.options import float_in, int_in, Parser, UsageError
from hydropump_sim.errors import HydropumpError

from .orchestration import starting, stop_on_sigterm

if TYPE_CHECKING:
    from hydropump_ctrl.experiment import Experiment

    from .orchestration import Graph

# The experiments, the orchestration and the analysis are imported where they run: the
# command line is checked first, at once (their imports take seconds).

#: How long a stopping run waits for a worker to end its graph [s]: beyond Graph.close's
#: worst case (each of three nodes 20 s after its SIGINT, then killed).
STOP_WAIT = 65.0


def _worker_init() -> None:
    """In each worker process: SIGTERM (from the run as it stops) unwinds what the worker
    runs, ending its graph's nodes, and ends the worker with exit code 143; Ctrl-C is left to
    the run, which stops the workers then."""
    from hydropump_ctrl.experiment import Stopped
    stop_on_sigterm(lambda: SystemExit(Stopped.EXIT_CODE))
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _children(pid: int) -> list[int]:
    """The PIDs of ``pid``'s child processes (Linux's /proc; none where it is not)."""
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*/children'):
        with contextlib.suppress(OSError, ValueError):
            out += [int(x) for x in task.read_text().split()]
    return out


def _halt(pool) -> None:
    """Stop a pool's workers by PID: SIGTERM, so that each ends the graph it runs; a worker
    still there after :data:`STOP_WAIT` is killed, and its children with it."""
    procs = list((pool._processes or {}).values())  # the executor's own record of them
    for proc in procs:
        if proc.exitcode is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, signal.SIGTERM)
    # The workers' sentinels follow once their tasks have unwound.
    pool.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + STOP_WAIT
    for proc in procs:
        proc.join(max(0.0, deadline - time.monotonic()))
        if proc.exitcode is None:
            for pid in _children(proc.pid):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGKILL)
            proc.kill()
            proc.join()


class _Pool(ProcessPoolExecutor):
    def submit(self, *args, **kwargs):
        with starting():  # a worker process may start and be recorded here
            return super().submit(*args, **kwargs)


@contextlib.contextmanager
def _workers(n: int):
    """A pool of ``n`` spawned processes, each stopped by PID (:func:`_halt`) when the run
    stops or fails."""
    import multiprocessing
    pool = _Pool(n, mp_context=multiprocessing.get_context('spawn'), initializer=_worker_init)
    try:
        yield pool
        pool.shutdown(wait=True)
    except BaseException:
        _halt(pool)
        raise


# ---- the command line -----------------------------------------------------------------------

def build_parser() -> Parser:
    ap = Parser(prog='hydropump-demo', description=__doc__.splitlines()[0])
    ap.add_argument('--out', help='run folder (default: out/<timestamp>); checked before '
                    'anything starts: a folder this user can write, without bags of an '
                    'earlier run')
    ap.add_argument('--quick', action='store_true',
                    help='a short campaign: three identification experiments, EMC only')
    ap.add_argument('--sets', type=int_in(1, 100),
                    help='identification experiments (default 9; 3 with --quick)')
    # A stair holds two time constants of eq. 14 at least (about 0.1 s), and the record of
    # four stairs then leaves room for the 55 ms delay in the fit's delay bounds; the upper
    # end is the controller's excitation.dwell range.
    ap.add_argument('--dwell', type=float_in(0.2, 100.0, 's'),
                    help='stair duration [s] (default 0.8; 0.6 with --quick)')
    ap.add_argument('--calibrate', action='store_true',
                    help='also calibrate the bench plant from the identification bags, with '
                         'its validation figure in the report (about 25 s more)')
    ap.add_argument('--no-fig1', dest='fig1', action='store_false',
                    help="leave out the Fig. 1 duty cycle (a second graph beside the paper's "
                         'campaign)')
    ap.add_argument('--no-excavator', dest='excavator', action='store_false',
                    help="leave out the excavator's duty cycle (a third graph beside the "
                         "paper's campaign)")
    ap.add_argument('--jobs', type=int_in(1), default=1, metavar='N',
                    help='run the experiments on N graphs at once, each in its own ROS '
                         'domain (default 1: one graph; at most the number of CPUs)')
    return ap


def run_folder(out: str | None) -> Path:
    """The run folder (``--out``, or ``out/<timestamp>``), created and written to once here:
    one the run could not write is refused before any node starts."""
    path = Path(out) if out else Path('out') / datetime.now().strftime('%Y%m%d-%H%M%S')
    what = f'--out {out}'
    try:
        if path.exists() and not path.is_dir():
            raise UsageError(f'{what}: is a file; give a folder for the run')
        bags = path / 'bags'
        if bags.is_dir() and any(bags.iterdir()):
            raise UsageError(f'{what}: already holds the bags of an earlier run ({bags}); '
                             'give another folder or remove them')
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise UsageError(f'{what if out else f"run folder {path}"}: cannot write there '
                         f'({exc.strerror or exc})') from None
    return path


def _progress(msg: str) -> None:
    print(msg, flush=True)


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)  # a refused number is a UsageError
        cpus = os.cpu_count() or 1
        if args.jobs > cpus:
            # More graphs than CPUs only starve each other's lock-step exchanges.
            print(f'note: --jobs {args.jobs}: this machine runs {cpus} graph'
                  f'{"s" * (cpus != 1)} at once; using {cpus}', file=sys.stderr)
            args.jobs = cpus
        run_dir = run_folder(args.out)
    except UsageError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    from hydropump_ctrl.experiment import Stopped
    stop_on_sigterm()
    try:
        return run(args, run_dir)
    except HydropumpError as exc:
        from hydropump_ctrl.demo.campaign import one_line
        # One line: what failed (a stage names itself), and what the run keeps.
        print(f'error: {one_line(exc)}; {kept(run_dir)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130
    except Stopped:
        print(f'stopped by SIGTERM: every node of the run ended; the partial run is in '
              f'{run_dir}', file=sys.stderr)
        return Stopped.EXIT_CODE


def kept(run_dir: Path) -> str:
    """What a failed run leaves: the bags closed before it failed (each with its
    ``metadata.yaml``, which the recorder writes on closing a bag), never touched after."""
    bag_dir = run_dir / 'bags'
    n = sum(1 for _ in bag_dir.glob('*/metadata.yaml'))
    if not n:
        return f'no bag was recorded (run folder {run_dir})'
    return (f'the {n} bag{"s" * (n != 1)} recorded before it {"are" if n != 1 else "is"} '
            f'kept in {bag_dir}')


# ---- the run --------------------------------------------------------------------------------

def _run_stage(graph: Graph, what: str, stage: int, exps: list[Experiment], bag_dir: Path,
               starts: dict, tag: str = '') -> dict:
    """Run ``exps`` one after the other through ``graph``, with progress lines; the stage's
    times (:func:`stage_times`)."""
    from hydropump_ctrl.demo.campaign import stage_times

    from .orchestration import run_experiments
    t0, running0 = time.perf_counter(), graph.running_s
    done = run_experiments(graph, exps, bag_dir,
                           lambda i, _: f'{tag}[{stage}/5 {what} {i}/{len(exps)}]', _progress)
    starts.update({name: r['t0_s'] for name, r in done.items()})
    wall = time.perf_counter() - t0
    return stage_times(wall, sum(e.duration for e in exps), wall - (graph.running_s - running0))


def run_graph(stages: dict[str, list[Experiment]], run_dir: Path, log_dir: Path,
              profile_path: Path, tag: str = '', topics: list[str] | None = None,
              **start) -> tuple[dict, dict]:
    """One graph in a ROS domain of its own: start it (``start``: more of
    :meth:`Graph.start`'s keywords), run each stage's experiments into ``run_dir/bags``
    (``topics`` recorded: the closed loop's by default), stop it, its nodes ended by PID
    whatever ends the run (SIGTERM included). Returns the stage times and each experiment's
    start time."""
    from hydropump_ctrl.demo.campaign import LOOP_TOPICS, stage, stage_times

    from .orchestration import Graph, Orchestrator, own_domain
    topics = LOOP_TOPICS if topics is None else topics
    walls, starts = {}, {}
    where = f' ({tag.strip(" []")})' if tag else ''  # which graph, in a failure's line
    # The main graph in the user's ROS_DOMAIN_ID when they set one; a graph beside it (a
    # tag) in one of its own.
    with own_domain(user=not tag) as did:
        # rclpy's own signal handlers would shut the context down under a running
        # experiment (an RCLError): a signal unwinds this run instead (Stopped).
        orch = Orchestrator(signals=False)
        try:
            t0 = time.perf_counter()
            _progress(f'{tag}[0/5 graph] simulator, controller and recorder (ROS domain {did})'
                      ' ...')
            with stage(f'graph start-up{where}'):
                graph = Graph.start(orch, log_dir, topics, sensor_profile=profile_path,
                                    **start)
            try:
                _progress(f'{tag}      ready in ' + ', '.join(
                    f'{k} {v:.1f} s' for k, v in graph.ready_s.items()))
                wall = time.perf_counter() - t0
                walls['graph start-up'] = stage_times(wall, 0.0, wall)
                for i, (what, exps) in enumerate(stages.items(), 1):
                    with stage(f'recording ({what})'):
                        walls[what] = _run_stage(graph, what, i, exps, run_dir / 'bags',
                                                 starts, tag)
            finally:
                graph.close()
        finally:
            orch.close()
    return walls, starts


def _split(exps: list[Experiment], n: int) -> list[list[Experiment]]:
    """``n`` groups of about equal simulated time (longest first to the lightest group)."""
    groups: list[list[Experiment]] = [[] for _ in range(n)]
    for exp in sorted(exps, key=lambda e: -(e.duration + e.preroll)):
        min(groups, key=lambda g: sum(e.duration + e.preroll for e in g)).append(exp)
    return [g for g in groups if g]


def _run_jobs(stages: dict, run_dir: Path, profile_path: Path, jobs: int) -> tuple[dict, dict]:
    """The experiments over ``jobs`` graphs at once, each in its own process and domain."""
    from hydropump_ctrl.demo.campaign import stage_times
    exps = [e for group in stages.values() for e in group]
    groups = _split(exps, jobs)
    t0 = time.perf_counter()
    with _workers(len(groups)) as pool:
        futures = [pool.submit(run_graph, {'experiments': g}, run_dir,
                               run_dir / 'logs' / f'graph{k + 1}', profile_path,
                               f'[graph {k + 1}] ') for k, g in enumerate(groups)]
        results = [f.result() for f in futures]
    wall = time.perf_counter() - t0
    starts = {k: v for _, st in results for k, v in st.items()}
    # Orchestration overhead of parallel graphs: the wall time the slowest graph was not
    # stepping (start-up included).
    idle = max(sum(v['overhead_s'] for v in w.values()) for w, _ in results)
    name = f'experiments ({len(groups)} graphs at once)'
    return {name: stage_times(wall, sum(e.duration for e in exps), min(idle, wall))}, starts


def _start_fig1(pool, run_dir: Path, profile_path: Path, quick: bool):
    """Submit the Fig. 1 duty cycle's graph to ``pool``: its experiments and the future of
    :func:`run_graph`. The simulator runs config/circuits/fig1.yaml with the bench's sensors
    but not its dither (at 400 Hz it costs the stepper five times over and moves nothing a
    load sees); the controller runs config/controller_fig1.yaml (hydropump design
    --circuit)."""
    from hydropump_ctrl.demo import fig1
    from hydropump_sim.circuit import default_circuit_path, load_circuit
    from hydropump_sim.measure import recorded_topics
    from hydropump_sim.params import default_params_path
    path = default_circuit_path().with_name('fig1.yaml')
    variants = fig1.VARIANTS[::3] if quick else fig1.VARIANTS
    exps = fig1.fig1_experiments(load_circuit(path), variants)
    future = pool.submit(
        run_graph, {'Fig. 1 duty cycle': exps}, run_dir, run_dir / 'logs' / 'fig1',
        profile_path, '[Fig. 1] ',
        topics=fig1.recorder_topics(recorded_topics(str(path), commands=False)),
        circuit_file=path,
        controller_file=default_params_path().with_name('controller_fig1.yaml'),
        simulator={'input.dither_amp': 0.0})
    return exps, future


def _joined(beside, label: str, walls: dict, starts: dict) -> list:
    """The experiments of a graph run beside the paper's (``(experiments, future)`` or
    ``None``), once it has ended: its stages' wall times join ``walls`` under ``label``, its
    start instants join ``starts``."""
    if beside is None:
        return []
    experiments, future = beside
    own_walls, own_starts = future.result()
    walls.update({f'{label}{k}': v for k, v in own_walls.items()})
    starts.update(own_starts)
    return experiments


def _demo_files(args) -> list[Path]:
    """The config files the demo's graphs read besides the pump and the bench: the
    controllers and the circuits of the duty cycles that run."""
    from hydropump_sim.circuit import default_circuit_path
    from hydropump_sim.params import default_params_path
    config = default_params_path().parent
    out = [config / 'controller.yaml']
    if args.fig1:
        out += [default_circuit_path().with_name('fig1.yaml'), config / 'controller_fig1.yaml']
    if args.excavator:
        out += [default_circuit_path().with_name('excavator.yaml'),
                config / 'controller_excavator.yaml']
    return [p for p in out if p.is_file()]


def _start_excavator(pool, run_dir: Path, profile_path: Path):
    """Submit the excavator's duty cycle's graph to ``pool``: its experiment and the future
    of :func:`run_graph`. The simulator runs config/circuits/excavator.yaml (its plant
    config/excavator_pump.yaml) with the bench's sensors but not its dither, publishing at
    200 Hz (one sample per control period: its modes are of a few hertz, and 40 topics at
    1 kHz would cost the graph more than the stepping); the controller runs
    config/controller_excavator.yaml (hydropump design --circuit)."""
    from hydropump_ctrl.demo import excavator
    from hydropump_sim.circuit import load_circuit
    from hydropump_sim.measure import recorded_topics
    path = excavator.circuit_path()
    circuit = load_circuit(path, compile=False)
    exps = excavator.excavator_experiments(circuit)
    future = pool.submit(
        run_graph, {'excavator duty cycle': exps}, run_dir, run_dir / 'logs' / 'excavator',
        profile_path, '[excavator] ',
        topics=excavator.recorder_topics(circuit, recorded_topics(str(path), commands=False)),
        circuit_file=path, controller_file=excavator.controller_path(),
        params_file=path.parent.parent / 'excavator_pump.yaml',
        simulator={'input.dither_amp': 0.0}, publish_rate=200.0)
    return exps, future


def run(args, run_dir: Path) -> int:
    from hydropump_ctrl.demo.campaign import (
        analyse_campaign,
        BESIDE,
        BESIDE_EXCAVATOR,
        CampaignRun,
        closed_loop_experiments,
        identification_experiments,
    )
    from hydropump_ctrl.provenance import collect
    from hydropump_sim.params import default_params_path, load_params
    from hydropump_sim.sensors import load_profile
    t_all = time.perf_counter()
    params = load_params(default_params_path())
    profile_path = default_params_path().with_name('bench.yaml')
    profile = load_profile(profile_path)
    n_sets = args.sets if args.sets is not None else 3 if args.quick else 9
    dwell = args.dwell if args.dwell is not None else 0.6 if args.quick else 0.8  # s: 8 tau
    idents = identification_experiments(params, n_sets, dwell)
    loops = closed_loop_experiments(params, ('emc',) if args.quick else ('emc', 'pi'))
    _progress(f'run folder: {run_dir}')
    # Two processes for the report's work that needs neither the graph nor the fit (the
    # operating map and dither figures, the plant's twin): they run beside the fit.
    with _workers(2) as pool, _workers(1) as beside, _workers(1) as machine:
        # The Fig. 1 duty cycle and the excavator's: graphs of their own, beside the paper's
        # campaign.
        duty = _start_fig1(beside, run_dir, profile_path, args.quick) if args.fig1 else None
        dig = (_start_excavator(machine, run_dir, profile_path) if args.excavator
               else None)
        # 1. The identification campaign, then 2. the closed loop; the stages are numbered
        # in the order they run.
        stages = {'identification': idents, 'closed loop': loops}
        if args.jobs > 1:
            walls, starts = _run_jobs(stages, run_dir, profile_path, args.jobs)
        else:
            walls, starts = run_graph(stages, run_dir, run_dir / 'logs', profile_path)
        fig1 = _joined(duty, BESIDE, walls, starts)
        excavator = _joined(dig, BESIDE_EXCAVATOR, walls, starts)
        # 3. Fitting, 4. model analysis, 5. report: no graph needed.
        run = CampaignRun(run_dir, run_dir / 'bags', params, profile, idents, loops, walls,
                          t_all, starts or {}, fig1=fig1, excavator=excavator,
                          prov=collect([default_params_path(), profile_path,
                                        *_demo_files(args)]))
        page = analyse_campaign(run, echo=_progress, pool=pool, calibrate=args.calibrate)
    print(f'\nreport: {page.resolve()}\nbags: {(run_dir / "bags").resolve()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
