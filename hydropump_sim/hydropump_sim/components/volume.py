"""A node volume: the capacitance of a hose or a chamber at a hydraulic node. Every node
whose pressure is not fixed needs at least one; the node's pressure then follows continuity
(eqs. 3 and 9)

    dP/dt = beta(P) / V * sum(Q into the node)

with ``V`` the sum of the volumes at the node (volume components, and chambers that
components declare), ``beta`` the circuit's fluid bulk modulus with entrained air and the
cavitation floor (components/laws.py).
"""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    y[0] = P[int(p[0])]


@dataclass(frozen=True)
class VolumeParams:
    V: float = spec('m^3', 'volume of the node (hose, chamber)', 1.0e-9, 1.0)


class Volume(Component):
    kind = 'volume'
    doc = 'node volume: the capacitance of continuity (eqs. 3, 9)'
    Params = VolumeParams
    PORTS = (PortSpec('node', 'the node it gives a volume to'),)
    SIGNALS = (SignalSpec('pressure', 'Pa', 'node pressure'),)
    kernel = kernel

    def volumes(self):
        return {'node': self.params.V}
