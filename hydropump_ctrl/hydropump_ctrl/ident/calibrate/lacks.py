"""What the model lacks: when a calibration does not fit its signals to their noise, the
parameters left fixed ranked by how much of the remaining misfit each would explain if freed.

Each candidate is judged by its profile: the model is simulated with the candidate moved to
a few trial values (a log grid over its range when it is zero, factors around its value
otherwise, then refined around the best), and the free parameters and the delays are let
move with it to first order (the residual's part in the span of their sensitivity columns
at the solution is taken out). The drop of the weighted sum of squares at the best trial
value is what freeing it would explain; the residual there, per signal in units of its
noise as the misfit table gives it, makes the line a user reads: freeing actuator.G_leak_a
would bring line_flow from 3.1x to about 1.1x the noise.

A score test (the drop the candidate's own column predicts at the solution) would cost no
simulation, but a missing effect is often absorbed locally by the free parameters (a
leakage by a larger pilot orifice) while a finite amount of it fits the data to the noise:
the slope at zero says little. The score serves only to choose which candidates with a
value are profiled (:data:`PROFILED`); every candidate at zero (a leakage, a Coulomb force,
the solenoid lag) is profiled.

Every parameter that could be freed is a candidate but the dither (:data:`NOT_CANDIDATES`);
the delays are already fitted. The
start of a free parameter at zero (:func:`zero_starts`) is the score step. Nothing here
imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
import math

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import Params
from hydropump_sim.schema import spec_map

from .engine import Engine
from .problem import check_free, Coordinates, Problem

#: A candidate is named when it would explain at least this fraction of the misfit beyond
#: the noise; at most :data:`SHOWN` of them.
EXPLAINS = 0.05
SHOWN = 3
#: Candidates with a value that are profiled: those the score ranks first.
PROFILED = 6
#: Trial factors on a candidate's value, and the decades of its range tried from zero.
FACTORS = (0.5, 0.7, 1.4, 2.0)
DECADES = (1e-4, 1e-3, 1e-2, 1e-1)
#: Not candidates: the dither's ripple is what the noise level (from second differences)
#: takes as noise, so it cannot explain a misfit beyond the noise (and its runs are slow).
NOT_CANDIDATES = ('input.dither_amp', 'input.dither_freq')


def candidates(base: Params, free: Sequence[str], recorded: Sequence[str] = ()) -> list[str]:
    """Every plant parameter that could be freed and is not."""
    return [n for n in spec_map(Params) if n not in free and n not in NOT_CANDIDATES
            and not check_free(base, [n], recorded)]


def _basis(prob: Problem, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An orthonormal basis of the free parameters' and delays' columns at ``z``, and the
    data residuals there."""
    Jp, Jn = prob.sensitivities(z)
    fixed = np.hstack([Jp, Jn])
    r = prob.data_residuals(z)
    return (np.linalg.qr(fixed)[0] if fixed.shape[1] else np.zeros((r.size, 0))), r


def columns(prob: Problem, params: Params, names: Sequence[str]) -> np.ndarray:
    """The sensitivity columns of the weighted residuals to ``names`` at ``params`` (the
    fitted delays and offsets held), in their search coordinates
    (:class:`.problem.Coordinates`), from copies of the plant stepped with the calibrated
    run. A parameter whose perturbed set the schema refuses (a cross-check at its edge) gets
    a zero column: it explains nothing here."""
    try:
        return _columns(prob, params, names)
    except HydropumpError:
        if len(names) == 1:
            return np.zeros((prob.n_rows, 1))
        return np.hstack([columns(prob, params, [n]) for n in names])


def _columns(prob: Problem, params: Params, names: Sequence[str]) -> np.ndarray:
    coords = Coordinates.of(params, names)
    engine = Engine(params, names, prob.exps, rtol=prob.engine.rtol, model=prob.engine.model,
                    executor=prob.engine.executor)
    try:
        other = Problem(engine, coords, offsets=[s for _, s in prob.with_offset],
                        fit_delays=prob.fit_delays, per_bag=prob.per_bag)
        J, _ = other.sensitivities(coords.to_z(np.array([params.flat()[n] for n in names])),
                                   nuis=prob.nuis)
        prob.engine.n_trajectories += engine.n_trajectories
        return J
    finally:
        engine.close()


def _scores(Q: np.ndarray, r: np.ndarray, J: np.ndarray, names: Sequence[str]
            ) -> dict[str, float]:
    """The drop in the weighted sum of squares each candidate's own column ``J[:, k]``
    predicts at the solution (the score test)."""
    J = J - Q @ (Q.T @ J)
    h = np.einsum('ij,ij->j', J, J)
    g = J.T @ r
    return {n: float(g[k] ** 2 / h[k]) if h[k] > 0 else 0.0 for k, n in enumerate(names)}


def _trials(value: float, lo: float, hi: float) -> list[float]:
    if value == 0.0:
        return [d * hi for d in DECADES if lo <= d * hi <= hi]
    return [value * f for f in FACTORS if lo <= value * f <= hi]


