"""The engine that simulates: every experiment for a parameter vector, and the sensitivities.

The model's outputs for a parameter vector are one :func:`hydropump_sim.simulate` per
experiment. The sensitivities to the free parameters come from copies of the plant, one per
perturbed parameter, stepped with the nominal run in one compiled loop
(:func:`hydropump_sim.simulate.simulate_copies`): every copy takes the nominal run's steps,
so the differences are smooth in the parameters (internal numerical differentiation: no
step-size noise, a perturbation of 1e-4 in log coordinates is enough) and a copy costs six
right-hand sides a step instead of a whole simulation's fourteen.

The jobs (one experiment for one or several parameter vectors) go to an executor of the
suite's execution layer (:mod:`hydropump_ctrl.batch`): by default threads of this process,
which run the compiled loops in parallel (they release the GIL) with nothing to start or to
pickle; on a Dask cluster (``--scheduler``) each job is a task, the experiments sent to every
worker once. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
import math
from typing import Any

import numpy as np

from hydropump_sim.measure import SIGNAL_OUTPUTS
from hydropump_sim.model import OUTPUTS, outputs, pack
from hydropump_sim.params import Params, params_from_dict
from hydropump_sim.simulate import simulate_copies
from hydropump_sim.trim import equilibrium

from ...batch import cores, Executor, InProcess
from .data import Experiment

#: What the nominal run of a job costs in copies: it takes 14 right-hand sides a step, a copy
#: stepped with it 6 (:func:`hydropump_sim.simulate.simulate_copies`).
NOMINAL_COST = 14.0 / 6.0
#: Threads of the default executor: one per core, up to four.
THREADS = min(4, cores())
_OUT_INDEX = {s: OUTPUTS.index(o) for s, o in SIGNAL_OUTPUTS.items() if o is not None}

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


def tied_values(flat: Mapping[str, Any], free: Sequence[str]) -> dict[str, float]:
    """The derived parameters that follow the ``free`` ones, recomputed from ``flat``."""
    out = {}
    values = dict(flat)
    for name, (sources, _, fn) in DERIVED.items():
        if any(s in free for s in sources):
            out[name] = values[name] = fn(values)
    return out


def params_with(base: Params, names: Sequence[str], theta: Sequence[float]) -> Params:
    """``base`` with the free parameters set and their ties followed (re-validated)."""
    flat = base.flat()
    flat.update({n: float(v) for n, v in zip(names, theta)})
    flat.update(tied_values(flat, names))
    return params_from_dict(flat)


def _initial_state(params: Params, exp: Experiment, model: str):
    if exp.start_signal is None:
        return None   # the equilibrium at the first inputs
    return equilibrium(params, exp.initial_current(params),
                       load_pressure=None if exp.load_pressure is None
                       else float(exp.load_pressure[0]), model=model).x


def simulate_runs(plist: Sequence[Params], exp: Experiment, rtol: float | None = None,
                  model: str = 'fine') -> list[dict[str, np.ndarray]]:
    """The true signals (SI, gauge) of the pump in the form ``model`` (the fine one, or
    eq. 10 at the simplified fidelity) for each parameter set of ``plist``, the first one's
    steps shared (see the module), on the experiment's model grid: ``fine`` output steps
    per recorded sample (the recorded sample ``k`` is row ``k fine``), the inputs held over
    each recorded sample."""
    m = exp.fine
    n = (exp.n - 1) * m + 1
    load = None if exp.load_pressure is None else np.repeat(exp.load_pressure, m)
    runs = simulate_copies(plist, (exp.n - 1) * exp.dt, np.repeat(exp.current, m),
                           load_pressure=load, dt_out=exp.dt_model, dt_max=exp.dt_model,
                           rtol=rtol, t0=exp.t0, model=model,
                           x0=[_initial_state(p, exp, model) for p in plist])
    out = []
    for params, res in zip(plist, runs):
        y = res.y[:n]
        # A sample at an input change is the one of the step that ended there (as the
        # simulator measures and a sampler sees): the load flow, which the load pressure
        # moves at once (eq. 9), with the inputs before the change.
        changed = np.flatnonzero(np.any(res.u[1:n] != res.u[:n - 1], axis=1)) + 1
        if changed.size:
            y = y.copy()
            p = pack(params, model)
            for k in changed:
                o = outputs(float(res.t[k]), res.x[k], res.u[k - 1], params, model, p=p)
                y[k] = [o[name] for name in OUTPUTS]
        out.append({s: y[:, _OUT_INDEX[s]] for s in exp.measured})
    return out


def simulate_experiment(params: Params, exp: Experiment, rtol: float | None = None,
                        model: str = 'fine') -> dict[str, np.ndarray]:
    """The true signals on the experiment's recorded grid (SI, gauge)."""
    return {s: y[::exp.fine] for s, y in simulate_runs([params], exp, rtol, model)[0].items()}


class Work:
    """What every job needs besides its parameter vectors (sent to each worker once), and
    the validated parameter sets built from them, kept where the jobs run."""

    def __init__(self, base: Params, names: Sequence[str], exps: Sequence[Experiment],
                 rtol: float, model: str = 'fine'):
        self.base, self.names, self.exps, self.rtol = base, tuple(names), list(exps), rtol
        self.model = model
        self.params: dict[bytes, Params] = {}

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != 'params'}

    def __setstate__(self, state):
        self.__dict__.update(state, params={})

    def plant(self, theta) -> Params:
        """The parameter set of ``theta``, validated once (validation takes milliseconds)."""
        key = np.asarray(theta, float).tobytes()
        p = self.params.get(key)
        if p is None:
            if len(self.params) > 64:
                self.params.clear()
            p = self.params[key] = params_with(self.base, self.names, theta)
        return p


