"""Several data sets: per-set fits, their pooled estimate and a joint fit of shared parameters.

The paper reports ``value ± spread`` over nine data sets: the mean and sample standard
deviation of the per-set estimates (:func:`pool`). :func:`fit_joint` fits one shared
``(G0, tau, t_d)`` to all sets at once, each set keeping its own nuisance parameters.
:func:`fit_recordings` and :func:`fit_bags` are the entry points for recordings and bags; an
:class:`Identification` holds what they found (``report.to_dict`` turns it into the JSON
result).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math
import time

import numpy as np

from .diagnostics import bound_flags, covariance, fit_figures, FopdtFit, standard_errors
from .errors import FitError
from .fit import blas_single_threaded, fit_recording
from .model import PARAMS
from .recording import DEFAULT_CURRENT_TOPIC, DEFAULT_FLOW_TOPIC, read_recordings
from .robust import solve_bounded, Window
from .signals import (
    check_data,
    default_bounds,
    detect_dither,
    find_steps,
    load_default_params,
    normalise,
)


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


@blas_single_threaded
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
    ``(G0, tau, td)``, e.g. the pooled mean; ``dither`` as in :func:`~.fit.fit_fopdt`.
    """
    t0 = time.perf_counter()
    dur = min(u.size * dt for u, _, dt in records)
    dt_min = min(dt for _, _, dt in records)
    td_b, tau_b = default_bounds(dur, dt_min, td_bounds, tau_bounds)
    wins = []
    for u, y, dt in records:
        u, y = check_data(u, y, dt)
        wins.append(Window(u, y, dt, td_b[1], detect_dither(u, dt) if dither else ()))
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

    res = solve_bounded(both, np.asarray(start, dtype=float), lo, hi, max_nfev=100)
    r, J = both(res.x)
    cw, ch, _ = covariance(J, r, [slice(rows[i], rows[i + 1]) for i in range(len(wins))])
    G0, tau, td = (float(x) for x in res.x)
    flags = [] if res.status > 0 else ['not_converged']
    flags += bound_flags(res.x, lo, hi, res.active_mask, dt_min)
    y_all = np.concatenate([w.y for w in wins])
    fit, rmse = fit_figures(y_all, y_all + r)
    return FopdtFit(G0=G0, tau=tau, td=td, se=standard_errors(ch, PARAMS),
                    se_white=standard_errors(cw, PARAMS), offset=float('nan'),
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
    provenance: dict | None = None     # where it came from (..provenance.collect)

    @property
    def G0(self) -> float:
        return self.pooled.mean['G0']

    @property
    def tau(self) -> float:
        return self.pooled.mean['tau']

    @property
    def td(self) -> float:
        return self.pooled.mean['td']


@blas_single_threaded
def branch(rec, params) -> str:
    """Which branch of the flow's response a recording's current steps excite: 'growing'
    (every step up: eq. 14's time constant), 'falling' (every step down: eq. 15's), 'both'
    (or none found)."""
    u, _ = normalise(rec, params)
    _, sizes = find_steps(u, rec.dt)
    if sizes.size and np.all(sizes > 0):
        return 'growing'
    if sizes.size and np.all(sizes < 0):
        return 'falling'
    return 'both'


def refuse_mixed_branches(recordings: Sequence, params) -> None:
    """One line when some recordings step the flow only up and others only down: eqs. 14
    and 15 give the two branches different time constants, and a mean of both is neither
    (59.5 +- 47 ms from a 100 ms and a 20 ms set)."""
    kinds: dict[str, list[str]] = {}
    for k, rec in enumerate(recordings):
        kinds.setdefault(branch(rec, params), []).append(rec.name or f'set {k + 1}')
    if kinds.get('growing') and kinds.get('falling'):
        raise FitError(f'the sets mix growing-flow steps ({", ".join(kinds["growing"])}) and '
                       f'falling-flow steps ({", ".join(kinds["falling"])}): eqs. 14 and 15 '
                       'give the two branches different time constants, and a mean of both '
                       'is neither; fit each branch on its own')


def fit_recordings(recordings: Sequence, *, method: str = 'robust', params=None,
                   start: Sequence[float] | None = None, td_bounds=None, tau_bounds=None,
                   joint: bool | None = None, progress: bool | None = False,
                   allow_flow_filter: bool = False, dither: str | None = 'auto',
                   current: str | None = None, flow: str | None = None) -> Identification:
    """Fit every :class:`~.recording.Recording` and pool the estimates.

    Parameters
    ----------
    recordings : sequence of Recording
        SI recordings (absolute current [A], flow [m^3/s]).
    method : {'robust', 'paper'}
    params : hydropump_sim.Params, optional
        Plant parameters for the normalisation (current range, ``V_p f_p``); default
        ``config/pump.yaml``.
    start, td_bounds, tau_bounds
        See :func:`~.fit.fit_fopdt`.
    joint : bool, optional
        Also fit shared parameters to all sets at once (default: robust method, 2+ sets).
    progress : bool or None
        Show a tqdm progress bar (``None``: only on a terminal).
    allow_flow_filter : bool
        Fit a recording whose flow alone was filtered (flagged) instead of refusing it.
    dither : 'auto' or None
        Dither handling of the robust method (see :func:`~.fit.fit_fopdt`).
    current, flow : str, optional
        Signals that act as current and flow (default: each recording's ``roles``).
    """
    from tqdm import tqdm

    t0 = time.perf_counter()
    params = load_default_params() if params is None else params
    recordings = [rec.with_roles(current=current, flow=flow) for rec in recordings]
    refuse_mixed_branches(recordings, params)
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
    return Identification(method=method, sets=fits, pooled=pooled, recordings=recordings,
                          normalisation={'current_range_A': [lo, hi],
                                         'flow_full_scale_m3s': params.Q_max},
                          seconds=time.perf_counter() - t0)


def fit_bags(paths: Sequence, *, method: str = 'robust',
             current_topic: str = DEFAULT_CURRENT_TOPIC, flow_topic: str = DEFAULT_FLOW_TOPIC,
             params=None, start=None, td_bounds=None, tau_bounds=None,
             joint: bool | None = None, progress: bool | None = False,
             allow_truncated: bool = False, allow_flow_filter: bool = False,
             dither: str | None = 'auto') -> Identification:
    """Read rosbag2 bags (MCAP or sqlite3) and identify eq. 19 on each, then pool.

    Parameters
    ----------
    paths : path-like or sequence of path-like
        Bag directories, ``.mcap``/``.db3`` files or saved ``.npz`` recordings.
    method : {'robust', 'paper'}
    current_topic, flow_topic : str
        Topic names, matched exactly or by unique suffix (``/ns/line_flow``).
    params : hydropump_sim.Params, optional
        For the normalisation; default ``config/pump.yaml``.
    allow_truncated : bool
        Fit the readable part of a truncated bag (flagged ``truncated_bag``) instead of
        raising :class:`~hydropump_ctrl.bag.BagReadError`.

    A bag whose current or flow cannot be the pump's (mA, L/min, the wrong message type, two
    runs, too few samples) raises :class:`~.errors.PlausibilityError` before any fit.

    Other parameters are those of :func:`fit_recordings`.

    Returns
    -------
    Identification
        ``.sets`` per bag, ``.pooled`` over bags; ``.G0``, ``.tau``, ``.td`` are the pooled
        means (the single fit for one bag). ``.recordings`` hold every contract signal the
        bags carry, decoded once.
    """
    params = load_default_params() if params is None else params
    # Checked against the pump before the fit, as ``hydropump fit`` does (current, flow).
    recs = read_recordings(paths, current_topic=current_topic, flow_topic=flow_topic,
                           allow_truncated=allow_truncated, progress=progress, params=params,
                           check=())
    return fit_recordings(recs, method=method, params=params, start=start,
                          td_bounds=td_bounds, tau_bounds=tau_bounds, joint=joint,
                          progress=progress, allow_flow_filter=allow_flow_filter,
                          dither=dither)
