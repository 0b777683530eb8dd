"""What a fit says about itself: residual tests, covariance, standard errors and flags.

Each method hands its result to :func:`assess` as an :class:`Estimate` (estimates, the fitted
window, the covariance behind the standard errors and the method's own flags); the residual
tests (as MATLAB ``resid``), the fit figures and the flags every method shares are computed
here, once, and returned as a :class:`FopdtFit`. The covariance is the Jacobian one with a
Newey-West correction for coloured residuals (:func:`covariance`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math
import time

import numpy as np
from scipy import fft as sfft

from .model import PARAMS

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
# Names of the standard errors a fit reports, in the order of its covariance.
SE_NAMES = (*PARAMS, 'offset')


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


@dataclass
class Estimate:
    """One method's result on one record, before the shared diagnostics.

    ``cov_white`` and ``cov_hac`` are square, their first rows ``G0``, ``tau``, ``td`` and,
    where the method estimates it, ``offset`` (a 3 x 3 covariance has no offset error).
    ``y``, ``y_hat`` and ``u`` are the fitted window, which starts at sample ``k0`` of the
    record; ``v`` is the input the residual is tested against.
    """

    G0: float
    tau: float
    td: float
    offset: float
    y: np.ndarray
    y_hat: np.ndarray
    u: np.ndarray
    v: np.ndarray
    k0: int
    cov_white: np.ndarray
    cov_hac: np.ndarray
    nfev: int
    flags: list = field(default_factory=list)
    seed: tuple | None = None
    bounds: dict = field(default_factory=dict)
    dither: list = field(default_factory=list)


def assess(est: Estimate, *, method: str, dt: float, name: str = '',
           start: tuple | None = None, t_start: float | None = None) -> FopdtFit:
    """Residual tests, fit figures and the shared flags of ``est``, as a :class:`FopdtFit`.

    ``t_start`` is the ``time.perf_counter()`` at which the fit began (for ``seconds``).
    """
    r = est.y - est.y_hat
    fit, rmse = fit_figures(est.y, est.y_hat)
    checks = residual_checks(r, est.v)
    flags = list(est.flags)
    if not checks['whiteness']['ok']:
        flags.append('residuals_not_white')
    if not checks['cross']['ok']:
        flags.append('input_correlated_residuals')
    if est.G0 <= 0:
        flags.append('nonpositive_gain')
    if fit < 50.0:
        flags.append('poor_fit')
    t = np.arange(est.k0, est.k0 + est.y.size) * dt
    return FopdtFit(G0=est.G0, tau=est.tau, td=est.td, se=standard_errors(est.cov_hac),
                    se_white=standard_errors(est.cov_white), offset=float(est.offset),
                    fit_percent=fit, rmse=rmse, n=int(est.y.size), dt=dt, method=method,
                    flags=flags, checks=checks, name=name, nfev=int(est.nfev),
                    seconds=0.0 if t_start is None else time.perf_counter() - t_start,
                    start=start, seed=est.seed, bounds=est.bounds, dither=est.dither,
                    cov=est.cov_hac[:3, :3], t=t, u=est.u, y=est.y, y_hat=est.y_hat)


def standard_errors(cov: np.ndarray, names: Sequence[str] = SE_NAMES) -> dict[str, float]:
    """Square roots of the diagonal by name; NaN for a name beyond the covariance."""
    return {n: float(math.sqrt(max(cov[i, i], 0.0))) if i < cov.shape[0] else float('nan')
            for i, n in enumerate(names)}


def fit_figures(y: np.ndarray, yhat: np.ndarray) -> tuple[float, float]:
    """Fit [%] as MATLAB ``compare`` and the rms error."""
    r = y - yhat
    den = float(np.linalg.norm(y - y.mean())) or 1.0
    return 100.0 * (1.0 - float(np.linalg.norm(r)) / den), float(np.sqrt(np.mean(r * r)))


def bound_flags(theta: np.ndarray, lo: np.ndarray, hi: np.ndarray, active: np.ndarray,
                dt: float) -> list[str]:
    """``tau_on_..._bound`` and ``td_on_..._bound`` of ``theta = (G0, tau, td, ...)``.

    A value within ``1e-4`` of the bound range (plus ``1e-3 dt``) of a bound, or held there by
    the optimiser's active set (``active``, as scipy's ``active_mask``), is on it.
    """
    flags = []
    for i, p in ((1, 'tau'), (2, 'td')):
        val, a, b, act = theta[i], lo[i], hi[i], int(active[i])
        tol = 1e-4 * (b - a if math.isfinite(b) else abs(val)) + 1e-3 * dt
        if act < 0 or val - a <= tol:
            flags.append(f'{p}_on_lower_bound')
        elif act > 0 or b - val <= tol:
            flags.append(f'{p}_on_upper_bound')
    return flags


# --------------------------------------------------------------------------------------------
# Residual tests
# --------------------------------------------------------------------------------------------

def xcorr(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """Normalised cross-correlation ``r_ab[l] = sum a[k] b[k+l] / (N sd_a sd_b)``, l = -L..L."""
    a = a - a.mean()
    b = b - b.mean()
    n = a.size
    nfft = sfft.next_fast_len(2 * n)
    c = np.fft.irfft(np.conj(np.fft.rfft(a, nfft)) * np.fft.rfft(b, nfft), nfft)
    den = math.sqrt(float(a @ a) * float(b @ b)) or 1.0
    return np.concatenate([c[nfft - lags:], c[:lags + 1]]) / den


def residual_checks(r: np.ndarray, v: np.ndarray, lags: int = N_LAGS,
                    alpha: float = ALPHA) -> dict:
    """Whiteness and input-residual independence tests (as MATLAB ``resid``).

    Each test compares the largest normalised correlation over its lags with a Sidak-corrected
    two-sided level, so that ``alpha`` is the family-wise false-alarm rate. The standard
    deviation of a cross-correlation lag is ``sqrt(sum_k rho_u(k) rho_e(k) / N)`` (Bartlett),
    which is ``1/sqrt(N)`` for a white residual.
    """
    n = r.size
    acf = xcorr(r, r, lags)[lags:]
    z_auto = np.abs(acf[1:]) * math.sqrt(n)
    # scipy.stats takes 0.7 s to import: only where the whiteness test needs its quantiles.
    from scipy import stats
    zc_auto = float(stats.norm.ppf(1 - (1 - (1 - alpha) ** (1 / lags)) / 2))
    ccf = xcorr(v, r, lags)
    acf_u = xcorr(v, v, lags)[lags:]
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


# --------------------------------------------------------------------------------------------
# Covariance
# --------------------------------------------------------------------------------------------

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
        L = _bandwidth(xcorr(rg, rg, nl)[nl:], m)
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
