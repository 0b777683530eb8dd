"""The front end of the calibration: :func:`calibrate` and :func:`validate`, and what they
return (:class:`Calibration`, :class:`ParameterEstimate`, the fit and misfit tables). The
package's ``__init__`` only names what it offers (scipy's ``optimize._lsq`` keeps
``least_squares`` in a module of its own the same way).
"""


from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import math
import time
from typing import Any

import numpy as np

from hydropump_sim.errors import HydropumpError, InputError
from hydropump_sim.params import Params
from hydropump_sim.plant_model import PumpModel
from hydropump_sim.reduction import Fidelity, with_fidelity

from ..fit import blas_single_threaded
from .data import (
    CalibrationError,
    check_signals,
    excitation_check,
    Experiment,
    experiment_from,
)
from .engine import Engine, params_with, tied_values
from .lacks import columns, missing, zero_starts
from .problem import (
    check_free,
    Coordinates,
    DELAY_MAX,
    LEAD_SAMPLES,
    Prior,
    Problem,
    timing_convention,
)
from .start import start_values
from .uncertainty import (
    analyse,
    CONSIDERED,
    considered,
    DETERMINED_REL_STD,
    interval,
    singular_directions,
)
from .writers import (
    SCHEMA,
)

# ---- the result ----------------------------------------------------------------------------


@dataclass
class ParameterEstimate:
    """One free parameter: its estimate and what the data say about it (SI)."""

    name: str
    value: float
    initial: float
    stderr: float                     # standard error [the parameter's unit]
    ci95: tuple[float, float]         # 95 % interval
    well_determined: bool
    reason: str = ''                  # why it is not, and what the data determine instead
    held: bool = False                # held at ``value`` (a singular direction)
    on_bound: str | None = None       # 'lower' / 'upper'
    prior: str | None = None          # the prior it was given
    # The part of the interval's width from constants the model fixes (uncertainty.CONSIDERED)
    model_stderr: float = 0.0

    @property
    def relative_stderr(self) -> float:
        return self.stderr / abs(self.value) if self.value else math.inf

    def to_dict(self) -> dict[str, Any]:
        return {'value': self.value, 'stderr': _num(self.stderr),
                'relative_stderr': _num(self.relative_stderr),
                'ci95': [_num(v) for v in self.ci95], 'initial': self.initial,
                'well_determined': self.well_determined, 'reason': self.reason,
                'held': self.held, 'held_at': self.value if self.held else None,
                'on_bound': self.on_bound, 'prior': self.prior,
                'model_stderr': _num(self.model_stderr)}


def _num(v):
    return None if v is None or not math.isfinite(v) else float(v)


