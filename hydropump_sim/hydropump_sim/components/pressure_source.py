"""Pressure source: fixes the pressure of its node to an input (a held load pressure, a
test rig's supply). Its signal ``flow`` is the net flow into it."""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, PortSpec, SignalSpec


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    y[0] = P[int(p[0])]


@dataclass(frozen=True)
class SourceParams:
    pressure: float = spec('Pa', 'pressure (gauge)', -1.0e5, 1.0e8)


class PressureSource(Component):
    kind = 'pressure_source'
    doc = 'pressure source: a node held at an input pressure'
    Params = SourceParams
    PORTS = (PortSpec('node', 'the node it holds'),)
    INPUTS = (InputSpec('pressure', 'Pa', 'source pressure (gauge)', -1.0e5, 1.0e8,
                        'pressure'),)
    SIGNALS = (SignalSpec('pressure', 'Pa', 'source pressure'),
               SignalSpec('flow', 'm^3/s', 'net flow into the source'))
    kernel = kernel

    def pressure_cap(self, u):
        return u['pressure']

    def fixed_pressure(self):
        return ('node', 'input', 'pressure')
