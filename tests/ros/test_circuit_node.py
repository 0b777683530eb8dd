"""The simulator node running the circuit of Fig. 1, as a user starts it (the installed
executable with ``circuit_file``): its load topics and commands, its operator inputs as live
parameters, ``circuit_sets`` live from the next reset, and a bad circuit file.

The truth is the pre-compensated section's closed form: its compensator holds ``dp_set``
across the directional valve, within its regulation range (1 bar) and hysteresis (0.3 bar),
so the boom takes ``C_d A_max a(xi) sqrt(2 dp_set / rho)`` whatever its load and the pump's
pressure, as long as the pump keeps the margin (here the hydromechanical load-sensing pump
does); ``a(xi) = (xi - 0.1) / 0.9`` is the 4/3 valve's opening past its 10 % overlap."""

import math
import subprocess
import time

import numpy as np
import pytest

from ..conftest import ROOT
from .rosutil import call, executable, spin_until, wait_for_publisher, wait_for_subscriber

pytestmark = pytest.mark.ros

FIG1 = ROOT / 'config' / 'circuits' / 'fig1.yaml'
# The boom section of config/circuits/fig1.yaml and the oil of config/pump.yaml, read here
# as a user reads them: the figures the closed form needs.
C_D, RHO = 0.65, 870.0
BOOM_A_MAX, BOOM_DP_SET, OVERLAP = 2.2e-5, 1.0e6, 0.1
# The compensator's drop is dp_set within half its regulation range and hysteresis, less
# its flow-force droop (0.5 + 0.15 bar, and 1e8 Pa s/m^3 at 0.4 L/s: 1.05 bar of 10): the
# flow within 5 %.
REGULATION = math.sqrt(1.0 + (0.65e5 + 1.0e8 * 4.0e-4) / BOOM_DP_SET) - 1.0
LS_PUMP = 'pump.type=ls_pump pump.ls.margin=2500000.0'


def boom_flow(xi: float) -> float:
    opening = min(max((xi - OVERLAP) / (1.0 - OVERLAP), 0.0), 1.0)
    return C_D * BOOM_A_MAX * opening * math.sqrt(2 * BOOM_DP_SET / RHO)


def _param(name, value):
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    if isinstance(value, str):
        v = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=value)
    else:
        v = ParameterValue(type=ParameterType.PARAMETER_DOUBLE, double_value=float(value))
    return Parameter(name=name, value=v)


class Flow:
    """A load's flow topic (``loads/<load>/flow``), sample by sample."""

    def __init__(self, node, load='boom'):
        from std_msgs.msg import Float64
        self.load = load
        self.samples = []
        node.create_subscription(Float64, f'loads/{load}/flow',
                                 lambda m: self.samples.append(m.data), 100)

    def settled(self, node, target=None, timeout=60.0, window=40, each=lambda: None):
        """The median of the last ``window`` samples once they agree to 1 % (and lie within
        10 % of ``target``, if given); ``each`` is called at every spin (to keep publishing
        a command: one message may go out before the node has matched the publisher)."""
        def done():
            each()
            v = np.array(self.samples[-window:])
            if len(v) < window or np.median(v) <= 0.0:
                return False
            near = target is None or abs(np.median(v) - target) < 0.1 * target
            return near and np.ptp(v) < 0.01 * np.median(v)
        spin_until(node, done, timeout, f'the {self.load} flow to settle' + (
            f' near {target:.3g} m^3/s' if target else ''))
        return float(np.median(self.samples[-window:]))