@dataclass
class Calibration:
    """What :func:`calibrate` found (see :meth:`to_dict` for the JSON form)."""

    params: Params
    start: Params
    estimates: list[ParameterEstimate]
    correlation: np.ndarray
    singular_values: np.ndarray
    weak: list[dict]                          # poorly determined directions
    held: list[dict]                          # singular directions held at the start
    fit: dict[str, dict[str, float]]          # experiment -> signal -> fit %
    fit_before: dict[str, dict[str, float]]
    misfit: dict[str, dict[str, dict]]        # experiment -> signal -> rms [SI], noise, ratio
    delays: dict[str, dict[str, float]]       # experiment ('all': shared) -> signal -> s
    offsets: dict[str, dict[str, float]]
    sigma: dict[str, dict[str, float]]
    flags: list[str]
    notes: list[str]
    sources: list[str]
    free: tuple[str, ...]
    tied: dict[str, float]
    priors: list[Prior]
    method: str
    n_simulations: int
    wall_time: float
    cost: float
    cost_start: float = math.nan              # the same at the start: did the fit improve?
    # The fixed parameters that would explain most of a misfit beyond the noise (.lacks).
    missing: list[dict] = field(default_factory=list)
    timing: str = ''                          # the bench's timing convention, in words
    provenance: dict | None = None            # where it came from (..provenance.collect)
    fidelity: str = 'fine'                    # the model fitted (reduction.Fidelity.text)
    predictions: list[dict[str, np.ndarray]] = field(default_factory=list, repr=False)
    predictions_before: list[dict[str, np.ndarray]] = field(default_factory=list, repr=False)
    experiments: list[Experiment] = field(default_factory=list, repr=False)
    # Fisher information of the data in the search coordinates (the nuisance projected out).
    information: np.ndarray | None = field(default=None, repr=False)
    covariance: np.ndarray | None = field(default=None, repr=False)

    def estimate(self, name: str) -> ParameterEstimate:
        return next(p for p in self.estimates if p.name == name)

    def to_dict(self) -> dict[str, Any]:
        return {
            'schema': SCHEMA,
            'free': list(self.free),
            'parameters': {p.name: p.to_dict() for p in self.estimates},
            'tied': self.tied,
            'priors': [p.text for p in self.priors],
            'correlation': [[_num(v) for v in row] for row in self.correlation],
            'singular_values': [float(v) for v in self.singular_values],
            'weak_directions': self.weak, 'held_directions': self.held,
            'fit_percent': self.fit, 'fit_percent_before': self.fit_before,
            'misfit': self.misfit,
            'delays_s': self.delays, 'offsets': self.offsets, 'noise_sigma': self.sigma,
            'flags': self.flags, 'notes': self.notes, 'bags': self.sources,
            'method': self.method, 'fidelity': self.fidelity,
            'n_simulations': self.n_simulations,
            'wall_time_s': self.wall_time, 'cost': self.cost, 'cost_start': _num(self.cost_start),
            'missing_effects': [{k: v for k, v in c.items() if k != 'signals'}
                                | {'noise_ratio': {s: list(v) for s, v in c['signals'].items()}}
                                for c in self.missing],
            'timing': self.timing,
            **({'provenance': self.provenance} if self.provenance else {}),
        }

    @property
    def improved(self) -> bool:
        """Does the calibrated model fit the data better than the start?"""
        return bool(self.cost < self.cost_start) if math.isfinite(self.cost_start) else True


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """Normalised-RMSE fit ``100 (1 - |y - yhat| / |y - mean y|)`` [%] (MATLAB's ``compare``)."""
    ok = np.isfinite(y) & np.isfinite(yhat)
    y, yhat = y[ok], yhat[ok]
    den = np.linalg.norm(y - y.mean())
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den)) if den > 0 else float('nan')


# A signal that moves less than this many times its noise in a recording (a flow at a held
# current while the load pressure steps) has no variance for a fit % to measure: its fit %
# is reported as not meaningful (None), never as a failure.
MEANINGFUL_SPREAD = 3.0


def _fits(exps, preds) -> dict[str, dict[str, float | None]]:
    out = {}
    for e, p in zip(exps, preds):
        per = {}
        for s, y in e.measured.items():
            spread = float(np.nanstd(y)) if np.isfinite(y).any() else 0.0
            per[s] = round(fit_percent(y, p[s]), 3) \
                if spread > MEANINGFUL_SPREAD * e.sigma[s] else None
        out[e.name] = per
    return out


# A signal whose residual rms exceeds its noise level by this factor is not fitted: the model
# leaves out something the data have.
MISFIT_RATIO = 1.5


def misfit_table(exps, preds) -> dict[str, dict[str, dict]]:
    """Per experiment and signal: the residual's rms in SI units, the noise level, their
    ratio (1 when the model explains everything but the noise)."""
    out = {}
    for e, p in zip(exps, preds):
        per = {}
        for s, y in e.measured.items():
            d = p[s] - y
            rms = float(np.sqrt(np.nanmean(d ** 2)))
            per[s] = {'rms': rms, 'noise': float(e.sigma[s]),
                      'ratio': rms / e.sigma[s] if e.sigma[s] > 0 else math.inf,
                      'max_abs': float(np.nanmax(np.abs(d)))}
        out[e.name] = per
    return out


