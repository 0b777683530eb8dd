"""The simulator node over real DDS: topics, stamps, rates, lock-step physics, services,
live parameters and every bad-input case."""

import math
import subprocess

import numpy as np
import pytest

from hydropump_sim import IntegratorConfig, load_params, simulate

from ..conftest import PUMP_YAML
from .rosutil import (
    call,
    executable,
    LockStepDriver,
    spin_until,
    StepCollector,
    wait_for_publisher,
    wait_for_subscriber,
)

pytestmark = pytest.mark.ros

FLOATS = ('pump_flow', 'line_flow', 'load_flow', 'solenoid_current')
PRESSURES = ('actuator_pressure', 'line_pressure', 'load_pressure')


def _diag_values(msg):
    return {s.name: {kv.key: kv.value for kv in s.values} for s in msg.status}


def test_topics_types_stamps_and_rate(nodes, test_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import FluidPressure, JointState
    from std_msgs.msg import Float64
    nodes.start('simulator')
    got = {k: [] for k in FLOATS + PRESSURES + ('joint_states', 'clock', 'diag')}
    for t in FLOATS:
        test_node.create_subscription(Float64, t, got[t].append, 2000)
    for t in PRESSURES:
        test_node.create_subscription(FluidPressure, t, got[t].append, 2000)
    test_node.create_subscription(JointState, 'joint_states', got['joint_states'].append, 2000)
    test_node.create_subscription(Clock, '/clock', got['clock'].append, 2000)
    test_node.create_subscription(DiagnosticArray, '/diagnostics', got['diag'].append, 10)
    wait_for_publisher(test_node, 'joint_states')
    # The first step comes after the simulator's look for another one (DISCOVERY_WINDOW).
    spin_until(test_node, lambda: len(got['joint_states']) > 200, 30, '0.2 s of steps')
    n_diag = len(got['diag'])
    spin_until(test_node, lambda: len(got['diag']) >= n_diag + 2, 20,
               'two diagnostics messages of the run')
    types = dict(test_node.get_topic_names_and_types())
    assert types['/line_flow'] == ['std_msgs/msg/Float64']
    assert types['/solenoid_current'] == ['std_msgs/msg/Float64']
    assert types['/line_pressure'] == ['sensor_msgs/msg/FluidPressure']
    assert types['/joint_states'] == ['sensor_msgs/msg/JointState']
    assert types['/clock'] == ['rosgraph_msgs/msg/Clock']
    assert test_node.count_subscribers('solenoid_current_cmd') == 1
    # Every step carries one stamp on every stamped topic, 1 ms apart (1 kHz in sim time).
    js = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
                   for m in got['joint_states']])
    assert np.allclose(np.diff(js), 1e-3, atol=1e-9)
    stamps = {t: {(m.header.stamp.sec, m.header.stamp.nanosec) for m in got[t]}
              for t in PRESSURES}
    common = set.intersection(*stamps.values())
    assert len(common) > 0.9 * min(len(s) for s in stamps.values())
    # Absolute pressures at the nominal point; names and SI values of the joint states.
    p = load_params(PUMP_YAML)
    assert got['line_pressure'][-1].fluid_pressure == pytest.approx(
        150.017e5 + p.fluid.p_atm, rel=1e-4)
    assert got['load_pressure'][-1].fluid_pressure == pytest.approx(p.line.P_u + p.fluid.p_atm)
    assert list(got['joint_states'][-1].name) == ['spool', 'swash_plate_actuator']
    assert got['line_flow'][-1].data == pytest.approx(p.Q_max / 2, rel=1e-9)
    assert got['solenoid_current'][-1].data == pytest.approx(0.5)
    # Paced at real time (factor 1), unlike the free run; reported on /diagnostics.
    d = _diag_values(got['diag'][-1])
    assert 0.5 < float(d['simulator: integrator']['achieved_real_time_factor']) < 1.5
    for key in ('spool_at_stop', 'plate_at_stop', 'relief_open', 'pressure_floor_active'):
        assert d['simulator: plant'][key] == 'False'
    for key in ('command_age_s', 'nan_commands', 'clamped_commands', 'watchdog_active'):
        assert key in d['simulator: command']


def _lock_step(nodes, *extra):
    return nodes.start('simulator', '-p', 'lock_step:=true', '-p', 'lock_step_timeout:=30.0',
                       *extra)


