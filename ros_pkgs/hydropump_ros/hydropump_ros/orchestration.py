"""One orchestration for every run through the real nodes: ``hydropump-demo`` and
``hydropump record``.

- :class:`Orchestrator` - the run's own rclpy node: service calls, parameter sets, the
  simulation clock and the controller's update instants;
- :class:`Graph` - simulator, controller and recorder: started here (:meth:`Graph.start`, in
  lock-step, the simulator paused) or already running (:meth:`Graph.attach`); either way
  :meth:`Graph.run` takes one :class:`~hydropump_ctrl.demo.campaign.Experiment`
  through them into its bag, with live parameters, the simulator's ``~/reset`` and
  ``pause_at``, and the recorder's ``~/start`` and ``~/stop``;
- :func:`run_experiments` - experiments one after the other with a line as each starts and
  ends; :func:`own_domain` - a ROS domain of this host that no other graph holds.

A node that fails stops the run with a message that names it and its log
(:class:`GraphError`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
import contextlib
import math
import os
from pathlib import Path
import random
import signal
import socket
import subprocess
import time
from typing import TYPE_CHECKING

from hydropump_sim.errors import HydropumpError

from .command_line import node_command

if TYPE_CHECKING:  # light to import: a signal handler of the run uses stop()
    from hydropump_ctrl.experiment import Experiment


class GraphError(HydropumpError):
    """A failure of the graph that ends the run: one line for the user."""


class GraphTimeoutError(GraphError):
    """What the graph was waited for did not come in time."""


# The largest ROS_DOMAIN_ID (DDS ports for a domain above it fall outside the port range).
MAX_DOMAIN_ID = 232


# ---- a stop by signal -----------------------------------------------------------------------

_starting = 0  # process starts under way in this process (starting())
_held: list[BaseException] = []  # a stop that came during one


def stop(exc: BaseException) -> None:
    """Raise ``exc`` from a signal handler that ends the run, or, while a process is being
    started and recorded (:func:`starting`), hold it until that is done: a process started
    but not yet recorded would be left running."""
    if _starting:
        _held[:] = [exc]
        return
    raise exc


@contextlib.contextmanager
def starting():
    """Start a process and record it (in :attr:`Orchestrator.procs`, in a process pool)
    inside this block: a :func:`stop` is held until its end."""
    global _starting
    _starting += 1
    try:
        yield
    finally:
        _starting -= 1
        if not _starting and _held:
            raise _held.pop()


def stop_on_sigterm(exc: Callable[[], BaseException] | None = None) -> None:
    """From now on SIGTERM stops the run in this process: its handler raises ``exc()``
    (default :class:`~hydropump_ctrl.experiment.Stopped`) in the main thread,
    through :func:`stop` (held while a node process starts), once: a second SIGTERM must not
    cut the stop short. The run's :class:`Orchestrator` is then made with ``signals=False``."""
    if exc is None:
        from hydropump_ctrl.experiment import Stopped  # now, not in the handler
        exc = Stopped

    def on_sigterm(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        stop(exc())
    signal.signal(signal.SIGTERM, on_sigterm)


def _stamp_s(stamp) -> float:
    return stamp.sec + stamp.nanosec * 1e-9


class Orchestrator:
    """The run's own rclpy node, in ``namespace`` (where the graph's nodes are): service
    calls, parameter sets, the latest ``/clock`` (:attr:`t`) and the latest update instant of
    the controller (:attr:`ctrl_t`, from its ``~/state``).

    ``signals=False`` keeps rclpy's signal handlers out: the caller's own then stop the run
    (rclpy's shut the context down under a waiting call, which fails with an RCLError)."""

    def __init__(self, namespace: str = '', *, signals: bool = True):
        import rclpy
        from rclpy.node import Node
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState

        from .conversions import CLOCK
        self.rclpy = rclpy
        rclpy.init(signal_handler_options=None if signals else SignalHandlerOptions.NO)
        self.namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
        self.node = Node(f'hydropump_run_{os.getpid()}', namespace=self.namespace or None)
        self.t = -1.0
        self.ctrl_t = -1.0
        # Only the latest time matters here: one callback per spin, not one per step.
        latest = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                            history=HistoryPolicy.KEEP_LAST)
        self.node.create_subscription(Clock, CLOCK, self._on_clock, latest)
        self.node.create_subscription(JointState, 'controller/state', self._on_state, latest)
        self._clients = {}
        self.procs: dict = {}

    def _on_clock(self, msg) -> None:
        self.t = _stamp_s(msg.clock)

    def _on_state(self, msg) -> None:
        self.ctrl_t = _stamp_s(msg.header.stamp)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()

    def name(self, relative: str) -> str:
        """The graph name of ``relative`` (``'simulator/reset'``) in the namespace."""
        return f'{self.namespace}/{relative.lstrip("/")}'

    def check_nodes(self) -> None:
        for name, (proc, log, exp) in self.procs.items():
            if proc.poll() is not None:
                raise GraphError(f'node {name} of {exp} exited with code {proc.returncode}: '
                                 f'see {log}')

    def spin_until(self, predicate, timeout: float, what: str, poll: float = 0.0) -> None:
        """Spin until ``predicate()``; with ``poll`` [s], sleep that long between spins (a
        wait on simulation time: each /clock message would otherwise cost a spin, and the
        run's own process would take a third of a core from the graph)."""
        deadline = time.monotonic() + timeout
        while not predicate():
            self.check_nodes()
            if time.monotonic() > deadline:
                raise GraphTimeoutError(f'timed out after {timeout:g} s waiting for {what}')
            self.rclpy.spin_once(self.node, timeout_sec=0.01)
            if poll and not predicate():
                time.sleep(poll)

    def service_ready(self, name: str) -> bool:
        """Has the graph a server of ``name``? (Any type: the name says which node.)"""
        full = self.name(name)
        return any(n == full for n, _ in self.node.get_service_names_and_types())

    def nodes(self) -> set[str]:
        """The names of the nodes in the namespace."""
        ns = self.namespace or '/'
        return {n for n, space in self.node.get_node_names_and_namespaces() if space == ns}

    def call(self, srv_type, name: str, request, timeout: float = 60.0, attempts: int = 1):
        """``request`` to the service ``name``: at most ``timeout`` [s] for it to be ready
        and as long for its answer; an idempotent request may be sent ``attempts`` times,
        each waiting its share of that (an answer lost to a client made just before, which
        rclpy's services may lose, then costs a share, not the whole wait)."""
        if name not in self._clients:
            self._clients[name] = self.node.create_client(srv_type, name)
        client = self._clients[name]
        self.spin_until(client.service_is_ready, timeout, f'the service {self.name(name)}')
        attempts = max(1, int(attempts))
        for attempt in range(attempts):
            future = client.call_async(request)
            try:
                self.spin_until(future.done, timeout / attempts,
                                f'the answer of {self.name(name)}')
            except GraphTimeoutError:
                client.remove_pending_request(future)
                if attempt == attempts - 1:
                    raise
                continue
            return future.result()

    def set_params(self, node: str, values: dict, timeout: float = 60.0,
                   attempts: int = 1) -> None:
        """Set ``values`` on ``node`` one at a time, in their order (each must leave a valid
        configuration); ``timeout`` and ``attempts`` as :meth:`call` takes them (setting
        the same values again is harmless)."""
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg()
                                                for k, v in values.items()])
        for name, result in zip(values, self.call(SetParameters, f'{node}/set_parameters',
                                                  req, timeout, attempts).results):
            if not result.successful:
                raise GraphError(f'{self.name(node)} refused {name} = {values[name]}: '
                                 f'{result.reason}')

    def get_params(self, node: str, names: Iterable[str]) -> dict:
        """The values of ``names`` on ``node`` (``None`` where it has no such parameter)."""
        from rcl_interfaces.srv import GetParameters
        from rclpy.parameter import parameter_value_to_python
        names = list(names)
        res = self.call(GetParameters, f'{node}/get_parameters', GetParameters.Request(
            names=names))
        return {n: parameter_value_to_python(v) for n, v in zip(names, res.values)}


