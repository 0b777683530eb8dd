"""Start-up and shutdown of every node's ``main()``, as ROS users start and stop them.

- ``rclpy.init`` problems (a missing ``--params-file``) and bad parameters end with one
  ``error:`` line per problem and exit code 2, never a traceback.
- ``--help`` (before ``--ros-args``) prints the node's parameters and exits.
- SIGINT, a second SIGINT (``ros2 launch`` forwards a terminal's Ctrl-C, so each node gets
  two), and SIGTERM each end the node with exit code 0 and no traceback, at any moment,
  start-up included: the executables' entry points (:func:`simulator`, :func:`controller`,
  :func:`recorder`, :func:`foxglove`) install the handlers before the heavy imports; rclpy's
  own handlers are never installed. The first signal asks the node to stop, later ones are
  ignored. The executor spins in a thread while the main thread waits for the signal, then
  the node's ``close()`` stops its own work (stepping thread, take loop, open bag) *before*
  the executor and the context go, so nothing publishes on a dead context.

This module stays light (no rclpy, no numerics at import): it runs first.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
import contextlib
import importlib
import signal
import sys
import threading
import traceback

# Set by SIGINT or SIGTERM: the process is asked to end.
STOP = threading.Event()


def request_shutdown() -> None:
    """End the process as a signal would (a node that finds a fatal problem after start-up
    sets its ``exit_code`` first)."""
    STOP.set()


def install_signal_handlers() -> threading.Event:
    """SIGINT and SIGTERM set :data:`STOP` (again and again, harmlessly); returns it."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: STOP.set())
    return STOP


def _launch(module: str) -> int:
    install_signal_handlers()
    # The launcher (venv_index) starts Python with these blocked: one that came during the
    # interpreter's start is delivered now, to the handlers above.
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        mod = importlib.import_module(f'hydropump_ros.{module}')
    except KeyboardInterrupt:  # a Ctrl-C before our handlers were in place
        return 0
    return mod.main()


def simulator() -> int:
    """Entry point of ``ros2 run hydropump_ros simulator``."""
    return _launch('simulator_node')


def controller() -> int:
    """Entry point of ``ros2 run hydropump_ros controller``."""
    return _launch('controller_node')


def recorder() -> int:
    """Entry point of ``ros2 run hydropump_ros recorder``."""
    return _launch('recorder_node')


def foxglove() -> int:
    """Entry point of ``ros2 run hydropump_ros foxglove``."""
    return _launch('foxglove_node')


def dds_profile() -> None:
    """Point Fast DDS at the suite's writer settings (``config/fastdds.xml``: a fast
    heartbeat and a longer blocking time for keep-all writers), unless the environment names
    a profile file already."""
    import os
    if os.environ.get('FASTRTPS_DEFAULT_PROFILES_FILE'):
        return
    from hydropump_sim.params import default_params_path
    path = default_params_path().with_name('fastdds.xml')
    if path.is_file():
        os.environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(path)


def log(logger, level: str, text: str) -> None:
    """Log ``text`` at ``level`` (``info``, ``warn``, ``error``) from the pure libraries.

    rclpy ties a severity to each calling line, so each level has its own line here.
    """
    if level == 'error':
        logger.error(text)
    elif level == 'warn':
        logger.warning(text)
    else:
        logger.info(text)


def _help(prog: str, doc: str, specs: Iterable) -> str:
    from hydropump_sim.schema import default_text
    lines = [f'usage: ros2 run hydropump_ros {prog} [--ros-args -p NAME:=VALUE ...]', '',
             doc.strip().splitlines()[0], '', 'parameters (SI units):']
    for s in specs:
        live = ', live' if s.live else ''
        lines.append(f'  {s.name} = {default_text(s)}  [{s.unit}{live}]  {s.desc}')
    return '\n'.join(lines)


