"""What every controller shares: modes, references, command limits, measurement checks,
open-loop excitation and the node-facing API.

The API is shaped for a thin ROS 2 node, as control_toolbox's ``Pid`` is for ros2_controllers:

- ``update(t, dt, meas)`` returns the absolute solenoid current [A]; ``dt`` is the measured
  period (ros2_control's ``update(time, period)``); ``meas`` maps signal names to SI values;
- ``set_mode``, ``set_reference`` and ``set_config`` apply at the next update without a bump;
- ``reset`` restarts from a steady state at a given current;
- ``state()`` is a flat dictionary for a ``~/state`` topic.

Measurements (SI, as the simulator publishes them): ``line_flow``, ``pump_flow``, ``load_flow``
[m^3/s]; ``line_pressure``, ``load_pressure``, ``ls_pressure``, ``actuator_pressure`` [Pa];
``solenoid_current`` [A]. Only the pressure difference ``line_pressure - load_pressure`` is
used, so the pressures may be gauge or absolute as long as both are the same kind; in a
load-sensing circuit the load-sensing pressure ``ls_pressure`` (the highest load) takes the
place of ``load_pressure``. A missing or non-finite value is
skipped (the embedded model predicts through it); when the signals the mode needs stay invalid
for ``limits.measurement_timeout`` the command ramps to ``limits.safe_current``.
"""

from __future__ import annotations

from collections.abc import Mapping
import math
from typing import Any

from hydropump_sim.measure import LS_PRESSURE_SIGNAL, SIGNALS
from hydropump_sim.params import ParamError

from .embedded import PumpModel
from .excitation import ExcitationSignal
from .schema import ControllerConfig, MODES, specs

MEASUREMENTS = {**{name: info.unit for name, info in SIGNALS.items() if info.bench},
                LS_PRESSURE_SIGNAL: 'Pa'}


def sensed_load(meas: Mapping[str, float]) -> Mapping[str, float]:
    """The measurements with the load-sensing pressure as the load pressure wherever a
    circuit has one: margin mode then regulates ``P_l - P_LS``, the highest load's."""
    if finite_value(meas, LS_PRESSURE_SIGNAL) is None:
        return meas
    return {**meas, 'load_pressure': meas[LS_PRESSURE_SIGNAL]}


def finite_value(meas: Mapping[str, float] | None, name: str) -> float | None:
    """A finite measurement or ``None``."""
    if not meas:
        return None
    v = meas.get(name)
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


