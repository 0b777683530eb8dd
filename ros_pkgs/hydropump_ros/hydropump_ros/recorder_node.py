"""The ``recorder`` node: topics to a rosbag2 bag (``metadata.yaml`` version 9 + MCAP).

Messages are taken serialized (no decode) and written with ``rosbags``. Log times:

- a message with a ``std_msgs/Header`` gets its header stamp;
- with ``use_sim_time``, an unstamped message gets the simulation time of the latest
  ``/clock`` its publisher had sent before it (matched by DDS source timestamps, so arrival
  order does not matter: the simulator publishes ``/clock`` first in every step);
- otherwise the receive time.

Messages wait in a short reorder buffer and are written in (log time, topic, arrival) order,
so two identical lock-step runs give byte-identical bags. The MCAP chunk is closed and
flushed every ``flush_period`` of simulation time (wall time without ``use_sim_time``): a hard
kill (SIGKILL) loses at most ``flush_period + reorder_window`` (0.35 s by default) plus any
backlog, and the bag then has no summary and no ``metadata.yaml``: the project's reader
reads it anyway, and ``ros2 bag reindex`` rebuilds the metadata. SIGINT and SIGTERM close
the bag cleanly.

Services (``std_srvs/Trigger``): ``~/start`` opens a bag, ``~/stop`` waits for the queues to go
quiet and closes it, ``~/ready`` answers whether every topic has a matched publisher.
"""

from __future__ import annotations

from collections import deque
from datetime import datetime
import heapq
import importlib
from pathlib import Path
import signal
import struct
import sys
import threading
import time

import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from std_srvs.srv import Trigger

from hydropump_sim.schema import ParamSpec

from . import bridge

# Suite topics and their types; other topics are looked up in the ROS graph.
KNOWN_TYPES = {
    'solenoid_current_cmd': 'std_msgs/msg/Float64',
    'solenoid_current': 'std_msgs/msg/Float64',
    'pump_flow': 'std_msgs/msg/Float64',
    'line_flow': 'std_msgs/msg/Float64',
    'load_flow': 'std_msgs/msg/Float64',
    'actuator_pressure': 'sensor_msgs/msg/FluidPressure',
    'line_pressure': 'sensor_msgs/msg/FluidPressure',
    'load_pressure': 'sensor_msgs/msg/FluidPressure',
    'joint_states': 'sensor_msgs/msg/JointState',
    'controller/state': 'sensor_msgs/msg/JointState',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    '/clock': 'rosgraph_msgs/msg/Clock',
}
DEFAULT_TOPICS = ['solenoid_current_cmd', 'solenoid_current', 'pump_flow', 'line_flow',
                  'load_flow', 'actuator_pressure', 'line_pressure', 'load_pressure',
                  'joint_states', 'controller/state']

SPECS = [
    ParamSpec('topics', list, '-', 'topics to record (relative names resolve in the namespace)',
              (None, None), None, False, False),
    ParamSpec('output', str, 'path', 'bag directory; empty = bags/recorder_<time>; an existing '
              'one is never overwritten', (None, None), None, True, False),
    ParamSpec('autostart', bool, '-', 'open a bag and record at start-up', (None, None), None,
              False, False),
    ParamSpec('flush_period', float, 's', 'close and flush the MCAP chunk this often (sim '
              'time with use_sim_time)', (0.01, 10.0), None, False, False),
    ParamSpec('reorder_window', float, 's', 'hold messages this long to write them in time '
              'order', (0.0, 5.0), None, False, False),
]


def _msg_class(msgtype: str):
    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


def _header_stamp(data: bytes) -> int:
    """Stamp [ns] of a serialized message that starts with a Header (or a Clock)."""
    little = data[1] == 1  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
    sec, nsec = struct.unpack_from('<iI' if little else '>iI', data, 4)
    return sec * 1_000_000_000 + nsec


