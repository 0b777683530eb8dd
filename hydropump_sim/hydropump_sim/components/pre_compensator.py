"""Pressure compensator upstream of a metering edge (pre-compensated load sensing): a
normally open pressure-reducing spool between ``in`` (the supply) and ``out`` (the
metering edge's inlet) that holds the metering drop ``P_out - P_sense`` at its spring
setting ``dp_set``, ``P_sense`` being the pressure downstream of the metering edge. The
section's flow is then ``C_d A(xi) sqrt(2 dp_set / rho)`` whatever its load pressure, until
the supply cannot hold ``dp_set`` any more: then the section with the highest load starves
first.

    s* = clip(1/2 + (dp_set - (P_out - P_sense)) / p_band, 0, 1),   tau ds/dt = s* - s
    Q  = C_d A_max s sqrt(2/rho) sroot(max(P_in - P_out, 0))

``p_band`` is the spring's gradient over the stroke (the drop moves by it from closed to
fully open).
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .directional_valve import metering
from .laws import balance, clip01, lag
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b, c = int(p[0]), int(p[1]), int(p[2])
    k, dp_set, p_band, tau, dp_cr = p[3], p[4], p[5], p[6], p[7]
    held = P[b] - P[c]
    target = balance(dp_set - held, p_band)
    if tau > 0.0:
        dx[0] = lag(x[0], target, tau)
        s = clip01(x[0])
    else:
        s = target
    q = metering(k, s, P[a] - P[b], dp_cr)
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = s
    y[2] = held


@dataclass(frozen=True)
class CompensatorParams:
    A_max: float = spec('m^2', 'throttling area fully open', 1.0e-9, 1.0e-2)
    dp_set: float = spec('Pa', 'spring setting: the pressure difference held', 1.0e4, 1.0e7)
    p_band: float = spec('Pa', 'spring gradient over the stroke', 1.0e2, 1.0e6, default=2.0e4)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    tau: float = spec('s', 'spool time constant; 0 = static', 0.0, 1.0, default=2.0e-3)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=5.0e4)


def spool_state(params) -> tuple:
    return (StateSpec('spool', '-', 1.0),) if params.tau > 0.0 else ()


def spool_start(params) -> np.ndarray:
    return np.array([1.0]) if params.tau > 0.0 else np.array([])


class PreCompensator(Component):
    kind = 'pre_compensator'
    doc = 'pressure compensator before a metering edge: holds its drop at dp_set'
    Params = CompensatorParams
    PORTS = (PortSpec('in', 'supply'), PortSpec('out', 'to the metering edge'),
             PortSpec('sense', 'downstream of the metering edge (the load)', sense=True))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow in -> out'),
               SignalSpec('opening', '-', 'spool opening 0..1'),
               SignalSpec('dp', 'Pa', 'held drop P_out - P_sense'))
    kernel = kernel
    ROLES = frozenset({'compensator'})

    def metering_drop(self, margin: float) -> float:
        """The drop [Pa] it holds across its section's metering edge."""
        return self.params.dp_set

    def static_values(self):
        """Its lag off: the opening follows its target at once."""
        return {'tau': 0.0}

    def states(self):
        return spool_state(self.params)

    def pack(self):
        r = self.params
        return [coefficient(r.C_d, r.A_max, self.fluid.rho), r.dp_set, r.p_band, r.tau,
                r.dp_cr]

    def initial_state(self, P, u):
        return spool_start(self.params)
