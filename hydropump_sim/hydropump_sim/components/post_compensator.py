"""Pressure compensator downstream of a metering edge (post-compensated load sensing, flow
sharing): a spool between ``in`` (the metering edge's outlet) and ``out`` (the load) pushed
open by ``P_in`` and closed by the load-sensing pressure ``P_ls`` plus a light spring
``dp_set``. Every section's metering edge then discharges at ``P_ls + dp_set``: all see the
same drop ``P_supply - P_ls - dp_set``, so their flows keep the ratios of their openings,
and when the pump saturates every load slows in proportion.

    s* = clip(1/2 + ((P_in - P_ls) - dp_set) / p_band, 0, 1),   tau ds/dt = s* - s
    Q  = C_d A_max s sqrt(2/rho) sroot(max(P_in - P_out, 0))      (its check: no reverse flow)
"""


from ..jitcache import jit
from .base import Component, PortSpec, SignalSpec
from .directional_valve import metering
from .laws import balance, clip01, lag
from .orifice import coefficient
from .pre_compensator import CompensatorParams, spool_start, spool_state


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b, c = int(p[0]), int(p[1]), int(p[2])
    k, dp_set, p_band, tau, dp_cr = p[3], p[4], p[5], p[6], p[7]
    held = P[a] - P[c]
    target = balance(held - dp_set, p_band)
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


class PostCompensator(Component):
    kind = 'post_compensator'
    doc = 'flow-sharing compensator after a metering edge: holds its inlet at P_ls + dp_set'
    Params = CompensatorParams
    PORTS = (PortSpec('in', 'from the metering edge'), PortSpec('out', 'to the load'),
             PortSpec('ls', 'load-sensing pressure (the highest load)', sense=True))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow in -> out'),
               SignalSpec('opening', '-', 'spool opening 0..1'),
               SignalSpec('dp', 'Pa', 'P_in - P_ls'))
    kernel = kernel
    ROLES = frozenset({'compensator'})

    def metering_drop(self, margin: float) -> float:
        """The drop [Pa] its section's metering edge sees: the margin less its spring."""
        return margin - self.params.dp_set

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
