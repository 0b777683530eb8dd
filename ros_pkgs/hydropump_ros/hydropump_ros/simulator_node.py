"""The ``simulator`` node: the fine model in the loop.

It owns simulation time: a stepping thread advances :class:`hydropump_sim.Simulator` in fixed
increments, paced to a real-time factor or locked to the controller, and publishes every
measurement stamped with the simulation time of its step, then ``/clock``... in this order per
step:

1. ``/clock`` (the step's time);
2. the measurements of the step, ``joint_states`` last;
3. ``solenoid_current``: the current held from this step on (in lock-step, after the
   controller's command for the period has arrived).

Unstamped messages (``std_msgs/Float64``) therefore belong to the latest ``/clock`` published
before them, which is how the recorder times them.
"""

from __future__ import annotations

import math
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
import rclpy
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from hydropump_sim import Simulator
from hydropump_sim.model import OUTPUTS
from hydropump_sim.params import default_params_path, params_from_dict
from hydropump_sim.params import iter_specs as plant_specs
from hydropump_sim.scenario import load_scenario, ScenarioError
from hydropump_sim.schema import ParamError, ParamSpec
from hydropump_sim.sensors import (
    load_profile,
    profile_from_dict,
    sensor_specs,
    SensorBank,
    SIGNALS,
)
from hydropump_sim.simulate import IntegrationError

from . import bridge

Y = {name: i for i, name in enumerate(OUTPUTS)}

# Node parameters (the plant and sensor schemas come from hydropump_sim).
NODE_SPECS = [
    ParamSpec('params_file', str, 'path', 'plant params file; empty = config/pump.yaml',
              (None, None), None, False, False),
    ParamSpec('sensor_profile', str, 'path', 'sensor profile file (e.g. config/bench.yaml); '
              'empty = ideal sensors', (None, None), None, False, False),
    ParamSpec('scenario_file', str, 'path', 'schedule of load pressure, aperture and shaft '
              'speed in simulation time; empty = none', (None, None), None, False, False),
    ParamSpec('dt', float, 's', 'integration increment (inputs held over it)', (1e-5, 0.01),
              None, False, False),
    ParamSpec('publish_rate', float, 'Hz', 'measurement publish rate', (1.0, 10000.0), None,
              False, False),
    ParamSpec('real_time_factor', float, '-', 'pacing: simulated s per wall s; 0 = as fast as '
              'possible', (0.0, 1000.0), None, True, False),
    ParamSpec('lock_step', bool, '-', 'advance one control period per controller command',
              (None, None), None, False, False),
    ParamSpec('control_period', float, 's', 'lock-step period (the controller update period)',
              (1e-4, 1.0), None, False, False),
    ParamSpec('lock_step_timeout', float, 's', 'steady-clock wait for a command in lock-step '
              'before advancing anyway', (1e-3, 60.0), None, True, False),
    ParamSpec('command_timeout', float, 's', 'steady-clock age of the last command after which '
              'the safe current applies', (1e-3, 60.0), None, True, False),
    ParamSpec('safe_current', float, 'A', 'current applied when commands stop (default: 0 % '
              'displacement)', (0.0, 5.0), None, True, False),
    ParamSpec('initial_current', float, 'A', 'current of the initial equilibrium (default: '
              '50 % displacement)', (0.0, 5.0), None, False, False),
    ParamSpec('diagnostics_period', float, 's', 'period of /diagnostics (steady clock)',
              (0.1, 60.0), None, False, False),
    ParamSpec('start_paused', bool, '-', 'wait for ~/pause false before publishing t = 0, so '
              'that every peer is matched first', (None, None), None, False, False),
    ParamSpec('pause_at', float, 's', 'pause by itself once simulation time reaches this; 0 = '
              'never (experiments end at an exact instant)', (0.0, 1.0e6), None, True, False),
]

LIVE_INPUTS = {'line.P_u': 'load_pressure', 'line.xi_u': 'aperture', 'pump.f_p': 'shaft_speed'}
FLOW_TOPICS = {'pump_flow': 'Q_p', 'line_flow': 'q_l', 'load_flow': 'Q_load'}
PRESSURE_TOPICS = {'actuator_pressure': 'P_a', 'line_pressure': 'P_l', 'load_pressure': 'P_u'}



