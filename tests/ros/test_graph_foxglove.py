"""``hydropump-graph --foxglove PORT`` as a user starts it: the installed command in a
subprocess; a real WebSocket client (as tests/ros/test_foxglove.py) finds every topic the
graph's simulator and controller publish, as DDS shows them, advertised with its ROS type, and
receives the line pressure; SIGTERM then ends every node, the foxglove node included."""

import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import time

import pytest

from .rosutil import spin_until
from .test_foxglove import connect, free_port, message_frames, SUBPROTOCOLS

pytestmark = pytest.mark.ros

GRAPH = str(Path(sys.executable).with_name('hydropump-graph'))
# Every ROS graph has them; the view leaves them out (docs/ros.md).
SYSTEM = {'/rosout', '/parameter_events'}


def published(node) -> dict[str, str]:
    """What the graph's simulator and controller publish, as DDS shows it: topic -> type."""
    out = {}
    seen = node.get_node_names_and_namespaces()
    for name in ('simulator', 'controller'):
        if (name, '/') in seen:  # else not discovered yet
            out.update({topic: types[0] for topic, types in
                        node.get_publisher_names_and_types_by_node(name, '/')
                        if topic not in SYSTEM})
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != 'Z'


def test_graph_with_foxglove_serves_the_suite_topics(test_node, tmp_path):
    import rclpy
    port = free_port()
    proc = subprocess.Popen([GRAPH, '--foxglove', str(port), '--log-dir', str(tmp_path / 'logs'),
                             '--bag', str(tmp_path / 'bag')],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    pids = {}
    try:
        # The graph says what it started, by PID, and where the view is.
        while len(pids) < 4:
            line = proc.stdout.readline()
            assert line, f'hydropump-graph ended early: {proc.stderr.read()}'
            if m := re.fullmatch(r'started (\w+) \(pid (\d+)\)\n', line):
                pids[m[1]] = int(m[2])
        assert set(pids) == {'simulator', 'controller', 'recorder', 'foxglove'}
        assert proc.stdout.readline().startswith(f'live view: ws://127.0.0.1:{port} ')
        # The simulator's and controller's publishers on DDS: the clock, the measurements and
        # /diagnostics; the command and the state, once the controller is configured.
        # (The simulator advertises its topics together once it knows it is alone; DDS
        # shows them one by one: wait for every one judged below.)
        suite = {'/clock', '/pump_flow', '/line_flow', '/actuator_pressure', '/load_pressure',
                 '/joint_states', '/diagnostics'}
        spin_until(test_node, lambda: {'/line_pressure', '/solenoid_current_cmd',
                                       '/controller/state', *suite}
                   <= set(published(test_node)), 60, "the graph's publishers on DDS")
        channels = {}
        with connect(port, timeout=60) as ws:
            assert ws.subprotocol in SUBPROTOCOLS
            deadline = time.monotonic() + 60
            # The node looks for new topics every second: wait until each one DDS shows
            # (looked up again as discovery goes on) is advertised.
            while not set(published(test_node)) <= set(channels):
                assert time.monotonic() < deadline, \
                    f'not advertised: {sorted(set(published(test_node)) - set(channels))}'
                try:
                    frame = ws.recv(timeout=0.5)
                except TimeoutError:
                    frame = None
                if isinstance(frame, str) and json.loads(frame)['op'] == 'advertise':
                    channels.update({c['topic']: c for c in json.loads(frame)['channels']})
                rclpy.spin_once(test_node, timeout_sec=0.01)
            want = published(test_node)
            for topic, msgtype in want.items():
                assert channels[topic]['schemaName'] == msgtype, (topic, channels[topic])
                assert channels[topic]['encoding'] == 'json'
            # Live: the line pressure (absolute, Pa) from the running simulator.
            ch = channels['/line_pressure']
            ws.send(json.dumps({'op': 'subscribe',
                                'subscriptions': [{'id': 7, 'channelId': ch['id']}]}))
            frames = message_frames(ws, 5)
        assert {sid for sid, _, _ in frames} == {7}
        assert all(1.0e5 < msg['fluid_pressure'] < 1.0e8 for _, _, msg in frames), frames
        # The suite's measurements, clock and health among them, not only the three waited
        # for above.
        for topic in suite:
            assert topic in want, sorted(want)
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(timeout=60)
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid in pids.values():  # by PID, the processes the graph said it started
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert rc == 0 and 'Traceback' not in err, err
    assert not [n for n, pid in pids.items() if _alive(pid)]
    log = (tmp_path / 'logs' / 'foxglove.log').read_text()
    assert 'Traceback' not in log and f'ws://127.0.0.1:{port}' in log, log