class Controller:
    """Base class of the controllers (modes, limits, excitation, bumpless switching).

    Subclasses implement ``_reset``, ``_observe``, ``_law``, ``_applied``, ``_on_mode``,
    ``_configure`` and ``_state``.

    Parameters
    ----------
    config : ControllerConfig
        Validated configuration (:func:`hydropump_ctrl.control.schema.load_config`).
    """

    algorithm = ''

    def __init__(self, config: ControllerConfig):
        self._cfg = config
        self._pump = PumpModel.from_config(config.model)
        self.mode = config.controller.mode
        self._refs = {'flow': config.reference.flow, 'margin': config.reference.margin}
        self._excitation = ExcitationSignal(config.excitation, self._pump)
        self._configure(config)
        self.reset()

    # --- configuration ---------------------------------------------------------------------

    @property
    def config(self) -> ControllerConfig:
        return self._cfg

    def set_config(self, config: ControllerConfig | Mapping[str, Any]) -> None:
        """Apply new parameters at the next update, without a bump.

        ``config`` is a full :class:`ControllerConfig` or a mapping of dotted names to values
        (validated against the current configuration). Read-only parameters may not change.

        Raises
        ------
        ParamError
            One line per refused value.
        """
        new = self._cfg.replace(config) if isinstance(config, Mapping) else config
        old_flat, new_flat = self._cfg.flat(), new.flat()
        sp = specs()
        bad = [f'{k} is read-only while the controller runs (it fixes the embedded model)'
               for k, v in new_flat.items() if v != old_flat[k] and not sp[k].live]
        if new.controller.algorithm != self._cfg.controller.algorithm:
            bad.append(f'controller.algorithm = {new.controller.algorithm}: this object is the '
                       f'{self.algorithm} law; make_controller builds the other one')
        if bad:
            raise ParamError(bad)
        self._cfg = new
        if new.excitation != self._excitation.cfg:
            # A new experiment starts at the next update.
            self._t_mode = None
        self._configure(new)
        if new.reference.flow != old_flat['reference.flow']:
            self.set_reference(new.reference.flow, 'flow')
        if new.reference.margin != old_flat['reference.margin']:
            self.set_reference(new.reference.margin, 'margin')
        if new.controller.mode != self.mode:
            self.set_mode(new.controller.mode)

    # --- mode and reference ----------------------------------------------------------------

    def set_mode(self, mode: str, hold: bool = False) -> None:
        """Switch to ``flow``, ``margin`` or ``open_loop`` at the next update, without a bump.

        With ``hold`` the new mode's reference becomes the present estimate of its controlled
        variable (flow or margin), so nothing moves at the switch.
        """
        if mode not in MODES:
            raise ValueError(f'unknown mode {mode!r}: choose one of {", ".join(MODES)}')
        if hold and mode in self._refs:
            est = self._estimate(mode)
            if est is not None:
                self._refs[mode] = est
        old, self.mode = self.mode, mode
        self._t_mode = None
        if mode != old:
            self._on_mode(old, mode)

    def set_reference(self, value: float, mode: str | None = None) -> None:
        """Set the reference of ``mode`` (default: the current mode) in SI units.

        Flow [m^3/s] or margin ``P_l - P_u`` [Pa]. The reference generator shapes the change,
        so a step in the reference gives a smooth, feasible transition.
        """
        mode = self.mode if mode is None else mode
        if mode not in self._refs:
            raise ValueError(f'mode {mode!r} has no reference (flow or margin)')
        name = f'reference.{mode}'
        err = None
        try:
            self._cfg.replace({name: value})
        except ParamError as exc:
            err = exc.lines[0]
        if err:
            raise ValueError(err)
        self._refs[mode] = float(value)

    @property
    def references(self) -> dict[str, float]:
        """The reference of each mode (SI): ``flow`` and ``margin``."""
        return dict(self._refs)

    @property
    def reference(self) -> float | None:
        """Reference of the current mode (SI), ``None`` in open loop."""
        return self._refs.get(self.mode)

    # --- the update cycle ------------------------------------------------------------------

    def reset(self, current: float | None = None, meas: Mapping[str, float] | None = None
              ) -> None:
        """Restart from a steady state at the absolute current ``current`` [A] (bumpless).

        ``meas`` (optional) gives the measurements at that steady state, which initialise the
        estimates; without it the embedded model's static map is used. Without ``current``
        the steady state's current comes from ``meas``: the applied ``solenoid_current``, or
        else eq. 11 of the embedded model inverted on the measured flow; with neither it is
        ``limits.safe_current``.
        """
        lim = self._cfg.limits
        if current is None:
            current = finite_value(meas, 'solenoid_current')
        if current is None:
            q = finite_value(meas, self._cfg.controller.flow_signal)
            current = lim.safe_current if q is None else self._pump.current(q)
        u = min(max(float(current), lim.current_min), lim.current_max)
        self._command = u
        self._desired = u
        self._t_last = None
        self._t_valid = None
        self._t_mode = None
        self._fault = False
        self._reset(u, sensed_load(meas or {}))

    def update(self, t: float, dt: float, meas: Mapping[str, float]) -> float:
        """One controller step: read ``meas`` (SI), return the absolute current command [A].

        Parameters
        ----------
        t : float
            Time of the measurements [s] (simulation time under ``use_sim_time``).
        dt : float
            Measured period since the previous update [s]; a non-positive or non-finite
            period leaves everything unchanged and returns the previous command.
        meas : Mapping[str, float]
            Measurements by name (see the module docstring).
        """
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
            return self._command
        meas = sensed_load(meas)
        t = float(t)
        self._t_last = t
        self._observe(dt, meas)
        if self._required_valid(meas) or self._t_valid is None:
            # The timeout counts from the last valid sample, or from the first update.
            self._t_valid = t
        lim = self._cfg.limits
        timed_out = (self.mode != 'open_loop' and (
            self._t_valid is None or t - self._t_valid > lim.measurement_timeout))
        self._fault = timed_out
        if self.mode == 'open_loop':
            if self._t_mode is None:
                self._t_mode = t
                # The experiment starts now, around the present command if it is relative.
                self._excitation = ExcitationSignal(self._cfg.excitation, self._pump,
                                                    self._command)
            desired = float(self._excitation(t - self._t_mode))
        elif timed_out:
            desired = lim.safe_current
        else:
            desired = self._law(dt)
        u = min(max(desired, lim.current_min), lim.current_max)
        step = lim.rate_limit * dt
        u = min(max(u, self._command - step), self._command + step)
        self._desired = desired
        self._command = u
        self._applied(u, desired, dt)
        return u

    def _required_valid(self, meas: Mapping[str, float]) -> bool:
        if self.mode == 'flow':
            return finite_value(meas, self._cfg.controller.flow_signal) is not None
        if self.mode == 'margin':
            return (finite_value(meas, 'line_pressure') is not None
                    and finite_value(meas, 'load_pressure') is not None)
        return True

    @property
    def command(self) -> float:
        """The last applied command (absolute current) [A]."""
        return self._command

    def state(self) -> dict[str, float | str | bool]:
        """Flat dictionary for a ``~/state`` topic (SI units).

        Keys: ``mode``, ``algorithm``, ``t`` [s], ``reference`` (of the mode; NaN in open
        loop), ``command`` and ``command_desired`` [A], ``saturated`` and ``fault`` (bool),
        plus the algorithm's estimates (see the subclass).
        """
        ref = self.reference
        out = {'algorithm': self.algorithm, 'mode': self.mode,
               't': math.nan if self._t_last is None else self._t_last,
               'reference': math.nan if ref is None else ref,
               'command': self._command, 'command_desired': self._desired,
               'saturated': abs(self._desired - self._command) > 1e-12,
               'fault': self._fault}
        out.update(self._state())
        return out

    # --- subclass hooks --------------------------------------------------------------------

    def _estimate(self, mode: str) -> float | None:
        """Present estimate of the controlled variable of ``mode`` (for ``hold``)."""
        return None

    def _configure(self, cfg: ControllerConfig) -> None:
        raise NotImplementedError

    def _reset(self, current: float, meas: Mapping[str, float]) -> None:
        raise NotImplementedError

    def _observe(self, dt: float, meas: Mapping[str, float]) -> None:
        raise NotImplementedError

    def _law(self, dt: float) -> float:
        raise NotImplementedError

    def _applied(self, u: float, desired: float, dt: float) -> None:
        raise NotImplementedError

    def _on_mode(self, old: str, new: str) -> None:
        raise NotImplementedError

    def _state(self) -> dict:
        return {}
