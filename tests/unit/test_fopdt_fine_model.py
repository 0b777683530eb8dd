"""Identification on data of the plant library's fine model (``hydropump_sim.simulate``).

Truth from outside the fitter: the gain from the plant's equilibria at the two currents
(trim, eq. 14), the time constant as the 63 % time read off the simulated response itself,
the paper (G0 = 100 ± 0.7, tau = 100 ± 2 ms) and, for the bench chain, the configured
sensor delay of config/bench.yaml.
"""

from pathlib import Path

import numpy as np
import pytest

from hydropump_ctrl import ident as fp
from hydropump_ctrl.ident import Recording, recording_to_bag
from hydropump_sim import held, simulate
from hydropump_sim.scaling import current_for_displacement
from hydropump_sim.sensors import apply_profile, load_profile, profile_from_dict

ROOT = Path(__file__).resolve().parents[2]
BENCH_YAML = ROOT / 'config' / 'bench.yaml'
NOISE = {'noise_std': 5.625e-6, 'quantum': 2.8125e-6}      # 0.5 % and 0.25 % of V_p f_p


def _record(t, current, flow, **kw):
    return Recording(t, {'solenoid_current': current, 'line_flow': flow}, **kw)


def _up_step(params, t_step, duration=3.0):
    lo, hi = current_for_displacement(params, [0.4, 0.6])
    return simulate(params, duration, lambda t: np.where(np.asarray(t) >= t_step, hi, lo))


def _t63(t, y, t_step, t_end):
    """The time from ``t_step`` until ``y`` first covers 63.2 % of its change up to
    ``t_end``, read off the samples (linear between them)."""
    y0 = y[np.searchsorted(t, t_step) - 1]
    y1 = y[np.searchsorted(t, t_end) - 1]
    after = t >= t_step
    level = y0 + (1.0 - np.exp(-1.0)) * (y1 - y0)
    k = np.argmax((y[after] - level) * np.sign(y1 - y0) >= 0.0)
    ta, ya = t[after], y[after]
    return ta[k - 1] + (level - ya[k - 1]) / (ya[k] - ya[k - 1]) * (ta[k] - ta[k - 1]) - t_step


def test_clean_up_step_matches_the_plant_s_own_gain_and_63_percent_time(params):
    from hydropump_sim import equilibrium
    res = _up_step(params, 1.0)
    fit = fp.fit_recording(_record(res.t, res.I_s, res.q_l, name='clean'), params=params)
    lo, hi = current_for_displacement(params, [0.4, 0.6])
    q = [equilibrium(params, i).q_l for i in (lo, hi)]
    span = params.current_range[1] - params.current_range[0]
    G0 = 100.0 * (q[1] - q[0]) / params.Q_max / ((hi - lo) / span)
    assert fit.G0 == pytest.approx(G0, abs=0.1)
    # A first order's time constant is its 63 % time less its delay.
    assert fit.tau + fit.td == pytest.approx(_t63(res.t, res.q_l, 1.0, 3.0), abs=1e-3)
    assert 0.0 <= fit.td < 1e-3
    assert fit.fit_percent > 99.0
    # The fine model is not first order: the residual test says so.
    assert 'residuals_not_white' in fit.flags


def test_noisy_up_steps_give_the_papers_figures(params):
    # Five 40 -> 60 % up-steps (growing flow, as the paper identifies), bench noise and
    # quantisation, no delay.
    recs = []
    for i, t_step in enumerate((1.0, 1.1, 1.2, 1.3, 1.4)):
        res = _up_step(params, t_step)
        prof = profile_from_dict({'sensors': {'seed': 40 + i, 'line_flow': NOISE}})
        flow = apply_profile(prof, res.t, {'line_flow': res.q_l})['line_flow']
        recs.append(_record(res.t, res.I_s, flow, name=f'up{i}'))
    ident = fp.fit_recordings(recs, params=params)
    po = ident.pooled
    assert abs(po.mean['G0'] - 100.0) <= 0.7
    assert abs(po.mean['tau'] - 0.100) <= 0.002
    for f in ident.sets:
        assert f.fit_percent >= 90.0
        assert abs(f.G0 - 100.0) <= 0.7
        assert abs(f.tau - 0.100) <= 0.002 + 3 * f.se['tau']


def test_bench_chain_delay_is_recovered_from_a_bag(params, tmp_path):
    # Offline twin of the ROS bench test: the fine model with the bench profile's dither,
    # a 55 ms flow delay, noise and quantisation, written as an MCAP bag like the
    # recorder's and fitted with fit_bags. The plant's own response under the same dither
    # is read off the noise-free, delay-free record of the same run: its 63 % times.
    # Growing flow only (the paper's zone; down-steps follow eq. 15, not eq. 19): a staircase
    # of 10 % up-steps from 30 to 70 %.
    prof = load_profile(BENCH_YAML)
    plant = params.replace(prof.plant_overrides)
    levels = np.array([0.3, 0.4, 0.5, 0.6, 0.7])
    times = np.array([0.0, 1.0, 3.5, 6.0, 8.5])
    lo, hi = params.current_range

    current = held(times, lo + (hi - lo) * levels)

    res = simulate(plant, 11.0, current)
    meas = apply_profile(prof, res.t, {'solenoid_current': res.I_s, 'line_flow': res.q_l})
    bag = recording_to_bag(_record(res.t, meas['solenoid_current'], meas['line_flow']),
                           tmp_path / 'bench', namespace='pump')
    ident = fp.fit_bags([bag], params=params)
    fit = ident.sets[0]
    # The dithered plant's 63 % time per step (smoothed over the dither's period, which
    # the flow sensor averages too).
    w = int(round(1.0 / (plant.input.dither_freq * res.t[1]))) or 1
    smooth = np.convolve(res.q_l, np.ones(w) / w, mode='same')
    t63 = np.mean([_t63(res.t, smooth, a, b) for a, b in zip(times[1:], [*times[2:], 11.0])])
    configured = prof.spec('line_flow').delay
    assert configured == pytest.approx(0.055)
    # The fitted delay is the sensor's plus the plant's own few milliseconds, and delay
    # plus time constant is the 63 % time.
    assert 0.0 <= fit.td - configured <= 3e-3
    assert fit.td - configured + fit.tau == pytest.approx(t63, abs=2e-3)
    assert ident.td == fit.td and ident.pooled.n == 1
