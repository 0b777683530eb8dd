"""A user's FMU as the simulator's plant, without ROS: the stepper the node uses
(hydropump_ctrl.fmi.plant) on a first-order pump FMU this suite did not write, against FMPy
running it alone; the names it needs; a failing step's own message; the simulator's Runner
publishing what the FMU computes."""

from pathlib import Path

import numpy as np
import pytest

from hydropump_ctrl.fmi.export import FmuError
from hydropump_ctrl.fmi.plant import FmuSimulator, topic_of
from hydropump_sim.runner import Runner
from hydropump_sim.simulate import IntegrationError

from .. import fmus

fmpy = pytest.importorskip('fmpy')
pytest.importorskip('pythonfmu')


@pytest.fixture(scope='module')
def lag_pump(tmp_path_factory):
    return fmus.lag_pump(tmp_path_factory.mktemp('lag'))


def _alone(path, currents, dt=1.0e-3):
    """FMPy alone: each current held over its step, the line flow after each."""
    return fmus.alone(path, currents, dt)[1:]


def test_the_stepper_is_the_fmu_run_alone(lag_pump, params):
    currents = np.where(np.arange(120) < 30, 0.5, 0.62)
    sim = FmuSimulator(lag_pump, params, 1.0e-3)
    try:
        assert sim.model.plant_inputs() == {'current': 'current'}
        assert sim.model.measured() == {'line_flow': 'line_flow',
                                        'line_pressure': 'line_pressure'}
        assert sim.model.parameters() == {'tau': 0.02, 'gain': 1.0e-3, 'noise': 0.0,
                                          'fail_after': 0.0, 'substeps': 10.0}
        flow = []
        for i in currents:
            sim.set_input('current', i)
            sim.step()
            flow.append(sim.outputs()[sim.model.signal_index('line_flow')])
        np.testing.assert_array_equal(flow, _alone(lag_pump, currents))
        assert sim.t == pytest.approx(0.12) and flow[-1] > flow[0]
        # A reset goes back to the FMU's start at the held inputs.
        sim.reset()
        assert sim.t == 0.0
        assert sim.outputs()[0] == pytest.approx(1.0e-3 * (0.62 - 0.3))
    finally:
        sim.close()


def test_parameters_set_before_the_initialisation_change_the_run(lag_pump, params):
    """A parameter set by name applies from the next reset (FMI 2.0 sets them before the
    initialisation): the FMU starts settled at its closed-form flow, gain (I - 0.3)."""
    sim = FmuSimulator(lag_pump, params, 1.0e-3)
    try:
        q = sim.model.signal_index('line_flow')
        sim.reset({'current': 0.7})
        assert sim.outputs()[q] == pytest.approx(1.0e-3 * 0.4, rel=1e-12)
        sim.set_parameters({'gain': 2.5e-3})
        assert sim.outputs()[q] == pytest.approx(1.0e-3 * 0.4, rel=1e-12)   # not yet
        sim.reset()
        assert sim.outputs()[q] == pytest.approx(2.5e-3 * 0.4, rel=1e-12)
        sim.step()
        assert sim.outputs()[q] == pytest.approx(2.5e-3 * 0.4, rel=1e-12)   # settled
        with pytest.raises(FmuError) as err:
            sim.set_parameters({'gian': 1.0})
        assert err.value.lines == ['gian: unknown real parameter of lag_pump.fmu (did you '
                                   'mean gain?)']
    finally:
        sim.close()


def test_the_runner_publishes_what_the_fmu_computes(lag_pump, params):
    """The simulator node's core (Runner) on the FMU: ideal sensors, the measured signals
    the FMU has and its every output on fmu/<name>."""
    from .test_runner import cfg, run, Sink, still
    sim = FmuSimulator(lag_pump, params, 1.0e-3)
    runner = Runner(sim, cfg(real_time_factor=0.0, initial_current=0.55), **still())
    sink = Sink(runner, 50)
    try:
        runner.command(0.55)
        run(runner, sink)
    finally:
        sim.close()
    frames = sink.frames
    assert sorted(frames[-1].signals) == ['line_flow', 'line_pressure']
    want = _alone(lag_pump, np.full(50, 0.55))
    got = [f.signals['line_flow'] for f in frames]
    np.testing.assert_allclose(got, want[:len(got)], rtol=1e-12)
    assert frames[-1].extra['fmu/line_pressure'] == frames[-1].signals['line_pressure']


