"""``hydropump fmu``: the exported FMU (FMI 2.0 co-simulation, and 3.0 with ``--fmi 3``)
read and run by FMPy, as another tool would: its model description (units, ranges, FMPy's
validation), every output against ``simulate()`` stepped as the nodes step, a parameter set
through FMI against the same value set in the library, and the one-line refusals."""

import os
import subprocess
import sys

import numpy as np
import pytest

from hydropump_ctrl.fmi.export import export_fmu, FmuError
from hydropump_sim.circuit import load_circuit
from hydropump_sim.measure import SIGNALS
from hydropump_sim.simulate import IntegratorConfig, simulate

from .. import fmus
from ..conftest import ROOT

fmpy = pytest.importorskip('fmpy')
from fmpy.validation import validate_fmu  # noqa: E402

CIRCUITS = ROOT / 'config' / 'circuits'
DT = 1.0e-3
N = 400


def _run(path, inputs, params=None, n=N):
    """The FMU stepped ``n`` times by DT the way FMI 2.0 orders it: inputs of t_k set, a
    step to t_k+1, then the inputs of t_k+1 set before its outputs are read. ``inputs``:
    name -> array of n + 1 values; returns the outputs' names and values at t_0..t_n."""
    md = fmpy.read_model_description(str(path))
    outs = [v.name for v in md.modelVariables if v.causality == 'output']
    with fmus.opened(path) as (fmu, vr):
        fmu.enterInitializationMode()
        for name, value in (params or {}).items():
            fmu.setReal([vr[name]], [value])
        for name, u in inputs.items():
            fmu.setReal([vr[name]], [float(u[0])])
        fmu.exitInitializationMode()
        rows = [fmu.getReal([vr[o] for o in outs])]
        for k in range(n):
            for name, u in inputs.items():
                fmu.setReal([vr[name]], [float(u[k])])
            fmu.doStep(currentCommunicationPoint=k * DT, communicationStepSize=DT)
            for name, u in inputs.items():
                fmu.setReal([vr[name]], [float(u[k + 1])])
            rows.append(fmu.getReal([vr[o] for o in outs]))
        fmu.terminate()
    return outs, np.array(rows)


def _library(circuit_file, inputs, sets=None, n=N):
    """The same run through the library: ``simulate()`` stepped at every increment (as the
    simulator node steps), the measured signals by the suite's names."""
    c = load_circuit(circuit_file, sets)
    r = simulate(c, n * DT, inputs={k: v[:n] for k, v in inputs.items()}, dt_out=DT,
                 config=IntegratorConfig())
    measured = c.measured()
    return {name: r.y[:, c.signal_index(measured[name])] for name in SIGNALS
            if name in measured}


@pytest.fixture(scope='module')
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp('fmu')
    return {name: export_fmu(out / f'{name}.fmu', CIRCUITS / f'{name}.yaml', stop_time=0.5)
            for name in ('paper', 'fig1')}


@pytest.mark.parametrize('name', ['paper', 'fig1'])
def test_the_fmu_passes_validation_and_describes_its_variables_in_si(exported, name):
    done = exported[name]
    assert validate_fmu(str(done.path)) == []
    md = fmpy.read_model_description(str(done.path))
    c = load_circuit(CIRCUITS / f'{name}.yaml')
    by = {v.name: v for v in md.modelVariables}
    assert [v.name for v in md.modelVariables if v.causality == 'input'] == c.inputs
    assert [v.name for v in md.modelVariables if v.causality == 'output'] == \
        [s for s in SIGNALS if s in c.measured()] == list(done.outputs)
    for name_, info in SIGNALS.items():
        if name_ in by and info.unit != '-':
            assert by[name_].unit == info.unit
    current = by['pump.current']
    lo, hi = c.input_ranges[c.inputs.index('pump.current')]
    assert (current.unit, float(current.min), float(current.max)) == ('A', lo, hi)
    K_a = by['pump.spool.K_a']
    assert K_a.causality == 'parameter' and K_a.unit == 'N/m' and float(K_a.start) > 0
    assert md.defaultExperiment.stopTime == '0.5' or float(md.defaultExperiment.stopTime) \
        == 0.5
    assert md.coSimulation is not None and md.modelExchange is None


