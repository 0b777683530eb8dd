"""Offline simulation, the fixed-increment stepper and the Radau reference.

Inputs are held (zero-order hold) over each integration increment, as a digital current
driver and the ROS simulator hold them; inside an increment the Rodas4 stepper adapts its own
steps, so accuracy does not depend on the increment. The dither of ``input.dither_amp`` is
part of the plant and is evaluated continuously.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
import math
from pathlib import Path
import time

import numpy as np

from . import _core as c
from . import integrator as ig
from .errors import HydropumpError, InputError
from .files import replacing
from .inputs import sample, Signal
from .model import INPUTS, OUTPUT_UNITS, OUTPUTS, pack, state_names
from .params import check_input, Params
from .trim import equilibrium, operating_inputs


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


@dataclass
class SimResult:
    """Time response on a uniform grid (SI units, gauge pressures).

    Attributes ``t``, ``I_s``, ``x_c``, ``v_c``, ``x_a``, ``v_a``, ``P_a``, ``P_l``, ``Q_p``,
    ``Q_a``, ``q_l``, ``Q_load``, ``Q_relief`` are arrays of equal length. ``x`` holds the model
    states (columns ``states``), ``u`` the held inputs ``[i_s, P_u, xi_u, f_p]``.
    """

    t: np.ndarray
    y: np.ndarray
    x: np.ndarray
    u: np.ndarray
    model: str
    states: tuple
    n_clamped: int = 0
    stats: dict = field(default_factory=dict)

    def __getattr__(self, name):
        if name in OUTPUTS:
            return self.__dict__['y'][:, OUTPUTS.index(name)]
        if name in INPUTS:
            return self.__dict__['u'][:, INPUTS.index(name)]
        raise AttributeError(name)

    @property
    def units(self) -> dict:
        return dict(zip(OUTPUTS, OUTPUT_UNITS))

    def to_npz(self, path: str | Path) -> None:
        """Save arrays, names and units to ``.npz``."""
        with replacing(path, 'result') as tmp:
            np.savez_compressed(tmp, t=self.t, y=self.y, x=self.x, u=self.u,
                                outputs=np.array(OUTPUTS), units=np.array(OUTPUT_UNITS),
                                states=np.array(self.states), model=np.array(self.model))

    @classmethod
    def from_npz(cls, path: str | Path) -> SimResult:
        with np.load(path) as d:
            return cls(t=d['t'], y=d['y'], x=d['x'], u=d['u'], model=str(d['model']),
                       states=tuple(str(s) for s in d['states']))

    def to_csv(self, path: str | Path) -> None:
        """Save time and outputs as CSV with a unit row in the header."""
        head = 't [s],' + ','.join(f'{n} [{u}]' for n, u in zip(OUTPUTS, OUTPUT_UNITS))
        with replacing(path, 'result') as tmp:
            np.savetxt(tmp, np.column_stack([self.t, self.y]), delimiter=',', header=head,
                       comments='', fmt='%.10g')


def input_table(params: Params, t: np.ndarray, current: Signal, load_pressure: Signal = None,
                aperture: Signal = None, shaft_speed: Signal = None, dt_held: float = 0.0
                ) -> tuple[np.ndarray, int]:
    """Held inputs ``[i_s, P_u, xi_u, f_p]`` on ``t``; current clamped to eq. 2. An input
    given as an array holds each sample for ``dt_held``.

    Returns the table and the number of clamped current samples.
    """
    u0 = operating_inputs(params)
    I_s = sample(current, params.I_nominal, t, 'current', dt_held)
    lo, hi = params.I_limits
    n_clamped = int(np.count_nonzero((I_s < lo) | (I_s > hi)))
    U = np.empty((t.size, c.N_U))
    U[:, c.U_IS] = np.clip(I_s, lo, hi) - params.I_nominal
    U[:, c.U_PU] = sample(load_pressure, u0[c.U_PU], t, 'load_pressure', dt_held)
    U[:, c.U_XI] = sample(aperture, u0[c.U_XI], t, 'aperture', dt_held)
    U[:, c.U_FP] = sample(shaft_speed, u0[c.U_FP], t, 'shaft_speed', dt_held)
    # The operating-point inputs take the ranges of their plant parameters.
    for col, name in ((c.U_PU, 'load_pressure'), (c.U_XI, 'aperture'),
                      (c.U_FP, 'shaft_speed')):
        err = check_input(name, U[:, col], t)
        if err:
            raise InputError(err)
    return U, n_clamped


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


def simulate(params: Params, duration: float, current: Signal = None, *, model: str = 'fine',
             load_pressure: Signal = None, aperture: Signal = None, shaft_speed: Signal = None,
             x0=None, dt_out: float = 1.0e-3, dt_max: float = 1.0e-3, method: str = 'rodas',
             config: IntegratorConfig = IntegratorConfig(), rtol: float | None = None,
             t0: float = 0.0) -> SimResult:
    """Simulate the fine or the simplified model.

    Parameters
    ----------
    params : Params
        Plant parameters (:func:`hydropump_sim.load_params`).
    duration : float
        Simulated time [s].
    current : float or callable or ndarray or None
        Absolute solenoid current ``I_s`` [A], a function of time ``t`` [s], or an array of
        samples each held for ``dt_out`` (sample ``k`` from ``k dt_out`` on, as a recording
        holds its current); ``None`` is ``I_min + I_max`` (50 %). Values outside eq. 2 are
        clamped and counted.
    model : {'fine', 'simplified', 'simplified_Kc'}
        ``'simplified'`` is eq. 10 as printed; ``'simplified_Kc'`` keeps ``K_c``.
    load_pressure, aperture, shaft_speed : float or callable or ndarray or None
        ``P_u`` [Pa gauge], ``xi_u`` [-] and ``f_p`` [Hz], in the forms ``current`` takes;
        ``None`` = parameter file value.
    x0 : array_like, optional
        Initial state; default the equilibrium at the initial inputs.
    dt_out : float
        Output grid [s]. Inputs are held over increments of at most ``dt_max``.
    method : {'rodas', 'radau'}
        The compiled Rodas4 stepper, or scipy's Radau (the reference; use a tight ``rtol``).
    rtol : float, optional
        Relative tolerance (overrides ``config.rtol``).
    t0 : float
        Plant time [s] of the first sample: the phase of the dither (a recording that starts
        at simulation time ``t0``); inputs and outputs stay on ``0 .. duration``.

    Returns
    -------
    SimResult
    """
    return _simulate([params], duration, current, model, load_pressure, aperture, shaft_speed,
                     [x0], dt_out, dt_max, method, config, rtol, t0)[0]


def simulate_copies(params: Sequence[Params], duration: float, current: Signal = None, *,
                    model: str = 'fine', load_pressure: Signal = None, aperture: Signal = None,
                    shaft_speed: Signal = None, x0=None, dt_out: float = 1.0e-3,
                    dt_max: float = 1.0e-3, config: IntegratorConfig = IntegratorConfig(),
                    rtol: float | None = None, t0: float = 0.0,
                    own_jacobian: bool = False) -> list[SimResult]:
    """Simulate several parameter sets on the same inputs in one compiled loop, every copy
    taking the steps that the first one's error control chooses (Rodas4, see
    :func:`simulate` for the arguments; the inputs are checked against the first set).

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
    return _simulate(params, duration, current, model, load_pressure, aperture, shaft_speed,
                     x0s, dt_out, dt_max, 'rodas', config, rtol, t0, own_jacobian)


