"""Helpers for tests that run real nodes over DDS: processes ended by PID, discovery waits."""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import time

from ament_index_python.packages import get_package_prefix


def executable(name: str, package: str = 'hydropump_ros') -> str:
    """The node executable as ``ros2 run`` finds it: ``<prefix>/lib/<package>/<name>``."""
    path = Path(get_package_prefix(package)) / 'lib' / package / name
    assert os.access(path, os.X_OK), f'{path} is not executable'
    return str(path)


class NodeProcess:
    """A node in its own process, its log in a file; stopped by PID, never by name."""

    def __init__(self, name: str, ros_args: list[str], log_dir: Path, env: dict | None = None,
                 preexec_fn=None):
        self.name = name
        self.log_path = log_dir / f'{name}-{time.monotonic_ns()}.log'
        self._log = open(self.log_path, 'w')  # noqa: SIM115 - closed in stop()
        # preexec_fn: runs in the child before the node starts (e.g. a file-size limit).
        self.proc = subprocess.Popen([executable(name), '--ros-args', *ros_args],
                                     stdout=self._log, stderr=subprocess.STDOUT,
                                     env=env or os.environ.copy(), preexec_fn=preexec_fn)

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 15.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()


def spin_until(node, predicate, timeout: float, what: str = 'condition') -> None:
    """Spin ``node`` until ``predicate()`` holds; fail with ``what`` after ``timeout`` s."""
    import rclpy
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out after {timeout:g} s waiting for {what}')
        rclpy.spin_once(node, timeout_sec=0.01)


def wait_for_publisher(node, topic: str, timeout: float = 20.0) -> None:
    spin_until(node, lambda: node.count_publishers(topic) > 0, timeout,
               f'a publisher on {topic}')


def wait_for_subscriber(node, topic: str, timeout: float = 20.0) -> None:
    spin_until(node, lambda: node.count_subscribers(topic) > 0, timeout,
               f'a subscriber on {topic}')


def call(node, client, request, timeout: float = 10.0):
    """Call a service and spin until the answer arrives."""
    spin_until(node, client.service_is_ready, timeout, f'service {client.srv_name}')
    future = client.call_async(request)
    spin_until(node, future.done, timeout, f'the answer of {client.srv_name}')
    return future.result()


def run_python(code: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=timeout)


class LockStepDriver:
    """A stand-in controller for lock-step runs: answers every control instant on /clock with
    the current of ``schedule(t)`` (absolute A) on ``solenoid_current_cmd``."""

    def __init__(self, node, schedule, period: float = 0.005, topic: str = 'solenoid_current_cmd'):
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Float64
        self.schedule = schedule
        self.period_ns = int(round(period * 1e9))
        self.answered = -1
        self.t = 0.0
        self.active = True
        self._msg = Float64
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        self.node = node
        # Keep-all, as the controller's: a lagging recorder holds it back, losing nothing.
        self.pub = node.create_publisher(Float64, topic, QoSProfile(
            depth=1000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL))
        self.sub = node.create_subscription(Clock, '/clock', self._on_clock, 100)

    def destroy(self) -> None:
        """Leave the graph (a later run must not see this publisher)."""
        self.active = False
        self.node.destroy_publisher(self.pub)
        self.node.destroy_subscription(self.sub)

    def kick(self) -> None:
        """Answer the instant t = 0 if its /clock went by before this node matched."""
        if self.answered < 0:
            self.answered = 0
            self.pub.publish(self._msg(data=float(self.schedule(0.0))))

    def _on_clock(self, msg) -> None:
        ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        self.t = ns * 1e-9
        k = ns // self.period_ns
        if self.active and ns % self.period_ns == 0 and k > self.answered:
            self.answered = k
            self.pub.publish(self._msg(data=float(self.schedule(self.t))))


class StepCollector:
    """Collects a Float64 topic and gives each message the simulation time of its step: the
    latest /clock published before it (matched by DDS source timestamps, as the recorder)."""

    def __init__(self, node, topics):
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import Float64
        self.clocks = []
        self.raw = {t: [] for t in topics}
        node.create_subscription(Clock, '/clock', self._on_clock, 1000)
        for t in topics:
            node.create_subscription(Float64, t, lambda m, info, t=t: self.raw[t].append(
                (info['source_timestamp'], m.data)), 1000)

    def _on_clock(self, msg, info) -> None:
        self.clocks.append((info['source_timestamp'],
                            msg.clock.sec * 1_000_000_000 + msg.clock.nanosec))

    def series(self, topic):
        """``(t [s], values)`` of ``topic``, messages before the first clock dropped."""
        import bisect

        import numpy as np
        srcs = [c[0] for c in self.clocks]
        t, v = [], []
        for src, val in self.raw[topic]:
            i = bisect.bisect_right(srcs, src) - 1
            if i >= 0:
                t.append(self.clocks[i][1] * 1e-9)
                v.append(val)
        return np.array(t), np.array(v)
