"""The ``foxglove`` node: the suite's topics, live, over the Foxglove WebSocket protocol.

Open ``ws://<host>:<port>`` in Foxglove (``config/foxglove/hydropump.json`` is a layout for
it). Each topic is a channel of JSON messages with a JSON schema titled with its ROS type;
pressures are as published (Pa absolute). A message's time is its header stamp (the
simulation time of its step), else the latest ``clock`` of the namespace (``/clock`` in the
root namespace); the server announces that clock to the clients as its time. The decisions
are pure (:mod:`hydropump_ctrl.foxglove`); this node subscribes and serves.

- The subscriptions are best effort: a viewer that falls behind drops messages, it never
  holds back a keep-all writer (the controller's command, a lock-step run).
- A message is converted only while a client subscribes to its channel: an idle view costs
  the graph little.
- Every ``discovery_period`` the graph is searched for the types of the configured topics
  not yet seen and, with ``discover``, for the other topics of the namespace.
"""

from __future__ import annotations

import importlib
import threading
import time

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message

from hydropump_ctrl.foxglove import (
    CLOCK,
    converter,
    discoverable,
    FoxgloveConfig,
    is_stamped,
    json_schema,
    RateLimit,
    TimeKeeper,
)
from hydropump_ctrl.recorder import header_stamp, SUITE_TYPES
from hydropump_sim.schema import spec_map, specs_of

from . import bridge, entry, subprotocols

CLOCK_TYPE = SUITE_TYPES['/clock']


def _msg_class(msgtype: str):
    """The message class of ``pkg/msg/Name`` (or ``pkg/Name``)."""
    parts = msgtype.split('/')
    return getattr(importlib.import_module(f'{parts[0]}.msg'), parts[-1])


def _fields_of(msgtype: str) -> dict[str, str]:
    return _msg_class(msgtype).get_fields_and_field_types()


class _Topic:
    """One served topic: its channel, message class, converter, time and rate rules."""

    def __init__(self, channel, cls, convert, stamped: bool, limit: RateLimit):
        self.channel = channel
        self.cls = cls
        self.convert = convert
        self.stamped = stamped
        self.limit = limit


class FoxgloveNode(bridge.ExplainedParameters, Node):
    """The suite's topics over the Foxglove WebSocket protocol (see the module)."""

    def __init__(self):
        super().__init__('foxglove')
        self.cfg = bridge.declare(self, FoxgloveConfig)
        self.schema_specs = spec_map(FoxgloveConfig)
        import foxglove
        from foxglove.websocket import Capability
        self._fox = foxglove
        # A context of our own: channels and server of this node only, not the SDK's global.
        self._ctx = foxglove.Context()
        try:
            # The SDK's server on a local port of its own, behind the relay that serves the
            # user's port under both subprotocol names (subprotocols.py).
            self._server = foxglove.start_server(
                name=f'hydropump {self.get_namespace()}', host='127.0.0.1', port=0,
                capabilities=[Capability.Time], context=self._ctx)
            try:
                self._relay = subprotocols.Relay(self.cfg.host, self.cfg.port,
                                                 self._server.port)
            except BaseException:
                self._server.stop()
                raise
        except Exception as exc:  # the SDK raises a bare RuntimeError (address in use, ...)
            raise bridge.StartupError([f'port = {self.cfg.port}: cannot serve on '
                                       f'{self.cfg.host}:{self.cfg.port}: '
                                       f'{" ".join(str(exc).split())}']) from None
        self._lock = threading.Lock()
        self._topics: dict[str, _Topic] = {}
        self._wanted = [self.resolve_topic_name(t) for t in self.cfg.topics]
        self._clock = self.resolve_topic_name(CLOCK)
        self._unknown: set[str] = set()       # types that do not import: said once
        self._time = TimeKeeper()
        self._qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT,
                               history=HistoryPolicy.KEEP_LAST)
        # The data subscriptions are served by a loop of their own (1 kHz topics), raw: a
        # message is deserialized only when a client wants it.
        self._io = entry.SideExecutor(self)
        try:
            self._io.subscribe(_msg_class(CLOCK_TYPE), CLOCK, self._on_clock, self._qos)
            for topic, name in zip(self._wanted, self.cfg.topics):
                msgtype = (CLOCK_TYPE if topic == self._clock else
                           SUITE_TYPES.get(name) or SUITE_TYPES.get(topic))
                if msgtype:
                    self._add(topic, msgtype)
        except BaseException:
            # A node that fails here never reaches close(): a side loop left running aborts
            # the process at exit.
            self.close()
            raise
        self.create_timer(self.cfg.discovery_period, self._discover,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f'ready: serving {len(self._topics)} topics on '
                               f'ws://{self.cfg.host}:{self._relay.port}')

    # ---- the graph -----------------------------------------------------------------------

    def _add(self, topic: str, msgtype: str) -> None:
        try:
            cls = _msg_class(msgtype)
            convert = converter(msgtype, _fields_of)
            schema = json_schema(msgtype, _fields_of)
        except (ImportError, AttributeError, ValueError):
            if msgtype not in self._unknown:
                self._unknown.add(msgtype)
                self.get_logger().warning(f'{topic}: type {msgtype} is not installed here; '
                                          'not served')
            return
        channel = self._fox.Channel(topic, schema=schema, context=self._ctx,
                                    metadata={'ros_type': msgtype})
        entry_ = _Topic(channel, cls, convert, is_stamped(cls.get_fields_and_field_types()),
                        RateLimit(self.cfg.max_rate))
        with self._lock:
            self._topics[topic] = entry_
        if topic != self._clock:  # served from the clock subscription
            self._subscribe(topic, cls)

    def _subscribe(self, topic: str, cls) -> None:
        # Served by the side loop, raw; the loop takes it into its wait set at its next wake.
        self._io.subscribe(cls, topic, lambda data, topic=topic: self._on_message(topic, data),
                           self._qos, raw=True)

    def _discover(self) -> None:
        missing = [t for t in self._wanted if t not in self._topics]
        if not missing and not self.cfg.discover:
            return
        ns = self.get_namespace()
        for topic, types in self.get_topic_names_and_types():
            if topic in self._topics or not types:
                continue
            if topic in missing or (self.cfg.discover and discoverable(topic, ns)):
                self._add(topic, types[0])
                if topic in self._topics:
                    self.get_logger().info(f'serving {topic} ({types[0]})')

    # ---- messages ------------------------------------------------------------------------

    def _on_clock(self, msg) -> None:
        ns = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        if self._time.clock(ns, time.monotonic()):
            self._server.broadcast_time(ns)
        served = self._topics.get(self._clock)
        if served is not None and served.channel.has_sinks() and served.limit.admit(ns):
            served.channel.log(served.convert(msg), log_time=ns)

    def _on_message(self, topic: str, data: bytes) -> None:
        served = self._topics.get(topic)
        if served is None or not served.channel.has_sinks():
            return
        t = self._time.log_time(header_stamp(data) if served.stamped else None)
        if not served.limit.admit(t):
            return
        msg = served.convert(deserialize_message(data, served.cls))
        served.channel.log(msg, log_time=t)

    def close(self) -> None:
        """SIGINT or SIGTERM: end the side loop, then the server (clients see it close)."""
        self._io.close()
        for served in list(self._topics.values()):
            served.channel.close()
        self._relay.stop()
        self._server.stop()


def main(args=None) -> int:
    return entry.run(FoxgloveNode, prog='foxglove', doc=__doc__,
                     specs=lambda: specs_of(FoxgloveConfig), args=args)


if __name__ == '__main__':
    raise SystemExit(main())
