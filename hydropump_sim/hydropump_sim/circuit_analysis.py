"""The paper's method applied to a circuit: steady state, linearisation, modal analysis, the
singular-perturbation check of section IV component by component, a simplified circuit
for the controller, and the transfer matrix that generalises eq. 16.

A circuit's integrating states (positions) are left out of the linear models: nothing in
the circuit depends on them away from the end stops, and they would only add poles at the
origin.
"""

from __future__ import annotations

from collections.abc import Sequence
import dataclasses
from dataclasses import dataclass
import math

import control
import numpy as np

from .circuit import Circuit
from .circuit_sim import CircuitEquilibrium, equilibrium, simulate_circuit
from .components.pump import P_BRANCH
from .linear import LinearModel, modal_analysis, Mode
from .metrics import moving_average

#: The control bandwidth of section IV: a controller averaging over T [s].
T_CONTROL = 0.05
#: A mode may be made static when it is this much faster than T (epsilon = tau/T below it):
#: the separation section IV asks for ("much smaller"), a fifth.
EPSILON_STATIC = 0.2


def _branch_p(circuit: Circuit, branch: str | None) -> np.ndarray:
    """The parameter vector with the pump's pilot-valve law forced to one side of its kink
    (``x_c = 0`` at every steady state, docs/reference.md I2)."""
    p = circuit.p.copy()
    pump = circuit.pump()
    if pump is not None and branch is not None:
        p[pump.p.start + pump.comp.P_OFFSET + P_BRANCH] = {'pos': 1.0, 'neg': -1.0}[branch]
    return p


def linearize(circuit: Circuit, eq: CircuitEquilibrium | None = None, *,
              inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
              branch: str | None = 'pos') -> LinearModel:
    """Central-difference linearisation at a steady state (default: the circuit's own).

    Parameters
    ----------
    inputs, outputs : sequence of str, optional
        Input and signal names (a composite's own names resolve); default every input and
        every component signal.
    branch : {'pos', 'neg', None}
        Side of the pump's pilot-valve kink (growing or falling flow); ``None`` leaves it.

    Returns
    -------
    LinearModel
        Over the non-integrating states.
    """
    eq = equilibrium(circuit) if eq is None else eq
    inputs = list(inputs) if inputs is not None else list(circuit.inputs)
    outputs = list(outputs) if outputs is not None else circuit.component_signals()
    p = _branch_p(circuit, branch)
    keep = np.flatnonzero(~circuit.integrating)
    iu = [circuit.input_index(n) for n in inputs]
    iy = [circuit.signal_index(n) for n in outputs]
    n = circuit.n_states
    dx = np.empty(n)
    y = np.empty(circuit.n_signals)

    def f(x, u):
        circuit.evaluate(0.0, x, u, p, dx, y)
        return dx[keep].copy(), y[iy].copy()

    A = np.empty((keep.size, keep.size))
    C = np.empty((len(iy), keep.size))
    for c, k in enumerate(keep):
        h = 1.0e-6 * circuit.state_scale[k]
        xp, xm = eq.x.copy(), eq.x.copy()
        xp[k] += h
        xm[k] -= h
        (fp, yp), (fm, ym) = f(xp, eq.u), f(xm, eq.u)
        A[:, c], C[:, c] = (fp - fm) / (2 * h), (yp - ym) / (2 * h)
    B = np.empty((keep.size, len(iu)))
    D = np.empty((len(iy), len(iu)))
    for c, k in enumerate(iu):
        lo, hi = circuit.input_ranges[k]
        h = 1.0e-6 * max(abs(eq.u[k]), (hi - lo) * 1e-3, 1e-9)
        up, um = eq.u.copy(), eq.u.copy()
        up[k] += h
        um[k] -= h
        (fp, yp), (fm, ym) = f(eq.x, up), f(eq.x, um)
        B[:, c], D[:, c] = (fp - fm) / (2 * h), (yp - ym) / (2 * h)
    return LinearModel(A, B, C, D, tuple(circuit.states[k] for k in keep), tuple(inputs),
                       tuple(outputs), branch or 'natural')


def component_of(circuit: Circuit, state: str) -> str:
    """The component a state belongs to (``node:<n>`` for a node's pressure)."""
    if state.startswith('node:'):
        return state
    return state.rpartition('.')[0]


