"""Grey-box calibration of the fine model to recordings (``hydropump calibrate``).

Chosen plant parameters (dotted names of ``config/pump.yaml``) are estimated by fitting the
6th-order fine model to several recordings at once, in the manner of MATLAB's ``nlgreyest``:

- **Inputs** come from each recording: the applied current (the command where it was
  recorded, else the measured current) and the load pressure where it was recorded; aperture
  and shaft speed come from the params file. Each run starts at the equilibrium of its
  initial inputs (the recordings start settled, as the recorder's experiments do).
- **Outputs** are every measured signal the recording has (:data:`OUTPUT_SIGNALS`), each
  weighted by its noise level estimated from the data (:func:`noise_level`).
- **Nuisance parameters**: a measurement delay per signal (0 to :data:`DELAY_MAX`,
  fractional, as the sensor chain delays by linear interpolation) and, where asked, an offset
  per signal. Their sensitivities are computed from the simulated signals (the time
  derivative for a delay, one for an offset), so they cost no simulation.
- **Tied parameters stay consistent**: a parameter the schema derives from another
  (:data:`DERIVED`) moves with it, and freeing the derived one is refused with the name of the
  one to free.
- **Free parameters** are searched in log coordinates (``log theta``; scaled linearly where
  the schema's range reaches zero), bounded by the schema's ranges, with scipy's trust-region
  least squares. The plant sensitivities are forward differences of whole simulations, the
  columns run in parallel processes (:data:`WORKERS`).
- **Identifiability** (:mod:`.identifiability`) is assessed at the optimum; a direction the
  data cannot determine is reported with the combination that is determined, and the fit is
  repeated in the determined subspace, the undetermined combination kept at the start, so
  that no undetermined value is returned as a confident number (:func:`.design.suggest`
  names the experiments that would determine it).
- **Convergence**: a start far from the optimum is handled by multi-start: if the first
  solution does not reach the noise level of the data, the fit restarts from the start
  scaled by 0.6 and 1.6 along every free parameter together and keeps the best.

Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
import math
import multiprocessing
import os
from pathlib import Path
import time
from typing import Any

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.measure import SIGNAL_OUTPUTS
from hydropump_sim.model import OUTPUTS
from hydropump_sim.params import Params, params_from_dict
from hydropump_sim.schema import spec_map, unknown_key_line
from hydropump_sim.simulate import simulate
from hydropump_sim.trim import equilibrium

from .errors import FitError
from .signals import detect_dither

# Measured signals the model is compared on (the load pressure is an input).
OUTPUT_SIGNALS = ('line_flow', 'pump_flow', 'load_flow', 'line_pressure', 'actuator_pressure',
                  'spool_position', 'actuator_position')
PRESSURES = ('line_pressure', 'actuator_pressure', 'load_pressure')
DELAY_MAX = 0.25          # s, the largest measurement delay fitted
NOISE_FLOOR = 1e-3        # the smallest noise level, relative to a signal's span
WORKERS = min(4, os.cpu_count() or 1)

# Parameters the schema derives from others (the cross-checks of params.py): the derived
# name -> (the parameters it follows, the relation, its value from the others).
DERIVED: dict[str, tuple[tuple[str, ...], str, Callable[[Mapping[str, float]], float]]] = {
    'actuator.h_a': (('actuator.mu_a', 'fluid.rho'), 'mu_a = h_a sqrt(2/rho) (eq. 4)',
                     lambda f: f['actuator.mu_a'] / math.sqrt(2.0 / f['fluid.rho'])),
    'actuator.d_a': (('actuator.S_a',), 'S_a = pi d_a^2 / 4',
                     lambda f: math.sqrt(4.0 * f['actuator.S_a'] / math.pi)),
    'spool.phi_s': (('spool.K_a', 'pump.x_a_max', 'spool.I_max'),
                    'phi_s I_max = K_a x_a_max (design condition D1)',
                    lambda f: f['spool.K_a'] * f['pump.x_a_max'] / f['spool.I_max']),
}
# Parameters that are not in the equations, and the operating-point inputs a bag carries.
NOT_IN_MODEL = {'fluid.nu': 'it documents dp_cr and is not in the equations',
                'pump.l_d': 'it is information only (eq. 5), not in the equations'}
FROM_BAG = {'line.P_u': 'load_pressure'}


class CalibrationError(FitError):
    """A calibration that cannot be run or did not converge (one line per problem)."""


# --------------------------------------------------------------------------------------------
# Free parameters and ties
# --------------------------------------------------------------------------------------------

def tied_values(flat: Mapping[str, Any], free: Sequence[str]) -> dict[str, float]:
    """The derived parameters that follow the ``free`` ones, recomputed from ``flat``."""
    out = {}
    values = dict(flat)
    for name, (sources, _, fn) in DERIVED.items():
        if any(s in free for s in sources):
            out[name] = values[name] = fn(values)
    return out


def check_free(base: Params, free: Sequence[str], recorded: Sequence[str] = ()) -> list[str]:
    """One line per free parameter that cannot be freed (unknown, derived, not a number, not
    in the model, an input the recordings carry); empty when all can."""
    specs = spec_map(Params)
    errors = []
    if not free:
        return ['no free parameter: name at least one with --free (e.g. actuator.mu_a)']
    seen = set()
    for name in free:
        if name in seen:
            errors.append(f'{name} is given twice')
            continue
        seen.add(name)
        s = specs.get(name)
        if s is None:
            errors.append(unknown_key_line(name, specs, 'plant parameter'))
        elif name in DERIVED:
            sources, rel, _ = DERIVED[name]
            primary = [x for x in sources if x != 'fluid.rho'] or list(sources)
            errors.append(f'{name} is derived from {" and ".join(sources)} ({rel}): free '
                          f'{" or ".join(primary)} instead')
        elif s.type is not float:
            errors.append(f'{name} is a {s.type.__name__}, not a number: it cannot be fitted')
        elif name in NOT_IN_MODEL:
            errors.append(f'{name} cannot be informed by any data: {NOT_IN_MODEL[name]}')
        elif name in FROM_BAG and FROM_BAG[name] in recorded:
            errors.append(f'{name} is an input: the recordings carry it as '
                          f'{FROM_BAG[name]}')
    return errors


@dataclass(frozen=True)
class Coordinates:
    """Free parameters <-> the search vector ``z``: ``log theta`` where the schema's range is
    positive, ``theta / scale`` where it reaches zero."""

    names: tuple[str, ...]
    log: np.ndarray
    scale: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, base: Params, free: Sequence[str]) -> Coordinates:
        specs = spec_map(Params)
        flat = base.flat()
        lo, hi = (np.array([specs[n].range[k] for n in free], float) for k in (0, 1))
        log = lo > 0
        v = np.array([float(flat[n]) for n in free])
        scale = np.where(log, 1.0, np.where(v > 0, np.abs(v), 1e-3 * hi))
        return cls(tuple(free), log, scale, lo, hi)

    def to_z(self, theta: np.ndarray) -> np.ndarray:
        theta = np.asarray(theta, float)
        return np.where(self.log, np.log(np.maximum(theta, 1e-300)), theta / self.scale)

    def to_theta(self, z: np.ndarray) -> np.ndarray:
        return np.where(self.log, np.exp(z), np.asarray(z) * self.scale)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.to_z(self.lo), self.to_z(self.hi)

    def dtheta_dz(self, theta: np.ndarray) -> np.ndarray:
        """``d theta / d z`` per parameter (``theta`` in log coordinates)."""
        return np.where(self.log, theta, self.scale)


def params_with(base: Params, names: Sequence[str], theta: Sequence[float]) -> Params:
    """``base`` with the free parameters set and their ties followed (re-validated)."""
    flat = base.flat()
    flat.update({n: float(v) for n, v in zip(names, theta)})
    flat.update(tied_values(flat, names))
    return params_from_dict(flat)


# --------------------------------------------------------------------------------------------
# Experiments: what each recording gives the model
# --------------------------------------------------------------------------------------------

@dataclass
class Experiment:
    """One recording as the model sees it: held inputs and weighted measured outputs."""

    name: str
    dt: float
    current: np.ndarray                  # absolute A, held from t[k] to t[k+1]
    load_pressure: np.ndarray | None     # gauge Pa, held; None = the params file's value
    measured: dict[str, np.ndarray]      # SI, gauge pressures, NaN where missing
    sigma: dict[str, float]              # noise level per signal
    current_source: str = ''
    notes: list[str] = field(default_factory=list)
    t0: float = 0.0                      # s, plant time of the first sample (dither phase)
    # The run's initial state, when it did not start settled at its first inputs: the
    # measured plate position (or pump flow) at the start, whose equilibrium it was.
    start_signal: tuple[str, float] | None = None

    def initial_current(self, params: Params) -> float:
        """The current whose equilibrium the run starts from: the first input, or the one the
        measured initial plate position says (``phi_s i_s = K_a x_a`` at ``x_c = 0``, eq. 1;
        from a pump flow through eq. 8)."""
        if self.start_signal is None:
            return float(self.current[0])
        name, v = self.start_signal
        sp = params.spool
        x_a = v if name == 'actuator_position' else params.stroke_scale * (
            v / params.Q_max - 0.5)
        lo, hi = params.I_limits
        return float(min(max(params.I_nominal + sp.K_a * x_a / sp.phi_s, lo), hi))

    @property
    def n(self) -> int:
        return self.current.size

    @property
    def duration(self) -> float:
        return self.n * self.dt


def noise_level(y: np.ndarray, quantum: float = 0.0) -> float:
    """Noise standard deviation of a sampled signal from its second differences (robust: the
    median absolute deviation), which a smooth response leaves out: for white noise
    ``var(d2 y) = 6 sigma^2``."""
    d2 = np.diff(y[np.isfinite(y)], 2)
    if d2.size < 8:
        return 0.0
    mad = float(np.median(np.abs(d2 - np.median(d2)))) * 1.4826
    return mad / math.sqrt(6.0)


def experiment_from(rec, base: Params, signals: Sequence[str] | None = None) -> Experiment:
    """An :class:`Experiment` from a :class:`~.recording.Recording` (pressures made gauge with
    the params file's ``p_atm``). The command is the current where it was recorded; else
    the measured current, one sample earlier (the simulator stamps the current with the end of
    the step it was applied over), without its dither lines when the model has its own
    dither."""
    name = rec.name or rec.source or 'recording'
    notes = []
    dt = rec.dt
    if 'solenoid_current_cmd' in rec and np.isfinite(rec['solenoid_current_cmd']).all():
        cur, source = np.array(rec['solenoid_current_cmd'], float), 'solenoid_current_cmd'
    elif 'solenoid_current' in rec:
        cur = np.array(rec['solenoid_current'], float)
        cur = np.append(cur[1:], cur[-1])
        source = 'solenoid_current'
        if base.input.dither_amp > 0:
            lines = detect_dither(cur, dt)
            t = np.arange(cur.size) * dt
            for line in lines:
                cur = cur - line.at(t)
            if lines:
                notes.append(f'{name}: took {len(lines)} dither line(s) out of the measured '
                             'current (the model has its own dither)')
    else:
        raise CalibrationError(f'{name}: no current to drive the model: the recording has '
                               f'{", ".join(rec.signals)}; record solenoid_current or '
                               'solenoid_current_cmd')
    if not np.isfinite(cur).all():
        raise CalibrationError(f'{name}: the current {source} has gaps (NaN)')
    p_atm = base.fluid.p_atm
    load = None
    if 'load_pressure' in rec and np.isfinite(rec['load_pressure']).all():
        load = np.array(rec['load_pressure'], float) - p_atm
    want = OUTPUT_SIGNALS if signals is None else signals
    measured = {}
    for s in want:
        if s in rec and np.isfinite(rec[s]).sum() > 10:
            y = np.array(rec[s], float)
            measured[s] = y - p_atm if s in PRESSURES else y
    if not measured:
        raise CalibrationError(
            f'{name}: none of the signals the model is compared on ({", ".join(want)}) is in '
            f'the recording; it has: {", ".join(rec.signals)}')
    sigma = {}
    for s, y in measured.items():
        sig = noise_level(y)
        span = float(np.nanmax(y) - np.nanmin(y))
        # A noise-free signal (a simulator's exact joint states) still gets a finite weight:
        # 0.1 % of its span, about what the integrator's tolerance leaves of model error.
        sigma[s] = max(sig, NOISE_FLOOR * max(span, abs(float(np.nanmean(y))) * 1e-2, 1e-300))
    # A bag in simulation time starts at the simulator's time t0: the model's dither then has
    # the simulator's phase (a bench's dither phase is not known: see docs/identification.md).
    exp = Experiment(name, dt, cur, load, measured, sigma, source, notes,
                     t0=rec.t0_ns * 1e-9 if base.input.dither_amp > 0 else 0.0)
    # Did the run start settled? The plate position (exact state) or the pump flow of the first
    # samples (before the plate can have moved) gives the equilibrium it started from.
    for s, k in (('actuator_position', 3), ('pump_flow', 10)):
        if s in measured and np.isfinite(measured[s][:k]).all():
            exp.start_signal = (s, float(np.mean(measured[s][:k])))
            i0 = exp.initial_current(base)
            span = base.current_range[1] - base.current_range[0]
            if abs(i0 - cur[0]) > 0.02 * span:
                exp.notes.append(f'{name}: the run did not start settled: it starts from the '
                                 f'equilibrium at {i0:.4g} A (the {s} at the start), its first '
                                 f'input is {cur[0]:.4g} A')
            else:
                exp.start_signal = None
            break
    return exp


def excitation_check(exps: Sequence[Experiment]) -> list[str]:
    """A line per experiment whose inputs do not move (nothing to calibrate on)."""
    out = []
    for e in exps:
        span_i = float(np.ptp(e.current))
        span_p = float(np.ptp(e.load_pressure)) if e.load_pressure is not None else 0.0
        if span_i < 2e-3 and span_p < 1e5:
            out.append(f'{e.name}: no excitation: the current moves by {span_i * 1e3:.3g} mA '
                       f'and the load pressure by {span_p / 1e5:.3g} bar; record a staircase '
                       'or a load-pressure step')
    return out


# --------------------------------------------------------------------------------------------
# The model of the measurements
# --------------------------------------------------------------------------------------------

_OUT_INDEX = {s: OUTPUTS.index(o) for s, o in SIGNAL_OUTPUTS.items() if o is not None}


def held_signal(arr: np.ndarray, dt: float):
    """The samples ``arr`` as a function of time, each held from ``k dt`` to ``(k + 1) dt``
    (the form :func:`hydropump_sim.simulate` takes an input in)."""
    def signal(t):
        k = np.clip(np.floor(np.asarray(t) / dt + 1e-6).astype(int), 0, arr.size - 1)
        return arr[k]
    return signal


def simulate_experiment(params: Params, exp: Experiment, rtol: float | None = None
                        ) -> dict[str, np.ndarray]:
    """The fine model's true signals on the experiment's grid (SI, gauge)."""
    n = exp.n
    x0 = None
    if exp.start_signal is not None:
        x0 = equilibrium(params, exp.initial_current(params),
                         load_pressure=None if exp.load_pressure is None
                         else float(exp.load_pressure[0])).x
    res = simulate(params, (n - 1) * exp.dt, held_signal(exp.current, exp.dt),
                   load_pressure=None if exp.load_pressure is None
                   else held_signal(exp.load_pressure, exp.dt),
                   dt_out=exp.dt, dt_max=exp.dt, rtol=rtol, t0=exp.t0, x0=x0)
    return {s: res.y[:n, _OUT_INDEX[s]] for s in exp.measured}


def delayed(y: np.ndarray, d: float, dt: float) -> np.ndarray:
    """``y(t - d)`` by linear interpolation; before the start, the initial value (the run
    starts settled)."""
    k = np.arange(y.size) - d / dt
    return np.interp(k, np.arange(y.size), y)


# Work shared with forked workers (set before the pool starts).
_WORK: dict[str, Any] = {}


def _simulate_column(job):
    theta, e = job
    # One validated parameter set per vector, not per experiment (validation takes ms).
    cache = _WORK.setdefault('params', {})
    key = np.asarray(theta).tobytes()
    if key not in cache:
        if len(cache) > 16:
            cache.clear()
        cache[key] = params_with(_WORK['base'], _WORK['names'], theta)
    return simulate_experiment(cache[key], _WORK['exps'][e], _WORK['rtol'])


class Problem:
    """The weighted residuals of all experiments as a function of the plant coordinates ``z``,
    with the nuisance parameters (a delay and an optional offset per signal, shared by the
    recordings of one bench, or with ``per_bag`` per recording and signal) solved for
    inside by a bounded 1-D search each (variable projection); and the
    Jacobian of the plant part with the nuisance directions projected out (Kaufman's
    approximation), so the outer least squares sees only the plant parameters."""

    def __init__(self, base: Params, coords: Coordinates, exps: Sequence[Experiment], *,
                 offsets: Sequence[str] = (), fit_delays: bool = True, per_bag: bool = False,
                 rtol: float = 1e-5, workers: int = WORKERS,
                 progress: Callable[[str], None] | None = None):
        self.base, self.coords, self.exps = base, coords, list(exps)
        self.rtol = rtol
        self.blocks = [(i, s) for i, e in enumerate(self.exps) for s in e.measured]
        self.fit_delays = fit_delays
        self.per_bag = per_bag
        # The nuisance keys: (experiment or None, signal) -> the blocks they act on.
        self.keys: dict[tuple, list[tuple[int, str]]] = {}
        for b in self.blocks:
            self.keys.setdefault(self.key(*b), []).append(b)
        self.with_offset = {k for k in self.keys if k[1] in offsets}
        self.nuis = {k: (0.0, 0.0) for k in self.keys}   # (delay s, offset): warm starts
        self.n_plant = len(coords.names)
        self._cache: dict[bytes, list[dict[str, np.ndarray]]] = {}
        self._evals: dict[bytes, tuple] = {}
        self.n_sims = 0
        self.workers = workers
        self._pool = None
        self._progress = progress

    def theta(self, z: np.ndarray) -> np.ndarray:
        return self.coords.to_theta(z)

    def key(self, i: int, s: str) -> tuple:
        return (i if self.per_bag else None, s)

    # ---- simulation --------------------------------------------------------------------

    def _sims(self, thetas: list[np.ndarray]) -> list[list[dict[str, np.ndarray]]]:
        """Simulations of every experiment for each parameter vector (cached, parallel)."""
        keys = [np.asarray(th).tobytes() for th in thetas]
        todo = list({k: th for k, th in zip(keys, thetas) if k not in self._cache}.items())
        jobs = [(th, e) for _, th in todo for e in range(len(self.exps))]
        if jobs:
            self.n_sims += len(jobs)
            if self.workers > 1 and len(jobs) > 1:
                # A vector's experiments go to one worker together (its parameter cache).
                results = list(self._executor().map(_simulate_column, jobs,
                                                    chunksize=len(self.exps)))
            else:
                if (_WORK.get('exps') is not self.exps or _WORK.get('base') is not self.base
                        or _WORK.get('names') != self.coords.names):
                    _WORK.update(base=self.base, names=self.coords.names, exps=self.exps,
                                 rtol=self.rtol, params={})
                results = [_simulate_column(j) for j in jobs]
            m = len(self.exps)
            for i, (k, _) in enumerate(todo):
                self._cache[k] = results[i * m:(i + 1) * m]
        if len(self._cache) > 48:
            for k in list(self._cache)[:-24]:
                if k not in keys:
                    del self._cache[k]
        return [self._cache[k] for k in keys]

    def _executor(self):
        if self._pool is None:
            _WORK.update(base=self.base, names=self.coords.names, exps=self.exps,
                         rtol=self.rtol, params={})
            self._pool = ProcessPoolExecutor(self.workers,
                                             mp_context=multiprocessing.get_context('fork'))
        return self._pool

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    # ---- the nuisance parameters ---------------------------------------------------------

    def _inner(self, parts, start: float, offset: bool, search: bool
               ) -> tuple[float, float]:
        """The delay (and offset) that fit the simulated ``y`` to the measured ``m`` of
        every ``(y, m, dt, sigma)`` in ``parts`` best."""
        oks = [np.isfinite(m) for _, m, _, _ in parts]
        dt = parts[0][2]

        def fit(d):
            res = [(delayed(y, d, dt_)[ok] - m[ok]) / sg
                   for (y, m, dt_, sg), ok in zip(parts, oks)]
            o = 0.0
            if offset:
                w = sum(r.size / sg ** 2 for r, (_, _, _, sg) in zip(res, parts))
                o = -sum(float(r.sum()) / sg for r, (_, _, _, sg) in zip(res, parts)) / w
            return sum(float(np.sum((r + o / sg) ** 2)) for r, (_, _, _, sg)
                       in zip(res, parts)), o

        if not self.fit_delays:
            return 0.0, fit(0.0)[1]
        from scipy.optimize import minimize_scalar
        step = max(dt, 0.002)
        if search:
            grid = np.arange(0.0, DELAY_MAX + 1e-12, step)
            start = float(grid[int(np.argmin([fit(g)[0] for g in grid]))])
        # Refine within a grid step or so (a periodic signal, the dither, has a minimum every
        # period), moving the window while the minimum sits on its edge; never worse than the
        # start.
        d = start
        for _ in range(4):
            lo, hi = max(0.0, start - 1.5 * step), min(DELAY_MAX, start + 1.5 * step)
            cand = float(minimize_scalar(lambda v: fit(v)[0], bounds=(lo, hi), method='bounded',
                                         options={'xatol': 1e-6}).x)
            best = min((cand, start, lo, hi), key=lambda v: fit(v)[0])
            d = best
            on_edge = (best == lo and lo > 0.0) or (best == hi and hi < DELAY_MAX)
            if on_edge and best != start:
                start = best
                continue
            break
        return d, fit(d)[1]

    def evaluate(self, z: np.ndarray, search: bool = False):
        """``(sims, nuisance, residuals)`` at ``z`` (cached)."""
        key = np.asarray(z, float).tobytes()
        if key in self._evals and not search:
            return self._evals[key]
        sims = self._sims([self.theta(z)])[0]
        nuis = {}
        for k, blocks in self.keys.items():
            parts = [(sims[i][s], self.exps[i].measured[s], self.exps[i].dt,
                      self.exps[i].sigma[s]) for i, s in blocks]
            nuis[k] = self._inner(parts, self.nuis[k][0], k in self.with_offset, search)
        self.nuis = nuis
        r = np.concatenate(list(self._residual_blocks(self._apply(sims, nuis))))
        if len(self._evals) > 16:
            self._evals.clear()
        self._evals[key] = (sims, nuis, r)
        return sims, nuis, r

    def _apply(self, sims, nuis) -> list[dict[str, np.ndarray]]:
        out = []
        for i, (e, sim) in enumerate(zip(self.exps, sims)):
            out.append({s: delayed(sim[s], nuis[self.key(i, s)][0], e.dt)
                        + nuis[self.key(i, s)][1] for s in e.measured})
        return out

    def predictions(self, z: np.ndarray) -> list[dict[str, np.ndarray]]:
        """The model's measurements (delays and offsets applied) per experiment."""
        sims, nuis, _ = self.evaluate(z)
        return self._apply(sims, nuis)

    def _residual_blocks(self, pred):
        for e, p in zip(self.exps, pred):
            for s, y in e.measured.items():
                r = (p[s] - y) / e.sigma[s]
                yield np.where(np.isfinite(r), r, 0.0)

    def residuals(self, z: np.ndarray) -> np.ndarray:
        try:
            return self.evaluate(z)[2]
        except HydropumpError:
            # A trial point where the model cannot be integrated or trimmed: a large residual
            # sends the trust region back.
            return np.full(self.n_rows, 1e6)

    @property
    def n_rows(self) -> int:
        return sum(e.n * len(e.measured) for e in self.exps)

    def row_groups(self) -> list[slice]:
        """Row ranges of each (experiment, signal) block: independent noise records."""
        out, k = [], 0
        for e in self.exps:
            for _ in e.measured:
                out.append(slice(k, k + e.n))
                k += e.n
        return out

    def at_noise_level(self, r: np.ndarray, factor: float = 2.0) -> bool:
        """Do the residuals of most signals reach their noise level (an rms of the weighted
        residuals within ``factor``)? A fit stuck in a local minimum leaves whole signals
        far above it."""
        rms = [float(np.sqrt(np.mean(r[g] ** 2))) for g in self.row_groups()]
        return bool(np.median(rms) <= factor)

    # ---- sensitivities -------------------------------------------------------------------

    def sensitivities(self, z: np.ndarray, nuis=None) -> tuple[np.ndarray, np.ndarray]:
        """``(J_plant, J_nuisance)``: forward differences of whole simulations for the plant
        coordinates (the nuisance parameters held), and the exact columns of the free
        nuisance parameters (a delay: ``-y'(t - d)``; an offset: one). A delay on a bound is
        not free."""
        n = self.n_plant
        theta = self.coords.to_theta(z)
        lo, hi = self.coords.bounds()
        steps = np.empty(n)
        thetas = [theta]
        for j in range(n):
            h = 1e-3 if self.coords.log[j] else 1e-3 * max(abs(z[j]), 1.0)
            if z[j] + h > hi[j]:
                h = -h
            zj = z.copy()
            zj[j] += h
            steps[j] = h
            thetas.append(self.coords.to_theta(zj))
        sims = self._sims(thetas)
        if nuis is None:
            nuis = self.evaluate(z)[1]
        r0 = np.concatenate(list(self._residual_blocks(self._apply(sims[0], nuis))))
        Jp = np.zeros((r0.size, n))
        for j in range(n):
            rj = np.concatenate(list(self._residual_blocks(self._apply(sims[j + 1], nuis))))
            Jp[:, j] = (rj - r0) / steps[j]
        rows = dict(zip(self.blocks, self.row_groups()))
        cols = []
        for key, blocks in self.keys.items():
            d, _ = nuis[key]
            cd, co = np.zeros(r0.size), np.zeros(r0.size)
            for i, s in blocks:
                e = self.exps[i]
                ok = np.isfinite(e.measured[s])
                g = rows[(i, s)]
                cd[g] = -np.gradient(delayed(sims[0][i][s], d, e.dt), e.dt) / e.sigma[s] * ok
                co[g] = ok / e.sigma[s]
            if self.fit_delays and 0.0 < d < DELAY_MAX:
                cols.append(cd)
            if key in self.with_offset:
                cols.append(co)
        Jn = np.column_stack(cols) if cols else np.zeros((r0.size, 0))
        if self._progress:
            self._progress(f'{self.n_sims} simulations')
        return Jp, Jn

    def jacobian(self, z: np.ndarray) -> np.ndarray:
        """The plant Jacobian with the nuisance directions projected out."""
        Jp, Jn = self.sensitivities(z)
        if Jn.shape[1]:
            Q, _ = np.linalg.qr(Jn)
            Jp -= Q @ (Q.T @ Jp)
        return Jp


# --------------------------------------------------------------------------------------------
# The result
# --------------------------------------------------------------------------------------------

@dataclass
class ParameterEstimate:
    name: str
    value: float
    initial: float
    stderr: float | None          # None: not determined by the data
    determined: bool
    on_bound: str | None = None   # 'lower' / 'upper'


@dataclass
class Calibration:
    """What :func:`calibrate` found (see :meth:`to_dict` for the JSON form)."""

    params: Params
    start: Params
    estimates: list[ParameterEstimate]
    correlation: np.ndarray
    singular_values: np.ndarray
    undetermined: list[dict]
    fit: dict[str, dict[str, float]]          # experiment -> signal -> fit %
    fit_before: dict[str, dict[str, float]]
    delays: dict[str, dict[str, float]]       # experiment ('all': shared) -> signal -> s
    offsets: dict[str, dict[str, float]]
    sigma: dict[str, dict[str, float]]
    flags: list[str]
    notes: list[str]
    sources: list[str]
    free: tuple[str, ...]
    tied: dict[str, float]
    method: str
    n_simulations: int
    wall_time: float
    cost: float
    predictions: list[dict[str, np.ndarray]] = field(default_factory=list, repr=False)
    predictions_before: list[dict[str, np.ndarray]] = field(default_factory=list, repr=False)
    experiments: list[Experiment] = field(default_factory=list, repr=False)
    # Fisher information of the data in the plant coordinates (the nuisance projected out).
    information: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        def num(v):
            return None if v is None or not math.isfinite(v) else float(v)
        return {
            'free': list(self.free),
            'parameters': {p.name: {'value': p.value, 'stderr': num(p.stderr),
                                    'initial': p.initial, 'determined': p.determined,
                                    'on_bound': p.on_bound} for p in self.estimates},
            'tied': self.tied,
            'correlation': [[num(v) for v in row] for row in self.correlation],
            'singular_values': [float(v) for v in self.singular_values],
            'undetermined': self.undetermined,
            'fit_percent': self.fit, 'fit_percent_before': self.fit_before,
            'delays_s': self.delays, 'offsets': self.offsets, 'noise_sigma': self.sigma,
            'flags': self.flags, 'notes': self.notes, 'bags': self.sources,
            'method': self.method, 'n_simulations': self.n_simulations,
            'wall_time_s': self.wall_time, 'cost': self.cost,
        }


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """Normalised-RMSE fit ``100 (1 - |y - yhat| / |y - mean y|)`` [%] (MATLAB's ``compare``)."""
    ok = np.isfinite(y) & np.isfinite(yhat)
    y, yhat = y[ok], yhat[ok]
    den = np.linalg.norm(y - y.mean())
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den)) if den > 0 else float('nan')


