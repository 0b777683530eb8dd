"""The paper's method: Nelder-Mead on eq. 20 from seeds taken from the step data.

Section V fits ``G0``, ``tau`` and ``t_d`` by minimising the sum of squared flow errors

    J = sum_i (q_l,m - q_l,i)^2                                                 (eq. 20)

with MATLAB ``fminsearch`` (Nelder-Mead). Here: seeds from Smith's two-point method on the
largest up-step (:func:`step_seed`), deviation variables from the initial steady state
(:func:`initial_levels`), zero initial state, no bounds and no offset or initial-state
parameters, as the paper does; the model is evaluated with the exact sampled response of
:mod:`.model`.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np
from scipy import optimize

from hydropump_sim.metrics import moving_average

from .diagnostics import covariance, Estimate
from .errors import FitError
from .model import zero_state_response
from .signals import find_steps, smoothing_width


def step_seed(u, y, dt: float) -> tuple[float, float, float]:
    """Seeds ``(G0, tau, td)`` from the step data: Smith's two-point method.

    On the largest up-step (growing flow, the zone the paper identifies): ``G0`` from the
    settled levels before and after it, then the times ``t28`` and ``t63`` at which the
    smoothed flow covers 28.3 % and 63.2 % of its change give ``tau = 1.5 (t63 - t28)`` and
    ``t_d = t63 - tau``.
    """
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    idx, size = find_steps(u, dt)
    if idx.size == 0:
        raise FitError('no step in the current: the paper method needs step data')
    up = size > 0
    pick = int(np.argmax(np.where(up, size, -np.inf))) if up.any() else \
        int(np.argmax(np.abs(size)))
    k = int(idx[pick])
    prev = int(idx[pick - 1]) if pick > 0 else 0
    nxt = int(idx[pick + 1]) if pick + 1 < idx.size else u.size
    u0 = float(np.median(u[prev:k])) if k > prev else float(u[k - 1])
    u1 = float(np.median(u[k:nxt]))
    # Settled flow: the last third of each plateau (the delay shifts the flow's own edges).
    pre = y[max(k - max((k - prev) // 3, 1), 0):k]
    post = y[nxt - max((nxt - k) // 3, 1):nxt]
    y0, y1 = float(pre.mean()), float(post.mean())
    G0 = (y1 - y0) / (u1 - u0)
    # Half the step detection's window: the flow's edge is what is being timed.
    ys = moving_average(y[k:nxt], (smoothing_width(dt) // 2) | 1, edges='shrink')
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
    idx, _ = find_steps(u, dt)
    k1 = int(idx[0]) if idx.size else u.size
    n_u = max(k1, 1)
    n_y = max(min(k1 + int(td / dt), y.size), 1)
    return float(np.median(u[:n_u])), float(np.mean(y[:n_y]))


def fit_paper(u: np.ndarray, y: np.ndarray, dt: float, *,
              start: Sequence[float] | None = None) -> Estimate:
    """Nelder-Mead on eq. 20 (``fminsearch`` defaults), deviation variables, zero state.

    ``start`` ``(G0, tau, td)`` replaces the step seeds. Standard errors come from a
    central-difference Jacobian at the end point.
    """
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
        r = z - G0 * zero_state_response(v, dt, tau, td)
        return float(r @ r)

    # scipy's Nelder-Mead is fminsearch's algorithm: 5 % initial simplex (0.00025 for zero
    # components), TolX = TolFun = 1e-4, at most 200 n iterations and evaluations.
    res = optimize.minimize(J, x0, method='Nelder-Mead',
                            options={'xatol': 1e-4, 'fatol': 1e-4, 'maxiter': 600,
                                     'maxfev': 600})
    G0, tau, td = (float(x) for x in res.x)
    if not (tau > 0 and td >= 0 and math.isfinite(res.fun)):
        raise FitError(f'Nelder-Mead ended at an infeasible point (tau = {tau:.3g} s, '
                       f't_d = {td:.3g} s)')
    x = zero_state_response(v, dt, tau, td)
    yhat = y_ref + G0 * x
    # Jacobian by central differences, only for the standard errors.
    Jac = np.empty((u.size, 3))
    Jac[:, 0] = x
    for j, h in ((1, 1e-4 * tau), (2, 1e-2 * dt)):
        tp, tm = list(res.x), list(res.x)
        tp[j] += h
        tm[j] = max(tm[j] - h, 0.0)
        Jac[:, j] = G0 * (zero_state_response(v, dt, tp[1], tp[2])
                          - zero_state_response(v, dt, tm[1], tm[2])) / (tp[j] - tm[j])
    cw, ch, _ = covariance(Jac, y - yhat)
    flags = [] if res.success else ['not_converged']
    if td <= 1e-3 * dt:
        flags.append('td_on_lower_bound')
    return Estimate(G0=G0, tau=tau, td=td, offset=y_ref - G0 * u_ref, y=y, y_hat=yhat, u=u,
                    v=v, k0=0, cov_white=cw, cov_hac=ch, nfev=nfev, flags=flags, seed=seed)
