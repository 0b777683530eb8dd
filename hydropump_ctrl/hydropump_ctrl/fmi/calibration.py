"""Calibrating a user's FMU from bags (``hydropump calibrate --fmu MODEL.fmu``): the same
machinery as the suite's own model (:mod:`hydropump_ctrl.ident.calibrate`: the residuals
with their delays and offsets solved inside, the trust-region fit, standard errors,
intervals, weak and held directions, the misfit table), the model's simulator being the
FMU.

- The FMU meets the recordings as it meets the simulator node (:mod:`.plant`): its input
  ``current`` (or ``pump.current``) takes the recorded current, ``load_pressure`` (or
  ``load.load_pressure``) the recorded load pressure where it has one; its outputs named
  after the suite's measured signals are compared with the recorded ones (SI, gauge).
- Each experiment is one run of the FMU from its initialisation settled where the run's
  first samples show it (the current whose initial outputs fit them best: a recorder's run
  need not start settled at its first command), then the recorded inputs held over each
  model step and set before it, the outputs read after it (as FMPy alone and the node step
  it). The FMU is taken to initialise settled at its inputs.
- The free parameters are the FMU's Real parameters, set before each initialisation (FMI
  2.0); they are searched in log coordinates between the FMU's ``min`` and ``max`` where
  its range is positive (1000 times either side of the start where it declares none).
- Sensitivities are forward differences of whole runs with a relative step of 0.1 %: an
  FMU's integrator is its own, and a step-size controller inside it would drown a smaller
  one in its noise.

One FMU instance runs every simulation, in this thread (an FMU's instances may share one
interpreter, as PythonFMU's do: threads would buy nothing). Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
import time

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import Params
from hydropump_sim.schema import dump_ros_yaml, unknown_key_line

from ..ident.calibrate import (
    Calibration,
    CalibrationError,
    Coordinates,
    Experiment,
    fit_problem,
    prepare,
    Prior,
    Problem,
    result_of,
    write_text,
)
from ..ident.calibrate.calibration import MISFIT_RATIO
from ..ident.calibrate.writers import calibration_header
from ..ident.fit import blas_single_threaded
from .plant import FMU_PARAMETERS, FmuSimulator, ros_name

#: A run whose start current is this far from its first current (a fraction of the
#: current's range) did not start settled at it: the result says so.
UNSETTLED = 0.02
#: Where an FMU declares no range for a free parameter: this many times either side of its
#: start.
DEFAULT_SPAN = 1.0e3


class FmuEngine:
    """The FMU's outputs for the experiments of a calibration, as the suite's
    :class:`~hydropump_ctrl.ident.calibrate.engine.Engine` gives its model's (see the
    module)."""

    sensitivity_step = 1e-3
    sensitivities = 'forward differences of whole runs of the FMU (0.1 % steps)'

    def __init__(self, sim: FmuSimulator, names: Sequence[str], exps: Sequence[Experiment],
                 current_range: tuple[float, float]):
        self.sim, self.names, self.exps = sim, tuple(names), list(exps)
        self.n_trajectories = 0
        inputs = sim.model.plant_inputs()
        self._current = inputs['current']
        #: The FMU's load-pressure input, or None (the recorded one then drives nothing).
        self.load_input = inputs.get('load_pressure')
        lo, hi = sim.model.input_ranges[sim.model.inputs.index(self._current)]
        self.range = (max(lo, current_range[0]), min(hi, current_range[1]))
        self._cache: dict[bytes, list[dict[str, np.ndarray]]] = {}

    def _start(self, theta, exp: Experiment, current: float) -> np.ndarray:
        """The FMU initialised with ``theta`` at ``current`` and the first load pressure:
        the compared signals then."""
        sim = self.sim
        sim.dt = exp.dt_model
        sim.set_parameters(dict(zip(self.names, np.asarray(theta, float))))
        first = {self._current: float(current)}
        if self.load_input is not None and exp.load_pressure is not None:
            first[self.load_input] = float(exp.load_pressure[0])
        sim.reset(first)
        return sim.outputs()[[sim.model.signals.index(s) for s in exp.measured]]

    def _first(self, exp: Experiment) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The first finite sample of each compared signal that has one, its noise level,
        and which signals they are (a signal whose first message came late is NaN at the
        start of the grid)."""
        y, se, ok = [], [], []
        for s, v in exp.measured.items():
            finite = np.flatnonzero(np.isfinite(v))
            ok.append(finite.size > 0)
            if finite.size:
                y.append(float(v[finite[0]]))
                se.append(exp.sigma[s])
        return np.array(y), np.array(se), np.array(ok, dtype=bool)

    def start_current(self, theta, exp: Experiment) -> float:
        """The current whose settled start fits the first sample of ``exp`` best."""
        from scipy.optimize import minimize_scalar
        y, se, ok = self._first(exp)
        lo, hi = self.range
        res = minimize_scalar(lambda i: float(np.sum(((self._start(theta, exp, i)[ok] - y)
                                                      / se) ** 2)),
                              bounds=(lo, hi), method='bounded',
                              options={'xatol': 1e-9 * (hi - lo)})
        return float(res.x)

    def run(self, theta, exp: Experiment) -> dict[str, np.ndarray]:
        """The compared signals of one experiment at ``theta``, on its model grid."""
        sim, m = self.sim, exp.fine
        n = (exp.n - 1) * m + 1
        cur = np.repeat(exp.current, m)
        load = None if exp.load_pressure is None or self.load_input is None else \
            np.repeat(exp.load_pressure, m)
        i0 = self.start_current(theta, exp)
        cols = [sim.model.signals.index(s) for s in exp.measured]
        y = np.empty((n, len(cols)))
        y[0] = self._start(theta, exp, i0)
        for k in range(n - 1):
            sim.set_input(self._current, float(cur[k]))
            if load is not None:
                sim.set_input(self.load_input, float(load[k]))
            sim.step()
            y[k + 1] = sim.outputs()[cols]
        self.n_trajectories += 1
        return {s: y[:, j] for j, s in enumerate(exp.measured)}

    def outputs(self, theta: np.ndarray) -> list[dict[str, np.ndarray]]:
        """The compared signals of every experiment at ``theta`` (cached)."""
        key = np.asarray(theta, float).tobytes()
        if key not in self._cache:
            if len(self._cache) > 16:
                self._cache.clear()
            self._cache[key] = [self.run(theta, e) for e in self.exps]
        return self._cache[key]

    def sensitivity_runs(self, theta: np.ndarray, thetas: Sequence[np.ndarray]
                         ) -> tuple[list[dict], list[list[dict]]]:
        """The runs at ``theta`` and at each vector of ``thetas``."""
        return self.outputs(theta), [[self.run(t, e) for e in self.exps] for t in thetas]

    def close(self) -> None:
        self._cache.clear()


