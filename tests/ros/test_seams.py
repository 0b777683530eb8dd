"""The suite as a ROS user meets it: the installed executables started as ``ros2 run`` starts
them (no launch file, no ``use_sim_time``), stopped with Ctrl-C (once, twice as under
``ros2 launch``) and SIGTERM, bad input at start-up, a simulator that restarts under a running
controller, a second simulator in the same domain."""

from contextlib import ExitStack
import os
from pathlib import Path
import random
import re
import signal
import subprocess
import time

import numpy as np
import pytest
import yaml

from ..conftest import PUMP_YAML
from .rosutil import executable, spin_until

pytestmark = pytest.mark.ros

# Signal loops per node and pattern: two in the suite (each a fresh start at a moment of
# its own), ten in `make soak`.
LOOPS = int(os.environ.get('HYDROPUMP_SIGNAL_LOOPS', '2'))
READY = {'simulator': 'ready:', 'controller': 'active: publishing', 'recorder': 'recording '}
PLAIN = {'simulator': [], 'controller': ['-p', 'autostart:=true'], 'recorder': []}
PATTERNS = {'sigint': [signal.SIGINT], 'sigint_twice': [signal.SIGINT, signal.SIGINT],
            'sigterm': [signal.SIGTERM]}


@pytest.fixture
def domains():
    """Reserved ROS domain IDs, one per process that must not see the others."""
    from domain_coordinator import domain_id
    stack = ExitStack()
    state = [random.randrange(100)]

    def selector():
        state[0] += 1
        return state[0] % 100 + 1

    def take(n):
        return [stack.enter_context(domain_id(selector)) for _ in range(n)]
    with stack:
        yield take


class Proc:
    """A node process as ``ros2 run`` starts it, in its own domain, log to a file."""

    def __init__(self, name, args, log_dir, domain, cwd=None):
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        self.name = name
        self.log_path = Path(log_dir) / f'{name}-{domain}-{time.monotonic_ns()}.log'
        self._log = open(self.log_path, 'w')  # noqa: SIM115 - closed in wait()
        cmd = [executable(name)] + (['--ros-args', *args] if args else [])
        self.proc = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, env=env,
                                     cwd=cwd)

    def log(self):
        return self.log_path.read_text()

    def ready(self):
        return READY[self.name] in self.log()

    def wait(self, timeout=20.0):
        try:
            return self.proc.wait(timeout)
        finally:
            self._log.close()

    def end(self):
        if self.proc.poll() is None:
            self.proc.kill()
        self.wait()


def _wait_until(predicate, timeout, what, why=None):
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise AssertionError(f'timed out after {timeout:g} s waiting for {what}'
                                 + (f'\n{why()}' if why else ''))
        time.sleep(0.05)


@pytest.mark.slow
def test_every_node_ends_cleanly_on_ctrl_c_twice_and_sigterm(tmp_path, domains):
    """Each node, each pattern, LOOPS times: exit 0, no traceback; the recorder has closed
    its bag within a second of the first signal."""
    cases = [(n, p) for n in PLAIN for p in PATTERNS]
    ids = domains(len(cases))
    failures = []
    for loop in range(LOOPS):
        procs = [Proc(n, PLAIN[n], tmp_path, d, cwd=tmp_path)
                 for (n, _), d in zip(cases, ids)]
        try:
            _wait_until(lambda procs=procs: all(p.ready() for p in procs), 120,
                        'every node to be ready',
                        lambda procs=procs: '\n'.join(f'{p.name}: {p.log()[-300:]}'
                                                       for p in procs if not p.ready()))
            sent = {}
            for p, (_, pattern) in zip(procs, cases):
                sent[p] = time.time()
                p.proc.send_signal(PATTERNS[pattern][0])
            time.sleep(0.3)
            for p, (_, pattern) in zip(procs, cases):
                for sig in PATTERNS[pattern][1:]:
                    p.proc.send_signal(sig)
            for p, (name, pattern) in zip(procs, cases):
                rc = p.wait(20)
                log = p.log()
                if rc != 0 or 'Traceback' in log or 'rror' in log:
                    failures.append(f'{name} {pattern} loop {loop}: exit {rc}\n{log[-800:]}')
                if name == 'recorder':
                    m = re.search(r'\[(\d+\.\d+)\] \[recorder\]: closed ', log)
                    if not m or float(m.group(1)) - sent[p] > 1.0:
                        failures.append(f'recorder {pattern} loop {loop}: bag not closed '
                                        f'within 1 s of the signal\n{log[-400:]}')
        finally:
            for p in procs:
                p.end()
    assert not failures, '\n'.join(failures)