@pytest.mark.parametrize('name, inputs', [
    ('paper', {'pump.current': np.where(np.arange(N + 1) * DT >= 0.1 - 1e-9, 0.58, 0.5)}),
    ('fig1', {'boom.valve.command': np.where(np.arange(N + 1) * DT >= 0.05 - 1e-9, 0.8, 0.0),
              'pump.current': np.full(N + 1, 0.6)}),
])
def test_the_fmu_in_fmpy_equals_simulate_on_every_output(exported, name, inputs):
    """Every output at every 1 ms communication point within 1e-6 of its range of
    ``simulate()`` on the same held inputs; the run moves (a step a test can see)."""
    outs, got = _run(exported[name].path, inputs)
    want = _library(CIRCUITS / f'{name}.yaml', inputs)
    moved = 0
    for j, o in enumerate(outs):
        span = max(np.ptp(want[o]), 1e-9 * max(np.abs(want[o]).max(), 1e-300))
        np.testing.assert_allclose(got[:, j], want[o], rtol=0, atol=1e-6 * span,
                                   err_msg=f'{name}: {o}')
        moved += np.ptp(want[o]) > 1e-3 * np.abs(want[o]).max()
    assert moved >= 3


def _run3(path, inputs, tmp_path, n=N):
    """:func:`tests.fmus.run3` in a Python process of its own (its exit is judged too): the
    output names and values."""
    given, out = tmp_path / 'inputs.npz', tmp_path / 'outputs.npz'
    np.savez(given, **inputs)
    done = subprocess.run([sys.executable, '-m', 'tests.fmus', 'run3', str(path), str(given),
                           str(out), str(n)], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0 and 'written' in done.stdout, (done.returncode, done.stderr)
    with np.load(out) as f:
        return [str(x) for x in f['names']], f['values']


def test_an_fmi_3_fmu_passes_validation_and_equals_simulate(tmp_path):
    """``--fmi 3``: the paper's pump as an FMI 3.0 co-simulation FMU (PythonFMU3): FMPy's
    validation finds nothing, its variables carry SI units and ranges, and every output
    equals ``simulate()`` on a current step as the FMI 2.0 one does."""
    done = export_fmu(tmp_path / 'paper3.fmu', CIRCUITS / 'paper.yaml', stop_time=0.5, fmi=3)
    assert validate_fmu(str(done.path)) == []
    inputs = {'pump.current': np.where(np.arange(N + 1) * DT >= 0.1 - 1e-9, 0.58, 0.5)}
    outs, got = _run3(done.path, inputs, tmp_path)
    md = fmpy.read_model_description(str(done.path))
    assert md.fmiVersion == '3.0' and md.coSimulation is not None
    by = {v.name: v for v in md.modelVariables}
    c = load_circuit(CIRCUITS / 'paper.yaml')
    lo, hi = c.input_ranges[c.inputs.index('pump.current')]
    current = by['pump.current']
    assert (current.type, current.unit, float(current.min), float(current.max)) == \
        ('Float64', 'A', lo, hi)
    assert by['line_pressure'].unit == 'Pa' and by['pump.spool.K_a'].causality == 'parameter'
    assert outs == list(done.outputs)
    want = _library(CIRCUITS / 'paper.yaml', inputs)
    for j, o in enumerate(outs):
        span = max(np.ptp(want[o]), 1e-9 * max(np.abs(want[o]).max(), 1e-300))
        np.testing.assert_allclose(got[:, j], want[o], rtol=0, atol=1e-6 * span, err_msg=o)
    assert np.ptp(want['line_pressure']) > 1e5
    # PythonFMU3 0.3.4's library frees its interpreter state twice at a process's exit;
    # whether glibc notices (and aborts) depends on where the heap lies: without the FMU's
    # anchor instance (hydropump_fmu3.py) about one Python host in three aborted after
    # fmpy.simulate_fmu on this machine, none with it. Each host here must end cleanly (a
    # check of the exit, not a proof: the heap's layout moves with paths and hash seeds).
    for seed in ('4', '5'):
        ran = subprocess.run(
            [sys.executable, '-c', 'import sys, fmpy; fmpy.simulate_fmu(sys.argv[1], '
             'stop_time=0.05, step_size=1e-3, output_interval=1e-3)', str(done.path)],
            cwd=ROOT, capture_output=True, text=True, timeout=600,
            env=dict(os.environ, PYTHONHASHSEED=seed))
        assert ran.returncode == 0, (seed, ran.returncode, ran.stderr[-2000:])


def test_a_parameter_set_through_fmi_is_the_same_value_set_in_the_library(exported):
    """The line volume doubled through FMI before the initialisation ends: the pressure
    response is the library's with ``line.V`` doubled, and not the nominal one."""
    c = load_circuit(CIRCUITS / 'paper.yaml')
    V = 2.0 * c.volume['line']
    inputs = {'pump.current': np.where(np.arange(N + 1) * DT >= 0.05 - 1e-9, 0.58, 0.5)}
    outs, got = _run(exported['paper'].path, inputs, params={'line.V': V})
    big = _library(CIRCUITS / 'paper.yaml', inputs, {'line.V': V})['line_pressure']
    nominal = _library(CIRCUITS / 'paper.yaml', inputs)['line_pressure']
    p = got[:, outs.index('line_pressure')]
    np.testing.assert_allclose(p, big, rtol=0, atol=1e-6 * np.ptp(big))
    assert np.max(np.abs(p - nominal)) > 1e-3 * np.ptp(nominal)


def test_fmpy_runs_the_default_experiment(exported):
    """As a user runs an FMU: fmpy.simulate_fmu with its default experiment."""
    res = fmpy.simulate_fmu(str(exported['paper'].path))
    assert res['time'][-1] == pytest.approx(0.5)
    assert np.all(np.isfinite(res['line_pressure'])) and res['line_pressure'][0] > 1e6


def test_a_step_the_fmu_cannot_take_is_refused(exported):
    with fmus.opened(exported['paper'].path, 'odd') as (fmu, _):
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        with pytest.raises(Exception, match='fmi2DoStep'):
            fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1.5e-3)


