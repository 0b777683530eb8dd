"""Grey-box calibration with a known truth: bags of the fine model with perturbed parameters
through the bench sensor chain (noise, quantisation, the 55 ms flow delay), written as real
rosbag2 bags and read back; the calibration must find the truth, flag what the data cannot
determine, and refuse bad input with one line."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from hydropump_ctrl.ident import read_recordings, recording_to_bag
from hydropump_ctrl.ident.calibrate import (
    calibrate,
    CalibrationError,
    params_with,
    validate,
    write_params,
)
from hydropump_ctrl.ident.design import candidate_inputs, suggest
from hydropump_ctrl.ident.synthetic import plant_recording
from hydropump_sim.params import load_params
from hydropump_sim.sensors import load_profile, SensorProfile
from hydropump_sim.simulate import simulate

from ..conftest import ROOT

USUAL = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')
FLOWS_AND_PRESSURES = ['line_flow', 'pump_flow', 'load_flow', 'line_pressure',
                       'actuator_pressure']
BENCH_DELAY = 0.055   # s, the bench's flow-path delay (config/bench.yaml)


def _bench():
    """The bench sensor chain without its dither (the dither is a plant effect)."""
    prof = load_profile(ROOT / 'config' / 'bench.yaml')
    return prof.sensors


def _bags(tmp, truth, which=None):
    """The standard experiments of ``truth`` as bags: staircases up and down, staircases at a
    lower load pressure, load-pressure steps."""
    paths = []
    sensors = _bench()
    for k, (name, inputs) in enumerate(candidate_inputs(truth, dwell=0.8).items()):
        if which is not None and k not in which:
            continue
        rec = plant_recording(truth, inputs['current'], load_pressure=inputs['load_pressure'],
                              profile=SensorProfile(sensors, seed=k + 1), name=name)
        paths.append(recording_to_bag(rec, tmp / f'bag{k}'))
    return paths


@pytest.fixture(scope='module')
def base():
    return load_params(ROOT / 'config' / 'pump.yaml')


@pytest.fixture(scope='module')
def usual(base, tmp_path_factory):
    """The usual free set, the truth 15-35 % away from the start (config/pump.yaml)."""
    tmp = tmp_path_factory.mktemp('usual')
    truth = params_with(base, USUAL, [base.flat()[n] * f
                                      for n, f in zip(USUAL, (1.25, 0.85, 1.35, 0.9))])
    paths = _bags(tmp, truth)
    recs = read_recordings(paths)
    return truth, paths, calibrate(recs, base, USUAL), tmp


def test_the_usual_free_set_is_recovered_within_2_percent(usual):
    truth, _, cal, _ = usual
    tf = truth.flat()
    for p in cal.estimates:
        assert p.determined, p.name
        assert abs(p.value / tf[p.name] - 1.0) < 0.02, (p.name, p.value, tf[p.name])
        assert p.stderr is not None and 0 < p.stderr < 0.02 * p.value
        assert p.on_bound is None
    # One delay per signal for the bench: the flow path's 55 ms, the others none.
    delays = cal.delays['all']
    for s in ('line_flow', 'pump_flow', 'load_flow'):
        assert abs(delays[s] - BENCH_DELAY) < 1e-3
    assert delays['line_pressure'] < 1e-3
    # Eq. 4's tie: h_a moved with mu_a.
    p = cal.params
    assert math.isclose(p.actuator.h_a, p.actuator.mu_a / math.sqrt(2 / p.fluid.rho),
                        rel_tol=1e-9)
    # The fit improved on every signal and the correlation matrix is one.
    for name, per in cal.fit.items():
        for s, v in per.items():
            assert v >= cal.fit_before[name][s] - 0.05
    assert np.allclose(np.diag(cal.correlation), 1.0)


def test_the_calibrated_file_predicts_a_held_out_scenario(usual, base):
    """A current sine with a load-pressure step, never seen by the fit: the calibrated file
    against the truth within 0.25 % of V_p f_p in flow and 0.5 bar in line pressure (rms)."""
    truth, _, cal, tmp = usual
    out = tmp / 'calibrated.yaml'
    write_params(cal, out)
    calibrated = load_params(out)   # loadable, and the simulator node takes the same file
    text = out.read_text()
    assert 'Calibrated by hydropump calibrate' in text and 'free line.V_l' in text
    lo, hi = truth.current_range
    mid, amp = 0.5 * (lo + hi), 0.25 * (hi - lo)

    def current(t):
        return mid + amp * np.sin(2 * np.pi * 0.7 * t)

    def load(t):
        return np.where(t < 2.0, truth.line.P_u, truth.line.P_u - 3.0e6)

    runs = [simulate(p, 4.0, current, load_pressure=load) for p in (truth, calibrated, base)]
    q_err = [np.sqrt(np.mean((r.q_l - runs[0].q_l) ** 2)) / truth.Q_max for r in runs[1:]]
    p_err = [np.sqrt(np.mean((r.P_l - runs[0].P_l) ** 2)) for r in runs[1:]]
    assert q_err[0] < 0.0025 and p_err[0] < 0.5e5
    # ... where the uncalibrated file does not.
    assert q_err[1] > 0.0025 or p_err[1] > 0.5e5


def test_beta_and_the_line_volume_are_flagged_not_returned(base, tmp_path):
    """With a bench's flow and pressure sensors, beta and V_l enter only as beta / V_l: the
    pair is flagged with that combination, which is right, and neither is returned as a
    confident number."""
    free = ('actuator.mu_a', 'fluid.beta', 'line.V_l', 'line.mu_u')
    truth = params_with(base, free, [base.flat()[n] * f
                                     for n, f in zip(free, (1.25, 0.85, 1.35, 0.9))])
    recs = read_recordings(_bags(tmp_path, truth))
    cal = calibrate(recs, base, free, signals=FLOWS_AND_PRESSURES)
    est = {p.name: p for p in cal.estimates}
    for n in ('fluid.beta', 'line.V_l'):
        assert not est[n].determined and est[n].stderr is None
    (und,) = cal.undetermined
    assert set(und['parameters']) == {'fluid.beta', 'line.V_l'}
    assert und['determined_combination'] == 'beta / V_l'
    ratio = cal.params.fluid.beta / cal.params.line.V_l
    assert abs(ratio / (truth.fluid.beta / truth.line.V_l) - 1) < 0.02
    # The others are still found.
    for n in ('actuator.mu_a', 'line.mu_u'):
        assert est[n].determined and abs(est[n].value / truth.flat()[n] - 1) < 0.02
    assert any('beta / V_l' in f for f in cal.flags)
    # With these sensors no standard experiment separates them either (it takes the
    # positions, which see the actuator chamber's compressibility).
    suggest(cal)
    assert und['separated_by'] == []
    assert any('none of the standard experiments suffices' in f for f in cal.flags)
    out = tmp_path / 'cal.yaml'
    write_params(cal, out)
    assert 'free fluid.beta' in out.read_text() and 'not determined' in out.read_text()


def test_a_start_50_percent_off_still_converges(base, tmp_path):
    truth = base
    start = params_with(base, USUAL, [base.flat()[n] * 1.5 for n in USUAL])
    recs = read_recordings(_bags(tmp_path, truth, which=(0, 2, 3)))
    cal = calibrate(recs, start, USUAL)
    for p in cal.estimates:
        assert p.determined and abs(p.value / truth.flat()[p.name] - 1) < 0.02, p.name


def test_validate_reports_the_fit_on_bags_not_fitted(usual, base):
    truth, paths, cal, _ = usual
    recs = read_recordings(paths[-1:])
    fit_cal, delays, _, _ = validate(recs, cal.params)
    fit_base, _, _, _ = validate(recs, base)
    (name,) = fit_cal
    assert fit_cal[name]['line_pressure'] > 95.0
    assert fit_cal[name]['line_pressure'] > fit_base[name]['line_pressure'] + 5.0
    assert abs(delays['all']['load_flow'] - BENCH_DELAY) < 2e-3


# ---- bad input ---------------------------------------------------------------------------

@pytest.fixture(scope='module')
def one_bag(base, tmp_path_factory):
    return read_recordings(_bags(tmp_path_factory.mktemp('one'), base, which=(0,)))


@pytest.mark.parametrize('free, expected', [
    (['actuator.mu'], 'actuator.mu: unknown plant parameter (did you mean actuator.mu_a?)'),
    (['actuator.h_a'], 'actuator.h_a is derived from actuator.mu_a and fluid.rho '
                       '(mu_a = h_a sqrt(2/rho) (eq. 4)): free actuator.mu_a instead'),
    (['spool.phi_s'], 'free spool.K_a or pump.x_a_max or spool.I_max instead'),
    (['relief.enabled'], 'relief.enabled is a bool, not a number'),
    (['pump.l_d'], 'pump.l_d cannot be informed by any data'),
    (['relief.p_crack'], 'relief.p_crack cannot be informed by these recordings'),
])
def test_parameters_that_cannot_be_fitted_are_refused(base, one_bag, free, expected):
    with pytest.raises(CalibrationError) as exc:
        calibrate(one_bag, base, free)
    assert any(expected in line for line in exc.value.lines), exc.value.lines


def test_no_excitation_and_no_current_are_refused(base, tmp_path):
    from hydropump_ctrl.ident import Recording
    n = 2000
    t = np.arange(n) * 1e-3
    flat = Recording(t, {'solenoid_current': np.full(n, 0.5), 'line_flow': np.full(n, 5e-4)})
    with pytest.raises(CalibrationError) as exc:
        calibrate([flat], base, ['line.V_l'])
    assert any('no excitation' in ln for ln in exc.value.lines)
    no_current = Recording(t, {'line_flow': np.full(n, 5e-4)}, roles={'flow': 'line_flow'})
    with pytest.raises(CalibrationError) as exc:
        calibrate([no_current], base, ['line.V_l'])
    assert 'no current to drive the model' in str(exc.value)


def _cli(*args):
    return subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', *args],
                          capture_output=True, text=True, timeout=300)


def test_cli_errors_are_one_line(usual, tmp_path, capsys):
    from hydropump_ctrl.cli import main
    _, paths, _, _ = usual
    bad = tmp_path / 'bad.yaml'
    bad.write_text('line:\n  V_l: -1\n')
    for args, text in [
        (['--free', 'line.V_x'], 'line.V_x: unknown plant parameter'),
        (['--free', 'line.P_u'], 'line.P_u is an input: the recordings carry it as '
                                 'load_pressure'),
        (['--free', 'line.V_l', '--params', str(bad)], 'line.V_l'),
        (['--free', 'line.V_l', '--signals', 'line_flux'], '--signals line_flux'),
    ]:
        assert main(['calibrate', str(paths[0]), *args, '--report', str(tmp_path / 'r')]) == 2
        err = capsys.readouterr().err
        assert text in err and err.startswith('error: ')
    # As a user runs it: a path that is not a bag, one line and no traceback.
    proc = _cli('calibrate', str(tmp_path / 'nothing'), '--free', 'line.V_l', '--report',
                str(tmp_path / 'r'))
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert proc.stderr.startswith('error: ')


def test_cli_calibrate_validate_design_cycle(usual, tmp_path):
    """calibrate -> a params file the simulator loads, JSON with the documented keys;
    validate on a held-out bag; design on the calibrated plant."""
    truth, paths, _, _ = usual
    out = tmp_path / 'calibrated.yaml'
    proc = _cli('calibrate', str(paths[0]), '--free', 'line.mu_u', 'actuator.P_a_bar',
                '--params', str(ROOT / 'config' / 'pump.yaml'), '--out', str(out), '--report',
                str(tmp_path / 'rep'), '--json', '--no-plots')
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout)
    for key in ('parameters', 'correlation', 'singular_values', 'fit_percent', 'delays_s',
                'flags', 'undetermined'):
        assert key in res
    assert set(res['parameters']['line.mu_u']) >= {'value', 'stderr', 'initial'}
    assert load_params(out).line.mu_u == pytest.approx(res['parameters']['line.mu_u']['value'],
                                                       rel=1e-8)
    assert (tmp_path / 'rep' / 'report.md').is_file()
    proc = _cli('validate', str(paths[3]), '--params', str(out), '--out',
                str(tmp_path / 'val'), '--json', '--no-plots')
    assert proc.returncode == 0, proc.stderr
    assert 'fit_percent' in json.loads(proc.stdout)
    proc = _cli('design', '--params', str(out), '--out', str(tmp_path / 'controller.yaml'))
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / 'controller.yaml').is_file()


def test_a_run_that_did_not_start_settled_starts_where_its_plate_was(base):
    """A bag that begins while the plant still moves (the simulator settled at 0.5 A, the
    excitation starts lower): the initial plate position gives the equilibrium it came
    from, and the fit is as good as on a settled run."""
    from hydropump_ctrl.ident import Recording
    truth = params_with(base, ('line.mu_u',), [base.line.mu_u * 0.9])
    lo, hi = truth.current_range
    cur = np.concatenate([np.full(300, 0.5 * (lo + hi))] +
                         [np.full(600, lo + f * (hi - lo)) for f in (0.3, 0.45, 0.35)])
    full = plant_recording(truth, cur, name='late')
    rec = Recording(full.t[300:] - full.t[300], {k: v[300:] for k, v in full.signals.items()},
                    name='late')
    cal = calibrate([rec], base, ['line.mu_u'])
    assert any('did not start settled' in n for n in cal.notes)
    (p,) = cal.estimates
    assert abs(p.value / truth.line.mu_u - 1) < 0.002
    assert cal.fit['late']['actuator_position'] > 99.0
