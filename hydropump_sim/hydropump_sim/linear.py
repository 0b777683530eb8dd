"""Linearisation, modal analysis and the transfer matrix of any model.

A steady state of a pump sits at ``x_c = 0``, where its pilot valve's law has a kink (eq. 4,
docs/reference.md I2), so linearisations are one-sided: ``branch='pos'`` (growing flow,
``x_c > 0``, eq. 14) or ``branch='neg'`` (falling flow, ``x_c < 0``, eq. 15). A model's
integrating states (a cylinder's position) are left out: nothing depends on them away from
the end stops, and they would only add poles at the origin.

The paper's own closed forms of the pump alone (eqs. 14-18) are in :mod:`hydropump_sim.paper`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import control
import numpy as np

from .model import INPUTS, OUTPUTS
from .params import Params
from .plant_model import INPUT_NAMES, PumpModel, SIGNAL_NAMES, STATE_NAMES
from .steady import equilibrium
from .system import Model, SteadyState


@dataclass(frozen=True)
class LinearModel:
    """``dx = A x + B u``, ``y = C x + D u`` in deviations from a steady state (SI)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple
    inputs: tuple
    outputs: tuple
    branch: str

    def ss(self, inputs=None, outputs=None) -> control.StateSpace:
        """python-control state space, optionally restricted to named inputs and outputs
        (python-control's names take no dots: ``pump.q_l`` is ``pump_q_l`` there)."""
        ii = [self.inputs.index(n) for n in (inputs or self.inputs)]
        oo = [self.outputs.index(n) for n in (outputs or self.outputs)]
        return control.ss(self.A, self.B[:, ii], self.C[oo, :], self.D[np.ix_(oo, ii)],
                          states=[_py(s) for s in self.states],
                          inputs=[_py(self.inputs[i]) for i in ii],
                          outputs=[_py(self.outputs[o]) for o in oo])


def _py(name: str) -> str:
    return name.replace('.', '_').replace(':', '_')


def linearize(plant: Model | Params, eq: SteadyState | None = None, branch: str | None = 'pos',
              model: str = 'fine', *, inputs: Sequence[str] | None = None,
              outputs: Sequence[str] | None = None) -> LinearModel:
    """Central-difference linearisation at a steady state (default: the model's own).

    Parameters
    ----------
    plant : Model or Params
        Any model; or the paper's plant by its parameters, whose linear model then takes
        the paper's names (inputs ``[i_s, P_u, xi_u, f_p]``, outputs
        :data:`hydropump_sim.model.OUTPUTS`, states ``x_c .. P_l``).
    eq : SteadyState, optional
    branch : {'pos', 'neg', None}
        Side of the pump's pilot-valve kink (growing or falling flow); ``None`` leaves it.
    model : {'fine', 'simplified', 'simplified_Kc'}
        The paper plant's form.
    inputs, outputs : sequence of str, optional
        Input and signal names (default every input and every signal a user reads).

    Returns
    -------
    LinearModel
        Over the non-integrating states.
    """
    if branch not in ('pos', 'neg', None):
        raise ValueError(f"branch must be 'pos', 'neg' or None, got {branch!r}")
    if isinstance(plant, Params):
        return _paper_names(linearize(PumpModel(plant, model), eq, branch,
                                      inputs=list(INPUT_NAMES),
                                      outputs=[SIGNAL_NAMES[o] for o in OUTPUTS]))
    m = plant
    eq = equilibrium(m) if eq is None else eq
    inputs = list(inputs) if inputs is not None else list(m.inputs)
    outputs = list(outputs) if outputs is not None else m.component_signals()
    p = m.branch_p(branch)
    keep = np.flatnonzero(~m.integrating)
    iu = [m.input_index(n) for n in inputs]
    iy = [m.signal_index(n) for n in outputs]
    n = m.n_states
    dx = np.empty(n)
    y = np.empty(m.n_signals)

    def f(x, u):
        m.evaluate(0.0, x, u, p, dx, y)
        return dx[keep].copy(), y[iy].copy()

    A = np.empty((keep.size, keep.size))
    C = np.empty((len(iy), keep.size))
    for c, k in enumerate(keep):
        h = 1.0e-6 * m.state_scale[k]
        xp, xm = eq.x.copy(), eq.x.copy()
        xp[k] += h
        xm[k] -= h
        (fp, yp), (fm, ym) = f(xp, eq.u), f(xm, eq.u)
        A[:, c], C[:, c] = (fp - fm) / (2 * h), (yp - ym) / (2 * h)
    B = np.empty((keep.size, len(iu)))
    D = np.empty((len(iy), len(iu)))
    for c, k in enumerate(iu):
        h = 1.0e-6 * m.input_step(k, eq.u)
        up, um = eq.u.copy(), eq.u.copy()
        up[k] += h
        um[k] -= h
        (fp, yp), (fm, ym) = f(eq.x, up), f(eq.x, um)
        B[:, c], D[:, c] = (fp - fm) / (2 * h), (yp - ym) / (2 * h)
    return LinearModel(A, B, C, D, tuple(m.states[k] for k in keep), tuple(inputs),
                       tuple(outputs), branch or 'natural')