def _simulate(plist, duration, current, model, load_pressure, aperture, shaft_speed, x0s,
              dt_out, dt_max, method, config, rtol, t0, own_jacobian=False):
    params = plist[0]
    n_out, decim, dt = time_grid(duration, dt_out, dt_max)
    n_inc = n_out * decim
    t_inc = np.arange(n_inc) * dt
    U, n_clamped = input_table(params, t_inc, current, load_pressure, aperture, shaft_speed,
                               dt_out)
    names = state_names(params, model)
    P = np.array([pack(q, model) for q in plist])
    X0 = np.empty((len(plist), len(names)))
    for r, (q, x0) in enumerate(zip(plist, x0s)):
        if state_names(q, model) != names:
            raise InputError('the parameter sets have different states (input.tau_s on in '
                             'some, off in others)')
        if x0 is None:
            x0 = equilibrium(q, U[0, c.U_IS] + q.I_nominal, load_pressure=U[0, c.U_PU],
                             aperture=U[0, c.U_XI], shaft_speed=U[0, c.U_FP], model=model).x
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (len(names),):
            raise InputError(f'x0 must have {len(names)} entries ({", ".join(names)})')
        X0[r] = x0
    Y = np.zeros((len(plist), n_out + 1, c.N_Y))
    X = np.zeros((len(plist), n_out + 1, len(names)))
    stats = np.zeros(2, dtype=np.int64)
    tol = config.rtol if rtol is None else rtol
    if method == 'rodas':
        _run_rodas(X0, dt, U, P, tol, config, decim, Y, X, stats, t0, own_jacobian)
    elif t0 and params.input.dither_amp:
        raise InputError('t0 (the dither phase) needs the rodas method')
    elif method == 'radau':
        _run_radau(X0[0], dt, U, P[0], tol, decim, Y[0], X[0], stats)
    else:
        raise InputError(f'unknown method {method!r}: choose rodas or radau')
    t = np.arange(n_out + 1) * dt_out
    U_out = np.vstack([U[::decim], U[-1:]])
    st = {'accepted': int(stats[0]), 'rejected': int(stats[1])}
    return [SimResult(t=t, y=Y[r], x=X[r], u=U_out, model=model, states=names,
                      n_clamped=n_clamped, stats=st) for r in range(len(plist))]


# Increments per call of the compiled loop: the wall-time budget is checked between calls.
_CHUNK = 20000


