"""The PI baseline, with the vocabulary and semantics of control_toolbox's ``Pid`` (the law
behind ros2_controllers' ``pid_controller``).

Per mode one gain group (``pi.flow`` on the flow error in m^3/s, ``pi.margin`` on the margin
error in Pa), each with ``p``, ``i``, ``d``, ``i_clamp_max/min``, ``u_clamp_max/min``,
``feedforward_gain``, ``antiwindup_strategy`` (``none``, ``back_calculation``,
``conditional_integration``), ``tracking_time_constant`` (0 = ``p/i``, control_toolbox's
default without a ``d``) and ``error_deadband``. The command is

    u = u_ff + p e + I + d de/dt,    clamped to [u_clamp_min, u_clamp_max],

then the shared current range and rate limit. ``I`` integrates after the command is known, as
in ``Pid::compute_command``, and always within ``[i_clamp_min, i_clamp_max]``:

- ``back_calculation``: ``I += dt (i e + (u_applied - u_unsat) / T_t)``;
- ``conditional_integration``: ``I`` is frozen while the command is limited and the error
  pushes further into the limit. control_toolbox tests the sign of ``error * command``, which
  presumes a command centred on zero; here the command is an absolute current with an offset,
  so the test uses the direction of the limit instead.

Both strategies see the applied command, so the rate limit and the current range count as
saturation too.

Feedforward: in flow mode, the eq. 11 static map of the reference (``u_ff`` is the current
whose steady flow is the reference, scaled by ``feedforward_gain`` about ``I_nominal``). In
margin mode the flow the load needs is unknown; the feedforward is the static map of the flow
measured when the mode was entered, and the integral term supplies the rest.

Reference model (an addition, documented in docs/control.md): the error is taken against the
reference passed through the expected response of the feedforward, a first order
(``reference_tau`` rising, ``reference_tau_down`` falling: eqs. 19 and 15) plus the measurement
delay ``reference_delay``. Without it feedforward and feedback both answer a flow step for the
55 ms before the measurement moves, and the PI overshoots by about 55 %.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
import math

from .base import Controller, finite_value
from .embedded import fed_share
from .schema import ControllerConfig

HOLD_FILTER = 0.05  # s, averaging of the measurement a mode switch with hold takes over


class Pid:
    """One control_toolbox-style PID term with anti-windup on the applied command.

    Parameters
    ----------
    gains : PiFlow or PiMargin
        A ``pi.*`` group of the configuration.
    """

    def __init__(self, gains):
        self.gains = gains
        self.i_term = 0.0
        self.e_last = None

    @property
    def tracking_time_constant(self) -> float:
        g = self.gains
        if g.tracking_time_constant > 0.0:
            return g.tracking_time_constant
        if g.d > 0.0 and g.i > 0.0:
            return math.sqrt(g.d / g.i)
        return g.p / g.i if g.i > 0.0 else math.inf

    def command(self, error: float, dt: float, u_ff: float) -> float:
        """Unsaturated command ``u_ff + p e + I + d de/dt`` [A] (before ``u_clamp``)."""
        g = self.gains
        de = 0.0 if self.e_last is None else (error - self.e_last) / dt
        self.e_last = error
        u = u_ff + g.p * error + self.i_term + g.d * de
        return u

    def clamp(self, u: float) -> float:
        return min(max(u, self.gains.u_clamp_min), self.gains.u_clamp_max)

    def integrate(self, error: float, dt: float, u_unsat: float, u_applied: float) -> None:
        """Advance the integral term after the command is applied (anti-windup)."""
        g = self.gains
        if abs(error) < g.error_deadband or g.i == 0.0:
            return
        strategy = g.antiwindup_strategy
        limited = abs(u_applied - u_unsat) > 1e-12
        if strategy == 'back_calculation':
            self.i_term += dt * (g.i * error + (u_applied - u_unsat)
                                 / self.tracking_time_constant)
        elif strategy == 'conditional_integration':
            if not (limited and error * (u_unsat - u_applied) > 0.0):
                self.i_term += dt * g.i * error
        else:
            self.i_term += dt * g.i * error
        self.i_term = min(max(self.i_term, g.i_clamp_min), g.i_clamp_max)

    def align(self, u_applied: float, error: float, u_ff: float) -> None:
        """Bumpless transfer: choose ``I`` so that the next command equals ``u_applied``."""
        g = self.gains
        self.i_term = min(max(u_applied - u_ff - g.p * error, g.i_clamp_min), g.i_clamp_max)
        self.e_last = error


class ReferenceModel:
    """First order plus delay applied to the reference (the expected measured response).

    The time constant is ``tau`` while the output rises and ``tau_down`` while it falls: the
    feedforward response of the pump is eq. 19 for growing flow and eq. 15 for falling flow.
    """

    def __init__(self, tau: float, tau_down: float, delay: float, T: float, value: float):
        self.tau = tau
        self.tau_down = tau_down
        self.n = int(round(delay / T))
        self.reset(value)

    def reset(self, value: float) -> None:
        self.x = value
        self.buf = deque([value] * (self.n + 1), maxlen=self.n + 1)

    def step(self, r: float, dt: float) -> float:
        """Advance by ``dt`` with the reference ``r`` held; return the delayed output."""
        tau = self.tau if r >= self.x else self.tau_down
        self.x = r if tau <= 0.0 else r + (self.x - r) * math.exp(-dt / tau)
        self.buf.appendleft(self.x)
        return self.buf[-1]

    @property
    def output(self) -> float:
        return self.buf[-1]


class PIController(Controller):
    """PI baseline with eq. 11 feedforward and anti-windup, in the same modes as EMC.

    Notes
    -----
    ``state()`` adds ``estimate`` (the measured flow [m^3/s] or margin [Pa]),
    ``error`` (against the reference model), ``reference_model``, ``disturbance`` (the
    integral term, A) and ``feedforward`` [A].
    """

    algorithm = 'pi'

    def _configure(self, cfg: ControllerConfig) -> None:
        old = getattr(self, '_pid', None)
        self._pid = {'flow': Pid(cfg.pi_flow), 'margin': Pid(cfg.pi_margin)}
        T = cfg.period
        self._refmodel = {
            mode: ReferenceModel(g.reference_tau, g.reference_tau_down, g.reference_delay, T,
                                 self._refs[mode])
            for mode, g in (('flow', cfg.pi_flow), ('margin', cfg.pi_margin))}
        if old is not None:
            # New gains: keep the command where it is (bumpless gain change).
            for mode, pid in self._pid.items():
                pid.i_term, pid.e_last = old[mode].i_term, old[mode].e_last
            self._align(self.mode)

    def _measured(self, mode: str) -> float | None:
        if mode == 'flow':
            return self._y_flow
        if self._p_l is None or self._p_u is None:
            return None
        return self._p_l - self._p_u

    def _feedforward(self, mode: str) -> float:
        pump = self._pump
        q = self._refs['flow'] if mode == 'flow' else self._q_entry
        gain = self._cfg.group(f'pi.{mode}').feedforward_gain
        return pump.current(pump.Q_bar + gain * (q - pump.Q_bar))

    def _align(self, mode: str) -> None:
        """Re-initialise the reference model and the integral term of ``mode``: no bump."""
        if mode not in self._pid:
            return
        # The reference model restarts from the averaged measurement: a raw sample would put
        # its noise into the error, and the P term would answer it at once.
        y = self._filtered.get(mode)
        if mode == 'margin':
            q = self._filtered.get('flow')
            self._q_entry = q if q is not None else self._pump.steady_flow(self._command)
        ref = self._refmodel[mode]
        ref.reset(y if y is not None else self._refs[mode])
        self._pid[mode].align(self._command, 0.0, self._feedforward(mode))

    def _reset(self, current: float, meas: Mapping[str, float]) -> None:
        self._y_flow = finite_value(meas, self._cfg.controller.flow_signal)
        self._p_l = finite_value(meas, 'line_pressure')
        self._p_u = finite_value(meas, 'load_pressure')
        self._filtered = {m: y for m in ('flow', 'margin')
                          if (y := self._measured(m)) is not None}
        self._q_entry = self._y_flow if self._y_flow is not None else \
            self._pump.steady_flow(current)
        self._error = 0.0
        self._u_unsat = current
        self._u_ff = current
        self._active = False
        self._realign = False
        for mode in self._pid:
            self._align(mode)

    def _observe(self, dt: float, meas: Mapping[str, float]) -> None:
        self._y_flow = finite_value(meas, self._cfg.controller.flow_signal)
        self._p_l = finite_value(meas, 'line_pressure')
        self._p_u = finite_value(meas, 'load_pressure')
        self._active = False
        # Averaged measurements (50 ms) for a hold at a mode switch: one raw sample would
        # carry its noise (0.5 % FS, 0.3 bar on the bench) into the new reference.
        a = 1.0 - math.exp(-dt / HOLD_FILTER)
        for mode in ('flow', 'margin'):
            y = self._measured(mode)
            if y is not None:
                f = self._filtered.get(mode)
                self._filtered[mode] = y if f is None else f + a * (y - f)

    def _law(self, dt: float) -> float:
        mode = self.mode
        if self._realign:
            # Back from a measurement fault: restart from the present command.
            self._align(mode)
            self._realign = False
        y = self._measured(mode)
        r_m = self._refmodel[mode].step(self._refs[mode], dt)
        u_ff = self._feedforward(mode)
        self._u_ff = u_ff
        if y is None:
            # No sample this period: hold the command, do not integrate.
            self._u_unsat = self._command
            return self._command
        pid = self._pid[mode]
        self._error = r_m - y
        # The anti-windup compares the applied command with this unclamped one, so u_clamp,
        # the current range and the rate limit all count as saturation.
        self._u_unsat = pid.command(self._error, dt, u_ff)
        self._active = True
        return pid.clamp(self._u_unsat)

    def _applied(self, u: float, desired: float, dt: float) -> None:
        if self._active:
            self._pid[self.mode].integrate(self._error * self._starving(), dt, self._u_unsat,
                                           u)
        if self._fault:
            self._realign = True

    def _starving(self) -> float:
        """The integral's gain schedule against compensated loads: below the compensators'
        setting they take only the share :func:`~.embedded.fed_share` of each extra flow
        (orifices, no more integrators), and the loop gain falls by it; the integral gains
        it back, so the pump climbs out of starvation, or to its full flow when the loads
        ask more than it gives, at the rate it regulates a fed margin."""
        if self.mode != 'margin' or self._cfg.model.load_law != 'compensated':
            return 1.0
        y = self._measured('margin')
        return 1.0 if y is None else 1.0 / fed_share(y, self._cfg.model.dp_compensator)

    def _on_mode(self, old: str, new: str) -> None:
        self._align(new)

    def _estimate(self, mode: str) -> float | None:
        return self._filtered.get(mode)

    def _state(self) -> dict:
        mode = self.mode if self.mode in self._pid else 'flow'
        y = self._measured(mode)
        return {'estimate': math.nan if y is None else y, 'error': self._error,
                'reference_model': self._refmodel[mode].output,
                'disturbance': self._pid[mode].i_term, 'feedforward': self._u_ff}