def test_an_fmi_version_not_built_is_one_line(tmp_path):
    with pytest.raises(FmuError) as err:
        export_fmu(tmp_path / 'a.fmu', fmi=1)
    assert err.value.lines == ['--fmi 1: this suite builds FMI 2.0 and 3.0 co-simulation '
                               'FMUs (--fmi 2 or 3)']
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize('argv, line', [
    (['--out', '{tmp}/a.zip'], 'use a .fmu file name'),
    (['{tmp}/none.yaml', '--out', '{tmp}/a.fmu'], 'none.yaml'),
    (['--set', 'pump.spool.K_a=1', '--out', '{tmp}/a.fmu'],
     'error: pump.spool.K_a = 1 N/m: outside the accepted range'),
    (['--step', '0', '--out', '{tmp}/a.fmu'], '--step'),
])
def test_the_command_refuses_bad_input_in_one_line(tmp_path, argv, line):
    argv = [a.replace('{tmp}', str(tmp_path)) for a in argv]
    proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'fmu', *argv],
                          capture_output=True, text=True, timeout=300)
    errors = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and len(errors) == 1 and line in errors[0], proc.stderr
    assert 'Traceback' not in proc.stderr and not list(tmp_path.glob('*.fmu'))


def test_export_refuses_an_fmu_that_fmpy_would_not_load(tmp_path, monkeypatch):
    """What FMPy's validation finds is the export's error: no FMU is written."""
    import fmpy.validation
    monkeypatch.setattr(fmpy.validation, 'validate_fmu', lambda path: ['a made-up problem'])
    with pytest.raises(FmuError) as info:
        export_fmu(tmp_path / 'x.fmu')
    assert info.value.lines == [f'{tmp_path / "x.fmu"}: FMPy validation: a made-up problem']
    assert not list(tmp_path.iterdir())
