"""The FOPDT model of eq. 19 and its exact sampled form.

The paper models the path from the solenoid current ``i_s`` to the line flow ``q_l`` as

    G(s) = G0 / (1 + tau s) * exp(-s t_d)                                      (eq. 19)

with the current as the fraction of the range that spans 0..100 % displacement and the flow in
% of ``V_p f_p``, so a full-range gain is ``G0 = 100``; ``tau`` and ``t_d`` are in seconds.

Exact sampled model. With the input held over ``[k T, (k+1) T)`` and ``t_d = (d + f) T``
(``d`` whole samples, ``0 <= f < 1``), the delayed input changes inside each period at
``f T``, so the first-order lag integrates two input values per period (the modified
z-transform):

    x[k+1] = a x[k] + (1 - c) u[k-d] + (c - a) u[k-d-1],
    a = exp(-T/tau),  c = exp(-(1-f) T/tau),  y[k] = G0 x[k] (+ offset).

This module owns the parameter names, the paper's result and that recursion; the fits build
on it.
"""

from __future__ import annotations

import math

import numpy as np

# The paper's result (section V): value and "±" (spread over nine data sets), SI.
PAPER = {'G0': (100.0, 0.7), 'tau': (0.100, 0.002), 'td': (0.055, 0.0055)}
PARAMS = ('G0', 'tau', 'td')


def coefficients(tau: float, td: float, dt: float) -> tuple[float, float, float, int, float]:
    """Coefficients of the exact sampled eq. 19 for a held input.

    Parameters
    ----------
    tau, td, dt : float
        Time constant, delay and sample period [s]; ``tau > 0``, ``td >= 0``.

    Returns
    -------
    a, b1, b2 : float
        ``x[k+1] = a x[k] + b1 u[k-d] + b2 u[k-d-1]`` (``b1 + b2 = 1 - a``: unit gain).
    d : int
        Whole samples of the delay.
    f : float
        Fraction of a sample, ``td = (d + f) dt``.
    """
    q = td / dt
    d = int(math.floor(q))
    f = q - d
    a = math.exp(-dt / tau)
    c = math.exp(-(1.0 - f) * dt / tau)
    return a, 1.0 - c, c - a, d, f


def shift(v: np.ndarray, m: int) -> np.ndarray:
    """``v[k - m]`` with zeros before the start (a zero pre-history)."""
    out = np.zeros_like(v)
    if m < v.size:
        out[m:] = v[:v.size - m]
    return out


def zero_state_response(v: np.ndarray, dt: float, tau: float, td: float) -> np.ndarray:
    """Unit-gain response from zero state to ``v`` with a zero pre-history."""
    a, b1, b2, d, _ = coefficients(tau, td, dt)
    w = b1 * shift(v, d) + b2 * shift(v, d + 1)
    x = np.empty_like(v)
    x[0] = 0.0
    # scipy.signal takes half a second to import: only here, where it is used.
    from scipy import signal
    x[1:] = signal.lfilter([1.0], [1.0, -a], w[:-1])
    return x


def fopdt_response(u, dt: float, G0: float, tau: float, td: float, *, offset: float = 0.0,
                   u_before: float | None = None) -> np.ndarray:
    """Exact sampled response of eq. 19 to an input held between samples.

    The system starts in steady state at the input ``u_before`` (default ``u[0]``), which
    also fills the input history before the record.

    Parameters
    ----------
    u : array_like
        Input samples; ``u[k]`` is held over ``[k dt, (k+1) dt)``.
    dt : float
        Sample period [s].
    G0, tau, td : float
        Gain, time constant [s] and delay [s] (any fraction of a sample).
    offset : float
        Output at zero input.
    u_before : float, optional
        Input before the record.

    Returns
    -------
    ndarray
        ``y[k]``, the output at ``k dt``.
    """
    u = np.asarray(u, dtype=float)
    u0 = float(u[0]) if u_before is None else float(u_before)
    x = zero_state_response(u - u0, dt, tau, td)
    return offset + G0 * (u0 + x)
