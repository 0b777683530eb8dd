"""Model functions: packed parameters, state and output names, ``rhs`` and ``outputs``.

The model holds no state. ``rhs(t, x, u, params)`` follows python-control's ``nlsys``
convention; the equations themselves live in :mod:`hydropump_sim._core`.
"""

from __future__ import annotations

import numpy as np

from . import _core as c
from .components.pump import BRANCHES, model_code, MODELS, pack  # noqa: F401
from .params import Params

FINE_STATES = ('x_c', 'v_c', 'x_a', 'v_a', 'P_a', 'P_l')
FINE_UNITS = ('m', 'm/s', 'm', 'm/s', 'Pa', 'Pa')
SIMPLIFIED_STATES = ('x_a', 'P_l')
OUTPUTS = ('I_s', 'x_c', 'v_c', 'x_a', 'v_a', 'P_a', 'P_l', 'Q_p', 'Q_a', 'q_l', 'Q_load',
           'Q_relief', 'P_u')
OUTPUT_UNITS = ('A', 'm', 'm/s', 'm', 'm/s', 'Pa', 'Pa', 'm^3/s', 'm^3/s', 'm^3/s', 'm^3/s',
                'm^3/s', 'Pa')
#: The paper's inputs, as its linear models name them (deviations: ``i_s`` is eq. 2's).
INPUTS = ('i_s', 'P_u', 'xi_u', 'f_p')
INPUT_UNITS = ('A', 'Pa', '-', 'Hz')


def state_names(params: Params, model: str = 'fine') -> tuple[str, ...]:
    """Names of the states of ``model`` (the fine model gains ``i`` with ``tau_s > 0``)."""
    if model != 'fine':
        return SIMPLIFIED_STATES
    return FINE_STATES + (('i',) if params.input.tau_s > 0.0 else ())


def nominal_inputs(params: Params, i_s: float = 0.0) -> np.ndarray:
    """Input vector ``[I_s, P_u, xi_u, f_p]`` (absolute current, ``i_s`` its variation of
    eq. 2) at the parameter file's operating point."""
    return np.array([params.I_nominal + i_s, params.line.P_u, params.line.xi_u,
                     params.pump.f_p])


def rhs(t: float, x, u, params: Params, model: str = 'fine', branch: str | None = None,
        p: np.ndarray | None = None) -> np.ndarray:
    """State derivative ``dx/dt``.

    Parameters
    ----------
    t : float
        Time [s].
    x : array_like, shape (n,)
        State, see :func:`state_names` (SI, gauge pressures).
    u : array_like, shape (4,)
        ``[I_s, P_u, xi_u, f_p]`` in A, Pa, -, Hz; ``I_s`` the absolute current.
    params : Params
    model, branch : str
        See :func:`pack`. ``p`` may pass a pre-packed vector instead.

    Returns
    -------
    ndarray, shape (n,)
    """
    p = pack(params, model, branch) if p is None else p
    x = np.asarray(x, dtype=float)
    dx = np.empty_like(x)
    c.evaluate(float(t), x, np.asarray(u, dtype=float), p, dx, np.empty(c.N_Y))
    return dx


def outputs(t: float, x, u, params: Params, model: str = 'fine', branch: str | None = None,
            p: np.ndarray | None = None) -> dict[str, float]:
    """Outputs (``OUTPUTS`` names, SI) at one state, as a dictionary."""
    p = pack(params, model, branch) if p is None else p
    x = np.asarray(x, dtype=float)
    y = np.empty(c.N_Y)
    c.evaluate(float(t), x, np.asarray(u, dtype=float), p, np.empty_like(x), y)
    return dict(zip(OUTPUTS, y.tolist()))


def pump_flow(params: Params, x_a, f_p: float | None = None) -> np.ndarray:
    """Pump flow ``Q_p`` of eq. 8 [m^3/s] for plate positions ``x_a`` [m] (array or number),
    in the parameters' ``flow_map`` reading, with ``disp_clip``; ``f_p`` [Hz] defaults to the
    parameter file's shaft speed."""
    p = pack(params)
    f = params.pump.f_p if f_p is None else float(f_p)
    x = np.asarray(x_a, dtype=float)
    out = np.array([c.pump_flow(float(v), f, p) for v in x.ravel()]).reshape(x.shape)
    return out if out.ndim else float(out)
