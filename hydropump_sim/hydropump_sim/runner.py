"""What a simulator node does, without ROS: :class:`Runner` and its :class:`SimulatorConfig`.

The :class:`~hydropump_sim.Simulator` owns simulation time; the runner decides when it may
advance and what it holds while it does:

- **the command**: a current command is checked (a non-finite value is refused and counted, a
  value outside eq. 2 is clamped by the Simulator and counted) and held (zero-order hold);
- **the command watchdog** (steady clock, paced and free runs): with no command for
  ``command_timeout`` the safe current applies until commands come back;
- **the lock-step gate**: at every control instant the runner waits (steady clock, at most
  ``lock_step_timeout``) for a command newer than the last one it used, so that one
  exchange advances exactly one control period;
- **pause, pause-at and reset**: a paused runner does not advance; ``pause_at`` pauses once
  when simulation time reaches it; reset returns to the initial equilibrium (time runs on);
- **pacing** to a real-time factor, with period statistics;
- **the sensor models** of the profile and the scheduled inputs of a scenario.

The stepping thread calls :meth:`Runner.run` with a *sink* (an object with ``current(t,
value)`` and ``measurement(frame)``, and optionally ``event(name, t, text)``, told of every
lock-step timeout and watchdog trip, named by its :attr:`Runner.stats` key, at the
simulation time it happened); every other method may be called from any thread: the
changes they ask for are applied by the stepping thread between two increments, so the
integrator never sees an input change inside one.

Order of one step ``t_k -> t_k+1``: the gate (pause, lock-step command for ``t_k``), the
inputs held from ``t_k`` (watchdog, scenario), ``sink.current`` (the applied current held
from ``t_k``), pacing, one increment, ``sink.measurement`` (the signals of ``t_k+1``).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping
import dataclasses
from dataclasses import dataclass, field
import math
import threading
import time
from typing import Any, Protocol

import numpy as np

from . import energy
from .errors import InputError
from .measure import Readout
from .params import Params
from .reduction import FIDELITIES
from .schema import fmt, group, replace, spec
from .sensors import SensorBank, SensorProfile
from .simulate import bounded_steps, IntegrationError, Simulator

# Plant parameters that change the held inputs while running (the operating point).
# In lock-step, the first instant's measurements go out again this often [s] until a command
# comes: a controller whose subscription matched just after they went out (discovery is not
# symmetric) would otherwise wait for them, and the run a whole lock_step_timeout for it.
REPEAT_FIRST = 1.0
LIVE_INPUTS = {'line.P_u': 'load_pressure', 'line.xi_u': 'aperture', 'pump.f_p': 'shaft_speed'}


def _rates(dt: float, n: int = 6) -> str:
    """The first publish rates that divide ``1/dt``, for a message."""
    return ', '.join(fmt(1.0 / (k * dt)) for k in range(1, n + 1))


@dataclass(frozen=True)
class Solver:
    """Group ``solver`` of the simulator node: how each increment is integrated."""

    fixed_step: float = spec('s', 'a step for real time: each increment takes Rodas4 steps '
                             'of it (shorter where the error control asks), at most max_steps, '
                             'a bounded work (checked on the circuit at the start, refused '
                             'with the largest step that holds); 0 = adaptive steps, as many '
                             'as the error control takes', 0.0, 0.01, default=0.0)
    max_steps: int = spec('-', 'with fixed_step: the most Rodas4 steps an increment tries '
                          '(the last ones taken whatever their error): the bound of its work',
                          1, 1000, default=16)


@dataclass(frozen=True)
class SimulatorConfig:
    """The simulator node's own parameters (the plant and the sensors have their schemas)."""

    params_file: str = spec('path', 'plant params file; empty = config/pump.yaml', default='')
    circuit_file: str = spec('path', 'circuit the pump feeds (config/circuits/*.yaml), its plant '
                             "the params file; empty = config/circuits/paper.yaml, the paper's "
                             'load', default='')
    fmu_file: str = spec('path', "a user's FMU (FMI 2.0 co-simulation) as the plant, in place "
                         'of the circuit: its inputs and outputs met by name (docs/fmi.md); '
                         'empty = the circuit', default='')
    circuit_sets: str = spec('-', "values over the circuit file's, NAME=VALUE pairs separated "
                             'by spaces (boom.compensator=post pump.type=ls_pump), as '
                             'hydropump circuit --set takes them (live: from the next '
                             '~/reset on, if the topics stay the same)', default='', live=True)
    sensor_profile: str = spec('path', 'sensor profile file (e.g. config/bench.yaml); empty = '
                               'ideal sensors', default='')
    scenario_file: str = spec('path', 'inputs scheduled in simulation time (hydropump simulate '
                              "format): load pressure, aperture, shaft speed, a circuit's own "
                              '(boom.command); empty = none', default='')
    fidelity: str = spec('-', 'the circuit run: fine, or simplified (section IV: the '
                         'components whose modes lie beyond fidelity_bandwidth made static; '
                         '/diagnostics gives its error bound); live: from the next ~/reset on',
                         choices=FIDELITIES, default='fine', live=True)
    fidelity_bandwidth: float = spec('Hz', 'control bandwidth of the simplified fidelity; 0 = '
                                     "the controller's, as designed for the circuit (live: "
                                     'from the next ~/reset on)', 0.0, 1.0e4, default=0.0,
                                     live=True)
    solver: Solver = group(factory=Solver)
    dt: float = spec('s', 'integration increment (inputs are held over it)', 1.0e-5, 0.01,
                     default=1.0e-3)
    publish_rate: float = spec('Hz', 'measurement rate: 1/dt divided by a whole number',
                               1.0, 1.0e5, default=1000.0)
    real_time_factor: float = spec('-', 'pacing: simulated s per wall s; 0 = as fast as '
                                   'possible', 0.0, 1000.0, default=1.0, live=True)
    lock_step: bool = spec('-', 'advance one control period per controller command',
                           default=False)
    control_period: float = spec('s', 'lock-step period (the controller update period): a '
                                 'whole number of dt', 1.0e-4, 1.0, default=0.005)
    lock_step_timeout: float = spec('s', 'steady-clock wait for a command in lock-step before '
                                    'advancing anyway', 1.0e-3, 600.0, default=1.0, live=True)
    command_timeout: float = spec('s', 'steady-clock age of the last command after which the '
                                  'safe current applies (paced and free runs)', 1.0e-3, 600.0,
                                  default=0.5, live=True)
    safe_current: float = spec('A', 'current applied when commands stop; 0 = the current of '
                               '0 % displacement', 0.0, 5.0, default=0.0, live=True)
    initial_current: float = spec('A', 'current of the initial equilibrium (live: from the '
                                  "next ~/reset on); 0 = the circuit file's pump current (the "
                                  "paper's: 50 % displacement)", 0.0, 5.0, default=0.0,
                                  live=True)
    diagnostics_period: float = spec('s', 'period of /diagnostics (steady clock)', 0.1, 60.0,
                                     default=1.0)
    start_paused: bool = spec('-', 'wait for ~/pause false before publishing t = 0, so that '
                              'every peer is matched first', default=False)
    pause_at: float = spec('s', 'pause once simulation time reaches this (experiments end at '
                           'an exact instant); 0 = never', 0.0, 1.0e6, default=0.0, live=True)
    wait_subscribers: int = spec('-', 'on ~/pause false, wait (at most 10 s) until every '
                                 'measurement publisher has this many matched subscribers, so '
                                 "that an orchestrated run's recorder gets the first step", 0,
                                 100, default=0, live=True)

    @property
    def publish_every(self) -> int:
        """Increments per published step."""
        return max(1, int(round(1.0 / (self.publish_rate * self.dt))))

    @property
    def steps_per_period(self) -> int:
        """Increments per control period (lock-step)."""
        return max(1, int(round(self.control_period / self.dt)))

    def cross_checks(self) -> list[str]:
        out = []
        if self.solver.fixed_step:
            try:
                bounded_steps(self.dt, self.solver.fixed_step, self.solver.max_steps)
            except InputError as exc:
                out.append(str(exc))
        n = 1.0 / (self.publish_rate * self.dt)
        if n < 1.0 - 1e-9:
            out.append(f'publish_rate = {fmt(self.publish_rate)} Hz: faster than 1/dt = '
                       f'{fmt(1.0 / self.dt)} Hz (dt = {fmt(self.dt)} s); use one of '
                       f'{_rates(self.dt)} Hz')
        elif abs(n - round(n)) > 1e-6 * n:
            lo, hi = math.floor(n), math.ceil(n)
            out.append(f'publish_rate = {fmt(self.publish_rate)} Hz: 1/dt = '
                       f'{fmt(1.0 / self.dt)} Hz is not a whole multiple of it; the nearest '
                       f'rates are {fmt(1.0 / (hi * self.dt))} and {fmt(1.0 / (lo * self.dt))} '
                       f'Hz')
        m = self.control_period / self.dt
        if abs(m - round(m)) > 1e-6 * m or round(m) < 1:
            out.append(f'control_period = {fmt(self.control_period)} s: not a whole number of '
                       f'dt = {fmt(self.dt)} s')
        elif self.lock_step and not out and round(m) % self.publish_every:
            # The controller answers the samples of its instants: each must be published.
            out.append(f'publish_rate = {fmt(self.publish_rate)} Hz: lock-step needs a sample '
                       f'at every control instant (control_period = '
                       f'{fmt(self.control_period)} s); use a rate that divides into '
                       f'{fmt(1.0 / self.control_period)} Hz whole, e.g. '
                       f'{fmt(1.0 / self.dt)} or {fmt(1.0 / self.control_period)} Hz')
        return out

    def plant_checks(self, params: Params) -> list[str]:
        """Relations with the plant: the currents lie inside eq. 2."""
        lo, hi = params.I_limits
        return [f'{name} = {fmt(v)} A: outside the current range of eq. 2, [{fmt(lo)}, '
                f'{fmt(hi)}] A (0 = the default)'
                for name, v in (('safe_current', self.safe_current),
                                ('initial_current', self.initial_current))
                if v != 0.0 and not lo <= v <= hi]


