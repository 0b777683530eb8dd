"""The one closed-loop harness, without ROS: any model stepped at 1 kHz by the
:class:`~hydropump_sim.Simulator`, the bench's sensors, and a controller at its own rate
with a zero-order hold, as the simulator and controller nodes run them. The offline twin
runs what the node runs: the same model (the paper's plant or a circuit), read through the
same :class:`~hydropump_sim.measure.Readout`.

Inputs are scheduled by name on the simulator's grid (numbers, functions of time, samples);
plant events hold an input from their time on; controller events change its reference, mode
or configuration. A settling time before ``t = 0`` runs with the inputs of ``t = 0`` and is
not recorded. The run's invariants (:mod:`hydropump_sim.invariants`) are checked.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydropump_sim import invariants
from hydropump_sim.errors import InputError
from hydropump_sim.measure import Readout
from hydropump_sim.sensors import SensorBank, SensorConfig, SensorProfile
from hydropump_sim.simulate import Simulator
from hydropump_sim.system import Model

#: Controller events and plant events (an operating-point input by its name).
CONTROLLER_EVENTS = {'reference', 'mode', 'config'}
PLANT_EVENTS = {'aperture', 'load_pressure', 'shaft_speed'}


@dataclass(frozen=True)
class Event:
    """Something that happens at time ``t`` [s].

    ``action`` is ``reference`` (``value`` in SI, for ``mode`` or the current mode), ``mode``
    (``value`` a mode name), ``config`` (``value`` a mapping of controller parameters), or a
    plant input held from then on: ``aperture`` [-], ``load_pressure`` [Pa gauge],
    ``shaft_speed`` [Hz], or any input of the model by its name (``boom.command``).
    """

    t: float
    action: str
    value: Any
    mode: str | None = None


@dataclass
class LoopRun:
    """One run: every signal of the model on the simulator's grid (``run['pump.q_l']``),
    the inputs held, the current the controller commanded, and what it saw and did."""

    model: Model
    t: np.ndarray
    y: np.ndarray
    u: np.ndarray
    command: np.ndarray
    t_ctrl: np.ndarray = field(default_factory=lambda: np.zeros(0))
    state: dict = field(default_factory=dict)
    meas: dict = field(default_factory=dict)
    mode: list = field(default_factory=list)
    violations: list = field(default_factory=list)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.y[:, self.model.signal_index(name)]

    def input(self, name: str) -> np.ndarray:
        return self.u[:, self.model.input_index(name)]

    def final(self) -> dict[str, float]:
        return {n: float(self[n][-1]) for n in self.model.component_signals()}


def _held(t_event: float, before: float, after: float):
    return lambda t: np.where(np.asarray(t) >= t_event - 1e-9, after, before)


def run_loop(model: Model, duration: float, *, controller=None,
             inputs: Mapping[str, Any] | None = None, events: Sequence[Event] = (),
             profile: SensorProfile | None = None, settle: float = 0.0, dt: float = 1.0e-3,
             start: Mapping[str, float] | None = None, x0=None) -> LoopRun:
    """Run ``model`` for ``duration`` [s] under ``controller`` (``None``: the inputs as
    scheduled).

    Parameters
    ----------
    controller : Controller, optional
        EMC or PI, updated every ``controller.config.period`` with the measurements of that
        instant; it commands the pump's current (the model's ``current`` input) and is reset
        to the steady state it starts from.
    inputs : mapping, optional
        Input name (``boom.command``, ``load.aperture``) -> a number, a function of time or
        samples held for ``dt``; unnamed inputs hold their values.
    events : sequence of Event
        Controller events, and plant events (an input held from their time on).
    profile : SensorProfile, optional
        The sensors the controller sees the model through (default ideal).
    settle : float
        Time [s] run before ``t = 0`` with the inputs of ``t = 0``, not recorded.
    start : mapping, optional
        Inputs by name of the steady state the run starts from (default those of
        ``t = 0``), e.g. the current a controller starts from.
    x0 : array_like, optional
        Where the search for that steady state starts (a nearby one).
    """
    plant = model.plant_inputs()
    sched = dict(inputs or {})
    ctrl_events = []
    for ev in sorted(events, key=lambda e: e.t):
        if ev.action in CONTROLLER_EVENTS:
            ctrl_events.append(ev)
            continue
        name = plant.get(ev.action, ev.action)
        if ev.action in PLANT_EVENTS and ev.action not in plant:
            raise InputError(f'event {ev.action}: the model has no such input')
        k = model.input_index(name)
        before = sched.get(name, model.u0[k])
        sched[name] = (lambda t, f=before, e=ev: _held(e.t, f(t) if callable(f) else f,
                                                      e.value)(t))
    n, n0 = int(round(duration / dt)), int(round(settle / dt))
    ratio = 1
    if controller is not None:
        period = controller.config.period
        ratio = int(round(period / dt))
        if ratio < 1 or abs(ratio * dt - period) > 1e-9:
            raise InputError(f'controller period {period:g} s is not a multiple of dt_sim '
                             f'{dt:g} s (the simulator increment)')
        n0 = int(round(n0 / ratio)) * ratio
        if 'current' not in plant:
            raise InputError(f'{model.name}: a controller needs a pump driven by the solenoid '
                             'current (type pump)')
    t = np.arange(n + 1) * dt
    U, _ = model.input_table(np.maximum(np.arange(-n0, n + 1) * dt, 0.0), sched, dt)
    i_cur = model.input_index(plant['current']) if controller is not None else None
    held = {name: float(U[0, k]) for k, name in enumerate(model.inputs)}
    sim = Simulator(model, dt, inputs={**held, **(start or {})}, x0=x0)
    readout = Readout(model) if controller is not None else None
    bank = SensorBank(profile or SensorProfile.from_config(SensorConfig()), dt,
                      like={'ls_pressure': 'line_pressure'})
    if controller is not None:
        # The controller starts from the exact steady state, as after a long rest.
        controller.reset(float(sim.u[i_cur]), readout.signals(sim.outputs()))
    Y = np.empty((n + 1, model.n_signals))
    Uo = np.empty((n + 1, len(model.inputs)))
    cmd = np.empty(n + 1)
    t_ctrl, st_log, meas_log, modes = [], {}, {}, []
    pending = list(ctrl_events)
    for j in range(-n0, n + 1):
        tj = j * dt
        while j >= 0 and pending and pending[0].t <= tj + 1e-9:
            _apply(pending.pop(0), controller)
        row = U[j + n0]
        if controller is not None:
            row = row.copy()
            row[i_cur] = sim.u[i_cur]
        sim.u[:] = row
        y = sim.outputs()
        if controller is not None:  # the sensors see every step, as the node's do
            meas = bank.measure(readout.signals(y))
        if controller is not None and (j + n0) % ratio == 0:
            sim.set_input(plant['current'], controller.update(tj, controller.config.period,
                                                              meas))
            if j >= 0:
                t_ctrl.append(tj)
                for key, val in controller.state().items():
                    if isinstance(val, (int, float)) and not isinstance(val, bool):
                        st_log.setdefault(key, []).append(float(val))
                for key, val in meas.items():
                    meas_log.setdefault(key, []).append(val)
                modes.append(controller.mode)
        if j >= 0:
            Y[j] = y
            Uo[j] = sim.u
            cmd[j] = controller.command if controller is not None else np.nan
        if j < n:
            sim.step()
    violations = invariants.check(model, t, Y, Uo)
    if violations and invariants.strict():
        raise invariants.InvariantError(violations, model.name)
    return LoopRun(model, t, Y, Uo, cmd, np.array(t_ctrl),
                   {k: np.array(v) for k, v in st_log.items()},
                   {k: np.array(v) for k, v in meas_log.items()}, modes, violations)


def _apply(ev: Event, controller) -> None:
    if controller is None:
        raise InputError(f'event {ev.action} at t = {ev.t:g} s: there is no controller')
    if ev.action == 'reference':
        controller.set_reference(ev.value, ev.mode)
    elif ev.action == 'mode':
        controller.set_mode(ev.value)
    else:
        controller.set_config(ev.value)
