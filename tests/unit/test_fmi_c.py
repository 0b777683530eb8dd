"""FMUs of other tools, without ROS: the first-order pump of tests/fmus.py written in C against
the standard's headers (neither PythonFMU nor the suite), as an FMI 3.0 co-simulation FMU
(its lag integrated exactly over each step) and as an FMI 2.0 model-exchange FMU (its
equations only, integrated by the suite, with a time event between communication points):
read and checked, stepped as the simulator's plant against their closed form, failing with
their own message, and calibrated from recordings made in closed form with noise."""

import json

import numpy as np
import pytest

from hydropump_ctrl import cli
from hydropump_ctrl.fmi.calibration import calibrate_fmu
from hydropump_ctrl.fmi.plant import FmuSimulator
from hydropump_ctrl.fmi.reading import read_fmu
from hydropump_sim.simulate import IntegrationError

from .. import fmus
from .test_fmi_calibration import GAIN, recordings, TAU  # noqa: F401 (a fixture)

pytest.importorskip('fmpy')


def _run(sim, currents, signal='line_flow'):
    j = sim.model.signal_index(signal)
    out = []
    for i in currents:
        sim.set_input('current', i)
        sim.step()
        out.append(sim.outputs()[j])
    return np.array(out)


def test_an_fmi_3_fmu_is_read_with_its_float64_variables(pump3, capsys):
    info = read_fmu(pump3, inputs=['current'], outputs=['line_flow'])
    assert info.fmi_version == '3.0' and info.model_identifier == 'lag_pump3'
    v = info.variables
    assert [n for n in v if v[n].real] == ['time', 'current', 'line_flow', 'line_pressure',
                                           'tau', 'gain', 'fail_after']
    assert (v['tau'].causality, v['tau'].unit, v['tau'].min, v['tau'].max) == \
        ('parameter', 's', 1e-3, 1.0)
    assert cli.main(['fmu', '--check', str(pump3)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f'{pump3}: FMI 3.0 co-simulation, model lag_pump3')
    assert 'line_pressure' in out and 'tau' in out


def test_the_plant_steps_an_fmi_3_fmu_as_its_closed_form(pump3, params):
    currents = np.where(np.arange(150) < 40, 0.5, 0.64)
    sim = FmuSimulator(pump3, params, 1.0e-3)
    try:
        assert sim.model.plant_inputs() == {'current': 'current'}
        assert sim.model.parameters() == {'tau': 0.02, 'gain': 1.0e-3, 'fail_after': 0.0}
        flow = _run(sim, currents)
        np.testing.assert_allclose(flow, fmus.lag_closed_form(currents)[1:], rtol=1e-12)
        assert np.ptp(flow) > 1e-4
        # A parameter set by name applies from the next reset (FMI 3.0 sets it in the
        # instantiated state, before the initialisation): the closed form with that lag.
        sim.set_parameters({'tau': 0.05})
        sim.reset(inputs={'current': 0.5})
        flow = _run(sim, currents)
        np.testing.assert_allclose(flow, fmus.lag_closed_form(currents, tau=0.05)[1:],
                                   rtol=1e-12)
    finally:
        sim.close()


@pytest.mark.parametrize('fmu, fail_after, call', [('pump3', 0.002, 'fmi3DoStep'),
                                                   ('pump_me', 0.0025, 'CVode')])
def test_a_failing_step_is_the_fmus_own_message(fmu, fail_after, call, params, request):
    """The FMI 3.0 pump fails its step, the model-exchange one its derivatives, past
    ``fail_after``: the third step ends with the FMU's own message."""
    sim = FmuSimulator(request.getfixturevalue(fmu), params)
    try:
        sim.set_parameters({'fail_after': fail_after})
        sim.reset()
        sim.step()
        sim.step()
        with pytest.raises(IntegrationError) as info:
            sim.step()
        assert str(info.value) == (f'the FMU failed in {call} at t = 0.002 s of simulation '
                                   'time: the pump model diverged (made to, for the test)')
    finally:
        sim.close()


def test_an_fmi_3_fmu_is_calibrated_to_the_closed_form(pump3, recordings, params):  # noqa: F811
    """The recordings of the FMI 2.0 calibration test (the exact lag with noise, gain and
    time constant 20 % and 25 % off the FMU's starts): recovered within 2 %, the truth in
    the intervals (this FMU's lag is exact, so no integrator bias is left)."""
    cal = calibrate_fmu(pump3, recordings, params, ['gain', 'tau'])
    est = {p.name: p for p in cal.estimates}
    for name, truth in (('gain', GAIN), ('tau', TAU)):
        assert est[name].value == pytest.approx(truth, rel=0.02)
        assert est[name].ci95[0] <= truth <= est[name].ci95[1], name
    assert all(p.well_determined for p in cal.estimates)
    assert cal.improved and cal.cost < 0.01 * cal.cost_start


def test_a_model_exchange_fmu_is_read_as_integrated_by_the_suite(pump_me, capsys):
    info = read_fmu(pump_me, inputs=['current'], outputs=['line_flow', 'line_pressure'])
    assert info.model_exchange and info.fmi_version == '2.0'
    assert cli.main(['fmu', '--check', str(pump_me)]) == 0
    assert capsys.readouterr().out.startswith(
        f'{pump_me}: FMI 2.0 model exchange (integrated by the suite), model lag_pump_me')


def test_the_plant_integrates_a_model_exchange_fmu_through_its_time_event(pump_me, params):
    """CVode between communication points, the FMU's time event (its gain doubled at
    30.5 ms, between two of them) at its instant: the closed form within 1e-4 of the
    flow's range, where the event taken at the next communication point instead would be
    off by 1.8 %; the current's step at 20 ms restarts the integration."""
    currents = np.where(np.arange(100) < 20, 0.5, 0.64)
    sim = FmuSimulator(pump_me, params, 1.0e-3)
    try:
        sim.set_parameters({'t_switch': 0.0305})
        sim.reset(inputs={'current': 0.5})
        flow = _run(sim, currents)
        truth = fmus.lag_closed_form(currents, t_switch=0.0305)[1:]
        span = np.ptp(truth)
        assert np.max(np.abs(flow - truth)) < 1e-4 * span
        late = fmus.lag_closed_form(currents, t_switch=0.031)[1:]
        assert np.max(np.abs(late - truth)) > 0.01 * span
        assert sim.t == pytest.approx(0.1)
        # The pressure output follows the same state (2 MPa + 8e9 q, gauge, as published).
        sim.reset(inputs={'current': 0.5})
        pressure = _run(sim, currents, 'line_pressure')
        assert np.max(np.abs(pressure - (2.0e6 + 8.0e9 * truth))) < 1e-4 * 8.0e9 * span
    finally:
        sim.close()


def test_a_time_event_on_a_communication_point_far_into_a_run(pump_me, params):
    """The FMU takes its event where its time is at least the event's, with no tolerance;
    the node's clock, a sum of 1 ms steps, lands a few ulps off 1.01 s: the event is still
    taken at its instant, and the run goes on as the closed form."""
    currents = np.full(1100, 0.6)
    sim = FmuSimulator(pump_me, params, 1.0e-3)
    try:
        sim.set_parameters({'t_switch': 1.01})
        sim.reset(inputs={'current': 0.6})
        flow = _run(sim, currents)
    finally:
        sim.close()
    truth = fmus.lag_closed_form(currents, t_switch=1.01)[1:]
    assert np.max(np.abs(flow - truth)) < 1e-4 * np.ptp(truth)
    assert flow[-1] > 1.9 * flow[1000]


def test_the_plant_finds_a_model_exchange_fmus_state_event(pump_me, params):
    """The end stop (an event indicator crossing zero between communication points, 25 ms
    after the current's step at 20 ms): the flow meets q_max at that instant and never
    passes it, leaves it when the current falls back at 70 ms, the closed form within 1e-4
    of the range throughout."""
    q_max = 3.0e-4
    currents = np.select([np.arange(120) < 20, np.arange(120) < 70], [0.5, 0.64], 0.5)
    sim = FmuSimulator(pump_me, params, 1.0e-3)
    try:
        sim.set_parameters({'q_max': q_max})
        sim.reset(inputs={'current': 0.5})
        flow = _run(sim, currents)
    finally:
        sim.close()
    truth = fmus.lag_closed_form(currents, q_max=q_max)[1:]
    assert np.max(np.abs(flow - truth)) < 1e-4 * np.ptp(truth)
    assert flow.max() <= q_max * (1 + 1e-9)
    at_stop = np.flatnonzero(flow >= q_max * (1 - 1e-9))
    assert at_stop[0] == 45 and at_stop[-1] == 69           # met at 45.06 ms, left at 70 ms
    assert flow[-1] < 0.8 * q_max


def test_a_model_exchange_fmu_is_calibrated_to_the_closed_form(pump_me, recordings,  # noqa: F811
                                                                params):
    """CVode is adaptive: the sensitivities are forward differences of whole runs, and the
    fit still recovers the gain and time constant within 2 %."""
    cal = calibrate_fmu(pump_me, recordings, params, ['gain', 'tau'])
    est = {p.name: p for p in cal.estimates}
    for name, truth in (('gain', GAIN), ('tau', TAU)):
        assert est[name].value == pytest.approx(truth, rel=0.02)
    assert cal.improved and cal.cost < 0.01 * cal.cost_start


def test_a_fleet_of_pumps_calibrates_one_fmu(pump3, params, tmp_path, capsys):
    """``calibrate --fmu --fleet``: the FMU goes to each task as bytes, as it goes to a
    cluster's workers (here the tasks run in this process), each pump's gain and time
    constant (other for each) within 2 % of its truth, a params file of the simulator node
    per pump, one table."""
    import yaml
    truth = {'pump_a': (1.2e-3, 0.025), 'pump_b': (0.9e-3, 0.03)}
    designs = ([0.4, 0.6, 0.8, 0.5], [0.6, 0.45, 0.65, 0.35])
    # A third pump whose bags hardly move its current: its time constant is not determined
    # (a weak direction, flagged), and the fleet goes on.
    for k, (name, (gain, tau), levels) in enumerate([
            *((n, g, designs) for n, g in truth.items()),
            ('pump_weak', (1.0e-3, 0.02), ([0.5, 0.503], [0.5, 0.503]))]):
        (tmp_path / 'fleet' / name).mkdir(parents=True)
        for j, design in enumerate(levels):
            fmus.lag_recording(design, params.fluid.p_atm, 10 * k + j, gain=gain, tau=tau).save(
                tmp_path / 'fleet' / name / f'run{j}.npz')
    report = tmp_path / 'report'
    assert cli.main(['calibrate', '--fmu', str(pump3), '--fleet', str(tmp_path / 'fleet'),
                     '--free', 'gain', 'tau', '--in-process', '--report', str(report),
                     '--no-plots', '--json', '--no-progress']) == 0
    result = json.loads(capsys.readouterr().out)
    for name, (gain, tau) in truth.items():
        got = result[name]['parameters']
        assert got['gain']['value'] == pytest.approx(gain, rel=0.02), name
        assert got['tau']['value'] == pytest.approx(tau, rel=0.02), name
        node = yaml.safe_load((report / name / 'calibrated.yaml').read_text())
        node = node['/**']['ros__parameters']
        assert node['fmu_file'] == str(pump3.resolve())
        assert node['fmu_parameters']['tau'] == pytest.approx(tau, rel=0.02)
    assert (report / 'fleet.csv').is_file()
    assert not result['pump_weak']['parameters']['tau']['well_determined']