def test_current_step_follows_the_plant_library(nodes, test_node):
    """Lock-step: the flow the node publishes is the plant library's for the same inputs."""
    p = load_params(PUMP_YAML)
    I0, I1 = 0.46, 0.54
    schedule = lambda t: I0 if t < 0.05 else I1  # noqa: E731
    _lock_step(nodes, '-p', f'initial_current:={I0}')
    col = StepCollector(test_node, ['line_flow', 'solenoid_current'])
    driver = LockStepDriver(test_node, schedule)
    wait_for_subscriber(test_node, 'solenoid_current_cmd')
    wait_for_publisher(test_node, 'line_flow')
    driver.kick()
    spin_until(test_node, lambda: driver.t >= 0.4, 60, 'simulation time 0.4 s')
    t, q = col.series('line_flow')
    # Offline, stepped as the node steps it (a step ending at every increment).
    ref = simulate(p, 0.4, lambda tt: np.where(tt < 0.05, I0, I1), config=IntegratorConfig())
    k = np.searchsorted(ref.t, t[(t > 0.0) & (t <= 0.4)] - 1e-9)
    assert len(k) > 300
    q = q[(t > 0.0) & (t <= 0.4)]
    assert np.max(np.abs(q - ref.q_l[k])) < 1e-6 * p.Q_max
    assert q[-1] > q[0] + 0.1 * p.Q_max  # the step really moved the flow
    ti, i_meas = col.series('solenoid_current')
    assert set(np.round(i_meas, 9)) == {I0, I1}
    assert ti[np.flatnonzero(np.isclose(i_meas, I1))[0]] == pytest.approx(0.05)


def test_pause_reset_and_live_parameters(nodes, test_node):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import FluidPressure
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool, Trigger
    nodes.start('simulator', '-p', 'real_time_factor:=0.0')
    clock, line, flow = [], [], []
    test_node.create_subscription(Clock, '/clock', clock.append, 10)
    test_node.create_subscription(FluidPressure, 'line_pressure', line.append, 10)
    test_node.create_subscription(Float64, 'line_flow', flow.append, 10)
    pause = test_node.create_client(SetBool, 'simulator/pause')
    reset = test_node.create_client(Trigger, 'simulator/reset')
    setp = test_node.create_client(SetParameters, 'simulator/set_parameters')
    wait_for_publisher(test_node, '/clock')
    spin_until(test_node, lambda: clock, 20, '/clock')

    def now():
        return clock[-1].clock.sec + clock[-1].clock.nanosec * 1e-9

    assert call(test_node, pause, SetBool.Request(data=True)).success
    _spin_for(test_node, 0.3)  # drain what was in flight
    t_paused = now()
    _spin_for(test_node, 0.5)
    assert now() == t_paused  # paused: simulation time stands still
    assert call(test_node, pause, SetBool.Request(data=False)).success
    spin_until(test_node, lambda: now() > t_paused + 0.5, 20, 'time to advance again')

    def set_param(name, value):
        v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=value)
        return call(test_node, setp, SetParameters.Request(
            parameters=[Parameter(name=name, value=v)])).results[0]

    bad = set_param('line.xi_u', 2.0)
    assert not bad.successful and bad.reason.startswith('line.xi_u = 2: outside the '
                                                        'accepted range [0, 1]')
    # The reason that ros2 param set prints carries the unit hint.
    bar = set_param('line.P_u', 120.0)
    assert not bar.successful and 'looks like a value in bar: 120 bar = 1.2e+07 Pa' in \
        bar.reason
    ro = set_param('spool.m_c', 0.005)
    assert not ro.successful and 'read-only' in ro.reason  # plant parameters are read-only
    p_before = line[-1].fluid_pressure
    assert set_param('line.xi_u', 0.25).successful
    t_set = now()
    spin_until(test_node, lambda: now() > t_set + 0.3, 20, 'the live change to act')
    assert line[-1].fluid_pressure > p_before + 20e5  # a smaller aperture raises P_l
    res = call(test_node, reset, Trigger.Request())
    assert res.success
    t_reset = now()
    spin_until(test_node, lambda: now() > t_reset + 0.05, 20, 'steps after the reset')
    assert now() > t_reset  # time keeps running across a reset
    # Reset restores the initial equilibrium state; the live aperture stays as set.
    params = load_params(PUMP_YAML)
    assert flow[-1].data == pytest.approx(params.Q_max / 2, rel=1e-3)


def _spin_for(node, seconds):
    import time

    import rclpy
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.01)


