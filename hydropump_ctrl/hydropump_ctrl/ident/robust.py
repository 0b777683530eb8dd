"""The robust method (the default): exact sampled eq. 19, global delay search, local refinement.

The model is the exact sampled response of eq. 19 for an input held between samples, with a
fractional delay (no Pade, no rounding to whole samples), a free offset and a free initial
state. A global grid covers the delay (every whole-sample delay in the bounds, each with the
best ``tau`` of a log grid, the linear parameters solved in closed form:
:func:`delay_profile`); a bounded least-squares fit of all parameters then starts from the
best grid minima. A sinusoidal dither on the current (not held between samples) is taken out
of the input and fitted as a free sinusoid in the flow.

Owns :class:`Window` (one record's data and model with its Jacobian, also the building block
of the joint fit) and the bounded solver both use.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np
from scipy import fft as sfft
from scipy import optimize

from .diagnostics import bound_flags, covariance, Estimate
from .model import coefficients
from .signals import Dither, dither_lines


class Window:
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
        from scipy import signal  # half a second to import: where it is used
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


def delay_profile(win: Window, taus: np.ndarray, d_lo: int, d_hi: int) -> np.ndarray:
    """SSE on the grid of ``taus`` times whole-sample delays ``d_lo..d_hi``.

    For each ``tau`` one filter pass gives the unit response ``s``; a delay of ``d`` samples
    is ``s`` shifted by ``d``, so all delays follow from one FFT cross-correlation with the
    data, and the linear parameters ``(G0, c0, e0)`` from a 3x3 normal equation per delay.
    The products of ``s`` with the free response ``a^(k-k0)`` for all delays come from one
    backward first-order filter pass.
    """
    from scipy import signal  # half a second to import: where it is used
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


def profile_minima(P: np.ndarray, n: int = 3, sep: int = 3) -> list[int]:
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


def solve_bounded(both, theta0: np.ndarray, lo: np.ndarray, hi: np.ndarray, max_nfev: int):
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


def _starts(win: Window, dt: float, td_b, tau_b, start, n_tau: int
            ) -> tuple[list[np.ndarray], int]:
    """Starting points of the local fit from the global grid (and the user's start), and the
    number of grid evaluations."""
    # Every whole-sample delay in the bounds, tau on a log grid.
    d_lo = int(math.ceil(td_b[0] / dt - 1e-9))
    d_hi = int(math.floor(td_b[1] / dt + 1e-9))
    taus = np.geomspace(tau_b[0], tau_b[1], n_tau)
    sse = delay_profile(win, taus, d_lo, d_hi)
    P = sse.min(axis=0)
    starts = []
    minima = profile_minima(P)
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
    return starts, int(taus.size * P.size)


def fit_robust(u: np.ndarray, y: np.ndarray, dt: float, *, td_bounds, tau_bounds,
               start: Sequence[float] | None = None, n_tau: int = 24,
               dither='auto') -> Estimate:
    """The robust fit of checked, normalised data (see :func:`~.fit.fit_fopdt`).

    ``td_bounds`` and ``tau_bounds`` are ``(lower, upper)`` [s]; ``start`` is ``(G0, tau,
    td)`` or ``None``; ``dither`` as in :func:`~.signals.dither_lines`.
    """
    lines = dither_lines(u, dt, dither)
    win = Window(u, y, dt, td_bounds[1], lines)
    extra = np.full(win.p - 3, np.inf)
    lo = np.r_[-np.inf, tau_bounds[0], td_bounds[0], -extra]
    hi = np.r_[np.inf, tau_bounds[1], td_bounds[1], extra]
    starts, nfev = _starts(win, dt, td_bounds, tau_bounds, start, n_tau)

    def both(th):
        yhat, J = win.model(th, jac=True)
        return yhat - win.y, J

    best = None
    for th0 in starts:
        res = solve_bounded(both, th0, lo, hi, max_nfev=200)
        nfev += res.nfev
        if best is None or res.cost < best.cost:
            best = res
    theta = best.x
    yhat, J = win.model(theta, jac=True)
    G0, tau, td, c0 = (float(x) for x in theta[:4])
    # Offset at u = 0 is c0 - G0 mean(u): its variance follows from the covariance.
    T = np.eye(win.p)
    T[3, 0] = -win.u_mean
    cw, ch, _ = covariance(J, win.y - yhat)
    flags = [] if best.status > 0 else ['not_converged']
    flags += bound_flags(theta, lo, hi, best.active_mask, dt)
    return Estimate(G0=G0, tau=tau, td=td, offset=c0 - G0 * win.u_mean, y=win.y, y_hat=yhat,
                    u=u[win.k0:], v=win.v[win.k0:], k0=win.k0, cov_white=T @ cw @ T.T,
                    cov_hac=T @ ch @ T.T, nfev=nfev, flags=flags,
                    bounds={'td': td_bounds, 'tau': tau_bounds},
                    dither=[{'freq': d.freq, 'amp': d.amp} for d in lines])
