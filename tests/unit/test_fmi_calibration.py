"""Calibrating a user's FMU (hydropump_ctrl.fmi.calibration), without ROS: the first-order
pump FMU of tests/fmus.py (not the suite's code; ten explicit Euler steps a step) fitted to
recordings made in closed form (the lag's exact response to held currents, with Gaussian
noise), so the truth is not the FMU's own output; its bad input in one line each."""

import numpy as np
import pytest
import yaml

from hydropump_ctrl.fmi.calibration import calibrate_fmu, write_fmu_params
from hydropump_ctrl.ident.calibrate import CalibrationError
from hydropump_ctrl.ident.recording import Recording

from .. import fmus

pytest.importorskip('fmpy')
pytest.importorskip('pythonfmu')

GAIN, TAU, DT = 1.2e-3, 0.025, 1.0e-3     # the truth: 20 % and 25 % off the FMU's starts
ROLES = {'current': 'solenoid_current_cmd', 'flow': 'line_flow'}


@pytest.fixture(scope='module')
def lag_pump(tmp_path_factory):
    return fmus.lag_pump(tmp_path_factory.mktemp('lag'))


@pytest.fixture(scope='module')
def recordings(params):
    # The second starts where a recorder's run may: settled at another current (0.7 A)
    # than its first (0.6 A).
    # The first one's pressure starts late (its first messages lost): NaN there.
    first = fmus.lag_recording([0.4, 0.6, 0.8, 0.5], params.fluid.p_atm, 1, gain=GAIN, tau=TAU)
    first.signals['line_pressure'][:3] = np.nan
    return [first, fmus.lag_recording([0.6, 0.45, 0.65, 0.35], params.fluid.p_atm, 2,
                                      settled_at=0.7, gain=GAIN, tau=TAU)]


def test_an_fmu_is_calibrated_to_the_closed_form(lag_pump, recordings, params, tmp_path):
    cal = calibrate_fmu(lag_pump, recordings, params, ['gain', 'tau'])
    est = {p.name: p for p in cal.estimates}
    assert est['gain'].initial == 1.0e-3 and est['tau'].initial == 0.02
    # Within 2 % of the truth; the gain to its interval (its Euler steps leave the flow's
    # settled level exact), the time constant to the Euler bias: (1 - h/tau)^10 is
    # exp(-10 h / (1.0025 tau)) at h = 0.1 ms.
    assert est['gain'].value == pytest.approx(GAIN, rel=0.02)
    assert est['gain'].ci95[0] <= GAIN <= est['gain'].ci95[1]
    assert est['tau'].value == pytest.approx(TAU, rel=0.02)
    assert est['tau'].value == pytest.approx(TAU * 1.0025, rel=2e-3)
    assert all(p.well_determined for p in cal.estimates)
    # Fitted to the noise on both signals, no delay found where there is none.
    for per in cal.misfit.values():
        for m in per.values():
            assert 0.8 < m['ratio'] < 1.2
    for d in cal.delays['all'].values():
        assert abs(d) < 0.2 * DT
    assert cal.improved and cal.cost < 0.01 * cal.cost_start
    assert 'forward differences of whole runs of the FMU' in cal.method
    # The run that started settled elsewhere starts there, within its first sample's noise.
    (note,) = [n for n in cal.notes if 'settled' in n]
    head = ('staircase2: the run did not start settled at its first current (0.6 A): its '
            'first samples show the FMU settled at ')
    assert note.startswith(head) and note.endswith(' A, where its run starts'), note
    assert float(note[len(head):].split()[0]) == pytest.approx(0.7, abs=0.005)
    # Its params file is the simulator node's: the FMU and its calibrated parameters.
    out = write_fmu_params(cal, lag_pump, tmp_path / 'calibrated.yaml')
    node = yaml.safe_load(out.read_text())['/**']['ros__parameters']
    assert node['fmu_file'] == str(lag_pump.resolve())
    assert node['fmu_parameters'] == pytest.approx({'gain': est['gain'].value,
                                                    'tau': est['tau'].value}, rel=1e-9)


@pytest.mark.parametrize('free, signals, line', [
    (['gian'], None, 'gian: unknown real parameter of '),
    (['tau', 'tau'], None, 'tau is given twice'),
    ([], None, 'no free parameter: name at least one with --free (the parameters of '
               'lag_pump.fmu: tau, gain, noise, fail_after, substeps)'),
    (['tau'], ['pump_flow'], 'no output pump_flow, which the recordings have'),
])
def test_bad_input_is_one_line(lag_pump, recordings, params, free, signals, line):
    recs = recordings
    if signals:
        recs = [Recording(r.t, dict(r.signals, pump_flow=r['line_flow']), name=r.name,
                          roles=ROLES) for r in recordings]
    with pytest.raises(CalibrationError) as err:
        calibrate_fmu(lag_pump, recs, params, free, signals=signals)
    assert any(line in ln for ln in err.value.lines), err.value.lines


def test_the_command_fits_the_fmu_and_ends_bad_input_in_one_line(lag_pump, recordings, tmp_path,
                                                                  capsys):
    from hydropump_ctrl import cli
    bags = [str(r.save(tmp_path / f'{r.name}.npz')) for r in recordings]
    report = tmp_path / 'report'
    assert cli.main(['calibrate', '--fmu', str(lag_pump), *bags, '--free', 'gain', 'tau',
                     '--report', str(report), '--no-plots', '--json']) == 0
    result = yaml.safe_load(capsys.readouterr().out)
    assert result['parameters']['gain']['value'] == pytest.approx(GAIN, rel=0.02)
    assert (report / 'report.md').is_file()
    node = yaml.safe_load((report / 'calibrated.yaml').read_text())['/**']['ros__parameters']
    assert node['fmu_parameters']['tau'] == pytest.approx(TAU, rel=0.02)
    for args, line in [
            (['--fmu', str(tmp_path / 'none.fmu'), *bags, '--free', 'tau'],
             f'{tmp_path / "none.fmu"}: no such file'),
            (['--fmu', str(lag_pump), *bags, '--free', 'tua'],
             'tua: unknown real parameter of '),
            (['--fmu', str(lag_pump), *bags, '--workers', '2', '--free', 'tau'],
             '--fmu with --workers: one FMU is calibrated in this process (a fleet of them, '
             '--fleet, goes to a cluster)')]:
        assert cli.main(['calibrate', *args, '--report', str(tmp_path / 'r')]) == 2
        (err,) = capsys.readouterr().err.splitlines()
        assert err.startswith(f'error: {line}'), err


def test_a_parameter_whose_name_makes_no_ros_parameter_is_refused(recordings, params,
                                                                  tmp_path):
    """The calibrated file sets ``fmu_parameters.<name>``: a name no ROS parameter takes is
    refused before anything runs, in one line."""
    odd = fmus.PUMP.replace('        self.q = 0.0\n', "        self.q = 0.0\n"
                            "        setattr(self, 'dead-band', 0.1)\n"
                            "        self.register_variable(Real('dead-band', causality="
                            "Fmi2Causality.parameter, variability=Fmi2Variability.fixed))\n",
                            1)
    assert odd != fmus.PUMP
    path = fmus.build(tmp_path, 'odd_pump', odd)
    with pytest.raises(CalibrationError) as err:
        calibrate_fmu(path, recordings, params, ['tau', 'dead-band'])
    assert err.value.lines == ['dead-band: not a name a ROS parameter takes (letters, digits, '
                               '_ and dots): the calibrated file could not set it']
