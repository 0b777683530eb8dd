"""Pilot-operated check valve: free flow ``in`` -> ``out`` above its cracking pressure, and
reverse flow ``out`` -> ``in`` once the pressure at ``pilot`` (sensed, no flow) pushes the
poppet off its seat through the pilot piston, ``ratio`` times the seat's area:

    s = clip((P_in - P_out + ratio P_pilot - p_crack) / p_band, 0, 1)
    Q = k s sroot(P_in - P_out) + G_leak (P_in - P_out)          (in -> out; both ways)

with ``k = C_d A sqrt(2/rho)``. With the pilot at zero it is a check valve: closed, it
holds a pressure at ``out`` with its seat's leakage only (``G_leak dp``, laws.edge); the
reverse flow needs ``ratio P_pilot > P_out - P_in + p_crack``. The poppet opens smoothly
over ``p_band`` (no dynamics of its own, as Hopsan's, which switches on/off).

Defaults and their sources: ``ratio`` 3.5 and ``p_crack`` 1 bar, Hopsan's pilot-controlled
check valve defaults (phi 3.5, p_f 1 bar); ``p_band`` 2 bar, the project's check_valve
(cracks at 1 bar, full at 3 bar); ``G_leak`` laws.G_LEAK_POPPET (a seated poppet:
0.15 mL/min at 100 bar); ``C_d`` 0.65 and ``dp_cr`` 0.1 bar as check_valve.
"""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec
from .laws import clip01, edge, G_LEAK_POPPET
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b, c = int(p[0]), int(p[1]), int(p[2])
    k, ratio, p_crack, p_band, dp_cr, g = p[3], p[4], p[5], p[6], p[7], p[8]
    dp = P[a] - P[b]
    s = clip01((dp + ratio * P[c] - p_crack) / p_band)
    q = edge(k, s, dp, dp_cr, g)
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = s
    y[2] = q * dp


@dataclass(frozen=True)
class PilotCheckParams:
    A: float = spec('m^2', 'flow area fully open', 1.0e-10, 1.0e-2)
    ratio: float = spec('-', 'pilot ratio (pilot piston area over seat area; Hopsan 3.5)',
                        0.1, 50.0, default=3.5)
    p_crack: float = spec('Pa', 'cracking pressure (Hopsan 1 bar)', 0.0, 1.0e7, default=1.0e5)
    p_band: float = spec('Pa', 'pressure over which the poppet opens fully', 1.0e3, 1.0e7,
                         default=2.0e5)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    G_leak: float = spec('m^3/(s Pa)', 'seat leakage (laws.G_LEAK_POPPET: 0.15 mL/min at '
                         '100 bar)', 0.0, 1.0e-9, default=G_LEAK_POPPET)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=1.0e4)


class PilotCheck(Component):
    kind = 'pilot_check'
    LOSS_GROUP = 'holding'
    doc = 'pilot-operated check valve: free flow in -> out, reverse when piloted'
    Params = PilotCheckParams
    PORTS = (PortSpec('in', 'inlet (free-flow side)'), PortSpec('out', 'outlet (load side)'),
             PortSpec('pilot', 'pilot pressure (sensed)', sense=True))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow in -> out (negative: reverse)'),
               SignalSpec('opening', '-', 'poppet opening 0..1'),
               SignalSpec('loss', 'W', 'power dissipated'))
    kernel = kernel

    def pack(self):
        r = self.params
        return [coefficient(r.C_d, r.A, self.fluid.rho), r.ratio, r.p_crack, r.p_band,
                r.dp_cr, r.G_leak]