def coordinates(sim: FmuSimulator, free: Sequence[str], start: Sequence[float]
                ) -> Coordinates:
    """The search coordinates of the free parameters from the FMU's declared ranges (see
    the module)."""
    v = sim.model.info.variables
    lo, hi = [], []
    for name, x in zip(free, start):
        span = DEFAULT_SPAN * abs(x) if x else DEFAULT_SPAN
        lo.append(v[name].min if v[name].min is not None else
                  (x / DEFAULT_SPAN if x > 0 else x - span))
        hi.append(v[name].max if v[name].max is not None else
                  (x * DEFAULT_SPAN if x > 0 else x + span))
    lo, hi = np.array(lo, float), np.array(hi, float)
    theta = np.asarray(start, float)
    log = lo > 0
    scale = np.where(log, 1.0, np.where(theta != 0, np.abs(theta), 1e-3 * (hi - lo)))
    return Coordinates(tuple(free), log, scale, lo, hi)


def free_checker(sim: FmuSimulator):
    """A ``check_free`` for :func:`~hydropump_ctrl.ident.calibrate.prepare`: one line per
    free name that is not a Real parameter of the FMU with a start, or given twice."""
    known = sim.model.parameters()
    path = sim.model.info.path

    def check(base, free, recorded=()) -> list[str]:
        if not free:
            return [f'no free parameter: name at least one with --free (the parameters of '
                    f'{path.name}: {", ".join(known) or "none"})']
        errors, seen = [], set()
        for name in free:
            if name in seen:
                errors.append(f'{name} is given twice')
            elif name not in known:
                errors.append(unknown_key_line(name, known, f'real parameter of {path}')
                              + f' (its parameters: {", ".join(known) or "none"})')
            elif not ros_name(name):
                errors.append(f'{name}: not a name a ROS parameter takes (letters, digits, _ '
                              'and dots): the calibrated file could not set it')
            seen.add(name)
        return errors
    return check


def check_fmu_free(path, base: Params, free: Sequence[str]) -> list[str]:
    """One line per free name that is not a real parameter of the FMU at ``path`` (read and
    loaded once: :class:`FmuError` if it cannot be the plant), as :func:`calibrate_fmu`
    checks them: what a fleet checks before its tasks start."""
    sim = FmuSimulator(path, base)
    try:
        return free_checker(sim)(base, tuple(free))
    finally:
        sim.close()


