"""Hydraulic laws shared by the components: compiled scalar functions, no state.

- :func:`sroot`, :func:`groot`: orifice laws with the laminar regularisation of the pump
  (docs/reference.md I3): ``Q = mu dp^(1/gamma)`` above ``dp_cr``, linear below;
- :func:`continuity`: ``dP/dt = beta(P)/V * q`` with entrained air and the cavitation floor
  (eqs. 3 and 9);
- :func:`stop_force`: a penalty end stop that pushes and never pulls;
- :func:`lag`: a first-order lag toward a target, or the target itself when it has no time
  constant;
- :func:`edge`: a metering edge of a spool or poppet, both ways, with its leakage;
- :func:`play`: the hysteresis (play, backlash) of a spool that friction holds until the
  force on it moves it by more than half the band.

Leakage: every valve passes ``G_leak dp`` through its closed edges, as real valves do (and
as Simscape's leakage area and Hopsan's underlap make them), so no volume is ever sealed by
numerics: a trapped volume's pressure is the one its leakages settle it at. The defaults:
:data:`G_LEAK_SPOOL` (a spool edge: 0.1 L/min at 100 bar, the order of a proportional
valve's catalogue leakage) and :data:`G_LEAK_POPPET` (a seated poppet or ball: about 3
drops a minute at 100 bar).
"""

import math

from ..jitcache import jit


@jit
def sroot(dp, dp_cr):
    """Signed regularised square root: laminar below ``dp_cr``, ``sqrt`` above (I3)."""
    if dp_cr > 0.0:
        return dp / math.sqrt(math.sqrt(dp * dp + dp_cr * dp_cr))
    return math.sqrt(dp) if dp > 0.0 else 0.0


#: Laminar leakage of a spool edge [m^3/(s Pa)]: 0.1 L/min at 100 bar.
G_LEAK_SPOOL = 1.7e-13
#: Laminar leakage of a seated poppet or ball [m^3/(s Pa)]: 0.15 mL/min at 100 bar.
G_LEAK_POPPET = 2.5e-16


@jit
def signed_root(dp, dp_cr):
    """:func:`sroot`, and ``sign(dp) sqrt(|dp|)`` when ``dp_cr`` is 0: an edge's law both
    ways."""
    if dp_cr > 0.0:
        return dp / math.sqrt(math.sqrt(dp * dp + dp_cr * dp_cr))
    return math.sqrt(dp) if dp >= 0.0 else -math.sqrt(-dp)


@jit
def edge(k, s, dp, dp_cr, g_leak):
    """Flow [m^3/s] through a metering edge of coefficient ``k = C_d A sqrt(2/rho)`` at
    opening ``s`` (0..1) under ``dp`` [Pa], in the direction of ``dp`` (reverse flow when the
    pressure reverses), plus its leakage ``g_leak dp``."""
    q = g_leak * dp
    if s > 0.0:
        q += k * s * signed_root(dp, dp_cr)
    return q


@jit
def play(state, target, band):
    """Where a spool with a hysteresis ``band`` (in its own units) is driven from ``state``
    by a force that would put it at ``target``: it stays until the target leaves the band
    around it, then follows at the band's edge (a play operator: rate-independent
    hysteresis of width ``band``)."""
    half = 0.5 * band
    return min(max(state, target - half), target + half)


@jit
def spool_rate(s, error, p_band, p_h, tau):
    """Rate of a pressure-balance spool's opening ``s`` (0..1, a state with lag ``tau``)
    under the pressure ``error`` [Pa] that opens it (the force balance over the spool area:
    the spring setting less what the spool regulates, less the flow-force droop): half open
    at zero error over a regulation range ``p_band``, friction holding it within a
    hysteresis band ``p_h`` [Pa] (:func:`play`, on the force: a spool pushed far beyond an
    end goes there whatever its friction)."""
    target = 0.5 + error / p_band
    return (clip01(play(s, target, p_h / p_band)) - s) / tau


@jit
def groot(dp, dp_cr, gamma):
    """Signed regularised ``dp**(1/gamma)``, linear below ``dp_cr`` (eq. 9, I3)."""
    e = 1.0 / gamma
    if dp_cr > 0.0:
        return dp * (dp * dp + dp_cr * dp_cr) ** (0.5 * (e - 1.0))
    return dp ** e if dp > 0.0 else 0.0


# Penetration, as a fraction of the stroke limit, over which an end stop's damping ramps in.
STOP_RAMP = 0.01


@jit
def stop_force(x, v, x_max, k, c):
    """Penalty end stop at ``+-x_max``: spring and damper that push and never pull.

    The damping ramps in over ``STOP_RAMP * x_max`` of penetration, so the force is continuous
    at contact (a jump there stalls any error-controlled integrator at a fast impact).
    """
    if k <= 0.0:
        return 0.0
    if x > x_max:
        pen = x - x_max
        ramp = min(pen / (STOP_RAMP * x_max), 1.0)
        return min(-k * pen - ramp * c * v, 0.0)
    if x < -x_max:
        pen = x + x_max
        ramp = min(-pen / (STOP_RAMP * x_max), 1.0)
        return max(-k * pen - ramp * c * v, 0.0)
    return 0.0


@jit
def bulk_modulus(P, beta, alpha, p_atm):
    """Effective bulk modulus: pure liquid, or isothermal mixture with entrained air (I4)."""
    if alpha <= 0.0:
        return beta
    p_abs = max(P + p_atm, 1.0)
    theta = alpha / (1.0 - alpha) * p_atm / p_abs
    return beta * (1.0 + theta) / (1.0 + theta * beta / p_abs)


# Relaxation time that returns a pressure pushed below absolute zero by a finite step [s].
FLOOR_RELAX = 1.0e-4


@jit
def continuity(P, flow, volume, beta, alpha, p_atm, floor, dp_floor):
    """Continuity ``dP/dt = beta/V * flow`` with the cavitation floor at absolute zero.

    Within ``dp_floor`` of absolute zero an outflow lowers the pressure ever more slowly (the
    liquid cavitates instead), and a pressure below zero relaxes back in ``FLOOR_RELAX``;
    ``floor`` (0 or 1) switches this off or on.
    """
    d = bulk_modulus(P, beta, alpha, p_atm) / volume * flow
    if floor > 0.0:
        p_abs = P + p_atm
        if d < 0.0 and p_abs < dp_floor:
            d *= max(p_abs, 0.0) / dp_floor
        if p_abs < 0.0:
            d -= p_abs / FLOOR_RELAX
    return d


@jit
def lag(state, target, tau):
    """Rate of a first-order lag of time constant ``tau`` toward ``target``."""
    return (target - state) / tau


@jit
def clip01(v):
    """``v`` limited to [0, 1]."""
    return min(max(v, 0.0), 1.0)


@jit
def balance(error, p_band):
    """Opening 0..1 of a pressure-balance spool: half open at zero ``error`` [Pa] (the
    spring setting), fully open ``p_band / 2`` above it, closed ``p_band / 2`` below."""
    return clip01(0.5 + error / p_band)
