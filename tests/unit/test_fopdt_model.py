"""The exact sampled FOPDT of eq. 19 and the building blocks of the fit.

Truth here is the closed-form continuous-time step response (``synthetic.fopdt_truth``),
which shares no code with the sampled model.
"""

import math

import numpy as np
import pytest

from hydropump_ctrl import ident as fp
from hydropump_ctrl.ident import robust
from hydropump_ctrl.ident import synthetic as syn
from hydropump_sim.errors import HydropumpError


def _staircase(dt, duration=3.0, seed=0):
    rng = np.random.default_rng(seed)
    return syn.staircase(duration, dt, rng, dwell=(0.2, 0.5))


@pytest.mark.parametrize('dt, td', [(1e-3, 0.055), (1e-3, 0.0554), (1e-3, 0.0), (1e-3, 3e-4),
                                    (1e-2, 0.057), (1e-2, 0.0031), (1e-3, 0.0549999)])
def test_sampled_model_equals_the_analytic_response(dt, td):
    # Whole and fractional delays, at 1 kHz and 100 Hz: no Pade, no rounding to samples.
    steps = _staircase(dt)
    t = np.arange(int(3.0 / dt)) * dt
    u = syn.level_at(steps, t)
    truth = syn.Truth(100.0, 0.1, td)
    y_true = syn.fopdt_truth(t, steps, truth)
    y = fp.fopdt_response(u, dt, truth.G0, truth.tau, truth.td)
    assert np.max(np.abs(y - y_true)) < 1e-9


def test_rounding_the_delay_would_be_visible():
    # The check above is sensitive: a 0.4-sample error is far above its tolerance.
    dt = 1e-3
    steps = _staircase(dt)
    t = np.arange(3000) * dt
    u = syn.level_at(steps, t)
    y_true = syn.fopdt_truth(t, steps, syn.Truth(100.0, 0.1, 0.0554))
    y_round = fp.fopdt_response(u, dt, 100.0, 0.1, 0.055)
    assert np.max(np.abs(y_round - y_true)) > 0.05


def test_coefficients_have_unit_gain_and_are_continuous_in_the_delay():
    dt, tau = 1e-3, 0.1
    for td in (0.0, 0.0123, 0.055, 0.0999):
        a, b1, b2, d, f = fp.coefficients(tau, td, dt)
        assert b1 + b2 == pytest.approx(1.0 - a, abs=1e-15)
        assert d + f == pytest.approx(td / dt)
        assert b1 >= 0 and b2 >= 0
    # Crossing a whole sample, the response changes continuously.
    u = np.r_[np.zeros(10), np.ones(200)]
    below = fp.fopdt_response(u, dt, 1.0, tau, 0.020 - 1e-9)
    at = fp.fopdt_response(u, dt, 1.0, tau, 0.020)
    assert np.max(np.abs(below - at)) < 1e-6


def test_window_jacobian_matches_finite_differences():
    rec = syn.make_record(syn.Truth(100.0, 0.1, 0.0554), seed=3, duration=4.0, noise=0.0,
                        quantum=0.0)
    u, y = (rec.current - 0.3) / 0.4, rec.flow / 1.125e-5
    lines = fp.detect_dither(u, rec.dt)
    win = robust.Window(u, y, rec.dt, 0.25, lines)
    theta = np.r_[98.0, 0.097, 0.0537, 1.0, 0.5, 0.01, -0.02][:win.p]
    _, J = win.model(theta, jac=True)
    for i, h in enumerate((1e-4, 1e-7, 1e-8, 1e-5, 1e-5, 1e-5, 1e-5)[:win.p]):
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h
        tm[i] -= h
        fd = (win.model(tp)[0] - win.model(tm)[0]) / (2 * h)
        assert np.max(np.abs(J[:, i] - fd)) <= 1e-4 * (np.max(np.abs(fd)) + 1e-12), i


def test_delay_profile_equals_the_direct_projection():
    # The FFT and cumulative-sum grid gives the same SSE as a direct least-squares solve.
    rec = syn.make_record(syn.Truth(100.0, 0.1, 0.055), seed=4, duration=4.0, dither=0.0)
    u, y = (rec.current - 0.3) / 0.4, rec.flow / 1.125e-5
    win = robust.Window(u, y, rec.dt, 0.25)
    taus = np.array([0.03, 0.1, 0.4])
    sse = robust.delay_profile(win, taus, 0, 250)
    for i, tau in enumerate(taus):
        for d in (0, 40, 55, 250):
            _, direct = win.project(tau, d * rec.dt)
            assert sse[i, d] == pytest.approx(direct, rel=1e-7)


def test_dither_line_is_found_and_measured():
    dt = 1e-3
    t = np.arange(20000) * dt
    steps = syn.staircase(20.0, dt, np.random.default_rng(1))
    u = syn.level_at(steps, t) + 0.03 * np.sin(2 * math.pi * 150.0 * t + 0.7)
    (line,) = fp.detect_dither(u, dt)
    assert line.freq == pytest.approx(150.0, abs=0.01)
    assert line.amp == pytest.approx(0.03, rel=0.01)
    assert np.max(np.abs(line.at(t) - 0.03 * np.sin(2 * math.pi * 150.0 * t + 0.7))) < 1e-3
    assert fp.detect_dither(syn.level_at(steps, t), dt) == []
    # A slow sinusoidal test signal is excitation, not dither.
    assert fp.detect_dither(0.5 + 0.1 * np.sin(2 * math.pi * 1.0 * t), dt) == []


def test_noise_free_data_are_fitted_exactly():
    # Fractional delay, dither, non-zero start level and offset: recovered to 1e-6.
    truth = syn.Truth(100.0, 0.1, 0.0554, offset=2.0)
    rec = syn.make_record(truth, seed=8, duration=8.0, noise=0.0, quantum=0.0)
    u, y = (rec.current - 0.3) / 0.4, rec.flow / 1.125e-5
    fit = fp.fit_fopdt(u, y, rec.dt)
    assert fit.G0 == pytest.approx(truth.G0, abs=1e-5)
    assert fit.tau == pytest.approx(truth.tau, abs=1e-8)
    assert fit.td == pytest.approx(truth.td, abs=1e-8)
    assert fit.offset == pytest.approx(truth.offset, abs=1e-5)
    assert fit.fit_percent > 99.99


def test_bad_arrays_are_refused_with_one_line():
    u = np.r_[np.full(500, 0.4), np.full(500, 0.6)]
    y = 100 * u
    with pytest.raises(fp.FitError, match='no excitation'):
        fp.fit_fopdt(np.full(1000, 0.5), y, 1e-3)
    y_nan = y.copy()
    y_nan[700] = np.nan
    with pytest.raises(fp.FitError, match=r'flow has 1 NaN .*t = 0\.7 s'):
        fp.fit_fopdt(u, y_nan, 1e-3)
    with pytest.raises(fp.FitError, match='too short'):
        fp.fit_fopdt(u, y, 1e-3, td_bounds=(0.0, 0.5))
    with pytest.raises(fp.FitError, match='unknown method'):
        fp.fit_fopdt(u, y, 1e-3, method='procest')


def test_fit_errors_are_one_line_user_errors():
    with pytest.raises(fp.FitError) as err:
        fp.fit_fopdt(np.full(1000, 0.5), np.zeros(1000), 1e-3)
    assert isinstance(err.value, HydropumpError) and isinstance(err.value, ValueError)
    assert err.value.lines == [str(err.value)] and '\n' not in str(err.value)