def _fits(exps, preds) -> dict[str, dict[str, float]]:
    return {e.name: {s: round(fit_percent(e.measured[s], p[s]), 3) for s in e.measured}
            for e, p in zip(exps, preds)}


def _solve(prob: Problem, z0: np.ndarray, max_nfev: int):
    from scipy.optimize import least_squares
    lo, hi = prob.coords.bounds()
    z0 = np.clip(z0, lo, hi)
    return least_squares(prob.residuals, z0, jac=prob.jacobian, bounds=(lo, hi),
                         method='trf', x_scale='jac', max_nfev=max_nfev, xtol=1e-6,
                         ftol=1e-8, gtol=1e-8)


def _nuisance_tables(prob: Problem, nuis) -> tuple[dict, dict]:
    delays, offsets = {}, {}
    for (i, s), (d, o) in nuis.items():
        name = 'all' if i is None else prob.exps[i].name
        if prob.fit_delays:
            delays.setdefault(name, {})[s] = round(float(d), 6)
        if (i, s) in prob.with_offset:
            offsets.setdefault(name, {})[s] = float(o)
    return delays, offsets


def calibrate(recordings: Sequence, base: Params, free: Sequence[str], *,
              offsets: Sequence[str] = (), fit_delays: bool = True, per_bag: bool = False,
              signals=None, rtol: float = 1e-5, max_nfev: int = 30, multistart: bool = True,
              workers: int = WORKERS,
              progress: Callable[[str], None] | None = None) -> Calibration:
    """Fit the free plant parameters to ``recordings`` (see the module).

    Raises
    ------
    CalibrationError
        Bad free parameters, recordings without the needed signals, no excitation, a
        parameter the recordings cannot inform, or no convergence.
    """
    from .identifiability import analyse, reduce_nuisance
    t_wall = time.perf_counter()
    free = tuple(free)
    exps = [experiment_from(r, base, signals) for r in recordings]
    recorded = ['load_pressure'] if any(e.load_pressure is not None for e in exps) else []
    errors = check_free(base, free, recorded)
    errors += excitation_check(exps)
    bad_off = [s for s in offsets if s not in OUTPUT_SIGNALS]
    if bad_off:
        errors.append(f'--offset {", ".join(bad_off)}: not a compared signal (choose from '
                      f'{", ".join(OUTPUT_SIGNALS)})')
    if errors:
        raise CalibrationError(errors)
    names = {e.name for e in exps}
    if len(names) < len(exps):
        for k, e in enumerate(exps):
            e.name = f'{k + 1}:{e.name}'
    coords = Coordinates.of(base, free)
    theta0 = np.array([float(base.flat()[n]) for n in free])
    z0 = coords.to_z(theta0)
    prob = Problem(base, coords, exps, offsets=offsets, fit_delays=fit_delays,
                   per_bag=per_bag, rtol=rtol, workers=workers, progress=progress)
    try:
        try:
            prob.evaluate(z0, search=True)
            before = prob.predictions(z0)
        except HydropumpError as exc:
            raise CalibrationError(f'the start parameters do not simulate: {exc}') from None
        # A parameter no signal of any recording depends on cannot be informed.
        Jp0, _ = prob.sensitivities(z0)
        dead = [n for j, n in enumerate(free) if not np.any(Jp0[:, j])]
        if dead:
            raise CalibrationError(
                [f'{n} cannot be informed by these recordings: no measured signal depends on '
                 'it in these runs (for instance a relief valve never reached, or a friction '
                 'set to zero)' for n in dead])
        start_nuis = dict(prob.nuis)
        sol = _solve(prob, z0, max_nfev)
        tried = ['the start']
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
        z = sol.x
        Jp, Jn = prob.sensitivities(z)
        r = prob.residuals(z)
        groups = prob.row_groups()
        ident = analyse(np.hstack([Jp, Jn]), r, free, len(free), groups)
        method = ('trust-region least squares (scipy), forward-difference sensitivities, '
                  'delays and offsets by variable projection')
        Jr = reduce_nuisance(np.hstack([Jp, Jn]), len(free))
        information = Jr.T @ Jr
        if ident.undetermined:
            # Fit again in the determined subspace; the undetermined part stays at the start.
            z = _refit_subspace(prob, z, z0, ident.basis, max_nfev)
            Jp, Jn = prob.sensitivities(z)
            r = prob.residuals(z)
            ident = analyse(np.hstack([Jp, Jn]), r, free, len(free), groups,
                            basis=ident.basis, undetermined=ident.undetermined)
            method += '; refitted in the determined subspace'
        if len(tried) > 1:
            method += f'; multi-start from {", ".join(tried)}'
        theta = prob.theta(z)
        params = params_with(base, free, theta)
        after = prob.predictions(z)
        nuis = prob.evaluate(z)[1]
        flags = list(ident.flags)
        zlo, zhi = coords.bounds()
        estimates = []
        dth = coords.dtheta_dz(theta)
        for j, n in enumerate(free):
            tol = 1e-6 * max(1.0, abs(zhi[j] - zlo[j]))
            bound = 'lower' if z[j] <= zlo[j] + tol else 'upper' if z[j] >= zhi[j] - tol \
                else None
            if bound:
                flags.append(f'{n} is on its {bound} bound ({theta[j]:.6g}): the optimum may '
                             'lie outside the schema range, or the data pull it there')
            se_z = ident.stderr[j]
            se = None if se_z is None else float(se_z * dth[j])
            estimates.append(ParameterEstimate(n, float(theta[j]), float(theta0[j]), se,
                                               n not in ident.undetermined_names, bound))
        for (i, s), (d, _) in nuis.items():
            if fit_delays and d >= DELAY_MAX - 1e-6:
                flags.append(f'{"" if i is None else exps[i].name + ": "}the delay of {s} is '
                             f'on its bound {DELAY_MAX:g} s')
        delays, offs = _nuisance_tables(prob, nuis)
        n_total = prob.n_rows
        return Calibration(
            params=params, start=base, estimates=estimates, correlation=ident.correlation,
            singular_values=ident.singular_values, undetermined=ident.undetermined,
            fit=_fits(exps, after), fit_before=_fits(exps, before), delays=delays,
            offsets=offs, sigma={e.name: dict(e.sigma) for e in exps}, flags=flags,
            notes=[n for e in exps for n in e.notes],
            sources=[str(getattr(r, 'source', '') or getattr(r, 'name', ''))
                     for r in recordings],
            free=free, tied=tied_values(params.flat(), free), method=method,
            n_simulations=prob.n_sims, wall_time=time.perf_counter() - t_wall,
            cost=float(2.0 * sol.cost / max(n_total, 1)), predictions=after,
            predictions_before=before, experiments=exps, information=information)
    finally:
        prob.close()