#: Measurement rate of a graph started here [Hz]: 2 ms samples resolve a 100 ms time constant
#: and a 55 ms delay (the fit takes any fraction of a sample), and lock-step runs about three
#: times faster than at the simulator's default 1 kHz, since each sample costs every node a
#: message per topic.
PUBLISH_RATE = 200.0
#: The steady-time waits of a graph driven here [s]: a loaded machine, or a pause between two
#: changes, must slow the run down, never trip a node's watchdog.
LONG_WAITS = {'simulator': {'lock_step_timeout': 60.0, 'wait_subscribers': 1},
              'controller': {'watchdog.safe_timeout': 60.0, 'watchdog.hold_timeout': 30.0}}
# The order the graph starts its nodes in (the recorder first: it misses nothing).
START_ORDER = ('recorder', 'simulator', 'controller')
#: Sleep between spins while waiting for simulation time [s] (Orchestrator.spin_until).
CLOCK_POLL = 0.003
# A pause_at every simulation time has passed: the simulator pauses at the step it is at.
PAUSE_NOW = 1.0e-9


class Graph:
    """Simulator (lock-step, paused between experiments), controller and recorder, through
    which :meth:`run` takes one experiment at a time into its bag.

    Between experiments the simulator stands paused: the next one sets its operating point,
    initial current and noise seed (live), opens its bag, restarts the controller (lifecycle
    deactivate, parameters, activate) and resets the simulator, whose reset state comes out
    at the next control instant ``t0``. The schedule then runs in simulation time from
    ``t0``: pause at each change, apply it, go on, and at the end close the bag at
    ``t0 + duration`` exactly.

    Build it with :meth:`start` (the nodes started here, each logging to
    ``<log_dir>/<node>.log`` and ended by PID in :meth:`close`) or :meth:`attach` (nodes
    someone else started; :meth:`close` gives back the waits it lengthened).
    """

    def __init__(self, orch: Orchestrator, period: float = 0.005,
                 publish_rate: float = PUBLISH_RATE, log_dir: Path | None = None):
        self.orch = orch
        self.period = period              # the lock-step control period [s]
        self.publish_rate = publish_rate  # the simulator's [Hz]
        self.log_dir = log_dir
        self.ready_s: dict[str, float] = {}
        self.running_s = 0.0  # wall time the simulator spent stepping
        self.notes: list[str] = []  # what attaching changed, for the user
        self._restore: dict[str, dict] = {}
        self._open_bag: Path | None = None  # the bag the recorder has open for a run

    # ---- a graph of its own -------------------------------------------------------------

    @classmethod
    def start(cls, orch: Orchestrator, log_dir: Path, topics: list[str], *,
              sensor_profile: str | Path | None = None, params_file: str | Path | None = None,
              circuit_file: str | Path | None = None, controller_file: str | Path | None = None,
              simulator: dict | None = None, publish_rate: float = PUBLISH_RATE) -> Graph:
        """Start the three nodes (in parallel, in the orchestrator's namespace) and wait
        until each is ready; :attr:`ready_s` has each one's start-up time [s] from the
        process start: the simulator's services answer, the controller is active, the
        recorder has matched a publisher on every topic. ``simulator`` holds more of the
        simulator's parameters; ``controller_file`` is the controller's ``config_file``."""
        graph = cls(orch, log_dir=log_dir, publish_rate=publish_rate)
        log_dir.mkdir(parents=True, exist_ok=True)
        sim = {'lock_step': True, 'start_paused': True, 'command_timeout': 60.0,
               'publish_rate': publish_rate, **LONG_WAITS['simulator'], **(simulator or {})}
        for key, path in (('params_file', params_file), ('sensor_profile', sensor_profile),
                          ('circuit_file', circuit_file)):
            if path:
                sim[key] = str(Path(path).resolve())
        ctrl = {'autostart': True, **LONG_WAITS['controller']}
        if controller_file:
            ctrl['config_file'] = str(Path(controller_file).resolve())
        commands = {
            'recorder': {'autostart': False, 'topics': list(topics)},
            'simulator': sim,
            'controller': ctrl,
        }
        t0 = time.perf_counter()
        try:
            # Each node in orch.procs as it starts: whatever interrupts the start-up (a
            # signal included) ends those already started.
            for name in START_ORDER:
                log = log_dir / f'{name}.log'
                with starting():
                    orch.procs[name] = (subprocess.Popen(
                        node_command(name, commands[name], namespace=orch.namespace),
                        stdout=open(log, 'w'), stderr=subprocess.STDOUT), log, 'the graph')
            graph._wait_ready(t0, 60.0)
            graph._prime()
        except BaseException:
            graph.close()
            raise
        return graph

    def _wait_ready(self, t0: float, timeout: float) -> None:
        from lifecycle_msgs.msg import State
        from lifecycle_msgs.srv import GetState
        orch = self.orch
        orch.spin_until(lambda: orch.service_ready('simulator/reset'), timeout,
                        'the simulator to start')
        self.ready_s['simulator'] = time.perf_counter() - t0
        get_state = GetState.Request()
        orch.spin_until(lambda: orch.call(GetState, 'controller/get_state', get_state)
                        .current_state.id == State.PRIMARY_STATE_ACTIVE, timeout,
                        'the controller to be active')
        self.ready_s['controller'] = time.perf_counter() - t0
        orch.spin_until(lambda: orch.service_ready('recorder/start'), timeout,
                        'the recorder to start')
        self.ready_s['recorder'] = time.perf_counter() - t0
        self._recorder_ready(timeout)
        self.ready_s['graph'] = time.perf_counter() - t0

    def _recorder_ready(self, timeout: float) -> None:
        from std_srvs.srv import Trigger
        orch, last = self.orch, []

        def ready():
            answer = orch.call(Trigger, 'recorder/ready', Trigger.Request())
            last[:] = [answer.message]
            return answer.success
        try:
            orch.spin_until(ready, timeout, 'the recorder to match every topic')
        except GraphError:
            raise GraphError(f'{orch.name("recorder")} is not ready after {timeout:g} s: '
                             f'{last[0] if last else "no answer"}') from None

    def _prime(self) -> None:
        """Let the simulator take one step and pause: a simulator that has not run yet
        publishes its first state (at the params file's operating point), one that has run
        its next step. From then on every experiment's ``~/reset`` publishes the reset state
        at once, at the next control instant, with the operating point set before. (A
        ``pause_at`` already reached while paused is spent, and would not stop a later run:
        so no reset here.) The controller must be active: in lock-step the step may wait
        for its command."""
        from std_srvs.srv import SetBool
        orch = self.orch
        before = orch.t
        orch.set_params('simulator', {'pause_at': PAUSE_NOW})
        orch.call(SetBool, 'simulator/pause', SetBool.Request(data=False))
        orch.spin_until(lambda: orch.t > before, 60, "the simulator's first step")

    # ---- a graph someone else started ---------------------------------------------------

    @classmethod
    def attach(cls, orch: Orchestrator, timeout: float = 10.0) -> Graph:
        """Drive the simulator, controller and recorder already running in the orchestrator's
        namespace (and ROS domain): check that all three are there (a :class:`GraphError`
        names what is missing), that the simulator runs in lock-step, pause it, activate the
        controller if it is not, close a bag the recorder has open, and lengthen the nodes'
        steady-time waits for the run (given back by :meth:`close`)."""
        from std_srvs.srv import SetBool
        services = {'simulator': 'simulator/reset', 'controller': 'controller/get_state',
                    'recorder': 'recorder/ready'}

        def missing():
            return [n for n, s in services.items() if not orch.service_ready(s)]
        with contextlib.suppress(GraphError):
            orch.spin_until(lambda: not missing(), timeout, 'the graph')
        gone = missing()
        if gone:
            where = (f'namespace {orch.namespace}' if orch.namespace else 'the root namespace')
            found = sorted(orch.nodes() - {orch.node.get_name()})
            raise GraphError(
                f'no {", ".join(gone)} in ROS domain {os.environ.get("ROS_DOMAIN_ID", "0")}, '
                f'{where} (looked {timeout:g} s; nodes seen there: {", ".join(found) or "none"})'
                ': start them (e.g. hydropump-graph --lock-step --start-paused), or drop '
                '--attach to start a graph of its own')
        sim = orch.get_params('simulator', ['lock_step', 'control_period', 'publish_rate',
                                            *LONG_WAITS['simulator']])
        if not sim['lock_step']:
            raise GraphError(f'{orch.name("simulator")} does not run in lock-step, so an '
                             'experiment could not start and end at exact instants: restart '
                             'it with -p lock_step:=true (hydropump-graph --lock-step)')
        graph = cls(orch, period=sim['control_period'], publish_rate=sim['publish_rate'])
        orch.call(SetBool, 'simulator/pause', SetBool.Request(data=True))
        graph._restore = {
            'simulator': {k: sim[k] for k in LONG_WAITS['simulator']},
            # Back in the order that keeps safe_timeout >= hold_timeout.
            'controller': dict(reversed(list(orch.get_params(
                'controller', LONG_WAITS['controller']).items()))),
            'recorder': orch.get_params('recorder', ['output', 'stop_time'])}
        try:
            graph._take_over(timeout)
        except BaseException:
            graph.close()
            raise
        return graph

    def _take_over(self, timeout: float) -> None:
        from lifecycle_msgs.msg import State, Transition
        from lifecycle_msgs.srv import ChangeState, GetState
        from std_srvs.srv import Trigger
        orch = self.orch
        # Steps already published may still be on their way: the clock settles first, so
        # that the next reset state is the latest /clock (a bounded wait, once).
        seen = [orch.t, time.monotonic()]

        def settled():
            if orch.t != seen[0]:
                seen[:] = [orch.t, time.monotonic()]
            return time.monotonic() - seen[1] > 0.3
        orch.spin_until(settled, 30, "the paused simulator's last step")
        state = orch.call(GetState, 'controller/get_state', GetState.Request()).current_state.id
        steps = {State.PRIMARY_STATE_UNCONFIGURED: [Transition.TRANSITION_CONFIGURE,
                                                    Transition.TRANSITION_ACTIVATE],
                 State.PRIMARY_STATE_INACTIVE: [Transition.TRANSITION_ACTIVATE]}
        if state not in steps and state != State.PRIMARY_STATE_ACTIVE:
            raise GraphError(f'{orch.name("controller")} is finalized: restart it')
        for tr in steps.get(state, []):
            if not orch.call(ChangeState, 'controller/change_state', ChangeState.Request(
                    transition=Transition(id=tr))).success:
                raise GraphError(f'{orch.name("controller")} refused lifecycle transition '
                                 f'{tr}')
        self._recorder_ready(timeout)
        stop = orch.call(Trigger, 'recorder/stop', Trigger.Request())
        if stop.success:
            self.notes.append(f'the recorder had a bag open: closed {stop.message}')
        # With the node's own lock-step timeout: a controller activated just now may not
        # answer the instant the simulator stands at, and the step would wait it out.
        self._prime()
        for node, values in LONG_WAITS.items():
            orch.set_params(node, values)

    def plant(self):
        """The running simulator's plant parameters (:class:`hydropump_sim.params.Params`)."""
        from hydropump_sim.params import Params, params_from_dict
        from hydropump_sim.schema import specs_of
        names = [s.name for s in specs_of(Params)]
        return params_from_dict(self.orch.get_params('simulator', names),
                                source=self.orch.name('simulator'))

    # ---- one experiment -----------------------------------------------------------------

    def _lifecycle(self, transition: int) -> None:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState
        req = ChangeState.Request(transition=Transition(id=transition))
        if not self.orch.call(ChangeState, 'controller/change_state', req).success:
            raise GraphError(f'the controller refused lifecycle transition {transition}'
                             + self._log_hint('controller'))

    def _log_hint(self, node: str) -> str:
        return f': see {self.log_dir / (node + ".log")}' if self.log_dir else ''

    def run(self, exp: Experiment, bag: Path,
            started: Callable[[float], None] | None = None) -> float:
        """Run ``exp`` into ``bag``; the simulation time [s] it started at (also given to
        ``started`` as it starts)."""
        from lifecycle_msgs.msg import Transition
        from std_srvs.srv import Trigger
        orch = self.orch
        self._lifecycle(Transition.TRANSITION_DEACTIVATE)
        if exp.ctrl_first:
            orch.set_params('controller', exp.ctrl_first)
        orch.set_params('controller', exp.ctrl)
        orch.set_params('simulator', exp.sim)
        orch.set_params('recorder', {'output': str(bag)})
        if not exp.preroll:
            self._open(bag)
        self._lifecycle(Transition.TRANSITION_ACTIVATE)
        before = orch.t
        if not orch.call(Trigger, 'simulator/reset', Trigger.Request()).success:
            raise GraphError('the simulator refused ~/reset')
        # The simulator has published a state (_prime): its reset state comes out at once.
        orch.spin_until(lambda: orch.t > before, 60, f'the reset of {exp.name}')
        t0 = orch.t
        if exp.preroll:  # run it, then open the bag: the start is settled
            t0 = self._grid(t0 + exp.preroll)
            self._run_to(t0, exp)
            self._open(bag)
        if started:
            started(t0)
        for t, node, values in self._schedule(exp, t0):
            if node == 'controller':
                # A controller change must reach it before its update at the event's
                # instant, and after the one before: pause one control period early, once the
                # controller has answered there.
                self._run_to(t - self.period, exp)
                orch.spin_until(lambda t=t: orch.ctrl_t >= t - self.period - 1e-9, 60,
                                f"the controller's update at {t - self.period:.6g} s in "
                                f'{exp.name}', poll=CLOCK_POLL)
            else:
                self._run_to(t, exp)
            orch.set_params(node, values)
        # One sample past the end, so that the current held from the last instant is out too;
        # the bag ends at the end exactly.
        end = self._grid(t0 + exp.duration)
        self._run_to(end + 1.0 / self.publish_rate, exp)
        orch.set_params('recorder', {'stop_time': end})
        closed = orch.call(Trigger, 'recorder/stop', Trigger.Request(), timeout=120)
        if not closed.success:
            # Its answer says why (a full disk: the bag closed with what was written).
            raise GraphError(f'the recorder did not close {bag}: {closed.message}'
                             + self._log_hint('recorder'))
        self._open_bag = None
        return t0

    def _grid(self, t: float) -> float:
        """The control instant at or after ``t`` [s]: where the simulator publishes and
        pauses."""
        return math.ceil(t / self.period - 1e-6) * self.period

    def _schedule(self, exp: Experiment, t0: float) -> list:
        """The events in the order the run meets them: at their control instants, a
        controller change one period before the simulator's of the same instant."""
        out = [(self._grid(t0 + float(t)), node, values) for t, node, values in exp.events]
        return sorted(out, key=lambda e: (e[0] - (self.period if e[1] == 'controller' else 0),
                                          e[1] != 'controller'))

    def _open(self, bag: Path) -> None:
        from std_srvs.srv import Trigger
        start = self.orch.call(Trigger, 'recorder/start', Trigger.Request())
        if not start.success:
            raise GraphError(f'the recorder could not open {bag}: {start.message}')
        self._open_bag = bag

    def _run_to(self, t: float, exp: Experiment) -> None:
        """Let the simulator run to simulation time ``t`` [s] and pause there."""
        from std_srvs.srv import SetBool
        orch = self.orch
        if orch.t >= t - 1e-9:
            return  # there already (two changes at one instant)
        orch.set_params('simulator', {'pause_at': t})
        t_run = time.perf_counter()
        orch.call(SetBool, 'simulator/pause', SetBool.Request(data=False))
        orch.spin_until(lambda: orch.t >= t - 1e-9, 600,
                        f'simulation time {t:g} s in {exp.name}', poll=CLOCK_POLL)
        self.running_s += time.perf_counter() - t_run

    def close(self) -> None:
        """Nodes started here: SIGINT, as ``ros2 launch`` stops a node (the recorder closes
        the bag it has open); SIGKILL after 20 s. Nodes attached to: the bag of a run cut
        short (Ctrl-C, SIGTERM, a failure) closed with what it has, their waits as they were,
        and the recorder's output."""
        from std_srvs.srv import Trigger
        procs = [p for p, _, _ in self.orch.procs.values()]
        if self._open_bag is not None and not procs:
            with contextlib.suppress(GraphError):
                self.orch.call(Trigger, 'recorder/stop', Trigger.Request(), timeout=30)
        self._open_bag = None
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self.orch.procs = {}
        restore, self._restore = self._restore, {}
        # Bounded: a command stopped by a signal must end (at most 15 s for a node's service
        # and three tries of 5 s for its answer).
        for node, values in restore.items():
            with contextlib.suppress(GraphError):
                self.orch.set_params(node, values, timeout=15.0, attempts=3)


