"""The ``controller`` lifecycle node: EMC or PI of ``hydropump_ctrl.control`` in the loop.

The logic is :class:`hydropump_ctrl.control.supervisor.Supervisor` (pure): the measurement
gate, the rule of time (updates at the control instants of simulation time wherever a
``/clock`` is present, on a steady timer otherwise), the watchdogs, the bumpless (re)starts
and the live parameters. This node declares the parameters, subscribes, and publishes what
the supervisor returns:

- ``solenoid_current_cmd`` (``std_msgs/Float64``, A), only while active;
- ``~/state`` (``sensor_msgs/JointState`` used as a stamped named vector: reference,
  estimate, disturbance estimate, command; the mode in ``header.frame_id``), stamped with the
  simulation time of the update;
- ``/diagnostics``;
- ``events``: each engagement of the safe current (the watchdog, or a control law that
  failed) as one event, stamped with the simulation time it happened at, so that a bag
  recorded meanwhile says so.

``~/reference`` (``std_msgs/Float64``, SI) sets the reference of the present mode; gains,
mode and references are live parameters. ``autostart`` configures and activates at start-up.
"""

from __future__ import annotations

import math
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import Node as LifecycleNode
from rclpy.lifecycle import State, TransitionCallbackReturn
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64

from hydropump_ctrl.control.embedded import PumpModel
from hydropump_ctrl.control.excitation import ExcitationSignal
from hydropump_ctrl.control.schema import ControllerConfig
from hydropump_ctrl.control.supervisor import ControllerNodeConfig, STATE_KEYS, Supervisor
from hydropump_sim.params import default_params_path
from hydropump_sim.schema import check_all, ParamError, read_params_file, specs_of

from . import bridge, entry
from .conversions import CLOCK, ClockWriter, EVENTS, EVENTS_QOS, SAFE_CURRENT, stamp, to_ns
from .conversions import event as event_message

# What the laws read: the flow signal (line_flow or pump_flow), the current (bumpless starts)
# and the two pressures of the margin. Every sample costs an executor callback, so nothing
# more is subscribed.
PRESSURE_TOPICS = ('line_pressure', 'load_pressure')


def all_specs():
    return specs_of(ControllerNodeConfig) + specs_of(ControllerConfig)


