"""The ``recorder`` node: topics to rosbag2 bags (MCAP), in one clock, losing nothing.

The logic is pure (:mod:`hydropump_ctrl.recorder`): the sequencer gives every message its log
time by the rule of time (simulation time wherever a ``/clock`` is present, wall time only
where none is) and writes in log-time order behind a per-topic watermark; the bag writer
writes what rosbag2 Jazzy writes. This node takes the messages serialized, from a thread that
serves every subscription round-robin (a bounded batch per topic per pass, ``/clock`` last),
and reads the publishers' QoS from the graph for ``offered_qos_profiles``.

- A jump back of simulation time (a new simulator) closes the bag and opens a new one; a
  ``/clock`` that appears under a bag recorded in wall time does the same. Each says so.
- Messages lost on the way (gaps in a publisher's sequence numbers) are counted, reported in
  ``/diagnostics`` and in the bag's ``custom_data``; never silent.
- ``~/stop``, SIGINT and SIGTERM stop at once: the bag gets what was published up to the
  latest ``/clock`` and had arrived, or arrives within the next second, and closes.

Services (``std_srvs/Trigger``): ``~/start`` opens a bag, ``~/stop`` closes it, ``~/ready``
answers whether every topic has a matched publisher.
"""

from __future__ import annotations

from datetime import datetime
import importlib
from pathlib import Path
import struct
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from hydropump_ctrl.recorder import (
    BagError,
    BagWriter,
    qos_profile,
    RecorderConfig,
    Sequencer,
    SUITE_TYPES,
    unique_path,
)
from hydropump_sim.schema import spec_map, specs_of

from . import bridge, entry

STOP_LIMIT = 0.8   # s: a stop waits at most this long for messages still on their way


def _msg_class(msgtype: str):
    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


def _stamp(data: bytes) -> int:
    """Stamp [ns] of a serialized message that starts with a Header (or a Clock)."""
    little = data[1] == 1  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
    sec, nsec = struct.unpack_from('<iI' if little else '>iI', data, 4)
    return sec * 1_000_000_000 + nsec


def _qos_dict(q) -> dict:
    """An rclpy QoS profile of the graph in rosbag2's metadata layout."""
    def dur(d):
        ns = d.nanoseconds
        return None if ns >= 2 ** 63 - 1 or ns < 0 else {'sec': ns // 10 ** 9,
                                                          'nsec': ns % 10 ** 9}

    def name(e):
        return e.name.lower()
    return qos_profile(name(q.history), q.depth, name(q.reliability), name(q.durability),
                       name(q.liveliness), dur(q.deadline), dur(q.lifespan),
                       dur(q.liveliness_lease_duration), q.avoid_ros_namespace_conventions)


