"""The one smoothing helper (``hydropump_sim.metrics.moving_average``) and its dither window."""

import math

import numpy as np
import pytest

from hydropump_ctrl.experiments.closed_loop import dither_free
from hydropump_sim.metrics import dither_window, moving_average


def _direct(y, w, k):
    """Mean of the window of sample ``k`` by definition (``None`` where it leaves ``y``)."""
    lo = k - w // 2
    return None if lo < 0 or lo + w > y.size else float(np.mean(y[lo:lo + w]))


@pytest.mark.parametrize('w', [2, 5, 20, 21])
def test_window_of_a_sample_and_the_three_edge_rules(w):
    y = np.random.default_rng(w).standard_normal(60)
    full = moving_average(y, w, edges='full')
    shrink = moving_average(y, w, edges='shrink')
    valid = moving_average(y, w, edges='valid')
    assert full.shape == shrink.shape == y.shape and valid.size == y.size - w + 1
    for k in range(y.size):
        inside = _direct(y, w, k)
        if inside is not None:
            assert full[k] == pytest.approx(inside) and shrink[k] == pytest.approx(inside)
            assert valid[k - w // 2] == pytest.approx(inside)
            continue
        # Full: the nearest whole window; shrink: the part of the window inside the record.
        lo = min(max(k - w // 2, 0), y.size - w)
        assert full[k] == pytest.approx(np.mean(y[lo:lo + w]))
        a, b = max(k - w // 2, 0), min(k - w // 2 + w, y.size)
        assert shrink[k] == pytest.approx(np.mean(y[a:b]))


def test_short_windows_and_bad_edges():
    y = np.arange(5.0)
    assert np.array_equal(moving_average(y, 1), y)
    assert np.array_equal(moving_average(y, 9, edges='shrink'), y)     # longer than y
    with pytest.raises(ValueError, match='edges'):
        moving_average(y, 3, edges='same')


def test_a_window_of_whole_dither_periods_cancels_the_dither():
    dt = 1e-3
    assert dither_window(dt, 150.0) == 20            # 3 periods of 150 Hz at 1 kHz
    assert dither_window(dt, 100.0) == 10
    assert dither_window(dt, 0.0) == 1
    t = np.arange(3000) * dt
    ramp = 0.2 * t
    for f in (150.0, 100.0, 37.0):
        y = ramp + 0.1 * np.sin(2 * math.pi * f * t + 0.3) + 0.02 * np.sin(4 * math.pi * f * t)
        w = dither_window(dt, f)
        out = moving_average(y, w, edges='full')
        # The dither and its harmonic cancel to the window's rounding of the period; a ramp
        # comes out delayed by the half sample of an even window.
        lag = 0.5 * dt if w % 2 == 0 else 0.0
        assert np.max(np.abs(out - (ramp - 0.2 * lag))[w:-w]) < 2e-3, f
        np.testing.assert_allclose(dither_free(t, y, f), out, rtol=0, atol=1e-15)
    assert np.array_equal(dither_free(t, ramp, 0.0), ramp)


@pytest.mark.parametrize('n', [400, 20000])
def test_fig6_draws_the_residual_when_a_bucket_holds_one_sample(n):
    """Fig. 6's residual as an envelope of its samples: with fewer samples than buckets
    (a 200 Hz record: one sample a bucket) it was a band of no height, and drew nothing;
    now its edges follow the signal, whatever the rate."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from hydropump_ctrl.ident.report import draw_envelope
    t = np.linspace(0.0, 20.0, n)
    x = np.sin(t) + 0.1 * np.cos(37.0 * t)
    fig, ax = plt.subplots()
    draw_envelope(ax, t, x)
    lows, highs = (np.asarray(line.get_ydata()) for line in ax.lines)
    plt.close(fig)
    assert lows.size >= min(n, 2500) - 1 and np.all(lows <= highs)
    # Every sample lies inside the drawn edges (one sample a bucket: on them).
    k = int(np.ceil(n / 2500))
    m = n // k * k
    xb = x[:m].reshape(-1, k)
    assert np.allclose(lows, xb.min(axis=1)) and np.allclose(highs, xb.max(axis=1))
    assert np.ptp(lows) > 1.5        # the sine's swing is drawn, not a flat line


def test_step_peaks_follow_scipys_find_peaks_rule():
    """``signals.peaks`` stands in for ``scipy.signal.find_peaks(height=, distance=)`` (whose
    import costs every calibration half a second): scipy is the truth, on random records
    with flat tops and peaks closer than the distance (no two peaks of equal height, where
    the rule leaves the choice open)."""
    from scipy.signal import find_peaks

    from hydropump_ctrl.ident.signals import find_steps, peaks
    rng = np.random.default_rng(3)
    for k in range(600):
        n = int(rng.integers(3, 400))
        x = rng.standard_normal(n)
        if k % 2:
            r = int(rng.integers(2, 6))
            x = np.repeat(rng.standard_normal(n // r + 1), r)[:n]
        height, distance = 0.5 * rng.standard_normal(), int(rng.integers(1, 40))
        want = find_peaks(x, height=height, distance=distance)[0]
        assert np.array_equal(np.sort(peaks(x, height, distance)), want), (k, x, height)
    # A dithered staircase: its steps where they were made, with their signs.
    dt = 1e-3
    u = np.repeat([0.3, 0.6, 0.4, 0.7], 500) + 0.01 * np.sin(2 * np.pi * 150 * dt
                                                              * np.arange(2000))
    idx, size = find_steps(u, dt)
    assert np.abs(idx - [500, 1000, 1500]).max() <= 1
    assert np.allclose(size, [0.3, -0.2, 0.3], atol=0.02)
