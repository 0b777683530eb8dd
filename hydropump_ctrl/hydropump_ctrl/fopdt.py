"""FOPDT identification of the current-to-flow path (section V of the paper, eqs. 19-20).

The paper models the path from the solenoid current ``i_s`` to the line flow ``q_l`` as

    G(s) = G0 / (1 + tau s) * exp(-s t_d)                                      (eq. 19)

and fits ``G0``, ``tau`` and ``t_d`` by minimising the sum of squared flow errors

    J = sum_i (q_l,m - q_l,i)^2                                                 (eq. 20)

with Nelder-Mead (MATLAB ``fminsearch``) over nine data sets. Signals are normalised as in the
paper: the current is the fraction of the current range that spans 0..100 % displacement, the
flow is in % of ``V_p f_p``, so a full-range gain is ``G0 = 100``. ``tau`` and ``t_d`` are in
seconds everywhere inside this module.

Two methods:

``paper``
    Nelder-Mead on eq. 20 from seeds taken from the step data (Smith's two-point method on
    the largest up-step), in deviation variables from the initial steady state, as the paper
    does. No bounds, no offset or initial-state parameters.
``robust`` (default)
    The exact sampled response of eq. 19 for an input held between samples, with a fractional
    delay (no Pade, no rounding to whole samples), a free offset and a free initial state; a
    global grid over the delay (all whole-sample delays in the bounds, each with the best
    ``tau`` of a log grid, the linear parameters solved in closed form), then a bounded local
    least-squares fit of all parameters from the best grid minima. A sinusoidal dither on
    the current (not held between samples) is taken out of the input and fitted as a free
    sinusoid in the flow. Results on a bound are flagged; standard errors come from the
    Jacobian with a Newey-West correction for coloured residuals.

Several sets: per-set fits, their mean ± standard deviation (the paper's convention), and a
joint fit of shared parameters (:func:`fit_joint`). Entry points: :func:`fit_bags`,
:func:`fit_recordings`, :func:`fit_fopdt`. Details and the JSON schema:
``docs/identification.md``.

Exact sampled model. With the input held over ``[k T, (k+1) T)`` and ``t_d = (d + f) T``
(``d`` whole samples, ``0 <= f < 1``), the delayed input changes inside each period at
``f T``, so the first-order lag integrates two input values per period (the modified
z-transform):

    x[k+1] = a x[k] + (1 - c) u[k-d] + (c - a) u[k-d-1],
    a = exp(-T/tau),  c = exp(-(1-f) T/tau),  y[k] = G0 x[k] (+ offset).
"""

from __future__ import annotations

from collections.abc import Sequence
import contextlib
from dataclasses import dataclass, field
import functools
import math
import time
from typing import Any

import numpy as np
from scipy import fft as sfft
from scipy import optimize, signal, stats

# The paper's result (section V): value and "±" (spread over nine data sets), SI.
PAPER = {'G0': (100.0, 0.7), 'tau': (0.100, 0.002), 'td': (0.055, 0.0055)}

PARAMS = ('G0', 'tau', 'td')
METHODS = ('robust', 'paper')

# Flags a fit can carry (documented in docs/identification.md).
FLAG_TEXT = {
    'td_on_lower_bound': 't_d is on its lower bound: the delay is not resolved inside the bounds',
    'td_on_upper_bound': 't_d is on its upper bound: widen td_bounds',
    'tau_on_lower_bound': 'tau is on its lower bound',
    'tau_on_upper_bound': 'tau is on its upper bound: the record is too short or not excited',
    'not_converged': 'the optimiser stopped before its tolerances were met',
    'residuals_not_white': 'residual autocorrelation outside the 99 % band: the model misses '
                           'dynamics, standard errors use the Newey-West correction',
    'input_correlated_residuals': 'input-residual cross-correlation outside the 99 % band: '
                                  'the model misses part of the input-output relation',
    'nonpositive_gain': 'G0 <= 0: the flow does not follow the current',
    'poor_fit': 'fit below 50 %',
    'truncated_bag': 'the bag was truncated: fitted on its readable part',
    'flow_only_filter': 'a filter acts on the flow only: its lag biases t_d upwards',
}

# Residual tests: lags as in MATLAB ``resid`` and a family-wise 99 % level.
N_LAGS = 25
ALPHA = 0.01


