"""Gains from closed-loop eigenvalues, loop margins on the linear model with the delay, and the
design tool behind ``hydropump design``.

Every EMC gain here comes from an eigenvalue chosen in the ``emc`` group (as a continuous time
constant ``tau``, i.e. the discrete pole ``exp(-T/tau)``):

- reference generator: ``k_r`` puts the pole of the nominal model under the law
  ``v_r = Q_r + k_r (r - Q_r)`` at ``exp(-T/tau_reference)`` (``k_r_margin`` at
  ``exp(-T/tau_margin_flow)`` in margin mode, where the flow target moves with the estimated
  load conductance: disturbance rejection wants the faster trajectory);
- state feedback: ``k_x`` puts the tracking-error pole at ``exp(-T/tau_control)``;
- noise estimator (flow): ``(l_Q, l_d)`` put the two eigenvalues of the flow state and the
  random-walk disturbance at ``exp(-T/tau_estimator_fast)`` and ``exp(-T/tau_estimator_slow)``,
  once for each branch of the embedded model (eqs. 14 and 15 with its zero);
- noise estimator (line): ``(l_p, l_k)`` put the eigenvalues of the margin and the load
  conductance at ``exp(-T/tau_line_fast)``, ``exp(-T/tau_line_slow)``, recomputed each update
  from the line pole of the current operating point, so one tuning holds over the whole
  aperture range.

With a perfect model the closed-loop eigenvalues are these, plus ``N = t_d/T`` poles at the
origin from the measurement delay line (separation of estimator, control and delay).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import TYPE_CHECKING
import warnings

import numpy as np

from .schema import ControllerConfig

if TYPE_CHECKING:
    import control


def pole(tau: float, T: float) -> float:
    """Discrete pole ``exp(-T/tau)`` of a continuous time constant ``tau`` [s]."""
    return math.exp(-T / tau)


def observer_gains(Phi: np.ndarray, C: np.ndarray, poles) -> np.ndarray:
    """Predictor-form observer gain ``L`` with ``eig(Phi - L C) = poles`` (Ackermann).

    ``Phi`` is n x n, ``C`` 1 x n; the pair must be observable.
    """
    Phi = np.asarray(Phi, dtype=float)
    C = np.atleast_2d(np.asarray(C, dtype=float))
    n = Phi.shape[0]
    obs = np.vstack([C @ np.linalg.matrix_power(Phi, i) for i in range(n)])
    coeffs = np.real(np.poly(poles))
    p_of_phi = sum(c * np.linalg.matrix_power(Phi, n - i) for i, c in enumerate(coeffs))
    e_n = np.zeros((n, 1))
    e_n[-1, 0] = 1.0
    return (p_of_phi @ np.linalg.solve(obs, e_n)).ravel()


@dataclass(frozen=True)
class BranchGains:
    """Noise-estimator gains of one branch of the embedded model (predictor form).

    ``alpha`` is the branch's discrete pole and ``c`` the output feedthrough of the zero of
    eq. 17 (``y = (1 - c) Q + c (v + d)``); ``l_Q`` [-] and ``l_d`` [-] multiply the flow
    model error (both sides in m^3/s).
    """

    alpha: float
    c: float
    l_Q: float
    l_d: float


@dataclass(frozen=True)
class EmcGains:
    """All EMC gains for one update period ``T`` (see the module docstring)."""

    T: float
    N: int
    k_r: float
    k_r_margin: float
    k_x: float
    up: BranchGains
    down: BranchGains
    reference_limit: float   # m^3/s, largest |v_r - Q_r| of the reference generator
    poles: dict              # name -> discrete eigenvalue

    def branch(self, error: float) -> BranchGains:
        """Gains of the branch that a spool error ``v + d - Q`` selects."""
        return self.up if error >= 0.0 else self.down


def flow_estimator_gains(alpha: float, c: float, poles) -> tuple[float, float]:
    """``(l_Q, l_d)`` for ``Phi = [[alpha, 1 - alpha], [0, 1]]``, ``C = [1 - c, c]``."""
    L = observer_gains([[alpha, 1.0 - alpha], [0.0, 1.0]], [[1.0 - c, c]], poles)
    return float(L[0]), float(L[1])


def emc_gains(cfg: ControllerConfig, T: float | None = None) -> EmcGains:
    """EMC gains of ``cfg`` for the update period ``T`` (default: the nominal period)."""
    T = cfg.period if T is None else T
    m, e = cfg.model, cfg.emc
    a_up, a_dn = pole(m.tau, T), pole(m.tau_down, T)
    p_r, p_c = pole(e.tau_reference, T), pole(e.tau_control, T)
    p_est = (pole(e.tau_estimator_fast, T), pole(e.tau_estimator_slow, T))
    up = BranchGains(a_up, 0.0, *flow_estimator_gains(a_up, 0.0, p_est))
    c_dn = m.tau_z / m.tau_down
    down = BranchGains(a_dn, c_dn, *flow_estimator_gains(a_dn, c_dn, p_est))
    poles = {'reference': p_r, 'control': p_c, 'estimator_fast': p_est[0],
             'estimator_slow': p_est[1], 'line_fast': pole(e.tau_line_fast, T),
             'line_slow': pole(e.tau_line_slow, T), 'margin_reference':
             pole(e.tau_margin_reference, T), 'margin_flow': pole(e.tau_margin_flow, T)}
    return EmcGains(T=T, N=max(1, int(round(m.t_d / T))), k_r=(1.0 - p_r) / (1.0 - a_up),
                    k_r_margin=(1.0 - poles['margin_flow']) / (1.0 - a_up),
                    k_x=(a_up - p_c) / (1.0 - a_up), up=up, down=down,
                    reference_limit=e.reference_headroom * m.flow_error_max, poles=poles)


def line_estimator_gains(alpha: float, gamma: float, p1: float, p2: float
                         ) -> tuple[float, float]:
    """Predictor-form gains ``(l_p, l_k)`` of the margin and load-conductance estimator.

    Linearised in relative terms (``p = d(dp)/dp``, ``kappa = d(ln k)``) the line is
    ``p+ = alpha p + (1 - alpha) gamma (q - kappa)``, ``kappa+ = kappa``, measured ``p``; the
    gains place ``eig(Phi - L C)`` at ``p1, p2``. The load conductance is a random walk, so its
    one-step prediction ``kappa + l_k e`` is also its best present estimate, which the control
    law uses at once. Well defined for a fast line (``alpha -> 0``, quasi-static) and up to
    ``alpha = 0.98``.
    """
    alpha = min(max(alpha, 0.0), 0.98)
    l_p = alpha + 1.0 - p1 - p2
    l_k = ((alpha - l_p) - p1 * p2) / (gamma * (1.0 - alpha))
    return l_p, l_k


def compensated_estimator_gains(C_l: float, T: float, p1: float, p2: float
                                ) -> tuple[float, float]:
    """Predictor-form gains ``(l_p, l_q)`` of the margin and load-flow estimator against
    compensated loads: ``dp+ = dp + T/C_l (q - q_load)``, ``q_load+ = q_load``, measured
    ``dp``; the gains place ``eig(Phi - L C)`` at ``p1, p2`` (``l_p`` on the margin error in
    Pa, ``l_q`` in m^3/s per Pa)."""
    l_p = 2.0 - p1 - p2
    l_q = -(1.0 - p1) * (1.0 - p2) * C_l / T
    return l_p, l_q


# --- linear analysis ------------------------------------------------------------------------

def emc_flow_lti(cfg: ControllerConfig, branch: str = 'up') -> control.StateSpace:
    """The flow-mode EMC as a discrete LTI system from the measured flow to the command.

    Constant reference, no saturation: what remains is the noise estimator on the delayed
    embedded model, the ``N``-step predictor and the state feedback with disturbance
    cancellation, in flow units (m^3/s in, m^3/s out; the command is ``v`` of eq. 11). The
    ``branch`` ('up' or 'down') selects the model pole, the output zero and the estimator
    gains, as the controller does.
    """
    g = emc_gains(cfg)
    b = g.up if branch == 'up' else g.down
    a, c, N = b.alpha, b.c, g.N
    # State: [Q_m, d_m, v[k-1], ..., v[k-N-1]]
    n = 3 + N

    def f(x, y):
        Qm, dm, hist = x[0], x[1], x[2:]
        e = y - ((1.0 - c) * Qm + c * (hist[N] + dm))
        Qm2 = a * Qm + (1.0 - a) * (hist[N - 1] + dm) + b.l_Q * e
        dm2 = dm + b.l_d * e
        Q = Qm2
        for j in range(N - 2, -1, -1):
            Q = a * Q + (1.0 - a) * (hist[j] + dm2)
        v = -g.k_x * Q - dm2
        return np.concatenate([[Qm2, dm2, v], hist[:-1]]), v

    return _probe(f, n, g.T)


def _probe(f, n: int, T: float) -> control.StateSpace:
    """State-space matrices of a linear step function ``f(x, y) -> (x_next, u)``."""
    import control  # python-control costs a second to import: analysis only
    A, B = np.zeros((n, n)), np.zeros((n, 1))
    C, D = np.zeros((1, n)), np.zeros((1, 1))
    for i in range(n):
        x = np.zeros(n)
        x[i] = 1.0
        A[:, i], C[0, i] = f(x, 0.0)
    B[:, 0], D[0, 0] = f(np.zeros(n), 1.0)
    return control.ss(A, B, C, D, T)


def pi_lti(p: float, i: float, T: float) -> control.TransferFunction:
    """The PI as implemented (control_toolbox order): ``u = p e + I``, then ``I += T i e``."""
    import control  # python-control costs a second to import: analysis only
    return control.tf([p, T * i - p], [1.0, -1.0], T)


def flow_plant_lti(cfg: ControllerConfig, branch: str = 'up', gain: float = 1.0,
                   tau_scale: float = 1.0, delay: float | None = None) -> control.StateSpace:
    """Eq. 19 (growing flow) or eq. 15 with the zero of eq. 17 (falling flow), sampled.

    From the flow command ``v`` [m^3/s] (eq. 11) to the measured flow, with the measurement
    delay as whole periods plus a linear interpolation for the fraction, as the bench sensor
    model does. The zero acts through the spool, which follows the held command at once: a
    sample taken at ``t_k`` sees the command of the period before.
    """
    import control  # python-control costs a second to import: analysis only
    m, T = cfg.model, cfg.period
    tau = (m.tau if branch == 'up' else m.tau_down) * tau_scale
    c = 0.0 if branch == 'up' else m.tau_z / tau
    a = math.exp(-T / tau)
    A = np.array([[a, 0.0], [0.0, 0.0]])
    B = np.array([[gain * (1.0 - a)], [gain]])
    Cm = np.array([[1.0 - c, c]])
    P = control.ss(A, B, Cm, np.zeros((1, 1)), T)
    steps = (m.t_d if delay is None else delay) / T
    n = int(math.floor(steps + 1e-9))
    frac = steps - n
    if frac < 1e-9:
        delay_tf = control.tf([1.0], [1.0] + [0.0] * n, T)
    else:
        # z^-n ((1 - f) + f z^-1) = ((1 - f) z + f) / z^(n+1)
        delay_tf = control.tf([1.0 - frac, frac], [1.0] + [0.0] * (n + 1), T)
    return P * delay_tf


@dataclass(frozen=True)
class Margins:
    """Stability margins of a loop ``L(z)`` (negative feedback)."""

    gain_margin: float       # dB
    phase_margin: float      # deg
    delay_margin: float      # s
    crossover: float         # rad/s, the gain crossover of the smallest phase margin
    phase_crossover: float   # rad/s, where the smallest gain margin is taken
    stable: bool             # closed loop stable (all poles inside the unit circle)


def frequency_response(sys, w: np.ndarray) -> np.ndarray:
    """Complex response of a discrete SISO system at ``w`` [rad/s], batched.

    ``C (zI - A)^-1 B + D`` solved for blocks of frequencies at once (python-control solves one
    frequency at a time, 50x slower for the loops here).
    """
    import control  # python-control costs a second to import: analysis only
    ss = control.ss(sys)
    A, B = np.asarray(ss.A, dtype=complex), np.asarray(ss.B, dtype=complex)[:, :1]
    C, D = np.asarray(ss.C, dtype=complex)[:1], complex(np.asarray(ss.D)[0, 0])
    z = np.exp(1j * np.asarray(w) * ss.dt)
    n = A.shape[0]
    out = np.empty(z.size, dtype=complex)
    eye = np.eye(n)
    for i in range(0, z.size, 2000):
        zz = z[i:i + 2000]
        M = zz[:, None, None] * eye - A
        x = np.linalg.solve(M, np.broadcast_to(B, (zz.size, n, 1)))
        out[i:i + 2000] = (C @ x)[:, 0, 0] + D
    return out


def loop_margins(L, n: int = 4000) -> Margins:
    """Gain, phase and delay margins of a discrete SISO loop, scanned up to Nyquist.

    Every gain and phase crossover is examined (python-control's ``stability_margins`` may pick
    a spurious crossing near Nyquist when the loop has direct feedthrough); the delay margin is
    the smallest ``PM / w_c`` over the gain crossovers.
    """
    import control  # python-control costs a second to import: analysis only
    T = L.dt
    w = np.logspace(-2, math.log10(math.pi / T * (1.0 - 1e-6)), n)
    with warnings.catch_warnings():
        # scipy flags the delay line's leading zeros as badly conditioned when L is formed;
        # the state-space evaluation does not use those coefficients.
        warnings.simplefilter('ignore')
        H = frequency_response(L, w)
    mag = np.abs(H)
    ph = np.unwrap(np.angle(H))
    pm, dm, wgc = math.inf, math.inf, math.nan
    above = mag > 1.0
    for i in np.flatnonzero(above[:-1] != above[1:]):
        f = (1.0 - mag[i]) / (mag[i + 1] - mag[i])
        wc = w[i] + f * (w[i + 1] - w[i])
        phc = ph[i] + f * (ph[i + 1] - ph[i])
        pmi = math.degrees((phc + math.pi) % (2.0 * math.pi))
        pmi = pmi - 360.0 if pmi > 180.0 else pmi
        if pmi < pm:
            pm, wgc = pmi, wc
        dm = min(dm, math.radians(pmi) / wc if pmi > 0.0 else 0.0)
    gm, wpc = math.inf, math.nan
    turns = (ph + math.pi) / (2.0 * math.pi)
    for i in np.flatnonzero(np.floor(turns[:-1]) != np.floor(turns[1:])):
        level = max(math.floor(turns[i]), math.floor(turns[i + 1]))
        f = (level - turns[i]) / (turns[i + 1] - turns[i])
        mi = mag[i] + f * (mag[i + 1] - mag[i])
        if mi > 0.0 and 1.0 / mi < gm:
            gm, wpc = 1.0 / mi, w[i] + f * (w[i + 1] - w[i])
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        cl = control.feedback(L, 1)
        stable = bool(np.all(np.abs(control.poles(cl)) < 1.0))
    return Margins(20.0 * math.log10(gm) if math.isfinite(gm) else math.inf, pm, dm, wgc, wpc,
                   stable)


def emc_flow_margins(cfg: ControllerConfig, branch: str = 'up', **plant) -> Margins:
    """Loop margins of the flow-mode EMC on the linear model with the delay, loop broken at
    the plant input."""
    return loop_margins(-emc_flow_lti(cfg, branch) * flow_plant_lti(cfg, branch, **plant))


def pi_flow_margins(cfg: ControllerConfig, branch: str = 'up', **plant) -> Margins:
    """Loop margins of the PI baseline in flow mode (gains converted to flow units)."""
    pg, gain = cfg.pi_flow, cfg.model.gain
    C = pi_lti(pg.p * gain, pg.i * gain, cfg.period)
    return loop_margins(C * flow_plant_lti(cfg, branch, **plant))


def emc_margin_lti(cfg: ControllerConfig, alpha_l: float) -> control.StateSpace:
    """The margin-mode EMC, linearised in relative units, from the measured margin to the
    command.

    Variables are relative deviations at the operating point: flow ``q = dQ/Q``, margin
    ``p = d(dp)/dp``, load conductance ``kappa = d(ln k)``, command ``v = dv/Q``. In margin mode
    the pump model runs open loop (it is not corrected by the delayed flow), the line estimator
    corrects the margin and the conductance, the flow target is ``kappa_hat + p_r/gamma`` and the
    reference generator, the feedforward and the state feedback act as in flow mode (growing
    branch). ``alpha_l`` is the line pole ``exp(-T/tau_l)`` of the operating point: the only
    trace of the aperture left after the relative scaling.
    """
    g = emc_gains(cfg)
    gamma = cfg.model.gamma_u
    a = g.up.alpha
    l_p, l_k = line_estimator_gains(alpha_l, gamma, g.poles['line_fast'], g.poles['line_slow'])
    kr = g.k_r_margin

    def f(x, y):
        Qh, ph, kh, Qr = x
        e = y - ph
        kh2 = kh + l_k * e
        r = kh2                       # + p_r/gamma, constant
        v_r = Qr + kr * (r - Qr)
        Qr2 = Qr + (1.0 - a) * (v_r - Qr)
        v = v_r + g.k_x * (Qr - Qh)
        ph2 = (alpha_l * ph + (1.0 - alpha_l) * gamma * (Qh - kh2)
               + (l_p + gamma * (1.0 - alpha_l) * l_k) * e)
        Qh2 = a * Qh + (1.0 - a) * v
        return np.array([Qh2, ph2, kh2, Qr2]), v

    return _probe(f, 4, g.T)


def margin_plant_lti(cfg: ControllerConfig, alpha_l: float, gain: float = 1.0,
                     tau_scale: float = 1.0) -> control.StateSpace:
    """Pump and line from the relative command to the relative margin (eqs. 14 and 9), sampled;
    the margin is measured without delay."""
    import control  # python-control costs a second to import: analysis only
    T, gamma = cfg.period, cfg.model.gamma_u
    a = math.exp(-T / (cfg.model.tau * tau_scale))
    A = np.array([[a, 0.0], [(1.0 - alpha_l) * gamma, alpha_l]])
    B = np.array([[gain * (1.0 - a)], [0.0]])
    return control.ss(A, B, np.array([[0.0, 1.0]]), np.zeros((1, 1)), T)


def emc_margin_margins(cfg: ControllerConfig, alpha_l: float, **plant) -> Margins:
    """Loop margins of the margin-mode EMC at a line pole ``alpha_l``."""
    return loop_margins(-emc_margin_lti(cfg, alpha_l) * margin_plant_lti(cfg, alpha_l, **plant))


def emc_compensated_lti(cfg: ControllerConfig) -> control.StateSpace:
    """The margin-mode EMC against compensated loads (``model.load_law: compensated``),
    linearised, from the measured margin [Pa] to the flow command ``v`` [m^3/s]: the line
    an integrator ``C_l d(dp)/dt = Q - q_load`` with the load flow estimated as a random
    walk, the flow target the estimated load flow plus the capacitance filled toward the
    margin set-point over ``tau_margin_loop`` (emc.py), the reference generator, feedforward
    and state feedback as in flow mode (growing branch). Loads fed in full (above the
    compensators' setting), no relief."""
    g = emc_gains(cfg)
    a, T, C = g.up.alpha, g.T, cfg.model.C_l
    l_p, l_q = compensated_estimator_gains(C, T, g.poles['line_fast'], g.poles['line_slow'])
    kr, tau_loop = g.k_r_margin, cfg.emc.tau_margin_loop

    def f(x, y):
        Qh, ph, qh, Qr = x
        e = y - ph
        qh2 = qh + l_q * e
        r = qh2 - C * ph / tau_loop      # the set-point is the origin
        v_r = Qr + kr * (r - Qr)
        Qr2 = Qr + (1.0 - a) * (v_r - Qr)
        v = v_r + g.k_x * (Qr - Qh)
        ph2 = ph + T / C * (Qh - qh2) + l_p * e
        Qh2 = a * Qh + (1.0 - a) * v
        return np.array([Qh2, ph2, qh2, Qr2]), v

    return _probe(f, 4, T)


def compensated_plant_lti(cfg: ControllerConfig, C_l: float | None = None, gain: float = 1.0
                          ) -> control.StateSpace:
    """Pump (growing flow, eq. 19 without its delay) and a line of capacitance ``C_l``
    (default the model's) feeding compensated loads, from the command ``v`` [m^3/s] to the
    margin [Pa], sampled; the margin is measured without delay."""
    import control  # python-control costs a second to import: analysis only
    T = cfg.period
    a = math.exp(-T / cfg.model.tau)
    C = cfg.model.C_l if C_l is None else C_l
    A = np.array([[a, 0.0], [T / C, 1.0]])
    B = np.array([[gain * (1.0 - a)], [0.0]])
    return control.ss(A, B, np.array([[0.0, 1.0]]), np.zeros((1, 1)), T)


def emc_compensated_margins(cfg: ControllerConfig, C_l: float | None = None) -> Margins:
    """Loop margins of the margin-mode EMC against compensated loads, the line's
    capacitance ``C_l`` (default the model's: a plant whose line is larger or smaller than
    the model says)."""
    return loop_margins(-emc_compensated_lti(cfg) * compensated_plant_lti(cfg, C_l))


def closed_loop_eigenvalues(cfg: ControllerConfig, branch: str = 'up') -> np.ndarray:
    """Eigenvalues (z-plane) of the nominal flow loop: EMC on the linear model with delay."""
    import control  # python-control costs a second to import: analysis only
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        L = -emc_flow_lti(cfg, branch) * flow_plant_lti(cfg, branch)
        return np.sort_complex(control.poles(control.feedback(L, 1)))


# --- design from the plant ------------------------------------------------------------------

# The up-step whose 63 % time is the plant's growing-flow tau: the reference step of the paper
# (docs/reference.md A2), centred on the nominal point and small enough that the spool stays
# inside its stroke (x_c 3 of 4 mm on the reference pump), so the figure is the plant's slow
# dynamics and not its stroke limit.
TAU_STEP = (0.4, 0.6)


@dataclass(frozen=True)
class PlantModel:
    """The ``model`` group designed from a plant, with where each number came from.

    ``values`` are the ``model.*`` parameters (SI), ``sources`` a short text per parameter
    (``'63 % time of the fine model's 40 -> 60 % step, pump.yaml'``) and ``notes`` what the
    user should know about the design (e.g. a profile without a flow delay).
    """

    values: dict
    sources: dict
    notes: tuple = ()

    @property
    def G0(self) -> float:
        """The flow gain in the paper's units: % of ``V_p f_p`` per ``I_max`` of current."""
        return self.values['gain'] * self.values['I_max'] / self.values['Q_max'] * 100.0


def step_time_constant(params, d0: float = TAU_STEP[0], d1: float = TAU_STEP[1]) -> float:
    """63 % time [s] of the fine model's line flow after a current step between the
    displacements ``d0`` and ``d1`` (0..1), without dither, from the equilibrium at ``d0``.

    This is what eq. 19 identifies on the plant's own step: the FOPDT fit of the reference
    pump's 40 -> 60 % step gives tau 100.41 ms and t_d 0.36 ms, and its 63 % time is
    100.38 ms (docs/reference.md). The fast modes' lag of a fraction of a millisecond is
    folded into it, as a fit folds it into tau.
    """
    from hydropump_sim.metrics import step_figures
    from hydropump_sim.paper import eq14_time_constant
    from hydropump_sim.scaling import current_for_displacement
    from hydropump_sim.simulate import simulate
    from hydropump_sim.trim import equilibrium
    plant = params.replace({'input.dither_amp': 0.0}) if params.input.dither_amp else params
    I0, I1 = (float(i) for i in current_for_displacement(plant, [d0, d1]))
    t_step = 0.01
    # Eight times the eq. 14 estimate: the 63 % point lies well inside, whatever the plant.
    guess = eq14_time_constant(plant, equilibrium(plant, I0), 'pos' if d1 > d0 else 'neg',
                               keep_Kc=True)
    res = simulate(plant, t_step + 8.0 * guess, lambda t: np.where(t < t_step, I0, I1),
                   dt_out=1.0e-4)
    t63 = step_figures(res.t, res.q_l, t_step, final=equilibrium(plant, I1).q_l).t63
    if not math.isfinite(t63):
        from hydropump_sim.errors import InputError
        raise InputError(f'the fine model never reached 63 % of its {d0 * 100:.0f} -> '
                         f'{d1 * 100:.0f} % step')
    return float(t63)


def flow_dc_gain(params) -> float:
    """Static gain ``dq_l/di_s`` [m^3/(s A)] of the fine model linearised at the nominal
    point (eq. 11 when the plant keeps D1, ``V_p f_p / I_max``; leakage or the consistent
    flow map show here)."""
    from hydropump_sim.linear import linearize
    from hydropump_sim.model import INPUTS, OUTPUTS
    lm = linearize(params, branch='pos')
    i, o = INPUTS.index('i_s'), OUTPUTS.index('q_l')
    return float(lm.D[o, i] - lm.C[o] @ np.linalg.solve(lm.A, lm.B[:, i]))


def plant_model(params, profile=None, *, identified: dict | None = None,
                flow_signal: str = 'line_flow', plant_name: str = 'the plant file',
                profile_name: str = 'the sensor profile') -> PlantModel:
    """The ``model`` group of the embedded model from the plant's own model.

    Every number comes from ``params`` (the fine model at its nominal point) or from the
    sensor ``profile``, never from the paper's eq. 19 figures:

    - ``gain``: the static gain of the fine model's linearisation (eq. 11);
    - ``tau``: the 63 % time of the fine model's 40 -> 60 % up-step (:func:`step_time_constant`);
    - ``tau_down``: eq. 15 keeping ``K_c`` (docs/reference.md I8) at the nominal point, the pole
      of the falling branch (the down-step's 63 % time mixes it with the zero);
    - ``tau_z``: the zero ``S_a/b_p`` of eq. 17;
    - ``flow_error_max``: the spool stroke limit, the largest stroke rate
      ``b_p mu_a x_c_max sqrt(P_a)/S_a`` (eqs. 4, 10) times ``tau``;
    - ``t_d``: the delay of the profile's ``flow_signal`` sensor (0 without a profile);
    - ``Q_bar``, ``Q_max``, ``I_nominal``, ``I_max``, ``C_l = V_l/beta``, ``gamma_u``.

    ``identified`` replaces ``G0`` [%], ``tau`` [s] or ``t_d`` [s] by identified values, each
    as ``(value, source)`` (eq. 19 of a fit, or given by hand). An identified ``tau`` carries
    ``tau_down`` in the plant's ratio eq. 15 / eq. 14 (both scale with ``1/mu_a``) and keeps
    the plant's stroke rate.
    """
    from hydropump_sim.paper import eq14_time_constant, pilot_root, zero_time_constant
    from hydropump_sim.trim import equilibrium
    ident = dict(identified or {})
    eq = equilibrium(params)
    ac, sp = params.actuator, params.spool
    values, sources, notes = {}, {}, []
    of = f', {plant_name}'
    if 'G0' in ident:
        G0, src = ident['G0']
        values['gain'] = G0 / 100.0 * params.Q_max / sp.I_max
        sources['gain'] = f'G0 = {G0:.2f} %: {src}'
    else:
        # In the paper's 0.01 % of G0: the linearisation's finite differences are good to
        # 1e-10, and a design must not move with the last digits of the plant library.
        G0 = round(flow_dc_gain(params) * sp.I_max / params.Q_max * 100.0, 2)
        values['gain'] = G0 / 100.0 * params.Q_max / sp.I_max
        sources['gain'] = (f'G0 = {G0:.2f} %: static gain i_s -> q_l of the fine model '
                           f'linearised at the nominal point (eq. 11){of}')
    values['I_nominal'] = params.I_nominal
    sources['I_nominal'] = f'eq. 2, I_min + I_max{of}'
    values['I_max'] = sp.I_max
    sources['I_max'] = f'eq. 2{of}'
    values['Q_bar'] = float(eq.Q_p)
    sources['Q_bar'] = f"the fine model's equilibrium flow at I_nominal (eq. 8){of}"
    values['Q_max'] = params.Q_max
    sources['Q_max'] = f'V_p f_p{of}'
    tau_up = eq14_time_constant(params, eq, 'pos', keep_Kc=True)
    tau_dn = eq14_time_constant(params, eq, 'neg', keep_Kc=True)
    if 'tau' in ident:
        values['tau'], src = ident['tau']
        sources['tau'] = src
        values['tau_down'] = values['tau'] * tau_dn / tau_up
        sources['tau_down'] = f'tau x eq. 15 / eq. 14 = {tau_dn / tau_up:.4f} (with K_c){of}'
    else:
        # Four digits (0.1 ms here): the step is simulated on a 0.1 ms grid, and the design
        # must not move with the integrator's last digits.
        values['tau'] = float(f'{step_time_constant(params):.4g}')
        sources['tau'] = (f"63 % time of the fine model's {TAU_STEP[0] * 100:.0f} -> "
                          f'{TAU_STEP[1] * 100:.0f} % step{of}')
        values['tau_down'] = tau_dn
        sources['tau_down'] = (f'eq. 15 with K_c, S_a (1 + K_c/K_a)/(mu_a sqrt(P_l - P_a)) at '
                               f'the nominal point{of}')
    values['tau_z'] = zero_time_constant(params)
    sources['tau_z'] = f'zero of eq. 17, S_a/b_p{of}'
    if 't_d' in ident:
        values['t_d'], sources['t_d'] = ident['t_d']
    elif profile is None:
        values['t_d'] = 0.0
        sources['t_d'] = 'no sensor profile'
        notes.append('no sensor profile: t_d = 0, the embedded delay line keeps one period')
    else:
        sensor = profile.spec(flow_signal)
        values['t_d'] = float(sensor.delay)
        sources['t_d'] = f'delay of the {flow_signal} sensor, {profile_name}'
        if sensor.delay <= 0.0:
            notes.append(f'{profile_name} has no delay on {flow_signal}: t_d = 0, the embedded '
                         'delay line keeps one period')
        if sensor.filter_tau > 0.0:
            notes.append(f'{profile_name} filters {flow_signal} ({sensor.filter_tau:g} s): '
                         'that lag is not in t_d')
    rate = params.b_p * ac.mu_a * sp.x_c_max * pilot_root(params, eq, 'pos') / ac.S_a
    values['flow_error_max'] = rate * values['tau']
    sources['flow_error_max'] = (f'spool stroke limit: b_p mu_a x_c_max sqrt(P_a)/S_a (eqs. 4, '
                                 f'10) = {rate / params.Q_max * 100:.0f} % FS/s, times tau{of}')
    values['C_l'] = params.line.V_l / params.fluid.beta
    sources['C_l'] = f'line capacitance V_l/beta (eq. 9){of}'
    values['gamma_u'] = params.line.gamma_u
    sources['gamma_u'] = f'load law exponent (eq. 9){of}'
    return PlantModel(values, sources, tuple(notes))


def model_from_plant(params, profile=None, **kw) -> dict[str, float]:
    """The ``model`` group (values only) of :func:`plant_model`."""
    return plant_model(params, profile, **kw).values


def pi_flow_tuning(model: dict, T: float) -> tuple[float, float]:
    """SIMC PI (Skogestad 2003) for eq. 19: ``tau_c = theta``, ``theta = t_d + T/2``.

    Returns ``(p [A s/m^3], i [A/m^3])``: in flow units ``K_c = tau/(2 theta)``,
    ``T_i = min(tau, 8 theta)``, divided by the static gain of eq. 11.
    """
    theta = model['t_d'] + 0.5 * T
    Kc = model['tau'] / (2.0 * theta)
    Ti = min(model['tau'], 8.0 * theta)
    return Kc / model['gain'], Kc / model['gain'] / Ti


def pi_margin_compensated_tuning(model: dict, T: float) -> tuple[float, float]:
    """SIMC PI on the margin against compensated loads (``model.load_law compensated``).

    The plant from the current to the margin is an integrator behind the pump's lag,
    ``gain / (C_l s (tau s + 1))``: the loads take their flow whatever the margin. SIMC for an
    integrating process (Skogestad 2003) with the lag as delay (``theta = tau + T/2``,
    ``tau_c = theta``): ``K_c = 1/(k' 2 theta)``, ``T_i = 8 theta``, times
    :data:`PI_COMPENSATED`. Returns ``(p [A/Pa], i [A/(Pa s)])``.
    """
    k = model['gain'] / model['C_l']
    theta = model['tau'] + 0.5 * T
    Kc = 1.0 / (k * 2.0 * theta)
    return PI_COMPENSATED[0] * Kc, PI_COMPENSATED[1] * Kc / (8.0 * theta)


# Multiples of the SIMC gains above, found on Fig. 1 (docs/control.md): below the
# compensators' setting the loads take every extra flow as orifices do, the integrator's
# gain is gone, and SIMC's PI climbs out of that starvation at its integral rate alone
# (7 s for a boom and a motor started together). These are the largest that leave no limit
# cycle once the loads are fed.
PI_COMPENSATED = (15.0, 20.0)


def margin_operating_points(params, apertures=(0.08, 0.96), margins=(2.0e6, 3.0e6)):
    """Load-sensing operating points ``(xi_u, dp, q, g, tau_l)`` at the aperture and margin
    extremes: flow ``q = mu_u xi_u dp^(1/gamma)``, margin gain ``g = gamma dp/q`` [Pa s/m^3]
    and line time constant ``tau_l = gamma (V_l/beta) dp/q``."""
    ln = params.line
    C_l = ln.V_l / params.fluid.beta
    out = []
    for xi in apertures:
        for dp in margins:
            q = ln.mu_u * xi * dp ** (1.0 / ln.gamma_u)
            out.append((xi, dp, q, ln.gamma_u * dp / q, ln.gamma_u * C_l * dp / q))
    return out


def pi_margin_tuning(params, model: dict, T: float, apertures=(0.08, 0.96),
                     margins=(2.0e6, 3.0e6)) -> tuple[float, float]:
    """SIMC PI on the margin, tuned at the operating point of largest loop gain.

    The plant from the current to the margin is ``gain g / ((tau s + 1)(tau_l s + 1))``; its
    gain ``g`` grows as the aperture closes (12x over 0.08..0.96). One fixed PI must be stable
    at the largest gain, so it is tuned there (half rule: ``theta = tau_l/2 + T/2``,
    ``tau_c = theta``) and is slower elsewhere. Returns ``(p [A/Pa], i [A/(Pa s)])``.
    """
    xi, dp, q, g, tau_l = max(margin_operating_points(params, apertures, margins),
                              key=lambda op: op[3])
    theta = 0.5 * tau_l + 0.5 * T
    tau_eff = model['tau'] + 0.5 * tau_l
    K = model['gain'] * g
    Kc = tau_eff / (K * 2.0 * theta)
    Ti = min(tau_eff, 8.0 * theta)
    return Kc, Kc / Ti


def design_config(params, profile=None, *, identified: dict | None = None,
                  base: dict | None = None, model: PlantModel | None = None
                  ) -> ControllerConfig:
    """A complete controller configuration designed from the plant's own model.

    The ``model`` group is :func:`plant_model` of ``params`` and the sensor ``profile`` (its
    flow-sensor delay is ``t_d``), with ``identified`` eq. 19 numbers in place of the
    plant's where given; pass ``model`` to reuse one already made. ``base`` (dotted names)
    overrides the defaults, e.g. other eigenvalues; the model group and the PI gains come from
    the design unless ``base`` gives them.
    """
    from .schema import config_from_dict, General
    if model is None:
        signal = (base or {}).get('controller.flow_signal', General().flow_signal)
        model = plant_model(params, profile, identified=identified, flow_signal=signal)
    m = model.values
    probe = config_from_dict({'model': m, **(base or {})}, current_limits=params.I_limits)
    T = probe.period
    p_f, i_f = pi_flow_tuning(m, T)
    p_m, i_m = pi_margin_tuning(params, m, T)
    lo, hi = params.I_limits
    values = {f'model.{k}': v for k, v in m.items()}
    values.update({
        'limits.current_min': lo, 'limits.current_max': hi,
        'limits.safe_current': params.current_range[0],
        'reference.flow': float(m['Q_bar']),
        'pi.flow.p': p_f, 'pi.flow.i': i_f,
        'pi.flow.reference_tau': m['tau'], 'pi.flow.reference_tau_down': m['tau_down'],
        'pi.flow.reference_delay': m['t_d'],
        'pi.margin.p': p_m, 'pi.margin.i': i_m,
        'pi.flow.u_clamp_min': lo, 'pi.flow.u_clamp_max': hi,
        'pi.margin.u_clamp_min': lo, 'pi.margin.u_clamp_max': hi,
    })
    values.update(base or {})
    return probe.replace(values)
