"""Shuttle-valve network of load sensing: the highest of its input pressures reaches the
load-sensing line ``out`` (its volume ``V``, bled to ``tank``), as a cascade of shuttle
valves delivers it:

    k = argmax_i P_in,i,     Q_k->out = k_s sroot(P_in,k - P_ls)   (both ways, the ball open)
    Q_bleed = k_b sroot(P_ls - P_tank)

``P_ls`` is then the highest load pressure, less the drop the bleed flow makes across the
shuttle passages; it falls to tank pressure when every load is idle.
"""

from dataclasses import dataclass

import numba

from ..schema import spec
from .base import Component, PortSpec, SignalSpec
from .laws import sroot
from .orifice import coefficient

jit = numba.njit(cache=True, fastmath=False, nogil=True)


@jit
def kernel(t, x, dx, u, p, y, P, Q):
    out, tank, n = int(p[0]), int(p[1]), int(p[2])
    k, k_b, dp_cr = p[3 + n], p[4 + n], p[5 + n]
    sel = int(p[3])
    best = 0
    for i in range(1, n):
        j = int(p[3 + i])
        if P[j] > P[sel]:
            sel = j
            best = i
    q = k * sroot(P[sel] - P[out], dp_cr)
    Q[sel] -= q
    Q[out] += q
    q_b = 0.0
    if tank >= 0 and k_b > 0.0:
        q_b = k_b * sroot(P[out] - P[tank], dp_cr)
        Q[out] -= q_b
        Q[tank] += q_b
    y[0] = P[out]
    y[1] = best
    y[2] = q
    y[3] = q_b


@dataclass(frozen=True)
class ShuttleParams:
    V: float = spec('m^3', 'volume of the load-sensing line', 1.0e-9, 1.0e-2)
    A: float = spec('m^2', 'flow area of a shuttle passage', 1.0e-10, 1.0e-3, default=3.0e-6)
    A_bleed: float = spec('m^2', 'area of the bleed orifice to tank; 0 = none', 0.0, 1.0e-4,
                          default=2.0e-8)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=1.0e4)


class ShuttleNetwork(Component):
    kind = 'shuttle_network'
    doc = 'shuttle valves: the highest load pressure to the load-sensing line, with a bleed'
    Params = ShuttleParams
    PORTS = (PortSpec('out', 'load-sensing line (P_LS)'),
             PortSpec('tank', 'bleed outlet', optional=True),
             PortSpec('in', 'the sensed load nodes', many=True))
    SIGNALS = (SignalSpec('pressure', 'Pa', 'load-sensing pressure P_LS'),
               SignalSpec('selected', '-', 'index of the highest input'),
               SignalSpec('flow', 'm^3/s', 'flow from the selected input'),
               SignalSpec('bleed', 'm^3/s', 'bleed flow to tank'))
    kernel = kernel

    def pack(self):
        r = self.params
        rho = self.fluid.rho
        return [coefficient(r.C_d, r.A, rho), coefficient(r.C_d, r.A_bleed, rho), r.dp_cr]

    def volumes(self):
        return {'out': self.params.V}
