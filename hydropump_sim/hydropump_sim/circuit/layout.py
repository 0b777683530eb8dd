"""Laying out a checked circuit (states, inputs, signals, parameters, the Jacobian's
sparsity and colouring) and generating the source of its ``evaluate`` (see the package)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import energy
from ..components.base import Component, Expansion
from ..jitcache import DIGEST
from ..params import Fluid
from .model import Circuit, CircuitError, FLUID_KEYS, N_FLUID, NODE_PREFIX, Part


def lay_out(comps: list[Component], composites: dict[str, Expansion], fluid: Fluid,
            source: str, name: str, errors: list[str], meters: tuple[str, ...] = ()
            ) -> Circuit:
    """The checked components placed in one model: the nodes, then every vector laid out
    (:func:`_place`), the meters, the Jacobian's sparsity and colouring, and the source of
    ``evaluate``; :class:`CircuitError` with every problem of the nodes."""
    nodes, fixed, volume = _node_table(comps, errors)
    if errors:
        raise CircuitError(errors, source)
    index = {n: i for i, n in enumerate(nodes)}
    v = _place(comps, nodes, index, fixed, volume, fluid)
    node_states = {}
    for n in nodes:
        if n not in fixed:
            node_states[n] = len(v.states)
            v.add_state(f'{NODE_PREFIX}{n}', 'Pa', 1.0e6, False, None)
    for m in meters:
        v.add_state(f'meter:{m}', 'm^3', 1.0, True, None)
    circuit = Circuit(
        name=name, source=source, fluid=fluid, parts=v.parts, composites=composites,
        nodes=nodes, fixed=fixed, volume={n: vol for n, vol in volume.items() if n not in fixed},
        states=v.states, state_units=v.units, state_scale=np.array(v.scales, dtype=float),
        integrating=np.array(v.integ, dtype=bool),
        state_stops=np.array(v.stops, dtype=float).reshape(-1, 2), inputs=v.inputs,
        input_units=v.in_units, input_ranges=v.in_ranges, u0=np.array(v.u0, dtype=float),
        signals=v.signals, signal_units=v.sig_units, p=np.array(v.p, dtype=float),
        pattern=np.zeros((0, 0), bool), colors=np.zeros(0, np.int64), dither=v.dither,
        code='', power=v.power, power_y0=v.power_y0)
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
    from ..integrator import coloring
    circuit.colors = coloring(circuit.pattern)
    circuit.code = _generate(circuit, node_states, index)
    return circuit


def _node_table(comps: list[Component], errors: list[str]
                ) -> tuple[list[str], dict[str, tuple[str, str, str]], dict[str, float]]:
    """The nodes in the order the ports name them, who fixes a node's pressure, and the
    volume at each; a line in ``errors`` per node without a volume or a fixed pressure, two
    fixing one, a node no flow can leave, a relief or a source above its limits."""
    nodes: list[str] = []
    users: dict[str, list[str]] = {}
    for comp in comps:
        for spec in comp.PORTS:
            for node in comp.ports.get(spec.name, []):
                if node not in nodes:
                    nodes.append(node)
                users.setdefault(node, []).append(f'{comp.name}.{spec.name}')
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
    for node in nodes:
        if node not in fixed and volume[node] <= 0.0:
            errors.append(f'node {node} ({", ".join(users[node])}): no volume: its pressure '
                          'needs one (a volume component, or a chamber of a cylinder or '
                          'motor) or a component that fixes it (a tank)')
    errors += _return_paths(comps, nodes, fixed, users)
    errors += _pressure_limits(comps)
    return nodes, fixed, volume


@dataclass
class _Vectors:
    """The vectors of a circuit as they are laid out: states, inputs, signals (names, units
    and the rest), the parameters ``p``, the parts."""

    states: list = field(default_factory=list)
    units: list = field(default_factory=list)
    scales: list = field(default_factory=list)
    integ: list = field(default_factory=list)
    stops: list = field(default_factory=list)
    inputs: list = field(default_factory=list)
    in_units: list = field(default_factory=list)
    in_ranges: list = field(default_factory=list)
    u0: list = field(default_factory=list)
    signals: list = field(default_factory=list)
    sig_units: list = field(default_factory=list)
    p: list = field(default_factory=list)
    parts: list = field(default_factory=list)
    dither: float = 0.0
    power: object = None
    power_y0: int = 0

    def add_state(self, name: str, unit: str, scale: float, integrating: bool, stops):
        self.states.append(name)
        self.units.append(unit)
        self.scales.append(scale)
        self.integ.append(integrating)
        self.stops.append(stops or (np.nan, np.nan))


def _place(comps: list[Component], nodes: list[str], index: dict[str, int], fixed: dict,
           volume: dict[str, float], fluid: Fluid) -> _Vectors:
    """Every component's states, inputs, signals and parameter block, in order, after the
    nodes' signals (pressure, net inflow, volume) and the fluid's and nodes' parameters;
    then the energy account's sums."""
    v = _Vectors()
    v.signals = ([f'{NODE_PREFIX}{n}' for n in nodes] + [f'{NODE_PREFIX}{n}.inflow' for n in nodes]
                 + [f'{NODE_PREFIX}{n}.volume' for n in nodes])
    v.sig_units = ['Pa'] * len(nodes) + ['m^3/s'] * len(nodes) + ['m^3'] * len(nodes)
    v.p = [float(getattr(fluid, k)) for k in FLUID_KEYS]
    v.p += [volume[n] if n not in fixed else 0.0 for n in nodes]
    for n, (cname, how, key) in fixed.items():
        if how == 'param':
            comp = next(c for c in comps if c.name == cname)
            v.p[N_FLUID + index[n]] = float(getattr(comp.params, key))
    for comp in comps:
        x0, k0, y0 = len(v.states), len(v.inputs), len(v.signals)
        for s in comp.states():
            v.add_state(f'{comp.name}.{s.name}', s.unit, s.scale, s.integrating, s.stops)
        for s in comp.INPUTS:
            v.inputs.append(f'{comp.name}.{s.name}')
            v.in_units.append(s.unit)
            v.in_ranges.append((s.lo, s.hi))
            v.u0.append(comp.input_default(s))
        for s in comp.SIGNALS:
            v.signals.append(f'{comp.name}.{s.name}')
            v.sig_units.append(s.unit)
        block, used = _port_block(comp, index)
        p0 = len(v.p)
        v.p += block + [float(x) for x in comp.pack()]
        v.parts.append(Part(comp, slice(x0, len(v.states)), slice(k0, len(v.inputs)),
                            slice(y0, len(v.signals)), slice(p0, len(v.p)), used))
        v.dither = max(v.dither, comp.dither_frequency())
    # The energy account's sums after every component's signals (hydropump_sim.energy).
    v.power = energy.power_signals(v.parts, nodes, fixed)
    v.power_y0 = len(v.signals)
    v.signals += v.power.names()
    v.sig_units += ['W'] * len(v.power.names())
    return v


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