class _Session:
    """One open bag: its writer, its sequencer once the time base is known, loss counts."""

    def __init__(self, node: RecorderNode, path: Path):
        cfg = node.cfg
        self.node = node
        self.path = path
        self.writer = BagWriter(path, compression=cfg.compression,
                                chunk_period=cfg.flush_period).open()
        self.seq: Sequencer | None = None
        self.early: list = []                       # messages before the time base is known
        self.last_pub: dict[str, int] = {}          # topic -> last publication sequence number
        self.lost: dict[str, int] = {}
        self.stop_at: int | None = None             # sim ns: nothing after it is recorded
        self.dropped_after_stop = 0

    def start_sequencer(self, mode: str) -> None:
        self.seq = Sequencer(self.node.topics, mode, idle_timeout=self.node.cfg.idle_timeout)
        for topic in self.node.matched():
            self.seq.matched(topic)
        early, self.early = self.early, []
        for item in early:
            self._feed(*item[:5])

    def message(self, topic: str, stamped: bool, data: bytes, info: dict) -> None:
        seq_no = info.get('publication_sequence_number')
        if seq_no is not None and self.node.single_publisher(topic):
            last = self.last_pub.get(topic)
            if last is not None and seq_no > last + 1:
                self.lost[topic] = self.lost.get(topic, 0) + seq_no - last - 1
            self.last_pub[topic] = seq_no
        item = (topic, stamped, data, info, time.time_ns())
        if self.seq is None:
            self.early.append(item + (time.monotonic(),))
        else:
            self._feed(*item)

    def _feed(self, topic, stamped, data, info, received) -> None:
        stamp = _stamp(data) if stamped else None
        if self.stop_at is not None and stamp is not None and stamp > self.stop_at:
            self.dropped_after_stop += 1
            return
        self.seq.message(topic, data, source_ns=info['source_timestamp'], stamp_ns=stamp,
                         receive_ns=received)

    def write(self, records) -> None:
        w = self.writer
        for r in records:
            if self.stop_at is not None and self.seq.mode == 'sim' and r.log_ns > self.stop_at:
                self.dropped_after_stop += 1
                continue
            if r.topic not in w.topics:
                w.add_topic(r.topic, self.node.types[r.topic], self.node.offered_qos(r.topic))
            # One clock in a bag: in simulation time the publish time is the log time too
            # (a wall-clock send time beside it would mix clocks, and differ between runs).
            w.write(r.topic, r.log_ns, r.data,
                    r.log_ns if self.seq.mode == 'sim' else r.publish_ns)

    def complete(self) -> bool:
        """Has every active topic delivered up to the stop time?"""
        seq = self.seq
        if seq is None or seq.mode == 'wall' or self.stop_at is None:
            return True
        return seq.complete(self.stop_at)

    def close(self, reason: str) -> Path:
        if self.seq is None and self.early:
            self.start_sequencer('wall')
        if self.seq is not None:
            self.write(self.seq.drain())
            w = self.writer
            w.custom_data.update({
                'time_base': 'simulation' if self.seq.mode == 'sim' else 'wall',
                'messages_lost': str(sum(self.lost.values())),
                'messages_late': str(self.seq.late),
                'closed_by': reason})
            for topic, n in self.lost.items():
                w.custom_data[f'lost.{topic}'] = str(n)
        return self.writer.close()


