"""The parameter schema of the whole project: specs, checks, flattening, hints, YAML.

Every configurable thing (the plant, the sensor profile, the controller, the node
configurations) is a frozen dataclass whose fields carry their schema as metadata, made with
:func:`spec` (a value) or :func:`group` (a nested dataclass, one dotted level of the name).
This module is the one place that

- turns such a dataclass into :class:`ParamSpec` entries (type, unit, description, range or
  choices, default, ``live``), for the ROS parameter bridge, the docs and the checks;
- checks and coerces a value with one-line messages that name the value, the unit, the accepted
  range and, for a value typed in a common non-SI unit, what it looks like (``120 bar``);
- flattens nested mappings to dotted names, suggests the nearest name for a typo;
- builds a validated instance from a mapping (:func:`build`), running the class's own
  ``cross_checks()`` for relations between values;
- reads ROS 2 params files (YAML) without tracebacks, and writes them back.

Nothing here knows a particular parameter.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
import dataclasses
from dataclasses import dataclass, field, fields, is_dataclass
import difflib
import functools
import math
from pathlib import Path
import typing
from typing import Any

import yaml

from .errors import HydropumpError


class _Required:
    """The default of an entry that a parameter file must give."""

    def __repr__(self) -> str:
        return 'REQUIRED'


REQUIRED = _Required()


class ParamError(HydropumpError, ValueError):
    """Invalid parameters: ``lines`` holds one human-readable line per problem."""

    head = 'invalid parameters'


def spec(unit: str, desc: str, lo: float | None = None, hi: float | None = None, *,
         choices: tuple[str, ...] | None = None, default: Any = REQUIRED, live: bool = False):
    """Field of a schema dataclass: unit, description, accepted range or choices, default.

    A field without a default is required in a parameter file. ``live`` marks a parameter
    that may change while a node runs; all others are read-only there. A mutable default
    (a list) is copied per instance.
    """
    meta = {'unit': unit, 'desc': desc, 'range': (lo, hi), 'choices': choices, 'live': live}
    if default is REQUIRED or default is dataclasses.MISSING:
        return field(metadata=meta)
    if isinstance(default, list):
        return field(default_factory=functools.partial(list, default), metadata=meta)
    return field(default=default, metadata=meta)


def group(name: str | None = None, *, factory: Callable[[], Any] | None = None):
    """Field holding a nested schema dataclass: one level of the dotted names.

    ``name`` is the name's prefix (default: the field name; ``'pi.flow'`` for a field
    ``pi_flow``). ``factory`` (the group's class, when all its fields have defaults) makes the
    group optional in a constructor call; in a file every group is optional when its entries
    have defaults.
    """
    meta = {'group': name}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(metadata=meta)


@dataclass(frozen=True)
class ParamSpec:
    """One schema entry: what the ROS parameter bridge, the checks and the docs need."""

    name: str
    type: type
    unit: str
    desc: str
    range: tuple = (None, None)
    choices: tuple | None = None
    live: bool = False
    default: Any = REQUIRED

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def with_default(self, value: Any) -> ParamSpec:
        """The same entry with another default (e.g. one read from a params file)."""
        return dataclasses.replace(self, default=value)


_TYPES = {'float': float, 'int': int, 'bool': bool, 'str': str, 'list': list}


@functools.cache
def _type_hints(cls: type) -> dict[str, Any]:
    # Resolving the annotations compiles them: once per class, not per validation.
    return typing.get_type_hints(cls)


def _field_type(cls: type, f: dataclasses.Field) -> Any:
    return _type_hints(cls)[f.name]


def _group_fields(cls: type) -> Iterator[tuple[dataclasses.Field, str, type | None]]:
    """``(field, name prefix, nested class or None)`` for every field of ``cls``."""
    for f in fields(cls):
        if 'group' in f.metadata:
            sub = _field_type(cls, f)
            sub = next((a for a in typing.get_args(sub) if is_dataclass(a)), sub)
            yield f, f.metadata['group'] or f.name, sub
        elif 'unit' in f.metadata:
            yield f, f.name, None


def _scalar_type(cls: type, f: dataclasses.Field) -> type:
    t = _field_type(cls, f)
    origin = typing.get_origin(t) or t
    return _TYPES[origin.__name__]


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return REQUIRED


@functools.cache
def specs_of(cls: type, prefix: str = '') -> tuple[ParamSpec, ...]:
    """Every parameter of a schema dataclass, in declaration order, with dotted names."""
    out = []
    for f, name, sub in _group_fields(cls):
        full = f'{prefix}{name}'
        if sub is not None:
            out.extend(specs_of(sub, full + '.'))
            continue
        m = f.metadata
        out.append(ParamSpec(full, _scalar_type(cls, f), m['unit'], m['desc'], m['range'],
                             m['choices'], m['live'], _default(f)))
    return tuple(out)


def spec_map(cls: type) -> dict[str, ParamSpec]:
    """Schema entries of ``cls`` by dotted name."""
    return {s.name: s for s in specs_of(cls)}


# ---- values ------------------------------------------------------------------------------

# Common non-SI units a value may have been typed in: SI unit -> (factor to SI, unit name).
UNIT_HINTS = {
    'Pa': (1.0e5, 'bar'),
    'm': (1.0e-3, 'mm'),
    'm^3/s': (1.0 / 60000.0, 'L/min'),
    'Hz': (1.0 / 60.0, 'rpm'),
    'm^3': (1.0e-6, 'cm^3'),
    'm^3/rev': (1.0e-6, 'cm^3/rev'),
    's': (1.0e-3, 'ms'),
}


def fmt(v: float) -> str:
    """A number as the messages show it (six significant digits)."""
    return f'{v:.6g}'


def must_exceed(hi_name: str, hi: float, lo_name: str, lo: float, unit: str = 'Pa'
                ) -> list[str]:
    """The line that refuses ``hi <= lo`` (a full-open pressure at or below its crack), or
    none."""
    if hi > lo:
        return []
    return [f'{hi_name} = {fmt(hi)} {unit} must exceed {lo_name} = {fmt(lo)} {unit}']


def with_unit(value: float, unit: str) -> str:
    """``'120 Pa'``; a dimensionless value (unit ``-``) stands alone."""
    return fmt(value) if unit in ('-', '') else f'{fmt(value)} {unit}'


def text_number_hint(value: Any) -> str:
    """Why a number came as text, when it did: YAML 1.1 reads ``1.2e7`` (no dot, no
    exponent sign) as a string (``''`` for anything else)."""
    if not isinstance(value, str):
        return ''
    try:
        float(value)
    except (TypeError, ValueError):
        return ''
    return ' (YAML read it as text: write a dot and a signed exponent, e.g. 1.5e+9)'


def check_number(value: Any, where: str, errors: list[str], *, unit: str = '',
                 sign: str = '') -> float | None:
    """``value`` as a float if it is a finite number (and ``sign`` holds: ``'> 0'`` or
    ``'>= 0'``), else ``None`` and one line in ``errors``, with the hint for a number YAML
    read as text: the one number check of every file format (scenarios, recording plans,
    sweep specs)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and \
        math.isfinite(value)
    if ok and sign:
        ok = value > 0 if sign == '> 0' else value >= 0
    if ok:
        return float(value)
    errors.append(f'{where} = {value!r}: expected a finite number{" " + sign if sign else ""}'
                  f'{f" ({unit})" if unit else ""}{text_number_hint(value)}')
    return None


def range_text(s: ParamSpec) -> str:
    lo, hi = s.range
    lo_t = '-inf' if lo is None else fmt(lo)
    hi_t = 'inf' if hi is None else fmt(hi)
    unit = '' if s.unit == '-' else s.unit
    return f'[{lo_t}, {hi_t}] {unit}'.rstrip()


def unit_hint(s: ParamSpec, value: float) -> str:
    """``' (looks like a value in bar: 120 bar = 1.2e+07 Pa)'`` or ``''``."""
    if s.unit not in UNIT_HINTS or not value > 0:
        return ''
    factor, uname = UNIT_HINTS[s.unit]
    conv = value * factor
    lo, hi = s.range
    if (lo is None or conv >= lo) and (hi is None or conv <= hi):
        return f' (looks like a value in {uname}: {fmt(value)} {uname} = {fmt(conv)} {s.unit})'
    return ''


def _inside(s: ParamSpec, value: float) -> bool:
    lo, hi = s.range
    return (lo is None or value >= lo) and (hi is None or value <= hi)


def check_value(s: ParamSpec, value: Any) -> tuple[Any, str | None]:
    """Coerce and check one value: ``(value, None)`` or ``(None, one-line reason)``.

    Floats accept integers; integers accept integral floats; a number that YAML read as text
    (``1.5e9``) is refused with the fix. Out-of-range values name the range and, where it fits,
    the non-SI unit they look like.
    """
    if s.type is bool:
        if isinstance(value, bool):
            return value, None
        return None, f'{s.name} = {value!r}: expected true or false ({s.desc})'
    if s.type is str:
        if isinstance(value, str) and (s.choices is None or value in s.choices):
            return value, None
        if s.choices:
            return None, f'{s.name} = {value!r}: expected one of {", ".join(s.choices)}'
        return None, f'{s.name} = {value!r}: expected text ({s.desc})'
    if s.type is list:
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return list(value), None
        return None, f'{s.name} = {value!r}: expected a list of names ({s.desc})'
    if isinstance(value, str):
        return None, (f'{s.name} = {value!r}: not a number{text_number_hint(value)}; '
                      f'expected {range_text(s)}')
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None, f'{s.name} = {value!r}: not a number; expected {range_text(s)}'
    if s.type is int:
        if isinstance(value, float):
            if not value.is_integer():
                return None, f'{s.name} = {value!r}: expected an integer in {range_text(s)}'
            value = int(value)
        if not _inside(s, value):
            return None, (f'{s.name} = {value}: outside the accepted range {range_text(s)} '
                          f'({s.desc})')
        return value, None
    value = float(value)
    if not math.isfinite(value):
        return None, f'{s.name} = {value!r}: not finite; expected {range_text(s)}'
    if not _inside(s, value):
        return None, (f'{s.name} = {with_unit(value, s.unit)}: outside the accepted range '
                      f'{range_text(s)} ({s.desc}){unit_hint(s, value)}')
    return value, None


# ---- names -------------------------------------------------------------------------------

def flatten(data: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested groups (``pi: {flow: {p: 1}}``) or dotted keys to ``{'pi.flow.p': 1}``."""
    flat: dict[str, Any] = {}
    for key, val in data.items():
        key = f'{prefix}{key}'
        if isinstance(val, Mapping):
            flat.update(flatten(val, key + '.'))
        else:
            flat[key] = val
    return flat


def closest_name(key: str, names: Iterable[str]) -> str | None:
    """The known name nearest to a mistyped ``key``, or ``None``."""
    names = list(names)
    close = difflib.get_close_matches(key, names, n=1, cutoff=0.6)
    if close:
        return close[0]
    # Compare the last part within the same group, then across groups ('mc' -> 'spool.m_c',
    # 'rho' -> 'fluid.rho').
    head, _, last = key.rpartition('.')
    same = [n for n in names if n.rpartition('.')[0] == head]
    close = difflib.get_close_matches(last, [n.rpartition('.')[2] for n in same], n=1)
    if close:
        return f'{head}.{close[0]}' if head else close[0]
    exact = [n for n in names if n.rpartition('.')[2] == last]
    return exact[0] if len(exact) == 1 else None


def unknown_key_line(key: str, names: Iterable[str], what: str = 'parameter') -> str:
    """``'spool.mc: unknown parameter (did you mean spool.m_c?)'``."""
    close = closest_name(key, names)
    hint = f' (did you mean {close}?)' if close else ''
    return f'{key}: unknown {what}{hint}'


# ---- building ----------------------------------------------------------------------------

def _construct(cls: type, values: Mapping[str, Any], prefix: str = ''):
    kwargs = {}
    for f, name, sub in _group_fields(cls):
        full = f'{prefix}{name}'
        if sub is not None:
            kwargs[f.name] = _construct(sub, values, full + '.')
        elif full in values:
            kwargs[f.name] = values[full]
    return cls(**kwargs)


def check_all(cls: type, data: Mapping[str, Any], *, what: str = 'parameter',
              extra_names: Iterable[str] = ()) -> tuple[dict[str, Any], list[str]]:
    """Check a nested or dotted mapping against the schema of ``cls``.

    Returns the coerced values by dotted name and one error line per unknown, missing or bad
    value. ``extra_names`` are accepted without a check (they belong to someone else).
    """
    errors: list[str] = []
    flat = flatten(data)
    sp = spec_map(cls)
    extra = set(extra_names)
    values: dict[str, Any] = {}
    for key, val in flat.items():
        s = sp.get(key)
        if s is None:
            if key not in extra:
                errors.append(unknown_key_line(key, sp, what))
            continue
        v, err = check_value(s, val)
        if err:
            errors.append(err)
        else:
            values[key] = v
    for name, s in sp.items():
        if s.required and name not in flat:
            errors.append(f'{name}: missing ({s.unit}, {s.desc})')
    return values, errors


def build(cls: type, data: Mapping[str, Any], source: str | None = None, *,
          what: str = 'parameter',
          checks: Callable[[Any], list[str]] | None = None):
    """A validated instance of the schema dataclass ``cls`` from a nested or dotted mapping.

    Single values are checked first, all at once; then the relations between them
    (``cls.cross_checks(self)`` and ``checks``), so that a user sees every mistake in one go.

    Raises
    ------
    ParamError
        One line per unknown, missing or bad value, or violated relation.
    """
    values, errors = check_all(cls, data, what=what)
    if errors:
        raise ParamError(errors, source)
    obj = _construct(cls, values)
    errors = _cross_checks(obj)
    if checks is not None:
        errors += checks(obj)
    if errors:
        raise ParamError(errors, source)
    return obj


def _cross_checks(obj: Any) -> list[str]:
    """The ``cross_checks()`` of every group, innermost first."""
    out: list[str] = []
    for f, _, sub in _group_fields(type(obj)):
        if sub is not None:
            out += _cross_checks(getattr(obj, f.name))
    return out + (list(obj.cross_checks()) if hasattr(obj, 'cross_checks') else [])


def to_flat(obj: Any, prefix: str = '') -> dict[str, Any]:
    """A schema dataclass instance as ``{'group.name': value}`` (ROS parameter names)."""
    flat: dict[str, Any] = {}
    for f, name, sub in _group_fields(type(obj)):
        value = getattr(obj, f.name)
        if sub is not None:
            flat.update(to_flat(value, f'{prefix}{name}.'))
        else:
            flat[f'{prefix}{name}'] = value
    return flat


def replace(obj: Any, values: Mapping[str, Any], source: str | None = None) -> Any:
    """A re-validated copy of a schema dataclass instance with dotted names replaced."""
    return build(type(obj), {**to_flat(obj), **values}, source)


def defaults_of(cls: type) -> dict[str, Any]:
    """The schema's defaults by dotted name (required entries left out)."""
    return {s.name: s.default for s in specs_of(cls) if not s.required}


# ---- files -------------------------------------------------------------------------------

#: The largest YAML file any reader takes [bytes]: a params, circuit or scenario file is a
#: few kB; this bounds what a file can make a reader allocate, with the anchors refused.
MAX_YAML_BYTES = 4 << 20


#: The most values a YAML document may expand to, its aliases counted at every use: an
#: alias bomb (a few lines of nested aliases) expands to billions.
MAX_YAML_NODES = 200_000


def _expanded_size(node, memo: dict, path: set) -> int:
    key = id(node)
    if key in memo:
        return memo[key]
    if key in path:
        raise yaml.composer.ComposerError(None, None, 'a recursive alias', node.start_mark)
    path.add(key)
    n = 1
    if isinstance(node, yaml.SequenceNode):
        n += sum(_expanded_size(v, memo, path) for v in node.value)
    elif isinstance(node, yaml.MappingNode):
        n += sum(_expanded_size(k, memo, path) + _expanded_size(v, memo, path)
                 for k, v in node.value)
    path.discard(key)
    memo[key] = n
    if n > MAX_YAML_NODES:
        raise yaml.composer.ComposerError(
            None, None, f'it expands to more than {MAX_YAML_NODES} values through its '
            'aliases (*name)', node.start_mark)
    return n


class _StrictLoader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing a document that expands beyond
    :data:`MAX_YAML_NODES` values (aliases counted at every use), before anything is built
    from it, and a key given twice in one mapping (the last would silently win)."""

    def compose_document(self):
        node = super().compose_document()
        if node is not None:
            _expanded_size(node, {}, set())
        return node

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                dup = key in seen
            except TypeError:
                continue  # an unhashable key: the base class says so
            if dup:
                raise yaml.constructor.ConstructorError(
                    None, None, f'the key {key!r} is given twice', key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep)


def _load_yaml(text: str) -> Any:
    """A document read strictly; ``yaml.YAMLError`` or ``RecursionError`` as PyYAML raises
    them (the callers word them)."""
    return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass


def parse_yaml(text: str, where: str) -> Any:
    """A YAML document read strictly (:class:`_StrictLoader`, at most
    :data:`MAX_YAML_BYTES`); :class:`ParamError` names ``where`` and the place."""
    if len(text) > MAX_YAML_BYTES:
        raise ParamError([f'{where}: {len(text)} characters, more than the '
                          f'{MAX_YAML_BYTES >> 20} MiB a YAML file of this suite may hold'])
    try:
        return _load_yaml(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, 'problem_mark', None)
        at = f' at line {mark.line + 1}' if mark else ''
        raise ParamError([f'{where}: not valid YAML{at}: {getattr(exc, "problem", exc)}']) \
            from None
    except RecursionError:
        raise ParamError([f'{where}: nested too deeply to be a YAML file of this suite']) \
            from None


def assignments(items: Iterable[str], what: str = '--set',
                example: str = 'emc.tau_control=0.02') -> dict[str, Any]:
    """``NAME=VALUE`` pairs, values read as YAML (``0.02``, ``true``, ``post``);
    :class:`ParamError` names each bad pair."""
    out, errors = {}, []
    for item in items:
        name, sep, text = item.partition('=')
        if not sep or not name.strip():
            errors.append(f'{what} {item!r}: expected NAME=VALUE, e.g. {example}')
            continue
        try:
            out[name.strip()] = _load_yaml(text)
        except (yaml.YAMLError, RecursionError) as exc:
            why = getattr(exc, 'problem', None) or 'not a YAML value'
            errors.append(f'{what} {item!r}: the value is not valid YAML ({why})')
    if errors:
        raise ParamError(errors)
    return out


def read_yaml(path: str | Path) -> Any:
    """Read a YAML file; a missing, unreadable, non-UTF-8 or malformed file is a
    :class:`ParamError` that names the file and the place."""
    path = Path(path)
    try:
        if path.stat().st_size > MAX_YAML_BYTES:
            raise ParamError([f'{path}: {path.stat().st_size} bytes, more than the '
                              f'{MAX_YAML_BYTES >> 20} MiB a YAML file of this suite may '
                              'hold'])
        raw = path.read_bytes()
    except IsADirectoryError:
        raise ParamError([f'{path}: is a folder, not a YAML file']) from None
    except OSError as exc:
        raise ParamError([f'cannot read {path}: {exc.strerror or exc}']) from None
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b'\n') + 1
        raise ParamError([f'{path}: not a text file in UTF-8 (byte {exc.start}, line {line})'])\
            from None
    return parse_yaml(text, str(path))


def ros_parameters(doc: Any) -> Mapping[str, Any]:
    """The mapping under ``<node>: ros__parameters:``, or the document itself."""
    if isinstance(doc, Mapping):
        for val in doc.values():
            if isinstance(val, Mapping) and 'ros__parameters' in val:
                return val['ros__parameters'] or {}
        return doc
    return {}


def read_params_file(path: str | Path) -> dict[str, Any]:
    """The parameters of a ROS 2 params file (or a plain mapping file), flat and dotted.

    Raises
    ------
    ParamError
        The file cannot be read, is not YAML, or holds no parameters.
    """
    data = ros_parameters(read_yaml(path))
    if not isinstance(data, Mapping) or not data:
        raise ParamError([f'{path}: no parameters found'])
    return flatten(data)


def yaml_float(v: float) -> str:
    """A float that YAML 1.1 (PyYAML, rcl) reads back as a float, never as text.

    Ten significant digits; a mantissa always has a dot and an exponent always a sign, because
    YAML 1.1 reads ``1e-5`` as a string.
    """
    if math.isinf(v):
        return '.inf' if v > 0 else '-.inf'
    text = f'{float(v):.10g}'
    if 'e' in text:
        mant, exp = text.split('e')
        if '.' not in mant:
            mant += '.0'
        sign = '-' if exp.startswith('-') else '+'
        text = f'{mant}e{sign}{exp.lstrip("+-").lstrip("0") or "0"}'
    elif '.' not in text and 'n' not in text:
        text += '.0'
    return text


def dump_ros_yaml(flat: Mapping[str, Any], header: str = '',
                  comments: Mapping[str, str] | None = None,
                  specs: Mapping[str, ParamSpec] | None = None) -> str:
    """``{'group.name': value}`` as a nested ROS 2 params file (``/**: ros__parameters:``),
    each value followed by its unit and description from ``specs``. Every line of ``header``
    is a comment: one that came apart at a line break inside a text it quotes (a path, a
    command line) gets its ``#`` too, so no header text becomes YAML."""
    specs = specs or {}
    comments = comments or {}
    lines = [ln.rstrip() if not ln.strip() or ln.lstrip().startswith('#') else '# ' + ln.rstrip()
             for ln in header.splitlines()]
    lines += ['/**:', '  ros__parameters:']
    prev: list[str] = []
    for key, val in flat.items():
        parts = key.split('.')
        grp, name = parts[:-1], parts[-1]
        common = 0
        while common < min(len(grp), len(prev)) and grp[common] == prev[common]:
            common += 1
        for depth in range(common, len(grp)):
            lines.append('    ' + '  ' * depth + grp[depth] + ':')
        prev = grp
        if isinstance(val, float):
            text = yaml_float(val)
        else:
            text = yaml.safe_dump(val, default_flow_style=True).strip().removesuffix('...')
            text = text.strip()
        s = specs.get(key)
        note = comments.get(key) or (f'{s.unit}, {s.desc}' if s else '')
        entry = f'{"    " + "  " * len(grp)}{name}: {text}'
        lines.append(f'{entry:<44s} # {note}' if note else entry)
    return '\n'.join(lines) + '\n'


# ---- docs --------------------------------------------------------------------------------

def default_text(s: ParamSpec) -> str:
    """A default as the parameter tables show it."""
    v = s.default
    if s.required:
        return '(required)'
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return fmt(v)
    if isinstance(v, list):
        return ', '.join(v) if v else '[]'
    return repr(v) if v == '' else str(v)


def markdown_table(specs: Iterable[ParamSpec], title: str = 'parameter') -> str:
    """A Markdown table of schema entries: name, default, unit, range, live, description."""
    rows = [f'| {title} | default | unit | range | live | meaning |',
            '| --- | --- | --- | --- | --- | --- |']
    for s in specs:
        if s.choices:
            rng = ', '.join(s.choices)
        elif s.type in (float, int) and s.range != (None, None):
            rng = range_text(s).removesuffix(s.unit).strip()
        else:
            rng = ''
        rows.append(f'| `{s.name}` | {default_text(s)} | {s.unit} | {rng} | '
                    f'{"yes" if s.live else ""} | {s.desc} |')
    return '\n'.join(rows)
