"""What the data say about each parameter: standard errors, 95 % intervals, weak directions.

At the optimum, the Jacobian of the noise-weighted residuals with respect to the search
coordinates (``log theta``: relative sensitivities), with the nuisance columns (delays,
offsets) projected out, gives

- the **covariance** of the estimates: the Newey-West (HAC) sandwich of
  :func:`..diagnostics.covariance` (residuals correlated in time, e.g. by a model that does
  not quite fit, widen it honestly), never below the white-noise covariance, with a prior's
  information added where one was given;
- per parameter, its **standard error**, a **95 % interval** (in log coordinates, so
  asymmetric in the parameter) and whether it is **well determined**: a relative standard
  error below :data:`DETERMINED_REL_STD` (within 2 % at three standard errors). A poorly
  determined parameter is still estimated; it is flagged, with the direction of parameter
  space that is weak and the combination the data do determine (``beta / V_l``);
- the **constants the equations fix but no pump states** (:data:`CONSIDERED`: where the
  orifice laws turn laminar, where friction is smoothed) widen the 95 % intervals by what
  their uncertainty does to the estimates (consider analysis): a pump whose orifices follow
  another law near their laminar region than the model's biases the estimates by more than
  the noise does, and the interval says so; the standard error stays the noise's;
- directions the information matrix is **singular** in to working precision: an eigenvalue
  below :data:`SINGULAR` of the largest, after scaling each parameter to unit sensitivity.
  The sensitivities come from copies of the plant that share the nominal run's iteration
  matrix and are good to about 1e-3 (0.1 % on the flows and pressures), so a direction
  informed less than that, relative to the best-informed one, is numerical noise, not
  data. Only these are held at the start, and the result says that they were and at what;
  a parameter in one has no standard error.

:mod:`..design` says which of the standard experiments would determine a weak direction.
Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np

from ..diagnostics import covariance

# A combination of parameters is well determined when its relative standard error is below
# this (so that it is within 2 % at three standard errors).
DETERMINED_REL_STD = 0.02 / 3.0
# An information eigenvalue below this fraction of the largest (parameters scaled to unit
# sensitivity) is zero to working precision: the square of the sensitivities' accuracy.
SINGULAR = 1e-6
Z95 = 1.959963984540054   # the two-sided 95 % quantile of the normal distribution

#: Constants the equations fix but no pump states, considered uncertain in the intervals
#: (consider analysis), as a standard deviation of their logarithm: the model's
#: regularisations, the pressure drops at which the orifice laws turn laminar and the
#: velocities below which Coulomb friction is smoothed (a real orifice's transition and a
#: real friction's law near rest are known only to a factor of about two).
CONSIDERED = {'actuator.dp_cr_a': math.log(2.0), 'line.dp_cr_u': math.log(2.0),
              'spool.v_eps_c': math.log(2.0), 'plate.v_eps_a': math.log(2.0)}


@dataclass
class Uncertainty:
    singular_values: np.ndarray          # of the scaled, projected sensitivity matrix
    covariance: np.ndarray               # of the search coordinates (HAC, priors included)
    correlation: np.ndarray
    stderr: np.ndarray                   # per plant parameter, in the search coordinates
    weak: list[dict] = field(default_factory=list)     # poorly determined directions
    held: list[dict] = field(default_factory=list)     # singular directions, held
    basis: np.ndarray | None = None      # the estimable directions (columns), when some held
    information: np.ndarray | None = None   # J'J of the data (nuisance projected out)


def reduce_nuisance(J: np.ndarray, n_plant: int) -> np.ndarray:
    """The plant columns with the nuisance columns' span projected out."""
    Jp, Jn = J[:, :n_plant], J[:, n_plant:]
    if Jn.shape[1] == 0:
        return Jp
    Q, _ = np.linalg.qr(Jn)
    return Jp - Q @ (Q.T @ Jp)


def combination_text(names: Sequence[str], w: np.ndarray) -> tuple[list[str], str]:
    """The parameters a direction ``w`` mixes, and the combination orthogonal to it that the
    data determine (for two parameters)."""
    a = np.abs(w)
    involved = [j for j in range(len(w)) if a[j] >= 0.25 * a.max()]
    short = [names[j].split('.')[-1] for j in involved]
    if len(involved) == 1:
        return [names[involved[0]]], f'nothing of {short[0]} alone'
    if len(involved) == 2:
        i, j = involved
        p = -w[i] / w[j]     # theta_i * theta_j^p is determined
        if abs(abs(p) - 1.0) < 0.15:
            text = f'{short[0]} / {short[1]}' if p < 0 else f'{short[0]} * {short[1]}'
        else:
            text = f'{short[0]} * {short[1]}^{p:.2f}'
        return [names[k] for k in involved], text
    return [names[k] for k in involved], ('only combinations across ' + ', '.join(short)
                                          + ' that leave this direction out')


