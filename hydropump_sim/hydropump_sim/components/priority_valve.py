"""Priority valve: serves its controlled-flow port ``cf`` (the priority load, a steering
unit) first and sends the excess to ``ef`` (the loads on demand). One spool with two
complementary edges, pushed toward ``ef`` by ``P_cf`` and back by the priority load's
sensed pressure ``P_ls`` plus a spring ``dp_set``: it holds ``P_cf - P_ls`` at ``dp_set``,
so the priority load's metering drop, and its flow, stay put while the others vary; when
the supply falls short, the ``ef`` edge closes first.

    e = (P_cf - P_ls) - dp_set + r_ff Q_cf
    tau dy/dt = play(y, clip(1/2 + e / p_band, 0, 1), p_h / p_band) - y
    Q_cf = k_cf (1 - y) sroot(P_in - P_cf) + G_leak (P_in - P_cf)
    Q_ef = k_ef y sroot(P_in - P_ef) + G_leak (P_in - P_ef)

with ``k = C_d A sqrt(2/rho)`` of each edge fully open; the edges pass flow both ways and
leak when closed, the flow force through the cf edge pushes it shut (a droop of the held
drop). Regulation range, hysteresis, droop and lag as the compensators'
(:mod:`.pre_compensator`); with ``tau = 0`` the spool is static.
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .laws import balance, clip01, edge, G_LEAK_SPOOL, spool_rate
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, cf, ef, ls = int(p[0]), int(p[1]), int(p[2]), int(p[3])
    k_cf, k_ef, dp_set, p_band, tau, dp_cr = p[4], p[5], p[6], p[7], p[8], p[9]
    p_h, r_ff, g = p[10], p[11], p[12]
    held = P[cf] - P[ls]
    s = clip01(x[0]) if tau > 0.0 else balance(held - dp_set, p_band)
    dp_cf, dp_ef = P[a] - P[cf], P[a] - P[ef]
    q_cf = edge(k_cf, 1.0 - s, dp_cf, dp_cr, g)
    q_ef = edge(k_ef, s, dp_ef, dp_cr, g)
    if tau > 0.0:
        dx[0] = spool_rate(x[0], held - dp_set + r_ff * q_cf, p_band, p_h, tau)
    Q[a] -= q_cf + q_ef
    Q[cf] += q_cf
    Q[ef] += q_ef
    y[0] = q_cf
    y[1] = q_ef
    y[2] = s
    y[3] = held
    y[4] = q_cf * dp_cf + q_ef * dp_ef


@dataclass(frozen=True)
class PriorityParams:
    A_cf: float = spec('m^2', 'area of the priority edge fully open', 1.0e-9, 1.0e-2)
    A_ef: float = spec('m^2', 'area of the excess edge fully open', 1.0e-9, 1.0e-2)
    dp_set: float = spec('Pa', "spring setting: the priority load's held drop", 1.0e4, 1.0e7)
    p_band: float = spec('Pa', 'regulation range: the spring gradient over the stroke', 1.0e2,
                         1.0e6, default=1.0e5)
    p_h: float = spec('Pa', "hysteresis of the spool's friction", 0.0, 1.0e6, default=3.0e4)
    r_ff: float = spec('Pa s/m^3', 'flow-force droop of the held drop per priority flow', 0.0,
                       1.0e11, default=1.0e8)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    tau: float = spec('s', 'spool time constant; 0 = static', 0.0, 1.0, default=1.0e-2)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=5.0e4)
    G_leak: float = spec('m^3/(s Pa)', 'leakage of a closed edge (0.1 L/min at 100 bar)', 0.0,
                         1.0e-9, default=G_LEAK_SPOOL)


class PriorityValve(Component):
    kind = 'priority_valve'
    LOSS_GROUP = 'compensators'
    doc = 'priority valve: the cf port first, the excess to ef'
    Params = PriorityParams
    PORTS = (PortSpec('in', 'supply'), PortSpec('cf', 'controlled flow: the priority load'),
             PortSpec('ef', 'excess flow: the loads on demand'),
             PortSpec('ls', "the priority load's sensed pressure", sense=True))
    SIGNALS = (SignalSpec('cf_flow', 'm^3/s', 'flow to the priority port'),
               SignalSpec('ef_flow', 'm^3/s', 'flow to the excess port'),
               SignalSpec('position', '-', 'spool: 0 all to cf, 1 cf throttled'),
               SignalSpec('dp', 'Pa', 'P_cf - P_ls'),
               SignalSpec('loss', 'W', 'power dissipated across both edges'))
    kernel = kernel
    ROLES = frozenset({'compensator'})

    def metering_drop(self, margin: float) -> float:
        """The drop [Pa] it holds across the priority load's metering edge."""
        return self.params.dp_set

    def static_values(self):
        """Its lag off: the opening follows its target at once."""
        return {'tau': 0.0}

    def states(self):
        return (StateSpec('spool', '-', 1.0),) if self.params.tau > 0.0 else ()

    def pack(self):
        r = self.params
        rho = self.fluid.rho
        return [coefficient(r.C_d, r.A_cf, rho), coefficient(r.C_d, r.A_ef, rho), r.dp_set,
                r.p_band, r.tau, r.dp_cr, r.p_h, r.r_ff, r.G_leak]

    def initial_state(self, P, u):
        return np.array([0.5]) if self.params.tau > 0.0 else np.array([])
