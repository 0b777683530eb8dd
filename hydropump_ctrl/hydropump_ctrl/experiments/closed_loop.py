"""The pure closed-loop harness: the fine-model Simulator at 1 kHz, the sensor bank, and a
controller at its own rate with a zero-order hold. No ROS, no DDS.

This is the offline twin of the ROS graph (simulator node, controller node): the Simulator owns
time, the sensors see every plant step, the controller is called every ``1/update_rate`` with
the measurements of that instant and its command is held until the next call. Events (reference
and mode changes, load and shaft-speed steps) are scheduled in simulation time.

The controller sees the plant through :func:`hydropump_sim.measure.true_signals`, the
measurement map of the simulator node, so both feed it the same signals. The result keeps the
true plant outputs (for judging) and what the controller saw and did; the figures of a run
(step and disturbance figures, tone amplitudes) are here too.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Any

import numpy as np
from scipy.optimize import brentq

from hydropump_sim import equilibrium, Simulator, TrimError
from hydropump_sim.errors import InputError
from hydropump_sim.measure import true_signals
from hydropump_sim.metrics import dither_window, moving_average, step_figures, StepFigures
from hydropump_sim.model import OUTPUTS
from hydropump_sim.params import Params
from hydropump_sim.sensors import SensorBank, SensorProfile

from ..control.base import Controller

PLANT_EVENTS = {'aperture', 'load_pressure', 'shaft_speed'}
CONTROLLER_EVENTS = {'reference', 'mode', 'config'}


@dataclass(frozen=True)
class PlantVariation:
    """A perturbed plant for robustness cases, one physical cause per eq. 19 parameter.

    Attributes
    ----------
    gain : float
        Scale of ``G0`` through the shaft speed ``f_p`` (eq. 8: flow per displacement; an
        engine running 20 % fast gives ``gain = 1.2``).
    tau : float
        Scale of the time constant through the pilot orifice ``mu_a`` (and ``h_a``) of eq. 4:
        ``tau = S_a / (mu_a sqrt(P_a))`` for both branches.
    delay : float
        Scale of the flow sensors' delay ``t_d`` of the sensor profile.
    """

    gain: float = 1.0
    tau: float = 1.0
    delay: float = 1.0

    def apply(self, params: Params, profile: SensorProfile) -> tuple[Params, SensorProfile]:
        """The perturbed plant parameters and sensor profile."""
        if self.gain != 1.0 or self.tau != 1.0:
            ac = params.actuator
            params = params.replace({'pump.f_p': params.pump.f_p * self.gain,
                                     'actuator.mu_a': ac.mu_a / self.tau,
                                     'actuator.h_a': ac.h_a / self.tau})
        if self.delay != 1.0:
            sensors = {name: (replace(s, delay=s.delay * self.delay) if s.delay > 0 else s)
                       for name, s in profile.sensors.items()}
            profile = replace(profile, sensors=sensors)
        return params, profile

    @property
    def label(self) -> str:
        parts = [f'{n} x{v:g}' for n, v in (('G0', self.gain), ('tau', self.tau),
                                             ('t_d', self.delay)) if v != 1.0]
        return ', '.join(parts) or 'nominal'


@dataclass(frozen=True)
class Event:
    """Something that happens at time ``t`` [s].

    ``action`` is ``reference`` (``value`` in SI, for ``mode`` or the current mode), ``mode``
    (``value`` a mode name), ``config`` (``value`` a mapping of controller parameters), or a
    plant input: ``aperture`` [-], ``load_pressure`` [Pa gauge], ``shaft_speed`` [Hz].
    """

    t: float
    action: str
    value: Any
    mode: str | None = None


@dataclass
class ClosedLoopResult:
    """Time histories of one closed-loop run (SI units, gauge pressures).

    Attributes
    ----------
    t : ndarray
        Plant time grid [s] (the simulator increment).
    y : dict of ndarray
        True plant outputs by name (``hydropump_sim.model.OUTPUTS``) plus ``margin``
        (``P_l - P_u``), ``P_u``, ``xi_u`` and ``f_p``.
    command : ndarray
        Applied absolute current on the plant grid (held between controller updates) [A].
    t_ctrl : ndarray
        Controller update times [s].
    state : dict of ndarray
        Numeric entries of ``controller.state()`` at each update.
    meas : dict of ndarray
        Measurements the controller received at each update.
    mode : list of str
        Controller mode at each update.
    """

    t: np.ndarray
    y: dict
    command: np.ndarray
    t_ctrl: np.ndarray
    state: dict
    meas: dict
    mode: list
    params: Params
    profile: SensorProfile
    variation: PlantVariation
    info: dict = field(default_factory=dict)

    def smooth(self, name: str) -> np.ndarray:
        """A plant output with the dither ripple averaged out (see :func:`dither_free`)."""
        return dither_free(self.t, self.y[name], self.params.input.dither_freq
                           if self.params.input.dither_amp > 0.0 else 0.0)

    def step(self, name: str, t_step: float, initial: float, final: float,
             band: float = 0.02, band_abs: float | None = None) -> StepFigures:
        """Step figures of a dither-free output after a reference step at ``t_step``."""
        return step_figures(self.t, self.smooth(name), t_step, initial=initial, final=final,
                            band=band, band_abs=band_abs)


def dither_free(t: np.ndarray, y: np.ndarray, f_dither: float) -> np.ndarray:
    """Centred moving average over a whole number of dither periods (zero phase).

    The paper filters the dither out of its measurements before judging responses; a window of
    ``k`` periods (3 periods = 20 ms for 150 Hz at 1 kHz) removes the dither and its
    harmonics exactly and leaves ramps untouched; at the ends the nearest full window.
    ``f_dither = 0`` returns ``y``.
    """
    if f_dither <= 0.0 or t.size < 3:
        return np.asarray(y, dtype=float)
    return moving_average(y, dither_window(float(t[1] - t[0]), f_dither), edges='full')


def trim_current(params: Params, *, flow: float | None = None, margin: float | None = None,
                 model: str = 'fine') -> float:
    """Absolute current [A] whose equilibrium has the line flow ``flow`` [m^3/s] or the margin
    ``P_l - P_u`` = ``margin`` [Pa] at the parameters' operating point."""
    lo, hi = params.current_range
    lo, hi = lo + 1e-6, hi - 1e-6
    if flow is not None:
        def f(current):
            return equilibrium(params, current, model=model).q_l - flow
    elif margin is not None:
        def f(current):
            eq = equilibrium(params, current, model=model)
            return eq.P_l - eq.u[1] - margin
    else:
        raise InputError('trim_current: give flow or margin')
    if f(lo) * f(hi) > 0.0:
        what = 'flow' if flow is not None else 'margin'
        raise TrimError(f'no equilibrium inside the displacement range for {what} = '
                         f'{flow if flow is not None else margin:g}')
    return brentq(f, lo, hi, xtol=1e-10)


