"""Running a compiled circuit: offline simulation, a fixed-increment stepper for the
simulator node, and steady states.

The stepper is the one of :mod:`hydropump_sim.integrator` (Rodas4, inputs held over each
increment), as for the paper's plant alone. A circuit's steady state holds every state
still except the *integrating* ones (a cylinder's position, which moves at a constant
velocity wherever the piston is): they keep their start values.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
import math
from pathlib import Path
import time

import numpy as np
from scipy import optimize

from . import integrator as ig
from . import invariants
from .circuit import Circuit, CircuitError, N_FLUID, NODE_PREFIX
from .errors import HydropumpError, InputError
from .files import replacing
from .inputs import sample, Signal
from .simulate import IntegrationError, IntegratorConfig, run_model, time_grid

DEFAULT_CONFIG = IntegratorConfig()
#: Offline circuit runs step free of the increments (IntegratorConfig.dense).
OFFLINE_CONFIG = IntegratorConfig(dense=True)


class CircuitTrimError(HydropumpError, ValueError):
    """No steady state found at the requested inputs."""


def input_vector(circuit: Circuit, values: Mapping[str, float] | None = None) -> np.ndarray:
    """The circuit's held inputs with ``values`` (by name, aliases too) over them, checked
    against each input's range."""
    u = circuit.u0.copy()
    errors = []
    for name, v in (values or {}).items():
        k = circuit.input_index(name)
        lo, hi = circuit.input_ranges[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) \
                or not lo <= v <= hi:
            errors.append(f'{name} = {v!r}: expected a number in [{lo:.6g}, {hi:.6g}] '
                          f'{circuit.input_units[k]}')
            continue
        u[k] = float(v)
    if errors:
        raise CircuitError(errors)
    return u


@dataclass
class CircuitResult:
    """A circuit's time response on a uniform grid (SI units, gauge pressures).

    ``res['boom.flow']`` is a signal by name (a composite's names resolve), ``res.input(name)``
    an input; ``t``, ``y`` (signals by column, ``circuit.signals``), ``x`` (states), ``u``.
    """

    circuit: Circuit
    t: np.ndarray
    y: np.ndarray
    x: np.ndarray
    u: np.ndarray
    stats: dict = field(default_factory=dict)
    #: The physical invariants this run broke (:mod:`hydropump_sim.invariants`).
    violations: list = field(default_factory=list)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.y[:, self.circuit.signal_index(name)]

    def input(self, name: str) -> np.ndarray:
        return self.u[:, self.circuit.input_index(name)]

    def node(self, node: str) -> np.ndarray:
        """Pressure of a node [Pa gauge]."""
        return self[f'{NODE_PREFIX}{node}']

    def final(self) -> dict[str, float]:
        """Every component signal's last value, by name."""
        return {n: float(self[n][-1]) for n in self.circuit.component_signals()}

    def to_npz(self, path: str | Path) -> None:
        c = self.circuit
        with replacing(path, 'result') as tmp:
            np.savez_compressed(tmp, t=self.t, y=self.y, x=self.x, u=self.u,
                                signals=np.array(c.signals), units=np.array(c.signal_units),
                                states=np.array(c.states), inputs=np.array(c.inputs))

    def to_csv(self, path: str | Path, names: list[str] | None = None) -> None:
        """Time and the named signals (default every component signal) with units."""
        c = self.circuit
        names = names or c.component_signals()
        cols = [self[n] for n in names]
        units = [c.signal_units[c.signal_index(n)] for n in names]
        head = 't [s],' + ','.join(f'{n} [{u}]' for n, u in zip(names, units))
        with replacing(path, 'result') as tmp:
            np.savetxt(tmp, np.column_stack([self.t] + cols), delimiter=',', header=head,
                       comments='', fmt='%.10g')


