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

This module owns what needs the graph: the node processes, their services and parameters,
the simulation clock. The experiments, the analysis of their bags and the report are pure
(:mod:`hydropump_ctrl.experiments.campaign`).

The three nodes are started once (:class:`Graph`) and every experiment goes through them:
live parameters, the simulator's ``~/reset`` and ``pause_at``, one bag per experiment from
the recorder's ``~/start`` and ``~/stop``. Each node logs to ``<run>/logs/<node>.log`` and is
ended by PID. A node that fails stops the run with a message that names it and its log.
"""

from __future__ import annotations

import argparse
from datetime import datetime
import os
from pathlib import Path
import random
import signal
import subprocess
import sys
import time

from hydropump_ctrl.experiments.campaign import (
    analyse_campaign,
    closed_loop_experiments,
    Experiment,
    identification_experiments,
    LOOP_TOPICS,
    stage_times,
)
from hydropump_sim.errors import HydropumpError


class DemoError(HydropumpError):
    """A failure of the graph that ends the run: one line for the user."""


# ---- the node graph -------------------------------------------------------------------------

def _executable(name: str) -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix('hydropump_ros')) / 'lib' / 'hydropump_ros' / name)


def _ros_value(v) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, (list, tuple)):
        return '[' + ', '.join(str(x) for x in v) + ']'
    return str(v)


def _ros_args(values: dict) -> list[str]:
    out = []
    for k, v in values.items():
        out += ['-p', f'{k}:={_ros_value(v)}']
    return out


class Orchestrator:
    """The run's own rclpy node: service calls, parameter sets, the simulation clock."""

    def __init__(self):
        import rclpy
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        self.rclpy = rclpy
        rclpy.init()
        self.node = Node(f'hydropump_demo_{os.getpid()}')
        self.t = -1.0
        # Only the latest time matters here: one callback per spin, not one per step.
        self.node.create_subscription(Clock, '/clock', self._on_clock, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST))
        self._clients = {}
        self.procs: dict = {}

    def _on_clock(self, msg) -> None:
        self.t = msg.clock.sec + msg.clock.nanosec * 1e-9

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()

    def check_nodes(self) -> None:
        for name, (proc, log, exp) in self.procs.items():
            if proc.poll() is not None:
                raise DemoError(f'node {name} of experiment {exp} exited with code '
                                f'{proc.returncode}: see {log}')

    def spin_until(self, predicate, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            self.check_nodes()
            if time.monotonic() > deadline:
                raise DemoError(f'timed out after {timeout:g} s waiting for {what}')
            self.rclpy.spin_once(self.node, timeout_sec=0.01)

    def service_ready(self, name: str) -> bool:
        """Has the graph a server of ``name``? (Any type: the name says which node.)"""
        return any(n == '/' + name.lstrip('/') for n, _ in
                   self.node.get_service_names_and_types())

    def call(self, srv_type, name: str, request, timeout: float = 60.0):
        if name not in self._clients:
            self._clients[name] = self.node.create_client(srv_type, name)
        client = self._clients[name]
        self.spin_until(client.service_is_ready, timeout, f'the service {name}')
        future = client.call_async(request)
        self.spin_until(future.done, timeout, f'the answer of {name}')
        return future.result()

    def set_params(self, node: str, values: dict) -> None:
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                for k, v in values.items()])
        for name, result in zip(values, self.call(SetParameters, f'{node}/set_parameters',
                                                  req).results):
            if not result.successful:
                raise DemoError(f'{node} refused {name} = {values[name]}: {result.reason}')


#: Measurement rate of the campaign [Hz]: 2 ms samples resolve a 100 ms time constant and a
#: 55 ms delay (the fit takes any fraction of a sample), and lock-step runs about three times
#: faster than at the simulator's default 1 kHz, since each sample costs every node a message
#: per topic.
PUBLISH_RATE = 200.0