def _solve(prob: Problem, z0: np.ndarray, max_nfev: int, basis=None, z_ref=None):
    """Trust-region least squares from ``z0`` (scipy), in the span of ``basis`` around
    ``z_ref`` when given (the held directions stay at ``z_ref``)."""
    from scipy.optimize import least_squares
    lo, hi = prob.coords.bounds()
    if basis is None:
        z0 = np.clip(z0, lo, hi)
        return least_squares(prob.residuals, z0, jac=prob.jacobian, bounds=(lo, hi),
                             method='trf', x_scale='jac', max_nfev=max_nfev, xtol=1e-8,
                             ftol=1e-8, gtol=1e-8)

    def full(w):
        return np.clip(z_ref + basis @ w, lo, hi)

    sol = least_squares(lambda w: prob.residuals(full(w)), basis.T @ (z0 - z_ref),
                        jac=lambda w: prob.jacobian(full(w)) @ basis, method='trf',
                        x_scale='jac', max_nfev=max_nfev, xtol=1e-8, ftol=1e-8, gtol=1e-8)
    sol.x = full(sol.x)
    return sol


def _nuisance_tables(prob: Problem, nuis) -> tuple[dict, dict]:
    delays, offsets = {}, {}
    for (i, s), (d, o) in nuis.items():
        name = 'all' if i is None else prob.exps[i].name
        if prob.fit_delays:
            delays.setdefault(name, {})[s] = round(float(d), 7)
        if (i, s) in prob.with_offset:
            offsets.setdefault(name, {})[s] = float(o)
    return delays, offsets


def _recorded(exps) -> list[str]:
    """The model inputs the recordings carry besides the current."""
    return ['load_pressure'] if any(e.load_pressure is not None for e in exps) else []


def prepare(recordings, base: Params, free: Sequence[str], signals, offsets: Sequence[str],
            priors: Sequence[Prior], check_free=check_free, settled: bool = True
            ) -> list[Experiment]:
    """The recordings as experiments (:func:`.data.experiment_from`, ``settled`` passed on),
    after every check of what was asked: the compared signals, the free parameters (by
    ``check_free(base, free, recorded)``), the excitation, the offsets and the priors; one
    :class:`CalibrationError` with a line per problem."""
    errors = check_signals(signals)
    if errors:
        raise CalibrationError(errors)
    exps = [experiment_from(r, base, signals, settled) for r in recordings]
    recorded = _recorded(exps)
    errors = check_free(base, free, recorded) + excitation_check(exps)
    errors += [f'--offset {s}: not a compared signal of these recordings (compared: '
               f'{", ".join(sorted({x for e in exps for x in e.measured}))})'
               for s in offsets if not any(s in e.measured for e in exps)]
    errors += [f'--prior {p.name}: not a free parameter (free: {", ".join(free)})'
               for p in priors if p.name not in free]
    if errors:
        raise CalibrationError(errors)
    names = {e.name for e in exps}
    if len(names) < len(exps):
        for k, e in enumerate(exps):
            e.name = f'{k + 1}:{e.name}'
    return exps


@blas_single_threaded
def pump_fidelity(base: Params, fidelity: str, bandwidth: float, free: Sequence[str]
                  ) -> tuple[str, Fidelity]:
    """The pump's form at ``fidelity`` (see :func:`calibrate`), or a
    :class:`CalibrationError` saying why not: a free parameter the simplified pump does
    without (the spool's and plate's motion, which eq. 10 makes static), found as one whose
    change moves none of its derivatives and signals off rest."""
    try:
        simple, fid = with_fidelity(PumpModel(base), fidelity, bandwidth)
    except InputError as exc:
        raise CalibrationError([str(exc)]) from None
    if simple.model != 'fine':
        x = simple.start_states(simple.u0)[0] * (1.0 + 1e-3) + 1e-9
        at = simple.rhs(0.0, x, simple.u0)
        gone = []
        for name in free:
            other = PumpModel(params_with(base, [name], [1.1 * base.flat()[name]]),
                              simple.model)
            if all(np.array_equal(a, b) for a, b in zip(at, other.rhs(0.0, x, other.u0))):
                gone.append(name)
        if gone:
            raise CalibrationError([
                f'{", ".join(gone)}: not in the simplified pump (eq. 10 makes the spool and '
                'plate static); free it at --fidelity fine'])
    return simple.model, fid


