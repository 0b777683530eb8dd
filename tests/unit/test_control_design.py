"""Design: gains from eigenvalues, closed-loop eigenvalues, loop margins with the delay, and the
analysis model against the implementation."""

import math
from pathlib import Path

import control
import numpy as np
import pytest

from hydropump_ctrl.control import design as dz
from hydropump_ctrl.control.emc import EMCController

ROOT = Path(__file__).resolve().parents[2]



def _chosen(cfg):
    T, e = cfg.period, cfg.emc
    return {k: math.exp(-T / v) for k, v in (('control', e.tau_control),
                                              ('fast', e.tau_estimator_fast),
                                              ('slow', e.tau_estimator_slow))}


def test_gains_place_the_chosen_eigenvalues(cfg):
    g, p = dz.emc_gains(cfg), _chosen(cfg)
    for b in (g.up, g.down):
        Phi = np.array([[b.alpha, 1 - b.alpha], [0.0, 1.0]])
        L = np.array([[b.l_Q], [b.l_d]])
        C = np.array([[1 - b.c, b.c]])
        eig = np.sort(np.linalg.eigvals(Phi - L @ C).real)
        assert eig == pytest.approx(sorted([p['fast'], p['slow']]), abs=1e-9)
    a = g.up.alpha
    assert a - (1 - a) * g.k_x == pytest.approx(p['control'], abs=1e-12)
    assert 1 - (1 - a) * g.k_r == pytest.approx(math.exp(-cfg.period / cfg.emc.tau_reference))
    # The falling branch carries the zero of eq. 17 in its output.
    assert g.down.c == pytest.approx(cfg.model.tau_z / cfg.model.tau_down)


def test_line_estimator_places_its_eigenvalues_at_any_line_pole(cfg):
    g = dz.emc_gains(cfg)
    p1, p2 = g.poles['line_fast'], g.poles['line_slow']
    gamma = cfg.model.gamma_u
    for alpha in (0.0, 0.05, 0.3, 0.78, 0.95):
        l_p, l_k = dz.line_estimator_gains(alpha, gamma, p1, p2)
        Phi = np.array([[alpha, -gamma * (1 - alpha)], [0.0, 1.0]])
        eig = np.linalg.eigvals(Phi - np.array([[l_p], [l_k]]) @ np.array([[1.0, 0.0]]))
        assert np.sort(eig.real) == pytest.approx(sorted([p1, p2]), abs=1e-9)


def test_separation_closed_loop_eigenvalues_are_the_chosen_ones(cfg):
    """Nominal linear loop with the 11-period delay: control and estimator eigenvalues, plus
    the delay line near the origin."""
    z = dz.closed_loop_eigenvalues(cfg, 'up')
    dominant = np.sort(np.abs(z[np.abs(z) > 0.3]))
    assert dominant == pytest.approx(sorted(_chosen(cfg).values()), abs=1e-5)
    assert np.all(np.abs(z) < 1.0)


@pytest.mark.parametrize('branch', ['up', 'down'])
def test_emc_flow_margins_meet_the_targets(cfg, branch):
    m = dz.emc_flow_margins(cfg, branch)
    assert m.stable
    assert m.gain_margin >= 6.0
    assert m.phase_margin >= 45.0
    assert m.delay_margin >= 0.025


def test_margin_loop_is_the_same_at_every_aperture(cfg, params):
    ms = [dz.emc_margin_margins(cfg, math.exp(-cfg.period / op[4]))
          for op in dz.margin_operating_points(params, (0.08, 0.1, 0.5, 0.8, 0.96),
                                               (2.0e6, 3.0e6))]
    # The line pole in the gains cancels the plant's: one tuning, one loop.
    assert np.ptp([m.phase_margin for m in ms]) < 1e-6
    assert np.ptp([m.gain_margin for m in ms]) < 1e-6
    for m in ms:
        assert m.stable and m.gain_margin >= 6.0 and m.phase_margin >= 45.0
        assert m.delay_margin >= 0.025


