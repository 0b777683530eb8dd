"""Pressure compensator upstream of a metering edge (pre-compensated load sensing): a
normally open pressure-reducing spool between ``in`` (the supply) and ``out`` (the
metering edge's inlet) that holds the metering drop ``P_out - P_sense`` at its spring
setting ``dp_set``, ``P_sense`` being the pressure downstream of the metering edge. The
section's flow is then ``C_d A(xi) sqrt(2 dp_set / rho)`` whatever its load pressure, until
the supply cannot hold ``dp_set`` any more: then the section with the highest load starves
first.

    e  = dp_set - (P_out - P_sense) - r_ff Q          (the force balance over the spool)
    tau ds/dt = play(s, clip(1/2 + e / p_band, 0, 1), p_h / p_band) - s
    Q  = C_d A_max s sqrt(2/rho) sroot(P_in - P_out) + G_leak (P_in - P_out)

``p_band`` is the regulation range (the spring's gradient over the stroke: the drop moves by
it from closed to fully open), ``p_h`` the hysteresis of the spool's friction, ``r_ff`` the
steady flow force (it closes a spool) as a droop of the held drop with the flow. The edge
passes flow both ways (a spool), and leaks ``G_leak`` when closed; ``check`` puts the
section's load-holding check after it (no reverse flow, a seat's leakage only), as a
pre-compensated section has between its compensator and its directional spool.

Defaults: a 10 ms lag and a 1 bar regulation range (Hopsan's compensating valve: 10 ms;
Simscape's pressure compensator: a regulation range from about 1 bar), 0.3 bar of
hysteresis (friction of a compensator spool, a few per cent of its 10-20 bar spring;
Hopsan's 5 bar is a relief valve's), the flow-force droop of Hopsan's ``k_cf`` (1 bar per
60 L/min). With ``tau = 0`` the spool is static (no hysteresis nor droop: they need its
state).
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .laws import balance, clip01, edge, G_LEAK_POPPET, G_LEAK_SPOOL, spool_rate
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b, c = int(p[0]), int(p[1]), int(p[2])
    k, dp_set, p_band, tau, dp_cr, p_h, r_ff, g = p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10]
    held = P[b] - P[c]
    dp = P[a] - P[b]
    s = clip01(x[0]) if tau > 0.0 else balance(dp_set - held, p_band)
    if dp < 0.0 and p[11] > 0.0:
        q = G_LEAK_POPPET * dp  # the load-holding check is shut
    else:
        q = edge(k, s, dp, dp_cr, g)
    if tau > 0.0:
        dx[0] = spool_rate(x[0], dp_set - held - r_ff * q, p_band, p_h, tau)
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = s
    y[2] = held
    y[3] = q * dp


@dataclass(frozen=True)
class CompensatorParams:
    A_max: float = spec('m^2', 'throttling area fully open', 1.0e-9, 1.0e-2)
    dp_set: float = spec('Pa', 'spring setting: the pressure difference held', 1.0e4, 1.0e7)
    p_band: float = spec('Pa', 'regulation range: the spring gradient over the stroke', 1.0e2,
                         1.0e6, default=1.0e5)
    p_h: float = spec('Pa', "hysteresis of the spool's friction", 0.0, 1.0e6, default=3.0e4)
    r_ff: float = spec('Pa s/m^3', 'flow-force droop of the held difference per flow '
                       "(Hopsan's k_cf: 1 bar per 60 L/min)", 0.0, 1.0e11, default=1.0e8)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    tau: float = spec('s', 'spool time constant; 0 = static', 0.0, 1.0, default=1.0e-2)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=5.0e4)
    G_leak: float = spec('m^3/(s Pa)', "leakage of the closed spool (a spool's clearance: "
                         '0.1 L/min at 100 bar)', 0.0, 1.0e-9, default=G_LEAK_SPOOL)
    check: bool = spec('-', "a load-holding check after the spool (pre; a post "
                       "compensator's spool is one)", default=False)


SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow in -> out'),
           SignalSpec('opening', '-', 'spool opening 0..1'),
           SignalSpec('dp', 'Pa', 'the difference it holds'),
           SignalSpec('loss', 'W', 'power dissipated across it'))


class SpoolCompensator(Component):
    """What the two compensators share: the spool, its state, its packed values."""

    LOSS_GROUP = 'compensators'
    Params = CompensatorParams
    SIGNALS = SIGNALS
    ROLES = frozenset({'compensator'})

    def static_values(self):
        """Its lag off: the opening follows its target at once."""
        return {'tau': 0.0}

    def states(self):
        return (StateSpec('spool', '-', 1.0),) if self.params.tau > 0.0 else ()

    def pack(self):
        r = self.params
        return [coefficient(r.C_d, r.A_max, self.fluid.rho), r.dp_set, r.p_band, r.tau,
                r.dp_cr, r.p_h, r.r_ff, r.G_leak, float(r.check)]

    def initial_state(self, P, u):
        return np.array([1.0]) if self.params.tau > 0.0 else np.array([])


class PreCompensator(SpoolCompensator):
    kind = 'pre_compensator'
    doc = 'pressure compensator before a metering edge: holds its drop at dp_set'
    PORTS = (PortSpec('in', 'supply'), PortSpec('out', 'to the metering edge'),
             PortSpec('sense', 'downstream of the metering edge (the load)', sense=True))
    kernel = kernel

    def metering_drop(self, margin: float) -> float:
        """The drop [Pa] it holds across its section's metering edge."""
        return self.params.dp_set
