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


def closed_loop_eigenvalues(cfg: ControllerConfig, branch: str = 'up') -> np.ndarray:
    """Eigenvalues (z-plane) of the nominal flow loop: EMC on the linear model with delay."""
    import control  # python-control costs a second to import: analysis only
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        L = -emc_flow_lti(cfg, branch) * flow_plant_lti(cfg, branch)
        return np.sort_complex(control.poles(control.feedback(L, 1)))


# --- design from the plant ------------------------------------------------------------------

def model_from_plant(params, G0: float = 100.0, tau: float = 0.1, t_d: float = 0.055
                     ) -> dict[str, float]:
    """The ``model`` group from the identified eq. 19 and the simplified model.

    ``G0`` [%/(i_s/I_max)], ``tau`` [s] and ``t_d`` [s] are the paper's identification (eq. 19,
    growing flow). The simplified model (``params``, nominal operating point) adds what eq. 19
    leaves out: the falling-flow time constant, in the ratio of eq. 15 to eq. 14 (with ``K_c``,
    docs/reference.md I8); the zero ``tau_z = S_a/b_p`` of eq. 17; the spool stroke limit, as
    the largest stroke rate ``b_p mu_a x_c_max sqrt(P_a)/S_a`` (eqs. 4, 10) times ``tau``; the
    line capacitance ``V_l/beta`` and the load exponent of eq. 9.
    """
    from hydropump_sim.linear import eq14_time_constant, pilot_root, zero_time_constant
    from hydropump_sim.trim import equilibrium
    eq = equilibrium(params)
    ratio = (eq14_time_constant(params, eq, 'neg', keep_Kc=True)
             / eq14_time_constant(params, eq, 'pos', keep_Kc=True))
    ac = params.actuator
    rate = params.b_p * ac.mu_a * params.spool.x_c_max * pilot_root(params, eq, 'pos') / ac.S_a
    return {
        'gain': G0 / 100.0 * params.Q_max / params.spool.I_max,
        'I_nominal': params.I_nominal,
        'I_max': params.spool.I_max,
        'Q_bar': float(eq.Q_p),
        'Q_max': params.Q_max,
        'tau': tau,
        'tau_down': tau * ratio,
        'tau_z': zero_time_constant(params),
        't_d': t_d,
        'flow_error_max': rate * tau,
        'C_l': params.line.V_l / params.fluid.beta,
        'gamma_u': params.line.gamma_u,
    }


def pi_flow_tuning(model: dict, T: float) -> tuple[float, float]:
    """SIMC PI (Skogestad 2003) for eq. 19: ``tau_c = theta``, ``theta = t_d + T/2``.

    Returns ``(p [A s/m^3], i [A/m^3])``: in flow units ``K_c = tau/(2 theta)``,
    ``T_i = min(tau, 8 theta)``, divided by the static gain of eq. 11.
    """
    theta = model['t_d'] + 0.5 * T
    Kc = model['tau'] / (2.0 * theta)
    Ti = min(model['tau'], 8.0 * theta)
    return Kc / model['gain'], Kc / model['gain'] / Ti


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


def design_config(params, G0: float = 100.0, tau: float = 0.1, t_d: float = 0.055,
                  base: dict | None = None) -> ControllerConfig:
    """A complete controller configuration designed from the plant and eq. 19.

    ``base`` (dotted names) overrides the defaults, e.g. other eigenvalues; the model group
    and the PI gains come from the design unless ``base`` gives them.
    """
    from .schema import config_from_dict
    model = model_from_plant(params, G0, tau, t_d)
    probe = config_from_dict({'model': model, **(base or {})},
                             current_limits=params.I_limits)
    T = probe.period
    p_f, i_f = pi_flow_tuning(model, T)
    p_m, i_m = pi_margin_tuning(params, model, T)
    lo, hi = params.I_limits
    values = {f'model.{k}': v for k, v in model.items()}
    values.update({
        'limits.current_min': lo, 'limits.current_max': hi,
        'limits.safe_current': params.current_range[0],
        'reference.flow': float(model['Q_bar']),
        'pi.flow.p': p_f, 'pi.flow.i': i_f,
        'pi.flow.reference_tau': tau, 'pi.flow.reference_tau_down': model['tau_down'],
        'pi.flow.reference_delay': t_d,
        'pi.margin.p': p_m, 'pi.margin.i': i_m,
        'pi.flow.u_clamp_min': lo, 'pi.flow.u_clamp_max': hi,
        'pi.margin.u_clamp_min': lo, 'pi.margin.u_clamp_max': hi,
    })
    values.update(base or {})
    return probe.replace(values)