# ---- runs -----------------------------------------------------------------------------------

def run_experiments(graph: Graph, exps: list[Experiment], bag_dir: Path,
                    head: Callable[[int, Experiment], str],
                    echo: Callable[[str], None] = print) -> dict[str, dict]:
    """Run ``exps`` one after the other through ``graph`` into ``bag_dir/<name>``, with a line
    as each starts (its simulation time) and as it ends (simulated and wall time).

    Returns
    -------
    dict
        Per experiment name: ``t0_s`` (the simulation time it started at), ``duration_s``,
        ``wall_s`` and ``bag``.
    """
    out = {}
    for i, exp in enumerate(exps, 1):
        bag = exp.bag(bag_dir)
        w0 = time.perf_counter()
        tag = head(i, exp)

        def started(t0, tag=tag, exp=exp, w0=w0):
            echo(f'{tag} {exp.label}: starts at t = {t0:.3f} s '
                 f'({time.perf_counter() - w0:.1f} s to set up)')
        t0 = graph.run(exp, bag, started)
        wall = time.perf_counter() - w0
        echo(f'{tag} ends at t = {t0 + exp.duration:.3f} s: {exp.duration:g} s simulated in '
             f'{wall:.1f} s -> {bag}')
        out[exp.name] = {'t0_s': t0, 'duration_s': exp.duration, 'wall_s': wall, 'bag': bag}
    return out


