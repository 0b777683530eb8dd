"""SIGTERM to ``hydropump record`` while it records, as a service manager, ``timeout`` or
``kill`` sends it: the installed command in a subprocess, stopped by PID in the middle of a
long experiment. It stops its whole graph (every node process it started ends), the open bag
is closed and valid (read with the independent ``mcap`` reader: its summary, written on
closing, agrees with the recorder's metadata.yaml, and its commands are the plan's levels),
and it exits with code 143 and one line, no traceback. With ``--attach`` the nodes, someone
else's, run on, and the open bag is closed all the same."""

import os
from pathlib import Path
import queue
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import yaml

from .rosutil import spin_until

pytestmark = [pytest.mark.ros, pytest.mark.slow]

HYDROPUMP = str(Path(sys.executable).with_name('hydropump'))
# Current levels in A: the truth a bag's commands are held against comes from the plan alone.
LEVELS = (0.45, 0.55)
DWELL = 0.5  # s
PLAN = [
    # Far longer than the test waits: SIGTERM comes in its middle.
    {'name': 'long', 'duration': 600.0,
     'current': {'staircase': {'levels': list(LEVELS), 'dwell': DWELL}, 'unit': 'A'}},
    {'name': 'check', 'duration': 0.5, 'held_out': True,
     'current': {'offset': 0.5, 'sine': {'amplitude': 0.05, 'frequency': 2.0}}},
]


def _children(pid: int) -> list[int]:
    out = []
    for task in Path(f'/proc/{pid}/task').glob('*/children'):
        try:
            out += [int(x) for x in task.read_text().split()]
        except (OSError, ValueError):  # the thread has just ended
            pass
    return out


def _start_time(pid: int) -> str | None:
    """The start time of ``pid`` (a PID used again is another process); None if gone or a
    zombie."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except (OSError, IndexError):
        return None
    return None if fields[0] == 'Z' else fields[19]


def _alive(proc: tuple[int, str]) -> bool:
    return _start_time(proc[0]) == proc[1]


class ClockWatch:
    """The latest ``/clock`` of a ROS domain [s] (a context of its own: the graph that
    ``hydropump record`` starts is in a domain it picks)."""

    def __init__(self, domain: int):
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rosgraph_msgs.msg import Clock
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node('clock_watch', context=self.context)
        self.t = -1.0
        self.node.create_subscription(Clock, '/clock', self._on_clock, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def _on_clock(self, msg) -> None:
        self.t = msg.clock.sec + msg.clock.nanosec * 1e-9

    def spin(self) -> None:
        self.executor.spin_once(timeout_sec=0.05)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


class Command:
    """``hydropump ARGS`` in a subprocess, its output lines read as they come."""

    def __init__(self, *args):
        self.proc = subprocess.Popen([HYDROPUMP, *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True)
        self.lines: queue.Queue = queue.Queue()
        self.out: list[str] = []
        self.err: list[str] = []
        threading.Thread(target=lambda: [self.lines.put(ln) for ln in self.proc.stdout]
                         + [self.lines.put(None)], daemon=True).start()
        self._drain = threading.Thread(target=lambda: self.err.extend(self.proc.stderr),
                                       daemon=True)
        self._drain.start()
        self.nodes: dict[tuple[int, str], str] = {}

    def wait_for(self, pattern: str, timeout: float) -> re.Match:
        deadline = time.monotonic() + timeout
        while True:
            line = self.lines.get(timeout=max(0.1, deadline - time.monotonic()))
            assert line is not None, 'hydropump ended early:\n' + ''.join(self.out + self.err)
            self.out.append(line)
            if m := re.search(pattern, line):
                return m

    def terminate(self, timeout: float = 90.0) -> int:
        """SIGTERM by PID; the exit code, the output read to its end."""
        self.proc.send_signal(signal.SIGTERM)
        try:
            rc = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f'hydropump did not end within {timeout:g} s of SIGTERM')
        while (line := self.lines.get(timeout=10)) is not None:
            self.out.append(line)
        self._drain.join(timeout=10)
        return rc

    def children(self) -> dict[tuple[int, str], str]:
        """The command's child processes (its nodes), by (PID, start time): command line."""
        return {(pid, _start_time(pid)): Path(f'/proc/{pid}/cmdline').read_text()
                for pid in _children(self.proc.pid) if _start_time(pid)}

    def close(self) -> None:
        """End the command and its nodes, whatever the test got to: SIGTERM (it stops its
        graph), then SIGKILL, each by PID."""
        if self.proc.poll() is None:
            self.nodes = self.nodes or self.children()
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.proc.wait()
        for pid, started in self.nodes:  # only the very processes seen here
            if _alive((pid, started)):
                os.kill(pid, signal.SIGKILL)


def _record(tmp_path: Path, *extra, test_node=None) -> tuple[Command, Path, float]:
    """Start ``hydropump record`` on :data:`PLAN`; once it is recording the first experiment,
    past its second level in simulation time (the ``/clock`` of the graph: in the domain the
    command names, or, attached, the test node's): the command, the folder of the bags and the
    experiment's start [s]."""
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump(PLAN))
    out = tmp_path / 'bags'
    cmd = Command('record', str(plan), '--out', str(out), *extra)
    try:
        return cmd, out, _recording(cmd, test_node)
    except BaseException:
        cmd.close()
        raise


