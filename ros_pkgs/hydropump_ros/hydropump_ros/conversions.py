"""Conversions at the ROS edge: SI values <-> messages.

- Pressures: the plant works in gauge pressure; ``sensor_msgs/FluidPressure`` carries absolute
  pressure (REP-103), so the simulator adds ``p_atm`` once, here.
- Stamps: simulation time as integer nanoseconds <-> ``builtin_interfaces/Time``.
- Events: what makes a record unfit for identification, as one stamped message each on
  :data:`EVENTS` (:func:`event`).
"""

from __future__ import annotations

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import QoSProfile, ReliabilityPolicy

NS = 1_000_000_000
# The simulator's clock topic, relative: ``/clock`` in the root namespace as ROS tools expect,
# ``/<ns>/clock`` for a pump in namespace ``<ns>``, so that several pumps share a domain,
# each node following the simulator of its own namespace (docs/ros.md).
CLOCK = 'clock'
# The events topic, relative for the same reason (``/diagnostics`` is shared by every pump
# and its status names carry no namespace): ``diagnostic_msgs/DiagnosticArray`` stamped with
# the simulation time of the event, one status per event, named by its kind. The recorder
# always records it and counts the kinds in the bag's ``custom_data``.
EVENTS = 'events'
# The kinds: the plant got the safe current instead of the commands (a controller's
# watchdog or a failed control law, the simulator's command watchdog); a lock-step instant
# advanced without its command.
SAFE_CURRENT = 'safe_current'
LOCK_STEP_TIMEOUT = 'lock_step_timeout'
EVENT_KINDS = (SAFE_CURRENT, LOCK_STEP_TIMEOUT)
# Events are rare and each one matters: reliable, and a backlog a slow reader can catch up.
EVENTS_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


def absolute(gauge: float, p_atm: float) -> float:
    """Absolute pressure [Pa] of a gauge pressure [Pa]."""
    return gauge + p_atm


def stamp(ns: int) -> Time:
    """Nanoseconds as a ``builtin_interfaces/Time``."""
    return Time(sec=ns // NS, nanosec=ns % NS)


def set_stamp(msg_time: Time, ns: int) -> None:
    """Write ``ns`` into an existing ``Time`` (no allocation in the hot loop)."""
    msg_time.sec = ns // NS
    msg_time.nanosec = ns % NS


def to_ns(t: Time) -> int:
    """A ``builtin_interfaces/Time`` as nanoseconds."""
    return t.sec * NS + t.nanosec


def seconds_to_ns(t: float) -> int:
    """Seconds (simulation time) as whole nanoseconds."""
    return int(round(t * NS))


class ClockWriter:
    """The identity of the ``/clock`` writer as the graph shows it (its endpoint GIDs, sorted),
    for the rule of time's new-writer check (``hydropump_ctrl.timebase``): read again whenever
    ``/clock`` resumes after a pause of :attr:`GAP` (a new simulator's first samples) and on
    :meth:`refresh`. While the graph shows no writer the last identity is kept."""

    GAP = 0.3   # s of the publisher's wall clock between two /clock samples

    def __init__(self, node):
        self._node = node
        self.tag = None
        self._last: int | None = None

    def refresh(self) -> None:
        infos = self._node.get_publishers_info_by_topic(CLOCK)
        if infos:
            self.tag = tuple(sorted(bytes(i.endpoint_gid) for i in infos))

    def of(self, source_ns: int):
        """The writer identity for a sample sent at ``source_ns``."""
        if self._last is None or source_ns - self._last > self.GAP * 1e9:
            self.refresh()
        self._last = source_ns
        return self.tag


def event(kind: str, ns: int, message: str, source: str, **values) -> DiagnosticArray:
    """One event of ``kind`` at ``ns`` (simulation time where a ``/clock`` runs), for
    :data:`EVENTS`: ``message`` says what happened, ``source`` which node, ``values`` the
    figures (SI)."""
    st = DiagnosticStatus(level=DiagnosticStatus.WARN, name=kind, message=message,
                          hardware_id='hydropump',
                          values=[KeyValue(key='source', value=source)]
                          + [KeyValue(key=k, value=str(v)) for k, v in values.items()])
    arr = DiagnosticArray(status=[st])
    arr.header.stamp = stamp(ns)
    return arr
