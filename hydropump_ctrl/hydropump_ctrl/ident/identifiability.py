"""Which parameters the data determine: the scaled sensitivity matrix at the optimum.

The Jacobian of the noise-weighted residuals with respect to the search coordinates
(``log theta``: relative sensitivities) is reduced to the plant parameters by projecting out
the nuisance columns (delays, offsets), whose values are of no interest. Its singular values
say how well each direction of parameter space is informed; the Newey-West covariance of
:func:`.diagnostics.covariance` (residuals correlated in time, as the FOPDT fit does it) gives
the standard error of each parameter and of each direction.

A direction whose relative standard error exceeds :data:`DETERMINED_REL_STD` is *not
determined*: it is reported with the parameters it mixes and the combination that is
determined (for two parameters, a product of powers such as ``beta / V_l``), and the
calibration is repeated in the determined subspace. :mod:`.design` says which of the standard
experiments would determine it.

Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math

import numpy as np

from .diagnostics import covariance

# A combination of parameters is determined when its relative standard error is below this
# (so that a determined parameter is within 2 % at three standard errors).
DETERMINED_REL_STD = 0.02 / 3.0


@dataclass
class Identifiability:
    singular_values: np.ndarray
    correlation: np.ndarray
    stderr: list[float | None]            # per plant parameter, in the search coordinates
    undetermined: list[dict] = field(default_factory=list)
    undetermined_names: set = field(default_factory=set)
    basis: np.ndarray | None = None       # the determined directions (columns)
    flags: list[str] = field(default_factory=list)


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


def analyse(J: np.ndarray, r: np.ndarray, names: Sequence[str], n_plant: int,
            groups: Sequence[slice], *, basis: np.ndarray | None = None,
            undetermined: list[dict] | None = None) -> Identifiability:
    """Identifiability at a solution (see the module). With ``basis`` (after a refit in the
    determined subspace) the undetermined directions are kept as found before."""
    n = n_plant
    Jr = reduce_nuisance(J, n)
    sv = np.linalg.svd(Jr, compute_uv=False) if n else np.zeros(0)
    _, cov_h, _ = covariance(J, r, groups)
    C = cov_h[:n, :n]
    sd = np.sqrt(np.maximum(np.diag(C), 0.0))
    with np.errstate(invalid='ignore', divide='ignore'):
        corr = C / np.outer(sd, sd)
    corr = np.where(np.isfinite(corr), corr, np.nan)
    if basis is None:
        lam, W = np.linalg.eigh(0.5 * (C + C.T))
        # Directions informed weakly or not at all (the pseudo-inverse gives them no
        # variance when their information is exactly zero: those have a zero singular
        # value of the information matrix).
        info = Jr.T @ Jr
        li, Wi = np.linalg.eigh(info)
        dead = li <= 1e-12 * max(li.max(), 1e-300)
        und = [W[:, k] for k in range(n) if math.sqrt(max(lam[k], 0.0)) > DETERMINED_REL_STD]
        und += [Wi[:, k] for k in range(n) if dead[k]]
        undetermined = []
        U = np.zeros((n, 0))
        for w in und:
            w = w - U @ (U.T @ w)
            if np.linalg.norm(w) < 0.5:
                continue
            w = w / np.linalg.norm(w)
            U = np.column_stack([U, w])
            involved, text = combination_text(names, w)
            std = float(math.sqrt(max(w @ C @ w, 0.0)))
            undetermined.append({'parameters': involved, 'direction': [float(v) for v in w],
                                 'determined_combination': text,
                                 'relative_stderr': std if math.isfinite(std) and std > 0
                                 else None})
        if U.shape[1]:
            # The determined directions: the orthogonal complement of the undetermined ones.
            Qf, _ = np.linalg.qr(np.column_stack([U, np.eye(n)]))
            basis = Qf[:, U.shape[1]:n]
    undetermined = undetermined or []
    names_out = {p for u in undetermined for p in u['parameters']}
    stderr: list[float | None] = [None if names[j] in names_out else float(sd[j])
                                  for j in range(n)]
    flags = []
    for u in undetermined:
        comb = u['determined_combination']
        flags.append(f'not determined by these recordings: {", ".join(u["parameters"])}'
                     + (f'; only {comb} is' if '/' in comb or '*' in comb else ''))
    return Identifiability(sv, corr, stderr, undetermined, names_out, basis, flags)
