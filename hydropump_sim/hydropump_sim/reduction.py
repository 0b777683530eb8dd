"""The paper's method applied to any model: section IV component by component, the
simplified model for the controller, and what the controller's model takes of a circuit.

A component's fast dynamics (a valve's lag, the pump's spool and plate inertia) may be made
static when its slowest mode is much faster than the control period ``T``: section IV's
``epsilon = tau/T`` below :data:`EPSILON_STATIC`. The check measures, besides, the error of
making each such component static alone on a test run (every load's command and the pump's
current stepped), as the controller sees it: averaged over ``T``. The pump alone is one such
component, its static form the paper's simplified model (eq. 10).

:func:`with_fidelity` runs that simplified model in place of the fine one (the ``fidelity``
of the simulator node and of ``hydropump circuit``), with its error bound.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import TYPE_CHECKING

import numpy as np

from .errors import InputError
from .metrics import moving_average
from .simulate import simulate
from .steady import equilibrium
from .system import Model, SteadyState

if TYPE_CHECKING:
    from .linear import LinearModel, Mode

#: The control bandwidth of section IV: a controller averaging over T [s].
T_CONTROL = 0.05
#: A mode may be made static when it is this much faster than T (epsilon = tau/T below it):
#: the separation section IV asks for ("much smaller"), a fifth.
EPSILON_STATIC = 0.2
#: The fidelities a model runs at: the fine model, or section IV's simplified one.
FIDELITIES = ('fine', 'simplified')


def component_of(model: Model, state: str) -> str:
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
    it (averaged over ``T``), as a fraction of its excursion in the full model."""

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


def component_modes(model: Model, lin: LinearModel) -> dict[str, list[Mode]]:
    """The modes each component dominates (by participation), slowest first."""
    from .linear import modal_analysis
    out: dict[str, list[Mode]] = {}
    for m in modal_analysis(lin, n_dominant=1):
        out.setdefault(component_of(model, m.dominant[0]), []).append(m)
    return out


def staggered(model: Model, duration: float, target, back: bool = False) -> dict:
    """Each main input moved from where it holds to ``target(name, u0, lo, hi)`` at
    staggered instants over ``duration`` (with ``back``: over its first half, and back at
    the same instants of the second), as functions of time by name."""
    out = {}
    names = model.main_inputs()
    span = 0.5 * duration if back else duration
    for j, name in enumerate(names):
        k = model.input_index(name)
        lo, hi = model.input_ranges[k]
        u0 = model.u0[k]
        on = span * (j + 1) / (len(names) + 1)
        off = on + span if back else math.inf
        u1 = target(name, u0, lo, hi)
        out[name] = (lambda t, a=u0, b=u1, t1=on, t2=off: np.where(
            (np.asarray(t) >= t1) & (np.asarray(t) < t2), b, a))
    return out


def test_inputs(model: Model, duration: float) -> dict:
    """The test run of the check: every load's command and the pump's current stepped by a
    tenth of their range at staggered instants, from the circuit's steady state."""
    def tenth(name, u0, lo, hi):
        span = 0.2 * model.plant_params().spool.I_max if name.endswith('current') \
            else 0.1 * (hi - lo)
        return u0 + span if u0 + span <= hi else u0 - span
    return staggered(model, duration, tenth)


def same_start(model: Model, x: np.ndarray, simple: Model) -> np.ndarray:
    """The state of ``simple`` that starts where ``model`` is at ``x``: every state it keeps
    (by name) at its value there, the others at its own start. Each from its own steady
    state would judge the two steady states too, and a pressure that compensated loads leave
    free (a pump in open loop against its relief valve) differs there by more than any
    transient."""
    out = np.array(simple.start_states(simple.u0)[0], dtype=float)
    at = {name: k for k, name in enumerate(model.states)}
    for j, name in enumerate(simple.states):
        if name in at:
            out[j] = x[at[name]]
    return out


def _errors(full, simple, names, T: float) -> dict[str, float]:
    """The largest deviation of each signal, as the controller sees it (averaged over the
    control period ``T``), as a fraction of its excursion in the full model."""
    width = max(1, int(round(T / float(full.t[1] - full.t[0]))))
    out = {}
    for n in names:
        a = moving_average(full[n], width, edges='shrink')
        b = moving_average(simple[n], width, edges='shrink')
        span = max(float(np.ptp(a)), 1e-12, 1e-3 * float(np.max(np.abs(a))))
        out[n] = float(np.max(np.abs(a - b)) / span)
    return out


def singular_perturbation(model: Model, eq: SteadyState | None = None,
                          T: float = T_CONTROL, duration: float = 1.0,
                          each: bool = True) -> tuple[list[ComponentCheck], dict]:
    """Section IV, component by component (see :class:`ComponentCheck`), and the
    simplified model: every component whose removable dynamics are faster than
    ``EPSILON_STATIC T`` made static at once.

    ``each`` measures the error of each such component made static alone (a compiled
    variant of a circuit each, cached after the first time); the simplified model's error is
    always measured. Returns the checks (slowest first) and ``{'components', 'sets',
    'error'}`` of the simplified model (``sets``: the values that make it, for a circuit).
    """
    # The linear analysis (python-control) is imported where it runs: it takes a second,
    # which the simulator node, reading FIDELITIES at every start, would pay for nothing.
    from .linear import linearize, modal_analysis
    eq = equilibrium(model) if eq is None else eq
    lin = linearize(model, eq, inputs=[], outputs=[])
    modes = modal_analysis(lin, n_dominant=1)
    by_comp = component_modes(model, lin)
    ins = test_inputs(model, duration)
    names = model.judged_signals()
    full = simulate(model, duration, ins, x0=eq.x)
    reducible = model.reducible()
    checks = []
    for comp in model.component_names():
        own = by_comp.get(comp, [])
        removed = reducible.get(comp, ())
        gone = [m for m in modes if m.dominant[0] in removed]
        tau = max((m.tau for m in gone), default=max((m.tau for m in own), default=0.0))
        if not own and not gone:
            continue
        error = {}
        if each and removed and tau < EPSILON_STATIC * T:
            simple = model.made_static([comp])
            res = simulate(simple, duration, ins, x0=same_start(model, eq.x, simple))
            error = _errors(full, res, names, T)
        checks.append(ComponentCheck(comp, tuple(own), removed, tau, tau / T, bool(removed),
                                     error))
    for node, own in by_comp.items():
        if node.startswith('node:'):
            tau = max(m.tau for m in own)
            checks.append(ComponentCheck(node, tuple(own), (), tau, tau / T, False, {}))
    checks.sort(key=lambda c: -c.tau)
    fast = [c.component for c in checks if c.outside]
    simplified = {'components': fast, 'sets': model.static_sets(fast), 'error': {}}
    if fast:
        simple = model.made_static(fast)
        res = simulate(simple, duration, ins, x0=same_start(model, eq.x, simple))
        simplified['error'] = _errors(full, res, names, T)
    return checks, simplified