def run_closed_loop(controller: Controller, duration: float, events=(), *,
                    params: Params, profile: SensorProfile,
                    variation: PlantVariation = PlantVariation(),
                    start_flow: float | None = None, start_margin: float | None = None,
                    start_current: float | None = None, aperture: float | None = None,
                    load_pressure: float | None = None, mode: str | None = None,
                    settle: float = 0.5, dt_sim: float = 1.0e-3) -> ClosedLoopResult:
    """Run ``controller`` against the fine-model simulator with the sensor ``profile``.

    Parameters
    ----------
    controller : Controller
        EMC or PI; it is reset to the initial steady state.
    duration : float
        Simulated time [s].
    events : iterable of Event
        Scheduled changes (applied at the first plant step at or after their time).
    params : Params
        Nominal plant parameters; ``profile.plant_overrides`` (the dither) are applied here.
    profile : SensorProfile
        Sensor models (``hydropump_sim.sensors.load_profile('config/bench.yaml')``).
    variation : PlantVariation
        Perturbation of the plant for robustness cases.
    start_flow, start_margin, start_current : float, optional
        Initial steady state: line flow [m^3/s], margin [Pa] or current [A] (one of them).
    aperture, load_pressure : float, optional
        Initial load aperture ``xi_u`` [-] and load pressure ``P_u`` [Pa gauge].
    mode : str, optional
        Controller mode from the start. The reference of the mode is set to the initial
        steady state (``start_flow`` or ``start_margin``), so the run starts at rest.
    settle : float
        Closed-loop time [s] simulated before ``t = 0`` and not recorded: the dither biases
        the mean flow of a held current (the falling-flow branch is faster than the growing
        one), so the trimmed equilibrium is not quite the dithered one.
    dt_sim : float
        Simulator increment [s]; the controller period must be a multiple of it.

    Returns
    -------
    ClosedLoopResult
    """
    p = params.replace(profile.plant_overrides) if profile.plant_overrides else params
    live = {}
    if aperture is not None:
        live['line.xi_u'] = aperture
    if load_pressure is not None:
        live['line.P_u'] = load_pressure
    if live:
        p = p.replace(live)
    p, prof = variation.apply(p, profile)
    if start_current is not None:
        I0 = start_current
    else:
        I0 = trim_current(p, flow=start_flow, margin=start_margin)
    period = controller.config.period
    ratio = int(round(period / dt_sim))
    if ratio < 1 or abs(ratio * dt_sim - period) > 1e-9:
        raise InputError(f'controller period {period:g} s is not a multiple of dt_sim '
                         f'{dt_sim:g} s')
    sim = Simulator(p, dt=dt_sim)
    sim.reset(I0)
    bank = SensorBank(prof, dt_sim)
    n = int(round(duration / dt_sim))
    t = np.arange(n + 1) * dt_sim
    Y = np.empty((n + 1, len(OUTPUTS)))
    U = np.empty((n + 1, 3))
    cmd = np.empty(n + 1)
    n_ctrl = n // ratio + 1
    t_ctrl = np.empty(n_ctrl)
    st_log: dict[str, list] = {}
    meas_log: dict[str, list] = {}
    modes = []
    pending = sorted(events, key=lambda e: e.t)
    y = sim.outputs()
    # The controller starts from the exact steady state, as after a long rest.
    m0 = true_signals(y, sim.u)
    if mode is not None:
        controller.set_mode(mode)
    if start_flow is not None:
        controller.set_reference(start_flow, 'flow')
    if start_margin is not None:
        controller.set_reference(start_margin, 'margin')
    controller.reset(I0, m0)
    k_ctrl = 0
    n_settle = int(round(settle / dt_sim / ratio)) * ratio
    for j in range(-n_settle, n + 1):
        tj = j * dt_sim
        while j >= 0 and pending and pending[0].t <= tj + 1e-9:
            _apply(pending.pop(0), sim, controller)
        y = sim.outputs()
        m = bank.measure(true_signals(y, sim.u))
        if j % ratio == 0:
            u = controller.update(tj, period, m)
            sim.set_inputs(current=u)
            if j >= 0:
                t_ctrl[k_ctrl] = tj
                for key, val in controller.state().items():
                    if isinstance(val, (int, float)) and not isinstance(val, bool):
                        st_log.setdefault(key, []).append(float(val))
                for key, val in m.items():
                    meas_log.setdefault(key, []).append(val)
                modes.append(controller.mode)
                k_ctrl += 1
        if j >= 0:
            Y[j] = y
            U[j] = sim.u[1:]
            cmd[j] = controller.command
        if j < n:
            sim.step()
    out = {name: Y[:, i] for i, name in enumerate(OUTPUTS)}
    out['P_u'], out['xi_u'], out['f_p'] = U[:, 0], U[:, 1], U[:, 2]
    out['margin'] = out['P_l'] - out['P_u']
    return ClosedLoopResult(t=t, y=out, command=cmd, t_ctrl=t_ctrl[:k_ctrl],
                            state={k: np.array(v) for k, v in st_log.items()},
                            meas={k: np.array(v) for k, v in meas_log.items()}, mode=modes,
                            params=p, profile=prof, variation=variation,
                            info={'I0': I0, 'algorithm': controller.algorithm})


