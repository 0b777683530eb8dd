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
the analysis of their bags and the report are pure (:mod:`hydropump_ctrl.experiments.campaign`).
"""

from __future__ import annotations

import argparse
from datetime import datetime
from pathlib import Path
import sys
import time

from hydropump_ctrl.experiments.campaign import (
    analyse_campaign,
    BESIDE,
    closed_loop_experiments,
    Experiment,
    identification_experiments,
    LOOP_TOPICS,
    stage_times,
)
from hydropump_sim.errors import HydropumpError

from .orchestration import Graph, Orchestrator, own_domain, run_experiments

# ---- the run --------------------------------------------------------------------------------

def _progress(msg: str) -> None:
    print(msg, flush=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='hydropump-demo', description=__doc__.splitlines()[0])
    ap.add_argument('--out', help='run folder (default: out/<timestamp>)')
    ap.add_argument('--quick', action='store_true',
                    help='a short campaign: three identification experiments, EMC only')
    ap.add_argument('--sets', type=int, default=None, help='identification experiments')
    ap.add_argument('--dwell', type=float, default=None, help='stair duration [s]')
    ap.add_argument('--calibrate', action='store_true',
                    help='also calibrate the bench plant from the identification bags, with '
                         'its validation figure in the report (about 25 s more)')
    ap.add_argument('--no-fig1', dest='fig1', action='store_false',
                    help="leave out the Fig. 1 duty cycle (a second graph beside the paper's "
                         'campaign)')
    ap.add_argument('--jobs', type=int, default=1, metavar='N',
                    help='run the experiments on N graphs at once, each in its own ROS '
                         'domain (default 1: one graph)')
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error(f'--jobs {args.jobs}: give 1 or more graphs')
    try:
        return run(args)
    except HydropumpError as exc:
        for line in exc.lines:
            print(f'error: {line}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


def _run_stage(graph: Graph, what: str, stage: int, exps: list[Experiment], bag_dir: Path,
               starts: dict, tag: str = '') -> dict:
    """Run ``exps`` one after the other through ``graph``, with progress lines; the stage's
    times (:func:`stage_times`)."""
    t0, running0 = time.perf_counter(), graph.running_s
    done = run_experiments(graph, exps, bag_dir,
                           lambda i, _: f'{tag}[{stage}/5 {what} {i}/{len(exps)}]', _progress)
    starts.update({name: r['t0_s'] for name, r in done.items()})
    wall = time.perf_counter() - t0
    return stage_times(wall, sum(e.duration for e in exps), wall - (graph.running_s - running0))


def run_graph(stages: dict[str, list[Experiment]], run_dir: Path, log_dir: Path,
              profile_path: Path, tag: str = '', topics: list[str] = LOOP_TOPICS,
              **start) -> tuple[dict, dict]:
    """One graph in a ROS domain of its own: start it (``start``: more of
    :meth:`Graph.start`'s keywords), run each stage's experiments into ``run_dir/bags``,
    stop it. Returns the stage times and each experiment's start time."""
    walls, starts = {}, {}
    with own_domain() as did:
        orch = Orchestrator()
        try:
            t0 = time.perf_counter()
            _progress(f'{tag}[0/5 graph] simulator, controller and recorder (ROS domain {did})'
                      ' ...')
            graph = Graph.start(orch, log_dir, topics, sensor_profile=profile_path, **start)
            try:
                _progress(f'{tag}      ready in ' + ', '.join(
                    f'{k} {v:.1f} s' for k, v in graph.ready_s.items()))
                wall = time.perf_counter() - t0
                walls['graph start-up'] = stage_times(wall, 0.0, wall)
                for i, (what, exps) in enumerate(stages.items(), 1):
                    walls[what] = _run_stage(graph, what, i, exps, run_dir / 'bags', starts,
                                             tag)
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
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing
    exps = [e for group in stages.values() for e in group]
    groups = _split(exps, jobs)
    t0 = time.perf_counter()
    with ProcessPoolExecutor(len(groups), mp_context=multiprocessing.get_context('spawn')) \
            as pool:
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
    from hydropump_ctrl.experiments import fig1
    from hydropump_sim.circuit import default_circuit_path, load_circuit
    from hydropump_sim.circuit_plant import recorded_topics
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


def run(args) -> int:
    from hydropump_sim.params import default_params_path, load_params
    from hydropump_sim.sensors import load_profile
    t_all = time.perf_counter()
    run_dir = Path(args.out) if args.out else Path('out') / datetime.now().strftime(
        '%Y%m%d-%H%M%S')
    run_dir.mkdir(parents=True, exist_ok=True)
    params = load_params(default_params_path())
    profile_path = default_params_path().with_name('bench.yaml')
    profile = load_profile(profile_path)
    n_sets = args.sets or (3 if args.quick else 9)
    dwell = args.dwell or (0.6 if args.quick else 0.8)  # s: eight tau a stair
    idents = identification_experiments(params, n_sets, dwell)
    loops = closed_loop_experiments(params, ('emc',) if args.quick else ('emc', 'pi'))
    _progress(f'run folder: {run_dir}')
    from concurrent.futures import ProcessPoolExecutor
    import multiprocessing
    spawn = multiprocessing.get_context('spawn')
    # Two processes for the report's work that needs neither the graph nor the fit (the
    # operating map and dither figures, the plant's twin): they run beside the fit.
    with ProcessPoolExecutor(2, mp_context=spawn) as pool, \
            ProcessPoolExecutor(1, mp_context=spawn) as beside:
        # The Fig. 1 duty cycle: a graph of its own, beside the paper's campaign.
        duty = _start_fig1(beside, run_dir, profile_path, args.quick) if args.fig1 else None
        # 1. The identification campaign, then 2. the closed loop; the stages are numbered
        # in the order they run.
        stages = {'identification': idents, 'closed loop': loops}
        if args.jobs > 1:
            walls, starts = _run_jobs(stages, run_dir, profile_path, args.jobs)
        else:
            walls, starts = run_graph(stages, run_dir, run_dir / 'logs', profile_path)
        fig1 = []
        if duty is not None:
            fig1, future = duty
            fig1_walls, fig1_starts = future.result()
            walls.update({f'{BESIDE}{k}': v for k, v in fig1_walls.items()})
            starts.update(fig1_starts)
        # 3. Fitting, 4. model analysis, 5. report: no graph needed.
        page = analyse_campaign(run_dir, run_dir / 'bags', params, profile, idents, loops,
                                walls, t_all, starts, echo=_progress, pool=pool,
                                calibrate=args.calibrate, fig1=fig1)
    print(f'\nreport: {page.resolve()}\nbags: {(run_dir / "bags").resolve()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
