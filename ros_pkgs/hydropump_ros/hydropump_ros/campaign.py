"""``hydropump-demo``: the paper end to end through the real node graph.

1. Identification campaign: nine open-loop experiments (growing-flow current staircases at
   differing operating points and noise seeds) through the simulator (bench sensor profile),
   the controller in ``open_loop`` mode and the recorder, in lock-step, into nine bags.
2. Fitting: eq. 19 on the nine bags (``hydropump fit``), next to the paper's figures and the
   plant's own (a noise-free, delay-free twin of each experiment, and the configured delay).
3. Closed loop: EMC and PI on a flow step, a load-aperture step and a margin set-point step.
4. Model analysis: the modal table and the singular-perturbation check.
5. Report: one self-contained HTML page with PNG figures in ``out/<timestamp>/``, the bags
   beside it.

This module owns what needs the graph: the node processes, their services and parameters,
the simulation clock. The experiments, the analysis of their bags and the report are pure
(:mod:`hydropump_ctrl.experiments.campaign`).

Every node runs in its own process, logs to ``<run>/logs/<experiment>/<node>.log``, and is
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
        from rosgraph_msgs.msg import Clock
        self.rclpy = rclpy
        rclpy.init()
        self.node = Node(f'hydropump_demo_{os.getpid()}')
        self.t = -1.0
        self.node.create_subscription(Clock, '/clock', self._on_clock, 100)
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


def run_experiment(orch: Orchestrator, exp: Experiment, run_dir: Path, bag_dir: Path,
                   sensor_profile: Path) -> Path:
    """Start the three nodes, run the experiment in lock-step, stop, return the bag."""
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import GetState
    from std_srvs.srv import SetBool, Trigger
    logs = run_dir / 'logs' / exp.name
    logs.mkdir(parents=True, exist_ok=True)
    bag = exp.bag(bag_dir)
    # The first step waits until the recorder is matched; the bag ends at the experiment's
    # end however loaded the machine is.
    sim = {'lock_step': True, 'lock_step_timeout': 60.0, 'start_paused': True,
           'command_timeout': 60.0, 'wait_subscribers': 1, **exp.sim}
    if exp.scenario:
        import yaml
        sc = logs / 'scenario.yaml'
        sc.write_text(yaml.safe_dump({'duration': exp.duration, 'inputs': exp.scenario}))
        sim['scenario_file'] = str(sc)
    commands = {
        'recorder': ['-p', f'output:={bag}', '-p', f'topics:={_ros_value(exp.topics)}',
                     '-p', f'stop_time:={float(exp.duration)!r}'],
        'simulator': ['--params-file', str(sensor_profile)] + _ros_args(sim),
        'controller': ['-p', 'autostart:=true',
                       '-p', 'watchdog.hold_timeout:=30.0', '-p', 'watchdog.safe_timeout:=60.0']
        + _ros_args(exp.ctrl),
    }
    orch.procs = {}
    orch.t = -1.0  # this experiment's clock only
    try:
        for name in ('recorder', 'simulator', 'controller'):
            log = logs / f'{name}.log'
            proc = subprocess.Popen([_executable(name), '--ros-args'] + commands[name],
                                    stdout=open(log, 'w'), stderr=subprocess.STDOUT)
            orch.procs[name] = (proc, log, exp.name)
        get_state = GetState.Request()
        orch.spin_until(lambda: orch.call(GetState, 'controller/get_state', get_state)
                        .current_state.id == State.PRIMARY_STATE_ACTIVE, 60,
                        'the controller to be active')
        orch.spin_until(lambda: orch.call(Trigger, 'recorder/ready', Trigger.Request()).success,
                        60, 'the recorder to match every topic')
        # Run through the schedule: pause at each change, apply it, go on.
        for t, node, values in sorted(exp.events, key=lambda e: e[0]) + [
                (exp.duration, None, None)]:
            orch.set_params('simulator', {'pause_at': float(t)})
            orch.call(SetBool, 'simulator/pause', SetBool.Request(data=False))
            orch.spin_until(lambda t=t: orch.t >= t - 1e-9, 600,
                            f'simulation time {t:g} s of {exp.name}')
            if node:
                orch.set_params(node, values)
        if not orch.call(Trigger, 'recorder/stop', Trigger.Request(), timeout=120).success:
            raise DemoError(f'the recorder of {exp.name} did not close its bag: see '
                            f'{logs / "recorder.log"}')
    finally:
        for proc, _, _ in orch.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc, _, _ in orch.procs.values():
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        orch.procs = {}
    return bag


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
    args = ap.parse_args(argv)
    try:
        return run(args)
    except HydropumpError as exc:
        for line in exc.lines:
            print(f'error: {line}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


def _run_all(orch: Orchestrator, what: str, stage: int, exps: list[Experiment], run_dir: Path,
             bag_dir: Path, sensor_profile: Path) -> float:
    """Run ``exps`` one after the other, with a progress line each; the wall time [s]."""
    t0 = time.perf_counter()
    for i, exp in enumerate(exps, 1):
        t1 = time.perf_counter()
        _progress(f'[{stage}/5 {what} {i}/{len(exps)}] {exp.label} ...')
        bag = run_experiment(orch, exp, run_dir, bag_dir, sensor_profile)
        _progress(f'      {exp.duration:g} s simulated in {time.perf_counter() - t1:.1f} s'
                  + (f' -> {bag}' if stage == 1 else ''))
    return time.perf_counter() - t0


def run(args) -> int:
    from domain_coordinator import domain_id

    from hydropump_sim.params import default_params_path, load_params
    from hydropump_sim.sensors import load_profile
    t_all = time.perf_counter()
    run_dir = Path(args.out) if args.out else Path('out') / datetime.now().strftime(
        '%Y%m%d-%H%M%S')
    run_dir.mkdir(parents=True, exist_ok=True)
    bag_dir = run_dir / 'bags'
    params = load_params(default_params_path())
    profile_path = default_params_path().with_name('bench.yaml')
    profile = load_profile(profile_path)
    n_sets = args.sets or (3 if args.quick else 9)
    dwell = args.dwell or (0.6 if args.quick else 1.0)
    idents = identification_experiments(params, n_sets, dwell)
    loops = closed_loop_experiments(params, ('emc',) if args.quick else ('emc', 'pi'))
    walls = {}
    _progress(f'run folder: {run_dir}')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    start = random.randrange(100)
    with domain_id(lambda s=[start]: (s.__setitem__(0, s[0] + 1) or s[0] % 100 + 1)) as did:
        os.environ['ROS_DOMAIN_ID'] = str(did)
        orch = Orchestrator()
        try:
            # 1. The identification campaign, then 2. the closed loop, while the graph tools
            # are up; the stages are numbered in the order they run.
            walls['identification'] = _run_all(orch, 'identification', 1, idents, run_dir,
                                                bag_dir, profile_path)
            walls['closed loop'] = _run_all(orch, 'closed loop', 2, loops, run_dir, bag_dir,
                                             profile_path)
        finally:
            orch.close()
    # 3. Fitting, 4. model analysis, 5. report: no graph needed.
    page = analyse_campaign(run_dir, bag_dir, params, profile, idents, loops, walls, t_all,
                            echo=_progress)
    print(f'\nreport: {page.resolve()}\nbags: {bag_dir.resolve()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