def calibrate(recordings: Sequence, base: Params, free: Sequence[str], *,
              offsets: Sequence[str] = (), fit_delays: bool = True, per_bag: bool = False,
              signals: Sequence[str] | None = None, priors: Sequence[Prior] = (),
              rtol: float = 1e-5, max_nfev: int = 30, multistart: bool = True,
              closed_form_start: bool = True, executor=None, workers: int | None = None,
              progress: Callable[[str], None] | None = None, fidelity: str = 'fine',
              bandwidth: float = 0.0) -> Calibration:
    """Fit the free plant parameters to ``recordings`` (see the package).

    Parameters
    ----------
    recordings : sequence of Recording
    base : Params
        The start; every parameter not free keeps its value.
    free : sequence of str
        Dotted names of the parameters to fit.
    offsets : sequence of str
        Signals that also get an offset per recording (a sensor's zero error).
    fit_delays : bool
        Fit a measurement delay per signal (shared by the recordings, or per recording with
        ``per_bag``).
    signals : sequence of str, optional
        The compared outputs; default those a bench measures
        (:data:`hydropump_sim.measure.BENCH_OUTPUT_SIGNALS`).
    priors : sequence of Prior
        Gaussian priors in log coordinates on free parameters (:func:`parse_prior`).
    closed_form_start : bool
        Also try the start values of :func:`.start.start_values` and begin from the better.
    executor : hydropump_ctrl.batch.Executor, optional
        Where the simulations run (a Dask cluster: each a task); default threads of this
        process (:data:`.engine.THREADS`, or ``workers`` of them).
    fidelity, bandwidth : str, float
        The model fitted: the fine pump, or section IV's simplified one at ``bandwidth``
        [Hz] (eq. 10 where the spool and plate lie beyond it;
        :func:`hydropump_sim.reduction.with_fidelity`), whose error bound the result's
        ``fidelity`` states. Its free parameters must be ones it keeps.

    Raises
    ------
    CalibrationError
        Bad free parameters, recordings without the needed signals, no excitation, a
        parameter the recordings cannot inform, or no convergence.
    """
    t_wall = time.perf_counter()
    free, priors = tuple(free), list(priors)
    exps = prepare(recordings, base, free, signals, offsets, priors)
    coords = Coordinates.of(base, free)
    theta0 = np.array([float(base.flat()[n]) for n in free])
    form, fid = pump_fidelity(base, fidelity, bandwidth, free)
    engine = Engine(base, free, exps, rtol=rtol, executor=executor, workers=workers,
                    model=form)
    prob = Problem(engine, coords, offsets=offsets, fit_delays=fit_delays, per_bag=per_bag,
                   priors=priors, progress=progress)
    try:
        found = fit_problem(prob, theta0, max_nfev, multistart,
                            start_values(base, free, exps) if closed_form_start else None)
        params = params_with(base, free, prob.theta(found.z))
        model_se = _considered(prob, found.z, found.Jr, params, free)
        cal = result_of(prob, found, params, base, tied_values(params.flat(), free),
                        recordings, t_wall, model_se)
        cal.fidelity = fid.text()
        if any(m['ratio'] > MISFIT_RATIO for per in cal.misfit.values() for m in per.values()):
            try:
                cal.missing = missing(prob, found.z, cal.params, free, _recorded(exps))
            except HydropumpError as exc:   # an analysis beside the result, never its end
                cal.notes.append(f'what the model lacks was not judged: {exc}')
        return cal
    finally:
        engine.close()


