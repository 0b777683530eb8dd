"""The paper's plant with its fixed layout: the pump, the line volume, the load of eq. 9 and
the relief valve of Fig. 1, as ``simulate()``, the trim, the linearisation and the
calibration use it.

The equations are the components' (``hydropump_sim/components``): the pump's
:func:`~hydropump_sim.components.pump.pump_equations` (eqs. 1-8), the load law of
``orifice_load``, the relief law of ``relief`` and continuity (eq. 9). ``config/circuits/
paper.yaml`` is the same plant as a circuit, compiled from the same functions. The packed
parameter vector is the pump's (``P_*``, built by :func:`hydropump_sim.model.pack`), which
also carries the line's and the relief valve's entries.

Models (``p[P_MODEL]``):

- ``FINE``: the 6th-order fine model, eqs. 1-9 (7th state with solenoid current dynamics);
- ``SIMPLIFIED``: eqs. 10, 12 (first line) and 9, eq. 10 as printed (drops ``K_c``);
- ``SIMPLIFIED_KC``: the same, keeping ``K_c`` in the quasi-static spool position.

``evaluate`` is compiled twice: as a numba function for direct calls and as a ``cfunc``
(:data:`evaluate_c`) for the stepper of :mod:`hydropump_sim.integrator`.
"""

import numpy as np

from . import integrator as ig
from .components.laws import groot
from .components.orifice_load import load_flow
from .components.pump import (
    chamber_rate,
    FINE,
    P_DITHA,
    P_DITHF,
    P_DPCRU,
    P_GAMMA,
    P_IMAX,
    P_IMIN,
    P_MODEL,
    P_MUU,
    P_PATM,
    P_PCRACK,
    P_PFULL,
    P_QFULL,
    P_RELIEF,
    P_TAUS,
    P_VL,
    P_XASTOP,
    pump_equations,
    pump_flow,
)
from .components.pump import state_scale as pump_scale
from .components.relief import static_flow
from .jitcache import cfunc, jit

# What the plant modules (trim, linear, simulate) take from here besides the layouts below.
__all__ = ['FINE', 'N_U', 'N_Y', 'P_DITHA', 'P_DPCRU', 'P_GAMMA', 'P_MUU', 'P_PATM',
           'evaluate', 'evaluate_c', 'groot', 'pump_flow', 'relief_flow', 'state_scale',
           'structure']

# Inputs: the solenoid current I_s [A] (absolute, as the pump component's), load pressure
# P_u [Pa], aperture xi_u [-], shaft frequency f_p [Hz].
U_I, U_PU, U_XI, U_FP, N_U = range(5)

# Outputs: the pump's signals (components/pump.py Y_*), then the load and relief flows and
# the held load pressure.
(Y_IS, Y_XC, Y_VC, Y_XA, Y_VA, Y_PA, Y_PL, Y_QP, Y_QA, Y_QL, Y_QLOAD, Y_QRELIEF, Y_PU,
 N_Y) = range(14)




@jit
def relief_flow(P_l, p):
    """Relief valve of Fig. 1 on the line (components/relief.py, static)."""
    if p[P_RELIEF] <= 0.0:
        return 0.0
    return static_flow(P_l, p[P_PCRACK], p[P_PFULL], p[P_QFULL])


@jit
def n_states(p):
    """Number of states of the model selected in ``p``."""
    if p[P_MODEL] != FINE:
        return 2
    return 7 if p[P_TAUS] > 0.0 else 6


def _evaluate(t, x, u, p, dx, y):
    """Right-hand side and outputs in one pass.

    Parameters
    ----------
    t : float
        Time [s] (dither phase).
    x : ndarray, shape (n,)
        Fine: ``[x_c, v_c, x_a, v_a, P_a, P_l(, i)]`` in m, m/s, Pa (gauge), A.
        Simplified: ``[x_a, P_l]``.
    u : ndarray, shape (4,)
        ``[I_s, P_u, xi_u, f_p]``: solenoid current [A] (eq. 2's variation is
        ``I_s - I_min - I_max``), load pressure [Pa], aperture [-], shaft frequency [Hz].
    p : ndarray
        Packed parameters.
    dx : ndarray, shape (n,)
        Filled with the state derivative.
    y : ndarray, shape (N_Y,)
        Filled with the outputs (``Y_*`` layout).
    """
    k_l = 5 if p[P_MODEL] == FINE else 1
    P_l = x[k_l]
    q_l = pump_equations(t, x, dx, 6, P_l, u[U_I] - (p[P_IMIN] + p[P_IMAX]), u[U_FP], p, y)
    # Eq. 9: the load orifice, then the relief valve of Fig. 1.
    Q_load = load_flow(P_l, u[U_PU], u[U_XI], p[P_MUU], p[P_DPCRU], p[P_GAMMA])
    Q_r = relief_flow(P_l, p)
    dx[k_l] = chamber_rate(P_l, q_l - Q_load - Q_r, p[P_VL], p)
    y[Y_QLOAD] = Q_load
    y[Y_QRELIEF] = Q_r
    y[Y_PU] = u[U_PU]


evaluate = jit(_evaluate)
evaluate_c = cfunc(ig.EVALUATE)(_evaluate)


@jit
def state_scale(p, n):
    """Typical magnitude of each state, for tolerances and finite differences."""
    if p[P_MODEL] == FINE:
        s = pump_scale(p, n)
        s[5] = 1.0e6
        return s
    s = np.empty(n)
    s[0] = p[P_XASTOP]
    s[1] = 1.0e6
    return s


def structure(p: np.ndarray, n: int) -> dict:
    """What the stepper needs besides ``evaluate_c`` (integrator module): state scales, a
    dense Jacobian, and the dither's time dependence."""
    colors, pattern = ig.dense(n)
    freq = max(float(p[P_DITHF]), 1.0)
    return {'scale': state_scale(p, n), 'colors': colors, 'pattern': pattern,
            'timed': bool(p[P_DITHA] > 0.0), 'dt_time': 1.0e-7 / freq}