class Graph:
    """The campaign's one node graph: simulator (lock-step, bench profile, paused), controller
    and recorder, started once; :meth:`run` takes one experiment through it into its bag.

    Between experiments the simulator stands paused: the next one sets its operating point,
    initial current and noise seed (live), opens its bag, restarts the controller (lifecycle
    deactivate, parameters, activate) and resets the simulator, whose reset state comes out
    at the next control instant ``t0``. The schedule then runs in simulation time from
    ``t0``: pause at each change, apply it, go on, and at the end close the bag at
    ``t0 + duration`` exactly.
    """

    NODES = ('recorder', 'simulator', 'controller')

    def __init__(self, orch: Orchestrator, log_dir: Path, sensor_profile: Path,
                 topics: list[str]):
        self.orch = orch
        self.log_dir = log_dir
        log_dir.mkdir(parents=True, exist_ok=True)
        # Waits are long: a loaded machine must slow the run down, never cut it short.
        sim = {'lock_step': True, 'lock_step_timeout': 60.0, 'start_paused': True,
               'command_timeout': 60.0, 'wait_subscribers': 1, 'publish_rate': PUBLISH_RATE}
        self.commands = {
            'recorder': ['-p', 'autostart:=false', '-p', f'topics:={_ros_value(topics)}'],
            'simulator': ['--params-file', str(sensor_profile)] + _ros_args(sim),
            'controller': ['-p', 'autostart:=true', '-p', 'watchdog.hold_timeout:=30.0',
                           '-p', 'watchdog.safe_timeout:=60.0'],
        }
        self.ready_s: dict[str, float] = {}
        self.running_s = 0.0  # wall time the simulator spent stepping

    def start(self) -> dict[str, float]:
        """Start the nodes (in parallel) and wait until each is ready; its start-up time [s]
        from the process start: the simulator's services answer, the controller is active,
        the recorder has matched a publisher on every topic."""
        from lifecycle_msgs.msg import State
        from lifecycle_msgs.srv import GetState
        from std_srvs.srv import Trigger
        orch, t0 = self.orch, time.perf_counter()
        for name in self.NODES:
            log = self.log_dir / f'{name}.log'
            proc = subprocess.Popen([_executable(name), '--ros-args'] + self.commands[name],
                                    stdout=open(log, 'w'), stderr=subprocess.STDOUT)
            orch.procs[name] = (proc, log, 'the campaign')
        orch.spin_until(lambda: orch.service_ready('simulator/reset'), 60,
                        'the simulator to start')
        self.ready_s['simulator'] = time.perf_counter() - t0
        get_state = GetState.Request()
        orch.spin_until(lambda: orch.call(GetState, 'controller/get_state', get_state)
                        .current_state.id == State.PRIMARY_STATE_ACTIVE, 60,
                        'the controller to be active')
        self.ready_s['controller'] = time.perf_counter() - t0
        orch.spin_until(lambda: orch.service_ready('recorder/start'), 60,
                        'the recorder to start')
        self.ready_s['recorder'] = time.perf_counter() - t0
        orch.spin_until(lambda: orch.call(Trigger, 'recorder/ready', Trigger.Request()).success,
                        60, 'the recorder to match every topic')
        self.ready_s['graph'] = time.perf_counter() - t0
        return self.ready_s

    def _lifecycle(self, transition: int) -> None:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        req = ChangeState.Request(transition=Transition(id=transition))
        if not self.orch.call(ChangeState, 'controller/change_state', req).success:
            raise DemoError(f'the controller refused lifecycle transition {transition}: see '
                            f'{self.log_dir / "controller.log"}')

    def run(self, exp: Experiment, bag: Path) -> float:
        """Run ``exp`` into ``bag``; the simulation time [s] it started at."""
        from lifecycle_msgs.msg import Transition
        from std_srvs.srv import Trigger
        orch = self.orch
        self._lifecycle(Transition.TRANSITION_DEACTIVATE)
        orch.set_params('controller', exp.ctrl)
        orch.set_params('simulator', exp.sim)
        orch.set_params('recorder', {'output': str(bag)})
        if not exp.preroll:
            self._open(bag)
        self._lifecycle(Transition.TRANSITION_ACTIVATE)
        before = orch.t
        if not orch.call(Trigger, 'simulator/reset', Trigger.Request()).success:
            raise DemoError('the simulator refused ~/reset')
        if before < 0.0:
            t0 = 0.0  # not started yet: the reset state is the first step, at t = 0
        else:
            orch.spin_until(lambda: orch.t > before, 60, f'the reset of {exp.name}')
            t0 = orch.t
        if exp.preroll:  # run it, then open the bag: the start is settled
            t0 += exp.preroll
            self._run_to(t0, exp)
            self._open(bag)
        for t, node, values in sorted(exp.events, key=lambda e: e[0]):
            self._run_to(t0 + float(t), exp)
            orch.set_params(node, values)
        # One sample past the end, so that the current held from the last instant is out too;
        # the bag ends at the end exactly.
        self._run_to(t0 + exp.duration + 1.0 / PUBLISH_RATE, exp)
        orch.set_params('recorder', {'stop_time': t0 + exp.duration})
        if not orch.call(Trigger, 'recorder/stop', Trigger.Request(), timeout=120).success:
            raise DemoError(f'the recorder did not close {bag}: see '
                            f'{self.log_dir / "recorder.log"}')
        return t0

    def _open(self, bag: Path) -> None:
        from std_srvs.srv import Trigger
        start = self.orch.call(Trigger, 'recorder/start', Trigger.Request())
        if not start.success:
            raise DemoError(f'the recorder could not open {bag}: {start.message}')

    def _run_to(self, t: float, exp: Experiment) -> None:
        """Let the simulator run to simulation time ``t`` [s] and pause there."""
        from std_srvs.srv import SetBool
        orch = self.orch
        orch.set_params('simulator', {'pause_at': t})
        t_run = time.perf_counter()
        orch.call(SetBool, 'simulator/pause', SetBool.Request(data=False))
        orch.spin_until(lambda: orch.t >= t - 1e-9, 600,
                        f'simulation time {t:g} s in {exp.name}')
        self.running_s += time.perf_counter() - t_run

    def close(self) -> None:
        """SIGINT, as ``ros2 launch`` stops a node; SIGKILL after 20 s."""
        procs = [p for p, _, _ in self.orch.procs.values()]
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self.orch.procs = {}


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
    """Run ``exps`` one after the other through ``graph``, with a progress line each; the
    stage's times (:func:`stage_times`)."""
    t0, running0 = time.perf_counter(), graph.running_s
    for i, exp in enumerate(exps, 1):
        t1 = time.perf_counter()
        _progress(f'{tag}[{stage}/5 {what} {i}/{len(exps)}] {exp.label} ...')
        starts[exp.name] = graph.run(exp, exp.bag(bag_dir))
        _progress(f'{tag}      {exp.duration:g} s simulated in '
                  f'{time.perf_counter() - t1:.1f} s -> {exp.bag(bag_dir)}')
    wall = time.perf_counter() - t0
    return stage_times(wall, sum(e.duration for e in exps), wall - (graph.running_s - running0))