@dataclass
class Found:
    """What :func:`fit_problem` found: the search vector, the projected Jacobians, the
    uncertainty analysis, the start's predictions and cost, and how."""

    z: np.ndarray
    theta0: np.ndarray
    Jr: np.ndarray
    unc: Any
    before: list
    cost_start: float
    method: str


def fit_problem(prob: Problem, theta0: np.ndarray, max_nfev: int, multistart: bool,
                candidate: tuple[dict, list] | None = None) -> Found:
    """The fit of any model behind ``prob`` (its engine simulates): from ``theta0``, or from
    ``candidate`` (start values by name and why) where they fit better; the starts x 0.6 and
    x 1.6 with ``multistart`` where the first stops above the noise; every direction no data
    inform held at the start; the uncertainty analysis at the result."""
    free = prob.coords.names
    z0 = prob.coords.to_z(theta0)
    z_start, tried, before, cost_start = _start(prob, z0, theta0, candidate)
    _check_informed(prob, z_start, free)
    sol, tried = _fit(prob, prob.coords, theta0, z_start, tried, max_nfev, multistart)
    z = sol.x
    prob.evaluate(z, search=True)
    method = ('trust-region least squares (scipy) from ' + ', '.join(tried) + '; '
              f'sensitivities {prob.engine.sensitivities}; delays and offsets by variable '
              'projection')
    z, Jr, J_prior, held = _hold_uninformed(prob, z0, z, len(free), max_nfev)
    if held.shape[1]:
        method += '; a singular direction held at the start'
    unc = analyse(Jr, prob.data_residuals(z), free, prob.row_groups(), J_prior, held)
    return Found(z, np.asarray(theta0, float), Jr, unc, before, cost_start, method)


def _start(prob: Problem, z0: np.ndarray, theta0: np.ndarray, candidate
           ) -> tuple[np.ndarray, list[str], dict, float]:
    """Where the fit starts: the start values, or the ``candidate`` ones where they fit
    better, moved off zero. Returns the start, what it is, the predictions and the mean
    squared residual at the start values."""
    try:
        prob.evaluate(z0, search=True)
        before = prob.predictions(z0)
        r_start = prob.data_residuals(z0)
        cost_start = float(np.sum(r_start ** 2) / max(r_start.size, 1))
    except HydropumpError as exc:
        raise CalibrationError(f'the start parameters do not simulate: {exc}') from None
    tried = ['the start']
    z_start = z0
    cand, why = candidate or ({}, [])
    if cand:
        zc = prob.coords.to_z(np.array([cand.get(n, v) for n, v in
                                        zip(prob.coords.names, theta0)]))
        try:
            c0 = float(np.sum(prob.residuals(z0) ** 2))
            prob.evaluate(zc, search=True)
            c1 = float(np.sum(prob.residuals(zc) ** 2))
        except HydropumpError:
            c1 = math.inf
        if c1 < c0:
            z_start = zc
            tried = ['the closed-form start (' + ', '.join(why) + ')']
        else:
            prob.evaluate(z0, search=True)
    return _from_zero(prob, z_start), tried, before, cost_start


def _check_informed(prob: Problem, z: np.ndarray, free: tuple) -> None:
    """A parameter no signal of any recording depends on cannot be informed."""
    Jp0, _ = prob.sensitivities(z)
    dead = [n for j, n in enumerate(free) if not np.any(Jp0[:, j])]
    if dead:
        raise CalibrationError(
            [f'{n} cannot be informed by these recordings: no measured signal depends on '
             'it in these runs (for instance a relief valve never reached, or a friction '
             'set to zero)' for n in dead])


