"""The foxglove node over real DDS and a real WebSocket client: the simulator's messages reach
a Foxglove client as JSON with the values DDS carries and their simulation time; the node ends
cleanly on Ctrl-C and SIGTERM and refuses bad parameters in one line. Also the pure
conversion of ROS messages to JSON and their schemas."""

import json
import math
from pathlib import Path
import signal
import socket
import struct
import subprocess
import time

import pytest

from .rosutil import executable, spin_until, wait_for_publisher

pytestmark = pytest.mark.ros

# The SDK's server speaks the Foxglove WebSocket protocol under the subprotocol name
# foxglove.sdk.v1; a client offers both names, as current Foxglove apps do.
SUBPROTOCOLS = ['foxglove.websocket.v1', 'foxglove.sdk.v1']
OP_MESSAGE_DATA = 1
OP_TIME = 2


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def connect(port: int, timeout: float = 30.0, subprotocols=None):
    """A WebSocket client on the node's server, once the node serves (it starts in about a
    second; a loaded machine takes longer)."""
    from websockets.sync.client import connect as ws_connect
    deadline = time.monotonic() + timeout
    while True:
        try:
            return ws_connect(f'ws://127.0.0.1:{port}', open_timeout=5,
                              subprotocols=subprotocols or SUBPROTOCOLS)
        except (ConnectionRefusedError, TimeoutError):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


def advertised(ws, topic: str, timeout: float = 30.0) -> dict:
    """The channel the server advertises for ``topic``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        frame = ws.recv(timeout=max(deadline - time.monotonic(), 0.01))
        if isinstance(frame, str):
            op = json.loads(frame)
            if op['op'] == 'advertise':
                for ch in op['channels']:
                    if ch['topic'] == topic:
                        return ch
    raise AssertionError(f'no channel advertised for {topic} within {timeout:g} s')


def message_frames(ws, count: int, times: list | None = None, timeout: float = 30.0) -> list:
    """``count`` message-data frames: ``(subscription id, timestamp [ns], decoded JSON)``;
    the server's time frames go to ``times``."""
    out = []
    deadline = time.monotonic() + timeout
    while len(out) < count:
        assert time.monotonic() < deadline, f'{len(out)} of {count} messages in {timeout:g} s'
        frame = ws.recv(timeout=max(deadline - time.monotonic(), 0.01))
        if isinstance(frame, bytes):
            if frame[0] == OP_TIME:  # opcode (u8), time (u64 LE)
                if times is not None:
                    times.append(struct.unpack_from('<Q', frame, 1)[0])
                continue
            # Message data: opcode (u8), subscription id (u32 LE), receive timestamp (u64
            # LE), payload.
            op, sid, ts = struct.unpack_from('<BIQ', frame)
            assert op == OP_MESSAGE_DATA
            out.append((sid, ts, json.loads(frame[13:])))
    return out


def test_line_pressure_reaches_a_foxglove_client_as_dds_carries_it(nodes, test_node):
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import FluidPressure
    port = free_port()
    nodes.start('simulator')
    fox = nodes.start('foxglove', '-p', f'port:={port}')
    dds = {}
    test_node.create_subscription(
        FluidPressure, 'line_pressure',
        lambda m: dds.__setitem__(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec,
                                  m.fluid_pressure),
        # Two seconds of messages, the latest kept: the test reads the WebSocket without
        # spinning (a depth past Fast DDS's default sample limit would refuse new ones).
        QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT,
                   history=HistoryPolicy.KEEP_LAST))
    wait_for_publisher(test_node, 'line_pressure', timeout=60)
    # Data flows to the test node from here on (the graph shows a publisher before its
    # writer has matched this reader): the frames compared are later than this.
    spin_until(test_node, lambda: dds, 30, 'line_pressure on DDS')
    with connect(port) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        ch = advertised(ws, '/line_pressure')
        assert ch['encoding'] == 'json' and ch['schemaEncoding'] == 'jsonschema'
        assert ch['schemaName'] == 'sensor_msgs/msg/FluidPressure'
        schema = json.loads(ch['schema'])
        assert schema['properties']['fluid_pressure']['type'] == ['number', 'null']
        ws.send(json.dumps({'op': 'subscribe',
                            'subscriptions': [{'id': 42, 'channelId': ch['id']}]}))
        frames, times = [], []
        # After the first second of simulation (the start-up transient is over) and after
        # DDS delivered to the test node.
        t0 = max(max(dds), 10**9)
        while len(frames) < 300:
            frames += [f for f in message_frames(ws, 50, times) if f[1] > t0]
    assert {sid for sid, _, _ in frames} == {42}
    for _, ts, msg in frames:
        stamp = msg['header']['stamp']
        # The time of a message is its header stamp: simulation time, not wall time.
        assert ts == stamp['sec'] * 10**9 + stamp['nanosec']
    stamps = [ts for _, ts, _ in frames]
    assert stamps == sorted(stamps) and stamps[-1] < 10**12  # seconds of simulation time
    # The server announces /clock as its time (Foxglove's "now" in a live view).
    assert times and times == sorted(times) and times[-1] < 10**12, times[-5:]
    # The same messages over DDS. Best effort on both sides, and the test node, spinning
    # one message at a time, may lag the 1 kHz stream on a loaded machine (its queue keeps
    # the latest): some are missing, a few dozen of the 300 suffice.
    wanted = set(stamps)
    spin_until(test_node, lambda: len(wanted & dds.keys()) >= 20, 30,
               f'the WebSocket messages {stamps[0]}..{stamps[-1]} ns on DDS')
    pairs = [(msg['fluid_pressure'], dds[ts]) for _, ts, msg in frames if ts in dds]
    values = [b for _, b in pairs]
    assert all(1.0e5 < v < 1.0e8 for v in values), values[:5]  # Pa absolute
    spread = max(values) - min(values)
    for a, b in pairs:
        # At steady state within 1 % of each other; the same message, so equal in fact.
        assert abs(a - b) <= 0.01 * abs(b) and a == pytest.approx(b, rel=1e-12, abs=0)
    assert spread <= 0.01 * max(values), 'line pressure not at steady state'
    assert fox.alive()
    assert 'Traceback' not in fox.log()