def test_bad_commands_and_watchdog(nodes, test_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64
    nodes.start('simulator', '-p', 'command_timeout:=0.5', '-p', 'diagnostics_period:=0.2')
    applied, diag = [], []
    test_node.create_subscription(Float64, 'solenoid_current', applied.append, 100)
    test_node.create_subscription(DiagnosticArray, '/diagnostics', diag.append, 10)
    pub = test_node.create_publisher(Float64, 'solenoid_current_cmd', 10)
    wait_for_subscriber(test_node, 'solenoid_current_cmd')
    wait_for_publisher(test_node, 'solenoid_current')

    def settle(value, what):
        spin_until(test_node, lambda: applied and abs(applied[-1].data - value) < 1e-9, 20, what)

    # Until the simulator has matched this publisher, a command may be lost: repeat it, as a
    # controller does every period.
    spin_until(test_node, lambda: pub.publish(Float64(data=0.55)) or (
        applied and abs(applied[-1].data - 0.55) < 1e-9), 20, 'the commanded current')
    pub.publish(Float64(data=math.nan))
    pub.publish(Float64(data=math.inf))
    pub.publish(Float64(data=2.0))
    settle(0.9, 'the clamped current')  # eq. 2: I_min + 2 I_max
    n = len(diag)
    spin_until(test_node, lambda: len(diag) > n + 1, 20, 'diagnostics')
    cmd = _diag_values(diag[-1])['simulator: command']
    assert cmd['nan_commands'] == '2' and cmd['clamped_commands'] == '1'
    # The current the plant holds, not the command's 2 A (the safe current once the watchdog
    # holds, which a loaded machine may reach by now).
    for msg in diag[n:]:
        c = _diag_values(msg)['simulator: command']
        held = 0.3 if c['watchdog_active'] == 'True' else 0.9
        assert float(c['applied_current_A']) == pytest.approx(held), c
        assert float(c['commanded_current_A']) == pytest.approx(2.0), c
    # No command for command_timeout (steady clock): the safe current, 0 % displacement.
    settle(0.3, 'the safe current after the watchdog')
    n = len(diag)
    spin_until(test_node, lambda: len(diag) > n + 1, 20, 'diagnostics')
    cmd = _diag_values(diag[-1])['simulator: command']
    assert cmd['watchdog_active'] == 'True' and cmd['watchdog_trips'] == '1'
    assert float(cmd['applied_current_A']) == pytest.approx(0.3)
    pub.publish(Float64(data=0.5))
    settle(0.5, 'commands back after the watchdog')


def test_bad_params_file_exits_nonzero_with_the_library_message(tmp_path, ros_domain):
    bad = tmp_path / 'pump.yaml'
    bad.write_text(PUMP_YAML.read_text().replace('phi_s: 160.0', 'phi_s: 150.0').replace(
        'beta: 1.5e+9', 'beta: 15.0'))
    proc = subprocess.run([executable('simulator'), '--ros-args', '--params-file', str(bad),
                           '-p', 'spool.mc:=1.0'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    assert 'error: fluid.beta = 15 Pa: outside the accepted range' in proc.stderr
    assert 'spool.mc: unknown parameter of node simulator (did you mean spool.m_c?)' \
        in proc.stderr
    proc = subprocess.run([executable('simulator'), '--ros-args', '--params-file', str(
        tmp_path / 'none.yaml')], capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and 'Traceback' not in proc.stderr


def test_a_fixed_step_bounds_the_work_of_every_increment(nodes, test_node):
    """``solver.fixed_step:=0.0005``: every 1 ms increment at least two Rodas4 steps and at
    most ``solver.max_steps`` (16) tried, the bound stated on /diagnostics; the plant still
    follows the library's error-controlled run (the flow of a current step to the spool's
    stop, eq. 11)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64
    nodes.start('simulator', '-p', 'solver.fixed_step:=0.0005', '-p',
                'diagnostics_period:=0.2', '-p', 'real_time_factor:=0.0', '-p',
                'pause_at:=2.0')
    diag, flow = [], []
    test_node.create_subscription(DiagnosticArray, '/diagnostics', diag.append, 10)
    test_node.create_subscription(Float64, 'pump_flow', flow.append, 100)
    pub = test_node.create_publisher(Float64, 'solenoid_current_cmd', 10)
    wait_for_subscriber(test_node, 'solenoid_current_cmd')

    def integrator():
        return _diag_values(diag[-1])['simulator: integrator'] if diag else {}
    # Paused at 2 s (pause_at): the counts are those of 2000 increments.
    spin_until(test_node, lambda: pub.publish(Float64(data=0.6)) or
               integrator().get('sim_time_s') == '2.000000', 60, '2 s of simulation')
    d = integrator()
    assert d['fixed_step_s'] == '0.0005' and d['max_steps_per_increment'] == '16'
    tried = int(d['accepted_steps']) + int(d['rejected_steps'])
    assert int(d['accepted_steps']) >= 4000 and tried <= 16 * 2000
    assert int(d['model_evaluations_max']) > 16 * 7
    p = load_params(PUMP_YAML)
    ref = simulate(p, 2.0, current=0.6)
    assert flow[-1].data == pytest.approx(ref['pump.Q_p'][-1], rel=1e-3)


def test_a_fixed_step_that_does_not_divide_dt_is_one_error_line(ros_domain):
    proc = subprocess.run([executable('simulator'), '--ros-args', '-p',
                           'solver.fixed_step:=0.0003'], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert lines == ['error: solver.fixed_step = 0.0003 s: not a whole fraction of dt = '
                     '0.001 s (e.g. 0.000333333 or 0.00025 s)'], proc.stderr
