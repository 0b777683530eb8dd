"""The circuit compiler: a YAML description of components connected at named hydraulic
nodes becomes one compiled ``evaluate`` (right-hand side and outputs) for the stepper of
:mod:`hydropump_sim.integrator`.

A circuit file::

    name: paper                       # optional
    plant: ../pump.yaml               # a plant params file; 'plant.<group>.<name>' reads it
    fluid: {beta: 1.6e+9}             # optional: the circuit's fluid over the plant's
    components:
      pump: {type: pump, ports: {out: line}}
      line: {type: volume, ports: {node: line}, V: plant.line.V_l}
      load: {type: orifice_load, ports: {in: line}, mu: plant.line.mu_u, ...}

Each component names its ``type`` (``hydropump_sim/components``), connects each port to a
node (a list for a port that takes several), and gives its parameters, nested or dotted,
in SI units. The compiler checks everything and reports one line per problem naming the
component and the port; then it lays out

- the **states**: every component's own, then one pressure per node that has a volume
  (continuity, eqs. 3 and 9); a node whose pressure a component fixes (a tank) has none;
- the **inputs** ``<component>.<input>`` and the **signals** ``<component>.<signal>``
  (``y``: every node's pressure, net inflow and volume first, then the components'
  signals);
- the **parameters** ``p``: the fluid, each node's volume or fixed pressure, then each
  component's block (its ports' node indices, then its own values);

and generates the source of ``evaluate``: index tables and a loop per component type
calling its compiled kernel on each component's slices, then continuity at each node (the
source does not grow with the number of components, nor does numba's compile time). The
Jacobian the stepper needs is the compiled ``evaluate`` differenced one colour at a time:
the compiler derives the sparsity (a component couples its own states and the pressures at
its ports) and a colouring of it (columns that share no row move together), 13
evaluations for Fig. 1's 37 states. The source depends on the structure only (which
components, which ports, how many states), never on parameter values, so a file compiles
once per structure and is cached on disk for every later process, in a folder of the user's
own (:mod:`hydropump_sim.codecache`). The generated source holds indices and the package's
module names only: no name or value of the circuit file reaches it, and component and node
names must be identifiers besides (they name ROS topics).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
import re
from typing import Any

import numpy as np

from . import energy
from .codecache import compile_module
from .components import registry
from .components.base import Component, Expansion, PortSpec
from .errors import HydropumpError
from .jitcache import DIGEST
from .params import Fluid, load_params, Params
from .schema import build, flatten, fmt, ParamError, read_yaml, text_number_hint, to_flat
from .system import Model, unknown


class CircuitError(HydropumpError, ValueError):
    """An invalid circuit: ``lines`` holds one line per problem."""

    head = 'invalid circuit'


_TOP = ('name', 'plant', 'fluid', 'components', 'description')
_ENTRY = ('type', 'ports')
# Fluid entries the continuity of a node reads, in the order of the p vector's fluid block.
FLUID_KEYS = ('beta', 'alpha_air', 'p_atm', 'pressure_floor', 'dp_floor')
N_FLUID = len(FLUID_KEYS)
NODE_PREFIX = 'node:'
# Component and node names name states, signals, ROS topics and parameters: identifiers.
NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]{0,63}\Z')
NAME_RULE = 'a letter, then letters, digits or _, at most 64 characters'


@dataclass
class Part:
    """A primitive component placed in the circuit, with its slices of ``x``, ``u``, ``y``
    and ``p``."""

    comp: Component
    x: slice
    u: slice
    y: slice
    p: slice
    ports: list[int]          # node indices read through this part's ports (flow or sense)


@dataclass
class Circuit(Model):
    """A checked, laid-out and compiled circuit (see the module): a
    :class:`~hydropump_sim.system.Model`.

    Attributes
    ----------
    name, source : str
    fluid : Fluid
    parts : list of Part
        The primitives, in the order their kernels run.
    composites : dict
        Composite components by name, with their expansion (aliases of inputs, signals).
    nodes : list of str
    fixed : dict
        Node -> ``(component, 'param' or 'input', name)`` of the component fixing it.
    volume : dict
        Node -> total volume [m^3] (nodes that are not fixed).
    states, state_units, state_scale, integrating
        Full state names (``pump.x_c``, ``node:line``), units, scales, integrating flags.
    state_stops : ndarray (n, 2)
        The end stops of integrating states (NaN: none).
    inputs, input_units, u0
        Full input names, units, and the values they hold unless told otherwise.
    signals, signal_units
        Full signal names (``node:<n>`` pressures, ``node:<n>.inflow`` and
        ``node:<n>.volume`` first).
    p : ndarray
    module
        The compiled module (``evaluate``, ``evaluate_c``).
    """

    name: str
    source: str
    fluid: Fluid
    parts: list[Part]
    composites: dict[str, Expansion]
    nodes: list[str]
    fixed: dict[str, tuple[str, str, str]]
    volume: dict[str, float]
    states: list[str]
    state_units: list[str]
    state_scale: np.ndarray
    integrating: np.ndarray
    inputs: list[str]
    input_units: list[str]
    input_ranges: list[tuple[float, float]]
    u0: np.ndarray
    signals: list[str]
    signal_units: list[str]
    p: np.ndarray
    pattern: np.ndarray
    colors: np.ndarray
    dither: float
    code: str
    scale_offset: int = 0
    power: Any = field(repr=False, default=None)
    power_y0: int = 0
    state_stops: np.ndarray | None = None
    meters: dict[int, int] = field(default_factory=dict)
    entries: dict[str, Any] = field(repr=False, default_factory=dict)
    module: Any = field(repr=False, default=None)
    error = CircuitError

    # ---- names ----------------------------------------------------------------------------

    def _alias(self, name: str, kind: str) -> str:
        head, _, rest = name.partition('.')
        exp = self.composites.get(head)
        if exp is not None and rest in getattr(exp, kind):
            return getattr(exp, kind)[rest]
        return name

    def component_signals(self) -> list[str]:
        """Every signal a user reads, ``<component>.<signal>``: the parts', and each
        composite's own names."""
        out = [s for s in self.signals
               if not s.startswith((NODE_PREFIX, energy.POWER_PREFIX))]
        for name, exp in self.composites.items():
            out += [f'{name}.{alias}' for alias in exp.signals]
        return out

    def all_inputs(self) -> list[str]:
        out = list(self.inputs)
        for name, exp in self.composites.items():
            out += [f'{name}.{alias}' for alias in exp.inputs]
        return out

    def operator_inputs(self) -> list[str]:
        """The inputs an operator or a duty cycle sets (valve commands, forces, torques), by
        their shortest names: every input but those of the components whose inputs are the
        plant's operating point (``PLANT_INPUTS``: the pump's, the paper load's of eq. 9),
        which the simulator holds."""
        plant = {f'{pt.comp.name}.{s.name}' for pt in self.parts if pt.comp.PLANT_INPUTS
                 for s in pt.comp.INPUTS}
        aliased = {full for exp in self.composites.values() for full in exp.inputs.values()}
        return [n for n in self.all_inputs() if n not in plant and n not in aliased]

    def input_spec(self, name: str, prefix: str = ''):
        """The schema entry of an input (``boom.command``) as a live parameter
        ``<prefix><name>``, its default the value it holds."""
        k = self.input_index(name)
        pt = next(pt for pt in self.parts if pt.u.start <= k < pt.u.stop)
        entry = pt.comp.INPUTS[k - pt.u.start].param_spec('')
        return dataclasses.replace(entry, name=f'{prefix}{name}', default=float(self.u0[k]))

    def role(self, role: str) -> list[Part]:
        """The parts that declare ``role`` (``components.base.ROLES``)."""
        return [pt for pt in self.parts if role in pt.comp.ROLES]

    def pump(self) -> Part | None:
        """The circuit's pump (electro-hydraulic or hydromechanical), if any."""
        return next(iter(self.role('pump')), None)

    def electric_pump(self) -> bool:
        """Whether the circuit's pump is driven by the solenoid current."""
        pump = self.pump()
        return pump is not None and 'electric' in pump.comp.ROLES

    def measured(self) -> dict[str, str]:
        """The suite's measured signals (``hydropump_sim.measure.SIGNALS`` names, plus
        ``ls_pressure``) -> the circuit signal each is, as the components declare them
        (``MEASURES``: the pump's, the paper load's of eq. 9, the load-sensing pressure);
        the first component to declare a signal gives it."""
        out: dict[str, str] = {}
        for pt in self.parts:
            for sig, own in pt.comp.MEASURES.items():
                out.setdefault(sig, f'{pt.comp.name}.{own}')
        return out

    def loads(self) -> dict[str, dict[str, str]]:
        """Every load: a composite section, or a part with the ``load`` role -> its
        ``pressure``, ``flow``, ``position``/``velocity`` or ``speed`` signals and its
        ``command`` input."""
        out: dict[str, dict[str, str]] = {}
        for name, exp in self.composites.items():
            entry = {k: f'{name}.{k}' for k in exp.signals}
            if 'command' in exp.inputs:
                entry['command'] = f'{name}.command'
            out[name] = entry
        for pt in self.role('load'):
            n = pt.comp.name
            out[n] = {k: f'{n}.{v}' for k, v in pt.comp.LOAD_SIGNALS.items()}
        return out

    def joints(self) -> list[tuple[str, str | None, str | None]]:
        """``(joint, position signal, velocity signal)`` of every ``joint_states`` entry the
        components declare (valve spools, cylinders, motors)."""
        out = []
        for pt in self.parts:
            n = pt.comp.name
            for j in pt.comp.JOINTS:
                out.append((f'{n}{"." + j.suffix if j.suffix else ""}',
                            f'{n}.{j.position}' if j.position else None,
                            f'{n}.{j.velocity}' if j.velocity else None))
        return out

    def plant_inputs(self) -> dict[str, str]:
        """The pump's current (an electro-hydraulic pump's) and shaft speed, the paper
        load's pressure and aperture (eq. 9), where the circuit has them."""
        out = {}
        for pt in self.parts:
            if pt.comp.PLANT_INPUTS:
                for s in pt.comp.INPUTS:
                    out.setdefault(s.name, f'{pt.comp.name}.{s.name}')
        return out

    def pump_name(self) -> str | None:
        pump = self.pump()
        return pump.comp.name if pump is not None else None

    def relieved(self) -> list[str]:
        """The flow signals of its pressure-limiting components (relief valves)."""
        return [f'{pt.comp.name}.flow' for pt in self.role('pressure_limit')]

    def pressure_nodes(self) -> list[tuple[str, str]]:
        return [(n, f'{NODE_PREFIX}{n}') for n in self.nodes]

    def pressure_caps(self, U: np.ndarray) -> np.ndarray:
        """The highest of its components' :meth:`pressure_cap
        <hydropump_sim.components.base.Component.pressure_cap>` at each row of ``U``."""
        rows, inverse = np.unique(U, axis=0, return_inverse=True)
        caps = np.full(rows.shape[0], -np.inf)
        for part in self.parts:
            comp = part.comp
            for r, u in enumerate(rows):
                ins = {s.name: float(u[part.u.start + i]) for i, s in enumerate(comp.INPUTS)}
                cap = comp.pressure_cap(ins)
                if cap is not None:
                    caps[r] = max(caps[r], cap)
        caps[~np.isfinite(caps)] = np.nan
        return caps[np.ravel(inverse)]

    def branch_p(self, branch: str | None) -> np.ndarray:
        """The steady parameters with the pump's pilot-valve law forced to one side of its
        kink (``x_c = 0`` at every steady state, docs/reference.md I2)."""
        from .components.pump import P_BRANCH
        p = self.p_steady
        pump = self.pump()
        if pump is not None and branch is not None and hasattr(pump.comp, 'P_OFFSET'):
            p[pump.p.start + pump.comp.P_OFFSET + P_BRANCH] = {'pos': 1.0, 'neg': -1.0}[branch]
        return p

    def plant_params(self):
        pump = self.pump()
        return pump.comp.params.plant if pump is not None else None

    def component_names(self) -> list[str]:
        return [pt.comp.name for pt in self.parts]

    def reducible(self) -> dict[str, tuple[str, ...]]:
        """The states each component's static form does without (no compile: its own
        states, with its static values)."""
        out = {}
        for pt in self.parts:
            comp = pt.comp
            values = comp.static_values()
            if values is None:
                continue
            static = type(comp)(comp.name, dataclasses.replace(comp.params, **values),
                                comp.ports, comp.fluid)
            keep = {s.name for s in static.states()}
            gone = tuple(f'{comp.name}.{s.name}' for s in comp.states() if s.name not in keep)
            if gone:
                out[comp.name] = gone
        return out

    def static_sets(self, components) -> dict:
        sets = {}
        for pt in self.parts:
            name = pt.comp.name
            if name in components:
                head, _, own = name.rpartition('.')
                exp = self.composites.get(head)
                # A composite's part is set through the composite's group it comes from.
                where = f'{head}.{exp.groups.get(name, own)}' if exp is not None else name
                for k, v in (pt.comp.static_values() or {}).items():
                    sets[f'{where}.{k}'] = v
        return sets

    def made_static(self, components) -> Circuit:
        return self.with_values(self.static_sets(components))

    def start_states(self, u: np.ndarray) -> list[np.ndarray]:
        """A start for the steady-state search: every node at the highest fixed pressure
        (a tank's) or what its components expect there (a load holding its force, and
        upstream of it at least as much), every component at its own start."""
        fixed = {n: float(self.p[N_FLUID + self.nodes.index(n)] if how == 'param'
                          else u[self.inputs.index(f'{c}.{k}')])
                 for n, (c, how, k) in self.fixed.items()}
        p0 = max(fixed.values(), default=0.0)
        x = np.zeros(self.n_states)
        P = {n: fixed.get(n, p0) for n in self.nodes}
        for part in self.parts:
            ins = {s.name: float(u[part.u.start + i]) for i, s in enumerate(part.comp.INPUTS)}
            for port, v in part.comp.pressure_guess(ins).items():
                for n in part.comp.ports.get(port, []):
                    if n not in fixed:
                        P[n] = max(P[n], v)
        for n in self.nodes:
            if n not in fixed:
                x[self.node_state(n)] = P[n]
        for part in self.parts:
            comp = part.comp
            ports = {s.name: P[comp.ports[s.name][0]] for s in comp.PORTS
                     if comp.ports.get(s.name)}
            ins = {s.name: float(u[part.u.start + i]) for i, s in enumerate(comp.INPUTS)}
            xs = comp.initial_state(ports, ins)
            if xs.size:
                x[part.x] = xs
        return [x]

    def node_state(self, node: str) -> int:
        return self.states.index(f'{NODE_PREFIX}{node}')

    # ---- the stepper's view ---------------------------------------------------------------

    @property
    def evaluate_c(self):
        return self.module.evaluate_c

    @property
    def p_steady(self) -> np.ndarray:
        """The packed parameters of a steady state: every component's
        :meth:`~hydropump_sim.components.base.Component.steady_pack` (no dither)."""
        p = self.p.copy()
        for pt in self.parts:
            steady = pt.comp.steady_pack()
            p[pt.p.stop - len(steady):pt.p.stop] = steady
        return p

    def structure(self) -> dict:
        """What :mod:`hydropump_sim.integrator` needs besides ``evaluate_c``."""
        return {'scale': self.state_scale, 'colors': self.colors, 'pattern': self.pattern,
                'timed': self.dither > 0.0,
                'dt_time': 1.0e-7 / max(self.dither, 1.0)}

    def with_values(self, sets: Mapping[str, Any]) -> Circuit:
        """The same circuit file with more ``--set`` values (recompiled only if the
        structure changes)."""
        return load_circuit(self.source, {**self.entries.get('__sets__', {}), **sets},
                            self.entries.get('__plant__'),
                            meters=self.entries.get('__meters__', ()))