@pytest.mark.parametrize('names', [['foxglove.websocket.v1'], ['foxglove.sdk.v1']],
                         ids=['old_name', 'new_name'])
def test_a_client_that_offers_either_subprotocol_name_alone_is_served(nodes, names):
    """The SDK's server knows the protocol as foxglove.sdk.v1 only; the node's relay serves
    a client that offers only the older name foxglove.websocket.v1 (Lichtblick, older
    Foxglove Studio) as well: the handshake names what the client offered, and the protocol
    runs (the server's info, then a channel and its messages)."""
    port = free_port()
    nodes.start('foxglove', '-p', f'port:={port}', '-p', 'topics:=[clock]')
    nodes.start('simulator')
    with connect(port, subprotocols=names) as ws:
        assert ws.subprotocol == names[0]
        info = json.loads(ws.recv(timeout=30))
        assert info['op'] == 'serverInfo' and info['name'] == 'hydropump /'
        ch = advertised(ws, '/clock')
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [{'id': 1,
                                                                  'channelId': ch['id']}]}))
        ((sid, _, clock),) = message_frames(ws, 1)
        assert sid == 1 and clock['clock']['sec'] >= 0


@pytest.mark.parametrize('signals', [(signal.SIGINT, signal.SIGINT), (signal.SIGTERM,)],
                         ids=['ctrl_c_twice', 'sigterm'])
def test_ends_cleanly_on_ctrl_c_and_sigterm_with_a_client_connected(nodes, signals):
    port = free_port()
    fox = nodes.start('foxglove', '-p', f'port:={port}')
    with connect(port) as ws:
        ch = advertised(ws, '/clock')
        ws.send(json.dumps({'op': 'subscribe',
                            'subscriptions': [{'id': 1, 'channelId': ch['id']}]}))
        time.sleep(0.2)  # the subscription is in (nothing to wait on: no /clock publisher)
        for sig in signals:
            fox.proc.send_signal(sig)
            time.sleep(0.1)
        rc = fox.proc.wait(timeout=15)
    log = fox.log()
    assert rc == 0, log
    assert 'Traceback' not in log and 'terminate called' not in log, log


@pytest.mark.parametrize('args, line', [
    (['-p', 'port:=70000'], 'error: port = 70000: outside the accepted range [0, 65535]'),
    (['-p', "host:=''"], "error: host = '': give an address"),
    (['-p', 'discovery_period:=0.0'], 'error: discovery_period = 0'),
    (['-p', 'prot:=9000'], 'error: '),
])
def test_a_bad_parameter_exits_2_with_one_error_line(ros_domain, args, line):
    proc = subprocess.run([executable('foxglove'), '--ros-args', *args], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), proc.stderr
    assert 'Traceback' not in proc.stderr + proc.stdout


def test_a_port_in_use_exits_2_with_one_error_line(ros_domain):
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        s.listen()
        port = s.getsockname()[1]
        proc = subprocess.run([executable('foxglove'), '--ros-args', '-p', f'port:={port}'],
                              capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'error: port = {port}: cannot serve on'), \
        proc.stderr


# ---- the pure conversion (hydropump_ctrl.foxglove) -----------------------------------------

def _fields_of(msgtype):
    import importlib
    parts = msgtype.split('/')
    return getattr(importlib.import_module(f'{parts[0]}.msg'),
                   parts[-1]).get_fields_and_field_types()