def test_a_plain_graph_gives_one_clock_in_the_bag(tmp_path, ros_domain, test_node):
    """ros2 run simulator, controller, recorder: every log time, stamp and the metadata in
    simulation time, the bag as long as the run."""
    from rosbags.rosbag2 import Reader
    procs = [Proc(n, PLAIN[n], tmp_path, ros_domain, cwd=tmp_path)
             for n in ('recorder', 'simulator', 'controller')]
    try:
        _wait_until(lambda: all(p.ready() for p in procs), 120, 'every node to be ready')
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        states, bases = [], []
        test_node.create_subscription(JointState, 'controller/state', states.append, 10)
        test_node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: bases.extend(kv.value for s in m.status if s.name == 'recorder'
                                   for kv in s.values if kv.key == 'time_base'), 10)
        spin_until(test_node, lambda: states, 60, 'the controller to control')
        # The recorder has seen the simulator's /clock (discovery on a loaded machine can
        # miss the first announcements and take a few seconds more).
        spin_until(test_node, lambda: 'sim' in bases, 30, 'the recorder to take /clock')
        # `ros2 node info <node>` (the same graph query) lists each node's busy data
        # subscriptions, served by a loop of its own, and there is no hidden node for them.
        wanted = {'simulator': '/solenoid_current_cmd', 'controller': '/clock',
                  'recorder': '/line_flow'}

        def subscribed():
            return {n: t for n, t in wanted.items() if t in {
                name for name, _ in test_node.get_subscriber_names_and_types_by_node(n, '/')}}
        spin_until(test_node, lambda: subscribed() == wanted, 30, "the nodes' subscriptions")
        assert not [n for n, _ in test_node.get_node_names_and_namespaces()
                    if n.endswith('_io')]
        time.sleep(2.0)  # two seconds of a paced run
        for p in procs:
            p.proc.send_signal(signal.SIGINT)
        assert [p.wait(20) for p in procs] == [0, 0, 0]
    finally:
        for p in procs:
            p.end()
    (bag,) = (tmp_path / 'bags').iterdir()
    assert (bag / f'{bag.name}_0.mcap').is_file()
    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['ros_distro'] == 'jazzy' and info['custom_data']['time_base'] == 'simulation'
    start = info['starting_time']['nanoseconds_since_epoch']
    duration = info['duration']['nanoseconds']
    assert start < 60e9 and 0.5e9 < duration < 60e9  # seconds of a run, not decades
    with Reader(bag) as r:
        topics = {c.topic for c in r.connections}
        assert {'/line_flow', '/joint_states', '/solenoid_current_cmd',
                '/controller/state'} <= topics
        last = {}
        for conn, t, _ in r.messages():
            assert start <= t <= start + duration
            if conn.topic in ('/line_flow', '/pump_flow', '/solenoid_current', '/line_pressure'):
                assert t % 1_000_000 == 0, conn.topic  # on the simulator's 1 ms steps
            last[conn.topic] = t
    # The controller's messages are in the same clock as the simulator's.
    assert abs(last['/controller/state'] - last['/joint_states']) < 1e9