def test_fig1_boom_flow_from_its_command_topic_and_its_live_input(nodes, test_node):
    from rcl_interfaces.srv import GetParameters, SetParameters
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    nodes.start('simulator', '-p', f'circuit_file:={FIG1}', '-p', f'circuit_sets:={LS_PUMP}')
    flow = Flow(test_node)
    joints = []
    test_node.create_subscription(JointState, 'joint_states', joints.append, 10)
    cmd = test_node.create_publisher(Float64, 'loads/boom/command', 10)
    setp = test_node.create_client(SetParameters, 'simulator/set_parameters')
    wait_for_subscriber(test_node, 'loads/boom/command')
    wait_for_publisher(test_node, 'loads/boom/flow')

    # The command topic: 0.6 open.
    open_boom = Every(0.05, lambda: cmd.publish(Float64(data=0.6)))
    spin_until(test_node, lambda: open_boom() or
               (joints and _opening(joints[-1], 'boom.valve') > 0.59), 60,
               'the boom valve to open to 0.6')
    q = flow.settled(test_node, boom_flow(0.6), each=open_boom)
    assert q == pytest.approx(boom_flow(0.6), rel=REGULATION)
    # What the topic set, the parameter reads (ros2 param get agrees with ros2 topic pub).
    getp = test_node.create_client(GetParameters, 'simulator/get_parameters')

    def reads():
        res = call(test_node, getp, GetParameters.Request(names=['inputs.boom.command']))
        return res.values[0].double_value
    spin_until(test_node, lambda: open_boom() or reads() == pytest.approx(0.6), 10,
               'inputs.boom.command to read what the topic set')

    # The live operator input: the same input, now 0.3 as a parameter, halves it. The
    # publisher leaves first, so that no command in flight overrides the parameter.
    test_node.destroy_publisher(cmd)
    spin_until(test_node, lambda: test_node.count_publishers('loads/boom/command') == 0, 20,
               'the command publisher to leave')
    _spin_for(test_node, 0.5)
    res = call(test_node, setp, SetParameters.Request(
        parameters=[_param('inputs.boom.command', 0.3)])).results[0]
    assert res.successful, res.reason
    spin_until(test_node, lambda: _opening(joints[-1], 'boom.valve') < 0.31, 30,
               'the boom valve to close to 0.3')
    flow.samples.clear()
    q_half = flow.settled(test_node, boom_flow(0.3))
    assert q_half == pytest.approx(boom_flow(0.3), rel=REGULATION)
    assert q_half / q == pytest.approx(boom_flow(0.3) / boom_flow(0.6), rel=2 * REGULATION)

    # joint_states names every valve spool and actuator of the circuit.
    names = set(joints[-1].name)
    assert {'steering.valve', 'boom.valve', 'boom.cylinder', 'motor.valve',
            'motor.motor'} <= names

    # A bad value of an operator input is refused with its range.
    bad = call(test_node, setp, SetParameters.Request(
        parameters=[_param('inputs.boom.command', 1.5)])).results[0]
    assert not bad.successful and 'inputs.boom.command' in bad.reason


class Every:
    """Calls ``fn`` at most once every ``period`` s of wall time (returns None)."""

    def __init__(self, period, fn):
        self.period, self.fn, self.last = period, fn, -math.inf

    def __call__(self):
        now = time.monotonic()
        if now - self.last >= self.period:
            self.last = now
            self.fn()


def _spin_for(node, seconds):
    import rclpy
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.01)


def _opening(msg, joint):
    return msg.position[list(msg.name).index(joint)]


def test_fig1_circuit_sets_live_from_the_next_reset(nodes, test_node):
    """Switched live to post-compensated sections (flow sharing): every metering edge then
    sees the same drop, so the boom and the motor take flows in the ratio of their valves'
    areas (2.2 : 1.8 at equal commands), whatever that drop. A change of the topics (a
    cylinder made a motor) is refused, with why."""
    from rcl_interfaces.srv import SetParameters
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    nodes.start('simulator', '-p', f'circuit_file:={FIG1}', '-p', f'circuit_sets:={LS_PUMP}')
    boom, motor = Flow(test_node, 'boom'), Flow(test_node, 'motor')
    cmds = [test_node.create_publisher(Float64, f'loads/{n}/command', 10)
            for n in ('boom', 'motor')]
    setp = test_node.create_client(SetParameters, 'simulator/set_parameters')
    reset = test_node.create_client(Trigger, 'simulator/reset')
    wait_for_subscriber(test_node, 'loads/motor/command')
    wait_for_publisher(test_node, 'loads/motor/flow')

    def set_sets(text):
        return call(test_node, setp, SetParameters.Request(
            parameters=[_param('circuit_sets', text)]), timeout=120).results[0]

    refused = set_sets(LS_PUMP + ' boom.actuator=motor')
    assert not refused.successful and 'boom' in refused.reason and 'motor' in refused.reason
    unknown = set_sets(LS_PUMP + ' boom.compensatr=post')
    assert not unknown.successful and 'did you mean compensator' in unknown.reason

    post = set_sets(LS_PUMP + ' boom.compensator=post motor.compensator=post')
    assert post.successful, post.reason
    assert call(test_node, reset, Trigger.Request()).success

    def publish_all():
        for c in cmds:
            c.publish(Float64(data=0.4))
    publish = Every(0.05, publish_all)
    # 0.4 each: with the steering's 6 L/min well inside the pump's 67.5 L/min.
    motor.samples.clear()
    spin_until(test_node, lambda: publish() or (motor.samples and motor.samples[-1] > 1e-4),
               60, 'the motor to take flow')
    q_motor = motor.settled(test_node, each=publish)
    q_boom = boom.settled(test_node, each=publish)
    assert q_boom / q_motor == pytest.approx(2.2 / 1.8, rel=0.02)
    # Not the pre-compensated flow: the drop is now the pump's margin less dp_set.
    assert q_boom > 1.05 * boom_flow(0.4)


