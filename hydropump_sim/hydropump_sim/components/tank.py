"""Tank: fixes the pressure of its node (gauge; 0 = atmospheric). Its signal ``flow`` is
the net flow returning into it."""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    y[0] = P[int(p[0])]


@dataclass(frozen=True)
class TankParams:
    pressure: float = spec('Pa', 'tank pressure (gauge)', -1.0e5, 5.0e6, default=0.0)


class Tank(Component):
    kind = 'tank'
    doc = 'tank: a node at a fixed pressure'
    Params = TankParams
    PORTS = (PortSpec('node', 'the tank node'),)
    SIGNALS = (SignalSpec('pressure', 'Pa', 'tank pressure'),
               SignalSpec('flow', 'm^3/s', 'net flow returning into the tank'))
    kernel = kernel

    def pressure_cap(self, u):
        return self.params.pressure

    def fixed_pressure(self):
        return ('node', 'param', 'pressure')
