"""The ``simulator`` node: the fine model in the loop, over :class:`hydropump_sim.runner.Runner`.

The runner (pure) owns stepping, the command watchdog, the lock-step gate, pause-at and the
sensor models; this node declares the parameters, runs the runner in a thread and publishes.
Per step, in this order: ``/clock`` (the step's simulation time), the measurements stamped
with it (``joint_states`` last), then ``solenoid_current`` (the current held from this step
on; in lock-step after the controller's command for the period has arrived). An unstamped
message therefore belongs to the latest ``/clock`` published before it
(:mod:`hydropump_ctrl.timebase`). A lock-step instant that advanced without its command
(``lock_step_timeout``) and a trip of the command watchdog (the safe current applied) are
each an event on ``events``, stamped with the simulation time they happened at.
"""

from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock as RosClock
from rclpy.clock import ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from std_srvs.srv import SetBool, Trigger

from hydropump_ctrl.fmi.plant import FMU_LOADS, FMU_PARAMETERS, ros_name
from hydropump_sim import fixed_step
from hydropump_sim.circuit import default_circuit_path, load_circuit
from hydropump_sim.errors import HydropumpError
from hydropump_sim.measure import FLOW_SIGNALS, JOINTS, model_topics, PRESSURE_SIGNALS
from hydropump_sim.params import default_params_path, Params
from hydropump_sim.reduction import with_fidelity
from hydropump_sim.runner import LIVE_INPUTS, Runner, SimulatorConfig
from hydropump_sim.scenario import load_scenario, ScenarioError
from hydropump_sim.scenario import SIGNALS as SCENARIO_INPUTS
from hydropump_sim.schema import assignments, check_all, ParamError, read_params_file, specs_of
from hydropump_sim.sensors import load_profile, SensorConfig, SensorProfile
from hydropump_sim.simulate import Simulator

from . import bridge, entry
from .conversions import (
    absolute,
    CLOCK,
    EVENTS,
    EVENTS_QOS,
    LOCK_STEP_TIMEOUT,
    SAFE_CURRENT,
    seconds_to_ns,
    set_stamp,
    stamp,
)
from .conversions import event as event_message

# How long a new simulator looks for another publisher of its clock topic before its first
# step [s]: a simulator that refuses has published nothing. Discovery usually takes tenths of
# a second, but a lost announcement is repeated only with Fast DDS's 3 s lease announcement
# (seen on a loaded machine: 2.9 s; a look of exactly 3 s once missed it, and the refused
# simulator's writers then showed), so the look lasts longer than one such period. Two
# simulators started within it of each other both refuse; a later one refuses alone.
DISCOVERY_WINDOW = 3.5
# s it looks on once its own publishers exist (two simulators started together).
CONFIRM_WINDOW = 0.5
# The prefix of the circuit's operator inputs as live parameters (inputs.boom.command).
INPUTS = 'inputs.'
# s of steady clock between two mirrors of the command topics into their parameters.
MIRROR_PERIOD = 0.1
# The runner's events (its stats keys) as the suite's event kinds.
EVENT_KINDS = {'lock_step_timeouts': LOCK_STEP_TIMEOUT, 'watchdog_trips': SAFE_CURRENT}


def all_specs():
    return specs_of(SimulatorConfig) + specs_of(Params) + specs_of(SensorConfig)