def default_circuit_path() -> Path:
    """``config/circuits/paper.yaml`` beside the default plant file: the paper's plant."""
    from .params import default_params_path
    return default_params_path().parent / 'circuits' / 'paper.yaml'


# ---- reading ---------------------------------------------------------------------------------

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
    plant = None
    if isinstance(plant_over, Params):
        plant = to_flat(plant_over)
    elif plant_over is not None or doc.get('plant') is not None:
        plant_path = Path(plant_over) if plant_over is not None else base / str(doc['plant'])
        try:
            plant = to_flat(load_params(plant_path))
        except ParamError as exc:
            raise CircuitError([f'plant: {plant_path}: {ln}' for ln in exc.lines],
                               source) from None
    # The fluid: the plant's, then the circuit file's, then --set fluid.*.
    fluid_values = {k[len('fluid.'):]: v for k, v in (plant or {}).items()
                    if k.startswith('fluid.')}
    fluid_values.update(flatten(doc.get('fluid') or {}))
    fluid_values.update(by_comp.pop('fluid', {}))
    fluid = None
    try:
        fluid = build(Fluid, {k: _resolve(v, plant, f'fluid.{k}', errors)
                              for k, v in fluid_values.items()}, source)
    except ParamError as exc:
        errors += [f'fluid.{ln}' for ln in exc.lines]
    kinds = registry()
    comps: list[Component] = []
    composites: dict[str, Expansion] = {}
    input_sets: dict[str, float] = {}
    for name in by_comp:
        if name not in doc['components']:
            errors.append(unknown(name, list(doc['components']) + ['fluid'], 'component')
                          + ' in a set value')
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
    if errors:
        raise CircuitError(errors, source)
    circuit = _layout(comps, composites, fluid, source, doc.get('name') or Path(source).stem,
                      errors, meters)
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
    cap = float(circuit.pressure_caps(circuit.u0[None])[0])
    if np.isfinite(cap):
        for pt in circuit.parts:
            errors += pt.comp.cap_checks(cap)
    if errors:
        raise CircuitError(errors, source)
    circuit.entries['__sets__'] = dict(sets)
    circuit.entries['__plant__'] = plant_over
    circuit.entries['__meters__'] = meters
    if compile:
        circuit.module = compile_module(circuit.code)
    return circuit


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