@dataclass(frozen=True)
class ComponentCheck:
    """Section IV for one component: the modes its states dominate; those its static form
    would remove (``removed``: its lag's, or the pump's spool and plate inertia for eq. 10)
    and the slowest of them, ``tau`` and ``epsilon = tau/T``; whether they lie outside the
    control bandwidth (``epsilon < 1``); and, where measured, the error of making it static
    alone on a test run: the largest deviation of each judged signal as the controller sees
    it (averaged over ``T``), as a fraction of its excursion in the full circuit."""

    component: str
    modes: tuple[Mode, ...]
    removed: tuple[str, ...]
    tau: float
    epsilon: float
    static: bool
    error: dict

    @property
    def outside(self) -> bool:
        """Its removable dynamics are fast enough to be made static."""
        return self.static and self.epsilon < EPSILON_STATIC


def component_modes(circuit: Circuit, lin: LinearModel) -> dict[str, list[Mode]]:
    """The modes each component dominates (by participation), slowest first."""
    out: dict[str, list[Mode]] = {}
    for m in modal_analysis(lin, n_dominant=1):
        out.setdefault(component_of(circuit, m.dominant[0]), []).append(m)
    return out


def removed_states(comp) -> tuple[str, ...]:
    """The states a component's static form does without (no compile: its own states)."""
    values = comp.static_values()
    if values is None:
        return ()
    static = type(comp)(comp.name, dataclasses.replace(comp.params, **values), comp.ports,
                        comp.fluid)
    keep = {s.name for s in static.states()}
    return tuple(f'{comp.name}.{s.name}' for s in comp.states() if s.name not in keep)


def static_sets(circuit: Circuit, components: Sequence[str]) -> dict:
    """``--set`` values that make the named components static."""
    sets = {}
    for pt in circuit.parts:
        if pt.comp.name in components:
            for k, v in (pt.comp.static_values() or {}).items():
                sets[f'{pt.comp.name}.{k}'] = v
    return sets


def main_inputs(circuit: Circuit) -> list[str]:
    """The pump's current and every load's command (a section's by its own name)."""
    aliased = {t for exp in circuit.composites.values() for t in exp.inputs.values()}
    names = [n for n in circuit.all_inputs() if n.endswith('.command') and n not in aliased]
    if circuit.electric_pump():
        names.insert(0, f'{circuit.pump().comp.name}.current')
    return names


def test_inputs(circuit: Circuit, duration: float) -> dict:
    """The test run of the check: every load's command and the pump's current stepped by a
    tenth of their range at staggered instants, from the circuit's steady state."""
    out = {}
    names = main_inputs(circuit)
    pump = circuit.pump()
    for j, name in enumerate(names):
        k = circuit.input_index(name)
        lo, hi = circuit.input_ranges[k]
        u0 = circuit.u0[k]
        span = 0.2 * pump.comp.params.plant.spool.I_max if name.endswith('current') \
            else 0.1 * (hi - lo)
        u1 = u0 + span if u0 + span <= hi else u0 - span
        t_step = duration * (j + 1) / (len(names) + 1)
        out[name] = (lambda t, a=u0, b=u1, ts=t_step: np.where(np.asarray(t) < ts, a, b))
    return out


def judged_signals(circuit: Circuit) -> list[str]:
    """Line and load-sensing pressures and every load's flow."""
    m = circuit.measured()
    out = [m[k] for k in ('line_pressure', 'ls_pressure') if k in m]
    out += [v['flow'] for v in circuit.loads().values() if 'flow' in v]
    return out


def _errors(full, simple, names, T: float) -> dict[str, float]:
    """The largest deviation of each signal, as the controller sees it (averaged over the
    control period ``T``), as a fraction of its excursion in the full circuit."""
    width = max(1, int(round(T / float(full.t[1] - full.t[0]))))
    out = {}
    for n in names:
        a = moving_average(full[n], width, edges='shrink')
        b = moving_average(simple[n], width, edges='shrink')
        span = max(float(np.ptp(a)), 1e-12, 1e-3 * float(np.max(np.abs(a))))
        out[n] = float(np.max(np.abs(a - b)) / span)
    return out


