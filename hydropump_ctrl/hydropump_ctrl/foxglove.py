"""The live view without ROS: the ``foxglove`` node's parameters, which topics it serves,
ROS messages as JSON with a JSON schema per message type, and the time of each message.

The node (``hydropump_ros.foxglove_node``) subscribes and hands the messages to the Foxglove
WebSocket server; everything it decides is here:

- :class:`FoxgloveConfig`: its parameters (one schema, defaults included);
- :func:`discoverable`: which topics of the graph it serves besides the configured ones (the
  circuit's ``ls_pressure``, ``loads/<name>/...``: whatever the namespace holds);
- :func:`converter` and :func:`json_schema`: a message as plain JSON values and the JSON
  schema of its type, both read from the type's field table (``{'name': 'ros type'}``, as a
  ROS message class's ``get_fields_and_field_types()`` gives it), so nothing here imports a
  message package;
- :class:`TimeKeeper`: the time of a message by the rule of time (its header stamp, else the
  latest ``/clock``; wall time only where neither exists);
- :class:`RateLimit`: at most ``max_rate`` messages per second of message time per topic.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import json
import math
from pathlib import Path
import re
from typing import Any

from hydropump_sim.schema import spec

from .recorder import DEFAULT_TOPICS as RECORDED

# The simulator's clock, relative: /clock in the root namespace, /<ns>/clock for a pump in
# namespace <ns> (several pumps in one domain, docs/ros.md).
CLOCK = 'clock'
# What the view serves by default: what the recorder records, and time and health.
DEFAULT_TOPICS = [*RECORDED, CLOCK, '/diagnostics']
# Topics of every ROS graph that no plot wants.
SYSTEM_TOPICS = ('/rosout', '/parameter_events')
# A field table: ROS type name -> {field: ROS type} (get_fields_and_field_types()).
FieldsOf = Callable[[str], Mapping[str, str]]


@dataclass(frozen=True)
class FoxgloveConfig:
    """The foxglove node's parameters."""

    host: str = spec('-', 'address the WebSocket server listens on (0.0.0.0: every interface '
                     'of the machine)', default='127.0.0.1')
    port: int = spec('-', 'TCP port of the WebSocket server; 0 = any free port (logged)', 0,
                     65535, default=8765)
    topics: list = spec('-', 'topics served (relative names resolve in the namespace)',
                        default=DEFAULT_TOPICS)
    discover: bool = spec('-', 'also serve every other topic of the namespace as it appears '
                          "in the graph (a circuit's ls_pressure, loads/<name>/...)",
                          default=True)
    discovery_period: float = spec('s', 'steady-clock period of the look for new topics and '
                                   'their types', 0.1, 60.0, default=1.0)
    max_rate: float = spec('Hz', 'at most this many messages per second of message time per '
                           'topic to the clients (a slow link); 0 = every message', 0.0, 1.0e6,
                           default=0.0)

    def cross_checks(self) -> list[str]:
        if not self.host.strip():
            return ["host = '': give an address to listen on, e.g. 127.0.0.1"]
        return []


def discoverable(topic: str, namespace: str) -> bool:
    """Whether a topic found in the graph belongs to the suite in ``namespace``: below it,
    not hidden (no name part starting with ``_``) and not one of every graph's own."""
    if topic in SYSTEM_TOPICS:
        return False
    if any(part.startswith('_') for part in topic.strip('/').split('/')):
        return False
    ns = namespace.rstrip('/')
    return ns == '' or topic.startswith(ns + '/')


# ---- messages as JSON --------------------------------------------------------------------

_NUMBER = ('float', 'double', 'long double', 'float32', 'float64')
_INTEGER = ('int8', 'uint8', 'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64', 'short',
            'unsigned short', 'long', 'unsigned long', 'long long', 'unsigned long long')
# rclpy gives a `byte` (`octet`) as a one-byte bytes object; JSON wants the number.
_BYTE = ('octet', 'byte')
_STRING = ('string', 'wstring', 'char')
_SEQUENCE = re.compile(r'^sequence<(.+?)(?:,\s*\d+)?>$')
_ARRAY = re.compile(r'^(.+)\[\d*\]$')
_BOUNDED = re.compile(r'^(w?string)<=\d+$')


def _element(ros_type: str) -> str | None:
    """The element type of a sequence or array type, or ``None`` for a single value."""
    m = _SEQUENCE.match(ros_type) or _ARRAY.match(ros_type)
    return m.group(1).strip() if m else None


def _base(ros_type: str) -> str:
    m = _BOUNDED.match(ros_type)
    return m.group(1) if m else ros_type


def _finite(v: Any) -> float | None:
    # JSON has no NaN or infinity (a browser's JSON.parse refuses them): they become null.
    v = float(v)
    return v if math.isfinite(v) else None