class _Bag:
    """One open bag: the writer, its connections and the time-ordered write buffer."""

    def __init__(self, path: Path, typestore):
        self.path = path
        self.writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.typestore = typestore
        self.conns: dict[str, object] = {}
        self.heap: list = []
        self.count = 0
        self.chunk_end: int | None = None

    def connection(self, topic: str, msgtype: str):
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype,
                                                           typestore=self.typestore)
        return self.conns[topic]

    def push(self, log_ns: int, order: int, seq: int, topic: str, data: bytes) -> None:
        heapq.heappush(self.heap, (log_ns, order, seq, topic, data))

    def write_until(self, horizon: int, flush_period_ns: int) -> None:
        """Write buffered messages up to ``horizon``; close a chunk at every period boundary
        of log time, so chunking depends on the data, not on arrival timing."""
        heap = self.heap
        while heap and heap[0][0] <= horizon:
            log_ns, _, _, topic, data = heapq.heappop(heap)
            if self.chunk_end is None:
                self.chunk_end = (log_ns // flush_period_ns + 1) * flush_period_ns
            elif log_ns >= self.chunk_end:
                self.flush()
                self.chunk_end = (log_ns // flush_period_ns + 1) * flush_period_ns
            self.writer.write(self.conns[topic], log_ns, data)
            self.count += 1

    def flush(self) -> None:
        # rosbags 0.11 has no public flush; closing the pending chunk writes it out whole.
        storage = self.writer.storage
        if storage is not None and storage.chunk.bio.tell():
            storage.close_chunk()
            storage.bio.flush()

    def close(self) -> None:
        self.write_until(2**63 - 1, 2**62)
        self.writer.close()


class RecorderNode(Node):

    def __init__(self, **kwargs):
        super().__init__('recorder', **kwargs)
        defaults = {'topics': DEFAULT_TOPICS, 'output': '', 'autostart': True,
                    'flush_period': 0.25, 'reorder_window': 0.1}
        self.cfg = {}
        for s in SPECS:
            d = bridge.descriptor(s, read_only=not s.live) if s.type is not list else None
            self.cfg[s.name] = self.declare_parameter(s.name, defaults[s.name], d).value
        self.sim_time = self.get_parameter('use_sim_time').value
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        self._lock = threading.Lock()
        self._bag: _Bag | None = None
        self._seq = 0
        self._clocks: deque = deque(maxlen=100000)   # (source ns, clock ns)
        self._pending: list = []                     # unstamped, waiting for a later clock
        self._latest: dict[str, int] = {}            # topic -> last log time
        self._last_rx = time.monotonic()
        self._drain_waiters: list = []
        self._types: dict[str, str] = {}
        # Reliable and keep-all on both ends: a recorder that lags buffers instead of
        # dropping, and catches up before a stop closes the bag.
        self._qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                               history=HistoryPolicy.KEEP_ALL)
        # The data subscriptions live on a hidden node that no executor spins: a take loop
        # serves them, at about four times the rate rclpy's executor reaches. Names are
        # resolved (remapped) by this node first.
        self._io = Node(f'_{self.get_name()}_io', namespace=self.get_namespace(),
                        context=self.context, use_global_arguments=False,
                        start_parameter_services=False)
        self._subs: list = []  # (subscription, topic, order, stamped); order -1 is /clock
        self._add(self.resolve_topic_name('/clock'), 'rosgraph_msgs/msg/Clock', -1)
        self._topics = [self.resolve_topic_name(name) for name in self.cfg['topics']]
        for i, (name, topic) in enumerate(zip(self.cfg['topics'], self._topics)):
            msgtype = KNOWN_TYPES.get(name) or KNOWN_TYPES.get(topic)
            if msgtype:
                self._add(topic, msgtype, i)
        # Steady-clock timers: with use_sim_time a paused simulator would stop them.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if len(self._types) - 1 < len(self._topics):
            self._discovery = self.create_timer(0.5, self._discover, clock=steady)
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_service(Trigger, '~/ready', self._on_ready)
        # Its own group: a stop waiting (suspended) in the default group must not block it.
        self.create_timer(0.05, self._check_drained,
                          callback_group=MutuallyExclusiveCallbackGroup(), clock=steady)
        self._halt = False
        self._taker = threading.Thread(target=self._take_loop, name='take', daemon=True)
        if self.cfg['autostart']:
            self.start()
        self._taker.start()

    # ---- subscriptions -------------------------------------------------------------------

    def _add(self, topic: str, msgtype: str, order: int) -> None:
        cls = _msg_class(msgtype)
        fields = list(cls.get_fields_and_field_types().items())
        stamped = bool(fields) and fields[0] == ('header', 'std_msgs/Header')
        sub = self._io.create_subscription(cls, topic, lambda *_: None, self._qos, raw=True)
        with self._lock:
            self._types[topic] = msgtype
            self._subs.append((sub, topic, order, stamped))
            if self._bag is not None and order >= 0:
                self._bag.connection(topic, msgtype)

    def _discover(self) -> None:
        graph = dict(self.get_topic_names_and_types())
        for i, topic in enumerate(self._topics):
            if topic not in self._types and topic in graph:
                self._add(topic, graph[topic][0], i)
        if all(t in self._types for t in self._topics):
            self._discovery.cancel()

    def _take_loop(self) -> None:
        while not self._halt:
            got = 0
            for sub, topic, order, stamped in list(self._subs):
                handle = sub.handle
                while True:
                    taken = handle.take_message(sub.msg_type, True)
                    if taken is None:
                        break
                    got += 1
                    data, info = taken
                    if order < 0:
                        self._on_clock(data, info)
                    else:
                        self._on_message(topic, order, stamped, data, info)
            if got:
                self._last_rx = time.monotonic()
            else:
                time.sleep(0.0005)

    def _on_message(self, topic, order, stamped, data, info) -> None:
        with self._lock:
            bag = self._bag
            if bag is None:
                return
            self._seq += 1
            log = _header_stamp(data) if stamped else None
            if log:
                bag.push(log, order, self._seq, topic, data)
                self._latest[topic] = log
            elif self.sim_time:
                self._pending.append((info['source_timestamp'], order, self._seq, topic, data))
            else:
                now = self.get_clock().now().nanoseconds
                bag.push(now, order, self._seq, topic, data)
                bag.write_until(now, int(self.cfg['flush_period'] * 1e9))

    def _on_clock(self, data, info) -> None:
        clock_ns = _header_stamp(data)  # Clock starts with its time, laid out as a stamp
        src = info['source_timestamp']
        with self._lock:
            self._clocks.append((src, clock_ns))
            bag = self._bag
            if bag is None:
                return
            self._resolve(bag, src)
            window = int(self.cfg['reorder_window'] * 1e9)
            horizon = clock_ns - window
            active = [t for t in self._latest.values() if t >= clock_ns - window]
            if active:
                horizon = min(horizon, min(active))
            bag.write_until(horizon, int(self.cfg['flush_period'] * 1e9))

    def _resolve(self, bag: _Bag, src_limit: int | None) -> None:
        """Give unstamped messages published before ``src_limit`` their clock time."""
        keep = []
        clocks = self._clocks
        for item in self._pending:
            src, order, seq, topic, data = item
            if src_limit is not None and src >= src_limit:
                keep.append(item)
                continue
            log = None
            for c_src, c_ns in reversed(clocks):
                if c_src <= src:
                    log = c_ns
                    break
            if log is None:
                log = clocks[0][1] if clocks else 0
            bag.push(log, order, seq, topic, data)
            self._latest[topic] = log
        self._pending = keep

    # ---- start / stop --------------------------------------------------------------------

    def _bag_path(self) -> Path:
        out = self.get_parameter('output').value
        path = Path(out) if out else Path('bags') / f'recorder_{datetime.now():%Y%m%d-%H%M%S}'
        base, n = path, 1
        while path.exists():
            path = base.with_name(f'{base.name}_{n}')
            n += 1
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    def start(self) -> Path:
        with self._lock:
            if self._bag is not None:
                return self._bag.path
            path = self._bag_path()
            self._bag = _Bag(path, self.typestore)
            for topic in self._topics:
                if topic in self._types:
                    self._bag.connection(topic, self._types[topic])
            self._pending.clear()
            self._latest.clear()
        self.get_logger().info(f'recording {len(self._topics)} topics to {path}')
        return path

    def stop(self) -> tuple[Path, int] | None:
        with self._lock:
            bag, self._bag = self._bag, None
            if bag is None:
                return None
            self._resolve(bag, None)
            bag.close()
        self.get_logger().info(f'closed {bag.path}: {bag.count} messages')
        return bag.path, bag.count

    def _on_ready(self, request, response):
        """Ready when every recorded topic has a matched publisher: an experiment that
        starts after this loses nothing to discovery."""
        matched = {topic: sub.get_publisher_count() for sub, topic, _, _ in self._subs}
        waiting = [t for t in self._topics if matched.get(t, 0) < 1]
        response.success = not waiting
        response.message = ('waiting for a publisher on ' + ', '.join(waiting) if waiting
                            else 'all topics matched')
        return response

    def halt(self) -> None:
        """End the take loop and the hidden subscription node."""
        self._halt = True
        self._taker.join(timeout=2.0)
        self._io.destroy_node()

    def _on_start(self, request, response):
        try:
            path = self.start()
        except OSError as exc:
            response.success, response.message = False, f'cannot open the bag: {exc}'
            return response
        response.success, response.message = True, str(path)
        return response

    def drain(self, quiet: float = 0.2, limit: float = 5.0) -> None:
        """Wait until no message arrived for ``quiet`` s (at most ``limit`` s), so that a
        stop after the publishers went quiet (a paused or waiting simulator) loses nothing."""
        end = time.monotonic() + limit
        while time.monotonic() - self._last_rx < quiet and time.monotonic() < end:
            time.sleep(0.02)

    def _check_drained(self, quiet: float = 0.2, limit: float = 5.0) -> None:
        now = time.monotonic()
        for fut, t0 in list(self._drain_waiters):
            if now - self._last_rx >= quiet or now - t0 >= limit:
                self._drain_waiters.remove((fut, t0))
                fut.set_result(True)

    async def _on_stop(self, request, response):
        # Wait (without blocking the executor, which keeps taking messages) until the
        # publishers have gone quiet, then close.
        fut = Future()
        self._drain_waiters.append((fut, time.monotonic()))
        await fut
        done = self.stop()
        response.success = done is not None
        response.message = f'{done[0]} ({done[1]} messages)' if done else 'not recording'
        return response


def main(args=None) -> int:
    # Signals are handled here, not by rclpy, so that SIGINT and SIGTERM can first take what
    # is still queued and then close the bag while the context is alive.
    from rclpy.signals import SignalHandlerOptions
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rclpy raises RCLError for a bad command line
        print(f'error: cannot start: {exc}', file=sys.stderr)
        return 2
    node = RecorderNode()
    # One thread takes every message in arrival order; rclpy's multi-threaded executor
    # loses messages at the suite's 10 kHz message rate (measured in bench/bench_ros.py).
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        stop.wait()
        node.drain(quiet=0.2, limit=10.0)
        node.stop()
    finally:
        executor.shutdown(timeout_sec=2.0)
        spinner.join(timeout=2.0)
        node.halt()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
