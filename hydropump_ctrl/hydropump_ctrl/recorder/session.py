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
- **Stop** (``~/stop``, SIGINT, SIGTERM): the caller first takes everything DDS has
  delivered (:meth:`Recorder.swept`). Given an end time (``stop_time``), the bag ends
  there, once every active topic has delivered up to it. Otherwise, if ``/clock`` then goes
  quiet (a paused simulator at the end of an experiment), the bag ends at the last
  ``/clock``, once every active topic has delivered up to it: what was still on its way is
  in. If ``/clock`` runs on (a paced
  run stopped by a signal), the bag ends at the ``/clock`` of the sweep: nothing after the
  signal. Either way it closes by the deadline.
- **A write that fails** (disk full, a file-size limit, an I/O error): the writer closes the
  bag with the chunks written before (:class:`~.bag.BagWriteError`); the recorder records
  nothing more, and :attr:`Recorder.failed` says why (the node reports it and exits).

The node passes a *graph* (the ROS side's answers: ``types`` by topic, ``matched()``,
``publishers(topic)``, ``offered_qos(topic)``) and takes the messages; everything else is
here, tested without DDS.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime
from pathlib import Path
import struct
import time
from typing import Any, Protocol

from .bag import BagError, BagWriteError, open_unique
from .sequencer import Sequencer


def header_stamp(data: bytes) -> int:
    """Stamp [ns] of a serialized (CDR) message that starts with a Header, or of a Clock."""
    little = data[1] == 1  # CDR encapsulation: 0x0001 little endian, 0x0000 big endian
    sec, nsec = struct.unpack_from('<iI' if little else '>iI', data, 4)
    return sec * 1_000_000_000 + nsec


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
        self.lost: dict[str, int] = {}
        self.stop_at: int | None = None         # sim ns: nothing after it is recorded
        self.sim_stamped = False                # a stamp far from wall time: sim time

    @property
    def messages(self) -> int:
        return self.writer.count

    def start_sequencer(self, mode: str) -> None:
        self.seq = Sequencer(self.rec.topics, mode, idle_timeout=self.rec.cfg.idle_timeout)
        # Now, not only at close: a bag closed by a write error says it too.
        self.writer.custom_data['time_base'] = 'simulation' if mode == 'sim' else 'wall'
        for topic in self.rec.graph.matched():
            self.seq.matched(topic)
        early, self.early = self.early, []
        for item in early:
            self._feed(*item[:5])

    def message(self, topic: str, stamped: bool, data: bytes, info: dict) -> None:
        seq_no = info.get('publication_sequence_number')
        if seq_no is not None and self.rec.graph.publishers(topic) == 1:
            last = self.last_pub.get(topic)
            if last is not None and seq_no > last + 1:
                self.lost[topic] = self.lost.get(topic, 0) + seq_no - last - 1
            self.last_pub[topic] = seq_no
        item = (topic, stamped, data, info, time.time_ns())
        if self.seq is None:
            if stamped and abs(header_stamp(data) - item[4]) > SIM_STAMP:
                self.sim_stamped = True
            self.early.append(item + (time.monotonic(),))
        else:
            self._feed(*item)

    def _feed(self, topic, stamped, data, info, received) -> None:
        stamp = header_stamp(data) if stamped else None
        if self.stop_at is not None and stamp is not None and stamp > self.stop_at:
            return  # after the stop
        self.seq.message(topic, data, source_ns=info['source_timestamp'], stamp_ns=stamp,
                         receive_ns=received)

    def write(self, records) -> None:
        w = self.writer
        sim = self.seq.mode == 'sim'
        for r in records:
            if self.stop_at is not None and sim and r.log_ns > self.stop_at:
                continue  # after the stop
            if r.topic not in w.topics:
                w.add_topic(r.topic, self.rec.graph.types[r.topic],
                            self.rec.graph.offered_qos(r.topic))
            # One clock in a bag: in simulation time the publish time is the log time too
            # (a wall-clock send time beside it would mix clocks, and differ between runs).
            w.write(r.topic, r.log_ns, r.data, r.log_ns if sim else r.publish_ns)

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
            self.writer.custom_data.update({
                'time_base': 'simulation' if self.seq.mode == 'sim' else 'wall',
                'messages_lost': str(sum(self.lost.values())),
                'messages_late': str(self.seq.late),
                'closed_by': reason})
            for topic, n in self.lost.items():
                self.writer.custom_data[f'lost.{topic}'] = str(n)
        return self.writer.close()


Log = Callable[[str, str], None]

# A stamp this far [ns] from the wall clock is simulation time (a day).
SIM_STAMP = 86_400 * 10 ** 9
# /clock silent this long [s] after a stop's sweep: the simulator is paused or gone.
QUIET = 0.2


