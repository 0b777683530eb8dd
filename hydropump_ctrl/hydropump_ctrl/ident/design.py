"""Experiment design from the calibration's uncertainty analysis: which standard experiment
informs which parameter, and which would determine a direction a calibration left weak.

The standard experiments (:func:`candidate_inputs`) are simulated at the estimate; their
Fisher information (the noise-weighted sensitivities, the measurement delays free) is added
to that of the recordings, and a weak direction counts as separated when its relative
standard error with the candidate falls below :data:`.calibrate.DETERMINED_REL_STD`: a
candidate the recordings already hold adds only its own noise average (a second staircase
lowers the error by about 1/sqrt 2) and is named only if that is enough. The table of
``docs/experiment_design.md`` is :func:`experiment_table`. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np

from hydropump_sim.errors import HydropumpError

from .calibrate import Calibration, DETERMINED_REL_STD, Experiment
from .calibrate.engine import Engine
from .calibrate.problem import Coordinates, Problem
from .calibrate.uncertainty import reduce_nuisance

# A planned experiment's delays are taken as free, at a typical value [s].
DELAY_PLAN = 0.05


# --------------------------------------------------------------------------------------------

def _staircase(levels, dwell, dt):
    return np.concatenate([np.full(int(round(dwell / dt)), v) for v in levels])


def candidate_inputs(params, dt: float = 1e-3, dwell: float = 1.0) -> dict[str, dict]:
    """The standard experiments: current staircases up and down in the regulating range at
    the params file's load pressure, the same at a load pressure 40 bar lower, and a
    load-pressure step at a held current (inputs: absolute current A, gauge load Pa)."""
    lo, hi = params.current_range
    mid = 0.5 * (lo + hi)
    span = hi - lo
    up = [mid - 0.2 * span, mid - 0.1 * span, mid, mid + 0.1 * span, mid + 0.2 * span]
    P_u = params.line.P_u
    n = len(up) * int(round(dwell / dt))
    low = max(P_u - 4.0e6, 0.3 * P_u)
    step_p = np.concatenate([np.full(int(round(1.0 / dt)), P_u),
                             np.full(int(round(1.0 / dt)), low),
                             np.full(int(round(1.0 / dt)), P_u)])
    return {
        'staircase up': {'current': _staircase(up, dwell, dt), 'load_pressure': None},
        'staircase down': {'current': _staircase(up[::-1], dwell, dt), 'load_pressure': None},
        'staircases at a lower load pressure': {
            'current': _staircase(up + up[::-1][1:], dwell, dt),
            'load_pressure': np.full(n + (len(up) - 1) * int(round(dwell / dt)), low)},
        'load-pressure steps': {'current': np.full(step_p.size, mid), 'load_pressure': step_p},
    }


CANDIDATES = ('staircase up', 'staircase down', 'staircases at a lower load pressure',
              'load-pressure steps')


def experiment_information(params, free: Sequence[str], inputs: dict, sigma: dict,
                           dt: float = 1e-3) -> np.ndarray:
    """Fisher information (``J'J`` of the noise-weighted residuals, in log coordinates, the
    measurement delays projected out) of one candidate experiment at ``params``."""
    cur = inputs['current']
    load = inputs['load_pressure']
    meas = {s: np.zeros(cur.size) for s in sigma}
    exp = Experiment('candidate', dt, cur, load, meas, dict(sigma))
    prob = Problem(Engine(params, free, [exp], workers=1), Coordinates.of(params, free))
    flat = params.flat()
    z = prob.coords.to_z(np.array([flat[n] for n in free]))
    # The delays are unknown in a planned experiment: each signal's is free (projected out).
    nuis = {k: (DELAY_PLAN, 0.0) for k in prob.keys}
    Jp, Jn = prob.sensitivities(z, nuis)
    Jr = reduce_nuisance(np.hstack([Jp, Jn]), len(free))
    return Jr.T @ Jr


def separating_experiments(params, free: Sequence[str], information: np.ndarray,
                           direction: np.ndarray, sigma: dict) -> list[tuple[str, float]]:
    """Which candidate experiments, added to recordings of Fisher ``information``, determine
    ``direction`` (relative standard error below :data:`DETERMINED_REL_STD`), with the
    standard error it would have."""
    good = []
    w = np.asarray(direction, float)
    for name, inputs in candidate_inputs(params).items():
        try:
            info = information + experiment_information(params, free, inputs, sigma)
        except HydropumpError:   # a candidate the model cannot run is no candidate
            continue
        var = float(w @ np.linalg.pinv(info) @ w)
        if var > 0 and math.sqrt(var) < DETERMINED_REL_STD:
            good.append((name, math.sqrt(var)))
    return good


def experiment_table(params, free: Sequence[str], sigma: dict) -> dict[str, dict[str, float]]:
    """Relative standard error of each free parameter (all of ``free`` fitted together, the
    delays free) from each standard experiment alone, at ``params`` with noise ``sigma`` per
    measured signal; ``inf`` where the experiment does not inform it at all."""
    out = {}
    for name, inputs in candidate_inputs(params).items():
        info = experiment_information(params, free, inputs, sigma)
        ridge = 1e-12 * max(float(np.trace(info)), 1e-300)
        cov = np.linalg.inv(info + ridge * np.eye(len(free)))
        rel = np.sqrt(np.maximum(np.diag(cov), 0.0))
        out[name] = {n: (float(v) if v < 1e3 else math.inf) for n, v in zip(free, rel)}
    return out


def suggest(cal: Calibration) -> None:
    """Name, for every weak or held direction of ``cal``, the standard experiments that would
    determine it (``separated_by`` of each entry of ``cal.weak`` and ``cal.held``, and a
    flag); the Fisher information of the recordings is the one at the estimate."""
    dirs = cal.weak + cal.held
    if not dirs:
        return
    exps = cal.experiments
    sigma = {s: float(np.median([e.sigma[s] for e in exps if s in e.sigma]))
             for s in {s for e in exps for s in e.measured}}
    for u in dirs:
        sep = separating_experiments(cal.params, cal.free, cal.information,
                                     np.array(u['direction']), sigma)
        u['separated_by'] = [name for name, _ in sep]
        u['separated_stderr'] = {name: se for name, se in sep}
        cal.flags.append(f'to determine {", ".join(u["parameters"])}, add: '
                         + (', '.join(f'{n} ({100 * se:.2g} %)' for n, se in sep) if sep
                            else 'none of the standard experiments suffices with these '
                            'signals (a measurement of another signal, or a prior, is '
                            'needed)'))
