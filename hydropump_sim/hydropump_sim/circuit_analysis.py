"""The paper's method applied to a circuit: steady state, linearisation, modal analysis, the
singular-perturbation check of section IV component by component, a simplified circuit
for the controller, and the transfer matrix that generalises eq. 16.

A circuit's integrating states (positions) are left out of the linear models: nothing in
the circuit depends on them away from the end stops, and they would only add poles at the
origin.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import control
import numpy as np

from .circuit import Circuit
from .circuit_sim import CircuitEquilibrium, equilibrium, simulate_circuit
from .components.pump import P_BRANCH
from .linear import LinearModel, modal_analysis, Mode

#: The control bandwidth of section IV: a controller averaging over T [s].
T_CONTROL = 0.05


def _branch_p(circuit: Circuit, branch: str | None) -> np.ndarray:
    """The parameter vector with the pump's pilot-valve law forced to one side of its kink
    (``x_c = 0`` at every steady state, docs/reference.md I2)."""
    p = circuit.p.copy()
    pump = circuit.pump()
    if pump is not None and branch is not None:
        p[pump.p.start + 1 + P_BRANCH] = {'pos': 1.0, 'neg': -1.0}[branch]
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
    """Section IV for one component: its slowest mode, whether it lies outside the control
    bandwidth (``epsilon = tau/T < 1``), whether it can be made static, and the error of
    doing so alone, measured on a test run (largest deviation of each judged signal as a
    fraction of its excursion in the full circuit)."""

    component: str
    modes: tuple[Mode, ...]
    tau: float
    epsilon: float
    static: bool
    error: dict


def component_modes(circuit: Circuit, lin: LinearModel) -> dict[str, list[Mode]]:
    """The modes each component dominates (by participation), slowest first."""
    out: dict[str, list[Mode]] = {}
    for m in modal_analysis(lin, n_dominant=1):
        out.setdefault(component_of(circuit, m.dominant[0]), []).append(m)
    return out


def static_sets(circuit: Circuit, components: Sequence[str]) -> dict:
    """``--set`` values that make the named components static."""
    sets = {}
    for pt in circuit.parts:
        if pt.comp.name in components:
            for k, v in (pt.comp.static_values() or {}).items():
                sets[f'{pt.comp.name}.{k}'] = v
    return sets


def test_inputs(circuit: Circuit, duration: float) -> dict:
    """The test run of the check: every load's command and the pump's current stepped by a
    tenth of their range at staggered instants, from the circuit's steady state."""
    out = {}
    names = [n for n in circuit.all_inputs() if n.endswith('.command')]
    pump = circuit.pump()
    if pump is not None and pump.comp.kind == 'pump':
        names.insert(0, f'{pump.comp.name}.current')
    for j, name in enumerate(names):
        k = circuit.input_index(name)
        lo, hi = circuit.input_ranges[k]
        u0 = circuit.u0[k]
        span = 0.2 * circuit.pump().comp.params.plant.spool.I_max if name.endswith('current') \
            else 0.1 * (hi - lo)
        u1 = min(max(u0 + span, lo), hi) if u0 + span <= hi else u0 - span
        t_step = duration * (j + 1) / (len(names) + 1)
        out[name] = (lambda t, a=u0, b=u1, ts=t_step: np.where(np.asarray(t) < ts, a, b))
    return out


def judged_signals(circuit: Circuit) -> list[str]:
    """Line and load-sensing pressures and every load's flow."""
    m = circuit.measured()
    out = [m[k] for k in ('line_pressure', 'ls_pressure') if k in m]
    out += [v['flow'] for v in circuit.loads().values() if 'flow' in v]
    return out


def _errors(full, simple, names) -> dict[str, float]:
    out = {}
    for n in names:
        a, b = full[n], simple[n]
        span = max(float(np.ptp(a)), 1e-12, 1e-3 * float(np.max(np.abs(a))))
        out[n] = float(np.max(np.abs(a - b)) / span)
    return out


def singular_perturbation(circuit: Circuit, eq: CircuitEquilibrium | None = None,
                          T: float = T_CONTROL, duration: float = 1.0
                          ) -> tuple[list[ComponentCheck], dict]:
    """Section IV, component by component (see :class:`ComponentCheck`), and the
    simplified circuit: every component outside the bandwidth made static at once.

    Returns the checks (slowest component first) and ``{'sets', 'error', 'components'}`` of
    the simplified circuit (its ``--set`` values and its measured error).
    """
    eq = equilibrium(circuit) if eq is None else eq
    lin = linearize(circuit, eq, inputs=[], outputs=[])
    by_comp = component_modes(circuit, lin)
    ins = test_inputs(circuit, duration)
    names = judged_signals(circuit)
    full = simulate_circuit(circuit, duration, ins, x0=eq.x)
    checks = []
    fast = []
    for name, modes in by_comp.items():
        tau = max(m.tau for m in modes)
        comp = next((pt.comp for pt in circuit.parts if pt.comp.name == name), None)
        can = comp is not None and comp.static_values() is not None
        error = {}
        if can:
            simple = circuit.with_values(static_sets(circuit, [name]))
            res = simulate_circuit(simple, duration, ins)
            error = _errors(full, res, names)
            if tau < T:
                fast.append(name)
        checks.append(ComponentCheck(name, tuple(modes), tau, tau / T, can, error))
    checks.sort(key=lambda c: -c.tau)
    sets = static_sets(circuit, fast)
    simplified = {'components': fast, 'sets': sets, 'error': {}}
    if sets:
        res = simulate_circuit(circuit.with_values(sets), duration, ins)
        simplified['error'] = _errors(full, res, names)
    return checks, simplified


def transfer_matrix(circuit: Circuit, eq: CircuitEquilibrium | None = None,
                    inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
                    branch: str = 'pos') -> control.TransferFunction:
    """The transfer matrix from the pump's current and the loads' commands to the line and
    load-sensing pressures and the load flows (the generalisation of eq. 16), as
    python-control transfer functions of the linearisation."""
    eq = equilibrium(circuit) if eq is None else eq
    if inputs is None:
        inputs = [n for n in circuit.all_inputs() if n.endswith('.command')]
        pump = circuit.pump()
        if pump is not None and pump.comp.kind == 'pump':
            inputs.insert(0, f'{pump.comp.name}.current')
    outputs = judged_signals(circuit) if outputs is None else list(outputs)
    lin = linearize(circuit, eq, inputs=inputs, outputs=outputs, branch=branch)
    return control.ss2tf(lin.ss())


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
