"""Pressure-reducing valve: a normally open spool between ``in`` and ``out`` that holds the
outlet at its spring setting ``dp_set`` above the pressure at ``ref`` (its spring chamber's
drain: tank, for an absolute setting), as a pilot supply's reducing valve does. The spool,
its regulation range, hysteresis, flow-force droop and leakage are the pre-compensator's
(:mod:`.pre_compensator`: the same hydraulics, sensing its own outlet); it is no section's
compensator, so a margin controller does not count it among them.
"""

from .base import PortSpec
from .pre_compensator import kernel, SpoolCompensator


class ReducingValve(SpoolCompensator):
    kind = 'reducing_valve'
    doc = 'pressure-reducing valve: holds its outlet at dp_set above ref (tank)'
    PORTS = (PortSpec('in', 'supply'), PortSpec('out', 'reduced outlet'),
             PortSpec('ref', "the spring chamber's drain (tank)", sense=True))
    ROLES = frozenset()
    kernel = kernel