def singular_perturbation(circuit: Circuit, eq: CircuitEquilibrium | None = None,
                          T: float = T_CONTROL, duration: float = 1.0,
                          each: bool = True) -> tuple[list[ComponentCheck], dict]:
    """Section IV, component by component (see :class:`ComponentCheck`), and the
    simplified circuit: every component whose removable dynamics are faster than
    ``EPSILON_STATIC T`` made static at once.

    ``each`` measures the error of each such component made static alone (a compiled
    variant of the circuit each, cached after the first time); the simplified circuit's
    error is always measured. Returns the checks (slowest first) and ``{'components',
    'sets', 'error'}`` of the simplified circuit.
    """
    eq = equilibrium(circuit) if eq is None else eq
    lin = linearize(circuit, eq, inputs=[], outputs=[])
    modes = modal_analysis(lin, n_dominant=1)
    by_comp = component_modes(circuit, lin)
    ins = test_inputs(circuit, duration)
    names = judged_signals(circuit)
    full = simulate_circuit(circuit, duration, ins, x0=eq.x)
    checks = []
    for part in circuit.parts:
        comp = part.comp
        own = by_comp.get(comp.name, [])
        removed = removed_states(comp)
        gone = [m for m in modes if m.dominant[0] in removed]
        tau = max((m.tau for m in gone), default=max((m.tau for m in own), default=0.0))
        if not own and not gone:
            continue
        error = {}
        if each and removed and tau < EPSILON_STATIC * T:
            res = simulate_circuit(circuit.with_values(static_sets(circuit, [comp.name])),
                                   duration, ins)
            error = _errors(full, res, names, T)
        checks.append(ComponentCheck(comp.name, tuple(own), removed, tau, tau / T,
                                     bool(removed), error))
    for node, own in by_comp.items():
        if node.startswith('node:'):
            tau = max(m.tau for m in own)
            checks.append(ComponentCheck(node, tuple(own), (), tau, tau / T, False, {}))
    checks.sort(key=lambda c: -c.tau)
    fast = [c.component for c in checks if c.outside]
    sets = static_sets(circuit, fast)
    simplified = {'components': fast, 'sets': sets, 'error': {}}
    if sets:
        res = simulate_circuit(circuit.with_values(sets), duration, ins)
        simplified['error'] = _errors(full, res, names, T)
    return checks, simplified


def transfer_matrix(circuit: Circuit, eq: CircuitEquilibrium | None = None,
                    inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
                    branch: str = 'pos') -> control.TransferFunction:
    """The transfer matrix from the pump's current and the loads' commands to the line and
    load-sensing pressures and the load flows (the generalisation of eq. 16), as
    python-control transfer functions of the linearisation."""
    eq = equilibrium(circuit) if eq is None else eq
    inputs = main_inputs(circuit) if inputs is None else list(inputs)
    outputs = judged_signals(circuit) if outputs is None else list(outputs)
    lin = linearize(circuit, eq, inputs=inputs, outputs=outputs, branch=branch)
    # python-control's names take no dots: boom.flow -> boom_flow.
    def name(s):
        return s.replace('.', '_').replace(':', '_')
    sys = control.ss(lin.A, lin.B, lin.C, lin.D, states=[name(s) for s in lin.states],
                     inputs=[name(s) for s in lin.inputs],
                     outputs=[name(s) for s in lin.outputs])
    return control.ss2tf(sys)


def line_capacitance(circuit: Circuit, eq: CircuitEquilibrium, node: str) -> float:
    """The capacitance [m^3/Pa] a flow into ``node`` sees at low frequency: every node's
    ``V/beta`` weighted by how far its pressure follows the node's at rest (the first
    moment of the response to a flow step). It is ``V_l/beta`` for the paper's plant and
    takes the volumes behind open passages along for a circuit."""
    lin = linearize(circuit, eq, inputs=[], outputs=[], branch='pos')
    k = lin.states.index(f'node:{node}')
    b = np.zeros(len(lin.states))
    beta = circuit.fluid.beta
    b[k] = beta / circuit.volume[node]
    # A trapped node (an idle load behind a closed valve) makes A singular: its pressure
    # does not follow, which the least-squares solution says.
    dP = np.linalg.lstsq(lin.A, -b, rcond=None)[0]
    total = 0.0
    for j, s in enumerate(lin.states):
        if s.startswith('node:'):
            # A passive network's node follows the line at most fully.
            follow = min(max(dP[j] / dP[k], 0.0), 1.0)
            total += circuit.volume[s[5:]] / beta * follow
    return float(total) if math.isfinite(total) and total > 0 else circuit.volume[node] / beta
