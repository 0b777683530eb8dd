"""Offline simulation and the fixed-increment stepper of any model, and the Radau reference.

Inputs are held (zero-order hold) over each integration increment, as a digital current
driver and the ROS simulator hold them; inside an increment the Rodas4 stepper adapts its own
steps, so accuracy does not depend on the increment (or, with ``IntegratorConfig.dense``,
steps run free of the increments where the inputs hold and the outputs are interpolated).
A model's own time dependence within an increment (the dither of ``input.dither_amp``) is
evaluated continuously.

One function and one stepper for every model (:mod:`hydropump_sim.system`):
``simulate(circuit, duration, {'boom.command': 0.6})`` and ``Simulator(circuit)``; the paper's
plant is one more model, with the paper's own call as a convenience,
``simulate(params, duration, current, load_pressure=...)``, whose result also answers by
the paper's output names (``res.q_l``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
import time

import numpy as np

from . import _core as c
from . import integrator as ig
from . import invariants
from .errors import HydropumpError, InputError
from .files import replacing
from .inputs import Signal
from .model import OUTPUT_UNITS, OUTPUTS
from .params import Params
from .plant_model import PumpModel, SIGNAL_NAMES
from .steady import equilibrium, TrimError
from .system import Model, Result


class IntegrationError(HydropumpError, RuntimeError):
    """The integrator could not advance (step size underflow or non-finite state)."""


@dataclass(frozen=True)
class IntegratorConfig:
    """Settings of the Rodas4 stepper.

    ``rtol`` is the relative tolerance; absolute tolerances are ``rtol`` times each state's
    scale (4 mm spool stroke, 8 mm plate stroke, 1 MPa pressures, 0.1 m/s rates).
    """

    rtol: float = 1.0e-5
    h_min: float = 1.0e-10
    max_steps: int = 20000
    #: Solver steps per simulated second before a run is refused as too stiff (a nominal run
    #: takes about 10^4; a parameter set near the ends of its ranges can take 10^6).
    steps_per_second: float = 2.0e5
    #: Wall time [s] after which simulate() gives up.
    time_budget: float = 30.0
    #: Steps free of the held-input increments, outputs from the dense output
    #: (integrator.run_dense): faster where the solution is smooth; off, every increment
    #: ends a step, as the simulator node steps.
    dense: bool = False


#: A model's offline runs step free of the increments where the inputs hold.
OFFLINE_CONFIG = IntegratorConfig(dense=True)

#: The paper's input names in a result (``res.xi_u``) -> the model's.
PAPER_INPUTS = {'P_u': 'load.load_pressure', 'xi_u': 'load.aperture', 'f_p': 'pump.shaft_speed'}


class SimResult(Result):
    """A run of the paper's plant alone: a :class:`~hydropump_sim.system.Result` that also
    answers by the paper's names: ``t``, ``I_s``, ``x_c``, ``v_c``, ``x_a``, ``v_a``, ``P_a``,
    ``P_l``, ``Q_p``, ``Q_a``, ``q_l``, ``Q_load``, ``Q_relief``, ``P_u`` (outputs),
    ``xi_u``, ``f_p`` and ``i_s`` (the current's variation of eq. 2), SI units, gauge
    pressures. ``n_clamped`` counts current samples limited to eq. 2."""

    n_clamped: int = 0

    def __getattr__(self, name):
        if name in SIGNAL_NAMES:
            return self[SIGNAL_NAMES[name]]
        if name in PAPER_INPUTS:
            return self.input(PAPER_INPUTS[name])
        if name == 'i_s':
            return self['pump.current'] - self.model.params.I_nominal
        raise AttributeError(name)

    @property
    def units(self) -> dict:
        return dict(zip(OUTPUTS, OUTPUT_UNITS))

    @property
    def paper_y(self) -> np.ndarray:
        """The outputs in the paper's order (:data:`hydropump_sim.model.OUTPUTS`)."""
        return self.y[:, [self.model.signal_index(SIGNAL_NAMES[o]) for o in OUTPUTS]]

    def to_npz(self, path: str | Path) -> None:
        """Save arrays, names and units to ``.npz`` (the paper's output names)."""
        with replacing(path, 'result') as tmp:
            np.savez_compressed(tmp, t=self.t, y=self.paper_y, x=self.x, u=self.u,
                                outputs=np.array(OUTPUTS), units=np.array(OUTPUT_UNITS),
                                states=np.array(self.model.paper_states),
                                model=np.array(self.model.model))

    def to_csv(self, path: str | Path) -> None:
        """Save time and outputs as CSV with a unit row in the header."""
        head = 't [s],' + ','.join(f'{n} [{u}]' for n, u in zip(OUTPUTS, OUTPUT_UNITS))
        with replacing(path, 'result') as tmp:
            np.savetxt(tmp, np.column_stack([self.t, self.paper_y]), delimiter=',',
                       header=head, comments='', fmt='%.10g')


# The largest time grid simulate() builds: output samples and held-input increments.
MAX_SAMPLES = 20_000_000


def time_grid(duration: float, dt_out: float, dt_max: float, n_u: int = c.N_U,
              n_y: int = c.N_Y) -> tuple[int, int, float]:
    """Output points, increments per output and increment length (checked: one line for
    a duration or a step out of range, or a grid too large for memory with ``n_u`` inputs
    and ``n_y`` outputs a sample)."""
    if not (isinstance(duration, (int, float)) and not isinstance(duration, bool)
            and math.isfinite(duration) and duration > 0):
        raise InputError(f'duration = {duration!r}: expected a positive number of seconds')
    if not (isinstance(dt_out, (int, float)) and math.isfinite(dt_out)
            and 0 < dt_out <= duration):
        raise InputError(f'dt_out = {dt_out!r}: expected a step in (0, duration = '
                         f'{duration:.6g}] s')
    n_out = duration / dt_out
    decim = max(1, int(math.ceil(dt_out / dt_max - 1e-9)))
    if n_out * decim > MAX_SAMPLES:
        gib = n_out * (decim * n_u + n_y + 8) * 8 / 2 ** 30
        raise InputError(f'duration = {duration:.6g} s at dt_out = {dt_out:.6g} s (inputs held '
                         f'over {dt_out / decim:.6g} s) needs {n_out * decim:.3g} samples, '
                         f'about {gib:.3g} GiB; at most {MAX_SAMPLES:.3g}: shorten the '
                         'duration or raise dt_out')
    n_out = int(round(n_out))
    return n_out, decim, dt_out / decim


def _paper_inputs(current, load_pressure, aperture, shaft_speed) -> dict:
    """The paper call's inputs by the model's names."""
    return {'pump.current': current, 'load.load_pressure': load_pressure,
            'load.aperture': aperture, 'pump.shaft_speed': shaft_speed}


def refuse_external(model, what: str) -> None:
    """:class:`InputError` for a circuit with components a model outside it steps (a user's
    FMU load): the plant library steps none of them."""
    external = getattr(model, 'external', list)()
    if external:
        raise InputError(f'{what}: {", ".join(external)} step beside the circuit (an FMU): '
                         'run it with the simulator node, or stepped with '
                         'hydropump_ctrl.fmi.loads.CoupledSimulator')


def simulate(plant: Params | Model, duration: float, current: Signal | Mapping = None, *,
             model: str = 'fine', load_pressure: Signal = None, aperture: Signal = None,
             shaft_speed: Signal = None, x0=None, dt_out: float = 1.0e-3,
             dt_max: float = 1.0e-3, method: str = 'rodas',
             config: IntegratorConfig | None = None, rtol: float | None = None,
             t0: float = 0.0, inputs: Mapping | None = None) -> Result:
    """Simulate a model from its steady state at the initial inputs (or ``x0``).

    Parameters
    ----------
    plant : Model or Params
        Any model (a circuit: :func:`hydropump_sim.circuit.load_circuit`), or the paper's
        plant by its parameters (:func:`hydropump_sim.load_params`).
    duration : float
        Simulated time [s].
    current : mapping, or float, callable or ndarray
        For a model: input name (``boom.command``) -> a number, a function of time ``t``
        [s], or samples each held for ``dt_out``; unnamed inputs hold their values. For the
        paper's plant: the absolute solenoid current ``I_s`` [A] in those forms (``None``:
        50 %), clamped to eq. 2 and counted.
    model : {'fine', 'simplified', 'simplified_Kc'}
        The paper plant's form: eq. 10 as printed, or keeping ``K_c``.
    load_pressure, aperture, shaft_speed
        The paper plant's ``P_u`` [Pa gauge], ``xi_u`` [-] and ``f_p`` [Hz], as ``current``;
        ``None`` = the parameter file's values.
    x0 : array_like, optional
        Initial state (``model.states``).
    dt_out : float
        Output grid [s]. Inputs are held over increments of at most ``dt_max``.
    method : {'rodas', 'radau'}
        The compiled Rodas4 stepper, or scipy's Radau (the reference; use a tight ``rtol``).
    config, rtol
        The stepper's settings (``rtol`` overrides ``config.rtol``); by default every model
        steps free of the increments where the inputs hold, outputs from the dense output
        (``OFFLINE_CONFIG``; the paper's plant runs ten times faster so, within 0.005 % of
        a Radau reference); ``IntegratorConfig()`` ends a step at every increment, as the
        simulator node steps.
    t0 : float
        Model time [s] of the first sample: the phase of a dither (a recording that starts at
        simulation time ``t0``); inputs and outputs stay on ``0 .. duration``.
    inputs : mapping, optional
        A model's inputs by name, as ``current`` takes them (the clearer spelling).

    Returns
    -------
    Result
        A :class:`SimResult` for the paper's plant.
    """
    if isinstance(plant, Params):
        if inputs is not None:
            raise InputError("simulate: the paper's plant takes current=, load_pressure=, "
                             'aperture= and shaft_speed=, not inputs=')
        named = _paper_inputs(current, load_pressure, aperture, shaft_speed)
        return _simulate([PumpModel(plant, model)], duration, named, [x0], dt_out, dt_max,
                         method, config or OFFLINE_CONFIG, rtol, t0)[0]
    if not isinstance(plant, Model):
        raise InputError(f'simulate: expected a model or plant parameters, got '
                         f'{type(plant).__name__}')
    refuse_external(plant, 'simulate')
    if inputs is not None:
        if current is not None:
            raise InputError('simulate: give a model its inputs once, as inputs=')
        current = inputs
    if current is not None and not isinstance(current, Mapping):
        raise InputError('simulate: a model takes its inputs by name, {name: signal}')
    return _simulate([plant], duration, current, [x0], dt_out, dt_max, method,
                     config or OFFLINE_CONFIG, rtol, t0)[0]


def simulate_copies(params: Sequence[Params], duration: float, current: Signal = None, *,
                    model: str = 'fine', load_pressure: Signal = None, aperture: Signal = None,
                    shaft_speed: Signal = None, x0=None, dt_out: float = 1.0e-3,
                    dt_max: float = 1.0e-3, config: IntegratorConfig = OFFLINE_CONFIG,
                    rtol: float | None = None, t0: float = 0.0,
                    own_jacobian: bool = False) -> list[SimResult]:
    """Simulate several parameter sets of the paper's plant on the same inputs in one
    compiled loop, every copy taking the steps that the first one's error control chooses
    (Rodas4, see :func:`simulate` for the arguments; the inputs are checked against the
    first set).

    With a shared step sequence the difference between two copies is a smooth function of
    their parameters, free of the step-size noise two separate runs would have: divided by
    the parameter change it is the sensitivity of the solution (internal numerical
    differentiation). ``own_jacobian=False`` lets the copies reuse the first one's
    factorised iteration matrix (6 right-hand sides a step instead of 14; sensitivities
    within about 0.1 % of exact on the pump's flows and pressures); ``True`` makes each
    copy the exact Rodas4 solution of its own parameters.

    ``x0`` is a sequence of initial states, one per set (``None`` entries: the equilibrium at
    the initial inputs of that set).
    """
    params = list(params)
    if not params:
        raise InputError('simulate_copies needs at least one parameter set')
    x0s = [None] * len(params) if x0 is None else list(x0)
    if len(x0s) != len(params):
        raise InputError(f'x0 has {len(x0s)} states for {len(params)} parameter sets')
    named = _paper_inputs(current, load_pressure, aperture, shaft_speed)
    models = [PumpModel(q, model) for q in params]
    if any(m.states != models[0].states for m in models):
        raise InputError('the parameter sets have different states (input.tau_s on in '
                         'some, off in others)')
    return _simulate(models, duration, named, x0s, dt_out, dt_max, 'rodas', config, rtol, t0,
                     own_jacobian)


def _simulate(models: list[Model], duration, inputs, x0s, dt_out, dt_max, method, config,
              rtol, t0, own_jacobian=False) -> list[Result]:
    """Copies of one model structure (their rows of ``p``) on the same inputs."""
    first = models[0]
    n_out, decim, dt = time_grid(duration, dt_out, dt_max, len(first.inputs),
                                 first.n_signals + first.n_states)
    t_inc = np.arange(n_out * decim) * dt
    paper = isinstance(first, PumpModel)
    U, clamped = first.input_table(t_inc, inputs, dt_out,
                                   clamp=('pump.current',) if paper else ())
    n = first.n_states
    X0 = np.empty((len(models), n))
    for r, (m, x0) in enumerate(zip(models, x0s)):
        if x0 is None:
            x0 = equilibrium(m, U[0]).x
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (n,):
            raise InputError(f'x0 must have {n} entries ({", ".join(first.states)})')
        X0[r] = x0
    P = np.array([m.p for m in models])
    Y = np.zeros((len(models), n_out + 1, first.n_signals))
    X = np.zeros((len(models), n_out + 1, n))
    stats = np.zeros(2, dtype=np.int64)
    tol = config.rtol if rtol is None else rtol
    if method == 'rodas':
        st = first.structure()
        if len(models) > 1:  # the time dependence of any copy
            st['timed'] = any(m.structure()['timed'] for m in models)
        run_model(ig.model(first.evaluate_c, st), X0, dt, U, P, tol, config, decim, Y, X,
                  stats, t0, own_jacobian)
    elif t0 and first.dither:
        raise InputError('t0 (the dither phase) needs the rodas method')
    elif method == 'radau':
        _run_radau(first, X0[0], dt, U, P[0], tol, decim, Y[0], X[0], stats)
    else:
        raise InputError(f'unknown method {method!r}: choose rodas or radau')
    t = np.arange(n_out + 1) * dt_out
    U_out = np.vstack([U[::decim], U[-1:]])
    st = {'accepted': int(stats[0]), 'rejected': int(stats[1])}
    out = []
    for r, m in enumerate(models):
        res = (SimResult if paper else Result)(m, t, Y[r], X[r], U_out, st)
        if paper:
            res.n_clamped = clamped.get('pump.current', 0)
        res.violations = invariants.check(m, t, res.y, U_out)
        if res.violations and invariants.strict():
            raise invariants.InvariantError(res.violations, m.name)
        out.append(res)
    return out


# Increments per call of the compiled loop: the wall-time budget is checked between calls.
_CHUNK = 20000


def failure_text(status: int) -> str:
    """Why the stepper stopped, in words (its status code)."""
    return {ig.FAIL_STEP: 'step size underflow (the model changes faster than h_min '
                          'resolves: a stiff or discontinuous right-hand side)',
            ig.FAIL_NAN: 'non-finite state (a parameter or input far outside its range?)',
            ig.FAIL_STEPS: 'too many steps in one increment (max_steps)'}.get(
                status, f'stepper status {status}')


def run_model(model: tuple, X0, dt, U, P, rtol, config, decim, Y, X, stats, t0=0.0,
              own_jacobian=False):
    """The stepper's :func:`~hydropump_sim.integrator.run` of a model
    (:func:`hydropump_sim.integrator.model`) under the step and wall-time budgets of
    ``config``, in chunks; :class:`IntegrationError` on failure."""
    n_out = Y.shape[1] - 1
    rows = max(1, _CHUNK // decim)
    budget = int(max(config.steps_per_second * U.shape[0] * dt, 1000))
    t_wall = time.perf_counter()
    x = X0
    for r0 in range(0, n_out, rows):
        r1 = min(r0 + rows, n_out)
        k0, k1 = r0 * decim, r1 * decim
        run = ig.run_dense if config.dense else ig.run
        status, done = run(model, x, t0 + k0 * dt, dt, U[k0:k1], P, rtol, config.h_min,
                           config.max_steps, decim, Y[:, r0:r1 + 1], X[:, r0:r1 + 1], stats,
                           budget, own_jacobian)
        t_fail = (k0 + done) * dt
        if status == ig.FAIL_BUDGET:
            raise IntegrationError(
                f'the model is too stiff to integrate: {budget} solver steps were not enough '
                f'for the first {t_fail:.6g} s (budget {config.steps_per_second:g} per '
                'simulated second; a nominal run takes about 10000); check parameters near '
                'the ends of their ranges')
        if status != ig.OK:
            raise IntegrationError(f'integration failed at t = {t_fail:.6g} s: '
                                   f'{failure_text(status)}')
        x = X[:, r1].copy()
        elapsed = time.perf_counter() - t_wall
        if elapsed > config.time_budget and r1 < n_out:
            raise IntegrationError(f'stopped after {elapsed:.3g} s of wall time at t = '
                                   f'{k1 * dt:.6g} s of {n_out * decim * dt:.6g} s (time budget '
                                   f'{config.time_budget:g} s)')


def _run_radau(model: Model, x0, dt, U, p, rtol, decim, Y, X, stats):
    """Reference integration with scipy's Radau over each held-input segment."""
    from scipy.integrate import solve_ivp  # only the reference needs it (0.3 s to import)
    n = x0.size
    scale = model.state_scale
    dx = np.empty(n)
    ybuf = np.empty(model.n_signals)

    def fun(t, x, u):
        out = np.empty(n)
        model.evaluate(t, x, u, p, out, ybuf)
        return out

    def jac(t, x, u):
        return model.jacobian(t, x, u, p)

    x = x0.copy()
    model.evaluate(0.0, x, U[0], p, dx, Y[0])
    X[0] = x
    # Join consecutive increments with equal inputs into one call.
    k = 0
    n_inc = U.shape[0]
    row = 1
    while k < n_inc:
        k_end = k + 1
        while k_end < n_inc and np.array_equal(U[k_end], U[k]) and k_end % decim != 0:
            k_end += 1
        t0, t1 = k * dt, k_end * dt
        sol = solve_ivp(fun, (t0, t1), x, method='Radau', rtol=rtol, atol=rtol * scale,
                        jac=jac, args=(U[k],), first_step=min(1e-5, t1 - t0))
        if not sol.success:
            raise IntegrationError(f'Radau failed at t = {t0:.6g} s: {sol.message}')
        stats[0] += sol.t.size - 1
        x = sol.y[:, -1].copy()
        k = k_end
        if k % decim == 0:
            kk = min(k, n_inc - 1)
            model.evaluate(t1, x, U[kk], p, dx, Y[row])
            X[row] = x
            row += 1


def bounded_steps(dt: float, fixed_step: float, max_steps: int) -> int:
    """``max_steps`` checked against the steps of ``fixed_step`` in ``dt``
    (:func:`steps_of`), or an :class:`InputError` saying why not."""
    n = steps_of(dt, fixed_step)
    if isinstance(max_steps, bool) or not isinstance(max_steps, int) or max_steps < n:
        raise InputError(f'solver.max_steps = {max_steps!r}: fewer than the {n} steps of '
                         f'solver.fixed_step = {fixed_step:g} s in dt = {dt:g} s')
    return max_steps


def steps_of(dt: float, fixed_step: float) -> int:
    """The whole number of steps of ``fixed_step`` [s] in an increment ``dt``, or an
    :class:`InputError` saying why not."""
    if not (isinstance(fixed_step, (int, float)) and math.isfinite(fixed_step)
            and 0 < fixed_step <= dt):
        raise InputError(f'solver.fixed_step = {fixed_step!r}: expected seconds above 0 and '
                         f'at most dt = {dt:g} s (0: adaptive steps)')
    n = round(dt / fixed_step)
    if abs(n * fixed_step - dt) > 1e-9 * dt:
        raise InputError(f'solver.fixed_step = {fixed_step:g} s: not a whole fraction of dt = '
                         f'{dt:g} s (e.g. {dt / n:g} or {dt / (n + 1):g} s)')
    return n


class Simulator:
    """Fixed-increment stepper of any model (the simulator node's): holds ``t``, ``x`` and
    the inputs ``u`` (by name with :meth:`set_input`).

    Parameters
    ----------
    plant : Model or Params
        Any model, or the paper's plant by its parameters.
    dt : float
        Increment [s] that :meth:`step` advances (1 ms for a 1 kHz node).
    model : str
        The paper plant's form (:func:`hydropump_sim.model.pack`).
    config : IntegratorConfig
    inputs : mapping, optional
        Inputs by name over the model's own, held from the start (its steady state is at
        them).
    x0 : array_like, optional
        Where the search for that steady state starts (a nearby one).
    fixed_step, max_steps : float, int
        ``fixed_step`` 0: adaptive Rodas4 steps inside each increment (error-controlled,
        ``config``, as many as it takes). Otherwise a step [s] that divides ``dt``: each
        increment takes steps of it, shorter ones where the error control asks (a switch, a
        stop), but at most ``max_steps`` tried, the last ones taken whatever their error:
        the bounded work a real-time loop needs (:mod:`hydropump_sim.fixed_step` checks a
        step on the model first).
    """

    #: Whether this stepper steps the models a circuit's ``external`` components stand for
    #: (a subclass that does: hydropump_ctrl.fmi.loads.CoupledSimulator).
    steps_external = False

    def __init__(self, plant: Params | Model, dt: float = 1.0e-3, model: str = 'fine',
                 config: IntegratorConfig = IntegratorConfig(),
                 inputs: Mapping[str, float] | None = None, x0=None,
                 fixed_step: float = 0.0, max_steps: int = 16):
        if not (math.isfinite(dt) and dt > 0):
            raise InputError(f'dt = {dt!r}: expected a positive number of seconds')
        #: The fixed step and the most Rodas4 steps an increment tries (0, 0: adaptive).
        self.bounded = (fixed_step, bounded_steps(dt, fixed_step, max_steps)) if fixed_step \
            else (0.0, 0)
        #: The check of that step (a ``fixed_step.FixedStep``, set by who checked it).
        self.step_check = None
        self.model = PumpModel(plant, model) if isinstance(plant, Params) else plant
        if not self.steps_external:
            refuse_external(self.model, 'Simulator')
        self.dt = dt
        self.config = config
        self._stepper = self.model.stepper_model()
        self.stats = np.zeros(2, dtype=np.int64)
        #: What its model is, where it was simplified (a ``reduction.Fidelity``, set by who
        #: simplified it); ``None``: the model as given.
        self.fidelity = None
        self.u = self.model.u0.copy()
        self.t = 0.0
        self.steps = 0
        #: Why the last reset started from the nearest state found, or ``None``.
        self.reset_note: str | None = None
        if x0 is not None:
            self.x = np.array(x0, dtype=float)
        self.reset(inputs)

    @property
    def params(self) -> Params | None:
        """The paper plant's parameters (``None`` for a circuit)."""
        return getattr(self.model, 'params', None)

    def reset(self, inputs: Mapping[str, float] | None = None, keep_time: bool = False,
              keep_inputs: bool = True) -> None:
        """Back to the steady state at the held inputs (the model's own unless
        ``keep_inputs``), with ``inputs`` by name over them; time restarts at 0 unless
        ``keep_time``."""
        if not keep_inputs:
            self.u = self.model.u0.copy()
        for name, v in (inputs or {}).items():
            self.set_input(name, v)
        self.reset_note = None
        # From where the model is (a reset near its operating point is quick), with its
        # positions back at their start: a reset restores every state.
        x0 = getattr(self, 'x', None)
        if x0 is not None:
            x0 = x0.copy()
            keep = self.model.integrating
            x0[keep] = self.model.start_states(self.u)[0][keep]
        try:
            eq = equilibrium(self.model, self.u, x0=x0)
        except TrimError:
            # No rest at these inputs (a pump whose flow compensated loads take exactly
            # leaves the pressure free) starts from the nearest state found, and says so.
            eq = equilibrium(self.model, self.u, strict=False)
            if eq.residual > 1.0e-5:
                self.reset_note = (f'no steady state at the held inputs (scaled residual '
                                   f'{eq.residual:.2e})')
        self.x = eq.x.copy()
        if not keep_time:
            self.t = 0.0
            self.steps = 0
        self._h = self.dt

    def take_inputs(self, other: Simulator) -> None:
        """Hold what ``other`` (the model this one replaces) holds, input by input where the
        names agree."""
        mine, theirs = self.model.inputs, other.model.inputs
        for k, name in enumerate(mine):
            if name in theirs:
                self.u[k] = other.u[theirs.index(name)]

    def set_input(self, name: str, value: float) -> None:
        """Hold an input from the next increment, limited to its range."""
        k = self.model.input_index(name)
        lo, hi = self.model.input_ranges[k]
        self.u[k] = min(max(float(value), lo), hi)

    def step(self) -> None:
        """Advance one increment; :class:`IntegrationError` on failure (the state is then
        left at the start of the increment)."""
        t0 = self.steps * self.dt
        x = self.x.copy()[None]
        cfg = self.config
        if self.bounded[1]:
            h, status = self._h, ig.advance_bounded(
                self._stepper, t0, t0 + self.dt, x, self.u, self.model.p[None],
                self.bounded[0], cfg.rtol, self.bounded[1], self.stats, self.model.n_signals)
        else:
            h, status = ig.advance(self._stepper, t0, t0 + self.dt, x, self.u,
                                   self.model.p[None], self._h, cfg.rtol, cfg.h_min,
                                   cfg.max_steps, self.stats, False, self.model.n_signals)
        if status != ig.OK:
            raise IntegrationError(f'integration failed at t = {t0:.6g} s of simulation time: '
                                   f'{failure_text(status)}')
        self.x = x[0]
        self._h = h
        self.steps += 1
        self.t = self.steps * self.dt

    def outputs(self) -> np.ndarray:
        """Every signal at the present state (``model.signals``)."""
        return self.model.rhs(self.t, self.x, self.u)[1]