# ---- layout ----------------------------------------------------------------------------------

def _layout(comps: list[Component], composites: dict[str, Expansion], fluid: Fluid,
            source: str, name: str, errors: list[str], meters: tuple[str, ...] = ()
            ) -> Circuit:
    nodes: list[str] = []
    for comp in comps:
        for spec in comp.PORTS:
            for node in comp.ports.get(spec.name, []):
                if node not in nodes:
                    nodes.append(node)
    index = {n: i for i, n in enumerate(nodes)}
    # Who fixes a node, and the volume at each.
    fixed: dict[str, tuple[str, str, str]] = {}
    volume: dict[str, float] = {n: 0.0 for n in nodes}
    for comp in comps:
        fx = comp.fixed_pressure()
        if fx is not None:
            node = comp.ports[fx[0]][0]
            if node in fixed:
                errors.append(f'node {node}: its pressure is fixed by both {fixed[node][0]} and '
                              f'{comp.name}; keep one')
            else:
                fixed[node] = (comp.name, fx[1], fx[2])
        for port, v in comp.volumes().items():
            for node in comp.ports.get(port, []):
                volume[node] += v
    users: dict[str, list[str]] = {n: [] for n in nodes}
    for comp in comps:
        for spec in comp.PORTS:
            for node in comp.ports.get(spec.name, []):
                users[node].append(f'{comp.name}.{spec.name}')
    for node in nodes:
        if node not in fixed and volume[node] <= 0.0:
            errors.append(f'node {node} ({", ".join(users[node])}): no volume: its pressure '
                          'needs one (a volume component, or a chamber of a cylinder or '
                          'motor) or a component that fixes it (a tank)')
    errors += _return_paths(comps, nodes, fixed, users)
    errors += _pressure_limits(comps)
    if errors:
        raise CircuitError(errors, source)
    # States: components', then one pressure per node with a volume.
    states, units, scales, integ, stops = [], [], [], [], []
    parts: list[Part] = []
    inputs, in_units, in_ranges, u0 = [], [], [], []
    signals = ([f'{NODE_PREFIX}{n}' for n in nodes] + [f'{NODE_PREFIX}{n}.inflow' for n in nodes]
               + [f'{NODE_PREFIX}{n}.volume' for n in nodes])
    sig_units = ['Pa'] * len(nodes) + ['m^3/s'] * len(nodes) + ['m^3'] * len(nodes)
    p: list[float] = [float(getattr(fluid, k)) for k in FLUID_KEYS]
    p += [volume[n] if n not in fixed else 0.0 for n in nodes]
    for n, (cname, how, key) in fixed.items():
        if how == 'param':
            comp = next(c for c in comps if c.name == cname)
            p[N_FLUID + index[n]] = float(getattr(comp.params, key))
    dither = 0.0
    for comp in comps:
        sts = comp.states()
        x0 = len(states)
        for s in sts:
            states.append(f'{comp.name}.{s.name}')
            units.append(s.unit)
            scales.append(s.scale)
            integ.append(s.integrating)
            stops.append(s.stops or (np.nan, np.nan))
        k0 = len(inputs)
        for s in comp.INPUTS:
            inputs.append(f'{comp.name}.{s.name}')
            in_units.append(s.unit)
            in_ranges.append((s.lo, s.hi))
            u0.append(comp.input_default(s))
        y0 = len(signals)
        for s in comp.SIGNALS:
            signals.append(f'{comp.name}.{s.name}')
            sig_units.append(s.unit)
        block, used = _port_block(comp, index)
        p0 = len(p)
        p += block + [float(v) for v in comp.pack()]
        parts.append(Part(comp, slice(x0, len(states)), slice(k0, len(inputs)),
                          slice(y0, len(signals)), slice(p0, len(p)), used))
        if comp.dither_frequency() > 0.0:
            dither = max(dither, comp.dither_frequency())
    # The energy account's sums after every component's signals (hydropump_sim.energy).
    power = energy.power_signals(parts, nodes, fixed)
    power_y0 = len(signals)
    signals += power.names()
    sig_units += ['W'] * len(power.names())
    node_states = {}
    for n in nodes:
        if n not in fixed:
            node_states[n] = len(states)
            states.append(f'{NODE_PREFIX}{n}')
            units.append('Pa')
            scales.append(1.0e6)
            integ.append(False)
            stops.append((np.nan, np.nan))
    for m in meters:
        states.append(f'meter:{m}')
        units.append('m^3')
        scales.append(1.0)
        integ.append(True)
        stops.append((np.nan, np.nan))
    circuit = Circuit(
        name=name, source=source, fluid=fluid, parts=parts, composites=composites,
        nodes=nodes, fixed=fixed, volume={n: v for n, v in volume.items() if n not in fixed},
        states=states, state_units=units, state_scale=np.array(scales, dtype=float),
        integrating=np.array(integ, dtype=bool),
        state_stops=np.array(stops, dtype=float).reshape(-1, 2), inputs=inputs,
        input_units=in_units,
        input_ranges=in_ranges, u0=np.array(u0, dtype=float), signals=signals,
        signal_units=sig_units, p=np.array(p, dtype=float),
        pattern=np.zeros((0, 0), bool), colors=np.zeros(0, np.int64), dither=dither,
        code='', power=power, power_y0=power_y0)
    circuit.meters = {}
    for m in meters:
        try:
            circuit.meters[circuit.states.index(f'meter:{m}')] = circuit.signal_index(m)
        except CircuitError as exc:
            errors += exc.lines
    if errors:
        raise CircuitError(errors, source)
    # The state scales close the parameter vector: the Jacobian's difference steps.
    circuit.scale_offset = circuit.p.size
    circuit.p = np.concatenate([circuit.p, circuit.state_scale])
    circuit.pattern = _pattern(circuit, node_states)
    from .integrator import coloring
    circuit.colors = coloring(circuit.pattern)
    circuit.code = _generate(circuit, node_states, index)
    return circuit