class ControllerNode(bridge.ExplainedParameters, LifecycleNode):
    """The control law in the loop: measurements in, current commands out (see the module)."""

    def __init__(self):
        super().__init__('controller')
        d = bridge.Declarer(self)
        node_cfg = d.declare(ControllerNodeConfig)
        if node_cfg is None:
            d.finish()
        path = node_cfg.config_file or str(default_params_path().with_name('controller.yaml'))
        try:
            values = read_params_file(path)
        except ParamError as exc:
            raise bridge.StartupError(exc.lines) from None
        d.errors += [f'{path}: {line}' for line in check_all(ControllerConfig, values)[1]
                     if 'unknown' in line]
        law = d.declare(ControllerConfig, values, source=path)
        d.finish()
        self.schema_specs = d.specs
        self.autostart = node_cfg.autostart
        self.sup = Supervisor(law, node_cfg.watchdog, log=self._log)
        # The measurements and /clock come in on an executor of their own (what a lock-step
        # exchange waits for); timers, services and parameters on the node's. The lock keeps
        # the supervisor's calls from the two threads whole.
        self._lock = threading.Lock()
        self._io = entry.SideExecutor(self)
        self.add_on_set_parameters_callback(
            lambda params: bridge.result(self._locked(self.sup.set_parameters,
                                                      {p.name: p.value for p in params})))
        self._entities: list = []
        self._io_entities: list = []
        # Not a lifecycle publisher: an engagement is told whatever the state.
        self._pub_events = self.create_publisher(DiagnosticArray, EVENTS, EVENTS_QOS)

    def _locked(self, fn, *args, **kw):
        with self._lock:
            return fn(*args, **kw)

    def _run(self, fn, *args, **kw) -> None:
        """A supervisor call under the lock; its output published."""
        with self._lock:
            errors = self.sup.counts['control_errors']
            out = fn(*args, **kw)
            self._publish(out)
            if out is not None and self.sup.counts['control_errors'] > errors:
                self._event(out, 'the control law failed: commanding the safe current '
                                 f'{out.command:g} A')

    def _check_watchdog(self) -> None:
        """The watchdog; its engagement of the safe current told on ``events``."""
        with self._lock:
            was = self.sup.mode_state
            out = self.sup.check_watchdog()
            self._publish(out)
            if out is not None and was != 'safe' and self.sup.mode_state == 'safe':
                wd = self.sup.watchdog
                clock = 'simulation' if wd.simulation_time else 'steady'
                self._event(out, f'no measurements for watchdog.safe_timeout = '
                                 f'{wd.safe_timeout:g} s ({clock} time): commanding the safe '
                                 f'current {out.command:g} A')

    def _event(self, out, text: str) -> None:
        ns = out.stamp_ns if out.stamp_ns is not None else self.get_clock().now().nanoseconds
        self._pub_events.publish(event_message(SAFE_CURRENT, ns, text, 'controller',
                                               command_A=out.command))

    def _log(self, level: str, text: str) -> None:
        entry.log(self.get_logger(), level, text)

    # ---- lifecycle -----------------------------------------------------------------------

    def on_configure(self, state: State) -> TransitionCallbackReturn:
        self.sup = Supervisor(self.sup.config, self.sup.watchdog, log=self._log,
                              published=lambda topic: self.count_publishers(topic) > 0)
        cfg = self.sup.config
        # Reliable keep-all: a lagging recorder holds a lock-step run back instead of losing
        # commands.
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_ALL)
        self._pub_cmd = self.create_lifecycle_publisher(Float64, 'solenoid_current_cmd', qos)
        self._pub_state = self.create_lifecycle_publisher(JointState, '~/state', qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The latest sample of each measurement is what an update needs.
        latest = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                            history=HistoryPolicy.KEEP_LAST)
        sub, sup = self._io.subscribe, self.sup
        for topic in (cfg.controller.flow_signal, 'solenoid_current'):
            self._io_entities.append(sub(Float64, topic, lambda m, info, t=topic: self._run(
                sup.measurement, t, m.data, source_ns=info['source_timestamp']), latest))
        for topic in PRESSURE_TOPICS:
            self._io_entities.append(sub(FluidPressure, topic, lambda m, t=topic: self._run(
                sup.measurement, t, m.fluid_pressure, stamp_ns=to_ns(m.header.stamp)),
                latest))
        writer = ClockWriter(self)
        self._io_entities.append(sub(ClockMsg, CLOCK, lambda m, info: self._run(
            sup.clock, to_ns(m.clock), info['source_timestamp'],
            info.get('publication_sequence_number'), writer.of(info['source_timestamp'])),
            QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)))
        self._entities.append(self.create_subscription(Float64, '~/reference',
                                                       self._on_reference, 10))
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        wall = Clock(clock_type=ClockType.SYSTEM_TIME)
        self._timers = [
            self.create_timer(cfg.period, lambda: self._run(
                sup.wall_tick, wall.now().nanoseconds, self.count_publishers(CLOCK)),
                clock=steady),
            self.create_timer(0.05, self._check_watchdog, clock=steady),
            self.create_timer(0.1, writer.refresh, clock=steady),
            self.create_timer(1.0, self._publish_diagnostics, clock=steady)]
        self.get_logger().info(f'configured: {cfg.controller.algorithm} in '
                               f'{cfg.controller.mode} mode at {cfg.controller.update_rate:g} Hz')
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: State) -> TransitionCallbackReturn:
        result = super().on_activate(state)
        self.get_logger().info('active: publishing solenoid_current_cmd')
        self._excitation_note()
        # Bumpless start from the measurements, at the first instant that has them all.
        self._run(self.sup.activate)
        return result

    def _excitation_note(self) -> None:
        """In open loop, say how long one pass of the excitation lasts and what follows:
        nothing else tells when a pass ends (a staircase that starts again steps back down
        to its first level, also with ``excitation.direction`` up)."""
        cfg = self.sup.config
        if cfg.controller.mode != 'open_loop':
            return
        x = cfg.excitation
        length = ExcitationSignal(x, PumpModel.from_config(cfg.model)).duration
        if math.isinf(length):
            self.get_logger().info(f'open loop: a {x.signal} from the first update on, no end')
            return
        then = ('starts again (excitation.repeat true)' if x.repeat
                else 'holds its last value (excitation.repeat false)')
        self.get_logger().info(f'open loop: one {x.signal} pass of {length:g} s from the first '
                               f'update, then it {then}')

    def on_deactivate(self, state: State) -> TransitionCallbackReturn:
        self._locked(self.sup.deactivate)
        return super().on_deactivate(state)

    def on_cleanup(self, state: State) -> TransitionCallbackReturn:
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: State) -> TransitionCallbackReturn:
        self._locked(self.sup.deactivate)
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self) -> None:
        for s in self._io_entities:
            self._io.unsubscribe(s)
        for s in self._entities:
            self.destroy_subscription(s)
        for t in getattr(self, '_timers', ()):
            self.destroy_timer(t)
        self._entities, self._io_entities, self._timers = [], [], []
        self.destroy_lifecycle_publisher(self._pub_cmd)
        self.destroy_lifecycle_publisher(self._pub_state)
        self.destroy_publisher(self._pub_diag)

    def close(self) -> None:
        """Stop commanding before the context goes."""
        self._locked(self.sup.deactivate)
        self._io.close()

    # ---- messages ------------------------------------------------------------------------

    def _on_reference(self, msg: Float64) -> None:
        reason = self._locked(self.sup.set_reference, msg.data)
        if reason:
            self.get_logger().warn(f'reference refused: {reason}')

    def _publish(self, out) -> None:
        if out is None or not self.sup.active:
            return
        self._pub_cmd.publish(Float64(data=out.command))
        st = out.state
        msg = JointState(name=list(STATE_KEYS),
                         position=[float(st.get(k, math.nan)) for k in STATE_KEYS])
        msg.header.stamp = stamp(out.stamp_ns) if out.stamp_ns is not None \
            else self.get_clock().now().to_msg()
        msg.header.frame_id = str(st.get('mode', ''))
        self._pub_state.publish(msg)

    def _publish_diagnostics(self) -> None:
        with self._lock:
            d = self.sup.diagnostics()
            level, message = self.sup.status()
        st = DiagnosticStatus(
            name='controller', hardware_id='hydropump',
            level=DiagnosticStatus.WARN if level == 'warn' else DiagnosticStatus.OK,
            message=message, values=[KeyValue(key=k, value=str(v)) for k, v in d.items()])
        self._pub_diag.publish(DiagnosticArray(status=[st]))


def _autostart(node: ControllerNode) -> None:
    if node.autostart:
        node.trigger_configure()
        node.trigger_activate()


def main(args=None) -> int:
    return entry.run(ControllerNode, prog='controller', doc=__doc__, specs=all_specs,
                     args=args, before_spin=_autostart)


if __name__ == '__main__':
    raise SystemExit(main())