def own_domain(user: bool = True):
    """A context: a ROS domain of this host that no other graph of the domain coordinator
    holds (its number), with localhost discovery set for the processes started in it. With
    ``user`` and ``ROS_DOMAIN_ID`` set, that domain instead, the user's choice (they watch it
    from another terminal, or a test session chose it): held too where no one holds it, so
    that coordinated graphs keep out of it, and used as it is where its chooser holds it.
    Graphs started beside another (the demo's) take ``user=False``."""
    from domain_coordinator import domain_id
    from domain_coordinator.impl import PORT_BASE
    wanted = os.environ.get('ROS_DOMAIN_ID', '').strip() if user else ''
    if wanted and not (wanted.isdigit() and int(wanted) <= MAX_DOMAIN_ID):
        raise GraphError(f'ROS_DOMAIN_ID={wanted}: expected a whole number from 0 to '
                         f'{MAX_DOMAIN_ID}')

    @contextlib.contextmanager
    def users():
        did = int(wanted)
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            with contextlib.suppress(OSError):   # held already: by whoever chose it
                sock.bind(('', PORT_BASE + did))
            os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
            yield did
        finally:
            sock.close()

    @contextlib.contextmanager
    def coordinated():
        state = [random.randrange(100)]

        def pick() -> int:
            state[0] += 1
            return state[0] % 100 + 1
        with domain_id(pick) as did:
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
            os.environ['ROS_DOMAIN_ID'] = str(did)
            yield did
    return users() if wanted else coordinated()