def singular_directions(information: np.ndarray) -> np.ndarray:
    """Unit directions (columns) in which ``information`` is singular to working precision,
    judged with every parameter scaled to unit sensitivity."""
    n = information.shape[0]
    d = np.sqrt(np.maximum(np.diag(information), 0.0))
    dead = d <= 0.0
    d[dead] = 1.0
    lam, W = np.linalg.eigh(information / np.outer(d, d))
    out = [W[:, k] / d for k in range(n) if lam[k] <= SINGULAR * max(lam.max(), 1e-300)]
    out += [np.eye(n)[:, j] for j in np.flatnonzero(dead)]
    if not out:
        return np.zeros((n, 0))
    Q, _ = np.linalg.qr(np.column_stack(out))
    return Q[:, :len(out)]


def analyse(Jr: np.ndarray, r: np.ndarray, names: Sequence[str], groups: Sequence[slice],
            J_prior: np.ndarray | None = None, held: np.ndarray | None = None
            ) -> Uncertainty:
    """The uncertainty at a solution (see the module).

    Parameters
    ----------
    Jr : ndarray, shape (N, n)
        The data rows' plant Jacobian with the nuisance directions projected out.
    r : ndarray, shape (N,)
        The data residuals at the solution.
    groups : sequence of slice
        Row ranges of independent noise records (lagged products never cross them).
    J_prior : ndarray, shape (k, n), optional
        The prior rows' Jacobian.
    held : ndarray, shape (n, h), optional
        Directions held at the start (their variance is zero; the rest is conditional on
        them).
    """
    n = Jr.shape[1]
    J_prior = np.zeros((0, n)) if J_prior is None else J_prior
    info_data = Jr.T @ Jr
    info_prior = J_prior.T @ J_prior
    scale = np.sqrt(np.maximum(np.diag(info_data + info_prior), 0.0))
    scale[scale == 0] = 1.0
    sv = np.linalg.svd(np.vstack([Jr, J_prior]) / scale, compute_uv=False) if n else np.zeros(0)
    held = np.zeros((n, 0)) if held is None else held
    # The estimable subspace: the complement of the held directions.
    if held.shape[1]:
        Qf, _ = np.linalg.qr(np.column_stack([held, np.eye(n)]))
        basis = Qf[:, held.shape[1]:n]
    else:
        basis = np.eye(n)
    cov_white, cov_data, _ = covariance(Jr @ basis, r, groups)
    # Never less uncertainty than white residuals would give: the lag window of the HAC
    # estimate is itself estimated, and a short record can make it optimistic.
    lam, V = np.linalg.eigh(cov_white - cov_data)
    cov_data = cov_data + (V * np.maximum(lam, 0.0)) @ V.T
    # The sandwich with a prior: B (S_data + I_prior) B, B = (I_data + I_prior)^-1, in the
    # estimable subspace. It is the posterior covariance when the residuals are white.
    Id, Ip = basis.T @ info_data @ basis, basis.T @ info_prior @ basis
    B = np.linalg.pinv(Id + Ip)
    S = Id @ cov_data @ Id        # the data's meat: cov_data = Id^-1 S Id^-1
    C = basis @ (B @ (S + Ip) @ B) @ basis.T
    C = 0.5 * (C + C.T)
    sd = np.sqrt(np.maximum(np.diag(C), 0.0))
    with np.errstate(invalid='ignore', divide='ignore'):
        corr = C / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, np.nan)
    # Weak directions: the eigenvectors of the covariance whose standard error is large.
    lam, W = np.linalg.eigh(C)
    weak = []
    for k in range(n - 1, -1, -1):
        std = math.sqrt(max(lam[k], 0.0))
        if std <= DETERMINED_REL_STD:
            break
        w = W[:, k]
        involved, text = combination_text(names, w)
        weak.append({'parameters': involved, 'direction': [float(v) for v in w],
                     'determined_combination': text, 'relative_stderr': std})
    held_out = []
    for k in range(held.shape[1]):
        involved, text = combination_text(names, held[:, k])
        held_out.append({'parameters': involved, 'direction': [float(v) for v in held[:, k]],
                         'determined_combination': text})
    return Uncertainty(sv, C, corr, sd, weak, held_out, basis if held.shape[1] else None,
                       info_data)


def considered(Jr: np.ndarray, Jc: np.ndarray, sd: np.ndarray) -> np.ndarray:
    """The standard error each plant parameter (search coordinates) takes from constants
    held at uncertain values: ``Jc`` their columns (nuisance projected out, as ``Jr``'s),
    ``sd`` their standard deviations in their own search coordinates. Each shifts the
    least-squares estimate by ``-(Jr' Jr)^-1 Jr' Jc``; the shifts add in quadrature."""
    if Jc.shape[1] == 0 or Jr.shape[1] == 0:
        return np.zeros(Jr.shape[1])
    shift = np.linalg.lstsq(Jr, Jc, rcond=None)[0] * sd
    return np.sqrt(np.sum(shift ** 2, axis=1))


def interval(z: float, se: float, log: bool, scale: float) -> tuple[float, float]:
    """The 95 % interval of a parameter from its search coordinate ``z`` and standard error
    ``se`` (in that coordinate)."""
    lo, hi = z - Z95 * se, z + Z95 * se
    if log:
        return math.exp(max(lo, -700.0)), math.exp(min(hi, 700.0))
    return lo * scale, hi * scale
