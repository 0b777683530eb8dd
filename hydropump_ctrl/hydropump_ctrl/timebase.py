"""The rule of time of the suite, for every subscriber (the controller and the recorder).

The simulator's simulation time is the time of the suite:

1. The simulator publishes ``/clock`` first in every step, then the step's measurements.
   Stamped messages (``std_msgs/Header``) carry the simulation time of their step.
2. An unstamped message (``std_msgs/Float64``) belongs to the latest ``/clock`` its publisher
   had sent before it. Its DDS *source timestamp* (the publisher's wall clock at
   ``publish()``) is compared with the source timestamps of the ``/clock`` samples, so the
   order in which messages of different topics arrive does not matter. A message from another
   process (the controller's command) is timed the same way: it was published after the
   ``/clock`` of the instant it answers and before the next one.
3. Wherever a ``/clock`` is present, simulation time is used, whatever ``use_sim_time``
   says; wall time only where no ``/clock`` exists. Never a mix.
4. Simulation time never goes back while one simulator runs (``~/reset`` keeps time
   running). A ``/clock`` below the latest one means a new simulator: the history is dropped
   and the jump is reported, so that a controller restarts bumplessly and a recorder starts a
   new bag. So does a ``/clock`` from a new writer (its DDS publication sequence number below
   the latest one, or another writer identity, the endpoint GIDs the graph shows): on a loaded
   machine a new simulator's time may already have passed the old one's by the time it is
   discovered.

All times are integer nanoseconds. Nothing here imports ROS.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass


@dataclass(frozen=True)
class Jump:
    """A new simulator started: simulation time went from ``old`` to ``new`` [ns], back or
    (its ``/clock`` discovered late) on from a new writer."""

    old: int
    new: int

    def describe(self) -> str:
        if self.new < self.old:
            return (f'simulation time went back from {self.old * 1e-9:.6f} s to '
                    f'{self.new * 1e-9:.6f} s (a new simulator)')
        return (f'a new simulator: its /clock (a new writer) is at {self.new * 1e-9:.6f} s, '
                f'the old one was at {self.old * 1e-9:.6f} s')


class TimeBase:
    """Simulation time from ``/clock`` samples, and the time of unstamped messages.

    Parameters
    ----------
    history : int
        How many ``/clock`` samples are kept to time late unstamped messages (at 1 kHz,
        100000 is 100 s of simulation time).
    """

    def __init__(self, history: int = 100_000):
        # Lists, not deques: bisect needs fast indexing. The front is trimmed in halves.
        self._sim: list[int] = []   # simulation times [ns], increasing
        self._src: list[int] = []   # their source timestamps [ns], increasing
        self._history = history
        self.epoch = 0              # counts the jumps back
        self._seq: int | None = None  # the latest publication sequence number
        self._writer = None           # the latest writer identity

    @property
    def present(self) -> bool:
        """Has a ``/clock`` been received (since the last jump)?"""
        return bool(self._sim)

    @property
    def latest(self) -> int | None:
        """The latest simulation time [ns], or ``None``."""
        return self._sim[-1] if self._sim else None

    @property
    def latest_source(self) -> int | None:
        """The source timestamp of the latest ``/clock`` [ns], or ``None``."""
        return self._src[-1] if self._src else None

    def on_clock(self, sim_ns: int, source_ns: int, sequence: int | None = None,
                 writer=None) -> Jump | None:
        """Take a ``/clock`` sample (with its DDS publication sequence number and its writer's
        identity, where known); return a :class:`Jump` if time went back or the sample is
        from a new writer."""
        new_writer = ((sequence is not None and self._seq is not None and sequence < self._seq)
                      or (writer is not None and self._writer is not None
                          and writer != self._writer))
        if sequence is not None:
            self._seq = sequence
        if writer is not None:
            self._writer = writer
        if self._sim and (sim_ns < self._sim[-1] or new_writer):
            jump = Jump(self._sim[-1], sim_ns)
            self._sim.clear()
            self._src.clear()
            self.epoch += 1
            self._sim.append(sim_ns)
            self._src.append(source_ns)
            return jump
        if self._sim and source_ns < self._src[-1]:
            # A clock sample with an older source time than the previous one: from another
            # simulator publishing at the same time. Ignore it for the mapping.
            return None
        self._sim.append(sim_ns)
        self._src.append(source_ns)
        if len(self._sim) > 2 * self._history:
            del self._sim[:self._history]
            del self._src[:self._history]
        return None

    def time_of(self, source_ns: int) -> int | None:
        """Simulation time [ns] of an unstamped message published at ``source_ns``: the
        latest ``/clock`` sent at or before it; ``None`` if none was (yet) received."""
        i = bisect.bisect_right(self._src, source_ns) - 1
        return self._sim[i] if i >= 0 else None

    def settled(self, source_ns: int) -> bool:
        """Is :meth:`time_of` final for ``source_ns``? It is once a ``/clock`` sent after the
        message has arrived (clock samples arrive in order; messages of other topics may
        arrive before the clock that precedes them)."""
        return bool(self._src) and self._src[-1] > source_ns

    def source_of(self, sim_ns: int) -> int | None:
        """Source timestamp of the ``/clock`` sample at ``sim_ns`` (the first one, if the
        time was published more than once), or ``None``."""
        i = bisect.bisect_left(self._sim, sim_ns)
        if i < len(self._sim) and self._sim[i] == sim_ns:
            return self._src[i]
        return None

    def after(self, sim_ns: int, source_ns: int) -> bool:
        """Was a message published at ``source_ns`` sent after the ``/clock`` of ``sim_ns``?
        (An unstamped measurement of instant ``sim_ns`` has arrived.)"""
        src = self.source_of(sim_ns)
        return src is not None and source_ns >= src