def _port_block(comp: Component, index: dict[str, int]) -> tuple[list[float], list[int]]:
    """The packed port indices of a component (a ``many`` port as its count, then its
    nodes; an unconnected optional port as -1), and the nodes it reads."""
    block: list[float] = []
    used: list[int] = []
    for spec in comp.PORTS:
        nodes = comp.ports.get(spec.name, [])
        if spec.many:
            block.append(float(len(nodes)))
        if not nodes:
            block.append(-1.0)
        for node in nodes:
            block.append(float(index[node]))
            used.append(index[node])
    return block, used


def _return_paths(comps: list[Component], nodes: list[str], fixed: dict, users: dict
                  ) -> list[str]:
    """Every node must reach a node of fixed pressure through passages (valves, orifices;
    not through an actuator, which passes on what it takes): else its oil has nowhere to go,
    a load with no return path."""
    adj: dict[str, set[str]] = {n: set() for n in nodes}
    for comp in comps:
        if not comp.PASSAGE:
            continue
        flow_nodes = [n for spec in comp.PORTS if not spec.sense
                      for n in comp.ports.get(spec.name, [])]
        if comp.EXTERNAL_RETURN:
            flow_nodes.append('__load__')
        for a in flow_nodes:
            for b in flow_nodes:
                if a != b and a in adj:
                    adj[a].add(b)
    reached = set(fixed) | {n for n in nodes if '__load__' in adj[n]}
    todo = list(reached)
    while todo:
        n = todo.pop()
        for m in adj.get(n, ()):
            if m in adj and m not in reached:
                reached.add(m)
                todo.append(m)
    return [f'node {n} ({", ".join(users[n])}): no return path to a tank or a pressure '
            'source: the oil delivered there has nowhere to go' for n in nodes
            if n not in reached]