def _single_blas_thread():
    """Limit BLAS to one thread while fitting.

    The fits work on tall, narrow matrices (20 000 x 7): threads gain nothing, and on a
    loaded machine OpenBLAS threads that spin for a busy core make a fit ten times slower.
    Without ``threadpoolctl`` this is a no-op.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional speed-up
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api='blas')


def _blas_single_threaded(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kw):
        with _single_blas_thread():
            return fn(*args, **kw)
    return wrapper


class FitError(ValueError):
    """Data that cannot be identified (no excitation, NaNs, too short): one line."""


@dataclass
class FopdtFit:
    """One FOPDT fit (eq. 19). Times in s, ``G0`` in % of ``V_p f_p`` per unit current.

    Attributes
    ----------
    G0, tau, td : float
        Estimates.
    se : dict
        Standard errors of ``G0``, ``tau``, ``td``, ``offset``: Jacobian covariance with the
        Newey-West correction for coloured residuals (equal to ``se_white`` for white ones).
    se_white : dict
        Same, assuming white residuals (what ``procest`` reports).
    offset : float
        Steady-state flow [%] at zero current fraction: ``y_ss = G0 u + offset``.
    fit_percent : float
        ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``, as MATLAB ``compare``.
    flags : list of str
        Keys of :data:`FLAG_TEXT`.
    checks : dict
        Residual tests: ``whiteness`` and ``cross`` with the largest normalised correlation
        ``z_max``, its threshold ``z_crit`` and the lag.
    dither : list of dict
        Dither lines taken out of the current (``freq`` [Hz], ``amp`` [current fraction]).
    cov : ndarray
        Covariance of ``(G0, tau, td)`` behind ``se``.
    t, u, y, y_hat : ndarray
        Fitted window: time [s], current fraction, measured and model flow [%].
    """

    G0: float
    tau: float
    td: float
    se: dict
    se_white: dict
    offset: float
    fit_percent: float
    rmse: float
    n: int
    dt: float
    method: str
    flags: list = field(default_factory=list)
    checks: dict = field(default_factory=dict)
    name: str = ''
    nfev: int = 0
    seconds: float = 0.0
    start: tuple | None = None
    seed: tuple | None = None
    bounds: dict = field(default_factory=dict)
    dither: list = field(default_factory=list)
    cov: np.ndarray | None = None
    t: np.ndarray | None = field(default=None, repr=False)
    u: np.ndarray | None = field(default=None, repr=False)
    y: np.ndarray | None = field(default=None, repr=False)
    y_hat: np.ndarray | None = field(default=None, repr=False)

    @property
    def residual(self) -> np.ndarray:
        """Estimation error ``e = q_l,m - q_l,i`` of Fig. 6 [%]."""
        return self.y - self.y_hat

    def value(self, name: str) -> float:
        return float(getattr(self, name))


# --------------------------------------------------------------------------------------------
# The exact sampled model
# --------------------------------------------------------------------------------------------

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


def _shift(v: np.ndarray, m: int) -> np.ndarray:
    """``v[k - m]`` with zeros before the start (a zero pre-history)."""
    out = np.zeros_like(v)
    if m < v.size:
        out[m:] = v[:v.size - m]
    return out


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
    x = _zero_state_response(u - u0, dt, tau, td)
    return offset + G0 * (u0 + x)


def _zero_state_response(v: np.ndarray, dt: float, tau: float, td: float) -> np.ndarray:
    """Unit-gain response from zero state to ``v`` with a zero pre-history."""
    a, b1, b2, d, _ = coefficients(tau, td, dt)
    w = b1 * _shift(v, d) + b2 * _shift(v, d + 1)
    x = np.empty_like(v)
    x[0] = 0.0
    x[1:] = signal.lfilter([1.0], [1.0, -a], w[:-1])
    return x


@dataclass(frozen=True)
class Dither:
    """A sinusoidal dither ``amp sin(2 pi freq t + phase)`` on the current (``t`` from the
    record's first sample, ``amp`` in current fraction)."""

    freq: float
    amp: float
    phase: float

    def at(self, t: np.ndarray) -> np.ndarray:
        return self.amp * np.sin(2.0 * math.pi * self.freq * t + self.phase)


def detect_dither(u, dt: float, *, min_ratio: float = 100.0, max_lines: int = 3,
                  min_freq: float = 20.0, min_amp: float = 5e-4) -> list[Dither]:
    """Find sinusoidal dither lines in a (staircase) current.

    The differenced current turns the staircase into isolated spikes (a flat spectrum) and
    keeps a sinusoid a spectral line. A line whose periodogram stands ``min_ratio`` times
    above the median, between ``min_freq`` and Nyquist (an aliased dither shows at its
    alias), is refined in frequency and fitted by least squares on the differences, leaving
    out the step samples; then the next line is sought (harmonics of a non-sinusoidal
    dither), up to ``max_lines``. ``min_freq`` keeps a slow sinusoidal excitation (a test
    signal inside the plant's 1.6 Hz bandwidth) from being taken for dither; lines below
    ``min_amp`` (current fraction; 0.05 %, below the bench's quantum) are left alone.
    """
    u = np.asarray(u, dtype=float)
    t = np.arange(u.size) * dt
    lines: list[Dither] = []
    du = np.diff(u)
    n = du.size
    if n < 64:
        return lines
    nfft = sfft.next_fast_len(4 * n)
    fr = np.fft.rfftfreq(nfft, dt)
    band = fr >= min_freq
    win = np.hanning(n)
    kk = np.arange(n) * dt
    for _ in range(max_lines):
        P = np.abs(np.fft.rfft((du - du.mean()) * win, nfft)) ** 2
        pb = np.where(band, P, 0.0)
        k = int(np.argmax(pb))
        # A line stands out of the floor and is a peak, not the skirt of a slow signal's
        # spectrum at the band's lower edge.
        if pb[k] < min_ratio * float(np.median(P[band])) or not band[k - 1]:
            break
        df = fr[1] - fr[0]
        lo_f, hi_f = max(fr[k] - df, min_freq), min(fr[k] + df, 0.5 / dt)
        f0 = optimize.minimize_scalar(
            lambda f, du=du: -abs(np.sum(du * np.exp(-2j * math.pi * f * kk))),
            bounds=(lo_f, hi_f),
            method='bounded', options={'xatol': 1e-7 * fr[k]}).x
        w = 2.0 * math.pi * f0
        B = np.column_stack([np.diff(np.sin(w * t)), np.diff(np.cos(w * t))])
        keep = np.ones(n, bool)
        for _ in range(3):
            coef, *_ = np.linalg.lstsq(B[keep], du[keep], rcond=None)
            res = du - B @ coef
            mad = float(np.median(np.abs(res[keep]))) * 1.4826 + 1e-15
            keep = np.abs(res) <= 6.0 * mad
        # amp sin(wt + phase) = (amp cos phase) sin wt + (amp sin phase) cos wt
        line = Dither(freq=float(f0), amp=float(math.hypot(*coef)),
                      phase=float(math.atan2(coef[1], coef[0])))
        if line.amp < min_amp:
            break
        lines.append(line)
        du = du - np.diff(line.at(t))
    return lines


class _Window:
    """Data of one record for the robust fit: the centred input and the fitted window.

    The window starts at ``k0``, late enough that every input the model needs for a delay
    up to the upper bound is inside the record. The state at ``k0`` is a free parameter, so
    nothing is assumed about what happened before the record.

    Dither lines are taken out of the current, so that the rest is the held command the
    exact sampled model assumes (a sinusoid is not held between samples: treating it as held
    shifts its response by half a sample and biases ``t_d``). Their effect on the flow is a
    free sinusoid per line (two linear parameters each): the plant's response at the dither
    frequency need not follow eq. 19 (the spool resonates near 150 Hz), and an aliased
    dither cannot be predicted at all.
    """

    def __init__(self, u: np.ndarray, y: np.ndarray, dt: float, td_max: float,
                 dither: Sequence[Dither] = ()):
        self.dt = dt
        self.dither = list(dither)
        t = np.arange(u.size) * dt
        held = u - sum((dz.at(t) for dz in self.dither), np.zeros_like(u))
        self.u_mean = float(np.mean(held))
        self.v = held - self.u_mean       # centred: the offset is then weakly tied to G0
        self.k0 = int(math.floor(td_max / dt)) + 1
        self.y = y[self.k0:]
        self.M = self.y.size
        self.kk = np.arange(self.M, dtype=float)
        tw = t[self.k0:]
        cols = []
        for dz in self.dither:
            w = 2.0 * math.pi * dz.freq
            cols += [np.sin(w * tw), np.cos(w * tw)]
        H = np.column_stack(cols) if cols else np.zeros((self.M, 0))
        # Drop a column that vanishes on the grid (a line exactly at Nyquist has no sine).
        keep = np.linalg.norm(H, axis=0) > 1e-6 * math.sqrt(self.M)
        self.H = H[:, keep]
        self.p = 5 + self.H.shape[1]

    def model(self, theta, jac: bool = False):
        """Model output on the window and, optionally, its Jacobian.

        ``theta = (G0, tau, td, c0, e0, h...)``: ``y = c0 + G0 x + e0 a^(k-k0) + H h``, with
        ``x`` the unit-gain state from zero at ``k0`` and ``H`` the dither sinusoids.
        Derivatives of ``x`` with respect to ``tau`` and the delay fraction follow their own
        first-order recursions (one more filter pass).
        """
        G0, tau, td, c0, e0 = theta[:5]
        dt, v, k0, M = self.dt, self.v, self.k0, self.M
        N = v.size
        a, b1, b2, d, f = coefficients(tau, td, dt)
        vk = v[k0 - d:N - 1 - d]           # u[k-d],   k = k0 .. N-2
        vk1 = v[k0 - d - 1:N - 2 - d]      # u[k-d-1]
        x = np.empty(M)
        x[0] = 0.0
        x[1:] = signal.lfilter([1.0], [1.0, -a], b1 * vk + b2 * vk1)
        g = np.exp(-self.kk * dt / tau)     # a^(k-k0) without underflow warnings
        yhat = c0 + G0 * x + e0 * g
        if self.H.shape[1]:
            yhat = yhat + self.H @ np.asarray(theta[5:])
        if not jac:
            return yhat, x, g
        c = b2 + a
        a_tau = a * dt / tau ** 2
        c_tau = c * (1.0 - f) * dt / tau ** 2
        c_f = c * dt / tau
        drive = np.stack([a_tau * x[:-1] - c_tau * vk + (c_tau - a_tau) * vk1,
                          c_f * (vk1 - vk)])
        p = np.zeros((2, M))
        p[:, 1:] = signal.lfilter([1.0], [1.0, -a], drive, axis=1)
        J = np.empty((M, self.p))
        J[:, 0] = x
        J[:, 1] = G0 * p[0] + e0 * self.kk * g * dt / tau ** 2
        J[:, 2] = G0 * p[1] / dt
        J[:, 3] = 1.0
        J[:, 4] = g
        J[:, 5:] = self.H
        return yhat, J

    def project(self, tau: float, td: float) -> tuple[np.ndarray, float]:
        """Best linear parameters ``(G0, c0, e0, h...)`` for fixed ``tau``, ``td``; the SSE."""
        _, x, g = self.model(np.r_[1.0, tau, td, 0.0, 0.0, np.zeros(self.p - 5)])
        A = np.column_stack([x, np.ones(self.M), g, self.H])
        coef, *_ = np.linalg.lstsq(A, self.y, rcond=None)
        r = self.y - A @ coef
        return coef, float(r @ r)

    def theta(self, tau: float, td: float) -> np.ndarray:
        coef, _ = self.project(tau, td)
        return np.r_[coef[0], tau, td, coef[1:]]


# --------------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------------

def moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average (no phase shift), edges from the shrinking window."""
    width = max(1, int(width) | 1)
    if width == 1 or x.size < width:
        return x.astype(float)
    kern = np.ones(width)
    num = np.convolve(x, kern, mode='same')
    den = np.convolve(np.ones_like(x, dtype=float), kern, mode='same')
    return num / den


def _smooth_width(dt: float, span: float = 0.02) -> int:
    # 20 ms spans three periods of the 150 Hz dither, so it cancels in the average.
    return max(1, int(round(span / dt)))


def check_data(u, y, dt: float, *, min_excitation: float = 0.02) -> tuple[np.ndarray,
                                                                           np.ndarray]:
    """Validate normalised data; raise :class:`FitError` with one line on a problem.

    Parameters
    ----------
    u, y : array_like
        Current fraction and flow [%].
    dt : float
        Sample period [s].
    min_excitation : float
        Least peak-to-peak change of the smoothed current, as a fraction of the current
        range (the dither alone does not identify a 100 ms lag).
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    if u.ndim != 1 or u.shape != y.shape:
        raise FitError(f'current and flow must be 1-D arrays of equal length, got {u.shape} '
                       f'and {y.shape}')
    if not (math.isfinite(dt) and dt > 0):
        raise FitError(f'sample period must be positive, got {dt!r}')
    for name, arr in (('current', u), ('flow', y)):
        bad = ~np.isfinite(arr)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise FitError(f'{name} has {int(bad.sum())} NaN or infinite samples (first at '
                           f't = {k * dt:.6g} s)')
    if u.size < 50:
        raise FitError(f'only {u.size} samples: a fit needs a record of at least 50 samples')
    us = moving_average(u, _smooth_width(dt))
    span = float(us.max() - us.min())
    if span < min_excitation:
        raise FitError(f'no excitation: the current moves by {100 * span:.2g} % of its range '
                       f'(at least {100 * min_excitation:g} % needed); record current steps')
    return u, y


def default_bounds(duration: float, dt: float, td_bounds=None, tau_bounds=None
                   ) -> tuple[tuple[float, float], tuple[float, float]]:
    """Delay and time-constant bounds [s]: given ones, or defaults fitting the record."""
    if td_bounds is None:
        td_bounds = (0.0, min(0.25, duration / 8.0))
    if tau_bounds is None:
        tau_bounds = (dt / 4.0, min(2.0, duration / 4.0))
    td_lo, td_hi = (float(b) for b in td_bounds)
    tau_lo, tau_hi = (float(b) for b in tau_bounds)
    if not 0.0 <= td_lo < td_hi:
        raise FitError(f'td bounds must satisfy 0 <= lower < upper, got {td_bounds}')
    if not 0.0 < tau_lo < tau_hi:
        raise FitError(f'tau bounds must satisfy 0 < lower < upper, got {tau_bounds}')
    if td_hi > duration / 4.0:
        raise FitError(f'the record ({duration:.3g} s) is too short for a delay bound of '
                       f'{td_hi:.3g} s: it must be at least 4 times the bound')
    return (td_lo, td_hi), (tau_lo, tau_hi)


# --------------------------------------------------------------------------------------------
# Robust method
# --------------------------------------------------------------------------------------------

def delay_profile(win: _Window, taus: np.ndarray, d_lo: int, d_hi: int) -> np.ndarray:
    """SSE on the grid of ``taus`` times whole-sample delays ``d_lo..d_hi``.

    For each ``tau`` one filter pass gives the unit response ``s``; a delay of ``d`` samples
    is ``s`` shifted by ``d``, so all delays follow from one FFT cross-correlation with the
    data, and the linear parameters ``(G0, c0, e0)`` from a 3x3 normal equation per delay.
    The products of ``s`` with the free response ``a^(k-k0)`` for all delays come from one
    backward first-order filter pass.
    """
    v, k0, M, dt = win.v, win.k0, win.M, win.dt
    N = v.size
    y = win.y - win.y.mean()            # centring keeps the normal equations well scaled
    syy = float(y @ y)
    D = d_hi - d_lo + 1
    L = M + D - 1
    nfft = sfft.next_fast_len(L, real=True)
    Y = np.conj(sfft.rfft(y, nfft))
    d = np.arange(d_lo, d_hi + 1)
    out = np.empty((taus.size, D))
    for i, tau in enumerate(taus):
        a = math.exp(-dt / tau)
        s = signal.lfilter([0.0, 1.0 - a], [1.0, -a], v)
        seg = s[k0 - d_hi:N - d_lo]
        sy = sfft.irfft(sfft.rfft(seg, nfft) * Y, nfft)[:D][::-1]   # j -> delay d_lo + j
        g = np.exp(-win.kk * dt / tau)
        # sum_{i<M} s[m+i] a^i = H[m] - a^M H[m+M], H[m] = sum_{i>=0} s[m+i] a^i.
        H = np.zeros(N + 1)
        H[:N] = signal.lfilter([1.0], [1.0, -a], s[::-1])[::-1]
        sg = H[k0 - d] - math.exp(-M * dt / tau) * H[N - d]
        cs1 = np.concatenate([[0.0], np.cumsum(s)])
        cs2 = np.concatenate([[0.0], np.cumsum(s * s)])
        s1 = cs1[N - d] - cs1[k0 - d]
        s2 = cs2[N - d] - cs2[k0 - d]
        g1, g2, gy = float(g.sum()), float(g @ g), float(g @ y)
        A = np.empty((D, 3, 3))
        A[:, 0, 0] = s2
        A[:, 0, 1] = A[:, 1, 0] = s1
        A[:, 0, 2] = A[:, 2, 0] = sg
        A[:, 1, 1] = M
        A[:, 1, 2] = A[:, 2, 1] = g1
        A[:, 2, 2] = g2
        b = np.stack([sy, np.zeros(D), np.full(D, gy)], axis=1)
        # A tiny ridge keeps the solve finite where g and 1 are nearly collinear (long tau).
        A += np.eye(3) * (1e-12 * np.trace(A, axis1=1, axis2=2))[:, None, None]
        coef = np.linalg.solve(A, b[..., None])[..., 0]
        out[i] = syy - np.einsum('ij,ij->i', coef, b)
    return out


def _profile_minima(P: np.ndarray, n: int = 3, sep: int = 3) -> list[int]:
    """Indices of the ``n`` lowest local minima of ``P`` that are ``sep`` apart."""
    idx = np.argsort(P)
    chosen: list[int] = []
    for i in idx:
        left = P[i - 1] if i > 0 else np.inf
        right = P[i + 1] if i + 1 < P.size else np.inf
        if P[i] > min(left, right):
            continue
        if all(abs(int(i) - j) >= sep for j in chosen):
            chosen.append(int(i))
        if len(chosen) == n:
            break
    if not chosen:
        chosen = [int(idx[0])]
    return chosen


def _solve_bounded(both, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   max_nfev: int):
    """Bounded least squares (trust-region reflective, scipy).

    ``both(theta)`` returns the residual and its Jacobian, computed together in one model
    pass; the last pair is cached because scipy asks for them separately.
    """
    cache: dict[bytes, tuple] = {}

    def get(th):
        key = th.tobytes()
        if key not in cache:
            cache.clear()
            cache[key] = both(th)
        return cache[key]

    return optimize.least_squares(lambda th: get(th)[0], np.clip(theta0, lo, hi),
                                  jac=lambda th: get(th)[1], bounds=(lo, hi), method='trf',
                                  x_scale='jac', ftol=1e-12, xtol=1e-12, gtol=1e-12,
                                  max_nfev=max_nfev)


def _local_fit(win: _Window, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Bounded least squares of all parameters of one record from ``theta0``."""
    def both(th):
        yhat, J = win.model(th, jac=True)
        return yhat - win.y, J

    return _solve_bounded(both, theta0, lo, hi, max_nfev=200)


def _robust(u, y, dt, td_b, tau_b, start, n_tau, dither):
    win = _Window(u, y, dt, td_b[1], dither)
    extra = np.full(win.p - 3, np.inf)
    lo = np.r_[-np.inf, tau_b[0], td_b[0], -extra]
    hi = np.r_[np.inf, tau_b[1], td_b[1], extra]
    # Global stage: every whole-sample delay in the bounds, tau on a log grid.
    d_lo = int(math.ceil(td_b[0] / dt - 1e-9))
    d_hi = int(math.floor(td_b[1] / dt + 1e-9))
    taus = np.geomspace(tau_b[0], tau_b[1], n_tau)
    sse = delay_profile(win, taus, d_lo, d_hi)
    P = sse.min(axis=0)
    starts = []
    minima = _profile_minima(P)
    for j in minima:
        # A basin whose grid minimum is 1 % above the best cannot win: refining the delay
        # fraction gains far less than that (the SSE is within a sample of its minimum).
        if P[j] > 1.01 * P[minima[0]]:
            continue
        i = int(np.argmin(sse[:, j]))
        td0 = min(max((d_lo + j) * dt, td_b[0]), td_b[1])
        # Refine tau at this delay between the neighbouring grid points.
        lo_t, hi_t = taus[max(i - 1, 0)], taus[min(i + 1, taus.size - 1)]
        r = optimize.minimize_scalar(lambda lt, td0=td0: win.project(math.exp(lt), td0)[1],
                                     bounds=(math.log(lo_t), math.log(hi_t)),
                                     method='bounded', options={'xatol': 1e-2})
        starts.append(win.theta(math.exp(r.x), td0))
    if start is not None:
        # The user's start is one more candidate when it is competitive with the grid:
        # every basin of the delay is on the grid, so a worse start cannot lead elsewhere.
        tau0 = min(max(start[1], tau_b[0]), tau_b[1])
        td0 = min(max(start[2], td_b[0]), td_b[1])
        if win.project(tau0, td0)[1] <= 1.01 * P[minima[0]]:
            starts.append(win.theta(tau0, td0))
    best, nfev = None, int(taus.size * P.size)
    for th0 in starts:
        res = _local_fit(win, th0, lo, hi)
        nfev += res.nfev
        if best is None or res.cost < best.cost:
            best = res
    return win, best, nfev, lo, hi


# --------------------------------------------------------------------------------------------
# Paper's method
# --------------------------------------------------------------------------------------------

def _steps(u: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Step instants and signed sizes of a (dithered) staircase input."""
    w = _smooth_width(dt)
    us = moving_average(u, w)
    h = max(1, w)
    jump = np.zeros_like(us)
    jump[h:-h] = us[2 * h:] - us[:-2 * h]
    mag = np.abs(jump)
    if mag.max() <= 0:
        return np.array([], dtype=int), np.array([])
    cand = signal.find_peaks(mag, height=0.3 * mag.max(), distance=2 * h + 1)[0]
    idx, size = [], []
    for k in cand:
        # The step sample is where the raw input jumps most near the smoothed edge.
        seg = slice(max(k - h - 1, 1), min(k + h + 2, u.size))
        du = np.diff(u[seg.start - 1:seg.stop]) * np.sign(jump[k])
        idx.append(seg.start + int(np.argmax(du)))
        size.append(jump[k])
    return np.array(idx), np.array(size)


def step_seed(u, y, dt: float) -> tuple[float, float, float]:
    """Seeds ``(G0, tau, td)`` from the step data: Smith's two-point method.

    On the largest up-step (growing flow, the zone the paper identifies): ``G0`` from the
    settled levels before and after it, then the times ``t28`` and ``t63`` at which the
    smoothed flow covers 28.3 % and 63.2 % of its change give ``tau = 1.5 (t63 - t28)`` and
    ``t_d = t63 - tau``.
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    idx, size = _steps(u, dt)
    if idx.size == 0:
        raise FitError('no step in the current: the paper method needs step data')
    up = size > 0
    pick = int(np.argmax(np.where(up, size, -np.inf))) if up.any() else \
        int(np.argmax(np.abs(size)))
    k = int(idx[pick])
    prev = int(idx[pick - 1]) if pick > 0 else 0
    nxt = int(idx[pick + 1]) if pick + 1 < idx.size else u.size
    w = _smooth_width(dt)
    u0 = float(np.median(u[prev:k])) if k > prev else float(u[k - 1])
    u1 = float(np.median(u[k:nxt]))
    # Settled flow: the last third of each plateau (the delay shifts the flow's own edges).
    pre = y[max(k - max((k - prev) // 3, 1), 0):k]
    post = y[nxt - max((nxt - k) // 3, 1):nxt]
    y0, y1 = float(pre.mean()), float(post.mean())
    G0 = (y1 - y0) / (u1 - u0)
    ys = moving_average(y[k:nxt], w // 2)
    ts = np.arange(ys.size) * dt
    s = np.sign(y1 - y0) or 1.0

    def cross(frac):
        lev = y0 + frac * (y1 - y0)
        hit = np.flatnonzero(s * (ys - lev) >= 0)
        return float(ts[hit[0]]) if hit.size else float('nan')

    t28, t63 = cross(0.283), cross(0.632)
    tau = 1.5 * (t63 - t28)
    if not (math.isfinite(tau) and tau > dt):
        tau = max(t63, 2 * dt) if math.isfinite(t63) else 10 * dt
    td = max(t63 - tau, 0.0) if math.isfinite(t63) else 0.0
    return float(G0), float(tau), float(td)


def initial_levels(u: np.ndarray, y: np.ndarray, dt: float, td: float) -> tuple[float, float]:
    """Input and flow of the initial steady state (before the first step reaches the flow)."""
    idx, _ = _steps(u, dt)
    k1 = int(idx[0]) if idx.size else u.size
    n_u = max(k1, 1)
    n_y = max(min(k1 + int(td / dt), y.size), 1)
    return float(np.median(u[:n_u])), float(np.mean(y[:n_y]))


def _paper(u, y, dt, start):
    """Nelder-Mead on eq. 20 (``fminsearch`` defaults), deviation variables, zero state."""
    seed = step_seed(u, y, dt)
    x0 = np.array(seed if start is None else start, dtype=float)
    u_ref, y_ref = initial_levels(u, y, dt, max(x0[2], 0.0))
    v, z = u - u_ref, y - y_ref
    nfev = 0

    def J(th):
        nonlocal nfev
        nfev += 1
        G0, tau, td = th
        if not (tau > 0 and td >= 0):
            return np.inf          # fminsearch is unconstrained: infeasible points lose
        r = z - G0 * _zero_state_response(v, dt, tau, td)
        return float(r @ r)

    # scipy's Nelder-Mead is fminsearch's algorithm: 5 % initial simplex (0.00025 for zero
    # components), TolX = TolFun = 1e-4, at most 200 n iterations and evaluations.
    res = optimize.minimize(J, x0, method='Nelder-Mead',
                            options={'xatol': 1e-4, 'fatol': 1e-4, 'maxiter': 600,
                                     'maxfev': 600})
    return res, seed, u_ref, y_ref, nfev


# --------------------------------------------------------------------------------------------
# Uncertainty and residual tests
# --------------------------------------------------------------------------------------------

def _xcorr(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """Normalised cross-correlation ``r_ab[l] = sum a[k] b[k+l] / (N sd_a sd_b)``."""
    a = a - a.mean()
    b = b - b.mean()
    n = a.size
    nfft = sfft.next_fast_len(2 * n)
    c = np.fft.irfft(np.conj(np.fft.rfft(a, nfft)) * np.fft.rfft(b, nfft), nfft)
    den = math.sqrt(float(a @ a) * float(b @ b)) or 1.0
    return np.concatenate([c[nfft - lags:], c[:lags + 1]]) / den   # lags -L..L


def residual_checks(r: np.ndarray, v: np.ndarray, lags: int = N_LAGS,
                    alpha: float = ALPHA) -> dict:
    """Whiteness and input-residual independence tests (as MATLAB ``resid``).

    Each test compares the largest normalised correlation over its lags with a Sidak-corrected
    two-sided level, so that ``alpha`` is the family-wise false-alarm rate. The standard
    deviation of a cross-correlation lag is ``sqrt(sum_k rho_u(k) rho_e(k) / N)`` (Bartlett),
    which is ``1/sqrt(N)`` for a white residual.
    """
    n = r.size
    acf = _xcorr(r, r, lags)[lags:]
    z_auto = np.abs(acf[1:]) * math.sqrt(n)
    zc_auto = float(stats.norm.ppf(1 - (1 - (1 - alpha) ** (1 / lags)) / 2))
    ccf = _xcorr(v, r, lags)
    acf_u = _xcorr(v, v, lags)[lags:]
    sd = math.sqrt(max(float(acf_u[0] * acf[0] + 2 * np.sum(acf_u[1:] * acf[1:])), 1e-12) / n)
    z_cross = np.abs(ccf) / sd
    zc_cross = float(stats.norm.ppf(1 - (1 - (1 - alpha) ** (1 / ccf.size)) / 2))
    ka, kc = int(np.argmax(z_auto)), int(np.argmax(z_cross))
    return {
        'whiteness': {'z_max': float(z_auto[ka]), 'z_crit': zc_auto, 'lag': ka + 1,
                      'ok': bool(z_auto[ka] <= zc_auto)},
        'cross': {'z_max': float(z_cross[kc]), 'z_crit': zc_cross, 'lag': kc - lags,
                  'ok': bool(z_cross[kc] <= zc_cross)},
        'acf': acf, 'ccf': ccf, 'lags': lags,
    }


def _bandwidth(acf: np.ndarray, n: int) -> int:
    """Newey-West lag: the rule of thumb, or longer while the residual ACF stays significant."""
    rule = int(math.floor(4.0 * (n / 100.0) ** (2.0 / 9.0)))
    band = 2.0 / math.sqrt(n)
    below = np.flatnonzero(np.abs(acf[1:]) < band)
    first = int(below[0]) + 1 if below.size else acf.size
    return int(min(max(rule, 2 * first), n // 10, 2000))


def covariance(J: np.ndarray, r: np.ndarray, groups: Sequence[slice] | None = None
               ) -> tuple[np.ndarray, np.ndarray, int]:
    """White-noise and Newey-West (HAC) covariance of least-squares estimates.

    Returns ``(cov_white, cov_hac, lag)``. ``cov_white = s^2 (J'J)^-1`` with
    ``s^2 = SSE / (N - p)``; ``cov_hac = B S B`` with ``B = (J'J)^-1`` and ``S`` the
    Bartlett-weighted sum of the lagged outer products of ``J_k r_k``. ``groups`` are the
    row ranges of independent records: lagged products never cross them.
    """
    n, p = J.shape
    groups = [slice(0, n)] if groups is None else list(groups)
    scale = np.linalg.norm(J, axis=0)
    scale[scale == 0] = 1.0
    Js = J / scale
    B = np.linalg.pinv(Js.T @ Js)
    s2 = float(r @ r) / max(n - p, 1)
    cov_w = s2 * B
    S = np.zeros((p, p))
    L_max = 0
    for g in groups:
        rg = r[g]
        m = rg.size
        nl = min(m // 4, 4000)
        L = _bandwidth(_xcorr(rg, rg, nl)[nl:], m)
        L_max = max(L_max, L)
        Z = Js[g] * rg[:, None]
        S += Z.T @ Z
        for lag in range(1, L + 1):
            G = Z[lag:].T @ Z[:-lag]
            S += (1.0 - lag / (L + 1.0)) * (G + G.T)
    S *= n / max(n - p, 1)
    cov_h = B @ S @ B
    unscale = np.outer(1 / scale, 1 / scale)
    return cov_w * unscale, cov_h * unscale, L_max


def _on_bound(val: float, lo: float, hi: float, active: int, dt: float) -> str | None:
    tol = 1e-4 * (hi - lo if math.isfinite(hi) else abs(val)) + 1e-3 * dt
    if active < 0 or val - lo <= tol:
        return 'lower'
    if active > 0 or hi - val <= tol:
        return 'upper'
    return None


def _fit_figures(y, yhat):
    r = y - yhat
    den = float(np.linalg.norm(y - y.mean())) or 1.0
    return 100.0 * (1.0 - float(np.linalg.norm(r)) / den), float(np.sqrt(np.mean(r * r)))


# --------------------------------------------------------------------------------------------
# Entry point for arrays
# --------------------------------------------------------------------------------------------

@_blas_single_threaded
def fit_fopdt(u, y, dt: float, *, method: str = 'robust', start: Sequence[float] | None = None,
              td_bounds: Sequence[float] | None = None,
              tau_bounds: Sequence[float] | None = None, name: str = '',
              n_tau: int = 24, dither: Dither | str | None = 'auto') -> FopdtFit:
    """Fit eq. 19 to one record of normalised data.

    Parameters
    ----------
    u : array_like
        Current as a fraction of the 0..100 % displacement range; ``u[k]`` is held over
        ``[k dt, (k+1) dt)`` (true for a digitally commanded current).
    y : array_like
        Flow in % of ``V_p f_p``, sampled at ``k dt``.
    dt : float
        Sample period [s].
    method : {'robust', 'paper'}
        See the module docstring.
    start : (G0, tau, td), optional
        Starting point. ``paper``: replaces the step seeds. ``robust``: one more local start
        next to the global grid minima (the best result wins).
    td_bounds, tau_bounds : (lower, upper), optional
        Bounds [s] of the robust method; default ``td`` in ``[0, min(0.25 s, T_rec/8)]``,
        ``tau`` in ``[dt/4, min(2 s, T_rec/4)]``.
    name : str
        Label of the record.
    n_tau : int
        Points of the ``tau`` grid of the global stage.
    dither : 'auto', list of Dither, or None
        Robust method: dither lines to take out of the current and fit as free sinusoids
        in the flow (``'auto'``: find them with :func:`detect_dither`; ``None``: treat the
        whole current as held).

    Returns
    -------
    FopdtFit

    Raises
    ------
    FitError
        NaNs, no excitation, a record too short for the delay bound, an unknown method.
    """
    if method not in METHODS:
        raise FitError(f'unknown method {method!r}: choose {" or ".join(METHODS)}')
    t_start = time.perf_counter()
    u, y = check_data(u, y, dt)
    duration = u.size * dt
    td_b, tau_b = default_bounds(duration, dt, td_bounds, tau_bounds)
    start_t = None if start is None else tuple(float(s) for s in start)
    if start_t is not None and len(start_t) != 3:
        raise FitError('start must be (G0, tau, td)')
    flags: list[str] = []
    if method == 'robust':
        if isinstance(dither, str):
            if dither != 'auto':
                raise FitError(f"dither must be 'auto', a list of Dither or None, got "
                               f'{dither!r}')
            dither = detect_dither(u, dt)
        dither = list(dither or [])
        win, res, nfev, lo, hi = _robust(u, y, dt, td_b, tau_b, start_t, n_tau, dither)
        theta = res.x
        yhat, J = win.model(theta, jac=True)
        r = win.y - yhat
        G0, tau, td, c0 = (float(x) for x in theta[:4])
        offset = c0 - G0 * win.u_mean
        # Offset at u = 0 is c0 - G0 mean(u): its variance follows from the covariance.
        T = np.eye(win.p)
        T[3, 0] = -win.u_mean
        cw, ch, _ = covariance(J, r)
        cw, ch = T @ cw @ T.T, T @ ch @ T.T
        if res.status <= 0:
            flags.append('not_converged')
        for i, name_p in ((1, 'tau'), (2, 'td')):
            where = _on_bound(theta[i], lo[i], hi[i], int(res.active_mask[i]), dt)
            if where:
                flags.append(f'{name_p}_on_{where}_bound')
        k0 = win.k0
        v_w = win.v[k0:]
        seed = None
        bounds = {'td': td_b, 'tau': tau_b}
        y_fit, u_fit = win.y, u[k0:]
    else:
        res, seed, u_ref, y_ref, nfev = _paper(u, y, dt, start_t)
        G0, tau, td = (float(x) for x in res.x)
        if not (tau > 0 and td >= 0 and math.isfinite(res.fun)):
            raise FitError(f'Nelder-Mead ended at an infeasible point (tau = {tau:.3g} s, '
                           f't_d = {td:.3g} s)')
        x = _zero_state_response(u - u_ref, dt, tau, td)
        yhat = y_ref + G0 * x
        r = y - yhat
        # Jacobian by central differences, only for the standard errors.
        J = np.empty((u.size, 3))
        J[:, 0] = x
        for j, h in ((1, 1e-4 * tau), (2, 1e-2 * dt)):
            tp, tm = list(res.x), list(res.x)
            tp[j] += h
            tm[j] = max(tm[j] - h, 0.0)
            J[:, j] = G0 * (_zero_state_response(u - u_ref, dt, tp[1], tp[2])
                            - _zero_state_response(u - u_ref, dt, tm[1], tm[2])) / (tp[j] - tm[j])
        cw, ch, _ = covariance(J, r)
        offset = y_ref - G0 * u_ref
        if not res.success:
            flags.append('not_converged')
        if td <= 1e-3 * dt:
            flags.append('td_on_lower_bound')
        v_w = u - u_ref
        bounds = {}
        y_fit, u_fit = y, u
        k0 = 0
    fit, rmse = _fit_figures(y_fit, yhat)
    checks = residual_checks(r, v_w)
    if not checks['whiteness']['ok']:
        flags.append('residuals_not_white')
    if not checks['cross']['ok']:
        flags.append('input_correlated_residuals')
    if G0 <= 0:
        flags.append('nonpositive_gain')
    if fit < 50.0:
        flags.append('poor_fit')
    names = ('G0', 'tau', 'td', 'offset')
    pick = (0, 1, 2, 3) if method == 'robust' else (0, 1, 2)
    se = {n: float(math.sqrt(max(ch[i, i], 0.0))) for n, i in zip(names, pick)}
    se_w = {n: float(math.sqrt(max(cw[i, i], 0.0))) for n, i in zip(names, pick)}
    if method == 'paper':
        se['offset'] = se_w['offset'] = float('nan')
    t = (np.arange(u.size) * dt)[k0:]
    lines = [{'freq': d.freq, 'amp': d.amp} for d in dither] if method == 'robust' else []
    return FopdtFit(G0=G0, tau=tau, td=td, se=se, se_white=se_w, offset=float(offset),
                    fit_percent=fit, rmse=rmse, n=int(y_fit.size), dt=dt, method=method,
                    flags=flags, checks=checks, name=name, nfev=int(nfev),
                    seconds=time.perf_counter() - t_start, start=start_t, seed=seed,
                    bounds=bounds, dither=lines, cov=ch[:3, :3], t=t, u=u_fit, y=y_fit,
                    y_hat=yhat)


# --------------------------------------------------------------------------------------------
# Several data sets
# --------------------------------------------------------------------------------------------

@dataclass
class Pooled:
    """Estimates over several data sets.

    ``mean`` and ``std`` (sample standard deviation, ``ddof=1``) are the paper's
    ``value ± spread`` over data sets; ``se_mean = std / sqrt(n)`` is the standard error of
    the mean. ``joint`` is one fit of shared ``G0``, ``tau``, ``t_d`` to all sets at once
    (each set keeps its own offset and initial state); its standard errors are precision of
    the shared model only, not the spread between sets.
    """

    n: int
    mean: dict
    std: dict
    se_mean: dict
    fit_percent: float
    flagged: list
    joint: FopdtFit | None = None


def pool(fits: Sequence[FopdtFit]) -> Pooled:
    """Mean ± std across sets (the paper's convention) and the standard error of the mean."""
    n = len(fits)
    if n == 0:
        raise FitError('no data sets to pool')
    mean, std, sem = {}, {}, {}
    for p in PARAMS:
        vals = np.array([f.value(p) for f in fits])
        mean[p] = float(vals.mean())
        std[p] = float(vals.std(ddof=1)) if n > 1 else float('nan')
        sem[p] = std[p] / math.sqrt(n) if n > 1 else float('nan')
    return Pooled(n=n, mean=mean, std=std, se_mean=sem,
                  fit_percent=float(np.mean([f.fit_percent for f in fits])),
                  flagged=[f.name for f in fits if f.flags])


@_blas_single_threaded
def fit_joint(records: Sequence[tuple[np.ndarray, np.ndarray, float]], *,
              start: Sequence[float], td_bounds=None, tau_bounds=None,
              dither: str | None = 'auto') -> FopdtFit:
    """One robust fit of shared ``(G0, tau, t_d)`` to several records.

    Each record keeps its own offset, initial state and dither sinusoids. These nuisance
    parameters enter linearly, so they are eliminated per record (variable projection): the
    least-squares problem is in the three shared parameters only, with the residuals and
    Jacobian columns projected off each record's nuisance columns. By the Frisch-Waugh
    theorem the covariance of the projected problem is the exact marginal covariance of the
    shared parameters. ``records`` holds ``(u, y, dt)`` in normalised units; ``start`` is
    ``(G0, tau, td)``, e.g. the pooled mean; ``dither`` as in :func:`fit_fopdt`.
    """
    t0 = time.perf_counter()
    dur = min(u.size * dt for u, _, dt in records)
    dt_min = min(dt for _, _, dt in records)
    td_b, tau_b = default_bounds(dur, dt_min, td_bounds, tau_bounds)
    wins = []
    for u, y, dt in records:
        u, y = check_data(u, y, dt)
        wins.append(_Window(u, y, dt, td_b[1], detect_dither(u, dt) if dither else ()))
    rows = np.cumsum([0] + [w.M for w in wins])
    lo = np.array([-np.inf, tau_b[0], td_b[0]])
    hi = np.array([np.inf, tau_b[1], td_b[1]])
    def both(th):
        r = np.empty(rows[-1])
        J = np.empty((rows[-1], 3))
        for i, w in enumerate(wins):
            _, Ji = w.model(np.r_[th, np.zeros(w.p - 3)], jac=True)
            x, g, Js = Ji[:, 0], Ji[:, 4], Ji[:, :3]
            # Nuisance columns (1, a^(k-k0), dither sinusoids): project them out.
            Q, _ = np.linalg.qr(np.column_stack([np.ones(w.M), g, w.H]))
            e = w.y - th[0] * x
            r[rows[i]:rows[i + 1]] = Q @ (Q.T @ e) - e
            J[rows[i]:rows[i + 1]] = Js - Q @ (Q.T @ Js)
        return r, J

    res = _solve_bounded(both, np.asarray(start, dtype=float), lo, hi, max_nfev=100)
    r, J = both(res.x)
    cw, ch, _ = covariance(J, r, [slice(rows[i], rows[i + 1]) for i in range(len(wins))])
    G0, tau, td = (float(x) for x in res.x)
    flags = [] if res.status > 0 else ['not_converged']
    for i, p in ((1, 'tau'), (2, 'td')):
        where = _on_bound(res.x[i], lo[i], hi[i], int(res.active_mask[i]), dt_min)
        if where:
            flags.append(f'{p}_on_{where}_bound')
    y_all = np.concatenate([w.y for w in wins])
    fit, rmse = _fit_figures(y_all, y_all + r)
    se = {p: float(math.sqrt(max(ch[i, i], 0))) for i, p in enumerate(PARAMS)}
    se_w = {p: float(math.sqrt(max(cw[i, i], 0))) for i, p in enumerate(PARAMS)}
    return FopdtFit(G0=G0, tau=tau, td=td, se=se, se_white=se_w, offset=float('nan'),
                    fit_percent=fit, rmse=rmse, n=int(y_all.size), dt=dt_min, method='joint',
                    flags=flags, name='joint', nfev=int(res.nfev),
                    seconds=time.perf_counter() - t0, start=tuple(start),
                    bounds={'td': td_b, 'tau': tau_b}, cov=ch)


@dataclass
class Identification:
    """Per-set fits, their pooled estimate and the data they came from."""

    method: str
    sets: list
    pooled: Pooled
    recordings: list = field(default_factory=list, repr=False)
    normalisation: dict = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def G0(self) -> float:
        return self.pooled.mean['G0']

    @property
    def tau(self) -> float:
        return self.pooled.mean['tau']

    @property
    def td(self) -> float:
        return self.pooled.mean['td']

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready result (schema in docs/identification.md)."""
        from .fit_report import to_dict
        return to_dict(self)


@_blas_single_threaded
def fit_recordings(recordings: Sequence, *, method: str = 'robust', params=None,
                   start: Sequence[float] | None = None, td_bounds=None, tau_bounds=None,
                   joint: bool | None = None, progress: bool | None = False,
                   allow_flow_filter: bool = False, dither: str | None = 'auto'
                   ) -> Identification:
    """Fit every :class:`~hydropump_ctrl.recording.Recording` and pool the estimates.

    Parameters
    ----------
    recordings : sequence of Recording
        SI recordings (absolute current [A], flow [m^3/s]).
    method : {'robust', 'paper'}
    params : hydropump_sim.Params, optional
        Plant parameters for the normalisation (current range, ``V_p f_p``); default
        ``config/pump.yaml``.
    start, td_bounds, tau_bounds
        See :func:`fit_fopdt`.
    joint : bool, optional
        Also fit shared parameters to all sets at once (default: robust method, 2+ sets).
    progress : bool or None
        Show a tqdm progress bar (``None``: only on a terminal).
    allow_flow_filter : bool
        Fit a recording whose flow alone was filtered (flagged) instead of refusing it.
    dither : 'auto' or None
        Dither handling of the robust method (see :func:`fit_fopdt`).
    """
    from tqdm import tqdm

    from .recording import load_default_params, normalise
    t0 = time.perf_counter()
    params = load_default_params() if params is None else params
    fits = []
    for rec in tqdm(recordings, desc='fit', unit='set', disable=not progress if progress
                    is not None else None, leave=False):
        fits.append(fit_recording(rec, method=method, params=params, start=start,
                                  td_bounds=td_bounds, tau_bounds=tau_bounds,
                                  allow_flow_filter=allow_flow_filter, dither=dither))
    pooled = pool(fits)
    if joint is None:
        joint = method == 'robust' and len(fits) > 1
    if joint and len(fits) > 1:
        data = [(*normalise(rec, params), rec.dt) for rec in recordings]
        pooled.joint = fit_joint(data, start=[pooled.mean[p] for p in PARAMS],
                                 td_bounds=td_bounds, tau_bounds=tau_bounds, dither=dither)
    lo, hi = params.current_range
    return Identification(method=method, sets=fits, pooled=pooled, recordings=list(recordings),
                          normalisation={'current_range_A': [lo, hi],
                                         'flow_full_scale_m3s': params.Q_max},
                          seconds=time.perf_counter() - t0)


def fit_recording(rec, *, method: str = 'robust', params=None, start=None, td_bounds=None,
                  tau_bounds=None, allow_flow_filter: bool = False,
                  dither: str | None = 'auto') -> FopdtFit:
    """Normalise one recording as the paper does and fit eq. 19 (see :func:`fit_fopdt`)."""
    from .recording import load_default_params, normalise
    params = load_default_params() if params is None else params
    flow_f, cur_f = rec.filters.get('flow'), rec.filters.get('current')
    biased = flow_f is not None and flow_f != cur_f
    if biased and not allow_flow_filter:
        raise FitError(f'{rec.name}: the flow alone is filtered ({flow_f}): a filter on one '
                       'signal changes the current-to-flow relation (a lag adds to t_d); '
                       'filter both signals or neither')
    u, y = normalise(rec, params)
    fit = fit_fopdt(u, y, rec.dt, method=method, start=start, td_bounds=td_bounds,
                    tau_bounds=tau_bounds, name=rec.name, dither=dither)
    if rec.truncated:
        fit.flags.append('truncated_bag')
    if biased:
        fit.flags.append('flow_only_filter')
    fit.t = fit.t + rec.t[0]
    return fit


def fit_bags(paths: Sequence, *, method: str = 'robust',
             current_topic: str = 'solenoid_current', flow_topic: str = 'line_flow',
             params=None, start=None, td_bounds=None, tau_bounds=None,
             joint: bool | None = None, progress: bool | None = False,
             allow_truncated: bool = False, allow_flow_filter: bool = False,
             dither: str | None = 'auto') -> Identification:
    """Read rosbag2 bags (MCAP or sqlite3) and identify eq. 19 on each, then pool.

    Parameters
    ----------
    paths : sequence of path-like
        Bag directories, ``.mcap``/``.db3`` files or saved ``.npz`` recordings.
    method : {'robust', 'paper'}
    current_topic, flow_topic : str
        Topic names, matched exactly or by unique suffix (``/ns/line_flow``).
    params : hydropump_sim.Params, optional
        For the normalisation; default ``config/pump.yaml``.
    allow_truncated : bool
        Fit the readable part of a truncated bag (flagged ``truncated_bag``) instead of
        raising :class:`~hydropump_ctrl.recording.BagError`.

    Other parameters are those of :func:`fit_recordings`.

    Returns
    -------
    Identification
        ``.sets`` per bag, ``.pooled`` over bags; ``.G0``, ``.tau``, ``.td`` are the pooled
        means (the single fit for one bag).
    """
    from tqdm import tqdm

    from .recording import BagError, read_recording
    if isinstance(paths, (str, bytes)) or hasattr(paths, '__fspath__'):
        paths = [paths]
    recs = []
    for p in tqdm(paths, desc='read', unit='bag', disable=not progress if progress
                  is not None else None, leave=False):
        rec = read_recording(p, current_topic=current_topic, flow_topic=flow_topic)
        if rec.truncated and not allow_truncated:
            raise BagError(f'{p}: the bag is truncated ({rec.truncation}); fit its readable '
                           'part with allow_truncated (--allow-truncated)')
        recs.append(rec)
    return fit_recordings(recs, method=method, params=params, start=start,
                          td_bounds=td_bounds, tau_bounds=tau_bounds, joint=joint,
                          progress=progress, allow_flow_filter=allow_flow_filter,
                          dither=dither)