def _paper_names(lin: LinearModel) -> LinearModel:
    """The paper's names on a linear model of the pump alone."""
    states = {v: k for k, v in STATE_NAMES.items()}
    return LinearModel(lin.A, lin.B, lin.C, lin.D, tuple(states[s] for s in lin.states),
                       INPUTS, OUTPUTS, lin.branch)


def transfer_matrix(model: Model, eq: SteadyState | None = None,
                    inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None,
                    branch: str = 'pos') -> control.TransferFunction:
    """The transfer matrix of a linearisation (python-control transfer functions; names
    with ``_`` for ``.``), by default from the pump's current and the loads' commands to the
    line and load-sensing pressures and the load flows: eq. 16 generalised (for the pump
    alone, its closed form is :func:`hydropump_sim.paper.transfer_matrix`)."""
    eq = equilibrium(model) if eq is None else eq
    inputs = model.main_inputs() if inputs is None else list(inputs)
    outputs = model.judged_signals() if outputs is None else list(outputs)
    return control.ss2tf(linearize(model, eq, branch, inputs=inputs, outputs=outputs).ss())


@dataclass(frozen=True)
class Mode:
    """One eigenvalue (or complex pair) of a linear model."""

    eigenvalue: complex
    tau: float          # s, 1/|Re|
    f_n: float          # Hz, natural frequency |lambda|/(2 pi); 0 for real modes
    zeta: float         # damping ratio; 1 for real modes
    dominant: tuple     # state names, largest participation first
    participation: tuple

    @property
    def oscillatory(self) -> bool:
        return abs(self.eigenvalue.imag) > 0.0


def modal_analysis(lin: LinearModel, n_dominant: int = 2) -> list[Mode]:
    """Eigenvalues with time constants, natural frequencies, damping and dominant states.

    Dominant states are ranked by participation factors ``|v_ik w_ki|`` (right and left
    eigenvectors), normalised to sum to one per mode. Complex pairs are listed once (the
    member with positive imaginary part); modes are sorted slowest first.
    """
    lam, V = np.linalg.eig(lin.A)
    W = np.linalg.inv(V)
    modes = []
    for k, l_k in enumerate(lam):
        if l_k.imag < 0.0:
            continue
        part = np.abs(V[:, k] * W[k, :])
        part = part / part.sum()
        order = np.argsort(part)[::-1]
        osc = abs(l_k.imag) > 1e-9 * abs(l_k)
        modes.append(Mode(
            eigenvalue=complex(l_k) if osc else complex(l_k.real, 0.0),
            tau=1.0 / abs(l_k.real) if l_k.real != 0 else math.inf,
            f_n=abs(l_k) / (2 * math.pi) if osc else 0.0,
            zeta=-l_k.real / abs(l_k) if osc else 1.0,
            dominant=tuple(lin.states[i] for i in order[:n_dominant]),
            participation=tuple(float(part[i]) for i in order[:n_dominant])))
    return sorted(modes, key=lambda m: -m.tau)


def bode_data(sys_siso, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude (linear) and phase [deg, unwrapped] of a SISO LTI system at ``omega``."""
    resp = control.frequency_response(sys_siso, omega)
    h = np.asarray(resp.complex).reshape(-1)
    return np.abs(h), np.degrees(np.unwrap(np.angle(h)))