def _apply(ev: Event, sim: Simulator, controller: Controller) -> None:
    if ev.action == 'reference':
        controller.set_reference(ev.value, ev.mode)
    elif ev.action == 'mode':
        controller.set_mode(ev.value)
    elif ev.action == 'config':
        controller.set_config(ev.value)
    elif ev.action in PLANT_EVENTS:
        sim.set_inputs(**{ev.action: ev.value})
    else:
        raise InputError(f'unknown event {ev.action!r}: use reference, mode, config, '
                         f'{", ".join(sorted(PLANT_EVENTS))}')


# --- figures of the judged cases --------------------------------------------------------------

@dataclass(frozen=True)
class DisturbanceFigures:
    """Response of a regulated output to a disturbance at ``t_step``.

    ``peak`` is the largest deviation from the set-point [unit]; ``overshoot`` the largest
    excursion to the other side after the peak (the recovery overshooting) [unit, >= 0];
    ``beyond`` how far the output went past the ``reference_level`` (e.g. the unavoidable
    quasi-static dip; negative when it stayed short of it); ``recovery`` the time after which
    it stays within ``band`` [s]; ``iae`` the integral of the absolute error [unit s];
    ``ripple`` the peak-to-peak of the output over the last ``tail`` seconds [unit].
    """

    peak: float
    overshoot: float
    beyond: float
    recovery: float
    iae: float
    ripple: float


def disturbance_figures(t: np.ndarray, y: np.ndarray, t_step: float, setpoint: float,
                        band: float, reference_level: float | None = None,
                        tail: float = 0.2) -> DisturbanceFigures:
    """Figures of a (dither-free) regulated output ``y`` after a disturbance at ``t_step``."""
    after = t >= t_step - 1e-12
    dev = y[after] - setpoint
    k = int(np.argmax(np.abs(dev)))
    peak = float(dev[k])
    overshoot = max(0.0, float(np.max(-math.copysign(1.0, peak) * dev[k:])))
    if reference_level is None:
        beyond = math.nan
    else:
        ref = reference_level - setpoint
        beyond = float(abs(peak) - abs(ref)) if ref * peak >= 0.0 else float(abs(peak))
    outside = np.flatnonzero(np.abs(dev) > band)
    if outside.size == 0:
        recovery = 0.0
    elif outside[-1] == dev.size - 1:
        recovery = math.inf
    else:
        recovery = float(t[after][outside[-1] + 1] - t_step)
    iae = float(np.trapezoid(np.abs(dev), t[after]))
    last = t >= t[-1] - tail
    ripple = float(np.ptp(y[last]))
    return DisturbanceFigures(peak, overshoot, beyond, recovery, iae, ripple)


def tone_amplitude(t: np.ndarray, y: np.ndarray, f: float) -> float:
    """Amplitude of the sinusoid of frequency ``f`` [Hz] in ``y`` (least squares, with mean)."""
    w = 2.0 * math.pi * f
    A = np.column_stack([np.sin(w * t), np.cos(w * t), np.ones_like(t)])
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    return float(math.hypot(coef[0], coef[1]))
