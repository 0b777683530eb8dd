"""Open-loop excitation: staircase, PRBS, chirp and sine; seeded, reproducible, in % or A; and
the open_loop mode that plays them."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from hydropump_ctrl.control.embedded import PumpModel
from hydropump_ctrl.control.emc import EMCController
from hydropump_ctrl.control.excitation import ExcitationSignal
from hydropump_ctrl.control.pi import PIController

ROOT = Path(__file__).resolve().parents[2]



def _signal(cfg, **kw):
    return ExcitationSignal(dataclasses.replace(cfg.excitation, **kw),
                            PumpModel.from_config(cfg.model))


def test_percent_of_displacement_uses_the_static_map(cfg, params):
    s = _signal(cfg, signal='sine', unit='percent', offset=50.0, amplitude=10.0,
                frequency=1.0)
    lo, hi = params.current_range
    assert s(0.0) == pytest.approx(0.5 * (lo + hi))
    # 10 % of displacement is 10 % of the 0..100 % current span (0.4 A): 40 mA.
    assert s(0.25) - s(0.0) == pytest.approx(0.1 * (hi - lo))
    a = _signal(cfg, signal='sine', unit='A', offset=0.5, amplitude=0.04, frequency=1.0)
    assert a(0.25) == pytest.approx(s(0.25))


def test_staircase_visits_every_operating_point_up_and_down(cfg):
    s = _signal(cfg, signal='staircase', unit='percent', levels_min=20.0, levels_max=80.0,
                n_levels=4, amplitude=5.0, dwell=0.5, seed=3)
    assert s.duration == pytest.approx(4 * 4 * 0.5)
    t = np.arange(0.25, s.duration, 0.5)
    pump = s.pump
    pct = (np.array([pump.flow_command(v) for v in s(t)]) / pump.Q_max) * 100.0
    levels = pct.reshape(4, 4)
    assert levels[:, 0] == pytest.approx([20, 40, 60, 80])
    for row in levels:
        assert row[2] == pytest.approx(row[0])
        assert sorted(row[[1, 3]] - row[0]) == pytest.approx([-5.0, 5.0])


def test_seeds_make_it_reproducible_and_different(cfg):
    t = np.linspace(0, 30, 3001)
    for kind in ('staircase', 'prbs'):
        a = _signal(cfg, signal=kind, seed=1, dwell=0.5, n_levels=8)(t)
        b = _signal(cfg, signal=kind, seed=1, dwell=0.5, n_levels=8)(t)
        c = _signal(cfg, signal=kind, seed=2, dwell=0.5, n_levels=8)(t)
        assert np.array_equal(a, b)
        assert not np.array_equal(a, c)


def test_prbs_is_a_maximum_length_sequence(cfg):
    s = _signal(cfg, signal='prbs', unit='A', offset=0.5, amplitude=0.02, prbs_order=7,
                bit_time=0.01, seed=5)
    assert s.duration == pytest.approx((2 ** 7 - 1) * 0.01)
    bits = s(np.arange(127) * 0.01 + 0.005)
    assert set(np.round(bits, 12)) == {0.48, 0.52}
    # An m-sequence has one more 1 than 0s, and it repeats.
    assert np.sum(bits > 0.5) == 64
    assert np.array_equal(s(np.arange(127) * 0.01 + 0.005 + s.duration), bits)


def test_chirp_sweeps_from_f_start_to_f_end(cfg):
    s = _signal(cfg, signal='chirp', unit='A', offset=0.5, amplitude=0.01, f_start=0.5,
                f_end=20.0, sweep_time=10.0, sweep='logarithmic', repeat=False)
    t = np.linspace(0, 10, 200001)
    y = s(t) - 0.5
    assert np.max(np.abs(y)) == pytest.approx(0.01, rel=1e-3)
    up = np.flatnonzero((y[:-1] < 0) & (y[1:] >= 0))
    f_inst = 1.0 / np.diff(t[up])
    t_mid = 0.5 * (t[up][1:] + t[up][:-1])
    expected = 0.5 * (20.0 / 0.5) ** (t_mid / 10.0)
    assert f_inst == pytest.approx(expected, rel=0.05)
    # Without repeat it holds the final value.
    assert s(25.0) == pytest.approx(s(10.0 * (1 - 1e-12)))


@pytest.mark.parametrize('make', [EMCController, PIController])
def test_open_loop_mode_plays_the_excitation_inside_the_limits(cfg, make):
    c = make(cfg.replace({'excitation.signal': 'prbs', 'excitation.unit': 'A',
                          'excitation.offset': 0.5, 'excitation.amplitude': 0.3,
                          'excitation.bit_time': 0.02, 'limits.rate_limit': 5.0,
                          'limits.current_max': 0.75}))
    c.reset(0.5)
    c.set_mode('open_loop')
    exc, T = c._excitation, c.config.period
    prev = c.command
    t0 = 1.0
    for k in range(400):
        t = t0 + k * T
        u = c.update(t, T, {})
        # 0.8 A is above the limit and 0.2 A within: the command is clamped and rate limited.
        assert c.config.limits.current_min <= u <= 0.75 + 1e-12
        assert abs(u - prev) <= 5.0 * T + 1e-12
        prev = u
        target = min(exc(t - t0), 0.75)
        if k > 0 and abs(u - target) < 1e-12:
            reached = True
    assert reached
    assert not c.state()['fault']
    assert math.isnan(c.state()['reference'])


def test_up_staircase_only_grows(cfg, params):
    """direction: up climbs from levels_min to levels_max (growing flow, the paper's
    identification data), one level per dwell, and holds the top when not repeating."""
    s = _signal(cfg, signal='staircase', direction='up', unit='percent', levels_min=30.0,
                levels_max=60.0, n_levels=4, dwell=1.0, repeat=False)
    lo, hi = params.current_range
    levels = [s(t) for t in (0.5, 1.5, 2.5, 3.5, 9.0)]
    expect = [lo + (hi - lo) * d for d in (0.3, 0.4, 0.5, 0.6, 0.6)]
    assert levels == pytest.approx(expect)
    assert s.duration == pytest.approx(4.0)