class Recorder:
    """The recorder's sessions and their rules (see the module). Not thread-safe: the node
    calls it under one lock.

    Parameters
    ----------
    cfg : RecorderConfig
    topics : list of str
        The recorded topics (resolved names), in release order.
    graph : Graph
    log : callable(level, text)
    """

    def __init__(self, cfg: Any, topics: list[str], graph: Graph,
                 log: Log = lambda level, text: print(f'[{level}] {text}')):
        self.cfg = cfg
        self.topics = topics
        self.graph = graph
        self._log = log
        self.session: Session | None = None
        self.closed: list[tuple[Path, int]] = []
        self._stop: tuple[float, bool] | None = None   # (deadline, swept)
        self._sweep_clock: int | None = None           # latest /clock at the sweep
        self._last_clock = 0.0                          # steady time of the latest /clock
        self.output = cfg.output
        self.failed: BagWriteError | None = None        # a write failed: recording is over

    # ---- sessions ------------------------------------------------------------------------

    def start(self) -> Path:
        """Open a bag (:class:`~.bag.BagError` with the reason if it cannot be made)."""
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

    def _close(self, reason: str) -> tuple[Path, int]:
        s, self.session = self.session, None
        path = s.close(reason)
        lost = sum(s.lost.values())
        self._log('info', f'closed {path.resolve()}: {s.messages} messages'
                          + (f', {lost} LOST on the way' if lost else ''))
        self.closed.append((path, s.messages))
        return self.closed[-1]

    def _fail(self, exc: BagWriteError) -> None:
        """A write failed: the writer has closed the bag with what it could keep."""
        self.session, self._stop, self.failed = None, None, exc
        self.closed.append((exc.path, exc.messages))
        self._log('error', f'{exc}: recording stopped')

    def _restart(self, why: str, clock_ns: int, source_ns: int, sequence: int | None,
                 writer=None) -> None:
        old, _ = self._close(why)
        self.start()
        self.session.start_sequencer('sim')
        self.session.seq.clock(clock_ns, source_ns, sequence, writer)
        self._log('warn', f'{why}: closed {old}, recording to {self.session.path}')

    # ---- messages ------------------------------------------------------------------------

    def message(self, topic: str, stamped: bool, data: bytes, info: dict) -> None:
        if self.session is not None:
            self.session.message(topic, stamped, data, info)

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
        elif before is None or ns > before:
            self._last_clock = time.monotonic()

    def matched(self) -> None:
        """The graph's matched publishers changed (a periodic check)."""
        s = self.session
        if s is not None and s.seq is not None:
            for topic in self.graph.matched():
                s.seq.matched(topic)

    def advance(self, clock_publishers: int) -> None:
        """After each pass of the take loop: write what may be written, decide a bag's time
        base, finish a stop."""
        try:
            self._advance(clock_publishers)
        except BagWriteError as exc:
            self._fail(exc)

    def _advance(self, clock_publishers: int) -> None:
        s = self.session
        if s is None:
            return
        stopping = self._stop is not None and self._stop[1]
        now = time.monotonic()
        if s.seq is None:
            if s.early and now - s.early[0][5] > self.cfg.clock_wait and \
                    clock_publishers == 0 and not s.sim_stamped:
                s.start_sequencer('wall')
            elif stopping:
                self._close('stop')
            return
        s.seq.pass_done()
        if stopping and s.stop_at is None and s.seq.mode == 'sim':
            deadline = self._stop[0]
            if now - self._last_clock > QUIET:
                s.stop_at = s.seq.time.latest          # paused: up to its last /clock
            elif now > deadline - 2 * QUIET:
                s.stop_at = self._sweep_clock          # running on: up to the signal
        s.write(s.seq.ready())
        if stopping and (s.stop_at is not None and s.complete() or now > self._stop[0]):
            self._close('stop')

    # ---- stop ----------------------------------------------------------------------------

    def request_stop(self, limit: float, until_ns: int | None = None) -> bool:
        """Begin a stop that ends within ``limit`` s, at simulation time ``until_ns`` if
        given (see the module otherwise); ``False`` if not recording."""
        if self.session is None:
            return False
        self._stop = (time.monotonic() + limit, False)
        self.session.stop_at = until_ns
        return True

    @property
    def needs_sweep(self) -> bool:
        """A stop waits for the caller to take everything DDS has delivered."""
        return self._stop is not None and not self._stop[1]

    @property
    def stop_deadline(self) -> float:
        return self._stop[0] if self._stop else 0.0

    def swept(self) -> None:
        """Everything DDS had delivered is taken (see the module for what follows)."""
        s = self.session
        self._sweep_clock = s.seq.time.latest if s is not None and s.seq is not None else None
        self._stop = (self._stop[0], True)

    def finish_stop(self) -> tuple[Path, int] | None:
        """End a stop (closing now if the take loop did not); the bag closed, if any
        (``None`` if a write failed: see :attr:`failed`)."""
        if self.session is not None and self._stop is not None:
            try:
                self._close('stop')
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
                           'late': s.seq.late if s.seq else 0, 'lost': sum(s.lost.values()),
                           'time_base': s.seq.mode if s.seq else 'deciding'})
        return values
