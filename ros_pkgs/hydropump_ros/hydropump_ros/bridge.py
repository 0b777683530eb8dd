"""Parameter bridge and message helpers shared by the nodes.

The schemas live in the pure packages (``hydropump_sim.params``, ``hydropump_sim.sensors``,
the controller's gains); this module only turns them into ROS parameter descriptors, reads
them back and reports bad values with the schema's one-line messages.
"""

from __future__ import annotations

from collections.abc import Iterable
import difflib
from typing import Any

from builtin_interfaces.msg import Time
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterAlreadyDeclaredException,
)
from rclpy.node import Node

from hydropump_sim.schema import check_value, ParamSpec, read_yaml, ros_parameters

# Parameters every rclpy node may receive without declaring them.
_BUILTIN = ('use_sim_time', 'start_type_description_service')


def descriptor(spec: ParamSpec, read_only: bool) -> ParameterDescriptor:
    """ROS descriptor of a schema entry: type, unit-first description, range, read-only."""
    ptype = {float: ParameterType.PARAMETER_DOUBLE, bool: ParameterType.PARAMETER_BOOL,
             str: ParameterType.PARAMETER_STRING, int: ParameterType.PARAMETER_INTEGER}
    d = ParameterDescriptor(name=spec.name, type=ptype[spec.type], read_only=read_only,
                            description=f'[{spec.unit}] {spec.desc}')
    lo, hi = spec.range
    if spec.type is float and lo is not None and hi is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                     step=0.0)]
    elif spec.type is int and lo is not None and hi is not None:
        d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
    if spec.choices:
        d.additional_constraints = 'one of: ' + ', '.join(spec.choices)
    return d


def declare(node: Node, specs: Iterable[ParamSpec], defaults: dict[str, Any],
            live: bool | None = None) -> tuple[dict[str, Any], list[str]]:
    """Declare schema parameters with file defaults; overrides (``--params-file``, ``-p``)
    win. Returns the values and one error line per bad override.

    Ranges are checked here with the schema's own message (unit, range, unit hints) rather than
    rclpy's generic exception. ``live=None`` takes each spec's own ``live`` flag; parameters
    that are not live are read-only.
    """
    values, errors = {}, []
    overrides = getattr(node, '_parameter_overrides', {})
    for s in specs:
        read_only = not (s.live if live is None else live)
        raw = overrides[s.name].value if s.name in overrides else defaults.get(s.name)
        if raw is None:
            errors.append(f'{s.name}: missing ({s.unit}, {s.desc})')
            continue
        if s.type is float and isinstance(raw, int) and not isinstance(raw, bool):
            raw = float(raw)
        value, err = check_value(s, raw)
        if err:
            errors.append(err)
            continue
        d = descriptor(s, read_only)
        try:
            node.declare_parameter(s.name, value, d, ignore_override=True)
        except (InvalidParameterTypeException, InvalidParameterValueException,
                ParameterAlreadyDeclaredException) as exc:
            errors.append(f'{s.name}: {exc}')
            continue
        values[s.name] = value
    return values, errors


def unknown_overrides(node: Node, known: Iterable[str]) -> list[str]:
    """One line per override that names no parameter of this node (probably a typo)."""
    known = set(known) | set(_BUILTIN)
    lines = []
    for name in getattr(node, '_parameter_overrides', {}):
        if name in known or name.startswith('qos_overrides.'):
            continue
        close = difflib.get_close_matches(name, sorted(known), n=1, cutoff=0.6)
        hint = f' (did you mean {close[0]}?)' if close else ''
        lines.append(f'{name}: unknown parameter of node {node.get_name()}{hint}')
    return lines


def validate_live(specs: dict[str, ParamSpec], params) -> SetParametersResult:
    """Check a batch of live parameter changes; a rejection carries the schema's reason."""
    for p in params:
        s = specs.get(p.name)
        if s is None:
            continue
        _, err = check_value(s, p.value)
        if err:
            return SetParametersResult(successful=False, reason=err)
    return SetParametersResult(successful=True)


def file_defaults(path: str) -> dict:
    """Flat ``{'group.key': value}`` defaults from a params file."""
    doc = ros_parameters(read_yaml(path))
    flat = {}
    for g, grp in (doc or {}).items():
        if isinstance(grp, dict):
            for k, v in grp.items():
                if isinstance(v, dict):
                    for kk, vv in v.items():
                        flat[f'{g}.{k}.{kk}'] = vv
                else:
                    flat[f'{g}.{k}'] = v
        else:
            flat[g] = grp
    return flat


class StartupError(Exception):
    """Bad configuration at start-up: ``lines`` are printed and the node exits with 2."""

    def __init__(self, lines):
        self.lines = list(lines)
        super().__init__('\n'.join(self.lines))


def build_or_exit(factory):
    """Construct a node; on :class:`StartupError` print its lines and return ``None``."""
    import sys

    import rclpy
    try:
        return factory()
    except StartupError as exc:
        for line in exc.lines:
            print(f'error: {line}', file=sys.stderr)
        rclpy.try_shutdown()
        return None


def init_or_exit(args=None) -> bool:
    """``rclpy.init`` that turns a bad command line (e.g. a missing ``--params-file``) into
    one ``error:`` line instead of a traceback; returns False when the node must exit."""
    import sys

    import rclpy
    try:
        rclpy.init(args=args)
    except Exception as exc:  # rclpy raises RCLError, without a public class to catch
        text = str(exc).replace('\n', ' ')
        print(f'error: cannot start: {text}', file=sys.stderr)
        return False
    return True


def stamp(t: float) -> Time:
    """Simulation time [s] as a ``builtin_interfaces/Time``."""
    ns = int(round(t * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def set_stamp(msg_time: Time, ns: int) -> None:
    """Write ``ns`` nanoseconds into an existing ``Time`` (no allocation in the hot loop)."""
    msg_time.sec = ns // 1_000_000_000
    msg_time.nanosec = ns % 1_000_000_000