class RecorderNode(bridge.ExplainedParameters, Node):
    """Topics to rosbag2 bags (see the module)."""

    def __init__(self):
        super().__init__('recorder')
        self.cfg = bridge.declare(self, RecorderConfig)
        self.schema_specs = spec_map(RecorderConfig)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._lock = threading.RLock()
        self._session: _Session | None = None
        self._closed: list[tuple[Path, int]] = []
        # (deadline, done, swept): a stop in progress, see _take_loop
        self._stop_request: tuple[float, threading.Event, bool] | None = None
        self.topics = [self.resolve_topic_name(n) for n in self.cfg.topics]
        self.types: dict[str, str] = {}
        self._qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                               history=HistoryPolicy.KEEP_ALL)
        # The data subscriptions live on a node that no executor spins: the take loop serves
        # them, at about four times the rate of rclpy's executor. Names are resolved
        # (remapped) by this node first.
        self._io = Node(f'_{self.get_name()}_io', namespace=self.get_namespace(),
                        context=self.context, use_global_arguments=False,
                        start_parameter_services=False)
        self._subs: list = []                        # (subscription, topic, stamped)
        self._clock_sub = self._io.create_subscription(
            _msg_class(SUITE_TYPES['/clock']), '/clock', lambda *_: None, self._qos, raw=True)
        for name, topic in zip(self.cfg.topics, self.topics):
            msgtype = SUITE_TYPES.get(name) or SUITE_TYPES.get(topic)
            if msgtype:
                self._add(topic, msgtype)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._discovery = self.create_timer(0.2, self._discover, clock=steady)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_service(Trigger, '~/ready', self._on_ready)
        self._halt = threading.Event()
        if self.cfg.autostart:
            try:
                self.start()
            except BagError as exc:
                raise bridge.StartupError([f'output = {self.cfg.output!r}: {ln}'
                                           for ln in exc.lines]) from None
        self._taker = threading.Thread(target=self._take_loop, name='take', daemon=True)
        self._taker.start()

    # ---- graph ---------------------------------------------------------------------------

    def _add(self, topic: str, msgtype: str) -> None:
        cls = _msg_class(msgtype)
        fields = list(cls.get_fields_and_field_types().items())
        stamped = bool(fields) and fields[0] == ('header', 'std_msgs/Header')
        sub = self._io.create_subscription(cls, topic, lambda *_: None, self._qos, raw=True)
        with self._lock:
            self.types[topic] = msgtype
            self._subs.append((sub, topic, stamped))

    def _discover(self) -> None:
        missing = [t for t in self.topics if t not in self.types]
        if missing:
            graph = dict(self.get_topic_names_and_types())
            for topic in missing:
                if topic in graph:
                    self._add(topic, graph[topic][0])
        with self._lock:
            s = self._session
            if s is not None and s.seq is not None:
                for topic in self.matched():
                    s.seq.matched(topic)

    def matched(self) -> list[str]:
        return [topic for sub, topic, _ in self._subs if sub.get_publisher_count() > 0]

    def single_publisher(self, topic: str) -> bool:
        return self._io.count_publishers(topic) == 1

    def offered_qos(self, topic: str) -> list[dict]:
        """The QoS of the topic's publishers, as rosbag2 records them."""
        return [_qos_dict(i.qos_profile) for i in self._io.get_publishers_info_by_topic(topic)]

    # ---- the take loop -------------------------------------------------------------------

    def _take_loop(self) -> None:
        batch = self.cfg.take_batch
        while not self._halt.is_set():
            with self._lock:
                req = self._stop_request
                if req is not None and not req[2]:
                    # Stop: first everything DDS has delivered, then nothing after it.
                    while self._take(10 ** 9) and time.monotonic() < req[0]:
                        pass
                    s = self._session
                    if s is not None and s.seq is not None:
                        s.stop_at = s.seq.time.latest
                    self._stop_request = req = (req[0], req[1], True)
                got = self._take(batch)
            if not got:
                time.sleep(0.0005)

    def _take(self, batch: int) -> int:
        """One round-robin pass over the subscriptions, ``/clock`` last; what it took."""
        got = 0
        s = self._session
        for sub, topic, stamped in self._subs:
            for _ in range(batch):
                taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    break
                got += 1
                if s is not None:
                    s.message(topic, stamped, *taken)
        for _ in range(batch):
            taken = self._clock_sub.handle.take_message(self._clock_sub.msg_type, True)
            if taken is None:
                break
            got += 1
            if s is not None:
                s = self._on_clock(s, *taken)
        if s is not None:
            self._advance(s)
        return got

    def _on_clock(self, s: _Session, data: bytes, info: dict) -> _Session:
        ns = _stamp(data)
        if s.seq is None:
            s.start_sequencer('sim')
        elif s.seq.mode == 'wall':
            return self._restart(s, 'a /clock appeared: the bag so far is in wall time, the '
                                    'next one in simulation time', ns, info)
        jump = s.seq.clock(ns, info['source_timestamp'])
        if jump is not None:
            return self._restart(s, jump.describe(), ns, info)
        return s

    def _restart(self, s: _Session, why: str, ns: int, info: dict) -> _Session:
        old = self._close(s, why)
        new = self._open()
        new.start_sequencer('sim')
        new.seq.clock(ns, info['source_timestamp'])
        self.get_logger().warn(f'{why}: closed {old}, recording to {new.path}')
        return new

    def _advance(self, s: _Session) -> None:
        req = self._stop_request
        if req is not None and not req[2]:
            req = None  # the stop has not swept the queues yet
        if s.seq is None:
            # Wall time only after clock_wait of messages with no /clock publisher: a
            # simulator's measurements may come before its /clock is discovered.
            if s.early and time.monotonic() - s.early[0][5] > self.cfg.clock_wait and \
                    self._io.count_publishers('/clock') == 0:
                s.start_sequencer('wall')
            elif req is not None:
                self._closed.append((self._close(s, 'stop'), s.writer.count))
                req[1].set()
            return
        s.seq.pass_done()
        s.write(s.seq.ready())
        if req is not None and (s.complete() or time.monotonic() > req[0]):
            self._closed.append((self._close(s, 'stop'), s.writer.count))
            req[1].set()

    # ---- start / stop --------------------------------------------------------------------

    def _open(self) -> _Session:
        out = self.get_parameter('output').value
        path = Path(out) if out else Path('bags') / f'recorder_{datetime.now():%Y%m%d-%H%M%S}'
        s = _Session(self, unique_path(path))
        self._session = s
        return s

    def _close(self, s: _Session, reason: str) -> Path:
        path = s.close(reason)
        self._session = None
        lost = sum(s.lost.values())
        self.get_logger().info(f'closed {path.resolve()}: {s.writer.count} messages'
                               + (f', {lost} LOST on the way' if lost else ''))
        return path

    def start(self) -> Path:
        with self._lock:
            if self._session is not None:
                return self._session.path
            s = self._open()
        self.get_logger().info(f'recording {len(self.topics)} topics to {s.path.resolve()}')
        return s.path

    def stop(self, limit: float = STOP_LIMIT) -> tuple[Path, int] | None:
        """Stop recording now; close once what was sent up to the latest /clock is in."""
        with self._lock:
            s = self._session
            if s is None:
                return None
            done = threading.Event()
            self._stop_request = (time.monotonic() + limit, done, False)
        if not (self._taker.is_alive() and done.wait(limit + 1.0)):
            with self._lock:
                if self._session is s:
                    self._closed.append((self._close(s, 'stop'), s.writer.count))
        with self._lock:
            self._stop_request = None
            return self._closed[-1] if self._closed else None

    def close(self) -> None:
        """SIGINT or SIGTERM: stop recording, close the bag, end the take loop."""
        self.stop()
        self._halt.set()
        self._taker.join(timeout=2.0)
        self._io.destroy_node()

    # ---- services and parameters ---------------------------------------------------------

    def _on_start(self, request, response):
        try:
            path = self.start()
        except BagError as exc:
            response.success, response.message = False, exc.lines[0]
            return response
        response.success, response.message = True, str(path)
        return response

    def _on_stop(self, request, response):
        done = self.stop()
        response.success = done is not None
        response.message = f'{done[0]} ({done[1]} messages)' if done else 'not recording'
        return response

    def _on_ready(self, request, response):
        """Ready when every recorded topic has a matched publisher: an experiment that
        starts after this loses nothing to discovery."""
        matched = set(self.matched())
        waiting = [t for t in self.topics if t not in matched]
        response.success = not waiting
        response.message = ('waiting for a publisher on ' + ', '.join(waiting) if waiting
                            else 'all topics matched')
        return response

    def _on_set_parameters(self, params):
        return bridge.result(bridge.refusal(self.schema_specs, params))

    def _publish_diagnostics(self) -> None:
        with self._lock:
            s = self._session
            values = {'recording': s is not None}
            if s is not None:
                lost = sum(s.lost.values())
                values.update({'bag': str(s.path), 'messages': s.writer.count,
                               'buffered': s.seq.buffered if s.seq else len(s.early),
                               'late': s.seq.late if s.seq else 0, 'lost': lost,
                               'time_base': s.seq.mode if s.seq else 'deciding'})
        lost = values.get('lost', 0)
        st = DiagnosticStatus(name='recorder', hardware_id='hydropump',
                              level=DiagnosticStatus.WARN if lost else DiagnosticStatus.OK,
                              message=f'{lost} messages lost' if lost else
                              ('recording' if values['recording'] else 'idle'),
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        self._pub_diag.publish(DiagnosticArray(status=[st]))


def main(args=None) -> int:
    return entry.run(RecorderNode, prog='recorder', doc=__doc__,
                     specs=lambda: specs_of(RecorderConfig), args=args)


if __name__ == '__main__':
    raise SystemExit(main())
