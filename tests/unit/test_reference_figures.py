"""The reference figures of docs/reference.md, reproduced from the paper's equations.

Labels (I3, A2, ...) are the items of docs/reference.md. Tolerances: the figures are quoted to
three or four significant figures, so a figure is checked to the last quoted digit (plus the
0.1 % effect of the regularised orifice root, I3) unless an acceptance check (A1-A5) gives a
wider band, which is then used as given.
"""

import math

import numpy as np
import pytest

from hydropump_sim import equilibrium, linearize, modal_analysis, simulate
from hydropump_sim.metrics import fast_fraction, step_figures
from hydropump_sim.paper import eq14_time_constant, paper_linear, zero_time_constant
from hydropump_sim.scaling import current_for_displacement
from hydropump_sim.simulate import IntegratorConfig, OFFLINE_CONFIG

T_STEP = 0.01


def _step(params, d0, d1, model='fine', duration=1.2, dt=1e-4, **kw):
    I0, I1 = current_for_displacement(params, [d0, d1])
    r = simulate(params, duration, lambda t: np.where(t < T_STEP, I0, I1), model=model,
                 dt_out=dt, **kw)
    final = equilibrium(params, I1).q_l
    return r, final


@pytest.fixture(scope='module')
def up(params):
    return {m: _step(params, 0.4, 0.6, m) for m in ('fine', 'simplified', 'simplified_Kc')}


def test_equilibrium_at_50_percent(params):
    eq = equilibrium(params)
    assert eq.x_a == 0.0 and eq.x_c == 0.0
    assert eq.P_a == pytest.approx(20.0e5, abs=0.05e5)
    assert eq.P_l == pytest.approx(150.0e5, abs=0.1e5)
    assert eq.Q_p == pytest.approx(5.625e-4, rel=1e-12)
    # It is a steady state of the full nonlinear model, not just of a formula.
    r = simulate(params, 0.5, eq.I_s)
    assert np.max(np.abs(r.P_l - eq.P_l)) < 1.0  # Pa
    assert np.max(np.abs(r.q_l - eq.q_l)) < 1e-12


@pytest.mark.parametrize('d', [0.05, 0.3, 0.5, 0.62, 0.95])
@pytest.mark.parametrize('P_u, xi_u', [(1.2e7, 0.5), (5.0e6, 0.9), (2.0e7, 0.2)])
def test_steady_flow_is_eq_11(params, d, P_u, xi_u):
    """Acceptance check A1: q_p = V_p f_p i_s / I_max (eq. 11) at the exact equilibrium, any
    load."""
    I_s = float(current_for_displacement(params, d))
    eq = equilibrium(params, I_s, load_pressure=P_u, aperture=xi_u)
    i_s = I_s - params.I_nominal
    eq11 = params.Q_max * (0.5 + i_s / params.spool.I_max)
    assert eq.x_c == 0.0
    assert eq.Q_p == pytest.approx(eq11, rel=1e-9)
    assert eq.q_l == pytest.approx(eq11, rel=1e-9)


def _eigs(params, branch):
    lam = np.linalg.eigvals(linearize(params, branch=branch).A)
    return sorted(lam, key=lambda z: (abs(z), z.imag))


def test_eigenvalues_growing_flow(params):
    """Acceptance check A5: -10.08, -281.5, -439 +- 855j, -750 +- 9653j 1/s."""
    lam = _eigs(params, 'pos')
    expect = [-10.08, -281.5, -439 - 855j, -439 + 855j, -750 - 9653j, -750 + 9653j]
    for got, want in zip(lam, expect):
        assert abs(got - want) <= 0.002 * abs(want), (got, want)


