"""The controller lifecycle node with the real simulator over DDS."""

import math

import numpy as np
import pytest

from hydropump_sim import load_params
from hydropump_sim.metrics import step_figures

from ..conftest import PUMP_YAML, ROOT
from .rosutil import call, spin_until, wait_for_publisher, wait_for_subscriber

pytestmark = pytest.mark.ros


def _change_state(test_node, transition_id):
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState
    client = test_node.create_client(ChangeState, 'controller/change_state')
    return call(test_node, client, ChangeState.Request(
        transition=Transition(id=transition_id))).success


def _wait_active(test_node):
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import GetState
    client = test_node.create_client(GetState, 'controller/get_state')
    spin_until(test_node, lambda: call(test_node, client, GetState.Request()).current_state.id
               == State.PRIMARY_STATE_ACTIVE, 30, 'the active controller')


def _unpause(test_node):
    from std_srvs.srv import SetBool
    client = test_node.create_client(SetBool, 'simulator/pause')
    assert call(test_node, client, SetBool.Request(data=False)).success


def test_no_command_before_activation_then_bumpless_start(nodes, test_node):
    from lifecycle_msgs.msg import Transition
    from std_msgs.msg import Float64
    nodes.start('simulator', '-p', 'real_time_factor:=1.0')
    nodes.start('controller', '-p', 'use_sim_time:=true')
    cmds, applied = [], []
    test_node.create_subscription(Float64, 'solenoid_current_cmd', cmds.append, 100)
    test_node.create_subscription(Float64, 'solenoid_current', applied.append, 100)
    wait_for_publisher(test_node, 'solenoid_current')
    spin_until(test_node, lambda: len(applied) > 500, 30, 'half a second of simulation')
    assert cmds == []  # unconfigured: nothing published
    assert _change_state(test_node, Transition.TRANSITION_CONFIGURE)
    spin_until(test_node, lambda: len(applied) > 1000, 30, 'another half second')
    assert cmds == []  # configured but inactive: still nothing
    assert _change_state(test_node, Transition.TRANSITION_ACTIVATE)
    spin_until(test_node, lambda: len(cmds) > 50, 30, 'commands after activation')
    # Bumpless: the first commands continue the applied current (flow reference = nominal).
    assert abs(cmds[0].data - applied[-1].data) < 0.01
    assert all(0.1 <= c.data <= 0.9 for c in cmds)
    assert _change_state(test_node, Transition.TRANSITION_DEACTIVATE)
    # Commands published before the transition may still be on their way (a loaded machine
    # delivers them late): count from 0.1 s of simulation after it.
    n_applied = len(applied)
    spin_until(test_node, lambda: len(applied) > n_applied + 100, 30, '0.1 s more')
    n_cmd, n_applied = len(cmds), len(applied)
    spin_until(test_node, lambda: len(applied) > n_applied + 300, 30, '0.3 s more')
    assert len(cmds) == n_cmd  # inactive again: silent


