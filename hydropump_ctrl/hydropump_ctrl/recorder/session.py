"""What the recorder node does with the messages it takes, without ROS: :class:`Recorder`.

- **One bag at a time** (:class:`Session`): its writer, its :class:`~.sequencer.Sequencer`
  once the time base is known, and the losses counted from the publishers' sequence numbers
  (a gap is a message lost on the way; reported, never silent).
- **The time base of a bag**: simulation time from the first ``/clock``; wall time only once
  messages have come for ``clock_wait`` with no ``/clock`` publisher in the graph and none
  of them stamped in simulation time (a controller's state may arrive before the
  simulator, or its ``/clock``, is discovered). A ``/clock`` under
  a wall-time bag, or simulation time going back (a new simulator), closes the bag and opens
  the next one; the log says why.
- **Stop** (``~/stop``, SIGINT, SIGTERM) **drains**: the take loop goes on taking while the
  bag waits for what was published up to the stop and is still on its way (queued in DDS,
  or repaired by the publishers after a stall of the recorder). The stop's *instant* is the
  latest ``/clock`` published at or before the request, by the publishers' source
  timestamps (the rule of time), however far behind the recorder is: a paced run stopped by
  a signal ends there, nothing after it. If ``/clock`` goes quiet instead (a paused
  simulator at the end of an experiment), the bag ends at the last ``/clock``. Given an end
  time (``stop_time``), the bag ends there. The bag closes once no topic is behind that
  instant (:meth:`~.sequencer.Sequencer.behind`: a topic that stalls is waited for), and at
  the latest after the drain's bound (``drain_timeout``, default :data:`DRAIN_TIMEOUT`;
  ``stop_time`` stops pass their own, longer one). At the bound the caller takes
  what is still queued without writing it (:meth:`Recorder.unwritten`): whatever belonged in
  the bag is counted as lost, and so is each topic's missing tail up to the stop instant,
  estimated from its rate; ``custom_data.drain`` says so.
- **What the bag tells** (``custom_data``): ``time_base``; ``messages_lost`` and
  ``lost.<topic>``; ``messages_late``; ``closed_by`` (``stop``, ``stop_time``, ``SIGINT``,
  ``SIGTERM``, a new simulator, a write error); ``drain`` (``complete`` or cut at the bound);
  and ``events.<kind>`` with ``events.<kind>.first`` (simulation time [s] of the first) for
  every event of the ``events`` topic (``diagnostic_msgs/DiagnosticArray``, one status per
  event, named by its kind): the controller's safe-current engagements and the simulator's
  lock-step timeouts; ``ended.<topic>`` (simulation time [s] of its last message) for a
  periodic topic that stopped well before the bag's end while its publisher was still in
  the graph (:meth:`Session.ended`). A fit reads these (:mod:`hydropump_ctrl.ident.plausibility`;
  an ended topic is a note of the reader, :mod:`hydropump_ctrl.bag.reader`).
- **A write that fails** (disk full, a file-size limit, an I/O error): the writer closes the
  bag with the chunks written before (:class:`~.bag.BagWriteError`); the recorder records
  nothing more, and :attr:`Recorder.failed` says why (the node reports it and exits).

The node passes a *graph* (the ROS side's answers: ``types`` by topic, ``matched()``,
``publishers(topic)``, ``offered_qos(topic)``) and takes the messages; everything else is
here, tested without DDS.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
import struct
import time
from typing import Any, Protocol

from ..bag import BagError, BagWriteError, open_unique, typestore
from .sequencer import Sequencer

#: s: the default bound of a stop's drain (``RecorderConfig.drain_timeout``).
DRAIN_TIMEOUT = 2.0
#: The message type of the ``events`` topic: a stamped array, one status per event.
EVENTS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'


def header_stamp(data: bytes) -> int:
    """Stamp [ns] of a serialized (CDR) message that starts with a Header, or of a Clock."""
    little = data[1] == 1  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
    sec, nsec = struct.unpack_from('<iI' if little else '>iI', data, 4)
    return sec * 1_000_000_000 + nsec


def event_names(data: bytes) -> list[str]:
    """The kinds of the events of one serialized ``events`` message (its statuses' names)."""
    try:
        msg = typestore().deserialize_cdr(data, EVENTS_TYPE)
    except Exception:  # noqa: BLE001 - a foreign message on the topic is one unknown event
        return ['unreadable']
    return [st.name or 'unnamed' for st in msg.status]


class Graph(Protocol):
    types: dict[str, str]

    def matched(self) -> list[str]: ...

    def publishers(self, topic: str) -> int: ...

    def offered_qos(self, topic: str) -> list[dict]: ...


class Session:
    """One open bag (see the module)."""

    def __init__(self, rec: Recorder, path: Path):
        cfg = rec.cfg
        self.rec = rec
        self.writer = open_unique(path, compression=cfg.compression,
                                  chunk_period=cfg.flush_period)
        self.path = self.writer.path
        self.seq: Sequencer | None = None
        self.early: list = []                   # messages before the time base is known
        self.last_pub: dict[str, int] = {}      # topic -> last publication sequence number
        self.lost: dict[str, int] = {}          # gaps, and what a cut drain left unwritten
        self.estimated: dict[str, int] = {}     # of which estimated from a topic's rate
        self.stop_at: int | None = None         # sim ns: nothing after it is recorded
        self.stop_wall: int | None = None       # wall ns: published after it is after a stop
        self.sim_stamped = False                # a stamp far from wall time: sim time
        self.events: dict[str, list] = {name: [0, None] for name in rec.event_kinds}
        self.last_src: dict[str, int] = {}      # topic -> its latest source timestamp [ns]
        self.counted: dict[str, int] = {}       # topic -> latest log time counted as lost
        self.ended_at: dict[str, int] = {}      # topic -> its last log time, if it ended early
        self._channels = False                  # the first channels registered

    @property
    def messages(self) -> int:
        return self.writer.count

    def start_sequencer(self, mode: str) -> None:
        rec = self.rec
        self.seq = Sequencer(rec.topics, mode, idle_timeout=rec.cfg.idle_timeout,
                             sparse=[rec.events] if rec.events else ())
        # Now, not only at close: a bag closed by a write error says it too.
        self.writer.custom_data['time_base'] = 'simulation' if mode == 'sim' else 'wall'
        for topic in rec.graph.matched():
            self.seq.matched(topic)
        early, self.early = self.early, []
        for item in early:
            self._feed(*item[:5])

    def _sequence(self, topic: str, info: dict) -> None:
        """Count a gap in the publisher's sequence numbers as messages lost on the way."""
        seq_no = info.get('publication_sequence_number')
        if seq_no is not None and self.rec.graph.publishers(topic) == 1:
            last = self.last_pub.get(topic)
            if last is not None and seq_no > last + 1:
                self.lost[topic] = self.lost.get(topic, 0) + seq_no - last - 1
            self.last_pub[topic] = seq_no

    def message(self, topic: str, stamped: bool, data: bytes, info: dict) -> None:
        self._sequence(topic, info)
        self.last_src[topic] = info['source_timestamp']
        item = (topic, stamped, data, info, time.time_ns())
        if self.seq is None:
            if stamped and abs(header_stamp(data) - item[4]) > SIM_STAMP:
                self.sim_stamped = True
            self.early.append(item + (time.monotonic(),))
        else:
            self._feed(*item)

    def _feed(self, topic, stamped, data, info, received) -> None:
        src = info['source_timestamp']
        if self.seq.mode == 'wall' and self.stop_wall is not None and src > self.stop_wall:
            return  # published after the stop
        stamp = header_stamp(data) if stamped else None
        if self.stop_at is not None and stamp is not None and stamp > self.stop_at:
            return  # after the stop
        self.seq.message(topic, data, source_ns=src, stamp_ns=stamp, receive_ns=received)

    def write(self, records) -> None:
        w = self.writer
        sim = self.seq.mode == 'sim'
        events = self.rec.events
        if records and not self._channels:
            # Channels in the recorded topics' order, not in the order of the first arrivals
            # (which differ between runs): the same run gives the same bytes. A topic whose
            # publishers discovery has not reported yet (a recorder started into a running
            # graph) waits for its first message, by which its publishers are known: a
            # channel's QoS cannot change once written.
            self._channels = True
            self.register(lambda qos: bool(qos))
        for r in records:
            if self.stop_at is not None and sim and r.log_ns > self.stop_at:
                continue  # after the stop
            if r.topic not in w.topics:
                w.add_topic(r.topic, self.rec.graph.types[r.topic],
                            self.rec.graph.offered_qos(r.topic))
            # One clock in a bag: in simulation time the publish time is the log time too
            # (a wall-clock send time beside it would mix clocks, and differ between runs).
            w.write(r.topic, r.log_ns, r.data, r.log_ns if sim else r.publish_ns)
            if r.topic == events:
                for name in event_names(r.data):
                    seen = self.events.setdefault(name, [0, None])
                    seen[0] += 1
                    seen[1] = r.log_ns if seen[1] is None else min(seen[1], r.log_ns)

    # ---- a drain cut at its bound --------------------------------------------------------

    def unwritten(self, topic: str, stamped: bool, data: bytes, info: dict, until: bool
                  ) -> None:
        """A message taken after the drain's bound: lost if it belonged in the bag (at or
        before the stop instant; for a stop without ``stop_time`` (``until`` false) also
        published at or before the request)."""
        self._sequence(topic, info)
        src = info['source_timestamp']
        if self.seq is None or self.seq.mode == 'wall':
            log = src
            belongs = self.stop_wall is None or src <= self.stop_wall
        else:
            log = header_stamp(data) if stamped else self.seq.time.time_of(src)
            belongs = (log is not None and self.stop_at is not None and log <= self.stop_at
                       and (until or src <= self.stop_wall))
        if belongs:
            self.lost[topic] = self.lost.get(topic, 0) + 1
            if topic != self.rec.events:
                self.counted[topic] = max(self.counted.get(topic, log), log)

    def estimate_tails(self, since: float) -> None:
        """Count as lost, per topic still behind the stop instant (see
        :meth:`~.sequencer.Sequencer.behind`), the messages between its latest one (written,
        held or counted) and the stop instant that never arrived, from its period."""
        if self.seq is None or self.seq.mode == 'wall' or self.stop_at is None:
            return
        for topic, mark in self.seq.behind(self.stop_at, QUIET, since).items():
            period = self.seq.period(topic)
            if mark is None or not period:
                continue
            last = max(mark, self.counted.get(topic, mark))
            n = (self.stop_at - last) // period
            if n > 0:
                self.estimated[topic] = n
                self.lost[topic] = self.lost.get(topic, 0) + n

    def ended(self) -> dict[str, int]:
        """The topics that stopped well before the bag's end (its stop instant or its latest
        /clock, the earlier) while their publisher is still in the graph, with the log time [ns]
        of their last message. Either the publisher stopped, or DDS had still to repair
        samples the recorder missed when the stop took the silent topic as ended (a
        publisher with Fast DDS's 3 s heartbeat, docs/ros.md): the bag says so, either way."""
        seq = self.seq
        if seq is None or seq.mode != 'sim':
            return {}
        # No later than the latest /clock taken: nothing is due after it.
        ends = [t for t in (self.stop_at, seq.time.latest) if t is not None and t >= 0]
        if not ends:
            return {}
        end = min(ends)
        return {t: m for t, m in seq.ended(end, ENDED_PERIODS, ENDED_SPAN).items()
                if self.rec.graph.publishers(t) > 0}

    def untimed(self) -> int:
        """Drop the messages that came before any ``/clock`` in a graph that has one (they
        cannot be placed in simulation time); count those published before the stop as
        lost. Returns how many were lost."""
        n = 0
        for topic, _, _, info, *_ in self.early:
            if self.stop_wall is None or info['source_timestamp'] <= self.stop_wall:
                self.lost[topic] = self.lost.get(topic, 0) + 1
                n += 1
        self.early = []
        return n

    def register(self, ready: Callable[[list[dict]], bool]) -> None:
        """Channels for the recorded topics of known type whose offered QoS ``ready``
        accepts, in the recorded topics' order."""
        graph = self.rec.graph
        for t in self.rec.topics:
            if t in graph.types and t not in self.writer.topics:
                qos = graph.offered_qos(t)
                if ready(qos):
                    self.writer.add_topic(t, graph.types[t], qos)

    # ---- close ---------------------------------------------------------------------------

    def close(self, reason: str, drain: str | None = None,
              keep: Callable[[str, int], bool] | None = None) -> Path:
        if self.seq is None and self.early:
            self.start_sequencer('wall')
        cd = self.writer.custom_data
        if self.seq is not None:
            self.write(self.seq.drain(keep))
            self.ended_at = self.ended()
            for topic, mark in self.ended_at.items():
                cd[f'ended.{topic}'] = f'{mark * 1e-9:.6f}'
            cd.update({
                'time_base': 'simulation' if self.seq.mode == 'sim' else 'wall',
                'messages_late': str(self.seq.late)})
            for topic, n in self.seq.untimed.items():   # their /clock was lost: lost too
                self.lost[topic] = self.lost.get(topic, 0) + n
        cd.update({'messages_lost': str(sum(self.lost.values())), 'closed_by': reason})
        if drain is not None:
            cd['drain'] = drain
        for topic, n in self.lost.items():
            cd[f'lost.{topic}'] = str(n)
        for name, (n, first) in self.events.items():
            cd[f'events.{name}'] = str(n)
            if first is not None:
                cd[f'events.{name}.first'] = f'{first * 1e-9:.6f}'
        if self._channels:
            self.register(lambda qos: True)  # the topics that sent nothing: listed too
        return self.writer.close()


Log = Callable[[str, str], None]

# A stamp this far [ns] from the wall clock is simulation time (a day).
SIM_STAMP = 86_400 * 10 ** 9
# s of the take loop's running time with nothing new: nothing more is on its way (longer than
# two heartbeats of the publishers, config/fastdds.xml, which bring a stalled reader's
# repairs); /clock that quiet during a stop: the simulator is paused or gone.
QUIET = 0.3
# s of no new /clock after which a stop at a ``stop_time`` the run has not reached takes the
# run as stopped short of it (paused earlier, ended): the bag ends at its latest /clock. Far
# longer than QUIET: a lock-step run waiting for a slow controller is not a stopped one.
SHORT_OF_STOP_TIME = 2.0
# A topic whose last message lies this many of its periods, and this much simulation time
# [ns], before the bag's end has stopped (Session.ended): a message or two short of a stop is
# its edge, not an end.
ENDED_PERIODS = 10
ENDED_SPAN = 100_000_000
# s: a pass of the take loop later than this after the previous one is a stall of the
# recorder; silence counts at most this much of it.
STALL = 0.05


@dataclass
class _Stop:
    """A stop under way (see the module)."""

    deadline: float           # steady s: the drain's bound
    wall: int                 # wall ns of the request
    until: int | None         # sim ns of stop_time, if given
    reason: str
    since: float              # steady s of the request
    clock_quiet: float = 0.0  # running s since the request with no new /clock
    idle: float = 0.0         # running s since the request with nothing taken
    last_pass: float | None = None
    cut: bool = False         # the bound came first: the caller counts what is left
    short: str = ''           # the run stopped short of stop_time: where, in words

    def tick(self, now: float) -> None:
        if self.last_pass is not None:
            dt = min(now - self.last_pass, STALL)
            self.clock_quiet += dt
            self.idle += dt
        self.last_pass = now


class Recorder:
    """The recorder's sessions and their rules (see the module). Not thread-safe: the node
    calls it under one lock.

    Parameters
    ----------
    cfg : RecorderConfig
    topics : list of str
        The recorded topics (resolved names), in release order (``events`` among them).
    graph : Graph
    log : callable(level, text)
    events : str, optional
        The resolved name of the ``events`` topic (sparse; its events counted).
    event_kinds : sequence of str
        Event kinds whose count every bag states, 0 included.
    """

    def __init__(self, cfg: Any, topics: list[str], graph: Graph,
                 log: Log = lambda level, text: print(f'[{level}] {text}'), *,
                 events: str | None = None, event_kinds: Sequence[str] = ()):
        self.cfg = cfg
        self.topics = topics
        self.graph = graph
        self.events = events
        self.event_kinds = tuple(event_kinds)
        self._log = log
        self.session: Session | None = None
        self.closed: list[tuple[Path, int]] = []
        self.last: dict[str, Any] = {}                  # what the latest closed bag told
        self._stop: _Stop | None = None
        self._clock_publishers = 0
        self.output = cfg.output
        self.failed: BagWriteError | None = None        # a write failed: recording is over

    @property
    def drain_timeout(self) -> float:
        """The bound of a stop's drain [s]."""
        return self.cfg.drain_timeout

    # ---- sessions ------------------------------------------------------------------------

    def start(self) -> Path:
        """Open a bag (:class:`~hydropump_ctrl.bag.BagError` with the reason if it cannot be
        made)."""
        if self.failed is not None:
            raise BagError(f'recording failed: {self.failed}')
        if self.session is None:
            out = self.output
            path = Path(out) if out else (Path('bags')
                                          / f'recorder_{datetime.now():%Y%m%d-%H%M%S}')
            self.session = Session(self, path)
            self._log('info', f'recording {len(self.topics)} topics to '
                              f'{self.session.path.resolve()}')
        return self.session.path

    def _close(self, reason: str, drain: str | None = None,
               keep: Callable[[str, int], bool] | None = None) -> tuple[Path, int]:
        s, self.session = self.session, None
        path = s.close(reason, drain, keep)
        lost = sum(s.lost.values())
        events = {k: n for k, (n, _) in s.events.items() if n}
        if s.ended_at:
            self._log('warn', 'these topics stopped before the bag ended, their publishers '
                      'still in the graph: ' + ', '.join(f'{t} at t = {ns * 1e-9:g} s'
                                                         for t, ns in s.ended_at.items())
                      + ' (a publisher that stopped, or one whose missed samples DDS had yet '
                      'to repair: docs/ros.md)')
        self._log('warn' if lost or events else 'info',
                  f'closed {path.resolve()}: {s.messages} messages'
                  + (f', {lost} LOST' + (' (the drain was cut at its bound)'
                                         if drain and drain.startswith('cut') else '')
                     if lost else '')
                  + ''.join(f', {n} {k} events' for k, n in events.items()))
        self.closed.append((path, s.messages))
        self.last = {'last_bag': str(path), 'last_bag_messages': s.messages,
                     'last_bag_lost': lost, 'last_bag_closed_by': reason,
                     **({'last_bag_drain': drain} if drain else {}),
                     **{f'last_bag_events.{k}': n for k, n in events.items()}}
        return self.closed[-1]

    def _fail(self, exc: BagWriteError) -> None:
        """A write failed: the writer has closed the bag with what it could keep."""
        self.session, self._stop, self.failed = None, None, exc
        self.closed.append((exc.path, exc.messages))
        self._log('error', f'{exc}: recording stopped')

    def _restart(self, why: str, clock_ns: int, source_ns: int, sequence: int | None,
                 writer=None) -> None:
        if self._stop is not None:
            # The recording is ending: the new simulator's time goes in no bag.
            self._finish(why)
            return
        old, _ = self._close(why)
        self.start()
        self.session.start_sequencer('sim')
        self.session.seq.clock(clock_ns, source_ns, sequence, writer)
        self._log('warn', f'{why}: closed {old}, recording to {self.session.path}')

    # ---- messages ------------------------------------------------------------------------

    def message(self, topic: str, stamped: bool, data: bytes, info: dict) -> None:
        if self.session is not None:
            self.session.message(topic, stamped, data, info)
            if self._stop is not None:
                self._stop.idle = 0.0

    def clock(self, data: bytes, info: dict) -> None:
        try:
            self._clock(data, info)
        except BagWriteError as exc:
            self._fail(exc)

    def _clock(self, data: bytes, info: dict) -> None:
        s = self.session
        if s is None:
            return
        ns, src = header_stamp(data), info['source_timestamp']
        seq_no, writer = info.get('publication_sequence_number'), info.get('writer')
        if s.seq is None:
            s.start_sequencer('sim')
        elif s.seq.mode == 'wall':
            self._restart('a /clock appeared: the bag so far is in wall time, the next one in '
                          'simulation time', ns, src, seq_no, writer)
            return
        before = s.seq.time.latest
        jump = s.seq.clock(ns, src, seq_no, writer)
        if jump is not None:
            self._restart(jump.describe(), ns, src, seq_no, writer)
        elif (before is None or ns > before) and self._stop is not None:
            self._stop.clock_quiet = self._stop.idle = 0.0

    def matched(self) -> None:
        """The graph's matched publishers changed (a periodic check)."""
        s = self.session
        if s is not None and s.seq is not None:
            for topic in self.graph.matched():
                s.seq.matched(topic)

    def advance(self, clock_publishers: int) -> None:
        """After each pass of the take loop: write what may be written, decide a bag's time
        base, end a stop."""
        try:
            self._advance(clock_publishers)
        except BagWriteError as exc:
            self._fail(exc)

    def _advance(self, clock_publishers: int) -> None:
        s, st = self.session, self._stop
        if s is None:
            return
        self._clock_publishers = clock_publishers
        now = time.monotonic()
        if st is not None:
            st.tick(now)
        if s.seq is None:
            if s.early and now - s.early[0][5] > self.cfg.clock_wait and \
                    clock_publishers == 0 and not s.sim_stamped:
                s.start_sequencer('wall')
            elif st is not None:
                self._undecided_stop(s, st, now)
            return
        s.seq.pass_done()
        if st is not None and st.until is not None and s.seq.mode == 'sim' and \
                st.clock_quiet >= SHORT_OF_STOP_TIME and not st.short:
            latest = s.seq.time.latest
            if latest is not None and latest < s.stop_at:
                # Never reached: the bag ends where the run did, and nothing after it was
                # lost (no tail is estimated up to a stop_time nobody published).
                st.short = (f'the run stopped at t = {latest / 1e9:.6g} s, before stop_time '
                            f'= {st.until / 1e9:.6g} s: the bag ends there')
                s.stop_at = latest
        if st is not None and s.stop_at is None and s.seq.mode == 'sim':
            s.stop_at = self._stop_instant(s, st)
            if s.stop_at is None:
                # Not known yet: write nothing that could lie after it.
                if now > st.deadline:
                    st.cut = True
                return
        s.write(s.seq.ready())
        if st is None:
            return
        if self._drained(s, st):
            self._finish(st.reason, f'complete; {st.short}' if st.short else 'complete')
        elif now > st.deadline:
            st.cut = True

    def _undecided_stop(self, s: Session, st: _Stop, now: float) -> None:
        """A stop before the bag's time base is known."""
        if s.early and self._clock_publishers == 0 and not s.sim_stamped:
            s.start_sequencer('wall')   # no /clock in the graph: nothing to wait for
        elif not s.early and st.idle >= QUIET:
            self._finish(st.reason, 'complete')   # nothing came, nothing is coming
        elif now > st.deadline:
            st.cut = True   # the caller counts what is left; what came is untimed

    def _stop_instant(self, s: Session, st: _Stop) -> int | None:
        """Simulation time [ns] of a stop: ``stop_time``; the latest /clock published at or
        before the request, once a later one has come; the latest /clock once /clock is
        quiet; ``None`` while neither is known."""
        if st.until is not None:
            return st.until
        tb = s.seq.time
        if tb.latest_source is not None and tb.latest_source > st.wall:
            t = tb.time_of(st.wall)
            return t if t is not None else -1   # the first /clock came after the stop
        if st.clock_quiet >= QUIET:
            return tb.latest
        return None

    def _drained(self, s: Session, st: _Stop) -> bool:
        """Has everything that belongs in the bag been taken?"""
        if s.seq.mode == 'wall':
            if st.until is not None:
                return True   # a stop_time is simulation time: a wall-time bag ends now
            # Every topic has sent something after the request, or is quiet.
            return all(s.last_src.get(t, -1) > st.wall or s.seq.silent(t, st.since) >= QUIET
                       for t in self.topics if t != self.events)
        return not s.seq.behind(s.stop_at, QUIET, st.since)

    def _keep(self, s: Session, st: _Stop | None) -> Callable[[str, int], bool] | None:
        """Which unstamped messages still waiting for a later /clock a closing bag keeps
        (:meth:`Sequencer.drain`)."""
        if st is None or st.until is not None or s.seq is None or s.seq.mode != 'sim':
            return None
        tb = s.seq.time
        if tb.latest_source is not None and tb.latest_source > st.wall:
            return lambda topic, src: False   # sent after a /clock after the stop: after it
        if st.clock_quiet >= QUIET and not st.cut:
            return None                        # paused: the latest /clock is theirs

        def keep(topic: str, src: int) -> bool:
            # Their /clock may not have come: their time is unknown, lost if sent before.
            if src <= st.wall:
                s.lost[topic] = s.lost.get(topic, 0) + 1
            return False
        return keep

    def _finish(self, reason: str, drain: str | None = None, early: bool = False) -> None:
        """Close the bag of a stop; ``early``: before the drain decided (the waiting
        messages then take the latest /clock, as if it were quiet)."""
        s, st = self.session, self._stop
        self._stop = None
        if s is None:
            return
        if st is not None and s.seq is None and s.early and (self._clock_publishers or
                                                             s.sim_stamped):
            s.untimed()
        self._close(reason, drain, None if early else self._keep(s, st))

    # ---- stop ----------------------------------------------------------------------------

    def request_stop(self, limit: float, until_ns: int | None = None, *, reason: str = 'stop',
                     wall_ns: int | None = None) -> bool:
        """Begin a stop that ends within ``limit`` s (the drain's bound), at simulation time
        ``until_ns`` if given (see the module otherwise); ``wall_ns`` is the wall time of
        the request (default now), ``reason`` what ``closed_by`` will say. ``False`` if not
        recording."""
        if self.session is None:
            return False
        now = time.monotonic()
        wall = time.time_ns() if wall_ns is None else wall_ns
        self._stop = _Stop(now + limit, wall, until_ns, reason, now)
        self.session.stop_at = until_ns
        self.session.stop_wall = None if until_ns is not None else wall
        return True

    @property
    def needs_count(self) -> bool:
        """The drain's bound passed first: the caller takes what is still queued and hands
        it to :meth:`unwritten`, then calls :meth:`counted`."""
        return self._stop is not None and self._stop.cut and self.session is not None

    def settle_stop(self) -> None:
        """At the bound, with every queued /clock taken: fix the stop instant from what is
        known (the latest /clock published at or before the request)."""
        s, st = self.session, self._stop
        if s is None or st is None or s.seq is None or s.seq.mode != 'sim' or \
                s.stop_at is not None:
            return
        tb = s.seq.time
        t = tb.time_of(st.wall)
        s.stop_at = t if t is not None else -1

    def unwritten(self, topic: str, stamped: bool, data: bytes, info: dict) -> None:
        """A message taken after the drain's bound: not written; lost if it belonged in
        the bag."""
        s, st = self.session, self._stop
        if s is not None and st is not None:
            s.unwritten(topic, stamped, data, info, st.until is not None)

    def counted(self) -> None:
        """After :meth:`unwritten`: estimate the tails that never arrived, close the bag."""
        s, st = self.session, self._stop
        if s is None or st is None:
            return
        try:
            if s.seq is not None:
                self.settle_stop()
                s.write(s.seq.ready())
                s.estimate_tails(st.since)
            bound = f'{self.drain_timeout:g} s' if st.until is None else 'its bound'
            estimated = sum(s.estimated.values())
            drain = (f'cut after {bound}: what was still on its way is counted as lost'
                     + (f' ({estimated} of them estimated from the rates of '
                        f'{", ".join(sorted(s.estimated))})' if estimated else ''))
            self._finish(st.reason, drain)
        except BagWriteError as exc:
            self._fail(exc)

    def finish_stop(self) -> tuple[Path, int] | None:
        """End a stop (closing now if the take loop did not); the bag closed, if any
        (``None`` if a write failed: see :attr:`failed`)."""
        if self.session is not None and self._stop is not None:
            try:
                self._finish(self._stop.reason, 'closed before it ended', early=True)
            except BagWriteError as exc:
                self._fail(exc)
        self._stop = None
        if self.failed is not None:
            return None
        return self.closed[-1] if self.closed else None

    @property
    def stopping(self) -> bool:
        return self._stop is not None and self.session is not None

    def diagnostics(self) -> dict[str, Any]:
        s = self.session
        values: dict[str, Any] = {'recording': s is not None}
        if self.failed is not None:
            values.update({'bag': str(self.failed.path), 'messages': self.failed.messages,
                           'error': self.failed.reason})
        if s is not None:
            values.update({'bag': str(s.path), 'messages': s.messages,
                           'buffered': s.seq.buffered if s.seq else len(s.early),
                           'late': s.seq.late if s.seq else 0,
                           'lost': sum(s.lost.values()) + (sum(s.seq.untimed.values())
                                                           if s.seq else 0),
                           'time_base': s.seq.mode if s.seq else 'deciding'})
            values.update({f'events.{k}': n for k, (n, _) in s.events.items()})
        values.update(self.last)
        return values
