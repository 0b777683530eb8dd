"""What the controller node does around the control law, without ROS: :class:`Supervisor`.

- **The measurement gate**: a sample that is not finite or not physical
  (:data:`PLAUSIBLE`) is refused and counted; the controller predicts through it.
- **The time rule** (:mod:`hydropump_ctrl.timebase`): wherever a ``/clock`` is present, an
  update runs at every control instant ``t_K`` of simulation time once the measurements of
  ``t_K`` are in (stamped ones carry ``t_K``, unstamped ones were published after the
  ``/clock`` of ``t_K``), so a lock-step run is repeatable whatever order messages arrive in;
  the command and the state carry ``t_K``. With no ``/clock`` at all a steady timer drives
  the updates, stamped with the node's wall time. A jump back of simulation time (a new
  simulator) drops the time state and restarts the law bumplessly at the next instant.
- **The watchdogs** (steady clock, so a stopped ``/clock`` cannot hide a dead peer): no
  measurement for ``watchdog.hold_timeout`` stops the updates (the plant holds the last
  command); after ``watchdog.safe_timeout`` the safe current is commanded until
  measurements come back, then the law restarts bumplessly. With
  ``watchdog.simulation_time`` (lock-step runs) the ages are simulation time: a simulation
  held back by a slow peer or a loaded machine advances no time, so it trips nothing.
- **Bumpless (re)start** through :meth:`Controller.reset` from the measurements.
- **Live parameters**: checked against the schema and the configuration, applied at the next
  update.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
import math
import time
from typing import Any

from hydropump_sim.measure import SIGNALS
from hydropump_sim.schema import group, ParamError, replace, spec

from ..timebase import TimeBase
from . import make_controller
from .schema import ControllerConfig, validate_parameter

# Plausible ranges of the measurements as the nodes publish them (SI, absolute pressures):
# outside them a sample is a sensor fault.
# The range a sample is taken from, per signal (SI, pressures absolute): the signal table's.
PLAUSIBLE = {name: info.plausible for name, info in SIGNALS.items() if info.plausible}
STATE_KEYS = ('reference', 'estimate', 'disturbance', 'command', 'command_desired')


@dataclass(frozen=True)
class Watchdog:
    """Group ``watchdog``: the steady-clock watchdog on the measurements."""

    hold_timeout: float = spec('s', 'steady-clock age of the measurements after which updates '
                               'stop (the last command holds)', 0.01, 60.0, default=0.2,
                               live=True)
    safe_timeout: float = spec('s', 'steady-clock age after which the safe current is '
                               'commanded', 0.01, 600.0, default=1.0, live=True)
    simulation_time: bool = spec('-', 'count the ages in simulation time where a clock '
                                 'runs (lock-step: a simulation that waits for a slow peer '
                                 'trips nothing; measurements lost while it runs do)',
                                 default=False, live=True)

    def cross_checks(self) -> list[str]:
        if self.safe_timeout < self.hold_timeout:
            return [f'watchdog.safe_timeout = {self.safe_timeout:g} s must not be shorter than '
                    f'watchdog.hold_timeout = {self.hold_timeout:g} s']
        return []


@dataclass(frozen=True)
class ControllerNodeConfig:
    """The controller node's own parameters (the law's are :class:`ControllerConfig`)."""

    config_file: str = spec('path', 'controller params file (from hydropump design); empty = '
                            'config/controller.yaml', default='')
    autostart: bool = spec('-', 'configure and activate at start-up', default=False)
    watchdog: Watchdog = group(factory=Watchdog)


@dataclass(frozen=True)
class Output:
    """A command to publish: the time it answers [ns], the current [A], the state."""

    stamp_ns: int | None      # None: no simulation time yet (the node stamps wall time)
    command: float
    state: Mapping[str, Any] = field(default_factory=dict)


Log = Callable[[str, str], None]


def _print_log(level: str, text: str) -> None:
    print(f'[{level}] {text}')


class Supervisor:
    """The controller node's logic (see the module); every method returns an :class:`Output`
    to publish, or ``None``.

    Parameters
    ----------
    config : ControllerConfig
    watchdog : Watchdog
    clock : callable
        Steady clock [s] (tests pass a fake one).
    log : callable(level, text)
    published : callable(topic) -> bool
        Whether a measured topic has a publisher (the node's graph): a (re)start waits for
        what its mode feeds back, and for the rest of the operating point only where it
        is published.
    """

    #: Steady time [s] after a control instant after which an update uses the latest values,
    #: for a free-running simulator whose samples may never carry ``t_K`` exactly.
    STALE_WAIT = 0.02
    #: Steady time [s] of measurements without a ``/clock`` after which time is wall time:
    #: longer than a discovery that missed its first announcements (Fast DDS then waits for
    #: the next, 3 s later), so that a simulator's graph never gets a wall-time command.
    CLOCK_WAIT = 4.0
    THROTTLE = 2.0

    def __init__(self, config: ControllerConfig, watchdog: Watchdog = Watchdog(), *,
                 clock: Callable[[], float] = time.monotonic, log: Log = _print_log,
                 published: Callable[[str], bool] = lambda topic: True):
        self.config = config
        self._published = published   # does a topic have a publisher?
        self.watchdog = watchdog
        self._clock = clock
        self._log = log
        self._warned: dict[str, float] = {}
        self.ctrl = make_controller(config)
        self.period_ns = int(round(config.period * 1e9))
        self.time = TimeBase()
        self.counts = {'updates': 0, 'rejected_nan': 0, 'rejected_range': 0,
                       'stale_updates': 0, 'watchdog_safe': 0, 'control_errors': 0,
                       'time_jumps': 0}
        self.active = False
        self.mode_state = 'running'
        self._pending: ControllerConfig | None = None
        self._last_rx: float | None = None
        self._last_rx_sim: int | None = None  # the latest simulation time then [ns]
        self._first_rx: float | None = None
        self._listening = clock()  # since when a first measurement is awaited
        self._wall = False
        self._clear_time()

    def _clear_time(self) -> None:
        self._meas: dict[str, float] = {}
        self._stamp: dict[str, int] = {}     # stamped topics: header stamp [ns]
        self._src: dict[str, int] = {}       # unstamped topics: source timestamp [ns]
        self._due: int | None = None
        self._due_wall = 0.0
        self._t_prev: int | None = None      # last update: sim ns, or steady ns (wall mode)
        self._needs_reset = True

    def _warn(self, key: str, text: str, level: str = 'warn') -> None:
        now = self._clock()
        if now - self._warned.get(key, -math.inf) >= self.THROTTLE:
            self._warned[key] = now
            self._log(level, text)

    # ---- lifecycle -----------------------------------------------------------------------

    def activate(self) -> Output | None:
        """Start commanding; the first update restarts the law from the measurements."""
        self._needs_reset = True
        self._t_prev = None
        self.active = True
        if self._first_rx is None:
            self._listening = self._clock()
        return self._maybe_update()

    def deactivate(self) -> None:
        self.active = False

    # ---- inputs --------------------------------------------------------------------------

    def measurement(self, topic: str, value: float, *, stamp_ns: int | None = None,
                    source_ns: int | None = None) -> Output | None:
        """A measurement sample (SI, absolute pressures): with its header stamp, or, for an
        unstamped topic, its DDS source timestamp."""
        self._last_rx = self._clock()
        self._last_rx_sim = self.time.latest
        if self._first_rx is None:
            self._first_rx = self._last_rx
        if self.mode_state != 'running':
            self._resume()
        lo, hi = PLAUSIBLE.get(topic, (-math.inf, math.inf))
        if not math.isfinite(value):
            self.counts['rejected_nan'] += 1
            self._warn(f'nan {topic}', f'rejected {topic} = {value!r}')
            self._meas.pop(topic, None)
        elif not lo <= value <= hi:
            self.counts['rejected_range'] += 1
            self._warn(f'range {topic}', f'rejected {topic} = {value:.6g}: outside '
                                         f'[{lo:g}, {hi:g}]')
            self._meas.pop(topic, None)
        else:
            self._meas[topic] = value
        if stamp_ns is not None:
            self._stamp[topic] = stamp_ns
            if (self._due is None and self.time.present is False and stamp_ns % self.period_ns
                    == 0 and (self._t_prev is None or stamp_ns > self._t_prev)):
                # The first /clock went by before this node matched it: the stamps say an
                # instant has come (a lock-step simulator waits for its command).
                self._due = stamp_ns
                self._due_wall = self._clock()
        elif source_ns is not None:
            self._src[topic] = source_ns
        return self._maybe_update()

    def clock(self, sim_ns: int, source_ns: int, sequence: int | None = None, writer=None
              ) -> Output | None:
        """A ``/clock`` sample with its source timestamp (and publication sequence number
        and writer identity, see :meth:`TimeBase.on_clock`)."""
        jump = self.time.on_clock(sim_ns, source_ns, sequence, writer)
        if jump is not None:
            self.counts['time_jumps'] += 1
            self._log('warn', f'{jump.describe()}: restarting the control law from the '
                              'measurements')
            self._clear_time()
        if sim_ns % self.period_ns == 0 and (self._t_prev is None or sim_ns > self._t_prev):
            self._due = sim_ns
            self._due_wall = self._clock()
        return self._maybe_update()

    def wall_tick(self, now_ns: int, clock_publishers: int = 0) -> Output | None:
        """The steady timer's tick: where no ``/clock`` exists, update with the latest values,
        stamped ``now_ns`` (the node's wall time).

        Wall time only once measurements have come for :attr:`CLOCK_WAIT` with no
        ``/clock`` and no ``/clock`` publisher in the graph (``clock_publishers``): a
        simulator's measurements may arrive before its ``/clock`` is discovered, and its
        graph must never get a command in wall time."""
        if self.time.present or clock_publishers or not self._running():
            return None
        if not all(t in self._meas for t in self._required()):
            return None  # nothing to control on yet (no simulator, no sensors)
        if self._clock() - self._first_rx < self.CLOCK_WAIT:
            return None
        if not self._wall:
            self._wall = True
            self._log('info', 'no /clock in the graph: updates on the steady timer, stamped '
                              'with wall time')
        steady_ns = int(self._clock() * 1e9)
        dt = ((steady_ns - self._t_prev) * 1e-9 if self._t_prev is not None
              else self.config.period)
        self._t_prev = steady_ns
        return self._update(now_ns, dt)

    def check_watchdog(self) -> Output | None:
        """Run the watchdog (call it every few tens of ms); may command the safe current."""
        if self._listening is not None and self.never_measured():
            self._listening = None  # said once
            self._log('warn', f'no measurement received yet ({self.watchdog.safe_timeout:g} s '
                              'after start): is a simulator running in this namespace and '
                              'ROS domain?')
        if not self.active or self._last_rx is None:
            return None
        age = self._age()
        safe = self.config.limits.safe_current
        if age > self.watchdog.safe_timeout:
            if self.mode_state != 'safe':
                self._log('error', f'no measurements for {age:.2f} s: commanding the safe '
                                   f'current {safe:g} A')
            self.mode_state = 'safe'
            self.counts['watchdog_safe'] += 1
            return Output(self.time.latest, float(safe), self._state(safe))
        if age > self.watchdog.hold_timeout:
            if self.mode_state == 'running':
                self._log('warn', f'measurements stale ({age:.2f} s): holding the command')
            self.mode_state = 'hold'
        return None

    def _age(self) -> float:
        """The measurements' age [s]: steady time since the last one, or, with
        ``watchdog.simulation_time`` while a clock runs, the simulation time since."""
        if self.watchdog.simulation_time and self.time.present:
            latest, then = self.time.latest, self._last_rx_sim
            return 0.0 if latest is None or then is None else max(latest - then, 0) * 1e-9
        return self._clock() - self._last_rx

    def _resume(self) -> None:
        """Measurements are back: restart the law from them at the next instant."""
        self._log('info', 'measurements are back: resuming')
        self._needs_reset = True
        self._t_prev = None
        self.mode_state = 'running'

    def set_reference(self, value: float) -> str | None:
        """The reference of the present mode (SI); a refusal's reason, or ``None``."""
        try:
            self.ctrl.set_reference(value)
        except ValueError as exc:
            return str(exc)
        return None

    def set_parameters(self, values: Mapping[str, Any]) -> str | None:
        """Live controller (``emc.*``, ``reference.*``, ...) or ``watchdog.*`` parameters,
        applied at the next update; the reason of a refusal, or ``None``."""
        law = {k: v for k, v in values.items() if not k.startswith('watchdog.')}
        for name, value in law.items():
            reason = validate_parameter(self.config, name, value)
            if reason:
                return reason
        wd = {k.removeprefix('watchdog.'): v for k, v in values.items()
              if k.startswith('watchdog.')}
        try:
            new = self.config.replace(law) if law else self.config
            dog = replace(self.watchdog, wd) if wd else self.watchdog
        except ParamError as exc:
            return exc.lines[0]
        if dog.cross_checks():
            return dog.cross_checks()[0]
        self.watchdog = dog
        if law:
            self.config = new
            self._pending = new
        return None

    # ---- updates -------------------------------------------------------------------------

    def _running(self) -> bool:
        return self.active and self.mode_state == 'running'

    def _required(self) -> tuple[str, ...]:
        flow = self.config.controller.flow_signal
        if self._needs_reset:
            # A bumpless (re)start needs the whole operating point: always what the mode the
            # update will run in feeds back, the rest where some node publishes it (a user's
            # FMU may have no pressures; an excitation feeds back nothing).
            fed = {'flow': (flow,), 'margin': ('line_pressure', 'load_pressure')}.get(
                self.config.controller.mode, ())
            return tuple(t for t in (flow, 'line_pressure', 'load_pressure')
                         if t in fed or self._published(t))
        mode = self.ctrl.mode
        if mode == 'flow':
            return (flow,)
        if mode == 'margin':
            return ('line_pressure', 'load_pressure')
        return ()

    def _fresh(self, topic: str, due: int) -> bool:
        """Has ``topic`` delivered its sample of the instant ``due``?"""
        if topic in self._stamp:
            return self._stamp[topic] >= due
        src = self._src.get(topic)
        return src is not None and self.time.after(due, src)

    def _maybe_update(self) -> Output | None:
        due = self._due
        if due is None or not self._running():
            return None
        fresh = all(self._fresh(t, due) for t in self._required())
        if not fresh and self._needs_reset and not all(t in self._meas
                                                       for t in self._required()):
            return None  # a (re)start needs the whole operating point, never a guess
        if not fresh and self._clock() - self._due_wall < self.STALE_WAIT:
            return None
        if not fresh:
            self.counts['stale_updates'] += 1
        self._due = None
        dt = (due - self._t_prev) * 1e-9 if self._t_prev is not None else self.config.period
        self._t_prev = due
        return self._update(due, dt)

    def _update(self, stamp_ns: int, dt: float) -> Output:
        if self._pending is not None:
            new, self._pending = self._pending, None
            if new.controller.algorithm != self.ctrl.config.controller.algorithm:
                # Another law: built afresh and started from the present command (bumpless
                # transfer), or from the measurements if a restart is due anyway.
                old, last, refs = self.ctrl.config, self.ctrl.command, self.ctrl.references
                self.ctrl = make_controller(new)
                for mode, value in refs.items():  # those this change leaves as they were
                    if getattr(new.reference, mode) == getattr(old.reference, mode):
                        self.ctrl.set_reference(value, mode)
                if not self._needs_reset:
                    self.ctrl.reset(last, dict(self._meas))
                self._log('info', f'switched to {new.controller.algorithm}')
            else:
                try:
                    self.ctrl.set_config(new)
                except (ParamError, ValueError) as exc:
                    self._log('error', f'parameter change not applied: {exc}')
        if self._needs_reset:
            # From the samples of this instant only: a current left from before a reset (the
            # simulator publishes it once the command of the instant is in) is not the
            # present one, and the law then starts from the measured flow (eq. 11).
            meas = {k: v for k, v in self._meas.items()
                    if k != 'solenoid_current' or not self.time.present
                    or self._fresh(k, stamp_ns)}
            self.ctrl.reset(None, meas)
            self._needs_reset = False
        try:
            u = self.ctrl.update(stamp_ns * 1e-9, dt, self._meas)
        except (ArithmeticError, ValueError) as exc:
            # Never crash the loop: say so, command the safe current and restart bumplessly.
            self.counts['control_errors'] += 1
            self._warn('law', f'control law failed ({type(exc).__name__}: {exc}); safe '
                              'current, restarting', 'error')
            u = self.config.limits.safe_current
            self._needs_reset = True
        self.counts['updates'] += 1
        return Output(stamp_ns, float(u), self.ctrl.state())

    def _state(self, command: float) -> dict[str, Any]:
        st = dict(self.ctrl.state())
        st['command'] = command
        return st

    def never_measured(self) -> bool:
        """No measurement has ever come, for longer than ``watchdog.safe_timeout``: no
        simulator or sensor in the graph (a wrong namespace, a missing node). The watchdog
        cannot say so (it times the age of the last measurement), nor can ``updates: 0``."""
        return self._first_rx is None and (
            self._listening is None  # already said
            or self._clock() - self._listening > self.watchdog.safe_timeout)

    def status(self) -> tuple[str, str]:
        """``(level, message)`` of ``/diagnostics``: ``ok`` or ``warn``."""
        if self.never_measured():
            return 'warn', 'no measurement received yet'
        message = {'running': 'ok', 'hold': 'measurements stale: holding',
                   'safe': 'measurements lost: safe current'}[self.mode_state]
        bad = (self.mode_state != 'running' or self.counts['rejected_nan']
               or self.counts['rejected_range'])
        return ('warn' if bad else 'ok'), message

    def diagnostics(self) -> dict[str, Any]:
        """A snapshot for ``/diagnostics``."""
        age = self._age() if self._last_rx is not None else math.nan
        state = self.ctrl.state()
        return {'active': self.active, 'watchdog': self.mode_state,
                'measurements_received': self._first_rx is not None,
                'measurement_age_s': age, 'clock': 'simulation' if self.time.present
                else 'wall', **self.counts,
                **{k: state.get(k) for k in ('mode', 'algorithm', 'reference', 'command',
                                             'fault')}}

