"""The embedded model: exact discrete steps, its parameters against the plant library, and its
prediction against the fine model."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from hydropump_ctrl.control.design import model_from_plant
from hydropump_ctrl.control.embedded import LineModel, PumpModel, trajectory_step
from hydropump_sim import equilibrium, linearize, modal_analysis, simulate
from hydropump_sim.scaling import current_for_displacement


@pytest.fixture(scope='module')
def model(params):
    return model_from_plant(params)


@pytest.fixture(scope='module')
def pump(model):
    return PumpModel(model['gain'], model['I_nominal'], model['Q_bar'], model['Q_max'],
                     model['tau'], model['tau_down'], model['tau_z'], model['flow_error_max'])


def _integrate(pump, Q, target, dt):
    """Reference: the continuous model dQ/dt = sat(target - Q)/tau_branch, stops at 0, Q_max."""
    def f(t, x):
        e = target - x[0]
        tau = pump.tau if e >= 0 else pump.tau_down
        return [max(min(e, pump.E), -pump.E) / tau]
    sol = solve_ivp(f, (0.0, dt), [Q], rtol=1e-11, atol=1e-15, max_step=dt / 50)
    return min(max(sol.y[0, -1], 0.0), pump.Q_max)


@settings(max_examples=60, deadline=None)
@given(q=st.floats(0.05, 0.95), e=st.floats(-0.6, 0.6), dt=st.sampled_from([1e-3, 5e-3, 0.02]))
def test_step_is_the_exact_solution_for_a_held_target(pump, q, e, dt):
    Q, target = q * pump.Q_max, (q + e) * pump.Q_max
    assert pump.step(Q, target, dt)[0] == pytest.approx(_integrate(pump, Q, target, dt),
                                                        abs=1e-9 * pump.Q_max)


def test_spool_limit_bounds_the_rate_and_hides_the_disturbance(pump):
    Q = 0.3 * pump.Q_max
    Q1, sensitive = pump.step(Q, Q + 3 * pump.E, 0.005)
    assert (Q1 - Q) / 0.005 == pytest.approx(pump.E / pump.tau, rel=1e-12)
    assert not sensitive
    Q1, sensitive = pump.step(Q, Q + 0.5 * pump.E, 0.005)
    assert sensitive
    # Falling flow is faster (eq. 15).
    Qd, _ = pump.step(Q, Q - 3 * pump.E, 0.005)
    assert (Q - Qd) / 0.005 == pytest.approx(pump.E / pump.tau_down, rel=1e-12)


def test_end_stops(pump):
    assert pump.step(pump.Q_max, 2 * pump.Q_max, 0.005) == (pump.Q_max, False)
    assert pump.step(0.0, -pump.Q_max, 0.005) == (0.0, False)
    assert pump.line_flow(0.0, -pump.Q_max) == 0.0


def test_line_flow_has_the_zero_of_eq17_only_for_falling_flow(pump):
    Q = 0.5 * pump.Q_max
    de = 0.01 * pump.Q_max
    assert pump.line_flow(Q, Q + de) == Q
    # q_l = Q + tau_z dQ/dt with dQ/dt = e/tau_down: the instantaneous drop of eq. 17.
    assert pump.line_flow(Q, Q - de) == pytest.approx(Q - pump.tau_z / pump.tau_down * de)


@settings(max_examples=40, deadline=None)
@given(q=st.floats(0.1, 0.9), e=st.floats(-0.2, 0.2))
def test_inverse_undoes_a_linear_step(pump, q, e):
    Q = q * pump.Q_max
    target = Q + e * pump.E
    Q1, _ = pump.step(Q, target, 0.005)
    assert pump.inverse(Q, Q1, 0.005) == pytest.approx(target, abs=1e-9 * pump.Q_max)


def test_eq11_round_trip_and_static_map_against_the_fine_model(params, pump):
    for d in (0.1, 0.5, 0.9):
        current = float(current_for_displacement(params, d))
        assert pump.current(pump.flow_command(current)) == pytest.approx(current)
        # eq. 11 of the embedded model is the fine model's steady state.
        eq = equilibrium(params, current)
        assert pump.steady_flow(current) == pytest.approx(eq.q_l, rel=1e-6)


def test_branch_time_constants_match_the_fine_model_modes(params, model):
    slow = {b: modal_analysis(linearize(params, branch=b))[0].tau for b in ('pos', 'neg')}
    assert model['tau'] == pytest.approx(slow['pos'], rel=0.02)
    assert model['tau_down'] == pytest.approx(slow['neg'], rel=0.05)
    ac = params.actuator
    assert model['tau_z'] == pytest.approx(ac.S_a / params.b_p, rel=1e-9)


def test_spool_limit_rate_matches_a_large_step_of_the_fine_model(params, model):
    lo, hi = current_for_displacement(params, [0.1, 0.9])
    res = simulate(params, 0.3, lambda t: np.where(t < 0.01, lo, hi), dt_out=1e-3)
    # Half-way up the spool is still at x_c_max (40 % error > 26 %) and P_a is at its nominal
    # value (eq. 12 with x_a = 0), which the embedded model's rate assumes.
    k = int(np.argmax(res.Q_p >= 0.5 * params.Q_max))
    rate = np.gradient(res.Q_p, res.t)[k]
    assert res.x_c[k] == pytest.approx(params.spool.x_c_max, rel=0.05)
    assert rate == pytest.approx(model['flow_error_max'] / model['tau'], rel=0.03)


def test_prediction_follows_the_fine_model(params, pump):
    """Open loop, 40 -> 60 % and back: the embedded model at 5 ms against the fine model."""
    I0, I1 = current_for_displacement(params, [0.4, 0.6])
    for a, b in ((I0, I1), (I1, I0)):
        res = simulate(params, 0.4, lambda t, a=a, b=b: np.where(t < 0.05, a, b), dt_out=5e-3)
        Q, pred = pump.steady_flow(a), []
        for k in range(res.t.size):
            v = pump.flow_command(a if res.t[k] < 0.05 - 1e-9 else b)
            # The sample at t_k sees the spool set by the command of the period before.
            v_before = pump.flow_command(a if res.t[k] < 0.05 + 1e-9 else b)
            pred.append(pump.line_flow(Q, v_before))
            Q = pump.step(Q, v, 0.005)[0]
        err = np.max(np.abs(np.array(pred) - res.q_l)) / abs(pump.steady_flow(b) - Q)
        # Within the 3 % of docs/reference.md A3 (simplified vs fine), away from the 3 ms
        # spool mode.
        late = res.t >= 0.05 + 0.01
        err_late = np.max(np.abs(np.array(pred)[late] - res.q_l[late])) / abs(
            pump.steady_flow(b) - pump.steady_flow(a))
        assert err_late < 0.03, (a, b, err, err_late)


def test_trajectory_is_feasible_and_converges(pump):
    k_r = (1 - math.exp(-0.005 / 0.025)) / (1 - math.exp(-0.005 / pump.tau))
    Q, r = 0.3 * pump.Q_max, 0.7 * pump.Q_max
    for _ in range(200):
        Q1, v = trajectory_step(Q, r, k_r, pump.E, pump.tau, 0.005)
        assert abs(v - Q) <= pump.E * (1 + 1e-12)
        Q = Q1
    assert Q == pytest.approx(r, rel=1e-9)


def test_line_model_is_exact_at_rest_and_stable_for_long_steps(params, model):
    line = LineModel(model['C_l'], model['gamma_u'])
    k = params.line.mu_u * 0.5
    q = 0.5 * params.Q_max
    dp_ss = line.steady_margin(q, k)
    assert line.flow(dp_ss, k) == pytest.approx(q)
    assert line.step(dp_ss, q, k, 0.005) == pytest.approx(dp_ss)
    # The line pole (3 ms here) is faster than the period: the step must not overshoot.
    dp = 1.5 * dp_ss
    for _ in range(20):
        dp_new = line.step(dp, q, k, 0.005)
        assert dp_ss <= dp_new < dp
        dp = dp_new
    # Linearised line time constant of eq. 9 at the nominal point: about 3.55 ms at 30 bar.
    assert line.tau(dp_ss, q) == pytest.approx(2 * model['C_l'] * dp_ss / q)
