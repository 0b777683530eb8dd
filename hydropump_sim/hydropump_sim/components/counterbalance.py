"""Counterbalance (over-centre) valve: holds a hanging load at ``load`` (the cylinder side)
and lets it down only as the opposite line's pressure at ``pilot`` (sensed, no flow)
opens it, against the directional valve at ``valve``.

Free flow valve -> load through the integral check (crack ``p_check``, fully lifted at
``p_check_full``):

    c = clip((P_valve - P_load - p_check) / (p_check_full - p_check), 0, 1)
    Q_check = k_c c sroot(P_valve - P_load)                    (valve -> load only)

Controlled flow load -> valve: the poppet (spring chamber vented, so the back pressure at
``valve`` does not add to the setting) opens when the load pressure plus the pilot
pressure times the pilot ratio reaches the setting, proportionally over ``p_band``; the
steady flow force on it stiffens its spring as the drop ``dp = P_load - P_valve`` rises
(the force ``2 C_d w x dp cos(theta)`` is a spring rate proportional to ``dp``), a droop
that equals the spring's at ``dp = dp_ff``:

    f   = 1 + max(dp, 0) / dp_ff                         (1 when dp_ff = 0: no droop)
    s*  = (P_load + ratio P_pilot - p_set) / (p_band f)  (its target opening, unclipped)
    tau dz/dt = play(z, clip(s*, -h/2, 1 + h/2), h) - z,     h = p_h / (p_band f)
    s   = clip(z, 0, 1),     Q = k s sroot(dp) + G_leak dp

``play`` is the hysteresis of the poppet's friction (laws.play): rising, it opens at
``p_set + p_h/2``; falling, it closes at ``p_set - p_h/2``. With ``tau = 0`` the opening
is ``clip(s*, 0, 1)`` at once (no hysteresis, no state). ``G_leak dp`` is the seat's
leakage, both ways: what a held load drifts by, ``G_leak P_load / A_a`` for a cylinder of
cap area ``A_a``. The main poppet passes reverse flow when the pilot holds it open and the
pressure reverses (laws.edge); the check passes only valve -> load.

Defaults and their sources:

- ``ratio`` 5: Hopsan's over-centre valve default (a_ratio 5.0), in the usual 3:1 .. 8:1;
- ``tau`` 10 ms and ``p_h`` 5 bar: Hopsan's over-centre valve defaults;
- ``dp_ff`` 70 bar: Hopsan's over-centre valve has equal spring and flow-force gradients
  (k_cs = k_cf) at its p_nom of 70 bar, i.e. the flow force doubles its stiffness there;
- ``p_band`` 10 bar: the pressure rise from cracking to full opening, about 5 % of a
  200-bar setting, the override of a pressure-control cartridge (Hopsan's static gradient
  q_nom/k_cs is 1 bar for 60 L/min, stiffer: a hanging mass on a stiff counterbalance
  oscillates, a wider band is the usual cure);
- ``p_check`` 0.35 bar, fully lifted at 1.5 bar: a light check spring (0.3-0.5 bar, so free
  flow into the cylinder costs little), its poppet lifted by about a bar more;
- ``p_set`` has no default: it is 1.3 x the highest load-induced pressure of the circuit;
- ``G_leak`` laws.G_LEAK_POPPET (a seated poppet: 0.15 mL/min at 100 bar), ``C_d`` 0.65 and
  ``dp_cr`` 0.1 bar as the project's check_valve.
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import must_exceed, spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .laws import clip01, edge, G_LEAK_POPPET, lag, play, sroot
from .orifice import coefficient


@jit
def stiffening(dp, dp_ff):
    """The flow force's factor on the spring's gradient at the drop ``dp``."""
    if dp_ff <= 0.0:
        return 1.0
    return 1.0 + max(dp, 0.0) / dp_ff


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    il, iv, ip = int(p[0]), int(p[1]), int(p[2])
    k, k_c, p_set, ratio, p_band, p_h, tau = p[3], p[4], p[5], p[6], p[7], p[8], p[9]
    dp_ff, p_check, p_check_full, dp_cr, g = p[10], p[11], p[12], p[13], p[14]
    pl, pv = P[il], P[iv]
    dp = pl - pv
    band = p_band * stiffening(dp, dp_ff)
    target = (pl + ratio * P[ip] - p_set) / band
    if tau > 0.0:
        h = p_h / band
        goal = min(max(target, -0.5 * h), 1.0 + 0.5 * h)
        dx[0] = lag(x[0], play(x[0], goal, h), tau)
        s = clip01(x[0])
    else:
        s = clip01(target)
    q = edge(k, s, dp, dp_cr, g)
    c = clip01((-dp - p_check) / (p_check_full - p_check))
    q_c = k_c * c * sroot(-dp, dp_cr) if c > 0.0 else 0.0
    net = q - q_c
    Q[il] -= net
    Q[iv] += net
    y[0] = net
    y[1] = s
    y[2] = q * dp - q_c * dp


@dataclass(frozen=True)
class CounterbalanceParams:
    A: float = spec('m^2', 'flow area of the main poppet fully open', 1.0e-9, 1.0e-2)
    p_set: float = spec('Pa', 'setting: opens when P_load + ratio P_pilot reaches it (1.3 x '
                        'the highest load-induced pressure)', 1.0e5, 1.0e8)
    ratio: float = spec('-', 'pilot ratio (pilot area over seat area; 3:1 .. 8:1)', 0.1, 50.0,
                        default=5.0)
    p_band: float = spec('Pa', 'regulation range: pressure rise from cracking to full '
                         'opening', 1.0e3, 1.0e7, default=1.0e6)
    p_h: float = spec('Pa', 'hysteresis band of the poppet (Hopsan 5 bar)', 0.0, 1.0e7,
                      default=5.0e5)
    tau: float = spec('s', 'poppet time constant (Hopsan 10 ms); 0 = static, no hysteresis',
                      0.0, 1.0, default=0.01)
    dp_ff: float = spec('Pa', 'drop at which the flow force doubles the spring gradient '
                        '(Hopsan 70 bar); 0 = no flow-force droop', 0.0, 1.0e9, default=7.0e6)
    A_check: float = spec('m^2', 'flow area of the integral check fully open; 0 = A', 0.0,
                          1.0e-2, default=0.0)
    p_check: float = spec('Pa', 'cracking pressure of the integral check', 0.0, 1.0e6,
                          default=3.5e4)
    p_check_full: float = spec('Pa', 'pressure difference of the check fully open', 1.0e3,
                               1.0e7, default=1.5e5)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    G_leak: float = spec('m^3/(s Pa)', 'seat leakage (laws.G_LEAK_POPPET: 0.15 mL/min at '
                         '100 bar)', 0.0, 1.0e-9, default=G_LEAK_POPPET)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=1.0e4)

    def cross_checks(self):
        return must_exceed('p_check_full', self.p_check_full, 'p_check', self.p_check)


class Counterbalance(Component):
    kind = 'counterbalance'
    LOSS_GROUP = 'holding'
    doc = 'counterbalance valve: holds a load, pilot-opened descent, free-flow check'
    Params = CounterbalanceParams
    PORTS = (PortSpec('load', 'cylinder side'),
             PortSpec('valve', 'directional valve side'),
             PortSpec('pilot', 'the opposite line (sensed)', sense=True))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'flow load -> valve (negative through the check)'),
               SignalSpec('opening', '-', 'main poppet opening 0..1'),
               SignalSpec('loss', 'W', 'power dissipated in the poppet and the check'))
    kernel = kernel

    def static_values(self):
        """Its lag off: the opening follows its target at once."""
        return {'tau': 0.0}

    def states(self):
        return (StateSpec('opening', '-', 1.0),) if self.params.tau > 0.0 else ()

    def pack(self):
        r = self.params
        rho = self.fluid.rho
        a_check = r.A_check if r.A_check > 0.0 else r.A
        return [coefficient(r.C_d, r.A, rho), coefficient(r.C_d, a_check, rho), r.p_set,
                r.ratio, r.p_band, r.p_h, r.tau, r.dp_ff, r.p_check, r.p_check_full, r.dp_cr,
                r.G_leak]

    def initial_state(self, P, u):
        r = self.params
        if r.tau <= 0.0:
            return np.array([])
        dp = P['load'] - P['valve']
        f = 1.0 + max(dp, 0.0) / r.dp_ff if r.dp_ff > 0.0 else 1.0
        s = (P['load'] + r.ratio * P['pilot'] - r.p_set) / (r.p_band * f)
        return np.array([min(max(s, 0.0), 1.0)])
