"""The ``recorder`` node: topics to rosbag2 bags (MCAP), in one clock, losing nothing.

The logic is pure (:mod:`hydropump_ctrl.recorder`): the :class:`Recorder` keeps the bags and
their time base, the sequencer gives every message its log time by the rule of time
(simulation time wherever a ``/clock`` is present, wall time only where none is) and writes
in log-time order behind a per-topic watermark, the bag writer writes what rosbag2 Jazzy
writes. This node takes the messages serialized, from a thread that serves every subscription
round-robin (a bounded batch per topic per pass, ``/clock`` last), and answers the
recorder's questions about the graph (types, matched publishers, their QoS).

- A jump back of simulation time (a new simulator) closes the bag and opens a new one; a
  ``/clock`` that appears under a bag recorded in wall time does the same. Each says so.
- Messages lost on the way (gaps in a publisher's sequence numbers) are counted, reported in
  ``/diagnostics`` and in the bag's ``custom_data``; never silent.
- ``~/stop``, SIGINT and SIGTERM drain: the bag gets what was published up to the ``/clock``
  of the request (or up to ``stop_time``), also what a lagging recorder has still to take or
  the publishers still to repair, within ``drain_timeout``; whatever of it is not written
  then is counted as lost (:mod:`hydropump_ctrl.recorder.session`). ``closed_by`` says how
  the bag was closed.
- The namespace's ``events`` topic (safe-current engagements, lock-step timeouts) is always
  recorded, whatever ``topics`` says, and counted in ``custom_data``.

- A topic name that is empty or invalid ends start-up with one ``error:`` line (exit code 2);
  a recorded topic that no publisher offers within :data:`TOPIC_GRACE` of start-up (or of
  ``~/start``) is reported (log and ``/diagnostics`` WARN), with the nearest known topic.
- A write that fails (disk full, a file-size limit, an I/O error) closes the bag with the
  chunks written before; ``/diagnostics`` says ERROR and why, ``~/stop`` answers false with
  the reason, and after :data:`FAIL_LINGER` the node exits with one line ``error: <bag>:
  <reason>`` and exit code :data:`EXIT_WRITE_ERROR` (3).

Services (``std_srvs/Trigger``): ``~/start`` opens a bag, ``~/stop`` closes it, ``~/ready``
answers whether every topic has a matched publisher.
"""

from __future__ import annotations

import contextlib
import importlib
import signal
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from hydropump_ctrl.recorder import (
    BagError,
    qos_profile,
    Recorder,
    RecorderConfig,
    SUITE_TYPES,
    unpublished_note,
)
from hydropump_ctrl.recorder.session import EVENTS_TYPE
from hydropump_sim.schema import spec_map, specs_of

from . import bridge, entry
from .conversions import CLOCK, ClockWriter, EVENT_KINDS, EVENTS

# The take loop's sleep after an empty pass: first, and at most [s].
IDLE_NAP = (0.0005, 0.004)

END_LIMIT = 30.0   # s: a stop waits this long for every topic to reach a given stop_time
# s after the drain's bound to take (not write) what is still queued, and count it.
COUNT_LIMIT = 0.25
# s after start-up or ~/start: a recorded topic with no publisher yet is reported (longer
# than a discovery that missed its first announcements, 3 s later in Fast DDS).
TOPIC_GRACE = 5.0
# s a recorder whose write failed stays up to say so (/diagnostics, ~/stop) before it exits.
FAIL_LINGER = 1.5
EXIT_WRITE_ERROR = 3


def _msg_class(msgtype: str):
    pkg, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


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


