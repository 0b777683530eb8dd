"""The node-facing API of both controllers: limits, rate limit, bad samples, timeouts, state,
bumpless mode and reference switches, live gains."""

import math
from pathlib import Path

import numpy as np
import pytest

from hydropump_ctrl.control.emc import EMCController
from hydropump_ctrl.control.pi import PIController
from hydropump_ctrl.experiments.closed_loop import Event, run_closed_loop
from hydropump_sim.params import ParamError

ROOT = Path(__file__).resolve().parents[2]
CONTROLLERS = [EMCController, PIController]




def _meas(q, dp=2.5e6, p_u=1.2e7):
    return {'line_flow': q, 'pump_flow': q, 'line_pressure': p_u + dp, 'load_pressure': p_u}


@pytest.mark.parametrize('make', CONTROLLERS)
def test_commands_stay_in_range_and_rate(cfg, params, make):
    c = make(cfg)
    T, lim = cfg.period, cfg.limits
    c.reset(0.5, _meas(0.5 * params.Q_max))
    c.set_reference(params.Q_max, 'flow')           # far away: the command runs to its limits
    prev = c.command
    rng = np.random.default_rng(0)
    for k in range(300):
        u = c.update(k * T, T, _meas(params.Q_max * rng.uniform(0, 1)))
        assert lim.current_min <= u <= lim.current_max
        assert abs(u - prev) <= lim.rate_limit * T * (1 + 1e-12)
        prev = u
    c.set_reference(0.0, 'flow')
    for k in range(300, 600):
        u = c.update(k * T, T, _meas(0.0))
        assert lim.current_min <= u <= lim.current_max


@pytest.mark.parametrize('make', CONTROLLERS)
def test_bad_period_and_bad_samples(cfg, params, make):
    c = make(cfg)
    T = cfg.period
    q = 0.5 * params.Q_max
    c.set_reference(q, 'flow')
    c.reset(c._pump.current(q), _meas(q))
    u = c.update(0.0, T, _meas(q))
    before = c.state()
    for dt in (0.0, -T, math.nan):
        assert c.update(T, dt, _meas(q)) == u
    assert c.state() == before
    # Missing and non-finite values are skipped: the command stays finite.
    for k, m in enumerate(({}, {'line_flow': math.nan}, {'line_flow': None},
                           {'line_flow': 'x'})):
        assert math.isfinite(c.update((k + 1) * T, T, m))
    assert not c.state()['fault']


@pytest.mark.parametrize('make', CONTROLLERS)
@pytest.mark.parametrize('mode', ['flow', 'margin'])
def test_lost_measurements_ramp_to_the_safe_current(cfg, params, make, mode):
    c = make(cfg)
    T, lim = cfg.period, cfg.limits
    q = 0.8 * params.Q_max
    c.set_mode(mode)
    c.set_reference(q, 'flow')
    c.reset(c._pump.current(q), _meas(q))
    for k in range(10):
        c.update(k * T, T, _meas(q))
    t_lost = 10 * T
    n = int((lim.measurement_timeout + 0.2) / T)
    us = [c.update(t_lost + k * T, T, {}) for k in range(n)]
    assert c.state()['fault']
    assert us[-1] == pytest.approx(lim.safe_current)
    # Nothing moves before the timeout, then at most the rate limit.
    k_to = int(lim.measurement_timeout / T) - 2
    assert np.ptp(us[:k_to]) < 0.05
    assert np.all(np.abs(np.diff(us)) <= lim.rate_limit * T * (1 + 1e-12))
    # Back again: no fault, the loop resumes.
    c.update(t_lost + n * T, T, _meas(q))
    assert not c.state()['fault']


