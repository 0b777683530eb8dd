"""Check valve from ``in`` to ``out``: closed below the cracking pressure difference, fully
open from ``p_full`` on; backwards only its seat's leakage:

    s = clip((dp - p_crack) / (p_full - p_crack), 0, 1),   Q = C_d A s sqrt(2/rho) sroot(dp)
                                                           + G_leak dp
An anti-cavitation (make-up) check is one with a low crack pressure from tank to a motor or
cylinder line.
"""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import must_exceed, spec
from .base import Component, PortSpec, SignalSpec
from .laws import clip01, edge, G_LEAK_POPPET
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    dp = P[a] - P[b]
    s = clip01((dp - p[3]) / (p[4] - p[3]))
    q = edge(p[2], s, dp, p[5], p[6])
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = s
    y[2] = q * dp


@dataclass(frozen=True)
class CheckParams:
    A: float = spec('m^2', 'flow area fully open', 1.0e-10, 1.0e-1)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    p_crack: float = spec('Pa', 'cracking pressure difference', 0.0, 1.0e7, default=1.0e5)
    p_full: float = spec('Pa', 'pressure difference of full opening', 1.0e3, 1.0e7,
                         default=3.0e5)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=1.0e4)
    G_leak: float = spec('m^3/(s Pa)', 'leakage of the closed seat', 0.0, 1.0e-9,
                         default=G_LEAK_POPPET)

    def cross_checks(self):
        return must_exceed('p_full', self.p_full, 'p_crack', self.p_crack)


class CheckValve(Component):
    kind = 'check_valve'
    LOSS_GROUP = 'holding'
    doc = 'check valve: opens from p_crack to p_full, no reverse flow'
    Params = CheckParams
    PORTS = (PortSpec('in', 'inlet'), PortSpec('out', 'outlet'))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow in -> out'),
               SignalSpec('opening', '-', 'opening 0..1'),
               SignalSpec('loss', 'W', 'power dissipated'))
    kernel = kernel

    def pack(self):
        r = self.params
        return [coefficient(r.C_d, r.A, self.fluid.rho), r.p_crack, r.p_full, r.dp_cr,
                r.G_leak]