@dataclass(frozen=True)
class Fidelity:
    """Which model runs: ``fine``, or ``simplified``: section IV at the control bandwidth
    ``bandwidth`` [Hz] (``T = 1/bandwidth``), its ``components`` made static, with the
    ``error`` of each judged signal measured against the fine model on section IV's test run
    as the controller sees it (averaged over ``T``, a fraction of its excursion)."""

    name: str = 'fine'
    bandwidth: float = 1.0 / T_CONTROL
    components: tuple[str, ...] = ()
    error: dict = field(default_factory=dict)

    @property
    def bound(self) -> float:
        """The largest error of any judged signal (0 for the fine model)."""
        return max(self.error.values(), default=0.0)

    def text(self) -> str:
        """One line for a log, a report or the node's diagnostics."""
        if self.name == 'fine':
            return 'fine'
        made = ', '.join(self.components) or 'nothing'
        return (f'simplified at {self.bandwidth:.3g} Hz: {made} made static; error bound '
                f"{self.bound:.2%} of each signal's excursion in the bandwidth")


def with_fidelity(model: Model, fidelity: str = 'fine', bandwidth: float = 0.0,
                  controller: float | None = None, eq: SteadyState | None = None
                  ) -> tuple[Model, Fidelity]:
    """The model to run at ``fidelity`` and what it is (:class:`Fidelity`).

    ``simplified`` makes static, as :func:`singular_perturbation` does, the components whose
    removable modes are faster than ``EPSILON_STATIC / bandwidth``. ``bandwidth`` [Hz] 0
    takes the controller's (``controller`` [Hz], else section IV's ``1/T_CONTROL``). A
    bandwidth below the controller's that would make static a mode the controller acts on
    (one slower than ``EPSILON_STATIC`` of the controller's period) is refused, naming the
    mode: the controller would run against a plant without it.
    """
    if fidelity not in FIDELITIES:
        raise InputError(f'fidelity = {fidelity!r}: use {" or ".join(FIDELITIES)}')
    if fidelity == 'fine':
        return model, Fidelity()
    if not (isinstance(bandwidth, (int, float)) and math.isfinite(bandwidth)
            and bandwidth >= 0):
        raise InputError(f'fidelity bandwidth = {bandwidth!r}: expected a frequency in Hz '
                         "(0 = the controller's)")
    bandwidth = float(bandwidth) or controller or 1.0 / T_CONTROL
    checks, simple = singular_perturbation(model, eq, 1.0 / bandwidth, each=False)
    if controller is not None and bandwidth < controller:
        needed = [c for c in checks if c.outside and c.tau >= EPSILON_STATIC / controller]
        if needed:
            c = max(needed, key=lambda c: c.tau)
            raise InputError(
                f'fidelity bandwidth = {bandwidth:g} Hz: it would make static {c.component} '
                f'(its mode of {c.tau * 1e3:.3g} ms), which the controller acts on (its '
                f'bandwidth {controller:.3g} Hz keeps every mode slower than '
                f'{EPSILON_STATIC / controller * 1e3:.3g} ms); give at least '
                f"{EPSILON_STATIC / c.tau:.3g} Hz, or 0 for the controller's")
    made = tuple(simple['components'])
    return (model.made_static(list(made)) if made else model,
            Fidelity('simplified', bandwidth, made, dict(simple['error'])))


def line_capacitance(model: Model, eq: SteadyState, node: str) -> float:
    """The capacitance [m^3/Pa] a flow into ``node`` sees at low frequency: every node's
    ``V/beta`` weighted by how far its pressure follows the node's at rest (the first
    moment of the response to a flow step). It is ``V_l/beta`` for the paper's plant and
    takes the volumes behind open passages along for a model."""
    from .linear import linearize
    lin = linearize(model, eq, 'pos', inputs=[], outputs=[])
    k = lin.states.index(f'node:{node}')
    b = np.zeros(len(lin.states))
    beta = model.fluid.beta
    b[k] = beta / model.volume[node]
    # A trapped node (an idle load behind a closed valve) makes A singular: its pressure
    # does not follow, which the least-squares solution says.
    dP = np.linalg.lstsq(lin.A, -b, rcond=None)[0]
    total = 0.0
    for j, s in enumerate(lin.states):
        if s.startswith('node:'):
            # A passive network's node follows the line at most fully.
            follow = min(max(dP[j] / dP[k], 0.0), 1.0)
            total += model.volume[s[5:]] / beta * follow
    return float(total) if math.isfinite(total) and total > 0 else model.volume[node] / beta