def test_modes_on_both_sides(params):
    pos = modal_analysis(linearize(params, branch='pos'))
    neg = modal_analysis(linearize(params, branch='neg'))
    assert pos[0].tau == pytest.approx(99.2e-3, abs=0.05e-3)
    assert neg[0].tau == pytest.approx(38.3e-3, abs=0.05e-3)
    for modes in (pos, neg):
        assert modes[1].tau == pytest.approx(3.55e-3, abs=0.005e-3)
        assert modes[2].f_n == pytest.approx(153.0, abs=1.5)
        assert modes[2].zeta == pytest.approx(0.46, abs=0.01)
        assert modes[3].f_n == pytest.approx(1541.0, abs=2.0)
        assert modes[3].zeta == pytest.approx(0.08, abs=0.005)
    # Dominant states name the physics: plate stroke, line, spool, plate/oil spring.
    assert pos[0].dominant[0] == 'x_a'
    assert pos[1].dominant[0] == 'P_l'
    assert set(pos[2].dominant) == {'x_c', 'v_c'}
    assert set(pos[3].dominant) == {'v_a', 'P_a'}


def test_eq14_time_constant_and_zero(params):
    assert eq14_time_constant(params) == pytest.approx(95.24e-3, abs=0.01e-3)
    assert eq14_time_constant(params, keep_Kc=True) == pytest.approx(100.0e-3, abs=0.01e-3)
    assert eq14_time_constant(params, branch='neg') == pytest.approx(37.35e-3, abs=0.01e-3)
    assert zero_time_constant(params) == pytest.approx(10.05e-3, abs=0.01e-3)


def test_eq14_is_the_simplified_model_linearised(params):
    """Eq. 14 equals the Jacobian of the simplified model (eq. 10 as printed) up to the
    p_l S_d coupling the paper drops from eq. 12 (I9), which is zero at x_c = 0."""
    lin = linearize(params, model='simplified', branch='pos')
    pl = paper_linear(params, branch='pos')
    assert np.allclose(lin.A[0, 0], pl.A[0, 0], rtol=2e-3)
    assert np.allclose(lin.A[1], pl.A[1], rtol=2e-3)
    assert lin.B[0, 0] == pytest.approx(pl.B[0, 0], rel=2e-3)


@pytest.mark.parametrize('model, t63, tol', [
    ('fine', 100.4e-3, 1.0e-3),          # acceptance check A2: 100.4 +- 1 ms
    ('simplified', 94.5e-3, 0.1e-3),
    ('simplified_Kc', 99.2e-3, 0.1e-3),
])
def test_up_step_63_percent_time(up, model, t63, tol):
    r, final = up[model]
    assert step_figures(r.t, r.q_l, T_STEP, final=final).t63 == pytest.approx(t63, abs=tol)


def test_up_step_final_value(up):
    """6.749980e-4 m^3/s at t = 1.2 s; the exact equilibrium is eq. 11 (6.75e-4)."""
    r, final = up['fine']
    assert final == pytest.approx(6.75e-4, rel=1e-12)
    assert r.q_l[-1] == pytest.approx(6.74998e-4, abs=0.000005e-4)


def test_fine_versus_simplified(up):
    """Acceptance check A3: < 3 % of the step (printed eq. 10), < 1 % after 10 ms keeping K_c;
    the reference figures 2.27 % and 1.37 % (0.98 % after 10 ms)."""
    fine, final = up['fine']
    step = final - fine.q_l[0]
    late = fine.t >= T_STEP + 0.01
    err = {m: np.abs(up[m][0].q_l - fine.q_l) / step for m in ('simplified', 'simplified_Kc')}
    assert err['simplified'].max() == pytest.approx(0.0227, abs=0.001)
    assert err['simplified_Kc'].max() == pytest.approx(0.0137, abs=0.001)
    assert err['simplified_Kc'][late].max() == pytest.approx(0.0098, abs=0.001)
    assert err['simplified'].max() < 0.03 and err['simplified_Kc'][late].max() < 0.01