def _byte(v: Any) -> int:
    return v[0] if isinstance(v, (bytes, bytearray)) else int(v)


def _items(v: Any) -> list:
    # array.array and numpy arrays (rclpy's numeric sequences) give plain numbers with tolist.
    return v.tolist() if hasattr(v, 'tolist') else list(v)


def converter(msgtype: str, fields_of: FieldsOf) -> Callable[[Any], dict]:
    """A function from a message of ``msgtype`` to plain JSON values (dicts, lists, numbers,
    strings; a non-finite float becomes ``None``), built once per type."""
    cache: dict[str, Callable[[Any], Any]] = {}

    def of(ros_type: str) -> Callable[[Any], Any]:
        if ros_type in cache:
            return cache[ros_type]
        elem = _element(ros_type)
        base = _base(ros_type)
        if elem is not None:
            one = of(elem)
            if _base(elem) in _BYTE:
                # A sequence of bytes may come as one bytes object.
                def fn(v):
                    return [_byte(x) if not isinstance(x, int) else x for x in v]
            elif _base(elem) in _NUMBER:
                def fn(v):
                    return [x if math.isfinite(x) else None for x in _items(v)]
            else:
                def fn(v, one=one):
                    return [one(x) for x in _items(v)]
        elif base in _NUMBER:
            fn = _finite
        elif base in _INTEGER:
            fn = int
        elif base == 'boolean' or base == 'bool':
            fn = bool
        elif base in _BYTE:
            fn = _byte
        elif base in _STRING:
            fn = str
        else:
            table = list(fields_of(base).items())
            subs = [(name, of(t)) for name, t in table]

            def fn(v, subs=subs):
                return {name: sub(getattr(v, name)) for name, sub in subs}
        cache[ros_type] = fn
        return fn

    return of(msgtype)


def _schema(ros_type: str, fields_of: FieldsOf) -> dict:
    elem = _element(ros_type)
    base = _base(ros_type)
    if elem is not None:
        return {'type': 'array', 'items': _schema(elem, fields_of)}
    if base in _NUMBER:
        return {'type': ['number', 'null']}
    if base in _INTEGER or base in _BYTE:
        return {'type': 'integer'}
    if base in ('boolean', 'bool'):
        return {'type': 'boolean'}
    if base in _STRING:
        return {'type': 'string'}
    fields = fields_of(base)
    return {'type': 'object', 'properties': {n: _schema(t, fields_of) for n, t in
                                             fields.items()},
            'required': list(fields)}


def json_schema(msgtype: str, fields_of: FieldsOf) -> dict:
    """The JSON schema of the messages :func:`converter` makes of ``msgtype``, titled with the
    ROS type name (``sensor_msgs/msg/FluidPressure``): Foxglove's panels pick their topics by
    that name (the diagnostics panels take ``diagnostic_msgs/msg/DiagnosticArray``)."""
    return {**_schema(msgtype, fields_of), 'title': msgtype}


def is_stamped(fields: Mapping[str, str]) -> bool:
    """Whether a message type starts with a ``std_msgs/Header`` (its time is the stamp)."""
    first = next(iter(fields.items()), None)
    return first is not None and first[0] == 'header' and first[1] in (
        'std_msgs/Header', 'std_msgs/msg/Header')


# ---- time --------------------------------------------------------------------------------

class TimeKeeper:
    """The time each message is served with [ns], by the suite's rule of time: a message with
    a header keeps its stamp (the simulation time of its step); one without takes the latest
    ``/clock``; with neither, ``None`` (the server then uses wall time). Also when the server
    announces the time to the clients: at most every ``broadcast_period`` seconds of steady
    time, and at once when simulation time goes back (a new simulator)."""

    def __init__(self, broadcast_period: float = 0.05):
        self.clock_ns: int | None = None
        self._period = broadcast_period
        self._last_broadcast: float | None = None

    def clock(self, ns: int, now: float) -> bool:
        """A ``/clock`` of ``ns`` arrived at steady time ``now`` [s]; whether to broadcast."""
        back = self.clock_ns is not None and ns < self.clock_ns
        self.clock_ns = ns
        if back or self._last_broadcast is None or now - self._last_broadcast >= self._period:
            self._last_broadcast = now
            return True
        return False

    def log_time(self, stamp_ns: int | None) -> int | None:
        return stamp_ns if stamp_ns is not None else self.clock_ns


