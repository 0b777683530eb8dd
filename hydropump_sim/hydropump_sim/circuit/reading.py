"""Reading a circuit file: check its keys, names and values, one line per problem naming the
component and the port, and make its components; then :func:`.layout.lay_out` places and
compiles them (see the package)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..codecache import compile_module
from ..components import registry
from ..components.base import Component, Expansion, PortSpec
from ..params import Fluid, load_params, Params
from ..schema import build, flatten, fmt, ParamError, read_yaml, text_number_hint, to_flat
from ..system import unknown
from .layout import lay_out
from .model import Circuit, CircuitError, NAME, NAME_RULE

_TOP = ('name', 'plant', 'fluid', 'components', 'description')
_ENTRY = ('type', 'ports')


def _resolve(value: Any, plant: dict | None, where: str, errors: list[str]) -> Any:
    """A ``plant.<group>.<name>`` reference read from the plant params file."""
    if isinstance(value, str) and value.startswith('plant.'):
        if plant is None:
            errors.append(f'{where} = {value}: the circuit names no plant params file '
                          '(plant: FILE)')
            return None
        key = value[len('plant.'):]
        if key not in plant:
            errors.append(f'{where} = {value}: {unknown(key, plant, "plant parameter")}')
            return None
        return plant[key]
    return value


def _check_names(doc: Mapping) -> list[str]:
    """One line per component or node name of the file that is not an identifier."""
    errors = []
    name = doc.get('name')
    if name is not None and not (isinstance(name, str) and NAME.match(name)):
        errors.append(f'name {name!r}: a circuit name is {NAME_RULE}')
    for comp, entry in doc['components'].items():
        if not (isinstance(comp, str) and NAME.match(comp)):
            errors.append(f'component {comp!r}: a component name is {NAME_RULE}')
            continue
        ports = entry.get('ports') if isinstance(entry, Mapping) else None
        for port, nodes in (ports.items() if isinstance(ports, Mapping) else ()):
            for node in (nodes if isinstance(nodes, list) else [nodes]):
                if isinstance(node, str) and not NAME.match(node):
                    errors.append(f'{comp}.{port}: node {node!r}: a node name is {NAME_RULE}')
    return errors


def _split_sets(sets: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for name, value in sets.items():
        head, _, rest = str(name).partition('.')
        out.setdefault(head, {})[rest] = value
    return out


def load_circuit(path: str | Path, sets: Mapping[str, Any] | None = None,
                 plant: str | Path | Params | None = None, compile: bool = True,
                 meters: Sequence[str] = ()) -> Circuit:
    """Read, check, lay out and compile a circuit file.

    Parameters
    ----------
    path : str or Path
    sets : mapping, optional
        ``{'<component>.<parameter or input>': value, 'fluid.<name>': value}``: values
        over the file's (``--set``); an input set here holds that value.
    plant : path or Params, optional
        The plant parameters in place of the file's ``plant:`` (a user's own pump, a
        calibrated one, the bench's dither laid over them).
    compile : bool
        ``False`` checks and lays out only (its names, its topics), without compiling.
    meters : sequence of str
        Signals (flows) to integrate over time as states ``meter:<signal>`` (volumes
        delivered, returned): exact to the stepper's rounding, as a linear invariant of the
        equations.

    Raises
    ------
    CircuitError
        One line per problem, naming the component and the port.
    """
    path = Path(path)
    try:
        doc = read_yaml(path)
    except ParamError as exc:
        raise CircuitError(exc.lines, str(path)) from None
    return build_circuit(doc, str(path), path.parent, dict(sets or {}), plant, compile,
                         tuple(meters))


def build_circuit(doc: Any, source: str, base: Path, sets: dict[str, Any],
                  plant_over: str | Path | Params | None = None,
                  compile: bool = True, meters: tuple[str, ...] = ()) -> Circuit:
    """A circuit from its YAML form (see :func:`load_circuit`): the file's keys and names,
    its plant and fluid, its components (composites expanded), laid out, its held inputs
    set and its relief settings checked against what the sources can reach."""
    errors: list[str] = []
    if not isinstance(doc, Mapping) or not isinstance(doc.get('components'), Mapping) \
            or not doc['components']:
        raise CircuitError(['expected a mapping with components: {name: {type: ..., ports: '
                            '{...}, parameters}}'], source)
    for key in doc:
        if key not in _TOP:
            errors.append(unknown(str(key), _TOP, 'top-level key'))
    bad_names = _check_names(doc)
    if bad_names:  # nothing else is read under a name that is not an identifier
        raise CircuitError(bad_names, source)
    by_comp = _split_sets(sets)
    plant = _plant(doc, base, plant_over, source)
    fluid = _fluid(doc, plant, by_comp.pop('fluid', {}), source, errors)
    for name in by_comp:
        if name not in doc['components']:
            errors.append(unknown(name, list(doc['components']) + ['fluid'], 'component')
                          + ' in a set value')
    comps, composites, input_sets = _components(doc, plant, by_comp, fluid, errors)
    if errors:
        raise CircuitError(errors, source)
    circuit = lay_out(comps, composites, fluid, source, doc.get('name') or Path(source).stem,
                      errors, meters)
    errors += _hold_inputs(circuit, input_sets)
    cap = float(circuit.pressure_caps(circuit.u0[None])[0])
    if np.isfinite(cap):
        for pt in circuit.parts:
            errors += pt.comp.cap_checks(cap)
    if errors:
        raise CircuitError(errors, source)
    circuit.entries['__load__'] = load_circuit
    circuit.entries['__sets__'] = dict(sets)
    circuit.entries['__plant__'] = plant_over
    circuit.entries['__meters__'] = meters
    if compile:
        circuit.module = compile_module(circuit.code)
    return circuit


def _plant(doc: Mapping, base: Path, plant_over: str | Path | Params | None, source: str
           ) -> dict | None:
    """The plant parameters by dotted name: ``plant_over``, else the file's ``plant:``."""
    if isinstance(plant_over, Params):
        return to_flat(plant_over)
    if plant_over is None and doc.get('plant') is None:
        return None
    plant_path = Path(plant_over) if plant_over is not None else base / str(doc['plant'])
    try:
        return to_flat(load_params(plant_path))
    except ParamError as exc:
        raise CircuitError([f'plant: {plant_path}: {ln}' for ln in exc.lines],
                           source) from None