def test_down_step(params):
    """Acceptance check A4: 63 % time in 20..35 ms (27.5 ms), instantaneous drop about 27 %
    of the step (the zero of eq. 17: tau_z / tau_down)."""
    r, final = _step(params, 0.6, 0.4, duration=0.6)
    assert step_figures(r.t, r.q_l, T_STEP, final=final).t63 == pytest.approx(27.5e-3,
                                                                               abs=0.3e-3)
    drop, tau = fast_fraction(r.t, r.q_l, T_STEP, (0.015, 0.08))
    assert drop == pytest.approx(0.27, abs=0.015)
    rk, final_k = _step(params, 0.6, 0.4, 'simplified_Kc', duration=0.6)
    assert step_figures(rk.t, rk.q_l, T_STEP, final=final_k).t63 == pytest.approx(27.4e-3,
                                                                                  abs=0.2e-3)


def test_large_step_saturates_the_spool(params):
    """I18: a 10 -> 90 % step drives x_c to its 4 mm stop and takes about 188 ms to 63 %."""
    r, final = _step(params, 0.1, 0.9, duration=1.5, dt=5e-4)
    assert r.x_c.max() == pytest.approx(params.spool.x_c_max, rel=0.01)
    assert step_figures(r.t, r.q_l, T_STEP, final=final).t63 == pytest.approx(188e-3,
                                                                              abs=3e-3)


def test_fopdt_fit_of_the_fine_step(up):
    """The eq. 19 fit of the fine model's own step: G0 100, tau 100.4 ms, t_d < 1 ms."""
    from scipy.optimize import least_squares
    r, final = up['fine']
    params_u = r.I_s
    t = r.t - T_STEP
    q0 = r.q_l[0]
    du = (params_u[-1] - params_u[0])

    def model(th):
        G, tau, td = th
        y = np.where(t > td, 1.0 - np.exp(-(t - td) / tau), 0.0)
        return q0 + G * du * y

    sol = least_squares(lambda th: model(th) - r.q_l, [final / du, 0.08, 0.0],
                        x_scale=[1e-3, 0.1, 1e-3])
    G, tau, td = sol.x
    lo, hi = (0.3, 0.7)
    G0 = G * (hi - lo) / 1.125e-3 * 100.0
    assert G0 == pytest.approx(100.0, abs=0.7)
    assert tau == pytest.approx(100.4e-3, abs=0.5e-3)
    assert 0.0 <= td < 1e-3


@pytest.mark.parametrize('config', [IntegratorConfig(), OFFLINE_CONFIG],
                         ids=['a step every increment', 'free steps'])
def test_solvers_agree(params, config):
    """Rodas4 at its default tolerance against Radau at rtol 1e-9 on a step, stepped as the
    node steps and free of the increments (offline): within the tolerance asked."""
    I0, I1 = current_for_displacement(params, [0.4, 0.6])
    kw = dict(current=lambda t: np.where(t < T_STEP, I0, I1), dt_out=1e-3)
    a = simulate(params, 0.3, config=config, **kw)
    b = simulate(params, 0.3, method='radau', rtol=1e-9, **kw)
    step = b.q_l[-1] - b.q_l[0]
    assert np.max(np.abs(a.q_l - b.q_l)) / step < 1e-4
    assert np.max(np.abs(a.P_l - b.P_l)) < config.rtol * np.max(b.P_l)


def test_small_signal_matches_linearisation(params):
    """A 0.1 % step of the nonlinear model follows its one-sided linearisation."""
    import control
    eq = equilibrium(params)
    di = 0.001 * (params.current_range[1] - params.current_range[0])
    r = simulate(params, 0.5, lambda t: np.where(t < T_STEP, eq.I_s, eq.I_s + di), dt_out=1e-4)
    lin = linearize(params, eq, 'pos').ss(inputs=['i_s'], outputs=['q_l'])
    y = control.forced_response(lin, r.t, np.where(r.t < T_STEP, 0.0, di)).outputs
    dq = r.q_l - eq.q_l
    assert np.max(np.abs(dq - y)) < 0.01 * np.max(np.abs(y))
    assert math.isclose(dq[-1], y[-1], rel_tol=0.01)
