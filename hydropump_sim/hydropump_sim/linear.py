"""Linearisation, the paper's linear models (eqs. 14-18) and modal analysis.

Every equilibrium sits at ``x_c = 0``, where eq. 4 has a kink (docs/reference.md I2), so all
linearisations are one-sided: ``branch='pos'`` (growing flow, ``x_c > 0``, eq. 14) or
``branch='neg'`` (falling flow, ``x_c < 0``, eq. 15).
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import control
import numpy as np

from . import _core as c
from .model import INPUTS, OUTPUTS, pack, state_names
from .params import Params
from .trim import Equilibrium, equilibrium


@dataclass(frozen=True)
class LinearModel:
    """``dx = A x + B u``, ``y = C x + D u`` in deviations from an equilibrium (SI)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    states: tuple
    inputs: tuple
    outputs: tuple
    branch: str

    def ss(self, inputs=None, outputs=None) -> control.StateSpace:
        """python-control state space, optionally restricted to named inputs and outputs."""
        ii = [self.inputs.index(n) for n in (inputs or self.inputs)]
        oo = [self.outputs.index(n) for n in (outputs or self.outputs)]
        return control.ss(self.A, self.B[:, ii], self.C[oo, :], self.D[np.ix_(oo, ii)],
                          states=list(self.states), inputs=[self.inputs[i] for i in ii],
                          outputs=[self.outputs[o] for o in oo])


def linearize(params: Params, eq: Equilibrium | None = None, branch: str = 'pos',
              model: str = 'fine') -> LinearModel:
    """One-sided Jacobian linearisation of the nonlinear model by central differences.

    Parameters
    ----------
    params : Params
    eq : Equilibrium, optional
        Operating point; default the nominal equilibrium of ``model``.
    branch : {'pos', 'neg'}
        Side of the pilot-valve kink at ``x_c = 0``.
    model : {'fine', 'simplified', 'simplified_Kc'}

    Returns
    -------
    LinearModel
        Inputs ``[i_s, P_u, xi_u, f_p]``; outputs as :data:`hydropump_sim.model.OUTPUTS`.
    """
    if branch not in ('pos', 'neg'):
        raise ValueError(f"branch must be 'pos' or 'neg', got {branch!r}")
    eq = equilibrium(params, model=model) if eq is None else eq
    p = pack(params, model, branch)
    p[c.P_DITHA] = 0.0
    n = eq.x.size
    x_scale = c.state_scale(p, n)
    u_scale = np.array([params.spool.I_max, 1.0e6, 0.1, 1.0])

    def f(x, u):
        dx = np.empty(n)
        y = np.empty(c.N_Y)
        c.evaluate(0.0, x, u, p, dx, y)
        return dx, y

    def central(vec, scale, k, other, is_state):
        h = 1.0e-6 * scale[k]
        vp, vm = vec.copy(), vec.copy()
        vp[k] += h
        vm[k] -= h
        fp = f(vp, other) if is_state else f(other, vp)
        fm = f(vm, other) if is_state else f(other, vm)
        return (fp[0] - fm[0]) / (2 * h), (fp[1] - fm[1]) / (2 * h)

    A = np.empty((n, n))
    C = np.empty((c.N_Y, n))
    for k in range(n):
        A[:, k], C[:, k] = central(eq.x, x_scale, k, eq.u, True)
    B = np.empty((n, c.N_U))
    D = np.empty((c.N_Y, c.N_U))
    for k in range(c.N_U):
        B[:, k], D[:, k] = central(eq.u, u_scale, k, eq.x, False)
    return LinearModel(A, B, C, D, state_names(params, model), INPUTS, OUTPUTS, branch)


def load_slope(params: Params, eq: Equilibrium) -> float:
    """``G_u = dQ_load/dP_l`` at the operating point [m^3/(s Pa)] (docs/reference.md I10)."""
    ln = params.line
    dp = eq.P_l - eq.u[c.U_PU]
    return ln.mu_u * eq.u[c.U_XI] / ln.gamma_u * dp ** (1.0 / ln.gamma_u - 1.0)


def pilot_root(params: Params, eq: Equilibrium, branch: str) -> float:
    """``r(P)`` of eq. 18 (``f_p`` renamed, I11): sqrt(P_a) or sqrt(P_l - P_a) [Pa^0.5]."""
    dp = eq.P_a - params.fluid.P_T if branch == 'pos' else eq.P_l - eq.P_a
    return math.sqrt(dp)