def _fluid(doc: Mapping, plant: dict | None, sets: dict[str, Any], source: str,
           errors: list[str]) -> Fluid | None:
    """The fluid: the plant's, then the circuit file's, then ``--set fluid.*``."""
    values = {k[len('fluid.'):]: v for k, v in (plant or {}).items() if k.startswith('fluid.')}
    values.update(flatten(doc.get('fluid') or {}))
    values.update(sets)
    try:
        return build(Fluid, {k: _resolve(v, plant, f'fluid.{k}', errors)
                             for k, v in values.items()}, source)
    except ParamError as exc:
        errors += [f'fluid.{ln}' for ln in exc.lines]
        return None


def _components(doc: Mapping, plant: dict | None, by_comp: dict, fluid: Fluid | None,
                errors: list[str]) -> tuple[list[Component], dict[str, Expansion], dict]:
    """The primitive components in file order, a composite's parts in its place; the
    composites with their expansions; the inputs a set value holds (a composite's aliases
    resolved)."""
    kinds = registry()
    comps: list[Component] = []
    composites: dict[str, Expansion] = {}
    input_sets: dict[str, float] = {}
    pending = [(str(name), entry, None) for name, entry in doc['components'].items()]
    while pending:
        name, entry, parent = pending.pop(0)
        comp = _make(name, entry, kinds, plant, by_comp.get(name, {}) if parent is None else {},
                     fluid, input_sets, errors)
        if comp is None:
            continue
        try:
            exp = comp.expand()
        except ParamError as exc:
            errors += [f'{name}: {ln}' if not ln.startswith(name) else ln for ln in exc.lines]
            continue
        if exp is None:
            comps.append(comp)
            continue
        composites[name] = exp
        sub = by_comp.get(name, {}) if parent is None else {}
        for alias, target in exp.inputs.items():
            if alias in sub:
                input_sets[target] = sub[alias]
        pending = [(part_name, {'type': kind, 'ports': ports, **values}, name)
                   for part_name, kind, values, ports in exp.parts] + pending
    return comps, composites, input_sets