def input_table(circuit: Circuit, t: np.ndarray, inputs: Mapping[str, Signal] | None,
                dt_held: float = 0.0) -> np.ndarray:
    """Held inputs on the increment times ``t`` (every input not named holds its value)."""
    U = np.tile(circuit.u0, (t.size, 1))
    errors = []
    for name, sig in (inputs or {}).items():
        k = circuit.input_index(name)
        v = sample(sig, circuit.u0[k], t, name, dt_held)
        lo, hi = circuit.input_ranges[k]
        bad = (v < lo) | (v > hi)
        if bad.any():
            j = int(np.flatnonzero(bad)[0])
            errors.append(f'{name} = {v[j]:.6g} {circuit.input_units[k]} at t = {t[j]:.6g} s: '
                          f'outside [{lo:.6g}, {hi:.6g}]')
            continue
        U[:, k] = v
    if errors:
        raise InputError('; '.join(errors))
    return U


def simulate_circuit(circuit: Circuit, duration: float,
                     inputs: Mapping[str, Signal] | None = None, *, x0=None,
                     dt_out: float = 1.0e-3, dt_max: float = 1.0e-3,
                     config: IntegratorConfig = OFFLINE_CONFIG, rtol: float | None = None,
                     t0: float = 0.0) -> CircuitResult:
    """Simulate a circuit from its steady state at the initial inputs (or ``x0``).

    Parameters
    ----------
    circuit : Circuit
    duration : float
        Simulated time [s].
    inputs : mapping, optional
        Input name (``boom.command``) -> a number, a function of time, or samples held for
        ``dt_out`` each; unnamed inputs hold their values.
    x0 : array_like, optional
        Initial state (``circuit.states``).
    dt_out, dt_max, config, rtol, t0
        As :func:`hydropump_sim.simulate`; by default steps are free of the increments
        (``config.dense``).
    """
    n_out, decim, dt = time_grid(duration, dt_out, dt_max, len(circuit.inputs),
                                 circuit.n_signals + circuit.n_states)
    t_inc = np.arange(n_out * decim) * dt
    U = input_table(circuit, t_inc, inputs, dt_out)
    if x0 is None:
        x0 = equilibrium(circuit, U[0]).x
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (circuit.n_states,):
        raise InputError(f'x0 must have {circuit.n_states} entries')
    Y = np.zeros((1, n_out + 1, circuit.n_signals))
    X = np.zeros((1, n_out + 1, circuit.n_states))
    stats = np.zeros(2, dtype=np.int64)
    run_model(circuit.stepper_model(), x0[None].copy(), dt, U, circuit.p[None],
              config.rtol if rtol is None else rtol, config, decim, Y, X, stats, t0)
    U_out = np.vstack([U[::decim], U[-1:]])
    res = CircuitResult(circuit, np.arange(n_out + 1) * dt_out, Y[0], X[0], U_out,
                        {'accepted': int(stats[0]), 'rejected': int(stats[1])})
    res.violations = invariants.check(circuit, res.t, res.y, res.u)
    if res.violations and invariants.strict():
        raise invariants.InvariantError(res.violations, circuit.name)
    return res


class CircuitSimulator:
    """Fixed-increment stepper of a circuit (the simulator node's): holds ``t``, ``x`` and
    the inputs ``u`` (by name with :meth:`set_input`)."""

    def __init__(self, circuit: Circuit, dt: float = 1.0e-3,
                 config: IntegratorConfig = DEFAULT_CONFIG):
        if not (math.isfinite(dt) and dt > 0):
            raise InputError(f'dt = {dt!r}: expected a positive number of seconds')
        self.circuit = circuit
        self.dt = dt
        self.config = config
        self._model = circuit.stepper_model()
        self.stats = np.zeros(2, dtype=np.int64)
        self.u = circuit.u0.copy()
        self.t = 0.0
        self.steps = 0
        self.reset()

    def reset(self, inputs: Mapping[str, float] | None = None, keep_time: bool = False) -> None:
        """Back to the steady state at the held inputs (with ``inputs`` over them)."""
        for name, v in (inputs or {}).items():
            self.set_input(name, v)
        self.x = equilibrium(self.circuit, self.u).x.copy()
        if not keep_time:
            self.t = 0.0
            self.steps = 0
        self._h = self.dt

    def set_input(self, name: str, value: float) -> None:
        """Hold an input from the next increment, limited to its range."""
        k = self.circuit.input_index(name)
        lo, hi = self.circuit.input_ranges[k]
        self.u[k] = min(max(float(value), lo), hi)

    def step(self) -> None:
        """Advance one increment; :class:`IntegrationError` on failure (the state is then
        left at the start of the increment)."""
        t0 = self.steps * self.dt
        x = self.x.copy()[None]
        cfg = self.config
        h, status = ig.advance(self._model, t0, t0 + self.dt, x, self.u, self.circuit.p[None],
                               self._h, cfg.rtol, cfg.h_min, cfg.max_steps, self.stats, False,
                               self.circuit.n_signals)
        if status != ig.OK:
            raise IntegrationError(f'integration failed at t = {t0:.6g} s (code {status})')
        self.x = x[0]
        self._h = h
        self.steps += 1
        self.t = self.steps * self.dt

    def outputs(self) -> np.ndarray:
        """Every signal at the present state (``circuit.signals``)."""
        return self.circuit.rhs(self.t, self.x, self.u)[1]