def test_messages_become_plain_json_that_their_schema_describes():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from sensor_msgs.msg import JointState

    from hydropump_ctrl.foxglove import converter, is_stamped, json_schema
    js = JointState(name=['spool', 'swash_plate_actuator'], position=[1e-3, math.nan],
                    velocity=[0.0, math.inf])
    js.header.stamp.sec, js.header.stamp.nanosec = 3, 250_000_000
    out = converter('sensor_msgs/msg/JointState', _fields_of)(js)
    # JSON has no NaN or infinity: they become null, and the text parses in a browser.
    assert out['position'] == [1e-3, None] and out['velocity'] == [0.0, None]
    assert out['header'] == {'stamp': {'sec': 3, 'nanosec': 250_000_000}, 'frame_id': ''}
    json.dumps(out, allow_nan=False)
    diag = DiagnosticArray(status=[DiagnosticStatus(level=DiagnosticStatus.WARN, name='sim',
                                                    values=[KeyValue(key='k', value='v')])])
    d = converter('diagnostic_msgs/msg/DiagnosticArray', _fields_of)(diag)
    assert d['status'][0]['level'] == 1  # a ROS byte, as the number Foxglove's panel reads
    assert d['status'][0]['values'] == [{'key': 'k', 'value': 'v'}]
    schema = json_schema('diagnostic_msgs/msg/DiagnosticArray', _fields_of)
    assert schema['title'] == 'diagnostic_msgs/msg/DiagnosticArray'
    status = schema['properties']['status']
    assert status['type'] == 'array'
    assert status['items']['properties']['level'] == {'type': 'integer'}
    assert is_stamped(_fields_of('sensor_msgs/msg/FluidPressure'))
    assert not is_stamped(_fields_of('std_msgs/msg/Float64'))


def test_time_is_the_header_stamp_else_the_latest_clock_and_the_rate_limit():
    from hydropump_ctrl.foxglove import discoverable, RateLimit, TimeKeeper
    tk = TimeKeeper(broadcast_period=0.05)
    assert tk.log_time(None) is None           # no /clock yet: the server's wall time
    assert tk.clock(1_000_000, now=10.0)       # the first /clock is announced
    assert not tk.clock(2_000_000, now=10.01)  # ... then at most every 50 ms
    assert tk.clock(3_000_000, now=10.06)
    assert tk.clock(0, now=10.061)             # time going back (a new simulator): at once
    assert tk.log_time(None) == 0 and tk.log_time(7) == 7
    rl = RateLimit(100.0)  # Hz
    admitted = [t for t in range(0, 100_000_000, 1_000_000) if rl.admit(t)]
    assert admitted == list(range(0, 100_000_000, 10_000_000))
    assert rl.admit(0)                         # back in time: afresh
    assert all(RateLimit(0.0).admit(t) for t in (5, 5, 5))
    assert discoverable('/pump1/ls_pressure', '/pump1')
    assert discoverable('/pump1/loads/cyl/pressure', '/pump1/')
    assert not discoverable('/pump2/ls_pressure', '/pump1')
    assert not discoverable('/rosout', '/') and not discoverable('/a/_hidden/x', '/')


def test_the_layouts_plot_fields_the_suite_publishes():
    """Every series of config/foxglove/hydropump.json and config/plotjuggler/hydropump.xml
    names a topic the view serves and a field (or joint, or controller state entry) that its
    messages have: a renamed topic or field fails here, not silently in the viewer."""
    import re
    import xml.etree.ElementTree as ET

    from hydropump_ctrl.control.supervisor import STATE_KEYS
    from hydropump_ctrl.foxglove import DEFAULT_TOPICS
    from hydropump_ctrl.recorder import SUITE_TYPES
    from hydropump_sim.measure import JOINTS
    root = Path(__file__).resolve().parents[2] / 'config'
    types = {'/' + t.lstrip('/'): SUITE_TYPES['/' + t.lstrip('/')]
             if '/' + t.lstrip('/') in SUITE_TYPES else SUITE_TYPES[t] for t in DEFAULT_TOPICS}
    names = {'/joint_states': [j[0] for j in JOINTS], '/controller/state': list(STATE_KEYS)}
    layout = json.loads((root / 'foxglove' / 'hydropump.json').read_text())
    paths = [p['value'] for c in layout['configById'].values() for p in c.get('paths', [])]
    assert len(paths) >= 12
    for path in paths:
        topic, field, index = re.fullmatch(r'(/[\w/]+)\.(\w+)(?:\[(\d+)\])?', path).groups()
        assert field in _fields_of(types[topic]), path
        if index is not None:
            assert int(index) < len(names[topic]), path
    assert layout['configById']['DiagnosticSummary!diagnostics']['topicToRender'] in types
    curves = [c.get('name') for c in ET.parse(root / 'plotjuggler' / 'hydropump.xml')
              .getroot().iter('curve')]
    assert len(curves) == len(paths)
    for curve in curves:
        topic = next(t for t in sorted(types, key=len, reverse=True) if
                     curve.startswith(t + '/'))
        rest = curve[len(topic) + 1:].split('/')
        if topic in names:  # JointState: series named by joint (PlotJuggler's parser)
            assert rest[0] in names[topic] and rest[1] == 'position', curve
        else:
            assert rest[0] in _fields_of(types[topic]), curve