def _refit_subspace(prob: Problem, z: np.ndarray, z0: np.ndarray, basis: np.ndarray,
                    max_nfev: int) -> np.ndarray:
    """Least squares over the determined plant directions ``basis`` (columns, in ``z``): the
    plant part is ``z0 + basis w``, so the undetermined part stays at the start."""
    from scipy.optimize import least_squares
    lo, hi = prob.coords.bounds()

    def full(w):
        return np.clip(z0 + basis @ w, lo, hi)

    sol = least_squares(lambda w: prob.residuals(full(w)), basis.T @ (z - z0),
                        jac=lambda w: prob.jacobian(full(w)) @ basis, method='trf',
                        x_scale='jac', max_nfev=max_nfev, xtol=1e-6, ftol=1e-8)
    return full(sol.x)


def validate(recordings: Sequence, params: Params, *, signals=None, fit_delays: bool = True
             ) -> tuple[dict[str, dict[str, float]], dict, list[Experiment], list]:
    """Fit % per recording and signal of ``params`` on recordings it was not fitted to (the
    measurement delays are re-estimated per signal, nothing else).

    Returns ``(fit, delays, experiments, predictions)``.
    """
    exps = [experiment_from(r, params, signals) for r in recordings]
    coords = Coordinates((), np.zeros(0, bool), np.zeros(0), np.zeros(0), np.zeros(0))
    prob = Problem(params, coords, exps, fit_delays=fit_delays, workers=1)
    z = np.zeros(0)
    try:
        prob.evaluate(z, search=True)
    except HydropumpError as exc:
        raise CalibrationError(f'the params file does not simulate these recordings: {exc}') \
            from None
    pred = prob.predictions(z)
    delays, _ = _nuisance_tables(prob, prob.evaluate(z)[1])
    return _fits(exps, pred), delays, exps, pred