def _profile(prob: Problem, Q: np.ndarray, r: np.ndarray, params: Params, name: str):
    """``(sum of squares, value, residual)`` at the best trial value of ``name``, the free
    parameters and delays moved with it to first order; None if no trial simulates."""
    lo, hi = spec_map(Params)[name].range
    value = float(params.flat()[name])
    engine = Engine(params, (name,), prob.exps, rtol=prob.engine.rtol, model=prob.engine.model,
                    executor=prob.engine.executor)
    tried: dict[float, tuple[float, np.ndarray]] = {}

    def at(v: float):
        if v not in tried:
            try:
                rr = prob.residuals_of(engine.outputs(np.array([v])), prob.nuis)
            except HydropumpError:
                return None
            rr = rr - Q @ (Q.T @ rr)
            tried[v] = (float(rr @ rr), rr)
        return tried[v]
    if value:
        # At its own value the residual is the solution's, already clear of the span.
        tried[value] = (float(r @ r), r)
    try:
        grid = sorted(_trials(value, lo, hi) + ([value] if value else []))
        for v in grid:
            at(v)
        if not tried:
            return None
        # Refine: halfway (geometrically) to each neighbour of the best.
        best = min(tried, key=lambda v: tried[v][0])
        k = grid.index(best)
        for nb in (grid[k - 1] if k > 0 else None, grid[k + 1] if k + 1 < len(grid) else None):
            if nb is not None and nb > 0 and best > 0:
                at(math.sqrt(nb * best))
        # Then the vertex of the parabola (in log of the value) through the best and its two
        # neighbours among those tried.
        vs = sorted(v for v in tried if v > 0)
        best = min(tried, key=lambda v: tried[v][0])
        if best > 0 and 0 < vs.index(best) < len(vs) - 1:
            k = vs.index(best)
            x = np.log(vs[k - 1:k + 2])
            c = np.polyfit(x, [tried[v][0] for v in vs[k - 1:k + 2]], 2)
            if c[0] > 0 and x[0] < -c[1] / (2 * c[0]) < x[2]:
                at(float(np.exp(-c[1] / (2 * c[0]))))
        prob.engine.n_trajectories += engine.n_trajectories
    finally:
        engine.close()
    best = min(tried, key=lambda v: tried[v][0])
    return tried[best][0], best, tried[best][1]


def rank(prob: Problem, z: np.ndarray, names: Sequence[str], params: Params) -> list[dict]:
    """Every profiled candidate of ``names`` (see the module) that lowers the misfit, best
    first: the drop of the weighted sum of squares, the fraction of the misfit beyond the
    noise it explains, the value it would take, and each signal's residual over its noise
    before and after."""
    if not names:
        return []
    Q, r = _basis(prob, z)
    flat = params.flat()
    chosen = [n for n in names if flat[n] == 0.0]
    valued = [n for n in names if flat[n] != 0.0]
    if valued:
        score = _scores(Q, r, columns(prob, params, valued), valued)
        chosen += sorted(valued, key=lambda n: -score[n])[:PROFILED]
    blocks = list(zip(prob.blocks, prob.row_groups()))
    sse = float(r @ r)
    excess = max(sse - r.size, 1e-300)
    out = []
    for n in chosen:
        found = _profile(prob, Q, r, params, n)
        if found is None or not found[0] < sse:
            continue
        best, value, after = found
        out.append({'parameter': n, 'value': float(flat[n]), 'suggested': value,
                    'drop': sse - best, 'explains': min((sse - best) / excess, 1.0),
                    'signals': _signal_ratios(blocks, r, after)})
    out.sort(key=lambda c: -c['drop'])
    return out


def _signal_ratios(blocks, r: np.ndarray, after: np.ndarray) -> dict:
    """Per signal (all its recordings together): the rms of the weighted residual, before
    and after, i.e. the residual over its noise."""
    sums: dict[str, list[float]] = {}
    for (_, s), g in blocks:
        acc = sums.setdefault(s, [0.0, 0.0, 0])
        acc[0] += float(r[g] @ r[g])
        acc[1] += float(after[g] @ after[g])
        acc[2] += g.stop - g.start
    return {s: (math.sqrt(a / n), math.sqrt(b / n)) for s, (a, b, n) in sums.items()}


def text(c: dict) -> str:
    """One candidate in a line: the signal it helps most, from how much to how much."""
    s, (a, b) = max(c['signals'].items(), key=lambda kv: kv[1][0] - kv[1][1])
    return (f'freeing {c["parameter"]} (now {c["value"]:.4g}) would bring the {s} residual '
            f'from {a:.2g}x to about {b:.2g}x the noise, at about {c["suggested"]:.4g} '
            f'({100 * c["explains"]:.0f} % of the misfit beyond the noise)')


def missing(prob: Problem, z: np.ndarray, params: Params, free: Sequence[str],
            recorded: Sequence[str] = ()) -> list[dict]:
    """The candidates worth naming (see :data:`EXPLAINS`), best first, each with its line."""
    found = [c for c in rank(prob, z, candidates(params, free, recorded), params)
             if c['explains'] >= EXPLAINS][:SHOWN]
    for c in found:
        c['text'] = text(c)
    return found


def zero_starts(prob: Problem, z: np.ndarray) -> np.ndarray:
    """``z`` with every free parameter at zero (a leakage, a Coulomb force) moved to the value
    the data suggest: the score step of its own column with the other free parameters' and
    the delays' projected out, within its range; where the data suggest none (a column that
    is zero there), a thousandth of the range."""
    theta = prob.theta(z)
    zero = [k for k in range(prob.n_plant) if theta[k] == 0.0]
    if not zero:
        return z
    Jp, Jn = prob.sensitivities(z)
    r = prob.data_residuals(z)
    lo, hi = prob.coords.bounds()
    out = np.array(z, float)
    for k in zero:
        fixed = np.hstack([np.delete(Jp, k, axis=1), Jn])
        j = Jp[:, k]
        if fixed.shape[1]:
            Q = np.linalg.qr(fixed)[0]
            j = j - Q @ (Q.T @ j)
        h = float(j @ j)
        step = -float(j @ r) / h if h > 0.0 else 0.0
        out[k] = float(np.clip(z[k] + step, lo[k], hi[k]))
        if out[k] == z[k]:
            out[k] = float(min(z[k] + 1e-3 * (hi[k] - lo[k]), hi[k]))
    return out
