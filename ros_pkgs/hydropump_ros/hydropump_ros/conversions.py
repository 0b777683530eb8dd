"""Conversions at the ROS edge: SI values <-> messages.

- Pressures: the plant works in gauge pressure; ``sensor_msgs/FluidPressure`` carries absolute
  pressure (REP-103), so the simulator adds ``p_atm`` once, here.
- Stamps: simulation time as integer nanoseconds <-> ``builtin_interfaces/Time``.
"""

from __future__ import annotations

from builtin_interfaces.msg import Time

NS = 1_000_000_000


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
