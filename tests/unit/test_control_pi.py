"""The PI baseline: control_toolbox semantics, anti-windup, feedforward, bumpless gain change."""

from pathlib import Path
from types import SimpleNamespace

import pytest

from hydropump_ctrl.control.pi import PIController, Pid
from hydropump_ctrl.experiments.cases import unreachable_case

ROOT = Path(__file__).resolve().parents[2]




def _gains(**kw):
    base = dict(p=2.0, i=10.0, d=0.0, i_clamp_max=1.0, i_clamp_min=-1.0, u_clamp_max=1.0,
                u_clamp_min=0.0, feedforward_gain=1.0, antiwindup_strategy='back_calculation',
                tracking_time_constant=0.0, error_deadband=0.0)
    base.update(kw)
    return SimpleNamespace(**base)


def test_back_calculation_follows_control_toolbox():
    pid = Pid(_gains())
    # Default tracking time constant without d: p/i (control_toolbox Pid::set_gains).
    assert pid.tracking_time_constant == pytest.approx(0.2)
    pid.i_term = 0.1
    pid.integrate(error=0.5, dt=0.01, u_unsat=1.3, u_applied=1.0)
    assert pid.i_term == pytest.approx(0.1 + 0.01 * (10.0 * 0.5 + (1.0 - 1.3) / 0.2))
    assert Pid(_gains(d=0.4)).tracking_time_constant == pytest.approx((0.4 / 10.0) ** 0.5)


def test_conditional_integration_freezes_only_into_the_limit():
    pid = Pid(_gains(antiwindup_strategy='conditional_integration'))
    pid.integrate(error=0.5, dt=0.01, u_unsat=1.3, u_applied=1.0)   # pushing up into it
    assert pid.i_term == 0.0
    pid.integrate(error=-0.5, dt=0.01, u_unsat=1.3, u_applied=1.0)  # pulling out of it
    assert pid.i_term == pytest.approx(-0.05)
    pid.integrate(error=0.5, dt=0.01, u_unsat=0.6, u_applied=0.6)   # not limited
    assert pid.i_term == pytest.approx(0.0)


def test_clamp_and_deadband():
    pid = Pid(_gains(antiwindup_strategy='none', i_clamp_max=0.05, error_deadband=0.1))
    pid.integrate(error=0.05, dt=1.0, u_unsat=0.5, u_applied=0.5)
    assert pid.i_term == 0.0
    pid.integrate(error=1.0, dt=1.0, u_unsat=0.5, u_applied=0.5)
    assert pid.i_term == pytest.approx(0.05)


def test_flow_feedforward_is_the_static_map_of_eq11(cfg, params):
    c = PIController(cfg)
    q = 0.7 * params.Q_max
    c.set_reference(q, 'flow')
    lo, hi = params.current_range
    assert c._feedforward('flow') == pytest.approx(lo + 0.7 * (hi - lo))


def test_bumpless_gain_change(cfg, params):
    c = PIController(cfg)
    q = 0.5 * params.Q_max
    c.set_reference(q, 'flow')
    u0 = c._pump.current(q)
    c.reset(u0, {'line_flow': q})
    T = cfg.period
    y = 1.01 * q        # a standing error: the integral term is moving
    for k in range(40):
        u = c.update(k * T, T, {'line_flow': y})
    step = abs(u - c.update(40 * T, T, {'line_flow': y}))
    u = c.command
    c.set_config({'pi.flow.p': 3.0 * cfg.pi_flow.p, 'pi.flow.i': 0.5 * cfg.pi_flow.i})
    u_next = c.update(41 * T, T, {'line_flow': y})
    # Without re-alignment the new p would move the command by 2 p e = 3.5 mA at once.
    bump = 2.0 * cfg.pi_flow.p * 0.01 * q
    assert bump > 3e-3
    assert abs(u_next - u) <= step + 1e-9
    with pytest.raises(Exception, match='read-only'):
        c.set_config({'model.tau': 0.12})


def test_antiwindup_strategies_beat_no_antiwindup(cfg, params, bench):
    """Demand beyond full displacement for 1 s: the plate stops, the integral winds up."""
    FS = params.Q_max
    rec = {}
    for strategy in ('none', 'back_calculation', 'conditional_integration'):
        c = PIController(cfg.replace({'pi.flow.antiwindup_strategy': strategy}))
        rec[strategy] = unreachable_case(c, params, bench, 0.6 * FS, 1.1 * FS,
                                         after=1.2).figures['recovery']
    assert rec['back_calculation'] < rec['none']
    assert rec['conditional_integration'] < rec['none']