class RateLimit:
    """At most ``rate`` messages per second of message time (0: all). Time that goes back
    (a new simulator) starts afresh; a message without a time always passes."""

    def __init__(self, rate: float):
        self._step = int(round(1e9 / rate)) if rate > 0 else 0
        self._last: int | None = None

    def admit(self, t_ns: int | None) -> bool:
        if not self._step or t_ns is None:
            return True
        if self._last is None or t_ns < self._last or t_ns - self._last >= self._step:
            self._last = t_ns
            return True
        return False


# ---- layouts ---------------------------------------------------------------------------------

# The plots a circuit adds to the shipped layout: (panel, title, the kinds of
# measure.model_topics it plots).
CIRCUIT_PLOTS = (('Plot!circuit_pressures', 'Circuit pressures [Pa abs]',
                  ('pressure',)),
                 ('Plot!circuit_flows', 'Load flows [m^3/s]', ('flow',)),
                 ('Plot!circuit_positions', 'Load positions [m, rad]', ('position', 'angle')),
                 ('Plot!circuit_speeds', 'Load speeds [m/s, rad/s]', ('velocity', 'speed')))
COLOURS = ('#1f77b4', '#d62728', '#2ca02c', '#ff7f0e', '#9467bd', '#8c564b', '#e377c2',
           '#7f7f7f', '#bcbd22', '#17becf')
# What marks a layout file as one this suite wrote (hydropump-graph replaces only those).
WRITTEN_BY = 'hydropump'
# The shipped layout of a pump in the root namespace.
BASE_LAYOUT = Path(__file__).resolve().parents[2] / 'config' / 'foxglove' / 'hydropump.json'


def layout(base: Mapping[str, Any], namespace: str = '', topics=()) -> dict:
    """The Foxglove layout ``base`` (``config/foxglove/hydropump.json``) for a graph in
    ``namespace``: every topic it names moved under the namespace; with a circuit's
    ``topics`` (:func:`hydropump_sim.measure.model_topics`) a row of plots of what the
    circuit adds (its load-sensing and load pressures, load flows, load motion).
    Pressures are FluidPressure (``.fluid_pressure``), the rest Float64 (``.data``)."""
    import copy
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''

    def under(topic: str) -> str:
        return ns + '/' + topic.lstrip('/')
    out = copy.deepcopy(dict(base))
    for panel in out['configById'].values():
        for path in panel.get('paths', []):
            path['value'] = under(path['value'])
        if 'topicToRender' in panel and panel['topicToRender'] != '/diagnostics':
            panel['topicToRender'] = under(panel['topicToRender'])
    row = []
    template = next(p for p in out['configById'].values() if 'paths' in p)
    for panel_id, title, kinds in CIRCUIT_PLOTS:
        chosen = [t for t in topics if t.kind in kinds]
        if not chosen:
            continue
        paths = [{'value': under(t.topic) + ('.fluid_pressure' if t.kind == 'pressure'
                                             else '.data'),
                  'label': t.topic, 'enabled': True, 'timestampMethod': 'receiveTime',
                  'color': COLOURS[k % len(COLOURS)]} for k, t in enumerate(chosen)]
        out['configById'][panel_id] = {**{k: v for k, v in template.items()
                                          if k not in ('title', 'paths')},
                                       'title': title, 'paths': paths}
        row.append(panel_id)
    if row:
        tree: Any = row[-1]
        for panel_id in reversed(row[:-1]):
            tree = {'direction': 'row', 'first': panel_id, 'second': tree}
        out['layout'] = {'direction': 'column', 'splitPercentage': 75,
                         'first': out['layout'], 'second': tree}
    out['globalVariables'] = {**out.get('globalVariables', {}), 'written_by': WRITTEN_BY,
                              'namespace': ns or '/'}
    return out


def write_layout(path: Path, namespace: str = '', circuit_file: str | None = None) -> Path:
    """Write :func:`layout` for a graph in ``namespace`` with the circuit of ``circuit_file``
    (its structure only: nothing is compiled) to ``path``, whole or not at all
    (:class:`~hydropump_sim.files.WriteError` on a full disk). A file there that this suite
    did not write is never replaced: :class:`FileExistsError`."""
    from hydropump_sim.measure import model_topics
    topics = []
    if circuit_file:
        from hydropump_sim.circuit import load_circuit
        topics = model_topics(load_circuit(circuit_file, compile=False))[0]
    if path.exists():
        try:
            ours = json.loads(path.read_text())['globalVariables']['written_by'] == WRITTEN_BY
        except (OSError, ValueError, KeyError, TypeError):
            ours = False
        if not ours:
            raise FileExistsError(f'{path}: exists and is not a layout hydropump wrote; '
                                  'move it, or run from another folder')
    from hydropump_sim.files import write_text
    return write_text(path, json.dumps(layout(json.loads(BASE_LAYOUT.read_text()), namespace,
                                              topics), indent=2) + '\n', 'Foxglove layout')