def _fit(prob: Problem, coords: Coordinates, theta0: np.ndarray, z_start: np.ndarray,
         tried: list[str], max_nfev: int, multistart: bool):
    """The least-squares fit from ``z_start``, and (with ``multistart``, where it stops
    above the noise) from the start's values x 0.6 and x 1.6: the best, and every start
    tried."""
    start_nuis = dict(prob.nuis)
    sol = _solve(prob, z_start, max_nfev)
    if multistart and not prob.at_noise_level(sol.fun):
        for f in (0.6, 1.6):
            zs = coords.to_z(np.clip(theta0 * f, coords.lo, coords.hi))
            try:
                prob.nuis = dict(start_nuis)
                prob.evaluate(zs, search=True)
                cand = _solve(prob, zs, max_nfev)
            except HydropumpError:
                continue
            tried.append(f'the start x {f:g}')
            if cand.cost < sol.cost:
                sol = cand
    if not np.isfinite(sol.cost) or not np.all(np.abs(sol.fun) < 1e6):
        raise CalibrationError(f'the fit did not converge (tried from {", ".join(tried)}): '
                               'the model cannot follow the recordings from any start; '
                               'check the params file and the recorded signals')
    return sol, tried


def _hold_uninformed(prob: Problem, z0: np.ndarray, z: np.ndarray, n: int, max_nfev: int):
    """The fit at ``z`` with every direction no data inform held at the start's value (and
    fitted again in the others): the parameters, the projected Jacobians and the held
    directions."""
    Jr, J_prior = _projected(prob, z)
    held = singular_directions(Jr.T @ Jr + J_prior.T @ J_prior)
    if held.shape[1]:
        basis = np.linalg.qr(np.column_stack([held, np.eye(n)]))[0][:, held.shape[1]:n]
        z_ref = z0 - basis @ (basis.T @ z0) + basis @ (basis.T @ z)
        sol = _solve(prob, z_ref, max_nfev, basis=basis, z_ref=z_ref)
        z = sol.x
        prob.evaluate(z, search=True)
        Jr, J_prior = _projected(prob, z)
    return z, Jr, J_prior, held


def _from_zero(prob: Problem, z: np.ndarray) -> np.ndarray:
    """``z`` with the free parameters at zero started where the data suggest
    (:func:`.lacks.zero_starts`), when that fits better or a column is zero there."""
    zs = zero_starts(prob, z)
    if np.array_equal(zs, z):
        return z
    dead = not np.all(np.any(prob.sensitivities(z)[0], axis=0))
    c0 = float(np.sum(prob.residuals(z) ** 2))
    try:
        prob.evaluate(zs, search=True)
        c1 = float(np.sum(prob.residuals(zs) ** 2))
    except HydropumpError:
        c1 = math.inf
    if c1 < c0 or (dead and math.isfinite(c1)):
        return zs
    prob.evaluate(z, search=True)
    return z


def _considered(prob: Problem, z: np.ndarray, Jr: np.ndarray, params: Params,
                free: Sequence[str]) -> np.ndarray:
    """Per free parameter, the standard error (search coordinates) that the constants of
    :data:`.uncertainty.CONSIDERED` not free give it (consider analysis)."""
    names = [n for n in CONSIDERED if n not in free]
    if not names:
        return np.zeros(len(free))
    coords = Coordinates.of(params, names)
    theta = np.array([float(params.flat()[n]) for n in names])
    # The considered spread in each constant's own search coordinate.
    sd = np.array([CONSIDERED[n] for n in names]) * theta / coords.dtheta_dz(theta)
    try:
        Jc = columns(prob, params, names)
    except HydropumpError:
        return np.zeros(len(free))
    _, Jn = prob.sensitivities(z)
    if Jn.shape[1]:
        Q, _ = np.linalg.qr(Jn)
        Jc = Jc - Q @ (Q.T @ Jc)
    return considered(Jr, Jc, sd)


