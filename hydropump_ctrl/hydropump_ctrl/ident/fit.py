"""Fitting eq. 19 to one record: the entry points for arrays and for a recording.

:func:`fit_fopdt` checks normalised data, picks the bounds, runs one method
(:mod:`.robust` by default, :mod:`.paper` for the paper's procedure) and hands its result to
the shared diagnostics. :func:`fit_recording` normalises a :class:`~.recording.Recording`
as the paper does, refuses a filter on the flow alone and flags a truncated bag. Fits run
with BLAS on one thread (:func:`blas_single_threaded`).
"""

from __future__ import annotations

from collections.abc import Sequence
import contextlib
import functools
import math
import time

from .diagnostics import assess, FopdtFit
from .errors import FitError
from .paper import fit_paper
from .robust import fit_robust
from .signals import check_data, default_bounds, Dither, load_default_params, normalise

METHODS = ('robust', 'paper')


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


def blas_single_threaded(fn):
    """Decorator: run ``fn`` with BLAS limited to one thread (see above)."""
    @functools.wraps(fn)
    def wrapper(*args, **kw):
        with _single_blas_thread():
            return fn(*args, **kw)
    return wrapper


@blas_single_threaded
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
        See :mod:`.robust` and :mod:`.paper`.
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
        in the flow (``'auto'``: find them with :func:`~.signals.detect_dither`; ``None``:
        treat the whole current as held).

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
    td_b, tau_b = default_bounds(u.size * dt, dt, td_bounds, tau_bounds)
    start_t = None if start is None else tuple(float(s) for s in start)
    if start_t is not None and len(start_t) != 3:
        raise FitError('start must be (G0, tau, td)')
    if start_t is not None and not (all(math.isfinite(s) for s in start_t)
                                    and start_t[1] > 0.0 and start_t[2] >= 0.0):
        raise FitError(f'start (G0, tau, td) = {start_t}: expected finite values, '
                       'tau > 0 and td >= 0')
    if method == 'robust':
        est = fit_robust(u, y, dt, td_bounds=td_b, tau_bounds=tau_b, start=start_t,
                         n_tau=n_tau, dither=dither)
    else:
        est = fit_paper(u, y, dt, start=start_t)
    return assess(est, method=method, dt=dt, name=name, start=start_t, t_start=t_start)


def fit_recording(rec, *, method: str = 'robust', params=None, start=None, td_bounds=None,
                  tau_bounds=None, allow_flow_filter: bool = False,
                  dither: str | None = 'auto', current: str | None = None,
                  flow: str | None = None) -> FopdtFit:
    """Normalise one recording as the paper does and fit eq. 19 (see :func:`fit_fopdt`).

    ``current`` and ``flow`` name the recording's signals that act as current and flow
    (default: its own ``roles``); ``params`` gives the normalisation (default
    ``config/pump.yaml``). A filter on the flow alone raises :class:`FitError` unless
    ``allow_flow_filter`` (then the fit is flagged ``flow_only_filter``).
    """
    rec = rec.with_roles(current=current, flow=flow)
    params = load_default_params() if params is None else params
    flow_f = rec.filters.get(rec.roles['flow'])
    cur_f = rec.filters.get(rec.roles['current'])
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