def _pressure_limits(comps: list[Component]) -> list[str]:
    """A pump needs something to limit the pressure it can make: a relief valve in the
    circuit or a cut-off of its own."""
    if any('pressure_limit' in c.ROLES for c in comps):
        return []
    return [f'{c.name}: nothing limits the pressure this pump can make: add a relief valve '
            '(type relief) at its outlet or give it a pressure cut-off (cutoff.p_set)'
            for c in comps if 'pump' in c.ROLES
            and c.pressure_cap({s.name: 0.0 for s in c.INPUTS}) is None]


def _pattern(circuit: Circuit, node_states: dict[str, int]) -> np.ndarray:
    """Which state derivatives may depend on which states: each part couples its own states
    and the pressures of the nodes at its ports; each node its own pressure."""
    n = circuit.n_states
    pat = np.zeros((n, n), dtype=bool)
    for i in range(n):
        pat[i, i] = True
    for k in circuit.meters:  # a metered signal may depend on anything
        pat[k, :] = True
    for part in circuit.parts:
        idx = list(range(part.x.start, part.x.stop))
        idx += [node_states[circuit.nodes[k]] for k in part.ports
                if circuit.nodes[k] in node_states]
        pat[np.ix_(idx, idx)] = True
    return pat


# ---- code ------------------------------------------------------------------------------------