# ---- steady states --------------------------------------------------------------------------

@dataclass
class CircuitEquilibrium:
    """A steady state: states, held inputs, signals; ``eq['boom.flow']`` by name."""

    circuit: Circuit
    x: np.ndarray
    u: np.ndarray
    y: np.ndarray
    residual: float

    def __getitem__(self, name: str) -> float:
        return float(self.y[self.circuit.signal_index(name)])


def start_state(circuit: Circuit, u: np.ndarray, pressure: float | None = None) -> np.ndarray:
    """A start for the steady-state search: every node at ``pressure`` (default the highest
    fixed pressure, a tank's), every component at its own start."""
    fixed = {n: float(circuit.p[N_FLUID + circuit.nodes.index(n)] if how == 'param'
                      else u[circuit.inputs.index(f'{c}.{k}')])
             for n, (c, how, k) in circuit.fixed.items()}
    p0 = pressure if pressure is not None else max(fixed.values(), default=0.0)
    x = np.zeros(circuit.n_states)
    P = {n: fixed.get(n, p0) for n in circuit.nodes}
    # Loads holding their forces, and upstream of them at least as much.
    for part in circuit.parts:
        ins = {s.name: float(u[part.u.start + i]) for i, s in enumerate(part.comp.INPUTS)}
        for port, v in part.comp.pressure_guess(ins).items():
            for n in part.comp.ports.get(port, []):
                if n not in fixed:
                    P[n] = max(P[n], v)
    for n in circuit.nodes:
        if n not in fixed:
            x[circuit.node_state(n)] = P[n]
    for part in circuit.parts:
        comp = part.comp
        ports = {s.name: P[comp.ports[s.name][0]] for s in comp.PORTS if comp.ports.get(s.name)}
        ins = {s.name: float(u[part.u.start + i]) for i, s in enumerate(comp.INPUTS)}
        xs = comp.initial_state(ports, ins)
        if xs.size:
            x[part.x] = xs
    return x


def equilibrium(circuit: Circuit, u=None, *, x0=None, tol: float = 1.0e-9,
                horizon: float = 30.0, time_budget: float = 30.0, strict: bool = True
                ) -> CircuitEquilibrium:
    """The steady state at held inputs ``u`` (a vector, or values by name; default the
    circuit's).

    Marches the dynamics from ``x0`` (or :func:`start_state`) until the non-integrating
    states settle, holding the integrating ones at their start, then polishes by Newton.

    Raises
    ------
    CircuitTrimError
        When the state does not settle within ``horizon`` simulated seconds or
        ``time_budget`` seconds of wall time (unless not ``strict``: then the nearest state
        found comes back, its ``residual`` saying how far from rest it is).
    """
    if u is None or isinstance(u, Mapping):
        u = input_vector(circuit, u)
    u = np.asarray(u, dtype=float)
    x = start_state(circuit, u) if x0 is None else np.array(x0, dtype=float)
    held = x[circuit.integrating].copy()
    free = ~circuit.integrating
    scale = circuit.state_scale
    dx = np.empty(circuit.n_states)
    y = np.empty(circuit.n_signals)
    p = circuit.p_steady  # a dither oscillates about the steady state

    def rates(xv):
        circuit.evaluate(0.0, xv, u, p, dx, y)
        return dx

    def resid(z):
        xv = x.copy()
        xv[free] = z * scale[free]
        return rates(xv)[free] * 1.0e-3 / scale[free]

    def worst(xv):
        return float(np.max(np.abs(rates(xv)[free] * 1.0e-3 / scale[free]), initial=0.0))

    def polish(xv):
        if worst(xv) <= tol:
            return xv
        sol = optimize.root(resid, xv[free] / scale[free], method='hybr',
                            options={'xtol': 1e-13})
        out = xv.copy()
        out[free] = sol.x * scale[free]
        return out if worst(out) < worst(xv) else xv

    if x0 is not None:
        x = polish(x)
    if worst(x) > tol:
        x = _march(circuit, x, u, p, held, horizon, time_budget, worst)
        x = polish(x)
    r = worst(x)
    # A scaled rate of 1e-5 per ms: one per cent of a state's scale a second, at rest for any
    # use (the march and the polish stop short of tol where a component is nearly singular).
    if strict and not r <= max(tol, 1.0e-5):
        raise CircuitTrimError(
            f'{circuit.name}: no steady state found at the held inputs (scaled residual '
            f'{r:.2e}): ' + _describe(circuit, x, u))
    y_out = circuit.rhs(0.0, x, u)[1]
    return CircuitEquilibrium(circuit, x, u, y_out, r)


