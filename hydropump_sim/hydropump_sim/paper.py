"""The paper's closed forms of the pump alone (eqs. 14-18) and its section IV check.

These are the paper's own linear models of its plant, written out: eq. 14 (growing flow)
and eq. 15 (falling flow) with their transfer matrix (eq. 16), the zero of eq. 17, the pilot
root of eq. 18, and section IV's epsilon for every mode of the fine model. Any model's
numerical linearisation, modal analysis and transfer matrix are in
:mod:`hydropump_sim.linear`; the tests hold one against the other.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import control
import numpy as np

from . import _core as c
from .linear import linearize, LinearModel, modal_analysis, Mode
from .params import Params
from .trim import Equilibrium, equilibrium


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