class SimulatorNode(bridge.ExplainedParameters, Node):
    """The plant in the loop: parameters in, /clock and measurements out (see the module)."""

    def __init__(self):
        self._closing = False
        super().__init__('simulator')
        self._configure()
        # Lock-step runs are for complete, repeatable records: keep-all makes a slow reliable
        # reader (the recorder) hold the simulation back instead of losing steps. Paced and
        # free runs keep the last second per topic, so a slow reader cannot slow them down.
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_ALL if self.cfg.lock_step
                         else HistoryPolicy.KEEP_LAST)
        self._qos = qos
        # Its topics' publishers come once it knows it is alone in its namespace
        # (_advertise): a refused second simulator never shows a writer to the graph (a
        # controller or recorder would take a new /clock writer for a new simulator).
        readout = self.runner.readout
        # A command topic's value shows as its live parameter too (ros2 param get agrees
        # with ros2 topic pub), mirrored at most every MIRROR_PERIOD: a parameter event per
        # message of a 1 kHz command would flood /parameter_events.
        self._mirror: dict[str, float] = {}
        for topic, name in readout.commands:
            self.create_subscription(Float64, topic,
                                     lambda m, n=name: self._on_command(n, m.data), 10)
        if readout.commands:
            self.create_timer(MIRROR_PERIOD, self._mirror_commands,
                              clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The command has an executor of its own: what a lock-step exchange waits for.
        self._io = entry.SideExecutor(self)
        self._cmd = self._io.subscribe(Float64, 'solenoid_current_cmd',
                                       lambda m: self.runner.command(m.data), qos)
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.create_service(SetBool, '~/pause', self._on_pause)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.create_timer(self.cfg.diagnostics_period, self._publish_diagnostics,
                          clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self._make_messages()
        self._started = time.monotonic()
        self._advertised: float | None = None    # steady s its publishers were made
        self._other_since: float | None = None
        self._alone = threading.Event()
        self._alone_timer = self.create_timer(0.1, self._check_alone,
                                              clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self._thread = threading.Thread(target=self._run, name='stepper', daemon=True)
        self._thread.start()

    def _advertise(self) -> None:
        """The publishers of its topics: /clock, the measurements, ``joint_states``, what
        the circuit adds (its load-sensing pressure, each load's signals), the events."""
        qos = self._qos
        self._pub_clock = self.create_publisher(Clock, CLOCK, qos)
        have = self.runner.readout.names
        self._pub_p = {k: self.create_publisher(FluidPressure, k, qos) for k in PRESSURE_SIGNALS
                       if k in have}
        self._pub_f = {k: self.create_publisher(Float64, k, qos) for k in FLOW_SIGNALS
                       if k in have}
        self._pub_js = self.create_publisher(JointState, 'joint_states', qos)
        # Joint states that carry a measured position (an FMU without spool and plate
        # positions publishes zeros there, which no recorder is waited for).
        self._js_measured = bool({'spool_position', 'actuator_position'} & set(have))
        self._pub_i = self.create_publisher(Float64, 'solenoid_current', qos)
        self._pub_x = {t.topic: self.create_publisher(
            FluidPressure if t.kind == 'pressure' else Float64, t.topic, qos)
            for t in self.runner.readout.topics}
        self._pub_events = self.create_publisher(DiagnosticArray, EVENTS, EVENTS_QOS)

    def _configure(self) -> None:
        d = bridge.Declarer(self)
        cfg = d.declare(SimulatorConfig)
        if cfg is None:
            d.finish()
        plant_file = cfg.params_file or str(default_params_path())
        try:
            plant = read_params_file(plant_file)
            profile = load_profile(cfg.sensor_profile) if cfg.sensor_profile \
                else SensorProfile({})
        except ParamError as exc:
            raise bridge.StartupError(exc.lines) from None
        # The files are checked as load_params checks them: an unknown key is an error.
        d.errors += [f'{plant_file}: {line}' for line in check_all(Params, plant)[1]
                     if 'unknown' in line]
        overrides = profile.plant_overrides or {}
        d.errors += [f'{cfg.sensor_profile}: {line}'
                     for line in check_all(Params, overrides)[1] if 'unknown' in line]
        params = d.declare(Params, {**plant, **overrides}, source=plant_file)
        sensors = d.declare(SensorConfig, profile.flat(), source=cfg.sensor_profile or None)
        # The circuit's inputs are known once it is read, an FMU's parameters once it is.
        d.finish(pending=(INPUTS, FMU_PARAMETERS))
        errors = cfg.plant_checks(params)
        if errors:
            raise bridge.StartupError(errors)
        path = self._circuit_file = cfg.circuit_file or str(default_circuit_path())
        self.params = params
        self.cfg = cfg
        self._fidelity = (cfg.fidelity, cfg.fidelity_bandwidth)
        if cfg.fmu_file:
            return self._configure_fmu(d, cfg, sensors, overrides)
        try:
            circuit = self._circuit(cfg.circuit_sets)
        except HydropumpError as exc:
            raise bridge.StartupError([f'{path}: {ln}' for ln in exc.lines or [str(exc)]]) \
                from None
        # The operator's inputs (valve commands, forces, torques) as live parameters
        # inputs.<name>: an orchestrated run sets them at an exact instant, as it sets the
        # operating point; loads/<name>/command sets the same input.
        self._inputs = {f'{INPUTS}{n}': n for n in circuit.operator_inputs()}
        d.declare_specs([circuit.input_spec(n, INPUTS) for n in circuit.operator_inputs()])
        d.finish()
        for name, value in d.given.items():  # held from the first step
            if name in self._inputs:
                circuit.u0[circuit.input_index(self._inputs[name])] = float(value)
        self.cfg = cfg
        try:
            plant = self._simulator(circuit)
        except HydropumpError as exc:
            raise bridge.StartupError([f'{path}: {ln}' for ln in exc.lines or [str(exc)]]) \
                from None
        try:
            self._declare_fmu_loads(plant)
            scenario = self._scenario(cfg, circuit)
            self.schema_specs = d.specs
            self.runner = Runner(plant, cfg, profile=SensorProfile.from_config(sensors,
                                                                               overrides),
                                 scenario=scenario, log=self._log)
        except BaseException as exc:
            if hasattr(plant, 'close'):     # FMU loads: their instances and files
                plant.close()
            if isinstance(exc, HydropumpError) and not isinstance(exc, bridge.StartupError):
                raise bridge.StartupError([f'{path}: {ln}' for ln in exc.lines or [str(exc)]]) \
                    from None
            raise

    def _configure_fmu(self, d, cfg, sensors, overrides) -> None:
        """A user's FMU as the plant (hydropump_ctrl.fmi.plant): its parameters as
        read-only ``fmu_parameters.<name>``; a circuit file or circuit_sets beside it are
        refused."""
        if cfg.circuit_file or cfg.circuit_sets:
            raise bridge.StartupError(['fmu_file: the FMU is the whole plant; give no '
                                       'circuit_file or circuit_sets with it'])
        if cfg.fidelity != 'fine' or cfg.solver.fixed_step:
            raise bridge.StartupError(['fidelity, solver.fixed_step: an FMU plant steps as it '
                                       'is; give neither with fmu_file'])
        from hydropump_ctrl.fmi.plant import FmuSimulator
        try:
            plant = FmuSimulator(cfg.fmu_file, self.params, cfg.dt)
        except HydropumpError as exc:
            raise bridge.StartupError(exc.lines or [str(exc)]) from None
        try:
            self._fmu_node(d, cfg, plant, sensors, overrides)
        except BaseException:
            plant.close()
            raise

    def _fmu_node(self, d, cfg, plant, sensors, overrides) -> None:
        """The rest of the start on an FMU: its parameters, the scenario, the runner."""
        self._inputs = {}
        # Values given for the FMU's parameters (a calibrated file, -p fmu_parameters.x:=)
        # are set before its initialisation; after the start they are read-only.
        given = {k[len(FMU_PARAMETERS):]: v for k, v in d.given.items()
                 if k.startswith(FMU_PARAMETERS)}
        d.finish(pending=(FMU_PARAMETERS,))
        bad = [f'{FMU_PARAMETERS}{n}: {v!r} is not a number' for n, v in given.items()
               if isinstance(v, bool) or not isinstance(v, (int, float))]
        if bad:
            raise bridge.StartupError(bad)
        try:
            if given:
                plant.set_parameters(given)
                plant.reset()
        except HydropumpError as exc:
            raise bridge.StartupError([FMU_PARAMETERS + ln for ln in exc.lines or [str(exc)]]) \
                from None
        from rcl_interfaces.msg import ParameterDescriptor
        for name, value in plant.model.parameters().items():
            value = plant.parameter_values.get(name, value)
            key = FMU_PARAMETERS + name
            if ros_name(name):    # others make no ROS parameter: left undeclared
                # The value given (an integer too) is the FMU's already: declared as a float.
                self.declare_parameter(key, float(value), ParameterDescriptor(
                    read_only=True, description=f'the FMU parameter {name} '
                    f'[{plant.model.info.variables[name].unit or "-"}]'), ignore_override=True)
        scenario = self._scenario(cfg, plant.model)
        self.schema_specs = d.specs
        try:
            self.runner = Runner(plant, cfg, profile=SensorProfile.from_config(sensors, overrides),
                                 scenario=scenario, log=self._log)
        except HydropumpError as exc:
            raise bridge.StartupError(exc.lines or [str(exc)]) from None

    def _declare_fmu_loads(self, plant) -> None:
        """The parameters of the circuit's FMU loads, as they start (the FMU's, those the
        circuit file gives set), as read-only ``fmu_loads.<component>.<name>``."""
        from rcl_interfaces.msg import ParameterDescriptor
        loads = getattr(plant, 'loads', None)
        for comp, values in (loads.parameters() if loads else {}).items():
            for name, value in values.items():
                if ros_name(name):    # others make no ROS parameter: left undeclared
                    self.declare_parameter(f'{FMU_LOADS}{comp}.{name}', float(value),
                                           ParameterDescriptor(
                                               read_only=True, description=f'the parameter '
                                               f'{name} of the FMU of {comp}'))

    @staticmethod
    def _scenario(cfg, model):
        """The inputs ``scenario_file`` schedules (the operating point's and ``model``'s own),
        or ``None``."""
        if not cfg.scenario_file:
            return None
        try:
            return load_scenario(cfg.scenario_file, [*SCENARIO_INPUTS,
                                                     *model.all_inputs()]).inputs
        except ScenarioError as exc:
            raise bridge.StartupError([f'{cfg.scenario_file}: {ln}' for ln in exc.lines]) \
                from None

    def _circuit(self, sets: str):
        """The circuit file with ``circuit_sets``, on the node's plant parameters."""
        return load_circuit(self._circuit_file, assignments(
            sets.split(), 'circuit_sets', 'boom.compensator=post'), plant=self.params)

    def _simulator(self, circuit, fidelity: tuple[str, float] | None = None) -> Simulator:
        """The stepper of a circuit, which must have a pump, at ``fidelity`` (name,
        bandwidth; default the node's)."""
        if circuit.pump() is None:
            raise HydropumpError([f'{circuit.name}: the simulator node runs a circuit with a '
                                  'pump (type pump or ls_pump)'])
        name, bandwidth = fidelity or self._fidelity
        if circuit.external():
            if name != 'fine' or self.cfg.solver.fixed_step:
                raise HydropumpError(['fidelity, solver.fixed_step: a circuit with FMU loads '
                                      'runs fine, at adaptive steps'])
            # A user's FMU loads, stepped beside the circuit (co-simulation).
            from hydropump_ctrl.fmi.loads import CoupledSimulator
            return CoupledSimulator(circuit, self.cfg.dt)
        circuit, fid = with_fidelity(circuit, name, bandwidth,
                                     self._controller_bandwidth(circuit, name))
        step, most = self.cfg.solver.fixed_step, self.cfg.solver.max_steps
        checked = fixed_step.check(circuit, self.cfg.dt, step, most) if step else None
        sim = Simulator(circuit, self.cfg.dt, fixed_step=step, max_steps=most)
        sim.fidelity, sim.step_check = fid, checked
        if checked is not None:
            self.get_logger().info(checked.text())
        return sim

    @staticmethod
    def _controller_bandwidth(circuit, name: str) -> float | None:
        """The bandwidth [Hz] of the controller designed for the circuit (either mode), which
        the simplified fidelity must not reach into; ``None`` where none is designed."""
        if name == 'fine':
            return None
        from hydropump_ctrl.experiments.circuit_loop import controller_config
        try:
            return controller_config(circuit).bandwidth()
        except HydropumpError:
            return None

    def _other_circuit(self, sets: str, fidelity: tuple[str, float], label: str = ''
                       ) -> tuple[Simulator | None, str | None]:
        """The plant of new ``circuit_sets`` at ``fidelity``, or why not (after ``label``):
        its topics, commands and joints must be those the node has (publishers and
        subscriptions are made once)."""
        try:
            plant = self._simulator(self._circuit(sets), fidelity)
        except HydropumpError as exc:
            return None, label + '; '.join(exc.lines or [str(exc)])
        old = self.runner.sim

        def face(sim):
            topics, commands = model_topics(sim.model)
            return (topics, commands, [j[0] for j in sim.model.joints()],
                    sim.model.operator_inputs())
        if face(plant) != face(old):
            return None, (f'circuit_sets = {sets!r} changes the topics or inputs of the '
                          'circuit: restart the simulator with it')
        return plant, None

    def _log(self, level: str, text: str) -> None:
        entry.log(self.get_logger(), level, text)

    # ---- services and parameters (executor thread) --------------------------------------

    def _on_command(self, name: str, value: float) -> None:
        self.runner.set_input(name, value)
        self._mirror[f'{INPUTS}{name}'] = value

    def _mirror_commands(self) -> None:
        """The latest value of each command topic as its ``inputs.<name>`` parameter (a value
        outside its range, which the plant clamps, is left unmirrored)."""
        from rclpy.parameter import Parameter
        pending, self._mirror = self._mirror, {}
        changed = [Parameter(k, value=float(v)) for k, v in pending.items()
                   if self.has_parameter(k) and self.get_parameter(k).value != v]
        if changed:
            self.set_parameters(changed)

    def _on_reset(self, request, response):
        self.runner.reset()
        response.success = True
        response.message = f'reset to the equilibrium at {self.runner.initial_current:.4g} A'
        return response

    def _on_pause(self, request, response):
        if not request.data:
            self._matched()
        self.runner.set_paused(request.data)
        response.success = True
        response.message = 'paused' if request.data else 'running'
        return response

    def _on_set_parameters(self, params):
        reason = bridge.refusal(self.schema_specs, params)
        plant = None
        new = {p.name: p.value for p in params}
        fidelity = (new.get('fidelity', self._fidelity[0]),
                    new.get('fidelity_bandwidth', self._fidelity[1]))
        if reason is None and ({'circuit_sets', 'fidelity', 'fidelity_bandwidth'} & set(new)):
            sets = new.get('circuit_sets', self.get_parameter('circuit_sets').value)
            what = 'circuit_sets' if 'circuit_sets' in new else 'fidelity'
            plant, reason = (None, f'{what}: the plant is an FMU (fmu_file)') \
                if self.cfg.fmu_file else \
                (None, f'{what}: the circuit has FMU loads; restart the simulator '
                       'to change it') if getattr(self.runner.sim, 'loads', None) else \
                self._other_circuit(sets, fidelity, f'circuit_sets = {sets!r}: '
                                    if 'circuit_sets' in new else '')
            if plant is not None and fidelity != self._fidelity:
                # The running plant stays until the reset: a change of model mid-run would
                # jump every state. (rclpy drops the reason of an accepted change: logged.)
                self.get_logger().info(f'fidelity {plant.fidelity.text()}: from the next '
                                       '~/reset on')
        if reason is None:
            self._fidelity = fidelity
            if plant is not None:
                self.runner.set_plant(plant)
            for p in params:
                if p.name in ('circuit_sets', 'fidelity', 'fidelity_bandwidth'):
                    continue
                if p.name in self._inputs:
                    self.runner.set_input(self._inputs[p.name], p.value)
                elif p.name in LIVE_INPUTS or p.name in self.schema_specs:
                    self.runner.set_parameter(p.name, p.value)
        return bridge.result(reason)

    def _matched(self, limit: float = 10.0) -> None:
        """Before running on, wait (at most ``limit`` s) until every measurement writer has
        ``wait_subscribers`` matched readers and every reader the graph shows (a recorder's
        ~/ready sees only its side), the events writer every reader the graph shows (an event
        of the first instants reaches the bag), and in lock-step the command's writer is
        matched (a command sent before is lost, and the run would wait
        ``lock_step_timeout``). Before its publishers exist (alone not yet known), nothing."""
        if not self._alone.is_set():
            return
        pubs = [self._pub_clock, *([self._pub_js] if self._js_measured else []),
                *self._pub_p.values(), *self._pub_f.values()]
        want = self.runner.cfg.wait_subscribers
        end = time.monotonic() + limit
        while True:
            short = {p.topic_name: (p.get_subscription_count(), max(
                want if p is not self._pub_events else 0,
                len(self.get_subscriptions_info_by_topic(p.topic_name))))
                for p in (*pubs, self._pub_events)}
            if self.cfg.lock_step:
                name = self._cmd.topic_name
                # A lock-step run needs its controller: wait for one.
                short[name] = (self._cmd.get_publisher_count(), max(
                    1, len(self.get_publishers_info_by_topic(name))))
            short = {k: v for k, v in short.items() if v[0] < v[1]}
            if not short:
                return
            if time.monotonic() > end:
                break
            time.sleep(0.01)
        self.get_logger().warn(
            f'running on before every subscriber was matched (waited {limit:g} s): ' + ', '.join(
                f'{k} {n} of {m}' for k, (n, m) in short.items()))

    # ---- the stepping thread -------------------------------------------------------------

    def _run(self) -> None:
        cfg = self.cfg
        pace = ('lock-step' if cfg.lock_step else 'as fast as possible'
                if cfg.real_time_factor == 0 else f'real-time factor {cfg.real_time_factor:g}')
        self.get_logger().info(f'ready: {cfg.publish_rate:g} Hz, {pace}'
                               + (', paused until ~/pause false' if cfg.start_paused else ''))
        while not self._alone.wait(0.05):
            if self._closing or not self.context.ok():
                return
        if cfg.lock_step and not cfg.start_paused:
            # The first instant's clock and measurements must reach a controller already
            # matched, or the run waits a whole lock_step_timeout for its first command.
            self._matched()
        try:
            self.runner.run(self)
        except Exception as exc:  # a publisher gone at shutdown ends the thread quietly
            if self.context.ok() and not self._closing:
                self.get_logger().error(f'stepping stopped: {type(exc).__name__}: {exc}')
                raise

    def _check_alone(self) -> None:
        """Refuse to run beside another simulator of the same namespace: its clock would jump
        back and forth."""
        now = time.monotonic()
        # First it looks without a writer of its own: a simulator joining a running one is
        # refused before the graph sees anything of it. Then it advertises and looks
        # CONFIRM_WINDOW more: two started together see each other's writers then.
        if self._advertised is None:
            if now > self._started + DISCOVERY_WINDOW and self._other_since is None:
                self._advertise()
                self._advertised = now
                return
        elif now > self._advertised + CONFIRM_WINDOW and self._other_since is None:
            self.destroy_timer(self._alone_timer)
            self._alone.set()
            return
        others = [f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                  for i in self.get_publishers_info_by_topic(CLOCK)]
        if self._advertised is not None:
            # Leave out its own writer, once: another of the same name is another one too.
            own = f'{self.get_namespace().rstrip("/")}/{self.get_name()}'
            if own in others:
                others.remove(own)
        if not others or self._closing:
            return
        # A writer is discovered before its node's name is: wait a little for the name.
        self._other_since = self._other_since or now
        if any('_UNKNOWN_' in o for o in others) and now < self._other_since + 1.0:
            return
        named = [o for o in others if '_UNKNOWN_' not in o]
        self.get_logger().error(
            f'another node publishes {self.resolve_topic_name(CLOCK)} in this ROS domain'
            f'{" (" + ", ".join(named) + ")" if named else ""}: one simulator per namespace '
            '(give each pump its own namespace, or its own ROS_DOMAIN_ID)')
        self.exit_code = 2
        self.destroy_timer(self._alone_timer)
        self.runner.stop()
        entry.request_shutdown()

    def close(self) -> None:
        """Stop stepping before the publishers and the context go."""
        self._closing = True
        self.runner.stop()
        self._thread.join(timeout=5.0)
        self._io.close()
        # A user's FMU: ended and its files removed, once nothing steps it any more.
        if hasattr(self.runner.sim, 'close') and not self._thread.is_alive():
            self.runner.sim.close()

    # ---- publishing (stepping thread) ----------------------------------------------------

    def _make_messages(self) -> None:
        """Message objects reused every step (building them is most of a step's cost)."""
        prof = self.runner.profile
        self._m_clock = Clock()
        self._m_float = Float64()
        self._m_p = {k: FluidPressure(variance=prof.spec(k).noise_std ** 2)
                     for k in PRESSURE_SIGNALS if k in self.runner.readout.names}
        readout = self.runner.readout
        self._m_js = JointState(name=[j[0] for j in JOINTS]
                                + [j[0] for j in readout.model.joints()])
        self._m_x = {t.topic: FluidPressure(variance=prof.spec(t.like or '').noise_std ** 2)
                     if t.kind == 'pressure' else Float64() for t in readout.topics}
        self._p_atm = self.params.fluid.p_atm

    def current(self, t: float, value: float) -> None:
        self._m_float.data = value
        self._pub_i.publish(self._m_float)

    def event(self, name: str, t: float, text: str) -> None:
        self._pub_events.publish(event_message(EVENT_KINDS[name], seconds_to_ns(t), text,
                                               'simulator'))

    def measurement(self, frame) -> None:
        ns = seconds_to_ns(frame.t)
        set_stamp(self._m_clock.clock, ns)
        self._pub_clock.publish(self._m_clock)
        sig, f = frame.signals, self._m_float
        for topic, pub in self._pub_f.items():
            f.data = sig[topic]
            pub.publish(f)
        for topic, msg in self._m_p.items():
            set_stamp(msg.header.stamp, ns)
            msg.fluid_pressure = absolute(sig[topic], self._p_atm)
            self._pub_p[topic].publish(msg)
        for topic, value in frame.extra.items():
            msg = self._m_x[topic]
            if isinstance(msg, FluidPressure):
                set_stamp(msg.header.stamp, ns)
                msg.fluid_pressure = absolute(value, self._p_atm)
            else:
                msg.data = value
            self._pub_x[topic].publish(msg)
        js = self._m_js
        set_stamp(js.header.stamp, ns)
        names, positions, velocities = frame.joints
        js.position = [sig.get('spool_position', 0.0), sig.get('actuator_position', 0.0),
                       *positions]
        js.velocity = [*frame.velocities, *velocities]
        js.effort = [*frame.efforts, *(0.0 for _ in names)]
        self._pub_js.publish(js)

    # ---- diagnostics (executor thread) ---------------------------------------------------

    def _publish_diagnostics(self) -> None:
        d = self.runner.diagnostics()
        flags, stats = d['flags'], d['stats']

        def status(name, level, message, values):
            return DiagnosticStatus(name=f'simulator: {name}', hardware_id='hydropump',
                                    level=level, message=message,
                                    values=[KeyValue(key=k, value=str(v))
                                            for k, v in values.items()])
        ok, warn, error = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR
        bad = stats['nan_commands'] or stats['clamped_commands'] or d['watchdog']
        fid, fixed = d['fidelity'], d['step_check']
        pending = self._fidelity[0] != (fid.name if fid is not None else 'fine')
        arr = DiagnosticArray(status=[
            status('plant', warn if any(flags.values()) else ok,
                   ', '.join(k for k, v in flags.items() if v) or 'inside all limits', flags),
            status('integrator', error if d['failed'] else warn if d['overruns'] else ok,
                   d['failed'] or ('paused' if d['paused'] else
                                   f'running, {d["overruns"]} steps over their period'
                                   if d['overruns'] else 'running'),
                   {'sim_time_s': f'{d["sim_time"]:.6f}', 'accepted_steps': d['accepted_steps'],
                    'rejected_steps': d['rejected_steps'],
                    'achieved_real_time_factor': f'{d["achieved_rtf"]:.3f}',
                    'step_period_error_p99_s': f'{d["period_error_p99"]:.6f}',
                    # Each step's wall time against the period it must fit in.
                    'step_cost_p50_s': f'{d["step_cost_p50"]:.6f}',
                    'step_cost_p99_s': f'{d["step_cost_p99"]:.6f}',
                    'step_cost_max_s': f'{d["step_cost_max"]:.6f}',
                    'step_period_s': f'{d["step_budget"]:.6f}',
                    'step_overruns': d['overruns'],
                    # A fixed step: the bound of an increment's work.
                    'fixed_step_s': f'{fixed.step:.6g}' if fixed else '0',
                    'max_steps_per_increment': fixed.max_steps if fixed else '',
                    'model_evaluations_max': fixed.evaluations if fixed else '',
                    'lock_step': self.cfg.lock_step}),
            # Which model runs, and how far the simplified one may be from the fine one.
            status('model', ok, (fid.text() if fid is not None else 'fine') + (
                f'; {self._fidelity[0]} from the next ~/reset' if pending else ''),
                   {'fidelity': fid.name if fid is not None else 'fine',
                    'next_fidelity': self._fidelity[0] if pending else '',
                    'fidelity_bandwidth_hz': f'{fid.bandwidth:.4g}' if fid and fid.components
                    else '', 'made_static': ' '.join(fid.components) if fid else '',
                    'error_bound': f'{fid.bound:.4g}' if fid is not None else '0'}),
                        status('command', warn if bad else ok,
                   'watchdog: safe current applied' if d['watchdog'] else
                   'bad commands received' if bad else 'ok',
                   {'command_age_s': f'{d["command_age"]:.4f}',
                    'applied_current_A': f'{d["applied_current"]:.6f}',
                    'commanded_current_A': f'{d["commanded_current"]:.6g}',
                    'watchdog_active': d['watchdog'], **stats}),
        ])
        arr.header.stamp = stamp(seconds_to_ns(d['sim_time']))
        self._pub_diag.publish(arr)


def main(args=None) -> int:
    import sys
    # Two threads share the GIL: hand it over sooner, so a command taken by the executor
    # reaches the stepping thread without waiting out the 5 ms default interval.
    sys.setswitchinterval(2.0e-4)
    return entry.run(SimulatorNode, prog='simulator', doc=__doc__, specs=all_specs, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