def test_a_bad_circuit_file_exits_with_one_line_naming_the_component(tmp_path, ros_domain):
    text = FIG1.read_text().replace('plant: ../pump.yaml', f'plant: {ROOT / "config"}/pump.yaml')
    boom_ports = 'ports: {supply: demand, tank: tank, load: boom_load, sense: boom_ls, ls: ls}'
    assert boom_ports in text
    bad = tmp_path / 'fig1.yaml'
    bad.write_text(text.replace(boom_ports, boom_ports.replace(' tank: tank,', '')))
    proc = subprocess.run([executable('simulator'), '--ros-args', '-p',
                           f'circuit_file:={bad}'], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and 'boom: port tank is not connected' in lines[0], proc.stderr


def test_fig1_at_the_simplified_fidelity_and_a_change_taken_at_the_reset(nodes, test_node):
    """``fidelity:=simplified``: /diagnostics names it, what it made static and its error
    bound; the boom still takes its compensated flow (the closed form, within 5 %). A
    bandwidth that would drop a mode the controller acts on is refused, naming it; a change
    to ``fine`` is taken, shown as the next fidelity, and runs from the next ~/reset."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.srv import SetParameters
    from std_msgs.msg import Float64
    from std_srvs.srv import Trigger
    nodes.start('simulator', '-p', f'circuit_file:={FIG1}', '-p', f'circuit_sets:={LS_PUMP}',
                '-p', 'fidelity:=simplified', '-p', 'diagnostics_period:=0.2')
    model = []
    test_node.create_subscription(DiagnosticArray, '/diagnostics', lambda m: model.extend(
        {v.key: v.value for v in s.values} for s in m.status if s.name == 'simulator: model'),
        10)
    boom = Flow(test_node, 'boom')
    cmd = test_node.create_publisher(Float64, 'loads/boom/command', 10)
    setp = test_node.create_client(SetParameters, 'simulator/set_parameters')
    reset = test_node.create_client(Trigger, 'simulator/reset')
    wait_for_subscriber(test_node, 'loads/boom/command')
    spin_until(test_node, lambda: model, 60, 'the model diagnostics')
    first = model[-1]
    assert first['fidelity'] == 'simplified' and 'boom.comp' in first['made_static'].split()
    assert 0.0 < float(first['error_bound']) < 1.0
    publish = Every(0.05, lambda: cmd.publish(Float64(data=0.5)))
    q = boom.settled(test_node, boom_flow(0.5), each=publish)
    assert q == pytest.approx(boom_flow(0.5), rel=0.05 + REGULATION)

    def set_(name, value):
        return call(test_node, setp, SetParameters.Request(
            parameters=[_param(name, value)]), timeout=120).results[0]
    low = set_('fidelity_bandwidth', 1.0)
    assert not low.successful and 'the controller acts on' in low.reason, low.reason
    fine = set_('fidelity', 'fine')
    assert fine.successful, fine.reason
    model.clear()
    spin_until(test_node, lambda: model, 30, 'the model diagnostics')
    # Until the reset the simplified model runs on.
    assert model[-1]['fidelity'] == 'simplified' and model[-1]['next_fidelity'] == 'fine'
    assert call(test_node, reset, Trigger.Request()).success
    model.clear()
    spin_until(test_node, lambda: model and model[-1]['fidelity'] == 'fine', 30,
               'the fine model after the reset')
    assert model[-1]['made_static'] == '' and float(model[-1]['error_bound']) == 0.0
