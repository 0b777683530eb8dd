"""The ``controller`` lifecycle node: EMC or PI of ``hydropump_ctrl.control`` in the loop.

- No command before activation (lifecycle publishers); ``autostart`` configures and activates.
- On simulation time, an update runs at every control instant ``t_K`` (200 Hz by default) once
  the measurements of ``t_K`` are in: stamped ones carry ``t_K``, unstamped ones were published
  after ``/clock`` reached ``t_K`` (DDS source timestamps). So a lock-step run is repeatable
  whatever order the messages arrive in. On wall time, a timer runs it with the latest values.
- Gains, mode and references are live parameters, checked by the controller schema and
  applied at the next update without a bump; ``~/reference`` (``std_msgs/Float64``, SI) sets
  the reference of the present mode.
- Measurements that are not finite or not physical are rejected and counted.
- Watchdog on the steady clock: with no measurement for ``watchdog.hold_timeout`` the node
  stops updating (the simulator holds the last command); after ``watchdog.safe_timeout`` it
  commands ``limits.safe_current`` (zero displacement) until measurements come back.
- Publishes ``solenoid_current_cmd`` (A), ``~/state`` (``sensor_msgs/JointState`` used as a
  stamped named vector: reference, estimate, disturbance estimate, command; the mode in
  ``header.frame_id``) and ``/diagnostics``.
"""

from __future__ import annotations

import bisect
from collections import deque
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import rclpy
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64

from hydropump_ctrl.control import iter_specs, make_controller, validate_parameter
from hydropump_ctrl.control.schema import config_from_dict
from hydropump_sim.schema import ParamError, ParamSpec

from . import bridge

FLOAT_TOPICS = ('line_flow', 'pump_flow', 'load_flow', 'solenoid_current')
PRESSURE_TOPICS = ('line_pressure', 'load_pressure', 'actuator_pressure')
# Plausible ranges of the measurements (SI, absolute pressures); outside them a sample is
# rejected as a sensor fault.
PLAUSIBLE = {'line_flow': (-0.1, 0.1), 'pump_flow': (-0.1, 0.1), 'load_flow': (-0.1, 0.1),
             'solenoid_current': (0.0, 10.0), 'line_pressure': (0.0, 1.0e8),
             'load_pressure': (0.0, 1.0e8), 'actuator_pressure': (0.0, 1.0e8)}
STATE_KEYS = ('reference', 'estimate', 'disturbance', 'command', 'command_desired')

NODE_SPECS = [
    ParamSpec('config_file', str, 'path', 'controller params file; empty = '
              'config/controller.yaml', (None, None), None, False, False),
    ParamSpec('autostart', bool, '-', 'configure and activate at start-up', (None, None), None,
              False, False),
    ParamSpec('watchdog.hold_timeout', float, 's', 'steady-clock age of the measurements after '
              'which updates stop (the last command holds)', (0.01, 60.0), None, True, False),
    ParamSpec('watchdog.safe_timeout', float, 's', 'steady-clock age after which the safe '
              'current is commanded', (0.01, 600.0), None, True, False),
]


def _default_config_path() -> str:
    from hydropump_sim.params import default_params_path
    return str(default_params_path().with_name('controller.yaml'))