def run(factory: Callable[[], object], *, prog: str, doc: str,
        specs: Callable[[], Iterable], args: list[str] | None = None,
        before_spin: Callable[[object], None] | None = None) -> int:
    """Run a node to completion; return the process exit code.

    Parameters
    ----------
    factory : callable
        Builds the node (after ``rclpy.init``); may raise :class:`StartupError`.
    prog, doc, specs :
        Executable name, description and parameter schema, for ``--help``.
    args : list of str, optional
        Command line (default ``sys.argv``).
    before_spin : callable(node), optional
        Runs before the executor spins, in this thread (e.g. a lifecycle node's autostart).
    """
    argv = list(sys.argv if args is None else args)
    own = argv[1:argv.index('--ros-args')] if '--ros-args' in argv else argv[1:]
    if '-h' in own or '--help' in own:
        print(_help(prog, doc, specs()))
        return 0
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.utilities import remove_ros_args

    # A node takes its settings as ROS parameters only: anything else on the command line
    # (a mistyped flag, a file given without -p) is refused, not ignored.
    try:
        extra = remove_ros_args(argv)[1:]
    except Exception:  # noqa: BLE001 - a bad ROS argument: rclpy.init below words it
        extra = []
    if extra:
        print(f'error: {prog}: unexpected argument{"s" if len(extra) > 1 else ""} '
              f'{" ".join(extra)}: parameters go after --ros-args, as -p name:=value or '
              '--params-file FILE (see --help)', file=sys.stderr)
        return 2

    from .bridge import StartupError
    stop = install_signal_handlers()
    if stop.is_set():
        return 0
    dds_profile()
    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # rclpy raises RCLError, with no public class to catch
        print(f'error: cannot start: {" ".join(str(exc).split())}', file=sys.stderr)
        return 2
    install_signal_handlers()  # again: whatever rclpy.init did to the dispositions
    try:
        node = factory()
    except StartupError as exc:
        for line in exc.lines:
            print(f'error: {line}', file=sys.stderr)
        rclpy.try_shutdown()
        return 2
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    failure: list[BaseException] = []
    spinner = threading.Thread(target=_spin, args=(executor, stop, failure), name='executor',
                               daemon=True)
    try:
        if before_spin is not None:
            before_spin(node)
        spinner.start()
        while not stop.wait(0.5):
            pass
    finally:
        close = getattr(node, 'close', None)
        if close is not None:
            close()
        executor.shutdown(timeout_sec=2.0)
        if spinner.is_alive():
            spinner.join(timeout=2.0)
        node.destroy_node()
        # Keep our handlers: a second Ctrl-C during the rest of the exit must not kill us.
        if rclpy.ok():
            rclpy.shutdown(uninstall_handlers=False)
    # Python's finalisation puts the default disposition back for a Python handler (not for
    # SIG_IGN), and DDS threads still run then: a late Ctrl-C would kill the process (exit
    # code -2). From here on the signals are ignored.
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    if failure:  # a bug in a callback: show it whole
        traceback.print_exception(failure[0])
        return 1
    return getattr(node, 'exit_code', 0)


_UNSERVED = None


def unserved_group():
    """A callback group no executor serves (its ``can_execute`` is always false): the
    subscriptions in it stay on their node, where ``ros2 node info`` lists them, and a loop
    of the node's own takes their messages."""
    global _UNSERVED
    if _UNSERVED is None:
        from rclpy.callback_groups import CallbackGroup

        class Unserved(CallbackGroup):
            def can_execute(self, entity) -> bool:
                return False

            def beginning_execution(self, entity) -> bool:
                return False

            def ending_execution(self, entity) -> None:
                pass
        _UNSERVED = Unserved
    return _UNSERVED()


class SideExecutor:
    """A node's busiest subscriptions, served by a loop of their own in a thread of their
    own: one wait set over those subscriptions alone, and at each wake every message each
    ready one holds, handed to its callback directly. An rclpy executor rebuilds its wait set
    over every entity of its nodes and makes a task of each message: for the few topics a
    lock-step exchange waits on, that machinery was most of a node's CPU
    (bench/bench_ros.py). The subscriptions belong to the node itself, in a callback group
    its executor never serves (:func:`unserved_group`)."""

    def __init__(self, owner):
        from rclpy.guard_condition import GuardCondition
        self._owner = owner
        self.group = unserved_group()
        self._subs: list = []
        self._closed = False
        self._wake = GuardCondition(None, None, context=owner.context)
        self._thread = threading.Thread(target=self._spin, name='io', daemon=True)
        self._thread.start()

    def subscribe(self, msg_type, topic: str, callback, qos, raw: bool = False):
        sub = self._owner.create_subscription(msg_type, topic, callback, qos,
                                              callback_group=self.group, raw=raw)
        self._subs.append(sub)
        self._wake.trigger()  # into the wait set now
        return sub

    def unsubscribe(self, sub) -> None:
        self._subs.remove(sub)
        self._wake.trigger()
        self._owner.destroy_subscription(sub)

    def _spin(self) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        from rclpy.subscription import Subscription
        with_info = Subscription.CallbackType.WithMessageInfo
        ctx = self._owner.context
        try:
            while not self._closed and ctx.ok():
                subs = list(self._subs)
                with contextlib.ExitStack() as held:
                    # Held handles are destroyed only once the wait and the takes are done.
                    for sub in subs:
                        held.enter_context(sub.handle)
                    held.enter_context(self._wake.handle)
                    held.enter_context(ctx.handle)
                    ws = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, ctx.handle)
                    ws.clear_entities()
                    for sub in subs:
                        ws.add_subscription(sub.handle)
                    ws.add_guard_condition(self._wake.handle)
                    ws.wait(100_000_000)
                    ready = set(ws.get_ready_entities('subscription'))
                    for sub in subs:
                        if sub.handle.pointer not in ready:
                            continue
                        while not self._closed:
                            taken = sub.handle.take_message(sub.msg_type, sub.raw)
                            if taken is None:
                                break
                            if sub._callback_type is with_info:
                                sub.callback(*taken)
                            else:
                                sub.callback(taken[0])
        except Exception:  # the context going down at shutdown ends it
            if ctx.ok() and not self._closed:
                raise

    def close(self) -> None:
        """End the thread before the node goes: a node destroyed under a waiting loop
        aborts the process (a C++ thread left joinable), as a Ctrl-C at start-up showed."""
        self._closed = True
        self._wake.trigger()
        self._thread.join(timeout=2.0)
        self._wake.destroy()


def _spin(executor, stop: threading.Event, failure: list) -> None:
    try:
        executor.spin()
    except Exception as exc:  # an exception out of a callback ends the node
        if not stop.is_set():
            failure.append(exc)
            stop.set()