def test_loop_margins_agree_with_python_control_on_a_plain_loop(cfg):
    T = cfg.period
    L = dz.pi_lti(0.8, 8.0, T) * dz.flow_plant_lti(cfg, 'up')
    m = dz.loop_margins(L)
    gm, pm, _, wpc, wgc, _ = control.stability_margins(L)
    assert m.gain_margin == pytest.approx(20 * math.log10(gm), abs=0.05)
    assert m.phase_margin == pytest.approx(pm, abs=0.1)
    assert m.crossover == pytest.approx(wgc, rel=1e-3)


def test_delay_margin_is_the_delay_the_loop_tolerates(cfg):
    """Add whole periods of delay: stable below the delay margin, unstable beyond it."""
    m = dz.emc_flow_margins(cfg, 'up')
    T = cfg.period
    L = -dz.emc_flow_lti(cfg, 'up') * dz.flow_plant_lti(cfg, 'up')

    def stable(extra):
        Lx = L * control.tf([1.0], [1.0] + [0.0] * extra, T)
        return bool(np.all(np.abs(control.poles(control.feedback(Lx, 1))) < 1.0))
    below = int(math.floor(m.delay_margin / T))
    assert stable(below)
    assert not stable(below + 2)


def test_analysis_model_is_the_implementation(params):
    """The controller object, single-branch and far from every limit, against emc_flow_lti in
    the same closed loop with a discrete eq. 19 plant and an input disturbance step."""
    from hydropump_ctrl.control.design import design_config
    cfg = design_config(params, base={
        'model.tau_down': 0.1, 'model.tau_z': 0.0, 'limits.rate_limit': 1000.0,
        'emc.disturbance_max': 0.01})
    T, N = cfg.period, cfg.delay_steps
    Q0, w = 0.5 * params.Q_max, 0.01 * params.Q_max
    a = math.exp(-T / cfg.model.tau)
    ctrl = EMCController(cfg)
    pump = ctrl._pump
    u0 = pump.current(Q0)
    ctrl.set_reference(Q0, 'flow')
    ctrl.reset(u0, {'line_flow': Q0})
    Ct = dz.emc_flow_lti(cfg, 'up')
    Ac, Bc, Cc, Dc = (np.asarray(M) for M in (Ct.A, Ct.B, Ct.C, Ct.D))
    xc = np.zeros(Ac.shape[0])
    Q = Q0
    Qlin = 0.0
    hist, hist_lin = [Q0] * (N + 1), [0.0] * (N + 1)
    v_impl, v_lin = [], []
    for k in range(120):
        dist = w if k >= 10 else 0.0
        y, ylin = hist[-1 - N], hist_lin[-1 - N]
        u = ctrl.update(k * T, T, {'line_flow': y})
        v = pump.flow_command(u)
        vl = float((Cc @ xc)[0] + Dc[0, 0] * ylin)
        xc = Ac @ xc + Bc[:, 0] * ylin
        v_impl.append(v - Q0)
        v_lin.append(vl)
        Q = a * Q + (1 - a) * (v + dist)
        Qlin = a * Qlin + (1 - a) * (vl + dist)
        hist.append(Q)
        hist_lin.append(Qlin)
    assert np.max(np.abs(np.array(v_impl) - np.array(v_lin))) < 1e-9 * params.Q_max
    # and the disturbance is rejected: the last command cancels it.
    assert v_impl[-1] == pytest.approx(-w, rel=1e-3)


def test_pi_flow_gains_follow_simc(cfg):
    m = cfg.model
    theta = m.t_d + 0.5 * cfg.period
    assert cfg.pi_flow.p * m.gain == pytest.approx(m.tau / (2 * theta))
    assert cfg.pi_flow.p / cfg.pi_flow.i == pytest.approx(min(m.tau, 8 * theta))


def test_pi_margin_baseline_is_stable_over_the_aperture_range(cfg, params):
    """One fixed PI must hold every aperture: linear pump + line at 0.08..0.96, 20 and 30 bar."""
    T = cfg.period
    C = dz.pi_lti(cfg.pi_margin.p, cfg.pi_margin.i, T)
    for xi, dp, q, _g, tl in dz.margin_operating_points(params, (0.08, 0.3, 0.6, 0.96),
                                                       (2.0e6, 3.0e6)):
        P_rel = dz.margin_plant_lti(cfg, math.exp(-T / tl))
        L = C * (cfg.model.gain * dp / q) * P_rel
        m = dz.loop_margins(L)
        assert m.stable, (xi, dp)