class RecorderNode(bridge.ExplainedParameters, Node):
    """Topics to rosbag2 bags (see the module)."""

    def __init__(self):
        super().__init__('recorder')
        self.cfg = bridge.declare(self, RecorderConfig)
        self.schema_specs = spec_map(RecorderConfig)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._lock = threading.RLock()
        # Threads waiting for the lock: the take loop, which takes it again at once while a
        # backlog lasts, steps aside for them (a lock is not fair: a stop could starve).
        self._waiting = 0
        self._count_lock = threading.Lock()
        self.types: dict[str, str] = {}
        self._pub_counts: dict[str, int] = {}
        topics = self._resolve(self.cfg.topics)
        self.exit_code = 0
        self._failure_said = False
        self._grace_from = time.monotonic()
        self._unpublished: dict[str, str] = {}       # topic -> what the log said of it
        # The topics a publisher is expected on: events always recorded, maybe silent.
        self._expected = list(topics)
        self.events = self.resolve_topic_name(EVENTS)
        if self.events not in topics:
            topics.append(self.events)
        self.rec = Recorder(self.cfg, topics, self, log=lambda lvl, txt: entry.log(
            self.get_logger(), lvl, txt), events=self.events, event_kinds=EVENT_KINDS)
        self._qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                               history=HistoryPolicy.KEEP_ALL)
        # The data subscriptions sit in a callback group that no executor serves: the take
        # loop serves them, at about four times the rate of rclpy's executor.
        self._unserved = entry.unserved_group()
        self._subs: list = []                        # (subscription, topic, stamped)
        self._clock_sub = self._raw(_msg_class(SUITE_TYPES['/clock']), CLOCK)
        for name, topic in zip(self.cfg.topics, topics):
            msgtype = SUITE_TYPES.get(name) or SUITE_TYPES.get(topic)
            if msgtype and topic != self.events:
                self._add(topic, msgtype)
        self._add(self.events, EVENTS_TYPE)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._writer = ClockWriter(self)
        self.create_timer(0.2, self._discover, clock=steady)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        self.create_service(Trigger, '~/start', self._on_start)
        self.create_service(Trigger, '~/stop', self._on_stop)
        self.create_service(Trigger, '~/ready', self._on_ready)
        self._halt = threading.Event()
        self._stopped = threading.Event()
        self._signal = self._name_signals()
        if self.cfg.autostart:
            try:
                self.rec.start()
            except BagError as exc:
                raise bridge.StartupError([f'output = {self.cfg.output!r}: {ln}'
                                           for ln in exc.lines]) from None
        self._taker = threading.Thread(target=self._take_loop, name='take', daemon=True)
        self._taker.start()

    def _resolve(self, names: list[str]) -> list[str]:
        """Resolved topic names; every invalid one an ``error:`` line at start-up."""
        out, bad = [], []
        for name in names:
            try:
                out.append(self.resolve_topic_name(name))
            except Exception as exc:  # rclpy raises RCLError, with no public class to catch
                why = ' '.join(str(exc).split(', at ')[0].split())
                bad.append(f'topics: {name!r} is not a valid topic name '
                           f'({why.removeprefix("failed to resolve name: ")})')
        if bad:
            raise bridge.StartupError(bad)
        return out

    # ---- the graph (the recorder asks) ---------------------------------------------------

    def _add(self, topic: str, msgtype: str) -> None:
        cls = _msg_class(msgtype)
        fields = list(cls.get_fields_and_field_types().items())
        stamped = bool(fields) and fields[0] == ('header', 'std_msgs/Header')
        sub = self._raw(cls, topic)
        with self._exclusive():
            self.types[topic] = msgtype
            self._subs.append((sub, topic, stamped))

    def _raw(self, cls, topic: str):
        return self.create_subscription(cls, topic, lambda *_: None, self._qos, raw=True,
                                        callback_group=self._unserved)

    def _discover(self) -> None:
        missing = [t for t in self.rec.topics if t not in self.types]
        if missing:
            graph = dict(self.get_topic_names_and_types())
            for topic in missing:
                if topic in graph:
                    self._add(topic, graph[topic][0])
        counts = {topic: self.count_publishers(topic) for topic in self.types}
        self._writer.refresh()
        with self._exclusive():
            self._pub_counts = counts
            self.rec.matched()
        self._check_publishers()

    def _check_publishers(self) -> None:
        """After the grace period, say once which recorded topics no publisher offers (a typo
        records nothing, silently otherwise), and when one comes."""
        if time.monotonic() - self._grace_from < TOPIC_GRACE:
            return
        matched = set(self.matched())
        known = None
        for topic in self._expected:
            if topic in matched:
                if self._unpublished.pop(topic, None):
                    self._log('info', f'{topic}: a publisher is there now')
            elif topic not in self._unpublished:
                if known is None:
                    known = {self.resolve_topic_name(n) for n in SUITE_TYPES}
                    known.update(n for n, _ in self.get_topic_names_and_types())
                self._unpublished[topic] = unpublished_note(topic, known, TOPIC_GRACE)
                self._log('warn', self._unpublished[topic])

    def _log(self, level: str, text: str) -> None:
        entry.log(self.get_logger(), level, text)

    @contextlib.contextmanager
    def _exclusive(self):
        """The lock, for any thread but the take loop's."""
        with self._count_lock:
            self._waiting += 1
        with self._lock:
            with self._count_lock:
                self._waiting -= 1
            yield

    def matched(self) -> list[str]:
        return [topic for sub, topic, _ in self._subs if sub.get_publisher_count() > 0]

    def publishers(self, topic: str) -> int:
        # Asked for every message: a graph query each time would slow the take loop (and
        # with it a lock-step run), so the discovery timer keeps the counts.
        return self._pub_counts.get(topic, 0)

    def offered_qos(self, topic: str) -> list[dict]:
        """The QoS of the topic's publishers, as rosbag2 records them."""
        return [_qos_dict(i.qos_profile) for i in self.get_publishers_info_by_topic(topic)]

    # ---- the take loop -------------------------------------------------------------------

    def _take_loop(self) -> None:
        batch = self.cfg.take_batch
        # Between empty passes the loop sleeps 0.5 ms, doubling up to 4 ms while nothing
        # comes: a graph that stands still (paused, between experiments) costs no CPU, and
        # a stream is never left more than 4 ms behind (its writers keep a second of it).
        # A stop changes nothing here: the loop takes on while the recorder drains.
        nap = IDLE_NAP[0]
        while not self._halt.is_set():
            with self._lock:
                rec = self.rec
                if rec.needs_count:
                    self._count_rest()
                got = self._take(batch)
                if not rec.stopping:
                    self._stopped.set()
                failed = rec.failed is not None
            if self._waiting:
                time.sleep(0.001)
            if failed:
                self._write_failed()
                return
            if got:
                nap = IDLE_NAP[0]
            else:
                time.sleep(nap)
                nap = min(2.0 * nap, IDLE_NAP[1])

    def _take(self, batch: int) -> int:
        """One round-robin pass over the subscriptions, ``/clock`` last; what it took."""
        got = 0
        rec = self.rec
        for sub, topic, stamped in self._subs:
            for _ in range(batch):
                taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    break
                got += 1
                rec.message(topic, stamped, *taken)
        for _ in range(batch):
            taken = self._clock_sub.handle.take_message(self._clock_sub.msg_type, True)
            if taken is None:
                break
            got += 1
            data, info = taken
            info['writer'] = self._writer.of(info['source_timestamp'])
            rec.clock(data, info)
        rec.advance(self.count_publishers(CLOCK) if rec.session and
                    rec.session.seq is None else 1)
        return got

    def _count_rest(self) -> None:
        """The drain's bound passed: take what is still queued, ``/clock`` first (the stop
        instant may lie in it), without writing it; the recorder counts what belonged in the
        bag as lost and closes it."""
        rec = self.rec
        end = time.monotonic() + COUNT_LIMIT
        clock = self._clock_sub
        while time.monotonic() < end:
            taken = clock.handle.take_message(clock.msg_type, True)
            if taken is None:
                break
            data, info = taken
            info['writer'] = self._writer.of(info['source_timestamp'])
            rec.clock(data, info)
        rec.settle_stop()
        for sub, topic, stamped in self._subs:
            while time.monotonic() < end:
                taken = sub.handle.take_message(sub.msg_type, True)
                if taken is None:
                    break
                rec.unwritten(topic, stamped, *taken)
        rec.counted()

    # ---- start / stop --------------------------------------------------------------------

    def stop(self, until: float = 0.0, reason: str = 'stop'):
        """Stop recording: at simulation time ``until`` [s] if given, else now (see
        :mod:`hydropump_ctrl.recorder.session`); ``reason`` is what ``closed_by`` says."""
        limit = END_LIMIT if until > 0.0 else self.rec.drain_timeout
        reason = 'stop_time' if until > 0.0 else reason
        wall = time.time_ns()  # the publishers' clock: what was sent before belongs in
        with self._exclusive():
            if not self.rec.request_stop(limit, int(round(until * 1e9)) if until else None,
                                         reason=reason, wall_ns=wall):
                return None
            self._stopped.clear()
        self._log('info', f'stopping ({reason}): taking what was published up to '
                          + (f'stop_time = {until:g} s' if until else 'now')
                          + f', at most {limit:g} s')
        if self._taker.is_alive():
            self._stopped.wait(limit + COUNT_LIMIT + 1.0)
        with self._exclusive():
            done = self.rec.finish_stop()
        if self.rec.failed is not None:
            self._write_failed()
        else:
            self._publish_diagnostics()
        return done

    def _name_signals(self) -> list[str]:
        """Note which signal ends the node (``closed_by``); the handlers ``entry`` installed
        still run after."""
        got: list[str] = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            before = signal.getsignal(sig)

            def handler(signum, frame, before=before):
                if not got:
                    got.append(signal.Signals(signum).name)
                if callable(before):
                    before(signum, frame)
            try:
                signal.signal(sig, handler)
            except ValueError:  # not the main thread (a node built in a test): no name
                break
        return got

    def _write_failed(self) -> None:
        """A write failed (the bag is closed with what it could keep): say so on
        /diagnostics now, and end the process after :data:`FAIL_LINGER`, so that a
        supervisor sees the exit code and the reason rather than a recorder that records
        nothing."""
        with self._exclusive():
            if self._failure_said:
                return
            self._failure_said = True
        self.exit_code = EXIT_WRITE_ERROR
        self._publish_diagnostics()
        timer = threading.Timer(FAIL_LINGER, entry.request_shutdown)
        timer.daemon = True
        timer.start()

    def close(self) -> None:
        """SIGINT or SIGTERM: stop recording, close the bag, end the take loop."""
        self.stop(reason=self._signal[0] if self._signal else 'shutdown')
        self._halt.set()
        self._taker.join(timeout=2.0)
        if self.rec.failed is not None:
            self.exit_code = EXIT_WRITE_ERROR
            print(f'error: {self.rec.failed}', file=sys.stderr, flush=True)

    # ---- services and parameters ---------------------------------------------------------

    def _on_start(self, request, response):
        try:
            with self._exclusive():
                path = self.rec.start()
        except BagError as exc:
            response.success, response.message = False, exc.lines[0]
            return response
        self._grace_from = time.monotonic()
        self._unpublished.clear()
        response.success, response.message = True, str(path)
        return response

    def _on_stop(self, request, response):
        done = self.stop(self.get_parameter('stop_time').value)
        failed = self.rec.failed
        response.success = done is not None and failed is None
        response.message = (f'recording failed: {failed}' if failed else
                            f'{done[0]} ({done[1]} messages)' if done else 'not recording')
        return response

    def _on_ready(self, request, response):
        """Ready when every recorded topic has a matched publisher: an experiment that
        starts after this loses nothing to discovery."""
        matched = set(self.matched())
        waiting = [t for t in self._expected if t not in matched]
        response.success = not waiting
        response.message = ('waiting for a publisher on ' + ', '.join(waiting) if waiting
                            else 'all topics matched')
        return response

    def _on_set_parameters(self, params):
        reason = bridge.refusal(self.schema_specs, params)
        if reason is None:
            for p in params:
                if p.name == 'output':
                    self.rec.output = p.value
        return bridge.result(reason)

    def _publish_diagnostics(self) -> None:
        with self._exclusive():
            values = self.rec.diagnostics()
            failed = self.rec.failed
        unpublished = list(self._unpublished.values())
        values['unpublished'] = ', '.join(self._unpublished)
        lost = values.get('lost', 0)
        last = values.get('last_bag_lost', 0)
        if failed is not None:
            level, message = DiagnosticStatus.ERROR, f'write failed: {failed.reason}'
        elif lost or last or unpublished:
            level = DiagnosticStatus.WARN
            message = '; '.join(([f'{lost} messages lost'] if lost else [])
                                + ([f'the last bag lost {last} messages'] if last else [])
                                + unpublished)
        else:
            level, message = DiagnosticStatus.OK, ('recording' if values['recording']
                                                   else 'idle')
        st = DiagnosticStatus(name='recorder', hardware_id='hydropump', level=level,
                              message=message,
                              values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
        self._pub_diag.publish(DiagnosticArray(status=[st]))


def main(args=None) -> int:
    return entry.run(RecorderNode, prog='recorder', doc=__doc__,
                     specs=lambda: specs_of(RecorderConfig), args=args)


if __name__ == '__main__':
    raise SystemExit(main())