def write_params(cal: Calibration, path, header_lines: Sequence[str] = ()) -> None:
    """The calibrated parameters as a params file in the form of ``config/pump.yaml``, with a
    header that says where they came from."""
    from hydropump_sim.schema import dump_ros_yaml
    lines = ['Calibrated by hydropump calibrate from:']
    lines += [f'  {s}' for s in cal.sources]
    for p in cal.estimates:
        se = ("not determined by these recordings (kept at the start's combination)"
              if not p.determined else f'+- {p.stderr:.3g}' if p.stderr is not None else '')
        lines.append(f'free {p.name} = {p.value:.6g} (start {p.initial:.6g}) {se}'.rstrip())
    for n, v in cal.tied.items():
        lines.append(f'tied {n} = {v:.6g} ({DERIVED[n][1]})')
    for name, per in cal.fit.items():
        lines.append(f'fit % {name}: ' + ', '.join(f'{s} {v:.2f}' for s, v in per.items()))
    lines += list(header_lines)
    comments = {p.name: f'calibrated (start {p.initial:.6g})' for p in cal.estimates}
    comments.update({n: f'tied: {DERIVED[n][1]}' for n in cal.tied})
    text = dump_ros_yaml(cal.params.flat(), header='\n'.join('# ' + ln for ln in lines),
                         comments=comments, specs=spec_map(Params))
    try:
        Path(path).write_text(text, encoding='utf-8')
    except OSError as exc:
        raise CalibrationError(f'{path}: cannot write the params file ({exc.strerror})') \
            from None


__all__ = ['Calibration', 'CalibrationError', 'DELAY_MAX', 'DERIVED', 'Experiment',
           'OUTPUT_SIGNALS', 'ParameterEstimate', 'calibrate', 'check_free', 'experiment_from',
           'fit_percent', 'held_signal', 'noise_level', 'params_with', 'simulate_experiment',
           'tied_values', 'validate', 'write_params']