class SimulatorNode(Node):

    def __init__(self, **kwargs):
        super().__init__('simulator', **kwargs)
        self._lock = threading.Condition()
        self._configure()
        # Lock-step runs are for complete, repeatable records: keep-all makes a slow reliable
        # reader (the recorder) hold the simulation back instead of losing steps. Paced and
        # free runs keep the last second per topic, so a slow reader cannot slow them down.
        if self._cfg['lock_step']:
            qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                             history=HistoryPolicy.KEEP_ALL)
        else:
            qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                             history=HistoryPolicy.KEEP_LAST)
        self._pub_clock = self.create_publisher(Clock, '/clock', qos)
        self._pub_js = self.create_publisher(JointState, 'joint_states', qos)
        self._pub_p = {k: self.create_publisher(FluidPressure, k, qos) for k in PRESSURE_TOPICS}
        self._pub_f = {k: self.create_publisher(Float64, k, qos) for k in FLOW_TOPICS}
        self._pub_i = self.create_publisher(Float64, 'solenoid_current', qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', qos)
        self.create_subscription(Float64, 'solenoid_current_cmd', self._on_command, qos)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_service(SetBool, '~/pause', self._on_pause)
        self.add_pre_set_parameters_callback(self._explain_rejection)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(self._cfg['diagnostics_period'], self._publish_diagnostics,
                          clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self._stop = False
        self._thread = threading.Thread(target=self._run, name='stepper', daemon=True)
        self._thread.start()

    # ---- configuration -------------------------------------------------------------------

    def _configure(self) -> None:
        errors = []
        cfg, errs = bridge.declare(self, NODE_SPECS[:3], {s.name: '' for s in NODE_SPECS[:3]})
        errors += errs
        try:
            plant_file = cfg.get('params_file') or str(default_params_path())
            plant_defaults = bridge.file_defaults(plant_file)
            profile_file = cfg.get('sensor_profile')
            sensor_defaults = {s.name: 0.0 for s in sensor_specs()}
            seed = 0
            if profile_file:
                prof = load_profile(profile_file)
                for sig, spec in prof.sensors.items():
                    for f in ('delay', 'noise_std', 'quantum', 'filter_tau'):
                        sensor_defaults[f'sensors.{sig}.{f}'] = getattr(spec, f)
                seed = prof.seed
                plant_defaults.update(prof.plant_overrides or {})
        except ParamError as exc:
            raise bridge.StartupError(exc.lines) from None
        plant, errs = bridge.declare(self, list(plant_specs()), plant_defaults)
        errors += errs
        known = ([s.name for s in plant_specs()] + [s.name for s in NODE_SPECS]
                 + [s.name for s in sensor_specs()])
        errors += bridge.unknown_overrides(self, known)
        if errors:
            raise bridge.StartupError(errors)
        try:
            self.params = params_from_dict(plant, source=plant_file)
        except ParamError as exc:
            raise bridge.StartupError(exc.lines) from None
        lo, hi = self.params.current_range
        node_defaults = {'dt': 1e-3, 'publish_rate': 1000.0, 'real_time_factor': 1.0,
                         'lock_step': False, 'control_period': 0.005, 'lock_step_timeout': 1.0,
                         'command_timeout': 0.5, 'safe_current': lo,
                         'initial_current': self.params.I_nominal, 'diagnostics_period': 1.0,
                         'start_paused': False, 'pause_at': 0.0}
        more, errs = bridge.declare(self, NODE_SPECS[3:], node_defaults)
        cfg.update(more)
        errors += errs
        sensor_defaults['sensors.seed'] = seed
        sensors, errs = bridge.declare(self, sensor_specs(), sensor_defaults, live=False)
        errors += errs
        if errors:
            raise bridge.StartupError(errors)
        nested = {'sensors': {}}
        for name, v in sensors.items():
            if name == 'sensors.seed':
                continue
            _, sig, field = name.split('.')
            if v:
                nested['sensors'].setdefault(sig, {})[field] = v
        nested['sensors']['seed'] = sensors['sensors.seed']
        self.profile = profile_from_dict(nested)
        self._cfg = cfg
        self.scenario = None
        if cfg['scenario_file']:
            try:
                self.scenario = load_scenario(cfg['scenario_file']).inputs
            except ScenarioError as exc:
                raise bridge.StartupError(exc.lines) from None
        self._specs = {s.name: s for s in list(plant_specs()) + NODE_SPECS}
        dt = cfg['dt']
        self._publish_every = max(1, int(round(1.0 / (cfg['publish_rate'] * dt))))
        self._steps_per_period = max(1, int(round(cfg['control_period'] / dt)))
        self.sim = Simulator(self.params, dt=dt)
        self.sensors = SensorBank(self.profile, dt * self._publish_every)
        self._make_messages()
        self._y = self.sim.outputs()
        self._reset_state(initial=True)

    def _reset_state(self, initial: bool = False) -> None:
        """Back to the initial equilibrium (simulation time keeps running)."""
        self.sim.reset(self._cfg['initial_current'], keep_time=not initial)
        self.sensors.reset()
        self._current = self._cfg['initial_current']
        self._cmd_seq = 0
        self._cmd_used = 0
        self._last_cmd_wall = None
        self._watchdog = False
        if initial:
            self._paused = self._cfg['start_paused']
            self._failed = None
            self._stats = {'nan_commands': 0, 'clamped_commands': 0, 'lock_step_timeouts': 0,
                           'watchdog_trips': 0}
            self._periods = []

    # ---- callbacks (executor thread) -----------------------------------------------------

    def _on_command(self, msg: Float64) -> None:
        value = msg.data
        with self._lock:
            if not math.isfinite(value):
                self._stats['nan_commands'] += 1
                self.get_logger().warn(f'ignored non-finite current command {value!r}; holding '
                                       f'{self._current:.4g} A', throttle_duration_sec=1.0)
                return
            lo, hi = self.params.I_limits
            if not lo <= value <= hi:
                self._stats['clamped_commands'] += 1
                self.get_logger().warn(f'current command {value:.4g} A outside eq. 2 range '
                                       f'[{lo:.3g}, {hi:.3g}] A: clamped',
                                       throttle_duration_sec=1.0)
                value = min(max(value, lo), hi)
            self._current = value
            self._cmd_seq += 1
            self._last_cmd_wall = time.monotonic()
            if self._watchdog:
                self.get_logger().info('commands are back: watchdog released')
                self._watchdog = False
            self._lock.notify_all()

    def _on_reset(self, request, response):
        with self._lock:
            self._reset_state()
            self._failed = None
            self._lock.notify_all()
        response.success = True
        response.message = f'reset to the equilibrium at {self._cfg["initial_current"]:.4g} A'
        return response

    def _on_pause(self, request, response):
        with self._lock:
            self._paused = bool(request.data)
            self._lock.notify_all()
        response.success = True
        response.message = 'paused' if request.data else 'running'
        return response

    def _explain_rejection(self, params):
        # rclpy checks ranges before any callback and answers with its own reason; the log
        # gets the schema's line, with the unit and a unit hint.
        for p in params:
            s = self._specs.get(p.name)
            if s is not None and bridge.check_value(s, p.value)[1]:
                self.get_logger().warn(f'rejected: {bridge.check_value(s, p.value)[1]}')
        return params

    def _on_set_parameters(self, params):
        result = bridge.validate_live(self._specs, params)
        if not result.successful:
            return result
        with self._lock:
            for p in params:
                if p.name in LIVE_INPUTS:
                    self.sim.set_inputs(**{LIVE_INPUTS[p.name]: float(p.value)})
                elif p.name in self._cfg:
                    self._cfg[p.name] = p.value
        return result

    # ---- stepping thread -----------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # keep the node alive and say why stepping stopped
            if self._stop or not self.context.ok():
                return  # shutting down: publishers are gone
            self._failed = f'{type(exc).__name__}: {exc}'
            self.get_logger().error(f'stepping stopped: {self._failed}')

    def _loop(self) -> None:
        """Per step: inputs held from t_k (in lock-step, after the period's command), the
        applied current, pacing, one increment, then ``/clock`` and the measurements of
        t_k+1."""
        with self._lock:
            while self._paused and not self._stop:
                self._lock.wait(0.1)
        next_wall = time.monotonic()
        last_wall = None
        self._publish(self.sim.outputs())
        while not self._stop and rclpy.ok():
            with self._lock:
                pause_at = self._cfg['pause_at']
                if pause_at > 0.0 and self.sim.t >= pause_at - 0.5 * self.sim.dt \
                        and not self._paused_at_done(pause_at):
                    self._paused = True
                while (self._paused or self._failed) and not self._stop:
                    self._lock.wait(0.1)
                    next_wall = time.monotonic()
                if self._cfg['lock_step'] and self.sim.steps % self._steps_per_period == 0:
                    self._wait_for_command()
                self._apply_inputs()
            self._publish_current()
            rtf = self._cfg['real_time_factor']
            if rtf > 0.0 and not self._cfg['lock_step']:
                next_wall += self.sim.dt / rtf
                delay = next_wall - time.monotonic()
                if delay > 0.0:
                    time.sleep(delay)
                elif delay < -0.1:
                    next_wall = time.monotonic()  # too far behind: do not try to catch up
            now = time.monotonic()
            if last_wall is not None:
                self._periods.append(now - last_wall)
                if len(self._periods) > 5000:
                    del self._periods[:2500]
            last_wall = now
            try:
                self.sim.step()
            except IntegrationError as exc:
                with self._lock:
                    self._failed = str(exc)
                self.get_logger().error(f'{exc}; call ~/reset to restart')
                continue
            if self.sim.steps % self._publish_every == 0:
                self._publish(self.sim.outputs())

    def _paused_at_done(self, pause_at: float) -> bool:
        """Pause once per ``pause_at`` value: resuming at that instant must not pause again."""
        done = getattr(self, '_pause_done', None) == pause_at
        self._pause_done = pause_at
        return done

    def _wait_for_command(self) -> None:
        """Lock-step: wait (steady clock) for a command newer than the last one used."""
        deadline = time.monotonic() + self._cfg['lock_step_timeout']
        while self._cmd_seq <= self._cmd_used and not self._stop:
            left = deadline - time.monotonic()
            if left <= 0.0:
                self._stats['lock_step_timeouts'] += 1
                self.get_logger().warn('lock-step: no command within lock_step_timeout; '
                                       'advancing with the held current',
                                       throttle_duration_sec=5.0)
                break
            self._lock.wait(left)
        self._cmd_used = self._cmd_seq

    def _apply_inputs(self) -> None:
        """Held current (with the command watchdog) and the scheduled disturbances."""
        current = self._current
        if (self._last_cmd_wall is not None and not self._cfg['lock_step']
                and time.monotonic() - self._last_cmd_wall > self._cfg['command_timeout']):
            if not self._watchdog:
                self._watchdog = True
                self._stats['watchdog_trips'] += 1
                self.get_logger().warn(
                    f'no current command for {self._cfg["command_timeout"]:g} s: applying the '
                    f'safe current {self._cfg["safe_current"]:.4g} A')
            current = self._cfg['safe_current']
        self.sim.set_inputs(current=current)
        if self.scenario:
            self.sim.set_inputs(**{name: float(sig(self.sim.t)) for name, sig in
                                   self.scenario.items() if name != 'current'})

    # ---- publishing (stepping thread) ----------------------------------------------------

    def _make_messages(self) -> None:
        """Message objects reused every step (building them is most of a step's cost)."""
        self._m_clock = Clock()
        self._m_float = Float64()
        self._m_p = {k: FluidPressure(variance=self.profile.spec(k).noise_std ** 2)
                     for k in PRESSURE_TOPICS}
        self._m_js = JointState(name=['spool', 'swash_plate_actuator'])
        # Signals with an active sensor model go through it; the others pass unchanged.
        self._sensed = {sig for sig in SIGNALS if self.profile.spec(sig).active}

    def _measure(self, name: str, value: float) -> float:
        if name in self._sensed:
            return self.sensors.channels[name].update(value)
        return value

    def _publish(self, y: np.ndarray) -> None:
        ns = int(round(self.sim.t * 1e9))
        clock = self._m_clock
        bridge.set_stamp(clock.clock, ns)
        self._pub_clock.publish(clock)
        f = self._m_float
        for topic, out in FLOW_TOPICS.items():
            f.data = float(self._measure(topic, y[Y[out]]))
            self._pub_f[topic].publish(f)
        p_atm = self.params.fluid.p_atm
        gauge = {'actuator_pressure': y[Y['P_a']], 'line_pressure': y[Y['P_l']],
                 'load_pressure': self.sim.u[1]}
        for topic, msg in self._m_p.items():
            bridge.set_stamp(msg.header.stamp, ns)
            msg.fluid_pressure = float(self._measure(topic, gauge[topic]) + p_atm)
            self._pub_p[topic].publish(msg)
        js = self._m_js
        bridge.set_stamp(js.header.stamp, ns)
        js.position = [float(self._measure('spool_position', y[Y['x_c']])),
                       float(self._measure('actuator_position', y[Y['x_a']]))]
        js.velocity = [float(y[Y['v_c']]), float(y[Y['v_a']])]
        js.effort = [float(self.params.spool.phi_s * (y[Y['I_s']] - self.params.I_nominal)),
                     float(y[Y['P_a']] * self.params.actuator.S_a)]
        self._pub_js.publish(js)
        self._y = y

    def _publish_current(self) -> None:
        """Applied current held from this step on (dither and sensor model included)."""
        if self.sim.steps % self._publish_every:
            return
        f = self._m_float
        f.data = float(self._measure('solenoid_current',
                                     self.params.I_nominal + float(self.sim.u[0])
                                     if not self.params.input.dither_amp
                                     else float(self.sim.outputs()[Y['I_s']])))
        self._pub_i.publish(f)

    def _limit_flags(self) -> dict:
        y, p = self._y, self.params
        return {
            'spool_at_stop': bool(abs(y[Y['x_c']]) >= p.spool.x_c_max),
            'plate_at_stop': bool(abs(y[Y['x_a']]) >= p.x_a_stop),
            'relief_open': bool(y[Y['Q_relief']] > 0.0),
            'pressure_floor_active': bool(min(y[Y['P_a']], y[Y['P_l']]) + p.fluid.p_atm
                                          < p.fluid.dp_floor),
        }

    # ---- diagnostics (executor thread) ---------------------------------------------------

    def _publish_diagnostics(self) -> None:
        with self._lock:
            stats = dict(self._stats)
            flags = self._limit_flags()
            periods = np.array(self._periods[-2000:])
            age = (time.monotonic() - self._last_cmd_wall) if self._last_cmd_wall else math.nan
            failed, watchdog, paused = self._failed, self._watchdog, self._paused
        steps, rejected = (int(v) for v in self.sim.stats)
        achieved = (self.sim.dt / float(np.mean(periods))) if periods.size else math.nan
        rtf = self._cfg['real_time_factor']
        p99 = (float(np.percentile(np.abs(periods - self.sim.dt / rtf), 99))
               if periods.size and rtf > 0 and not self._cfg['lock_step'] else math.nan)

        def kv(d):
            return [KeyValue(key=k, value=str(v)) for k, v in d.items()]

        plant = DiagnosticStatus(name='simulator: plant', hardware_id='hydropump')
        plant.level = DiagnosticStatus.WARN if any(flags.values()) else DiagnosticStatus.OK
        plant.message = ', '.join(k for k, v in flags.items() if v) or 'inside all limits'
        plant.values = kv(flags)
        integ = DiagnosticStatus(name='simulator: integrator', hardware_id='hydropump')
        integ.level = DiagnosticStatus.ERROR if failed else DiagnosticStatus.OK
        integ.message = failed or ('paused' if paused else 'running')
        integ.values = kv({'sim_time_s': f'{self.sim.t:.6f}', 'accepted_steps': steps,
                           'rejected_steps': rejected, 'achieved_real_time_factor':
                           f'{achieved:.3f}', 'step_period_error_p99_s': f'{p99:.6f}',
                           'lock_step': self._cfg['lock_step']})
        cmd = DiagnosticStatus(name='simulator: command', hardware_id='hydropump')
        bad = stats['nan_commands'] or stats['clamped_commands'] or watchdog
        cmd.level = DiagnosticStatus.WARN if bad else DiagnosticStatus.OK
        cmd.message = ('watchdog: safe current applied' if watchdog else
                       'bad commands received' if bad else 'ok')
        cmd.values = kv({'command_age_s': f'{age:.4f}', 'applied_current_A':
                         f'{self._current:.6f}', 'watchdog_active': watchdog, **stats})
        arr = DiagnosticArray(status=[plant, integ, cmd])
        arr.header.stamp = bridge.stamp(self.sim.t)
        self._pub_diag.publish(arr)

    def shutdown(self) -> None:
        self._stop = True
        with self._lock:
            self._lock.notify_all()
        self._thread.join(timeout=2.0)


def main(args=None) -> int:
    if not bridge.init_or_exit(args):
        return 2
    # Two threads share the GIL: hand it over sooner, so a command taken by the executor
    # reaches the stepping thread without waiting out the 5 ms default interval.
    sys.setswitchinterval(2.0e-4)
    node = bridge.build_or_exit(SimulatorNode)
    if node is None:
        return 2
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
