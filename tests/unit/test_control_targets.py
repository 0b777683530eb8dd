"""The target table of docs/control.md on the fine-model simulator with the bench profile
config/bench.yaml exactly as shipped (55 ms flow delay, noise, quantisation, its 2 mA, 400 Hz
dither), fixed seeds, controllers designed from the plant's own model and that profile only
(config/controller.yaml)."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from hydropump_ctrl.control.emc import EMCController
from hydropump_ctrl.control.pi import PIController
from hydropump_ctrl.experiments import cases as cs
from hydropump_ctrl.experiments.closed_loop import PlantVariation, run_closed_loop

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope='module')
def FS(params):
    return params.Q_max


def test_bench_profile_is_the_judged_one(bench, cfg):
    """What the tests judge on is config/bench.yaml as the file says, read here as plain YAML:
    no fixture may swap its dither or its sensors."""
    shipped = yaml.safe_load((ROOT / 'config' / 'bench.yaml').read_text())['/**'][
        'ros__parameters']
    assert bench.plant_overrides == {f'input.{k}': v for k, v in shipped['input'].items()}
    for signal in ('line_flow', 'pump_flow', 'line_pressure', 'load_pressure'):
        for field, value in shipped['sensors'][signal].items():
            assert getattr(bench.spec(signal), field) == value, (signal, field)
    assert bench.seed == shipped['sensors']['seed']
    # The design took its delay from that profile: 11 periods at 200 Hz.
    assert cfg.model.t_d == shipped['sensors']['line_flow']['delay']
    assert cfg.delay_steps == 11 and cfg.controller.update_rate == 200.0


@pytest.mark.parametrize('r0, r1', cs.FLOW_STEPS)
def test_nominal_flow_steps(cfg, params, bench, FS, r0, r1):
    f = cs.flow_step_case(EMCController(cfg), params, bench, r0 * FS, r1 * FS).figures
    if r1 > r0:
        assert f['rise'] <= 0.15
        assert f['overshoot'] <= 5.0
        assert f['steady_error'] <= 0.005 * FS
    else:
        # The faster branch with the zero of eq. 17.
        assert f['overshoot'] <= 10.0
    assert f['settling'] <= 0.35


@pytest.mark.parametrize('var', cs.one_at_a_time(), ids=lambda v: v.label)
def test_plus_minus_20_percent_one_at_a_time(cfg, params, bench, FS, var):
    for r0, r1 in cs.FLOW_STEPS:
        f = cs.flow_step_case(EMCController(cfg), params, bench, r0 * FS, r1 * FS, var,
                              duration=1.0).figures
        assert f['overshoot'] <= 10.0, (r0, r1)
        assert f['settling'] <= 0.5, (r0, r1)
        assert f['steady_error'] <= 0.005 * FS, (r0, r1)


def test_worst_combined_corner(cfg, params, bench, FS):
    worst_os = worst_ts = 0.0
    for var in cs.corners():
        for r0, r1 in cs.FLOW_STEPS:
            f = cs.flow_step_case(EMCController(cfg), params, bench, r0 * FS, r1 * FS, var,
                                  duration=1.2).figures
            worst_os, worst_ts = max(worst_os, f['overshoot']), max(worst_ts, f['settling'])
            # Stable: it ends at the reference.
            assert f['steady_error'] <= 0.005 * FS
    assert worst_os <= 30.0
    assert worst_ts <= 0.8


def test_quasi_static_dip_is_what_the_plant_does_with_the_flow_held(params, bench):
    """The "unavoidable dip": an aperture step with the current held, line settled, before the
    pump moves (the pump cannot change its flow in the few ms the line needs)."""
    from hydropump_ctrl.experiments.closed_loop import trim_current
    from hydropump_sim import simulate
    for xi0, k in ((0.5, 1.2), (0.8, 0.8)):
        p = params.replace({'line.xi_u': xi0})
        I0 = trim_current(p, margin=2.5e6)
        res = simulate(p, 0.03, I0, aperture=lambda t, xi0=xi0, k=k: np.where(
            t < 0.01, xi0, xi0 * k), dt_out=1e-4)
        qs = cs.quasi_static_margin(2.5e6, xi0, xi0 * k, params.line.gamma_u)
        margin = res.P_l - res.P_u
        # 15 ms after the step: the line has settled (tau_l < 4 ms), the flow moved < 1 %.
        assert margin[res.t.searchsorted(0.025)] == pytest.approx(qs, rel=0.03)


@pytest.fixture(scope='module')
def aperture_runs(cfg, params, bench):
    out = {}
    for dp in cs.MARGINS:
        for xi in cs.APERTURES:
            for k in cs.APERTURE_FACTORS:
                out[(dp, xi, k)] = (
                    cs.aperture_case(EMCController(cfg), params, bench, dp, xi, k).figures,
                    cs.aperture_case(PIController(cfg), params, bench, dp, xi, k).figures)
    return out


@pytest.mark.parametrize('dp', cs.MARGINS)
@pytest.mark.parametrize('xi', cs.APERTURES)
@pytest.mark.parametrize('k', cs.APERTURE_FACTORS)
def test_load_sensing_aperture_steps(aperture_runs, dp, xi, k):
    emc, pi = aperture_runs[(dp, xi, k)]
    # The dip beyond the unavoidable quasi-static one.
    assert emc['beyond'] <= 1.0e5
    assert emc['recovery'] <= 0.3
    # No limit cycle: the margin is quiet at the end (bench noise alone is 0.28 bar).
    assert emc['ripple'] <= 1.0e5
    # Against the baseline: IAE at most 0.9 x, peak no worse (one 0.1 bar quantum).
    assert emc['iae'] <= 0.9 * pi['iae']
    assert abs(emc['peak']) <= abs(pi['peak']) + 1.0e4


def test_one_tuning_for_the_whole_aperture_range(aperture_runs):
    """The same eigenvalues at 0.1 and 0.8: recovery times within a factor 2 of each other
    (the PI, tuned where the loop gain is largest, spreads over more than 5x)."""
    rec = {xi: max(aperture_runs[(dp, xi, k)][0]['recovery'] for dp in cs.MARGINS
                   for k in cs.APERTURE_FACTORS) for xi in cs.APERTURES}
    assert max(rec.values()) <= 2.0 * min(rec.values())
    pi = {xi: max(aperture_runs[(dp, xi, k)][1]['recovery'] for dp in cs.MARGINS
                  for k in cs.APERTURE_FACTORS) for xi in cs.APERTURES}
    assert max(pi.values()) > 5.0 * min(pi.values())


@pytest.mark.parametrize('xi', cs.APERTURES)
def test_margin_set_point_step(cfg, params, bench, xi):
    f = cs.setpoint_case(EMCController(cfg), params, bench, 2.0e6, 2.5e6, xi).figures
    assert f['rise'] <= 0.2
    assert f['overshoot'] <= 10.0
    assert f['settling'] <= 0.4


def test_unreachable_demand_then_release(cfg, params, bench, FS):
    case = cs.unreachable_case(EMCController(cfg), params, bench, 0.6 * FS, 1.1 * FS)
    f = case.figures
    assert f['recovery'] <= 0.35
    assert f['undershoot'] <= 0.02 * FS
    # The demand was really unreachable: the plate sat at its stop.
    res = case.result
    hold = (res.t > 0.6) & (res.t < 1.1)
    assert np.mean(res.smooth('q_l')[hold]) == pytest.approx(FS, rel=0.01)
    # and the command stayed inside eq. 2 and within the rate limit.
    lim = cfg.limits
    assert lim.current_min <= res.command.min() and res.command.max() <= lim.current_max
    assert np.max(np.abs(np.diff(res.command))) <= lim.rate_limit * cfg.period + 1e-12


@pytest.mark.parametrize('mode, start', [('flow', {'start_flow': 5.625e-4}),
                                         ('margin', {'start_margin': 2.5e6, 'aperture': 0.5})])
def test_dither_ripple_on_the_command(cfg, params, bench, mode, start):
    f = cs.dither_case(EMCController(cfg), params, bench, mode, **start).figures
    # 1 % of the 0..100 % current span (0.4 A), at the dither frequency and at its alias in
    # the controller's 200 Hz samples (the bench's 400 Hz folds onto 0 Hz, a bias the
    # disturbance estimate takes; a 150 Hz dither would show at 50 Hz).
    assert f['ripple_dither'] <= 0.01 * cs.CURRENT_SPAN
    assert f['ripple_alias'] <= 0.01 * cs.CURRENT_SPAN


def test_flow_disturbance_against_the_baseline(cfg, params, bench, FS):
    """Shaft speed -/+10 % at 50 % flow, 8 noise seeds: the 0.9 x PI target on average over
    the seeds, for both directions, and never worse than 1.05 x on any seed (docs/control.md,
    section 9: under a dither below the spool's corner the rising speed reached only 0.94 x)."""
    from dataclasses import replace
    ratio = {}
    for k in (0.9, 1.1):
        r, peaks = [], []
        for seed in cs.SEEDS:
            prof = replace(bench, seed=seed)
            e = cs.shaft_speed_case(EMCController(cfg), params, prof, 0.5 * FS, k).figures
            p = cs.shaft_speed_case(PIController(cfg), params, prof, 0.5 * FS, k).figures
            r.append(e['iae'] / p['iae'])
            peaks.append((abs(e['peak']), abs(p['peak'])))
        ratio[k] = np.array(r)
        # The peak is the step itself, unseen for t_d: on average no worse than one 0.25 % FS
        # quantum of the flow sensor.
        emc_peak, pi_peak = np.mean(peaks, axis=0)
        assert emc_peak <= pi_peak + 0.0025 * FS
    for r in ratio.values():
        assert r.mean() <= 0.9 and r.max() <= 1.05
    # Lower bound of any causal controller: the error is the whole step for t_d.
    e = cs.shaft_speed_case(EMCController(cfg), params, bench, 0.5 * FS, 1.1).figures
    assert e['iae'] >= 0.05 * 0.5 * FS * bench.spec('line_flow').delay


def test_the_plant_is_really_the_fine_model_with_the_bench(cfg, params, bench, FS):
    """Guard: the judged runs use the dithered fine model and the delayed, noisy sensors."""
    res = run_closed_loop(EMCController(cfg), 0.2, [], params=params, profile=bench,
                          start_flow=0.5 * FS, mode='flow', variation=PlantVariation())
    assert res.params.input.dither_amp > 0.0
    assert res.params.input.dither_amp == pytest.approx(bench.plant_overrides['input.dither_amp'])
    assert np.std(res.meas['line_flow'] - np.mean(res.meas['line_flow'])) > 0.003 * FS
