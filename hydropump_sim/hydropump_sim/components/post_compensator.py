"""Pressure compensator downstream of a metering edge (post-compensated load sensing, flow
sharing): a spool between ``in`` (the metering edge's outlet) and ``out`` (the load) pushed
open by ``P_in`` and closed by the load-sensing pressure ``P_ls`` plus a light spring
``dp_set``. Every section's metering edge then discharges at ``P_ls + dp_set``: all see the
same drop ``P_supply - P_ls - dp_set``, so their flows keep the ratios of their openings,
and when the pump saturates every load slows in proportion.

    e  = (P_in - P_ls) - dp_set - r_ff Q
    tau ds/dt = play(s, clip(1/2 + e / p_band, 0, 1), p_h / p_band) - s
    Q  = C_d A_max s sqrt(2/rho) sroot(P_in - P_out) + G_leak (P_in - P_out),   P_in > P_out

Its spool is also the section's load-holding check (as in flow-sharing valve sections): no
reverse flow, only a seat's leakage. Spool, regulation range, hysteresis, flow-force droop
and defaults as the pre-compensator's (:mod:`.pre_compensator`).
"""

from ..jitcache import jit
from .base import PortSpec
from .laws import balance, clip01, edge, G_LEAK_POPPET, spool_rate
from .pre_compensator import SpoolCompensator


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b, c = int(p[0]), int(p[1]), int(p[2])
    k, dp_set, p_band, tau, dp_cr, p_h, r_ff, g = p[3], p[4], p[5], p[6], p[7], p[8], p[9], p[10]
    held = P[a] - P[c]
    dp = P[a] - P[b]
    if tau > 0.0:
        s = clip01(x[0])
    else:
        s = balance(held - dp_set, p_band)
    q = edge(k, s, dp, dp_cr, g) if dp > 0.0 else G_LEAK_POPPET * dp
    if tau > 0.0:
        dx[0] = spool_rate(x[0], held - dp_set - r_ff * q, p_band, p_h, tau)
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = s
    y[2] = held
    y[3] = q * dp


class PostCompensator(SpoolCompensator):
    kind = 'post_compensator'
    doc = 'flow-sharing compensator after a metering edge: holds its inlet at P_ls + dp_set'
    PORTS = (PortSpec('in', 'from the metering edge'), PortSpec('out', 'to the load'),
             PortSpec('ls', 'load-sensing pressure (the highest load)', sense=True))
    kernel = kernel

    def metering_drop(self, margin: float) -> float:
        """The drop [Pa] its section's metering edge sees: the margin less its spring."""
        return margin - self.params.dp_set