def _march(circuit: Circuit, x: np.ndarray, u: np.ndarray, p: np.ndarray, held: np.ndarray,
           horizon: float, time_budget: float, worst: Callable[[np.ndarray], float]
           ) -> np.ndarray:
    """Integrate with held inputs, in chunks of 0.2 s, until the state settles."""
    dt, chunk = 1.0e-3, 200
    U = np.tile(u, (chunk, 1))
    Y = np.empty((1, chunk + 1, circuit.n_signals))
    X = np.empty((1, chunk + 1, circuit.n_states))
    stats = np.zeros(2, dtype=np.int64)
    model = circuit.stepper_model(timed=False)
    t0 = time.perf_counter()
    for k in range(int(horizon / (dt * chunk))):
        status, _ = ig.run(model, x[None].copy(), k * dt * chunk, dt, U, p[None], 1.0e-6,
                           1.0e-12, 20000, 1, Y, X, stats, 2_000_000, False)
        if status != ig.OK:
            break
        x = X[0, -1].copy()
        x[circuit.integrating] = held
        if worst(x) < 1.0e-9 or time.perf_counter() - t0 > time_budget:
            break
    return x


def _describe(circuit: Circuit, x: np.ndarray, u: np.ndarray) -> str:
    """The states that still move most, for the error."""
    dx, _ = circuit.rhs(0.0, x, u)
    r = np.abs(dx) * 1.0e-3 / circuit.state_scale
    r[circuit.integrating] = 0.0
    worst = np.argsort(-r)[:3]
    return ', '.join(f'{circuit.states[k]} moves at {dx[k]:.3g} {circuit.state_units[k]}/s'
                     for k in worst if r[k] > 0)


def trim_input(circuit: Circuit, name: str, target: Callable[[CircuitEquilibrium], float],
               u=None, *, bounds: tuple[float, float] | None = None,
               xtol: float = 1.0e-7) -> tuple[CircuitEquilibrium, bool]:
    """The steady state where ``target(eq) = 0`` by the held input ``name`` (the pump's
    current for a margin): returns it and whether the target was reached (``False``: the
    input is at the end of its range, e.g. a demand beyond the pump's maximum flow)."""
    if u is None or isinstance(u, Mapping):
        u = input_vector(circuit, u)
    u = np.array(u, dtype=float)
    k = circuit.input_index(name)
    lo, hi = bounds or circuit.input_ranges[k]
    cache: dict[float, CircuitEquilibrium] = {}
    last = [None]

    def at(v):
        if v not in cache:
            uu = u.copy()
            uu[k] = v
            cache[v] = equilibrium(circuit, uu, x0=last[0])
            last[0] = cache[v].x
        return cache[v]

    f_lo, f_hi = target(at(lo)), target(at(hi))
    if f_lo * f_hi > 0.0:
        end = lo if abs(f_lo) < abs(f_hi) else hi
        return at(end), False
    v = optimize.brentq(lambda v: target(at(v)), lo, hi, xtol=xtol)
    return at(v), True

