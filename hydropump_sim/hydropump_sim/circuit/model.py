"""A compiled circuit: the :class:`Circuit` model the compiler (:mod:`.reading`,
:mod:`.layout`) builds from a circuit file, its parts and its names (see the package)."""

from __future__ import annotations

from collections.abc import Mapping
import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
import re
from typing import Any

import numpy as np

from .. import energy
from ..components.base import Component, Expansion
from ..errors import HydropumpError
from ..params import Fluid
from ..system import Model


class CircuitError(HydropumpError, ValueError):
    """An invalid circuit: ``lines`` holds one line per problem."""

    head = 'invalid circuit'


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
        which the simulator holds, and those of the models stepped beside the circuit
        (``external``: a user's FMU)."""
        plant = {f'{pt.comp.name}.{s.name}' for pt in self.parts
                 if pt.comp.PLANT_INPUTS or 'external' in pt.comp.ROLES
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

    def external(self) -> list[str]:
        """The components whose inputs a model outside the circuit gives (``external``: a
        user's FMU, stepped beside it by hydropump_ctrl/fmi/loads.py)."""
        return [pt.comp.name for pt in self.role('external')]

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
        from ..components.pump import P_BRANCH
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
        # The reader that made this circuit (entries['__load__']) makes it again: the model
        # does not import its compiler.
        return self.entries['__load__'](self.source, {**self.entries.get('__sets__', {}),
                                                      **sets},
                                        self.entries.get('__plant__'),
                                        meters=self.entries.get('__meters__', ()))


def default_circuit_path() -> Path:
    """``config/circuits/paper.yaml`` beside the default plant file: the paper's plant."""
    from ..params import default_params_path
    return default_params_path().parent / 'circuits' / 'paper.yaml'