@pytest.mark.parametrize('make', CONTROLLERS)
def test_state_is_flat_si(cfg, params, make):
    c = make(cfg)
    q = 0.5 * params.Q_max
    c.set_reference(q, 'flow')
    c.reset(c._pump.current(q), _meas(q))
    c.update(0.0, cfg.period, _meas(q))
    s = c.state()
    for key in ('mode', 'algorithm', 't', 'reference', 'estimate', 'disturbance', 'command',
                'saturated', 'fault'):
        assert key in s
    assert s['reference'] == q and s['estimate'] == pytest.approx(q, rel=1e-6)
    assert all(isinstance(v, (int, float, str, bool)) for v in s.values())


def test_reference_and_mode_validation(cfg):
    c = EMCController(cfg)
    with pytest.raises(ValueError, match='looks like a value in bar'):
        c.set_reference(25.0, 'margin')
    with pytest.raises(ValueError, match='unknown mode'):
        c.set_mode('pressure')
    c.set_mode('open_loop')
    with pytest.raises(ValueError, match='no reference'):
        c.set_reference(1.0)
    with pytest.raises(ParamError):
        c.set_config({'emc.tau_control': -1.0})


@pytest.mark.parametrize('make', CONTROLLERS)
def test_mode_switches_are_bumpless(cfg, params, bench, make):
    """Steady flow at 50 %, margin mode (holding the present margin), open loop around the
    present current, flow again (holding the present flow): nothing moves at the switches."""
    FS = params.Q_max
    c = make(cfg.replace({'excitation.signal': 'sine', 'excitation.unit': 'A',
                          'excitation.amplitude': 0.0, 'excitation.offset': 0.0,
                          'excitation.relative': True}))
    events = [Event(0.2, 'mode', 'margin'), Event(0.5, 'mode', 'open_loop'),
              Event(0.8, 'mode', 'flow')]
    res = run_closed_loop(_Holding(c), 1.1, events, params=params, profile=bench,
                          start_flow=0.5 * FS, mode='flow')
    q = res.smooth('q_l')
    # The whole run stays at the operating point: within 1.5 % FS. Holding takes the present
    # estimate, which carries a filtered part of the 0.5 % FS sensor noise.
    assert np.max(np.abs(q - 0.5 * FS)) < 0.015 * FS
    assert res.mode[-1] == 'flow'
    assert {'margin', 'open_loop'} <= set(res.mode)


class _Holding:
    """Wraps a controller so that every mode switch holds the present value (bumpless)."""

    def __init__(self, c):
        self._c = c

    def set_mode(self, mode):
        self._c.set_mode(mode, hold=True)

    def __getattr__(self, name):
        return getattr(self._c, name)


@pytest.mark.parametrize('make', CONTROLLERS)
def test_live_gain_change_is_bumpless(cfg, params, bench, make):
    FS = params.Q_max
    change = ({'emc.tau_control': 0.03, 'emc.tau_estimator_fast': 0.05}
              if make is EMCController else {'pi.flow.p': 0.5 * cfg.pi_flow.p})
    res = run_closed_loop(make(cfg), 0.6, [Event(0.2, 'config', change)], params=params,
                          profile=bench, start_flow=0.4 * FS, mode='flow')
    assert np.max(np.abs(res.smooth('q_l') - 0.4 * FS)) < 0.01 * FS


def test_reference_step_in_margin_mode_and_back_to_flow(cfg, params, bench):
    """A margin set-point step, then a switch to flow mode holding the flow: the margin moves
    once (to the new set-point) and the flow stays where the margin loop left it."""
    c = EMCController(cfg)
    res = run_closed_loop(_Holding(c), 1.0, [Event(0.1, 'reference', 2.2e6, 'margin'),
                                             Event(0.5, 'mode', 'flow')],
                          params=params, profile=bench, start_margin=2.0e6, aperture=0.5,
                          mode='margin')
    m = res.smooth('margin')
    q = res.smooth('q_l')
    k5 = np.searchsorted(res.t, 0.5)
    assert abs(np.mean(m[k5 - 50:k5]) - 2.2e6) < 0.3e5
    assert np.max(np.abs(q[k5:] - q[k5])) < 0.01 * params.Q_max