def _run_rodas(X0, dt, U, P, rtol, config, decim, Y, X, stats, t0=0.0, own_jacobian=False):
    """The compiled Rodas4 loop on the paper's plant (rows of ``X0``/``P``: copies, see
    :func:`simulate_copies`)."""
    run_model(ig.model(c.evaluate_c, c.structure_rows(P, X0.shape[1])), X0, dt, U, P, rtol,
              config, decim, Y, X, stats, t0, own_jacobian)


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
            why = {ig.FAIL_STEP: 'step size underflow', ig.FAIL_NAN: 'non-finite state',
                   ig.FAIL_STEPS: 'too many steps in one increment'}[status]
            raise IntegrationError(f'integration failed at t = {t_fail:.6g} s: {why}')
        x = X[:, r1].copy()
        elapsed = time.perf_counter() - t_wall
        if elapsed > config.time_budget and r1 < n_out:
            raise IntegrationError(f'stopped after {elapsed:.3g} s of wall time at t = '
                                   f'{k1 * dt:.6g} s of {n_out * decim * dt:.6g} s (time budget '
                                   f'{config.time_budget:g} s)')


def _run_radau(x0, dt, U, p, rtol, decim, Y, X, stats):
    """Reference integration with scipy's Radau over each held-input segment."""
    from scipy.integrate import solve_ivp  # only the reference needs it (0.3 s to import)
    n = x0.size
    scale = c.state_scale(p, n)
    dx = np.empty(n)
    ybuf = np.empty(c.N_Y)
    J = np.empty((n, n))
    work = np.empty(n)

    def fun(t, x, u):
        out = np.empty(n)
        c.evaluate(t, x, u, p, out, ybuf)
        return out

    def jac(t, x, u):
        f0 = fun(t, x, u)
        c.jacobian(t, x.copy(), u, p, f0, scale, J, work, ybuf)
        return J.copy()

    x = x0.copy()
    c.evaluate(0.0, x, U[0], p, dx, Y[0])
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
            c.evaluate(t1, x, U[kk], p, dx, Y[row])
            X[row] = x
            row += 1


class Simulator:
    """Fixed-increment stepper for the ROS simulator: holds ``t``, ``x`` and the inputs.

    Parameters
    ----------
    params : Params
    dt : float
        Increment [s] that :meth:`step` advances (1 ms for a 1 kHz node).
    model : str
        Model name, see :func:`hydropump_sim.model.pack`.
    config : IntegratorConfig
    """

    def __init__(self, params: Params, dt: float = 1.0e-3, model: str = 'fine',
                 config: IntegratorConfig = IntegratorConfig()):
        if not (math.isfinite(dt) and dt > 0):
            raise InputError(f'dt = {dt!r}: expected a positive number of seconds')
        self.params = params
        self.model = model
        self.dt = dt
        self.config = config
        self._p = pack(params, model)
        self._model = ig.model(c.evaluate_c, c.structure(self._p, len(state_names(params,
                                                                                   model))))
        self.stats = np.zeros(2, dtype=np.int64)
        self.u = operating_inputs(params)
        self.t = 0.0
        self.steps = 0
        self.reset()

    def reset(self, current: float | None = None, keep_time: bool = False,
              keep_inputs: bool = False) -> None:
        """Return to the equilibrium at ``current`` (absolute A) and the parameter file's
        operating point, or with ``keep_inputs`` the load pressure, aperture and shaft speed
        held now; time restarts at 0 unless ``keep_time``."""
        held = {} if not keep_inputs else {
            'load_pressure': float(self.u[c.U_PU]), 'aperture': float(self.u[c.U_XI]),
            'shaft_speed': float(self.u[c.U_FP])}
        self.u = operating_inputs(self.params, current, **held)
        self.x = equilibrium(self.params, current, model=self.model, **held).x.copy()
        if not keep_time:
            self.t = 0.0
            self.steps = 0
        self._h = self.dt

    def set_inputs(self, current: float | None = None, load_pressure: float | None = None,
                   aperture: float | None = None, shaft_speed: float | None = None) -> None:
        """Hold new inputs from the next increment; the current is absolute [A]."""
        if current is not None:
            lo, hi = self.params.I_limits
            self.u[c.U_IS] = min(max(current, lo), hi) - self.params.I_nominal
        if load_pressure is not None:
            self.u[c.U_PU] = load_pressure
        if aperture is not None:
            self.u[c.U_XI] = aperture
        if shaft_speed is not None:
            self.u[c.U_FP] = shaft_speed

    def step(self) -> None:
        """Advance one increment ``dt``; raise :class:`IntegrationError` on failure (the
        state is then left at the start of the increment)."""
        t0 = self.steps * self.dt
        x = self.x.copy()
        cfg = self.config
        h, status = ig.advance(self._model, t0, t0 + self.dt, x[None], self.u, self._p[None],
                               self._h, cfg.rtol, cfg.h_min, cfg.max_steps, self.stats, False,
                               c.N_Y)
        if status != c.OK:
            raise IntegrationError(f'integration failed at t = {t0:.6g} s (code {status})')
        self.x = x
        self._h = h
        self.steps += 1
        self.t = self.steps * self.dt

    def outputs(self) -> np.ndarray:
        """Outputs at the current state (``OUTPUTS`` layout, SI)."""
        y = np.empty(c.N_Y)
        c.evaluate(self.t, self.x, self.u, self._p, np.empty_like(self.x), y)
        return y
