"""The recorder's ordering: every message gets one log time, and leaves in log-time order.

Log time follows the rule of time (:mod:`hydropump_ctrl.timebase`): in simulation time
wherever a ``/clock`` is present (stamped messages: their header stamp; unstamped ones: the
``/clock`` their publisher had sent before them; one sent before the bag's first ``/clock``
belongs to that one if it is the simulator's very first (a command sent ahead of the first
step), else to a step before the bag, and is left out), in receive wall time only where
there is none; never a mix.

Messages are released in ``(log time, topic, arrival)`` order, the topics in the order the
recorder lists them, so two identical lock-step runs give byte-identical bags however the
messages arrived. A message at log time ``T`` is released only once every recorded topic
that is *active* has delivered something at or after ``T`` (a per-topic watermark): a topic
is active from the moment it has a matched publisher (or its first message) until it has been
silent for ``idle_timeout`` of steady time while the recorder was running. Time the recorder
itself was stopped (frozen, starved of CPU) does not count as silence: a pass of the take
loop that comes more than ``stall`` seconds after the previous one shifts every silence timer
by the gap. So a frozen
recorder that resumes sees its backlog, not idle topics.

A *sparse* topic (the suite's ``events``: a message now and then, none for most of a run)
never holds the others back; its messages are placed by their log time like any other.

A message older than what was already released (a topic that was idle and came back late)
is still written, and counted as ``late``. An unstamped message sent while ``/clock``
samples were lost on the way (a gap in their publication sequence numbers) has no known
time: it is left out and counted in :attr:`Sequencer.untimed`, never written at the time of
an earlier step. Nothing else is dropped here unless the caller says so at the end
(:meth:`Sequencer.drain`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
import heapq
import time

from ..timebase import Jump, TimeBase


@dataclass(frozen=True)
class Record:
    """A message ready for the bag."""

    log_ns: int
    order: int          # the topic's place in the recorder's list
    seq: int            # arrival order
    topic: str
    data: bytes
    publish_ns: int     # DDS source timestamp

    def key(self) -> tuple[int, int, int]:
        return (self.log_ns, self.order, self.seq)


class _Topic:
    __slots__ = ('name', 'order', 'mark', 'pending', 'last_rx', 'src', 'recent')

    def __init__(self, name: str, order: int):
        self.name = name
        self.order = order
        self.mark: int | None = None        # log time of the latest resolved message
        self.pending: deque = deque()       # unstamped messages waiting for a later /clock
        self.last_rx: float | None = None   # steady time of the latest message (or match)
        self.src: int | None = None         # source time of the latest message
        self.recent: deque = deque(maxlen=9)  # its latest log times, for its period


#: Wall seconds a topic one period short of a stop's instant is waited for: the message at
#: the instant is published just after its /clock, milliseconds later even on a loaded
#: machine.
EDGE_GRACE = 0.1


class Sequencer:
    """Log times and release order of a recording (see the module).

    Parameters
    ----------
    topics : sequence of str
        The recorded topics, in release order for equal log times.
    mode : {'sim', 'wall'}
        The bag's time base.
    idle_timeout : float
        Steady seconds of silence after which a topic no longer holds the others back.
    stall : float
        A take-loop pass later than this after the previous one [s] is a stall of the
        recorder, not silence of the topics.
    clock : callable
        Steady clock [s].
    sparse : sequence of str
        Topics of ``topics`` that never hold the others back (see the module).
    """

    def __init__(self, topics: Sequence[str], mode: str = 'sim', *, idle_timeout: float = 1.0,
                 stall: float = 0.05, clock: Callable[[], float] = time.monotonic,
                 sparse: Sequence[str] = ()):
        if mode not in ('sim', 'wall'):
            raise ValueError(f'mode {mode!r}: sim or wall')
        self.mode = mode
        self.time = TimeBase()
        self._topics = {name: _Topic(name, i) for i, name in enumerate(topics)}
        self._sparse = frozenset(sparse)
        self._heap: list = []
        self._seq = 0
        self._released: int | None = None
        self._idle = idle_timeout
        self._stall = stall
        self._clock = clock
        self._last_pass: float | None = None
        self._w: int | None = -1   # the latest watermark
        self.late = 0
        # Source times (before, after) around /clock samples lost on the way.
        self._gaps: deque = deque(maxlen=64)
        self._clock_seq: tuple[int, int] | None = None   # (sequence, source) of the latest
        # Is the bag's first /clock its writer's first sample (or unknown)? Then nothing was
        # before it, and what was sent before it belongs to it.
        self._origin: bool | None = None
        self.untimed: dict[str, int] = {}

    # ---- input ---------------------------------------------------------------------------

    def clock(self, sim_ns: int, source_ns: int, sequence: int | None = None, writer=None
              ) -> Jump | None:
        """A ``/clock`` sample; a jump (a new simulator) is returned (the caller starts a new
        bag)."""
        jump = self.time.on_clock(sim_ns, source_ns, sequence, writer)
        if self._origin is None:
            self._origin = sequence is None or sequence == 1
        if sequence is not None:
            last = self._clock_seq
            if jump is None and last is not None and sequence > last[0] + 1:
                self._gaps.append((last[1], source_ns))
            self._clock_seq = (sequence, source_ns)
        if jump is None:
            for t in self._topics.values():
                self._settle(t)
            if self._gaps:
                # A gap matters while a message sent in it may still come: until every
                # topic that is not silent has sent one after it.
                now = self._clock()
                oldest = min((t.src for t in self._topics.values() if t.src is not None
                              and now - t.last_rx <= self._idle), default=source_ns)
                while self._gaps and self._gaps[0][1] < oldest:
                    self._gaps.popleft()
        return jump

    def _in_gap(self, source_ns: int) -> bool:
        return any(a < source_ns < b for a, b in self._gaps)

    def message(self, topic: str, data: bytes, *, source_ns: int, stamp_ns: int | None = None,
                receive_ns: int | None = None) -> None:
        """A message of a recorded topic: its header stamp if it has one (sim mode), its
        source timestamp, and its receive time (wall mode)."""
        t = self._topics[topic]
        t.last_rx = self._clock()
        t.src = source_ns
        self._seq += 1
        if self.mode == 'wall':
            self._push(t, receive_ns, data, source_ns)
        elif stamp_ns is not None:
            self._push(t, stamp_ns, data, source_ns)
        else:
            t.pending.append((source_ns, self._seq, data))
            self._settle(t)

    def matched(self, topic: str) -> None:
        """``topic`` has a matched publisher: from now on it holds the others back until it
        delivers or has been silent for ``idle_timeout``."""
        t = self._topics[topic]
        if t.last_rx is None:
            t.last_rx = self._clock()

    def pass_done(self) -> None:
        """Call after every pass of the take loop: detects the recorder's own stalls."""
        now = self._clock()
        if self._last_pass is not None and now - self._last_pass > self._stall:
            gap = now - self._last_pass
            for t in self._topics.values():
                if t.last_rx is not None:
                    t.last_rx += gap
        self._last_pass = now

    # ---- output --------------------------------------------------------------------------

    def ready(self) -> Iterator[Record]:
        """The records that may be written now, in order."""
        w = self._watermark()
        heap = self._heap
        while heap and (w is None or heap[0][0] < w):
            yield self._pop()

    def drain(self, keep: Callable[[str, int], bool] | None = None) -> Iterator[Record]:
        """Everything left, in order (at a stop). Unstamped messages still waiting for a
        ``/clock`` sent after them take the latest one sent before them, which is their time
        only if no later ``/clock`` is still to come (a paused simulator): with ``keep(topic,
        source_ns)`` given, those it refuses are left out (the caller counts them)."""
        for t in self._topics.values():
            while t.pending:
                src, seq, data = t.pending.popleft()
                if self._gaps and self._in_gap(src):
                    self.untimed[t.name] = self.untimed.get(t.name, 0) + 1
                    continue
                if keep is not None and not keep(t.name, src):
                    continue
                log = self.time.time_of(src)
                if log is None and self._origin:   # sent ahead of the simulator's first step
                    log = self.time.latest
                if log is not None:
                    self._push_at(t, log, seq, data, src)
        while self._heap:
            yield self._pop()

    def behind(self, until_ns: int, quiet: float, since: float) -> dict[str, int | None]:
        """The topics that have not delivered up to ``until_ns`` (a stop's last instant)
        and should, with their latest log time (``None``: nothing yet). A topic is done
        once its latest message is at ``until_ns`` or less than one of its periods before
        it (the next would lie after it), or exactly one period before it and silent for
        :data:`EDGE_GRACE` s since the stop (the next would be the stop's own); one that sent
        nothing in the ``idle_timeout``
        before ``since`` (the stop's request, steady clock) had ended before the stop; one
        that sent nothing at all is done after ``quiet`` s of silence from ``since``. The
        recorder's own stalls do not count as silence. Sparse topics are never behind."""
        now = self._clock()
        latest = self.time.latest
        out: dict[str, int | None] = {}
        for t in self._topics.values():
            if t.name in self._sparse or t.last_rx is None:
                continue
            mark = t.mark
            if t.pending and latest is not None:  # waiting messages: at or after the latest
                mark = latest if mark is None else max(mark, latest)
            if mark is None:
                if now - max(t.last_rx, since) < quiet:
                    out[t.name] = None
                continue
            period = self.period(t.name) or 0
            if t.last_rx < since - self._idle:
                continue
            if mark < until_ns - period:
                out[t.name] = mark
            elif mark < until_ns and now - max(t.last_rx, since) < EDGE_GRACE:
                # One period short: a message at the stop instant itself may still be on its
                # way (a simulator publishes its pausing instant's measurements after that
                # instant's /clock); a topic published before each increment has none there.
                out[t.name] = mark
        return out

    def ended(self, until_ns: int, periods: int, span_ns: int) -> dict[str, int]:
        """The periodic topics whose latest message lies more than ``periods`` of their
        periods and ``span_ns`` before ``until_ns`` (a bag's end), with its log time [ns]."""
        out: dict[str, int] = {}
        for t in self._topics.values():
            period = self.period(t.name)
            if t.name in self._sparse or t.mark is None or not period:
                continue
            if until_ns - t.mark > max(periods * period, span_ns):
                out[t.name] = t.mark
        return out

    def period(self, topic: str) -> int | None:
        """The period [ns] of ``topic``'s latest messages (the median step of their log
        times), or ``None`` with fewer than two."""
        times = list(self._topics[topic].recent)
        steps = sorted(b - a for a, b in zip(times, times[1:]) if b > a)
        return steps[len(steps) // 2] if steps else None

    def silent(self, topic: str, since: float) -> float:
        """Steady seconds since ``topic`` was last heard from (or matched), counted from
        ``since`` at the earliest; infinite if never."""
        t = self._topics[topic]
        return float('inf') if t.last_rx is None else self._clock() - max(t.last_rx, since)

    def mark(self, topic: str) -> int | None:
        """Log time [ns] of the latest resolved message of ``topic`` (``None``: none)."""
        return self._topics[topic].mark

    @property
    def buffered(self) -> int:
        """Messages held (waiting for their log time or for the other topics)."""
        return len(self._heap) + sum(len(t.pending) for t in self._topics.values())

    # ---- internals -----------------------------------------------------------------------

    def _settle(self, t: _Topic) -> None:
        tb = self.time
        while t.pending and tb.settled(t.pending[0][0]):
            src, seq, data = t.pending.popleft()
            if self._gaps and self._in_gap(src):
                self.untimed[t.name] = self.untimed.get(t.name, 0) + 1
                continue
            log = tb.time_of(src)
            if log is None:   # sent before the bag's first /clock
                if not self._origin:
                    continue  # a step before the bag
                log = tb.latest
            self._push_at(t, log, seq, data, src)

    def _push(self, t: _Topic, log_ns: int, data: bytes, source_ns: int) -> None:
        self._push_at(t, log_ns, self._seq, data, source_ns)

    def _push_at(self, t: _Topic, log_ns: int, seq: int, data: bytes, source_ns: int) -> None:
        t.mark = log_ns if t.mark is None else max(t.mark, log_ns)
        t.recent.append(log_ns)
        heapq.heappush(self._heap, (log_ns, t.order, seq, t.name, data, source_ns))

    def _pop(self) -> Record:
        log, order, seq, topic, data, src = heapq.heappop(self._heap)
        if self._released is not None and log < self._released:
            self.late += 1
        else:
            self._released = log
        return Record(log, order, seq, topic, data, src)

    def _marks(self) -> list[int | None]:
        """The effective mark of every active topic (``None``: nothing resolved yet)."""
        now = self._clock()
        latest = self.time.latest
        marks = []
        for t in self._topics.values():
            if t.last_rx is None or now - t.last_rx > self._idle or t.name in self._sparse:
                continue  # no publisher yet, silent or sparse: does not hold the others back
            if t.pending:
                # Its waiting messages are at or after the latest /clock.
                marks.append(latest if t.mark is None else max(t.mark, latest or 0))
            else:
                marks.append(t.mark)
        return marks

    def _watermark(self) -> int | None:
        """The log time below which every active topic has delivered; ``None``: no limit."""
        if self.mode == 'wall':
            return None
        marks = self._marks()
        if any(m is None for m in marks):
            return -1  # an active topic with nothing resolved yet: wait
        if not marks:
            # Every topic silent (a paused simulator): nothing new can be placed, so nothing
            # more is released; what is held goes out when data comes back, or at a stop.
            return self._w
        self._w = min(marks)
        return self._w

    def complete(self, until_ns: int) -> bool:
        """Has every active topic delivered up to ``until_ns`` (a stop's last instant)?"""
        return all(m is not None and m >= until_ns for m in self._marks())