def paper_linear(params: Params, eq: Equilibrium | None = None, branch: str = 'pos'
                 ) -> LinearModel:
    """The paper's linear model: eq. 14 (``'pos'``) or eq. 15 (``'neg'``).

    States ``[x_a, p_l]``, inputs ``[i_s, p_u]``, outputs ``[p_l, q_l]``. ``beta`` replaces
    ``beta_p`` in eq. 15 (I5) and the local load slope ``G_u`` replaces ``mu_u xi_u`` (I10).
    """
    eq = equilibrium(params) if eq is None else eq
    sp, S_a = params.spool, params.actuator.S_a
    beta, V_l, b_p = params.fluid.beta, params.line.V_l, params.b_p
    m = params.actuator.mu_a * pilot_root(params, eq, branch)
    G_u = load_slope(params, eq)
    pilot = 0.0 if branch == 'pos' else m  # x_c < 0: pilot inflow comes from the line
    A = np.array([[-m / S_a, 0.0],
                  [beta / V_l * (b_p - pilot), -beta * G_u / V_l]])
    B = np.array([[m * sp.phi_s / (S_a * sp.K_a), 0.0],
                  [beta * pilot * sp.phi_s / (V_l * sp.K_a), beta * G_u / V_l]])
    C = np.array([[0.0, 1.0],
                  [b_p - pilot, 0.0]])
    D = np.array([[0.0, 0.0],
                  [pilot * sp.phi_s / sp.K_a, 0.0]])
    return LinearModel(A, B, C, D, ('x_a', 'p_l'), ('i_s', 'p_u'), ('p_l', 'q_l'), branch)


def transfer_matrix(params: Params, eq: Equilibrium | None = None, branch: str = 'pos'
                    ) -> control.TransferFunction:
    """Eq. 16 as a 2x2 transfer matrix from ``[i_s, p_u]`` to ``[p_l, q_l]``.

    ``G21 = eta r f_z(s) / (s S_a + mu_a r)`` with ``eta = mu_a phi_s / K_a``, ``r`` of eq. 18
    and ``f_z`` of eq. 17 (``b_p``, or ``b_p + s S_a`` for falling flow).
    """
    eq = equilibrium(params) if eq is None else eq
    sp, S_a, mu_a = params.spool, params.actuator.S_a, params.actuator.mu_a
    beta, V_l, b_p = params.fluid.beta, params.line.V_l, params.b_p
    r = pilot_root(params, eq, branch)
    eta = mu_a * sp.phi_s / sp.K_a
    G_u = load_slope(params, eq)
    f_z = [b_p] if branch == 'pos' else [S_a, b_p]
    pole_a = [S_a, mu_a * r]
    pole_l = [V_l, beta * G_u]
    num11 = np.polymul([eta * beta * r], f_z)
    den11 = np.polymul(pole_a, pole_l)
    num21 = np.polymul([eta * r], f_z)
    return control.tf([[num11, [beta * G_u]], [num21, [0.0]]],
                      [[den11, pole_l], [pole_a, [1.0]]],
                      inputs=['i_s', 'p_u'], outputs=['p_l', 'q_l'])


def eq14_time_constant(params: Params, eq: Equilibrium | None = None, branch: str = 'pos',
                       keep_Kc: bool = False) -> float:
    """Dominant time constant ``S_a / (mu_a r)`` of eqs. 14/15 [s] (times ``1 + K_c/K_a``)."""
    eq = equilibrium(params) if eq is None else eq
    tau = params.actuator.S_a / (params.actuator.mu_a * pilot_root(params, eq, branch))
    return tau * (1.0 + params.spool.K_c / params.spool.K_a) if keep_Kc else tau


def zero_time_constant(params: Params) -> float:
    """``tau_z = S_a / b_p`` [s], the zero of eq. 17 for falling flow."""
    return params.actuator.S_a / params.b_p


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


@dataclass(frozen=True)
class PerturbationMode:
    mode: Mode
    epsilon: float      # tau_mode / T
    neglected: bool     # outside the control bandwidth


def singular_perturbation_check(params: Params, T: float = 0.05, branch: str = 'pos',
                                eq: Equilibrium | None = None) -> list[PerturbationMode]:
    """Section IV: ``epsilon = tau/T`` for every fine-model mode; ``epsilon < 1`` is outside
    the control bandwidth of a controller averaging over ``T`` [s]."""
    lin = linearize(params, eq, branch)
    return [PerturbationMode(m, m.tau / T, m.tau < T) for m in modal_analysis(lin)]


def bode_data(sys_siso, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude (linear) and phase [deg, unwrapped] of a SISO LTI system at ``omega``."""
    resp = control.frequency_response(sys_siso, omega)
    h = np.asarray(resp.complex).reshape(-1)
    return np.abs(h), np.degrees(np.unwrap(np.angle(h)))
