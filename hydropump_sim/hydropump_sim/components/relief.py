"""Relief valve of Fig. 1: a poppet that cracks at ``p_crack`` and is fully open at
``p_full``, where it passes ``q_full``.

    s* = clip((dp - p_crack) / (p_full - p_crack), 0, 1),     dp = P_in - P_out
    Q  = q_full s sqrt(dp / p_full)                            (in -> out, dp > 0)

With ``tau > 0`` the opening ``s`` follows ``s*`` with that first-order lag (the poppet's
dynamics) and a hysteresis ``p_h`` (:func:`~.laws.play`: the poppet's friction holds it
until the pressure moves by half the band); with ``tau = 0`` it is ``s*`` itself, the static
law of the paper's plant. Its seat leaks ``G_leak dp`` (default a poppet's,
:data:`~.laws.G_LEAK_POPPET`). Hopsan's relief valve takes 10 ms and 5 bar; the defaults
here are the paper's static valve (no lag, no hysteresis), which circuit files override.
"""

from dataclasses import dataclass
import math

from ..jitcache import jit
from ..schema import must_exceed, spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .laws import clip01, G_LEAK_POPPET, play


@jit
def opening(dp, p_crack, p_full):
    """The static opening ``s*`` at pressure difference ``dp``."""
    if dp <= p_crack:
        return 0.0
    return min((dp - p_crack) / (p_full - p_crack), 1.0)


@jit
def flow(dp, s, p_full, q_full):
    """Flow at opening ``s`` and pressure difference ``dp`` (none backwards)."""
    if s <= 0.0 or dp <= 0.0:
        return 0.0
    return q_full * s * math.sqrt(dp / p_full)


@jit
def static_flow(dp, p_crack, p_full, q_full):
    """The paper plant's relief law (no poppet lag)."""
    if dp <= p_crack:
        return 0.0
    return q_full * opening(dp, p_crack, p_full) * math.sqrt(dp / p_full)


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    p_crack, p_full, q_full, tau, p_h, g = p[2], p[3], p[4], p[5], p[6], p[7]
    dp = P[a] - P[b]
    if tau > 0.0:
        s = clip01(x[0])
        span = p_full - p_crack
        target = clip01(play(s, (dp - p_crack) / span, p_h / span))
        dx[0] = (target - x[0]) / tau
        q = flow(dp, s, p_full, q_full)
    else:
        s = opening(dp, p_crack, p_full)
        q = static_flow(dp, p_crack, p_full, q_full)
    q += g * dp
    Q[a] -= q
    Q[b] += q
    y[0] = q
    y[1] = s
    y[2] = P[a]
    y[3] = q * dp


@dataclass(frozen=True)
class ReliefParams:
    p_crack: float = spec('Pa', 'cracking pressure difference', 1.0e5, 1.0e8)
    p_full: float = spec('Pa', 'pressure difference of full opening', 1.0e5, 1.0e8)
    q_full: float = spec('m^3/s', 'flow at p_full', 1.0e-7, 1.0)
    tau: float = spec('s', 'poppet time constant; 0 = static', 0.0, 1.0, default=0.0)
    p_h: float = spec('Pa', "hysteresis of the poppet's friction (with tau > 0)", 0.0, 5.0e6,
                      default=0.0)
    G_leak: float = spec('m^3/(s Pa)', 'leakage of the closed seat', 0.0, 1.0e-9,
                         default=G_LEAK_POPPET)

    def cross_checks(self):
        return must_exceed('p_full', self.p_full, 'p_crack', self.p_crack)


class Relief(Component):
    kind = 'relief'
    LOSS_GROUP = 'relief'
    doc = 'relief valve: cracks at p_crack, full flow q_full at p_full, optional poppet lag'
    Params = ReliefParams
    PORTS = (PortSpec('in', 'protected node'), PortSpec('out', 'tank side'))
    SIGNALS = (SignalSpec('flow', 'm^3/s', 'relieved flow in -> out'),
               SignalSpec('opening', '-', 'poppet opening 0..1'),
               SignalSpec('pressure', 'Pa', 'pressure at the inlet'),
               SignalSpec('loss', 'W', 'power dissipated'))
    kernel = kernel
    ROLES = frozenset({'pressure_limit'})

    def pressure_cap(self, u):
        """Full flow at ``p_full``, and one more regulation range (``p_full - p_crack``)
        for the poppet's lag and a flow beyond ``q_full``."""
        r = self.params
        return 2.0 * r.p_full - r.p_crack

    def relief_law(self):
        r = self.params
        return r.p_crack, r.p_full, r.q_full

    def static_values(self):
        """Its lag off: the opening follows its target at once."""
        return {'tau': 0.0}

    def states(self):
        return (StateSpec('opening', '-', 1.0),) if self.params.tau > 0.0 else ()

    def pack(self):
        r = self.params
        return [r.p_crack, r.p_full, r.q_full, r.tau, r.p_h, r.G_leak]
