"""Proportional directional valve, meter-in (the operator's lever or joystick): the metering
edge from ``in`` (P) to ``out`` (A) opens with the command ``xi`` (0..1) through a
first-order spool lag:

    tau dxi_s/dt = xi - xi_s,     Q = C_d A_max xi_s sqrt(2/rho) sroot(P_in - P_out) + G_leak dp

The edge passes flow both ways and leaks ``G_leak`` (a spool's clearance) when closed.
``check`` puts the section's load-holding check in series (the P-channel check of a
load-sensing valve section): no reverse flow through the edge then, only the seat's
leakage ``G_LEAK_POPPET dp``. With ``tau = 0`` the spool follows the command at once.

The spool also switches the section's load-sensing signal, as a valve section of a
load-sensing block does: the node at ``ls`` is connected to the work port through a small
passage while the spool is open and drained to ``drain`` while it is closed, so an idle
section's trapped load pressure is never sensed (``ls_from`` takes the signal elsewhere,
e.g. the load behind a post compensator):

    g = clip(xi_s / ls_open, 0, 1)    (the passage switches early in the spool's travel)
    Q_ls = k_ls g sroot(P_out - P_ls),     Q_drain = k_ls (1 - g) sroot(P_ls - P_drain)
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, JointSpec, PortSpec, SignalSpec, StateSpec
from .laws import clip01, edge, G_LEAK_POPPET, G_LEAK_SPOOL, lag, sroot
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    k, dp_cr, tau = p[5], p[6], p[7]
    cmd = clip01(u[0])
    if tau > 0.0:
        dx[0] = lag(x[0], cmd, tau)
        s = clip01(x[0])
    else:
        s = cmd
    dp = P[a] - P[b]
    if dp < 0.0 and p[11] > 0.0:
        q = G_LEAK_POPPET * dp  # the load-holding check is shut
    else:
        q = edge(k, s, dp, dp_cr, p[10])
    Q[a] -= q
    Q[b] += q
    loss = q * dp
    ls, drain, src, k_ls = int(p[2]), int(p[3]), int(p[4]), p[8]
    if src < 0:
        src = b
    if ls >= 0:
        g = clip01(s / p[9])
        dp_s = P[src] - P[ls]
        q_s = k_ls * g * sroot(dp_s, dp_cr)
        Q[src] -= q_s
        Q[ls] += q_s
        loss += q_s * dp_s
        if drain >= 0:
            dp_d = P[ls] - P[drain]
            q_d = k_ls * (1.0 - g) * sroot(dp_d, dp_cr)
            Q[ls] -= q_d
            Q[drain] += q_d
            loss += q_d * dp_d
    y[0] = q
    y[1] = s
    y[2] = dp
    y[3] = loss


@dataclass(frozen=True)
class ValveParams:
    A_max: float = spec('m^2', 'metering area fully open', 1.0e-9, 1.0e-2)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    tau: float = spec('s', 'spool time constant; 0 = follows the command', 0.0, 1.0,
                      default=0.02)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=5.0e4)
    command: float = spec('-', 'command 0..1 (an input)', 0.0, 1.0, default=0.0)
    A_ls: float = spec('m^2', 'area of the load-sensing passage (ls port): a 2 mm drilling',
                       1.0e-10, 1.0e-4, default=3.0e-6)
    ls_open: float = spec('-', 'spool opening at which the load-sensing passage is fully '
                          'switched from drain to the work port', 1.0e-3, 1.0, default=0.05)
    G_leak: float = spec('m^3/(s Pa)', "leakage of the closed edge (a spool's clearance: 0.1 "
                         'L/min at 100 bar)', 0.0, 1.0e-9, default=G_LEAK_SPOOL)
    check: bool = spec('-', "the section's load-holding check in series: no reverse flow",
                       default=True)


class DirectionalValve(Component):
    kind = 'directional_valve'
    LOSS_GROUP = 'metering'
    doc = 'proportional meter-in valve P -> A with a spool lag and a load-holding check'
    Params = ValveParams
    PORTS = (PortSpec('in', 'pressure port P'), PortSpec('out', 'work port A'),
             PortSpec('ls', 'load-sensing signal of the section', optional=True),
             PortSpec('drain', 'where the signal drains when closed', optional=True),
             PortSpec('ls_from', 'where the signal is taken (default: the work port; the '
                      'load behind a post compensator)', optional=True))
    INPUTS = (InputSpec('command', '-', 'valve command 0..1', 0.0, 1.0, 'command'),)
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'metered flow P -> A'),
               SignalSpec('opening', '-', 'spool opening 0..1'),
               SignalSpec('dp', 'Pa', 'metering pressure drop'),
               SignalSpec('loss', 'W', 'power dissipated in the edge and the LS passage'))
    kernel = kernel
    JOINTS = (JointSpec('', 'opening', None),)

    def static_values(self):
        """Its lag off: the opening follows its target at once."""
        return {'tau': 0.0}

    def states(self):
        return (StateSpec('spool', '-', 1.0),) if self.params.tau > 0.0 else ()

    def pack(self):
        r = self.params
        rho = self.fluid.rho
        return [coefficient(r.C_d, r.A_max, rho), r.dp_cr, r.tau, coefficient(r.C_d, r.A_ls, rho),
                r.ls_open, r.G_leak, float(r.check)]

    def initial_state(self, P, u):
        if self.params.tau <= 0.0:
            return np.array([])
        return np.array([min(max(float(u['command']), 0.0), 1.0)])