def _domain():
    """A ROS domain of this host that no other graph of the domain coordinator holds."""
    from domain_coordinator import domain_id
    first = random.randrange(100)
    return domain_id(lambda s=[first]: (s.__setitem__(0, s[0] + 1) or s[0] % 100 + 1))


def run_graph(stages: dict[str, list[Experiment]], run_dir: Path, log_dir: Path,
              profile_path: Path, tag: str = '') -> tuple[dict, dict]:
    """One graph in a ROS domain of its own: start it, run each stage's experiments into
    ``run_dir/bags``, stop it. Returns the stage times and each experiment's start time."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    walls, starts = {}, {}
    with _domain() as did:
        os.environ['ROS_DOMAIN_ID'] = str(did)
        orch = Orchestrator()
        graph = Graph(orch, log_dir, profile_path, LOOP_TOPICS)
        try:
            t0 = time.perf_counter()
            _progress(f'{tag}[0/5 graph] simulator, controller and recorder (ROS domain {did})'
                      ' ...')
            ready = graph.start()
            _progress(f'{tag}      ready in ' + ', '.join(f'{k} {v:.1f} s'
                                                         for k, v in ready.items()))
            wall = time.perf_counter() - t0
            walls['graph start-up'] = stage_times(wall, 0.0, wall)
            for i, (what, exps) in enumerate(stages.items(), 1):
                walls[what] = _run_stage(graph, what, i, exps, run_dir / 'bags', starts, tag)
        finally:
            graph.close()
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
    # Two processes for the report's work that needs neither the graph nor the fit (the
    # operating map and dither figures, the plant's twin): they run beside the fit.
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context('spawn')) as pool:
        # 1. The identification campaign, then 2. the closed loop; the stages are numbered
        # in the order they run.
        stages = {'identification': idents, 'closed loop': loops}
        if args.jobs > 1:
            walls, starts = _run_jobs(stages, run_dir, profile_path, args.jobs)
        else:
            walls, starts = run_graph(stages, run_dir, run_dir / 'logs', profile_path)
        # 3. Fitting, 4. model analysis, 5. report: no graph needed.
        page = analyse_campaign(run_dir, run_dir / 'bags', params, profile, idents, loops,
                                walls, t_all, starts, echo=_progress, pool=pool,
                                calibrate=args.calibrate)
    print(f'\nreport: {page.resolve()}\nbags: {(run_dir / "bags").resolve()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