@dataclass(frozen=True)
class Frame:
    """The measurements of one published step (SI; pressures gauge, as the model has them).

    ``signals`` are through the sensor models where the profile has one; ``velocities`` and
    ``efforts`` are the ``joint_states`` extras of the spool and the plate.
    """

    t: float
    signals: Mapping[str, float]
    velocities: tuple[float, float]
    efforts: tuple[float, float]
    #: A circuit's own topics (``ls_pressure``, ``loads/<name>/...``), through the sensor
    #: model of their kind where they have one, and its joints (names, positions,
    #: velocities).
    extra: Mapping[str, float] = field(default_factory=dict)
    joints: tuple = ((), (), ())


class Sink(Protocol):
    def current(self, t: float, value: float) -> None: ...

    def measurement(self, frame: Frame) -> None: ...

    # Optional: def event(self, name: str, t: float, text: str) -> None (see the module).


Log = Callable[[str, str], None]


def _print_log(level: str, text: str) -> None:
    print(f'[{level}] {text}')


class Runner:
    """Steps a :class:`~hydropump_sim.Simulator` as the simulator node does (see the module).

    Parameters
    ----------
    sim : Simulator
        The model's stepper (the paper's plant or a circuit); the runner resets it to its
        initial equilibrium and reads it by name (:class:`~hydropump_sim.measure.Readout`).
    cfg : SimulatorConfig
    profile : SensorProfile, optional
        Sensor models (none: ideal sensors).
    scenario : mapping of str to callable, optional
        Inputs scheduled in simulation time (``load_pressure``, ``aperture``,
        ``shaft_speed``), as :func:`hydropump_sim.scenario.load_scenario` gives them.
    log : callable(level, text), optional
        Where warnings go (a node passes its logger); levels ``info``, ``warn``, ``error``.
    clock, sleep : callable
        Steady clock [s] and sleep, for the watchdog, the gates and pacing (tests pass fakes).
    """

    THROTTLE = 1.0  # s between two repeats of the same warning

    def __init__(self, sim: Simulator, cfg: SimulatorConfig, *,
                 profile: SensorProfile | None = None,
                 scenario: Mapping[str, Callable] | None = None, log: Log = _print_log,
                 clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        self.sim = sim
        self.params = sim.model.plant_params()
        self.readout = Readout(sim.model)
        self.cfg = cfg
        self.profile = profile or SensorProfile({})
        self.scenario = {k: v for k, v in (scenario or {}).items() if k != 'current'}
        self._log = log
        self._clock = clock
        self._sleep = sleep
        self._cv = threading.Condition()
        self._warned: dict[str, float] = {}
        self._pending: dict[str, Any] = {}
        self._stop = False
        self._paused = cfg.start_paused
        self._pause_armed = cfg.pause_at
        self._failed: str | None = None
        self.stats = {'nan_commands': 0, 'clamped_commands': 0, 'lock_step_timeouts': 0,
                      'watchdog_trips': 0}
        self._periods: deque = deque(maxlen=2000)
        self._costs: deque = deque(maxlen=20000)   # wall time of each step() [s]
        self._overruns = 0
        self._events: list[tuple[str, float, str]] = []   # for the sink, out of the lock
        self._started = False       # the first step's signals are out
        self._sink, self._frame = None, None   # where the last measurement went, and it
        self._reset_out = False     # a reset's signals are due
        self._reset()

    # ---- configuration -------------------------------------------------------------------

    @property
    def safe_current(self) -> float:
        """The current applied when commands stop [A]."""
        return self.cfg.safe_current or self.params.current_range[0]

    @property
    def paused(self) -> bool:
        return self._paused

    @property
    def failed(self) -> str | None:
        """Why stepping stopped (an integration failure), or ``None``."""
        return self._failed

    def _reset(self) -> None:
        """Back to the initial equilibrium. Once running, at the operating point held now,
        and time moves on to the next control instant (lock-step; else the next published
        step), where the reset state is published: simulation time never repeats, so every
        reader can tell the samples before the reset from those after it."""
        plant = self._pending.pop('plant', None)
        if plant is not None:
            plant.steps, plant.t = self.sim.steps, self.sim.t
            plant.take_inputs(self.sim)
            self.sim = plant
            self.readout = Readout(plant.model)
        self.initial_current = self.cfg.initial_current or self._file_current()
        initial = {'current': self.initial_current}
        if self._started:
            self._hold({**self._pending.pop('inputs', {}), **initial})
            self.sim.reset(keep_time=True)
            n = self.cfg.steps_per_period if self.cfg.lock_step else self.cfg.publish_every
            self.sim.steps = (self.sim.steps // n + 1) * n
            self.sim.t = self.sim.steps * self.sim.dt
            self._reset_out = True
        else:
            self.sim.u = self.sim.model.u0.copy()
            self._hold(initial)
            self.sim.reset(keep_time=self.sim.steps > 0)
        if self.sim.reset_note:
            self._log('warn', f'reset: {self.sim.reset_note}; starting from the nearest '
                              'state found')
        # The energies count from the reset on (each experiment its own).
        self._meter = energy.Meter(self.sim.model)
        self._meter_due = self.sim.t
        like = {t.topic: t.like for t in self.readout.topics if t.like}
        self.sensors = SensorBank(self.profile, self.sim.dt * self.cfg.publish_every, like)
        self._sensed = {sig for sig in self.sensors.channels
                        if self.profile.spec(like.get(sig, sig)).active}
        self._current = self.initial_current
        lo, hi = self.params.I_limits
        self._applied = min(max(self.initial_current, lo), hi)  # what the plant holds
        self._cmd_seq = 0
        self._cmd_used = 0
        self._last_cmd: float | None = None
        self._watchdog = False
        self._y = self.sim.outputs()

    def _file_current(self) -> float:
        """The pump's current as the model holds it unless told (a circuit file's: an
        excavator's pump at rest; the paper's: 50 % displacement)."""
        model = self.sim.model
        name = model.plant_inputs().get('current')
        return float(model.u0[model.input_index(name)]) if name else self.params.I_nominal

    def _hold(self, values: Mapping[str, float]) -> None:
        """Hold inputs from the next increment: the operating point's by its names
        (``current``, ``load_pressure``, ``aperture``, ``shaft_speed``: those the model
        lacks are ignored, a load-sensing circuit holds no load pressure), any other by the
        model's own (``boom.command``)."""
        plant = self.sim.model.plant_inputs()
        for name, value in values.items():
            if name in plant:
                self.sim.set_input(plant[name], value)
            elif name not in ('current', 'load_pressure', 'aperture', 'shaft_speed'):
                self.sim.set_input(name, value)

    def _warn(self, key: str, text: str, level: str = 'warn') -> None:
        now = self._clock()
        if now - self._warned.get(key, -math.inf) >= self.THROTTLE:
            self._warned[key] = now
            self._log(level, text)

    # ---- requests (any thread) -----------------------------------------------------------

    def command(self, value: float) -> None:
        """A current command [A, absolute]: held from the next increment."""
        with self._cv:
            if not math.isfinite(value):
                self.stats['nan_commands'] += 1
                # What the plant holds (the last command clamped to eq. 2, or the
                # watchdog's safe current), not the last number received.
                self._warn('nan', f'ignored non-finite current command {value!r}; holding '
                                  f'{self._applied:.4g} A')
                return
            lo, hi = self.params.I_limits
            if not lo <= value <= hi:
                self.stats['clamped_commands'] += 1
                self._warn('clamp', f'current command {value:.4g} A outside the range of eq. '
                                    f'2, [{lo:.3g}, {hi:.3g}] A: clamped')
            self._current = value
            self._cmd_seq += 1
            self._last_cmd = self._clock()
            if self._watchdog:
                self._log('info', 'commands are back: watchdog released')
                self._watchdog = False
            self._cv.notify_all()

    def set_paused(self, paused: bool) -> None:
        with self._cv:
            self._paused = bool(paused)
            self._cv.notify_all()

    def reset(self) -> None:
        """Return to the initial equilibrium before the next increment, paused or not (time
        keeps running, see :meth:`_reset`)."""
        with self._cv:
            self._pending['reset'] = True
            self._cv.notify_all()

    def set_parameter(self, name: str, value: Any) -> None:
        """A live change: an operating-point input (``line.P_u``, ``line.xi_u``, ``pump.f_p``)
        or a live field of :class:`SimulatorConfig`; applied before the next increment."""
        with self._cv:
            if name in LIVE_INPUTS:
                self._pending.setdefault('inputs', {})[LIVE_INPUTS[name]] = float(value)
            elif name == 'sensors.seed':  # a new noise stream from the next reset on
                self.profile = dataclasses.replace(self.profile, seed=int(value))
            else:
                self.cfg = replace(self.cfg, {name: value})
                if name == 'pause_at':
                    self._pause_armed = value
                    if 0.0 < value < self.sim.t - 0.5 * self.sim.dt:
                        self._log('warn', f'pause_at = {value:.6g} s has already passed (t = '
                                          f'{self.sim.t:.6g} s): pausing now')
            self._cv.notify_all()

    def set_plant(self, sim: Simulator) -> None:
        """Step ``sim`` (a circuit of another structure, the same topics) from the next
        :meth:`reset` on; simulation time runs on."""
        with self._cv:
            self._pending['plant'] = sim
            self._cv.notify_all()

    def set_input(self, name: str, value: float) -> None:
        """A circuit's input by name (``boom.command``, from ``loads/boom/command``), held
        from the next increment; a non-finite value is ignored, with a warning."""
        with self._cv:
            if not math.isfinite(value):
                self._warn(f'nan {name}', f'ignored non-finite {name} {value!r}')
                return
            self._pending.setdefault('inputs', {})[name] = float(value)
            self._cv.notify_all()

    def stop(self) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()

    # ---- the stepping thread -------------------------------------------------------------

    def run(self, sink: Sink) -> None:
        """Step until :meth:`stop`; publish through ``sink`` (see the module)."""
        self._sink = sink
        with self._cv:
            while self._paused and not self._stop:
                if self._pending.pop('reset', False):
                    self._reset()
                self._cv.wait(0.1)
        self._emit(sink)
        self._started = True
        next_wall = self._clock()
        last_wall = None
        every = self.cfg.publish_every
        tell = getattr(sink, 'event', None)
        while True:
            with self._cv:
                go = self._gate()
                resumed, reset = self._resumed, self._reset_out
                if go and not reset:
                    self._inputs()
                events, self._events = self._events, []
            if not go:
                return
            if tell is not None:
                for event in events:
                    tell(*event)
            if resumed:
                next_wall, last_wall = self._clock(), None
            if reset:  # publish the reset state, then gate again (pause, lock-step)
                self._reset_out = False
                self._emit(sink)
                continue
            if self.sim.steps % every == 0:
                sink.current(self.sim.t, self._applied_current())
            rtf = self.cfg.real_time_factor
            if rtf > 0.0 and not self.cfg.lock_step:
                next_wall += self.sim.dt / rtf
                delay = next_wall - self._clock()
                if delay > 0.0:
                    self._sleep(delay)
                elif delay < -0.1:
                    next_wall = self._clock()  # far behind: do not try to catch up
            now = self._clock()
            if last_wall is not None:
                self._periods.append(now - last_wall)
            last_wall = now
            try:
                t_step = time.perf_counter()
                self.sim.step()
                self._cost(time.perf_counter() - t_step)
            except IntegrationError as exc:
                with self._cv:
                    self._failed = str(exc)
                self._log('error', f'{exc}; call ~/reset to restart')
                continue
            if self.sim.steps % every == 0:
                self._emit(sink)

    @property
    def step_budget(self) -> float:
        """The wall time [s] a step may take: its period when paced at a real-time factor,
        the increment itself otherwise (what real time would allow it)."""
        rtf = self.cfg.real_time_factor
        return self.sim.dt / rtf if rtf > 0.0 and not self.cfg.lock_step else self.sim.dt

    def _cost(self, cost: float) -> None:
        """Account one step's wall time; a paced step that took longer than its period is
        an overrun, and says so (throttled)."""
        with self._cv:
            self._costs.append(cost)
        budget = self.step_budget
        if cost > budget and self.cfg.real_time_factor > 0.0 and not self.cfg.lock_step:
            self._overruns += 1
            self._warn('overrun', f'step at t = {self.sim.t:.4f} s took {cost * 1e3:.3g} ms, '
                       f'over its {budget * 1e3:.3g} ms period ({self._overruns} overruns '
                       'so far): the simulation falls behind real time')

    def _gate(self) -> bool:
        """Wait (under the lock) until the next increment may run; False when stopping."""
        self._resumed = False
        if self._apply_reset():
            return not self._stop
        pause_at = self._pause_armed
        if pause_at > 0.0 and self.sim.t >= pause_at - 0.5 * self.sim.dt:
            self._pause_armed = 0.0  # once: resuming at that instant does not pause again
            self._paused = True
        while (self._paused or self._failed) and not self._stop:
            self._resumed = True
            self._cv.wait(0.1)
            if self._apply_reset():
                return not self._stop
        if self._stop:
            return False
        if self.cfg.lock_step and self.sim.steps % self.cfg.steps_per_period == 0:
            deadline = self._clock() + self.cfg.lock_step_timeout
            again = self._clock() + REPEAT_FIRST
            while self._cmd_seq <= self._cmd_used and not self._stop:
                left = deadline - self._clock()
                if self.sim.steps == 0 and self._frame is not None and left > 0.0:
                    if self._clock() >= again:
                        self._sink.measurement(self._frame)
                        again += REPEAT_FIRST
                    left = min(left, max(again - self._clock(), 0.0))
                    if left == 0.0:
                        continue
                if left <= 0.0:
                    self.stats['lock_step_timeouts'] += 1
                    self._warn('lockstep', 'lock-step: no command within lock_step_timeout; '
                                           'advancing with the held current')
                    self._events.append((
                        'lock_step_timeouts', self.sim.t,
                        f'no command within lock_step_timeout = '
                        f'{self.cfg.lock_step_timeout:g} s: advancing with the held current '
                        f'{self._current:.4g} A'))
                    break
                self._cv.wait(left)
            self._cmd_used = self._cmd_seq
            self._resumed = True
        return not self._stop

    def _apply_reset(self) -> bool:
        """Apply an asked-for reset; True if its state is to be published now."""
        if not self._pending.pop('reset', False):
            return False
        try:
            self._reset()
        except IntegrationError as exc:      # a plant that cannot start again (an FMU)
            self._failed = str(exc)
            self._log('error', f'{exc}; call ~/reset to try again')
            return False
        self._failed = None
        self._resumed = True
        return self._reset_out

    def _inputs(self) -> None:
        """The inputs held from ``t_k``: command (or the watchdog's safe current), the live
        changes asked for, the scenario."""
        current = self._current
        if (self._last_cmd is not None and not self.cfg.lock_step
                and self._clock() - self._last_cmd > self.cfg.command_timeout):
            if not self._watchdog:
                self._watchdog = True
                self.stats['watchdog_trips'] += 1
                text = (f'no current command for {self.cfg.command_timeout:g} s: applying the '
                        f'safe current {self.safe_current:.4g} A')
                self._log('warn', text)
                self._events.append(('watchdog_trips', self.sim.t, text))
            current = self.safe_current
        lo, hi = self.params.I_limits
        # As the Simulator clamps it: diagnostics report what is applied, not what was asked.
        self._applied = min(max(current, lo), hi)
        self._hold({'current': self._applied, **self._pending.pop('inputs', {})})
        if self.scenario:
            self._hold({name: float(sig(self.sim.t)) for name, sig in self.scenario.items()})

    def _sense(self, name: str, value: float) -> float:
        return self.sensors.channels[name].update(value) if name in self._sensed else value

    def _applied_current(self) -> float:
        """The current held from this step on, dither and sensor model included [A]."""
        value = None
        if self.params.input.dither_amp:
            value = self.readout.current(self.sim.outputs())
        elif 'current' in self.sim.model.plant_inputs():
            value = float(self.sim.u[self.sim.model.input_index(
                self.sim.model.plant_inputs()['current'])])
        if value is None:  # a pump without a solenoid: its nominal current
            value = self.params.I_nominal
        return self._sense('solenoid_current', value)

    def _emit(self, sink: Sink) -> None:
        try:
            y = self.sim.outputs()
        except IntegrationError as exc:      # a plant that fails to say its outputs (an FMU)
            with self._cv:
                self._failed = str(exc)
            self._log('error', f'{exc}; call ~/reset to restart')
            return
        self._y = y
        r = self.readout
        self._meter.add(self.sim.t, y)
        true = r.signals(y)
        true.pop('solenoid_current', None)  # published before the increment, see above
        signals = {k: self._sense(k, v) for k, v in true.items()}
        extra = {k: self._sense(k, v) for k, v in r.extra(y).items()}
        if self._meter.names and self.sim.t >= self._meter_due - 0.5 * self.sim.dt:
            extra.update(self._meter.values())
            self._meter_due = self.sim.t + energy.PUBLISH_PERIOD
        self._frame = Frame(self.sim.t, signals, r.velocities(y), r.efforts(y), extra,
                            r.joints(y))
        sink.measurement(self._frame)

    # ---- diagnostics (any thread) --------------------------------------------------------

    def diagnostics(self) -> dict[str, Any]:
        """A snapshot for ``/diagnostics``: limits, integrator, command, pacing."""
        with self._cv:
            periods = np.array(self._periods)
            age = (self._clock() - self._last_cmd) if self._last_cmd is not None else math.nan
            snap = {'flags': self.readout.flags(self._y), 'stats': dict(self.stats),
                    'failed': self._failed, 'paused': self._paused, 'watchdog': self._watchdog,
                    'command_age': age, 'applied_current': self._applied,
                    'commanded_current': self._current}
        rtf = self.cfg.real_time_factor
        snap['sim_time'] = self.sim.t
        snap['fidelity'], snap['step_check'] = self.sim.fidelity, self.sim.step_check
        with self._cv:
            costs = np.array(self._costs)
        snap['step_budget'] = self.step_budget
        snap['overruns'] = self._overruns
        for key, q in (('step_cost_p50', 50), ('step_cost_p99', 99), ('step_cost_max', 100)):
            snap[key] = float(np.percentile(costs, q)) if costs.size else math.nan
        snap['accepted_steps'], snap['rejected_steps'] = (int(v) for v in self.sim.stats)
        snap['achieved_rtf'] = (self.sim.dt / float(np.mean(periods))) if periods.size \
            else math.nan
        snap['period_error_p99'] = (float(np.percentile(np.abs(periods - self.sim.dt / rtf),
                                                        99))
                                    if periods.size and rtf > 0 and not self.cfg.lock_step
                                    else math.nan)
        return snap