def run_job(job, work: Work):
    """One experiment for several parameter vectors, the first one's steps shared."""
    e, thetas = job
    return simulate_runs([work.plant(t) for t in thetas], work.exps[e], work.rtol, work.model)


class Engine:
    """Simulations of the experiments of a calibration (see the module).

    Parameters
    ----------
    base : Params
        The parameters the free ones are set in.
    names : sequence of str
        The free parameters, in the order of the vectors ``theta``.
    exps : sequence of Experiment
    rtol : float
        The integrator's relative tolerance.
    executor : Executor, optional
        Where the jobs run (:mod:`hydropump_ctrl.batch`; the caller closes it). Default:
        :data:`THREADS` threads of this process, or with ``workers`` that many (1: a plain
        loop).
    model : str
        The pump's form (``fine``; ``simplified_Kc``, eq. 10, at the simplified fidelity).
    """

    #: The perturbation of a sensitivity, in the search coordinates: a relative change of
    #: 0.01 % (the copies share the nominal run's steps: no step-size noise).
    sensitivity_step = 1e-4
    #: How the sensitivities are made, as a calibration's method says it.
    sensitivities = 'from copies of the plant stepped with the nominal run'

    def __init__(self, base: Params, names: Sequence[str], exps: Sequence[Experiment], *,
                 rtol: float = 1e-5, executor: Executor | None = None,
                 workers: int | None = None, model: str = 'fine'):
        self.base, self.names, self.exps = base, tuple(names), list(exps)
        self.rtol, self.model = rtol, model
        self._own = executor is None
        self.executor = executor if executor is not None else \
            InProcess(THREADS if workers is None else workers)
        self.workers = self.executor.workers
        self.n_trajectories = 0       # simulated runs, a copy counted as one
        self.n_loops = 0              # compiled loops (a nominal run with its copies is one)
        self._work = Work(base, names, exps, rtol, model)
        self._shared = None
        self._cache: dict[bytes, list[dict[str, np.ndarray]]] = {}

    def _run(self, jobs):
        self.n_loops += len(jobs)
        self.n_trajectories += sum(len(th) for _, th in jobs)
        if self._shared is None:
            self._shared = self.executor.share(self._work)
        # The longest jobs first, so that no worker is left with one at the end: a job
        # costs its samples times its nominal run and copies.
        order = sorted(range(len(jobs)), key=lambda k: -self.exps[jobs[k][0]].n
                       * (NOMINAL_COST + len(jobs[k][1]) - 1))
        res = self.executor.map(run_job, [jobs[k] for k in order], work=self._shared)
        out = [None] * len(jobs)
        for k, r in zip(order, res):
            out[k] = r
        return out

    def outputs(self, theta: np.ndarray) -> list[dict[str, np.ndarray]]:
        """The true signals of every experiment at ``theta`` (cached)."""
        key = np.asarray(theta, float).tobytes()
        if key not in self._cache:
            res = self._run([(e, [theta]) for e in range(len(self.exps))])
            self._remember(key, [r[0] for r in res])
        return self._cache[key]

    def sensitivity_runs(self, theta: np.ndarray, thetas: Sequence[np.ndarray]
                         ) -> tuple[list[dict], list[list[dict]]]:
        """The true signals at ``theta`` and at each perturbed vector of ``thetas``, every
        perturbed run stepped with the nominal one: ``(nominal[e], perturbed[j][e])``."""
        m = len(thetas)
        jobs, where = [], []
        for e, groups in enumerate(self._groups(m)):
            bounds = np.linspace(0, m, groups + 1).round().astype(int)
            for g in range(groups):
                part = list(range(bounds[g], bounds[g + 1]))
                if part:
                    jobs.append((e, [theta] + [thetas[j] for j in part]))
                    where.append((e, part))
        res = self._run(jobs)
        nominal: list[dict] = [None] * len(self.exps)
        perturbed = [[None] * len(self.exps) for _ in range(m)]
        for (e, part), runs in zip(where, res):
            nominal[e] = runs[0]
            for j, run in zip(part, runs[1:]):
                perturbed[j][e] = run
        self._remember(np.asarray(theta, float).tobytes(), nominal)
        return nominal, perturbed

    def _groups(self, m: int) -> list[int]:
        """How many jobs the ``m`` copies of each experiment are split into, so that the
        jobs keep the workers busy alike: each group carries the nominal run (which chooses
        the steps, :data:`NOMINAL_COST` copies' worth), so a split costs work and is made
        only where it shortens the longest worker's share (largest jobs first)."""
        n = [e.n for e in self.exps]
        groups = [1] * len(n)
        if self.workers < 2 or m < 2:
            return groups

        def makespan(gs):
            sizes = sorted((n[e] * (NOMINAL_COST + m / g) for e, g in enumerate(gs)
                            for _ in range(g)), reverse=True)
            load = [0.0] * self.workers
            for c in sizes:
                load[load.index(min(load))] += c
            return max(load)
        best = makespan(groups)
        while True:
            tries = [groups[:e] + [groups[e] + 1] + groups[e + 1:] for e in range(len(n))
                     if groups[e] < min(m, self.workers)]
            cand = min(tries, key=makespan, default=None)
            if cand is None or makespan(cand) >= best * 0.99:
                return groups
            groups, best = cand, makespan(cand)

    def _remember(self, key: bytes, sims) -> None:
        if len(self._cache) > 32:
            for k in list(self._cache)[:16]:
                del self._cache[k]
        self._cache[key] = sims

    def close(self) -> None:
        """Release the shared work on a cluster; stop the executor if this engine made it."""
        self._shared = None
        if self._own:
            self.executor.close()