class ControllerNode(LifecycleNode):

    def __init__(self, **kwargs):
        super().__init__('controller', **kwargs)
        cfg, errors = bridge.declare(self, NODE_SPECS[:1], {'config_file': ''})
        path = cfg.get('config_file') or _default_config_path()
        try:
            defaults = bridge.file_defaults(path)
        except ParamError as exc:
            raise bridge.StartupError(exc.lines) from None
        self._specs = {s.name: s for s in iter_specs()}
        values, errs = bridge.declare(self, list(iter_specs()), defaults)
        errors += errs
        node_vals, errs = bridge.declare(self, NODE_SPECS[1:], {
            'autostart': False, 'watchdog.hold_timeout': 0.2, 'watchdog.safe_timeout': 1.0})
        errors += errs
        errors += bridge.unknown_overrides(self, list(self._specs) + [s.name for s in
                                                                       NODE_SPECS])
        if errors:
            raise bridge.StartupError(errors)
        try:
            self.config = config_from_dict(values, source=path)
        except ParamError as exc:
            raise bridge.StartupError(exc.lines) from None
        self.watchdog = {k: node_vals[k] for k in ('watchdog.hold_timeout',
                                                    'watchdog.safe_timeout')}
        self.sim_time = self.get_parameter('use_sim_time').value
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.ctrl = None
        self._active = False
        self._pending_config = None
        self.autostart = node_vals['autostart']

    # ---- lifecycle -----------------------------------------------------------------------

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        self.ctrl = make_controller(self.config)
        self._period_ns = int(round(self.config.period * 1e9))
        self._meas: dict[str, float] = {}
        self._stamp: dict[str, int] = {}       # stamped topics: header stamp [ns]
        self._src: dict[str, int] = {}         # unstamped topics: DDS source timestamp [ns]
        self._clocks: deque = deque(maxlen=4096)   # (clock ns, source ns)
        self._due: int | None = None
        self._due_wall = 0.0
        self._t_prev: int | None = None
        self._last_rx = None
        self._counts = {'updates': 0, 'rejected_nan': 0, 'rejected_range': 0,
                        'stale_updates': 0, 'watchdog_safe': 0, 'control_errors': 0}
        self._needs_reset = True
        self._mode_state = 'running'
        qos_cmd = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self._pub_cmd = self.create_lifecycle_publisher(Float64, 'solenoid_current_cmd', qos_cmd)
        self._pub_state = self.create_lifecycle_publisher(JointState, '~/state', qos_cmd)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The latest sample of each measurement is what an update needs.
        latest = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                            history=HistoryPolicy.KEEP_LAST)
        self._subs = []
        for topic in FLOAT_TOPICS:
            self._subs.append(self.create_subscription(
                Float64, topic, lambda m, info, t=topic: self._on_float(t, m, info), latest))
        for topic in PRESSURE_TOPICS:
            self._subs.append(self.create_subscription(
                FluidPressure, topic, lambda m, t=topic: self._on_pressure(t, m), latest))
        self._subs.append(self.create_subscription(Float64, '~/reference', self._on_reference,
                                                   10))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if self.sim_time:
            self._subs.append(self.create_subscription(
                ClockMsg, '/clock', self._on_clock,
                QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)))
            self._timer = None
        else:
            self._timer = self.create_timer(self.config.period, self._on_wall_timer, clock=steady)
        self._watch = self.create_timer(0.05, self._on_watchdog, clock=steady)
        self._diag_timer = self.create_timer(1.0, self._publish_diagnostics, clock=steady)
        self.get_logger().info(f'configured: {self.config.controller.algorithm} in '
                               f'{self.config.controller.mode} mode at '
                               f'{self.config.controller.update_rate:g} Hz')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        # Bumpless start from the applied current and the measurements, at the first update
        # that has them all (a controller started from guesses would first fight the plant).
        self._needs_reset = True
        self._t_prev = None
        self._active = True
        self.get_logger().info('active: publishing solenoid_current_cmd')
        result = super().on_activate(state)
        self._maybe_update()  # an instant that came due while inactive
        return result

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._active = False
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        self._active = False
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self) -> None:
        for sub in self._subs:
            self.destroy_subscription(sub)
        for timer in (self._timer, self._watch, self._diag_timer):
            if timer is not None:
                self.destroy_timer(timer)
        self.destroy_lifecycle_publisher(self._pub_cmd)
        self.destroy_lifecycle_publisher(self._pub_state)
        self.destroy_publisher(self._pub_diag)
        self.ctrl = None

    # ---- measurements --------------------------------------------------------------------

    def _accept(self, topic: str, value: float) -> bool:
        if not math.isfinite(value):
            self._counts['rejected_nan'] += 1
            self.get_logger().warn(f'rejected {topic} = {value!r}', throttle_duration_sec=2.0)
            return False
        lo, hi = PLAUSIBLE[topic]
        if not lo <= value <= hi:
            self._counts['rejected_range'] += 1
            self.get_logger().warn(f'rejected {topic} = {value:.6g}: outside [{lo:g}, {hi:g}]',
                                   throttle_duration_sec=2.0)
            return False
        return True

    def _on_float(self, topic: str, msg: Float64, info) -> None:
        self._last_rx = time.monotonic()
        if self._accept(topic, msg.data):
            self._meas[topic] = msg.data
        else:
            self._meas.pop(topic, None)
        self._src[topic] = info['source_timestamp']
        self._maybe_update()

    def _on_pressure(self, topic: str, msg: FluidPressure) -> None:
        self._last_rx = time.monotonic()
        if self._accept(topic, msg.fluid_pressure):
            self._meas[topic] = msg.fluid_pressure
        else:
            self._meas.pop(topic, None)
        self._stamp[topic] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._maybe_update()

    def _on_clock(self, msg: ClockMsg, info) -> None:
        ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        self._clocks.append((ns, info['source_timestamp']))
        if ns % self._period_ns == 0 and (self._t_prev is None or ns > self._t_prev):
            self._due = ns
            self._due_wall = time.monotonic()
        self._maybe_update()

    def _required(self) -> tuple[str, ...]:
        flow = self.config.controller.flow_signal
        if self._needs_reset:  # a bumpless (re)start needs the whole operating point
            return (flow, 'line_pressure', 'load_pressure')
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
        if src is None:
            return False
        i = bisect.bisect_left(self._clocks, (due, -1))
        return i < len(self._clocks) and self._clocks[i][0] == due and \
            src >= self._clocks[i][1]

    def _maybe_update(self) -> None:
        due = self._due
        if due is None or not self._active or self._mode_state != 'running':
            return
        fresh = all(self._fresh(t, due) for t in self._required())
        # On a free-running simulator a sample may never carry t_K exactly: after 20 ms of
        # waiting the update uses the latest values.
        if not fresh and time.monotonic() - self._due_wall < 0.02:
            return
        if not fresh:
            self._counts['stale_updates'] += 1
        self._due = None
        dt = (due - self._t_prev) * 1e-9 if self._t_prev is not None else self.config.period
        self._t_prev = due
        self._update(due * 1e-9, dt)

    def _on_wall_timer(self) -> None:
        if not self._active or self._mode_state != 'running':
            return
        now = time.monotonic()
        dt = now - self._t_wall if getattr(self, '_t_wall', None) else self.config.period
        self._t_wall = now
        self._update(now, dt)

    def _update(self, t: float, dt: float) -> None:
        if self._needs_reset:
            flow = self.config.controller.flow_signal
            current = self._meas.get('solenoid_current')
            if current is None:
                # The applied current of t_K comes after the command of t_K (lock-step): at
                # a steady start, eq. 11 inverted on the measured flow gives it.
                m = self.config.model
                q = self._meas.get(flow, m.Q_bar)
                current = m.I_nominal + (q - m.Q_bar) / m.gain
            self.ctrl.reset(current, dict(self._meas))
            self._needs_reset = False
        if self._pending_config is not None:
            try:
                self.ctrl.set_config(self._pending_config)
            except (ParamError, ValueError) as exc:
                self.get_logger().error(f'parameter change not applied: {exc}')
            self._pending_config = None
        try:
            u = self.ctrl.update(t, dt, self._meas)
        except (ArithmeticError, ValueError) as exc:
            # Never crash the loop: say so, command the safe current and restart bumplessly.
            self._counts['control_errors'] += 1
            self.get_logger().error(f'control law failed ({type(exc).__name__}: {exc}); '
                                    'safe current, restarting', throttle_duration_sec=1.0)
            u = self.config.limits.safe_current
            self._needs_reset = True
        self._pub_cmd.publish(Float64(data=float(u)))
        self._counts['updates'] += 1
        st = self.ctrl.state()
        msg = JointState(name=list(STATE_KEYS),
                         position=[float(st.get(k, math.nan)) for k in STATE_KEYS])
        msg.header.stamp = bridge.stamp(t)
        msg.header.frame_id = str(st.get('mode', ''))
        self._pub_state.publish(msg)

    # ---- reference, parameters, watchdog -------------------------------------------------

    def _on_reference(self, msg: Float64) -> None:
        if self.ctrl is None:
            return
        try:
            self.ctrl.set_reference(msg.data)
        except ValueError as exc:
            self.get_logger().warn(f'reference refused: {exc}')

    def _on_set_parameters(self, params):
        from rcl_interfaces.msg import SetParametersResult
        new = {}
        for p in params:
            if p.name in self._specs:
                reason = validate_parameter(self.config, p.name, p.value)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
                new[p.name] = p.value
            elif p.name.startswith('watchdog.'):
                self.watchdog[p.name] = p.value
        if new:
            try:
                self.config = self.config.replace(new)
            except ParamError as exc:
                return SetParametersResult(successful=False, reason=exc.lines[0])
            self._pending_config = self.config  # applied at the next update
        return SetParametersResult(successful=True)

    def _on_watchdog(self) -> None:
        if not self._active or self._last_rx is None:
            return
        age = time.monotonic() - self._last_rx
        if age > self.watchdog['watchdog.safe_timeout']:
            if self._mode_state != 'safe':
                self.get_logger().error(f'no measurements for {age:.2f} s: commanding the safe '
                                        f'current {self.config.limits.safe_current:g} A')
            self._mode_state = 'safe'
            self._counts['watchdog_safe'] += 1
            self._pub_cmd.publish(Float64(data=float(self.config.limits.safe_current)))
        elif age > self.watchdog['watchdog.hold_timeout']:
            if self._mode_state == 'running':
                self.get_logger().warn(f'measurements stale ({age:.2f} s): holding the command')
            self._mode_state = 'hold'
        elif self._mode_state != 'running':
            self.get_logger().info('measurements are back: resuming')
            self._needs_reset = True
            self._t_prev = None
            self._mode_state = 'running'

    def _publish_diagnostics(self) -> None:
        st = DiagnosticStatus(name='controller', hardware_id='hydropump')
        bad = self._mode_state != 'running' or self._counts['rejected_nan'] or \
            self._counts['rejected_range']
        st.level = DiagnosticStatus.WARN if bad else DiagnosticStatus.OK
        st.message = {'running': 'ok', 'hold': 'measurements stale: holding',
                      'safe': 'measurements lost: safe current'}[self._mode_state]
        age = (time.monotonic() - self._last_rx) if self._last_rx else math.nan
        state = self.ctrl.state() if self.ctrl else {}
        st.values = [KeyValue(key=k, value=str(v)) for k, v in {
            'active': self._active, 'watchdog': self._mode_state,
            'measurement_age_s': f'{age:.4f}', **self._counts,
            **{k: state.get(k) for k in ('mode', 'algorithm', 'reference', 'command',
                                         'fault')}}.items()]
        self._pub_diag.publish(DiagnosticArray(status=[st]))



def main(args=None) -> int:
    if not bridge.init_or_exit(args):
        return 2
    node = bridge.build_or_exit(ControllerNode)
    if node is None:
        return 2
    if node.autostart:
        node.trigger_configure()
        node.trigger_activate()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