def test_flow_step_end_to_end_in_lock_step_with_the_bench_profile(nodes, test_node):
    """30 -> 70 % flow step through the real nodes, bench sensors (55 ms flow delay, noise,
    quantisation, dither): the targets of docs/control.md on the true pump flow (from the plate
    stroke, averaged over the dither period as the paper filters it)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    p = load_params(PUMP_YAML)
    q30, q70 = 0.3 * p.Q_max, 0.7 * p.Q_max
    # The step is made at a pause of the simulator (pause_at), as the orchestration makes
    # its changes: published during the run, the reference reached the controller whenever
    # this process got to it, up to 0.3 s of simulation after the instant taken as the step.
    nodes.start('simulator', '--params-file', str(ROOT / 'config' / 'bench.yaml'),
                '-p', 'lock_step:=true', '-p', 'lock_step_timeout:=30.0',
                '-p', 'start_paused:=true', '-p', 'initial_current:=0.38',
                '-p', 'pause_at:=1.0')
    nodes.start('controller', '-p', 'use_sim_time:=true', '-p', 'autostart:=true',
                '-p', f'reference.flow:={q30}')
    js, diag = [], []
    test_node.create_subscription(JointState, 'joint_states', js.append, 5000)
    test_node.create_subscription(DiagnosticArray, '/diagnostics',
                                  lambda m: diag.extend(s for s in m.status
                                                        if s.name == 'controller'), 100)
    ref = test_node.create_publisher(Float64, 'controller/reference', 10)
    wait_for_subscriber(test_node, 'controller/reference')
    wait_for_publisher(test_node, 'joint_states')
    _wait_active(test_node)
    _unpause(test_node)

    def now():
        return js[-1].header.stamp.sec + js[-1].header.stamp.nanosec * 1e-9 if js else 0.0

    spin_until(test_node, lambda: now() >= 1.0, 120, '1 s of settling at 30 %')
    t_step = now()
    ref.publish(Float64(data=q70))

    def taken():
        values = {kv.key: kv.value for kv in diag[-1].values} if diag else {}
        return values.get('reference') not in (None, 'None') and \
            float(values['reference']) == pytest.approx(q70)
    spin_until(test_node, taken, 30, 'the controller to take the reference')
    _unpause(test_node)
    spin_until(test_node, lambda: now() >= t_step + 1.0, 120, 'the step response')
    t = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in js])
    x_a = np.array([m.position[1] for m in js])
    q = p.Q_max * (0.5 + x_a / p.pump.x_a_max)
    k = max(1, int(round(1.0 / (p.input.dither_freq * 1e-3))))
    q = np.convolve(q, np.ones(k) / k, mode='valid')  # one dither period, centred
    t = t[(k - 1) // 2:(k - 1) // 2 + q.size]
    sel = t >= t_step - 0.2
    fig = step_figures(t[sel], q[sel], t_step + 0.006, final=q70, initial=q30)
    assert fig.rise <= 0.15
    assert fig.overshoot <= 5.0
    assert fig.settling <= 0.35
    tail = q[(t > t_step + 0.7) & (t < t_step + 0.99)]
    assert abs(np.mean(tail) - q70) <= 0.005 * p.Q_max


def test_bad_measurements_watchdog_and_live_gains(nodes, test_node):
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool
    nodes.start('simulator', '-p', 'real_time_factor:=1.0', '-p', 'command_timeout:=30.0')
    nodes.start('controller', '-p', 'use_sim_time:=true', '-p', 'autostart:=true',
                '-p', 'watchdog.hold_timeout:=0.2', '-p', 'watchdog.safe_timeout:=0.6')
    cmds, diag = [], []
    test_node.create_subscription(Float64, 'solenoid_current_cmd', cmds.append, 100)
    test_node.create_subscription(DiagnosticArray, '/diagnostics',
                                  lambda m: diag.extend(s for s in m.status
                                                        if s.name == 'controller'), 100)
    spin_until(test_node, lambda: len(cmds) > 20, 30, 'commands')
    bad = test_node.create_publisher(Float64, 'line_flow', 10)
    wait_for_subscriber(test_node, 'line_flow')

    def value(key):
        return {kv.key: kv.value for kv in diag[-1].values}[key] if diag else None

    # The controller keeps only the latest sample, so keep sending the bad ones until they
    # are taken (the simulator's good samples interleave).
    def rejected():
        for v in (math.nan, math.inf, 5.0):
            bad.publish(Float64(data=v))
        return value('rejected_nan') not in (None, '0') and value('rejected_range') not in (
            None, '0')

    spin_until(test_node, rejected, 30, 'the rejections on /diagnostics')
    # Live gains: a bad value is refused with the schema's reason, a good one is taken.
    setp = test_node.create_client(SetParameters, 'controller/set_parameters')

    def set_param(name, v):
        pv = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=v)
        return call(test_node, setp, SetParameters.Request(
            parameters=[Parameter(name=name, value=pv)])).results[0]

    r = set_param('reference.margin', 25.0)  # bar typed for Pa: out of the range
    assert not r.successful and 'reference.margin' in r.reason
    r = set_param('limits.current_min', 0.95)  # in range, but above current_max
    assert not r.successful and 'current_min' in r.reason and 'current_max' in r.reason
    assert set_param('emc.tau_control', 0.012).successful
    # Measurements stop (simulator paused): hold, then the safe current.
    pause = test_node.create_client(SetBool, 'simulator/pause')
    assert call(test_node, pause, SetBool.Request(data=True)).success
    spin_until(test_node, lambda: cmds and cmds[-1].data == pytest.approx(0.3) and
               value('watchdog') == 'safe', 30, 'the safe current')
    assert call(test_node, pause, SetBool.Request(data=False)).success
    spin_until(test_node, lambda: value('watchdog') == 'running', 30, 'the resumed loop')


def test_bad_controller_file_exits_nonzero(tmp_path, ros_domain):
    import subprocess

    from .rosutil import executable
    bad = tmp_path / 'controller.yaml'
    bad.write_text((ROOT / 'config' / 'controller.yaml').read_text().replace(
        'rate_limit: 20.0', 'rate_limit: -1.0'))
    proc = subprocess.run([executable('controller'), '--ros-args', '-p',
                           f'config_file:={bad}'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert 'limits.rate_limit' in proc.stderr
