"""``hydropump record``: a recording plan through the real nodes, one bag per experiment.

The command itself (options, the plan's checks, the summary) is the pure
:mod:`hydropump_ctrl.cli.record`; it finds :func:`run` through the ``hydropump.runners``
entry point of this package. Here is only what needs the graph, on the one orchestration of
:mod:`.orchestration`: a graph of its own in a ROS domain of its own (simulator in lock-step
with the plan's params file and sensor profile, started paused), or the graph already running
in this domain and namespace (``--attach``).

SIGTERM stops the run as it stops ``hydropump-demo`` (:func:`.orchestration.stop_on_sigterm`):
:class:`~hydropump_ctrl.experiment.Stopped` unwinds it, a graph of its own ends
its nodes by PID (the recorder closes the open bag), an attached graph has its open bag
closed; the command says so in one line and exits with code 143.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import time

from hydropump_ctrl.plans import (
    check_plan,
    LOG_FOLDER,
    node_experiment,
    Plan,
    STANDARD,
    standard_plan,
)
from hydropump_sim.measure import suite_topics

from .orchestration import Graph, Orchestrator, own_domain, run_experiments, stop_on_sigterm


def run(plan: Plan, params, args, echo: Callable[[str], None] = print) -> dict[str, dict]:
    """Record every experiment of ``plan`` into ``args.out/<name>``.

    Parameters
    ----------
    plan : Plan
        Checked against ``params`` already.
    params : Params
        The plant of ``args.params`` (with the profile's overrides): the graph started here
        runs it. With ``args.attach`` the running simulator's plant is read instead, and the
        plan checked again against it.
    args : argparse.Namespace
        ``out``, ``params``, ``profile``, ``attach``, ``namespace``, ``wait``.
    echo : callable
        Where the progress lines go.

    Returns
    -------
    dict
        Per experiment (:func:`.orchestration.run_experiments`).
    """
    out = Path(args.out).resolve()
    # rclpy's own signal handlers would shut the context down under a waiting call (an
    # RCLError): SIGTERM unwinds the run instead.
    stop_on_sigterm()
    if args.attach:
        return _attached(plan, args, out, echo)
    with own_domain() as did:
        orch = Orchestrator(args.namespace, signals=False)
        try:
            t0 = time.perf_counter()
            echo(f'[graph] simulator, controller and recorder (ROS domain {did}'
                 + (f', namespace {orch.namespace}' if orch.namespace else '') + ') ...')
            graph = Graph.start(orch, out / LOG_FOLDER, suite_topics(),
                                sensor_profile=args.profile, params_file=args.params,
                                publish_rate=args.rate)
            try:
                echo(f'[graph] ready in {time.perf_counter() - t0:.1f} s; logs in '
                     f'{out / LOG_FOLDER}')
                return _record(graph, plan, params, out, echo)
            finally:
                graph.close()
        finally:
            orch.close()


def _attached(plan: Plan, args, out: Path, echo) -> dict[str, dict]:
    import os
    orch = Orchestrator(args.namespace, signals=False)
    try:
        echo(f'[graph] looking for simulator, controller and recorder (ROS domain '
             f'{os.environ.get("ROS_DOMAIN_ID", "0")}, namespace {orch.namespace or "/"}) ...')
        graph = Graph.attach(orch, timeout=args.wait)
        try:
            for note in graph.notes:
                echo(f'[graph] {note}')
            params = graph.plant()
            if plan.source == STANDARD:
                plan = standard_plan(params)   # the running plant's levels and load pressure
            else:
                check_plan(plan, params, graph.period)
            echo(f'[graph] attached: lock-step at {graph.period * 1e3:g} ms, '
                 f'{graph.publish_rate:g} Hz')
            return _record(graph, plan, params, out, echo)
        finally:
            graph.close()
    finally:
        orch.close()


def _record(graph: Graph, plan: Plan, params, out: Path, echo) -> dict[str, dict]:
    exps = [node_experiment(e, params, graph.period) for e in plan.experiments]
    n = len(exps)
    return run_experiments(graph, exps, out, lambda i, e: f'[{i}/{n} {e.name}]', echo)
