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

from collections.abc import Callable, Sequence
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

def candidate_inputs(params, dt: float = 1e-3, dwell: float = 1.0) -> dict[str, dict]:
    """The standard experiments, the calibration campaign of ``hydropump record standard``
    (:func:`hydropump_ctrl.plans.standard_plan`, the held-out one aside): current
    staircases up and down in the regulating range at the params file's load pressure, the
    same at a load pressure 40 bar lower, and load-pressure steps at a held current (inputs
    held per sample ``dt``: absolute current A, gauge load pressure Pa)."""
    from ..plans import held_inputs, standard_plan
    out = {}
    for e in standard_plan(params, dwell=dwell).experiments:
        if not e.held_out:
            h = held_inputs(e, params, dt)
            out[e.label] = {'current': h.current, 'load_pressure': h.load_pressure}
    return out


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


# A candidate adds what the recordings lack when it informs the direction at least this many
# times more per second than they do; one of the same kind only averages more noise.
RATE_RATIO = 2.0


def candidate_information(params, free: Sequence[str], sigma: dict, dt: float = 1e-3,
                          progress: Callable[[str], None] | None = None
                          ) -> dict[str, tuple[np.ndarray, float]]:
    """Per standard experiment the model can run at ``params``: its Fisher information
    (:func:`experiment_information`) and its duration [s], sampled every ``dt``."""
    out = {}
    inputs = candidate_inputs(params, dt=dt)
    for k, (name, inp) in enumerate(inputs.items()):
        if progress:
            progress(f'experiment design: {name} ({k + 1} of {len(inputs)})')
        try:
            out[name] = (experiment_information(params, free, inp, sigma, dt),
                         inp['current'].size * dt)
        except HydropumpError:   # a candidate the model cannot run is no candidate
            continue
    return out


def separating_experiments(params, free: Sequence[str], information: np.ndarray,
                           direction: np.ndarray, sigma: dict, duration: float,
                           dt: float = 1e-3, candidates: dict | None = None
                           ) -> list[tuple[str, float]]:
    """Which candidate experiments, added to recordings of Fisher ``information`` and
    ``duration`` seconds, determine ``direction`` (relative standard error below
    :data:`DETERMINED_REL_STD`) by information the recordings lack (at least
    :data:`RATE_RATIO` times theirs per second along it), with the standard error it would
    have; each candidate sampled every ``dt`` as the recordings were (``candidates``: their
    :func:`candidate_information`, computed here when not given)."""
    good = []
    w = np.asarray(direction, float)
    w = w / np.linalg.norm(w)
    rate = float(w @ information @ w) / max(duration, 1e-9)
    if candidates is None:
        candidates = candidate_information(params, free, sigma, dt)
    for name, (cand, t_c) in candidates.items():
        var = float(w @ np.linalg.pinv(information + cand) @ w)
        new = float(w @ cand @ w) / t_c >= RATE_RATIO * rate
        if new and var > 0 and math.sqrt(var) < DETERMINED_REL_STD:
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


def suggest(cal: Calibration, progress: Callable[[str], None] | None = None) -> None:
    """Name, for every weak or held direction of ``cal``, the standard experiments that would
    determine it (``separated_by`` of each entry of ``cal.weak`` and ``cal.held``, and a
    flag); the Fisher information of the recordings is the one at the estimate. The
    candidates' information is computed once for all directions (``progress`` is told as
    each is simulated)."""
    dirs = cal.weak + cal.held
    if not dirs:
        return
    exps = cal.experiments
    sigma = {s: float(np.median([e.sigma[s] for e in exps if s in e.sigma]))
             for s in {s for e in exps for s in e.measured}}
    duration = sum(e.duration for e in exps)
    dt = float(np.median([e.dt for e in exps]))
    cands = candidate_information(cal.params, cal.free, sigma, dt, progress)
    for u in dirs:
        sep = separating_experiments(cal.params, cal.free, cal.information,
                                     np.array(u['direction']), sigma, duration, dt, cands)
        u['separated_by'] = [name for name, _ in sep]
        u['separated_stderr'] = {name: se for name, se in sep}
        # A weak direction of a model that misses something is no question of data yet.
        first = (f' (first free what the model lacks: {cal.missing[0]["parameter"]}; its '
                 'misfit weakens these estimates more than the data do)'
                 if cal.missing else '')
        cal.flags.append(f'to determine {", ".join(u["parameters"])}, add: '
                         + (', '.join(f'{n} ({100 * se:.2g} %)' for n, se in sep) if sep
                            else 'none of the standard experiments adds what these recordings '
                            f'lack with these signals at {1 / dt:.4g} Hz (longer recordings '
                            'of the same kind lower the error as one over the square root of '
                            'their length; else sample faster, measure another signal, or '
                            'give a prior)') + first)
