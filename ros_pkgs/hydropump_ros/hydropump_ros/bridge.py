"""The schema -> ROS parameter bridge shared by the nodes.

The schemas live in the pure packages (:mod:`hydropump_sim.schema` and the dataclasses built
on it); this module only turns them into ``ParameterDescriptor`` declarations, reads the
values back as the typed configuration, and answers a refused change with the schema's own
one-line reason (unit, range, unit hint) instead of rclpy's generic one.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.node import Node

from hydropump_sim.errors import HydropumpError
from hydropump_sim.schema import (
    build,
    check_value,
    ParamError,
    ParamSpec,
    specs_of,
    unknown_key_line,
)

# Parameters every rclpy node may receive without declaring them.
BUILTIN = ('use_sim_time', 'start_type_description_service')

_PTYPE = {float: ParameterType.PARAMETER_DOUBLE, bool: ParameterType.PARAMETER_BOOL,
          str: ParameterType.PARAMETER_STRING, int: ParameterType.PARAMETER_INTEGER,
          list: ParameterType.PARAMETER_STRING_ARRAY}


class StartupError(HydropumpError):
    """Bad configuration at start-up: the lines are printed and the node exits with 2."""


def overrides(node: Node) -> dict[str, Any]:
    """The parameter overrides the node was started with (``--params-file``, ``-p``), as plain
    values. rclpy keeps them in a private attribute; this is the one place that reads it."""
    raw = getattr(node, '_parameter_overrides', None) or {}
    return {name: p.value for name, p in raw.items()}


def descriptor(spec: ParamSpec, read_only: bool) -> ParameterDescriptor:
    """ROS descriptor of a schema entry: type, unit-first description, range, read-only."""
    d = ParameterDescriptor(name=spec.name, type=_PTYPE[spec.type], read_only=read_only,
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


class Declarer:
    """Declares the parameters of one or more schemas on a node, collecting every problem,
    so that a user sees all bad values at once (:meth:`finish` raises them)."""

    def __init__(self, node: Node):
        self.node = node
        self.given = overrides(node)
        self.errors: list[str] = []
        self.specs: dict[str, ParamSpec] = {}

    def declare(self, cls: type, defaults: Mapping[str, Any] | None = None, *,
                source: str | None = None, read_only: bool | None = None):
        """Declare every parameter of the schema dataclass ``cls``; return the typed,
        cross-checked configuration, or ``None`` (the problems are kept for :meth:`finish`).

        Values come from the overrides, else ``defaults`` (e.g. a params file's values),
        else the schema's own defaults. Parameters that are not ``live`` are read-only, or
        all of them with ``read_only=True``.
        """
        defaults = defaults or {}
        values, bad = {}, False
        for s in specs_of(cls):
            self.specs[s.name] = s
            if s.name in self.given:
                raw = self.given[s.name]
            elif s.name in defaults:
                raw = defaults[s.name]
            elif not s.required:
                raw = s.default
            else:
                self.errors.append(f'{s.name}: missing ({s.unit}, {s.desc})'
                                   + (f' in {source}' if source else ''))
                bad = True
                continue
            value, err = check_value(s, raw)
            if err:
                where = '' if s.name in self.given or not source else f' (in {source})'
                self.errors.append(err + where)
                bad = True
                continue
            ro = (not s.live) if read_only is None else read_only
            self.node.declare_parameter(s.name, value, descriptor(s, ro), ignore_override=True)
            values[s.name] = value
        if bad:
            return None
        try:
            return build(cls, values, source)
        except ParamError as exc:
            self.errors += exc.lines
            return None

    def declare_specs(self, specs: Iterable[ParamSpec]) -> None:
        """Declare entries that no schema class holds (a circuit's inputs), each at its
        override or default; the bad ones are kept for :meth:`finish`."""
        for s in specs:
            self.specs[s.name] = s
            value, err = check_value(s, self.given.get(s.name, s.default))
            if err:
                self.errors.append(err)
                continue
            self.node.declare_parameter(s.name, value, descriptor(s, not s.live),
                                        ignore_override=True)

    def finish(self, pending: tuple[str, ...] = ()) -> None:
        """Raise :class:`StartupError` for every problem, and for every override that names
        no parameter of the node (probably a typo) but those under a ``pending`` prefix
        (declared later, once known)."""
        known = set(self.specs) | set(BUILTIN)
        for name in self.given:
            if pending and name.startswith(pending):
                continue
            if name not in known and not name.startswith('qos_overrides.'):
                self.errors.append(unknown_key_line(name, sorted(known),
                                                    f'parameter of node {self.node.get_name()}'))
        if self.errors:
            raise StartupError(self.errors)


def declare(node: Node, cls: type, defaults: Mapping[str, Any] | None = None):
    """Declare the schema ``cls`` alone on ``node``: the typed configuration, or
    :class:`StartupError` with every problem."""
    d = Declarer(node)
    cfg = d.declare(cls, defaults)
    d.finish()
    return cfg


def refusal(specs: Mapping[str, ParamSpec], params: Iterable) -> str | None:
    """The schema's reason for refusing a batch of parameter changes, or ``None``."""
    for p in params:
        s = specs.get(p.name)
        if s is None:
            continue
        if s.type is float and isinstance(p.value, int) and not isinstance(p.value, bool):
            continue  # rclpy refuses the type itself, with a clear reason
        _, err = check_value(s, p.value)
        if err:
            return err
        if not s.live:
            return f'{p.name} is read-only while the node runs (restart it to change it)'
    return None


class ExplainedParameters:
    """Node mixin: a refused parameter change (``ros2 param set``) answers with the schema's
    reason, unit hint included, rather than rclpy's generic range message. The node keeps its
    schema entries in ``self.schema_specs``."""

    schema_specs: dict[str, ParamSpec] = {}

    def set_parameters_atomically(self, parameter_list) -> SetParametersResult:
        result = super().set_parameters_atomically(parameter_list)
        if not result.successful:
            reason = refusal(self.schema_specs, parameter_list)
            if reason:
                result.reason = reason
        return result


def result(reason: str | None) -> SetParametersResult:
    """A ``SetParametersResult``: refused with ``reason``, or accepted."""
    return SetParametersResult(successful=reason is None, reason=reason or '')