def test_an_fmu_that_cannot_be_the_plant_says_what_it_lacks(tmp_path, params):
    path = fmus.build(tmp_path, 'Orifice', fmus.ORIFICE)
    with pytest.raises(FmuError) as info:
        FmuSimulator(path, params)
    assert info.value.lines == [
        f'{path}: no input current or pump.current (the solenoid current [A] the controller '
        'commands; its inputs: pressure)',
        f'{path}: no output named after a measured signal of the suite (solenoid_current, '
        'pump_flow, line_flow, load_flow, actuator_pressure, line_pressure, load_pressure, '
        'spool_position, actuator_position); its outputs: flow']


def test_a_failing_step_is_the_fmus_own_message(tmp_path, params):
    sim = FmuSimulator(fmus.lag_pump(tmp_path, 'failing', fail_after=0.003), params)
    try:
        for _ in range(3):
            sim.step()
        with pytest.raises(IntegrationError) as info:
            sim.step()
        assert str(info.value) == ('the FMU failed in fmi2DoStep at t = 0.003 s of simulation '
                                   'time: the pump model diverged (made to, for the test)')
    finally:
        sim.close()


@pytest.mark.parametrize('name, topic', [('line_flow', 'fmu/line_flow'),
                                         ('pump.x_c', 'fmu/pump/x_c'),
                                         ('der(x)', None), ('1st', None), ('a..b', None)])
def test_an_output_name_makes_a_topic_or_none(name, topic):
    assert topic_of(name) == topic


def test_only_real_variables_meet_the_suite(tmp_path, params):
    """FMI 2.0 counts value references per type: a Boolean input is left at its start,
    never written as a Real."""
    flag = ("        self.enabled = True\n"
            "        self.register_variable(Boolean('enabled', causality=Fmi2Causality.input,\n"
            "                                       variability=Fmi2Variability.discrete))\n")
    source = fmus.PUMP.replace('        self.q = 0.0\n', '        self.q = 0.0\n' + flag, 1) \
        .replace('Fmi2Variability, Real', 'Fmi2Variability, Real, Boolean')
    path = fmus.build(tmp_path, 'with_flag', source)
    sim = FmuSimulator(path, params)
    try:
        assert sim.model.info.variables['enabled'].type == 'Boolean'
        assert sim.model.inputs == ['current']
        sim.set_input('current', 0.6)
        for _ in range(5):
            sim.step()
        assert sim.outputs()[sim.model.signal_index('line_flow')] > 1.0e-3 * (0.5 - 0.3)
    finally:
        sim.close()


def test_a_binary_that_does_not_load_is_one_line_and_leaves_nothing(tmp_path, params,
                                                                    lag_pump, monkeypatch):
    import zipfile
    broken = tmp_path / 'broken.fmu'
    with zipfile.ZipFile(lag_pump) as zin, zipfile.ZipFile(broken, 'w') as zout:
        for e in zin.infolist():
            zout.writestr(e, b'not a library' if e.filename.endswith('.so') else zin.read(e))
    unpacked = []
    real = fmpy.extract
    monkeypatch.setattr(fmpy, 'extract', lambda *a, **k: unpacked.append(real(*a, **k))
                        or unpacked[-1])
    with pytest.raises(FmuError) as info:
        FmuSimulator(broken, params)
    assert len(info.value.lines) == 1
    assert info.value.lines[0].startswith(f'{broken}: cannot load or instantiate it: ')
    assert unpacked and not any(Path(d).exists() for d in unpacked)
    assert Path.cwd().exists()          # FMPy left the process in the library's folder