def _recording(cmd: Command, test_node) -> float:
    domain = None
    if test_node is None:
        domain = int(cmd.wait_for(r'\[graph\] .*\(ROS domain (\d+)', 60)[1])
    t0 = float(cmd.wait_for(r'\[1/2 long\] .*starts at t = ([0-9.]+) s', 120)[1])
    if test_node is not None:
        latest = [-1.0]
        from rosgraph_msgs.msg import Clock
        test_node.create_subscription(Clock, '/clock', lambda m: latest.__setitem__(
            0, m.clock.sec + m.clock.nanosec * 1e-9), 10)
        spin_until(test_node, lambda: latest[0] >= t0 + 2 * DWELL or cmd.proc.poll()
                   is not None, 60, 'the second level in simulation time')
    else:
        watch = ClockWatch(domain)
        try:
            deadline = time.monotonic() + 60
            while watch.t < t0 + 2 * DWELL and cmd.proc.poll() is None:
                assert time.monotonic() < deadline, f'/clock at {watch.t} s after 60 s'
                watch.spin()
        finally:
            watch.close()
    assert cmd.proc.poll() is None, ''.join(cmd.out + cmd.err)
    return t0


def _check_bag(bag: Path, t0: float) -> None:
    """The bag is closed and valid: the independent reader reads it through its summary (MCAP
    writes it on closing), the recorder's metadata.yaml counts the same messages, and the
    commands are the plan's levels, up to a stop well before the planned end."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    with open(bag / 'long_0.mcap', 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == \
            meta['message_count'] > 0
        cmds = [(m.log_time * 1e-9, d.data) for _, ch, m, d in
                reader.iter_decoded_messages(topics=['/solenoid_current_cmd'])]
    # Every topic that holds messages names the QoS its publishers offered (a recorder that
    # registered channels before discovery reported their publishers wrote none).
    for entry in meta['topics_with_message_count']:
        if entry['message_count']:
            assert entry['topic_metadata']['offered_qos_profiles'], entry
    t, i = np.array(cmds).T
    rel = t - t0
    assert rel[0] >= -1e-9 and 2 * DWELL <= rel[-1] < PLAN[0]['duration'], (rel[0], rel[-1])
    # Clear of the instants where a level changes (a sample either side).
    np.testing.assert_allclose(i[(rel > 0.01) & (rel < DWELL - 0.01)], LEVELS[0], atol=1e-12)
    np.testing.assert_allclose(i[(rel > DWELL + 0.01) & (rel < 2 * DWELL - 0.01)], LEVELS[1],
                               atol=1e-12)


@pytest.mark.skipif(not Path('/proc/self/task').is_dir(), reason='needs Linux /proc')
def test_sigterm_stops_the_graph_of_its_own_and_leaves_a_valid_bag(tmp_path, ros_domain):
    cmd, out = None, None
    try:
        cmd, out, t0 = _record(tmp_path)
        # The graph: the three nodes, started by the command.
        cmd.nodes = cmd.children()
        # Each node's launcher runs e.<node>() (hydropump_ros.venv_index).
        assert sorted(re.search(r'e\.(\w+)\(\)', c)[1] for c in cmd.nodes.values()) == \
            ['controller', 'recorder', 'simulator'], cmd.nodes
        rc = cmd.terminate()
        err = ''.join(cmd.err)
        # The whole output in the message (a tuple's repr would cut a traceback short).
        assert rc == 143, f'exit code {rc}, its output:\n{"".join(cmd.out)}\n{err}'
        assert 'Traceback' not in ''.join(cmd.out) + err, ''.join(cmd.out) + err
        assert err.splitlines() == [
            'stopped by SIGTERM: every node of the run ended, the open bag closed; the bags '
            f'recorded so far are in {out}'], err
        left = [c for p, c in cmd.nodes.items() if _alive(p)]
        assert not left, f'node processes left running: {left}'
    finally:
        if cmd:
            cmd.close()
    _check_bag(out / 'long', t0)
    # The run stopped there: the next experiment never started, no list of a whole run.
    assert not (out / 'check').exists() and not (out / 'record.yaml').exists()


def test_sigterm_with_attach_closes_the_open_bag_and_leaves_the_nodes(nodes, test_node,
                                                                     tmp_path):
    sim = nodes.start('simulator', '-p', 'lock_step:=true', '-p', 'start_paused:=true',
                      '-p', 'publish_rate:=200.0')
    ctrl = nodes.start('controller', '-p', 'autostart:=true')
    rec = nodes.start('recorder', '-p', 'autostart:=false')
    spin_until(test_node, lambda: {'/simulator/reset', '/controller/get_state',
                                   '/recorder/ready'} <= {n for n, _ in
                                                          test_node.get_service_names_and_types()},
               60, 'the three nodes')
    cmd = None
    try:
        cmd, out, t0 = _record(tmp_path, '--attach', test_node=test_node)
        rc = cmd.terminate()
        err = ''.join(cmd.err)
        assert rc == 143, f'exit code {rc}, its output:\n{"".join(cmd.out)}\n{err}'
        assert 'Traceback' not in ''.join(cmd.out) + err, ''.join(cmd.out) + err
        assert err.splitlines() == [
            'stopped by SIGTERM: the open bag closed, the nodes left running; the bags '
            f'recorded so far are in {out}'], err
        # Someone else's nodes: still there.
        assert sim.alive() and ctrl.alive() and rec.alive()
    finally:
        if cmd:
            cmd.close()
    _check_bag(out / 'long', t0)
    assert 'Traceback' not in rec.log()