def _projected(prob: Problem, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from .uncertainty import reduce_nuisance
    Jp, Jn = prob.sensitivities(z)
    return reduce_nuisance(np.hstack([Jp, Jn]), prob.n_plant), prob.prior_rows(z)[1]


def result_of(prob: Problem, found: Found, params, start, tied: dict, recordings,
              t_wall: float, model_se: np.ndarray | None = None) -> Calibration:
    """The :class:`Calibration` of what :func:`fit_problem` found; ``params`` and ``start``
    are the model's parameter sets (a :class:`Params`, or the values by name of an FMU's),
    ``tied`` the parameters that moved with the free ones."""
    exps, free, coords, z = prob.exps, prob.coords.names, prob.coords, found.z
    theta = prob.theta(z)
    after = prob.predictions(z)
    nuis = prob.evaluate(z)[1]
    if model_se is None:
        model_se = np.zeros(len(free))
    estimates, flags = _estimates(prob, free, coords, theta, found.theta0, z, found.unc,
                                  model_se)
    misfit = misfit_table(exps, after)
    fits = _fits(exps, after)
    flags += _fit_flags(prob, nuis, misfit, fits)
    delays, offs = _nuisance_tables(prob, nuis)
    r = prob.residuals(z)
    dt = max(e.dt for e in exps)
    unc = found.unc
    return Calibration(
        params=params, start=start, estimates=estimates, correlation=unc.correlation,
        singular_values=unc.singular_values, weak=unc.weak, held=unc.held,
        fit=fits, fit_before=_fits(exps, found.before), misfit=misfit,
        delays=delays, offsets=offs, sigma={e.name: dict(e.sigma) for e in exps},
        flags=flags, notes=[n for e in exps for n in e.notes],
        timing=timing_convention(delays, dt),
        sources=[str(getattr(rec, 'source', '') or getattr(rec, 'name', ''))
                 for rec in recordings],
        free=tuple(free), tied=tied, priors=list(prob.priors),
        method=found.method, n_simulations=prob.engine.n_trajectories,
        wall_time=time.perf_counter() - t_wall,
        cost=float(np.sum(r ** 2) / max(r.size, 1)), cost_start=found.cost_start,
        predictions=after, predictions_before=found.before, experiments=exps,
        information=unc.information, covariance=unc.covariance)


def _estimates(prob, free, coords, theta, theta0, z, unc, model_se
               ) -> tuple[list[ParameterEstimate], list[str]]:
    """Each free parameter's estimate with its standard error, interval and verdict (on a
    bound, held, weak and with what), and a flag per verdict."""
    flags: list[str] = []
    zlo, zhi = coords.bounds()
    dth = coords.dtheta_dz(theta)
    held_names = {n for h in unc.held for n in h['parameters']}
    weak_of = {}
    for w in unc.weak:
        for n in w['parameters']:
            weak_of.setdefault(n, w)
    prior_of = {p.name: p.text for p in prob.priors}
    estimates = []
    for j, n in enumerate(free):
        tol = 1e-6 * max(1.0, abs(zhi[j] - zlo[j]))
        bound = 'lower' if z[j] <= zlo[j] + tol else 'upper' if z[j] >= zhi[j] - tol \
            else None
        if bound:
            flags.append(f'{n} is on its {bound} bound ({theta[j]:.6g}): the optimum may '
                         'lie outside the schema range, or the data pull it there')
        se_z = float(unc.stderr[j])
        rel = se_z * dth[j] / abs(theta[j]) if theta[j] else math.inf
        good = bool(rel <= DETERMINED_REL_STD) and n not in held_names
        reason = ''
        if n in held_names:
            h = next(h for h in unc.held if n in h['parameters'])
            reason = (f'held at {theta[j]:.6g}: the recordings do not inform '
                      f'{", ".join(h["parameters"])} apart')
            if '/' in h['determined_combination'] or '*' in h['determined_combination']:
                reason += f' (only {h["determined_combination"]} is determined)'
        elif not good:
            w = weak_of.get(n)
            reason = (f'relative standard error {100 * rel:.2g} % (well determined below '
                      f'{100 * DETERMINED_REL_STD:.2g} %)')
            if w and len(w['parameters']) > 1:
                reason += (f'; it moves with {", ".join(x for x in w["parameters"] if x != n)}'
                           f': the data determine {w["determined_combination"]}')
            if rel > 0.3:
                reason += ('; so loosely bound that its interval, a linear approximation, is '
                           'only indicative')
        held = n in held_names
        se = math.inf if held else float(se_z * dth[j])
        ci = (math.nan, math.nan) if held else \
            interval(float(z[j]), math.hypot(se_z, float(model_se[j])), bool(coords.log[j]),
                     float(coords.scale[j]))
        estimates.append(ParameterEstimate(n, float(theta[j]), float(theta0[j]), se, ci, good,
                                           reason, held, bound, prior_of.get(n),
                                           float(model_se[j] * dth[j])))
        if reason:
            flags.append(f'{n}: {reason}')
    return estimates, flags


def _fit_flags(prob, nuis, misfit, fits) -> list[str]:
    """A flag per delay on its bound, per signal not fitted to its noise, per fit below
    zero."""
    exps = prob.exps
    flags: list[str] = []
    for (i, s), (d, _) in nuis.items():
        where = '' if i is None else exps[i].name + ': '
        if prob.fit_delays and d >= DELAY_MAX - 1e-6:
            flags.append(f'{where}the delay of {s} is on its upper bound ({1e3 * d:.3g} ms): '
                         'the signal may lag more')
        elif prob.fit_delays and d <= prob.delay_min + 1e-9:
            flags.append(f'{where}{s} leads the current by the most allowed ({-1e3 * d:.3g} '
                         f"ms, {LEAD_SAMPLES} samples): its stamps and the current's may be "
                         'further apart')
    for name, per in misfit.items():
        for s, m in per.items():
            if m['ratio'] > MISFIT_RATIO:
                flags.append(f'{name}: {s} is not fitted to its noise: residual rms '
                             f'{m["rms"]:.3g} against a noise of {m["noise"]:.3g} (SI), '
                             f'{m["ratio"]:.2g} x: the model leaves out something the data '
                             'have')
    for name, per in fits.items():
        for s, v in per.items():
            if v is not None and v < 0.0:
                flags.append(f'{name}: {s} fit {v:.4g} % is below zero: the model predicts it '
                             'worse than its mean (the units were checked: see the misfit '
                             'table and what the model may lack)')
    return flags


@blas_single_threaded
def validate(recordings: Sequence, params: Params, *, signals=None, fit_delays: bool = True,
             before: Params | None = None) -> dict[str, Any]:
    """How well ``params`` predicts recordings it was not fitted to (the measurement delays
    re-estimated per signal, nothing else): fit % and the residual in SI units per recording
    and signal, with the predictions (and those of ``before``, for overlays).

    Returns a dict with ``fit``, ``misfit``, ``delays``, ``experiments``, ``predictions``,
    and with ``before``: ``fit_before``, ``misfit_before``, ``predictions_before``.
    """
    errors = check_signals(signals)
    if errors:
        raise CalibrationError(errors)
    exps = [experiment_from(r, params, signals) for r in recordings]
    out: dict[str, Any] = {'experiments': exps}
    for tag, p in (('', params), ('_before', before)):
        if p is None:
            continue
        coords = Coordinates((), np.zeros(0, bool), np.zeros(0), np.zeros(0), np.zeros(0))
        prob = Problem(Engine(p, (), exps, workers=1), coords, fit_delays=fit_delays)
        z = np.zeros(0)
        try:
            prob.evaluate(z, search=True)
        except HydropumpError as exc:
            raise CalibrationError(f'the params file does not simulate these recordings: '
                                   f'{exc}') from None
        pred = prob.predictions(z)
        out['fit' + tag] = _fits(exps, pred)
        out['misfit' + tag] = misfit_table(exps, pred)
        out['predictions' + tag] = pred
        if not tag:
            out['delays'] = _nuisance_tables(prob, prob.evaluate(z)[1])[0]
    return out