@pytest.mark.parametrize('args, line', [
    (['-p', 'publish_rate:=10000.0'],
     'error: publish_rate = 10000 Hz: faster than 1/dt = 1000 Hz (dt = 0.001 s); use one of '
     '1000, 500, 333.333'),
    (['-p', 'publish_rate:=400.0'],
     'error: publish_rate = 400 Hz: 1/dt = 1000 Hz is not a whole multiple of it; the nearest '
     'rates are 333.333 and 500 Hz'),
    (['-p', 'line.P_u:=120.0'], 'error: line.P_u = 120 Pa: outside the accepted range'),
])
def test_simulator_bad_parameters_exit_2_with_one_line(tmp_path, ros_domain, args, line):
    proc = subprocess.run([executable('simulator'), '--ros-args', *args], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    assert line in proc.stderr, proc.stderr


def _files(tmp_path):
    unknown = tmp_path / 'unknown.yaml'
    text = PUMP_YAML.read_text()
    unknown.write_text(re.sub(r'( +)spool:[^\n]*\n', r'\g<0>\1  mc: 1.0\n', text, count=1))
    binary = tmp_path / 'binary.yaml'
    binary.write_bytes(b'\xff\xfe\x00garbage \x81\x82')
    scenario = tmp_path / 'scenario.yaml'
    scenario.write_text('duration: 2.0\ninputs:\n'
                        '  aperture: {steps: [[0.0, 0.5], [1.0, -3.0]]}\n'
                        '  shaft_speed: -25.0\n')
    return unknown, binary, scenario


@pytest.mark.parametrize('which, line', [
    ('unknown', 'spool.mc: unknown parameter (did you mean spool.m_c?)'),
    ('binary', 'not a text file in UTF-8 (byte 0, line 1)'),
    ('scenario', 'inputs.aperture = -3 at t = 1 s: outside the accepted range [0, 1]'),
])
def test_simulator_bad_files_exit_2_with_one_line(tmp_path, ros_domain, which, line):
    unknown, binary, scenario = _files(tmp_path)
    arg = {'unknown': f'params_file:={unknown}', 'binary': f'params_file:={binary}',
           'scenario': f'scenario_file:={scenario}'}[which]
    proc = subprocess.run([executable('simulator'), '--ros-args', '-p', arg],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if ln.startswith('error: ')]
    assert any(line in ln for ln in errors), proc.stderr


@pytest.mark.parametrize('output, line', [
    ('/proc/hydropump/bag', 'cannot create the bag'),
    ('{file}/bag', 'cannot create the bag'),
])
def test_recorder_unwritable_output_exits_2_with_one_line(tmp_path, ros_domain, output, line):
    a_file = tmp_path / 'a_file'
    a_file.write_text('')
    out = output.format(file=a_file)
    proc = subprocess.run([executable('recorder'), '--ros-args', '-p', f'output:={out}'],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    (err,) = [ln for ln in proc.stderr.splitlines() if ln.startswith('error: ')]
    assert f'output = {out!r}' in err and line in err


@pytest.mark.parametrize('node', ['simulator', 'controller', 'recorder'])
def test_help_prints_the_parameters_and_does_not_start(node):
    proc = subprocess.run([executable(node), '--help'], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0
    assert proc.stdout.startswith(f'usage: ros2 run hydropump_ros {node}')
    assert 'parameters (SI units):' in proc.stdout


@pytest.mark.parametrize('node', ['simulator', 'controller', 'recorder'])
def test_an_argument_that_is_not_a_ros_one_is_refused(node):
    """A mistyped flag or a file given without -p, before --ros-args or after its --, exits
    2 with one line naming it; the node does not start and run without it."""
    for argv in (['--bogus', 'x.yaml', '--ros-args', '-p', 'use_sim_time:=false'],
                 ['--ros-args', '-p', 'use_sim_time:=false', '--', 'extra']):
        proc = subprocess.run([executable(node), *argv], capture_output=True, text=True,
                              timeout=60)
        assert proc.returncode == 2 and 'Traceback' not in proc.stderr
        (err,) = proc.stderr.splitlines()
        bad = ' '.join(argv[:2]) if argv[0] == '--bogus' else 'extra'
        assert err.startswith(f'error: {node}: unexpected argument') and bad in err


def test_a_second_simulator_in_the_namespace_refuses_having_published_nothing(
        tmp_path, nodes, test_node):
    """One simulator per namespace: a second one in the same namespace refuses before its
    first step (the first one's clock never goes back), one in another namespace runs on
    its own clock topic."""
    from rosgraph_msgs.msg import Clock

    from hydropump_ros.simulator_node import DISCOVERY_WINDOW
    nodes.start('simulator')
    clocks, other = [], []
    test_node.create_subscription(Clock, '/clock', clocks.append, 1000)
    test_node.create_subscription(Clock, '/pump2/clock', other.append, 10)
    # The first one is past its own look-out window (two started together both refuse).
    spin_until(test_node, lambda: clocks and clocks[-1].clock.sec > DISCOVERY_WINDOW + 0.5,
               60, 'the first simulator to run for a while')
    import rclpy
    proc = subprocess.Popen([executable('simulator'), '--ros-args', '-r', '__ns:=/'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Its writers come only once it thinks itself alone, after a look longer than one
        # of Fast DDS's 3 s announcement periods: the graph never shows a second writer.
        deadline = time.monotonic() + 60
        writers = 0
        while proc.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(test_node, timeout_sec=0.05)
            writers = max(writers, test_node.count_publishers('/clock'))
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 2
    assert 'another node publishes /clock in this ROS domain (/simulator)' in out + err
    assert writers == 1, f'the refused simulator showed a /clock writer\n{out}{err}'
    spin_until(test_node, lambda: clocks[-1].clock.sec > DISCOVERY_WINDOW + 1.5, 30,
               'more of the first clock')
    t = [c.clock.sec * 10**9 + c.clock.nanosec for c in clocks]
    back = [(a, b) for a, b in zip(t, t[1:]) if b <= a]
    assert not back, f'the clock went back (nothing may come from the refused one): ' \
        f'{back[:5]}\n{out}{err}'
    pump2 = nodes.start('simulator', '-r', '__ns:=/pump2')
    spin_until(test_node, lambda: len(other) > 10, 30, 'the clock of /pump2')
    assert pump2.alive() and 'another node' not in pump2.log()


def test_a_controller_resumes_bumplessly_when_its_simulator_restarts(nodes, test_node):
    """A new simulator (simulation time back to 0) under a running controller: the controller
    says so, restarts from the measurements within one control period of the new time, and
    its command does not swing."""
    from sensor_msgs.msg import JointState
    # A long safe timeout: this is about time going back, not about the watchdog.
    ctrl = nodes.start('controller', '-p', 'autostart:=true', '-p',
                       'watchdog.safe_timeout:=60.0')
    sim = nodes.start('simulator')
    states = []
    test_node.create_subscription(JointState, 'controller/state', states.append, 1000)
    spin_until(test_node, lambda: len(states) > 200, 60, 'a second of control')
    steady = states[-1].position[3]
    sim.stop()
    spin_until(test_node, lambda: test_node.count_publishers('/clock') == 0, 30,
               'the simulator to leave')
    n = len(states)
    nodes.start('simulator')
    spin_until(test_node, lambda: len(states) > n + 100, 60, 'control on the new simulator')
    new = states[n:]
    t = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in new])
    u = np.array([m.position[3] for m in new])
    # The controller holds while no simulator runs: after the old simulator's last updates
    # (some may still be on their way at `n`), every update is on the new simulator's time;
    # the first one comes as soon as the new simulator is discovered (a few tenths of a second
    # here; up to seconds on a loaded machine).
    back = np.flatnonzero(np.diff(t) < 0)
    restart = int(back[0]) + 1 if back.size else 0
    assert t[restart] <= 3.0, (t[:5], ctrl.log()[-2000:])
    # It controls on the new time from then on (a paced run on a loaded machine may skip an
    # instant now and then).
    assert np.count_nonzero((t >= t[restart]) & (t < t[restart] + 0.3)) >= 10
    assert np.max(np.abs(u[restart:] - steady)) < 0.02  # no swing
    assert 'a new simulator' in ctrl.log()


def test_the_nodes_declare_their_schemas_defaults(nodes, test_node):
    """What `ros2 param get` shows on nodes started with no parameters is what the schemas
    (and so the tables of docs/ros.md) say, and the plant is config/pump.yaml."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    from hydropump_ctrl.control.supervisor import ControllerNodeConfig
    from hydropump_ctrl.recorder import RecorderConfig
    from hydropump_sim.params import load_params
    from hydropump_sim.runner import SimulatorConfig
    from hydropump_sim.schema import defaults_of

    from .rosutil import call
    for name in ('simulator', 'controller', 'recorder'):
        nodes.start(name)
    expected = {'simulator': {**defaults_of(SimulatorConfig),
                              **load_params(PUMP_YAML).flat()},
                'controller': defaults_of(ControllerNodeConfig),
                'recorder': defaults_of(RecorderConfig)}
    for node, values in expected.items():
        client = test_node.create_client(GetParameters, f'{node}/get_parameters')
        names = sorted(values)
        got = call(test_node, client, GetParameters.Request(names=names), timeout=60).values
        declared = dict(zip(names, (parameter_value_to_python(v) for v in got)))
        assert declared == {k: values[k] for k in names}, node