def _generate(circuit: Circuit, node_states: dict[str, int], index: dict[str, int]) -> str:
    """The source of the circuit's ``evaluate`` (see the module): index tables, and a loop
    over each component type's table calling its kernel, so that the source, and the time
    and memory numba takes to compile it, grow with the number of component types and not
    of components (one call per component made numba's optimiser superlinear: 40 sections
    took 280 s and 800 MB). Kernels only add to ``Q`` and ``V`` (components/base.py), so the
    order of the calls does not matter."""
    n_nodes = len(circuit.nodes)
    tables: list[str] = []

    def table(rows, width: int = 0) -> str:
        """A module-level int64 table (indices only) and its name."""
        name = f'T{len(tables)}'
        body = ', '.join(f'[{", ".join(str(int(v)) for v in r)}]' if width else str(int(r))
                         for r in rows)
        shape = f'.reshape(-1, {width})' if width else ''
        tables.append(f'{name} = np.array([{body}], dtype=np.int64){shape}')
        return name

    # Indices and the package's own module names only: no string of the circuit file.
    head = [f'"""Generated by hydropump_sim.circuit (package sources {DIGEST}): do not '
            'edit."""', '', 'import numpy as np', '',
            'from hydropump_sim.components.laws import continuity',
            'from hydropump_sim.integrator import EVALUATE',
            'from hydropump_sim.jitcache import cfunc']
    by_kernel: dict[str, list] = {}
    for part in circuit.parts:
        by_kernel.setdefault(type(part.comp).__module__, []).append(part)
    for k, mod in enumerate(by_kernel):
        head.append(f'from {mod} import kernel as k_{k}')
    # Each node's pressure: a state's, a parameter's or an input's (-1: not that one).
    source = []
    for i, node in enumerate(circuit.nodes):
        if node in node_states:
            source.append((node_states[node], -1, -1))
        else:
            cname, how, key = circuit.fixed[node]
            source.append((-1, N_FLUID + i, -1) if how == 'param'
                          else (-1, -1, circuit.inputs.index(f'{cname}.{key}')))
    lines = ['', '', 'def evaluate(t, x, u, p, dx, y):',
             f'    P = y[0:{n_nodes}]', f'    Q = y[{n_nodes}:{2 * n_nodes}]',
             f'    V = y[{2 * n_nodes}:{3 * n_nodes}]',
             f'    for i in range({n_nodes}):',
             f'        r = {table(source, 3)}[i]',
             '        P[i] = x[r[0]] if r[0] >= 0 else (p[r[1]] if r[1] >= 0 else u[r[2]])',
             '        Q[i] = 0.0',
             f'        V[i] = p[{N_FLUID} + i]']
    for k, parts in enumerate(by_kernel.values()):
        rows = [(pt.x.start, pt.x.stop, pt.u.start, pt.u.stop, pt.p.start, pt.p.stop,
                 pt.y.start, pt.y.stop) for pt in parts]
        lines += [f'    for r in {table(rows, 8)}:',
                  f'        k_{k}(t, x[r[0]:r[1]], dx[r[0]:r[1]], u[r[2]:r[3]], '
                  'p[r[4]:r[5]], y[r[6]:r[7]], P, Q, V)']
    fl = ', '.join(f'p[{k}]' for k in range(N_FLUID))
    if node_states:
        rows = [(k, index[node]) for node, k in node_states.items()]
        lines += [f'    for r in {table(rows, 2)}:',
                  f'        dx[r[0]] = continuity(P[r[1]], Q[r[1]], V[r[1]], {fl})']
    # A component that fixes its node's pressure reports the net flow into it.
    rows = []
    for node, (cname, _, _) in circuit.fixed.items():
        part = next(pt for pt in circuit.parts if pt.comp.name == cname)
        names = [s.name for s in part.comp.SIGNALS]
        if 'flow' in names:
            rows.append((part.y.start + names.index('flow'), index[node]))
    if rows:
        lines += [f'    for r in {table(rows, 2)}:', '        y[r[0]] = Q[r[1]]']
    lines += energy.code(circuit.power, circuit.power_y0, table)
    if circuit.meters:
        lines += [f'    for r in {table(list(circuit.meters.items()), 2)}:',
                  '        dx[r[0]] = y[r[1]]  # meters']
    lines += ['', '', 'evaluate_c = cfunc(EVALUATE)(evaluate)', '']
    return '\n'.join(head + [''] + tables + lines)