def _hold_inputs(circuit: Circuit, input_sets: dict[str, Any]) -> list[str]:
    """Each set input held at its value in ``circuit.u0``; a line per unknown input or a
    value outside its range."""
    errors = []
    for name, value in input_sets.items():
        try:
            k = circuit.inputs.index(name)
        except ValueError:
            errors.append(unknown(name, circuit.inputs, 'input'))
            continue
        lo, hi = circuit.input_ranges[k]
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not lo <= float(value) <= hi:
            hint = text_number_hint(value)
            errors.append(f'{name} = {value!r}: expected a number in [{fmt(lo)}, {fmt(hi)}] '
                          f'{circuit.input_units[k]}{hint}')
            continue
        circuit.u0[k] = float(value)
    return errors


def _make(name: str, entry: Any, kinds: dict, plant: dict | None, sets: dict[str, Any],
          fluid: Fluid | None, input_sets: dict[str, float], errors: list[str]
          ) -> Component | None:
    """One component from its entry (and its ``--set`` values), or ``None`` with errors."""
    if not isinstance(entry, Mapping):
        errors.append(f'{name}: expected a mapping with type, ports and parameters')
        return None
    sets = dict(sets)
    kind = sets.pop('type', entry.get('type'))
    cls = kinds.get(kind)
    if cls is None:
        errors.append(f'{name}: ' + unknown(str(kind), kinds, 'component type')
                      .replace(f'{kind}: ', f'type {kind!r}: '))
        return None
    values = {k: _resolve(v, plant, f'{name}.{k}', errors)
              for k, v in flatten({k: v for k, v in entry.items() if k not in _ENTRY}).items()}
    # A set value naming an input holds that input (a composite's, through its parts);
    # any other is a parameter.
    input_names = {s.name for s in cls.INPUTS}
    composite = cls.expand is not Component.expand
    # An input the file gives that no parameter of the component holds (the pump's current)
    # holds that input too.
    own = cls.param_specs()
    for key in [k for k in values if k in input_names and k not in own and not composite]:
        input_sets[f'{name}.{key}'] = values.pop(key)
    for key, value in sets.items():
        if key not in input_names:
            values[key] = value
        elif not composite:
            input_sets[f'{name}.{key}'] = value
    if getattr(cls, 'PLANT_PARAMS', False):
        if plant is None:
            errors.append(f'{name}: a {kind} takes its parameters from the plant params file: '
                          'name it (plant: FILE)')
            return None
        values = {**plant, **values}
    try:
        params = cls.build_params(values, None)
    except ParamError as exc:
        errors += [f'{name}.{ln}' for ln in exc.lines]
        return None
    ports = _ports(name, cls.PORTS, entry.get('ports'), errors)
    if ports is None:
        return None
    comp = cls(name, params, ports, fluid)
    problems = comp.port_problems()
    errors += problems
    return None if problems else comp


def _ports(name: str, specs: tuple[PortSpec, ...], given: Any, errors: list[str]
           ) -> dict[str, list[str]] | None:
    names = [s.name for s in specs]
    if given is None:
        given = {}
    if not isinstance(given, Mapping):
        errors.append(f'{name}: ports must map port names to nodes ({", ".join(names)})')
        return None
    out: dict[str, list[str]] = {}
    ok = True
    for key, node in given.items():
        spec = next((s for s in specs if s.name == key), None)
        if spec is None:
            errors.append(f'{name}: no port {key!r} (ports: {", ".join(names)})')
            ok = False
            continue
        nodes = node if isinstance(node, list) else [node]
        if not nodes or not all(isinstance(n, str) and n for n in nodes) \
                or (len(nodes) > 1 and not spec.many):
            errors.append(f'{name}.{key}: expected a node name'
                          + (' or a list of them' if spec.many else '') + f', got {node!r}')
            ok = False
            continue
        out[key] = list(nodes)
    for spec in specs:
        if spec.name not in out and not spec.optional:
            errors.append(f'{name}: port {spec.name} is not connected ({spec.desc})')
            ok = False
    return out if ok else None