def _check_outputs(sim: FmuSimulator, exps: Sequence[Experiment]) -> None:
    """:class:`CalibrationError` for a compared signal the FMU does not output."""
    outs = set(sim.model.outputs)
    missing = sorted({s for e in exps for s in e.measured} - outs)
    if missing:
        raise CalibrationError(f'{sim.model.info.path}: no output {", ".join(missing)}, which '
                               'the recordings have and are compared on; name the signals it '
                               f'has with --signals ({", ".join(sorted(outs)) or "none"})')


@blas_single_threaded
def calibrate_fmu(path, recordings: Sequence, base: Params, free: Sequence[str], *,
                  offsets: Sequence[str] = (), fit_delays: bool = True,
                  per_bag: bool = False, signals: Sequence[str] | None = None,
                  priors: Sequence[Prior] = (), max_nfev: int = 30, multistart: bool = True,
                  progress: Callable[[str], None] | None = None) -> Calibration:
    """Fit the free parameters of the FMU at ``path`` to ``recordings`` (see the module).

    ``base`` gives what the recordings are read with (the atmospheric pressure that makes
    their pressures gauge, the current's range). The result's ``params`` and ``start`` are
    the FMU's Real parameters by name, calibrated and as given; its ``tied`` is empty.

    Raises
    ------
    FmuError
        An FMU that cannot be the plant (:func:`.plant.check_plant`) or does not load.
    CalibrationError
        As :func:`~hydropump_ctrl.ident.calibrate.calibrate`, and a compared signal the FMU
        does not output.
    """
    t_wall = time.perf_counter()
    free, priors = tuple(free), list(priors)
    sim = FmuSimulator(path, base)
    try:
        exps = prepare(recordings, base, free, signals, offsets, priors,
                       check_free=free_checker(sim), settled=False)
        _check_outputs(sim, exps)
        start = dict(sim.model.parameters())
        theta0 = np.array([start[n] for n in free], float)
        engine = FmuEngine(sim, free, exps, base.current_range)
        prob = Problem(engine, coordinates(sim, free, theta0), offsets=offsets,
                       fit_delays=fit_delays, per_bag=per_bag, priors=priors,
                       progress=progress)
        try:
            found = fit_problem(prob, theta0, max_nfev, multistart)
        except HydropumpError as exc:
            if isinstance(exc, CalibrationError):
                raise
            raise CalibrationError(f'{sim.model.info.path}: {exc}') from None
        values = dict(start)
        values.update(zip(free, (float(v) for v in prob.theta(found.z))))
        cal = result_of(prob, found, values, start, {}, recordings, t_wall)
        lo, hi = engine.range
        for e in exps:
            i0 = engine.start_current(prob.theta(found.z), e)
            if abs(i0 - e.current[0]) > UNSETTLED * (hi - lo):
                cal.notes.append(f'{e.name}: the run did not start settled at its first '
                                 f'current ({e.current[0]:.4g} A): its first samples show the '
                                 f'FMU settled at {i0:.4g} A, where its run starts')
        loads = [e.name for e in exps if e.load_pressure is not None]
        if loads and engine.load_input is None:
            cal.notes.append(f'{path}: no load_pressure input; the recorded load pressure of '
                             f'{", ".join(loads)} is not its input')
        if any(m['ratio'] > MISFIT_RATIO for per in cal.misfit.values() for m in per.values()):
            cal.notes.append("what the model lacks is ranked for the suite's own model only "
                             "(an FMU's fixed parameters are not judged)")
        return cal
    finally:
        sim.close()



def write_fmu_params(cal: Calibration, fmu_path, path, header_lines: Sequence[str] = ()
                     ) -> Path:
    """The calibrated FMU as a params file of the simulator node (``--params-file``): its
    ``fmu_file`` and the calibrated ``fmu_parameters``, the others left at the FMU's own."""
    flat = {'fmu_file': str(Path(fmu_path).resolve())}
    flat.update({f'{FMU_PARAMETERS}{p.name}': p.value for p in cal.estimates})
    comments = {f'{FMU_PARAMETERS}{p.name}': f'calibrated (start {p.initial:.6g})'
                for p in cal.estimates}
    text = dump_ros_yaml(flat, header=calibration_header(cal, header_lines),
                         comments=comments)
    return write_text(path, text, 'params file')
