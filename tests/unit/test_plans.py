"""Recording plans (``hydropump record``): the standard campaign's held inputs against its
definition, the example file, the parser's one-line errors and warnings, what the node graph
is given, and the command's checks before any node starts."""

import math

import numpy as np
import pytest
import yaml

from hydropump_ctrl import cli
from hydropump_ctrl.cli import record as record_cli
from hydropump_ctrl.control.schema import load_config
from hydropump_ctrl.demo.campaign import closed_loop_experiments, identification_experiments
from hydropump_ctrl.ident.design import candidate_inputs
from hydropump_ctrl.plans import (
    example_plan_path,
    EXCITATION_BASE,
    held_inputs,
    load_plan,
    node_experiment,
    parse_plan,
    PlanError,
    standard_plan,
)

from ..conftest import ROOT

STAIRS = {'name': 'stairs', 'duration': 1.0,
          'current': {'staircase': {'levels': [40, 60, 50], 'dwell': 0.3}, 'unit': 'percent'}}


def _errors(doc, params):
    with pytest.raises(PlanError) as info:
        parse_plan(doc, params, source='plan.yaml')
    return info.value.lines


# ---- the standard campaign ------------------------------------------------------------------

def test_standard_plan_holds_its_definition(params):
    """Staircases of the range's middle +- 10 and 20 % of the range, 1 s a level, up, down,
    and up and down at 40 bar less; the load stepped 120 -> 80 -> 120 bar at the middle; the
    held-out sine with a load step. Absolute A and gauge Pa, per 1 ms sample."""
    lo, hi = params.current_range
    mid, span = 0.5 * (lo + hi), hi - lo
    up = [mid + f * span for f in (-0.2, -0.1, 0.0, 0.1, 0.2)]
    P_u, low = params.line.P_u, params.line.P_u - 4.0e6
    plan = standard_plan(params)
    assert [e.name for e in plan.experiments] == [
        'staircase_up', 'staircase_down', 'staircases_low_load', 'load_steps', 'sine_load_step']
    assert plan.held_out == ['sine_load_step']
    held = {e.name: held_inputs(e, params) for e in plan.experiments}

    def stairs(levels):
        return np.repeat(levels, 1000)
    expected = {
        'staircase_up': (stairs(up), np.full(5000, P_u)),
        'staircase_down': (stairs(up[::-1]), np.full(5000, P_u)),
        'staircases_low_load': (stairs(up + up[::-1][1:]), np.full(9000, low)),
        'load_steps': (np.full(3000, mid), np.repeat([P_u, low, P_u], 1000)),
    }
    for name, (current, load) in expected.items():
        h = held[name]
        assert h.t.size == current.size and h.t[1] == pytest.approx(1e-3)
        np.testing.assert_allclose(h.current, current, rtol=0, atol=1e-12, err_msg=name)
        np.testing.assert_array_equal(h.load_pressure, load, err_msg=name)
    sine = held['sine_load_step']
    # The controller's sine, sampled at its 5 ms updates and held between them.
    tk = np.floor(sine.t / 0.005 + 1e-6) * 0.005
    np.testing.assert_allclose(sine.current, mid + 0.15 * span * np.sin(np.pi * tk), atol=1e-12)
    np.testing.assert_array_equal(sine.load_pressure, np.repeat([P_u, low], 2000))


def test_the_calibration_candidates_are_the_standard_plan(params):
    """The calibration's candidate experiments (ident.design) are the plan's four, at the
    levels eq. 2 and eq. 10 give: the regulating range's middle +- 10 and 20 % of it."""
    lo, hi = params.current_range
    mid, span = 0.5 * (lo + hi), hi - lo
    up = [mid + f * span for f in (-0.2, -0.1, 0.0, 0.1, 0.2)]
    cand = candidate_inputs(params)
    assert list(cand) == ['staircase up', 'staircase down',
                          'staircases at a lower load pressure', 'load-pressure steps']
    np.testing.assert_allclose(cand['staircase up']['current'], np.repeat(up, 1000),
                               atol=1e-12)
    np.testing.assert_allclose(cand['staircase down']['current'], np.repeat(up[::-1], 1000),
                               atol=1e-12)
    low = params.line.P_u - 4e6
    np.testing.assert_array_equal(
        cand['staircases at a lower load pressure']['load_pressure'], np.full(9000, low))
    np.testing.assert_array_equal(cand['load-pressure steps']['load_pressure'],
                                  np.repeat([params.line.P_u, low, params.line.P_u], 1000))
    np.testing.assert_allclose(cand['load-pressure steps']['current'], mid, atol=1e-12)


def test_the_example_file_is_the_standard_plan(params):
    path = example_plan_path()
    assert path == ROOT / 'config' / 'plans' / 'calibration.yaml'
    from_file, standard = load_plan(path, params), load_plan('standard', params)
    assert from_file.warnings == standard.warnings == []
    for a, b in zip(from_file.experiments, standard.experiments, strict=True):
        assert (a.name, a.label, a.held_out, a.duration) == (b.name, b.label, b.held_out,
                                                             b.duration)
        ha, hb = held_inputs(a, params), held_inputs(b, params)
        np.testing.assert_allclose(ha.current, hb.current, atol=1e-12)
        np.testing.assert_array_equal(ha.load_pressure, hb.load_pressure)


# ---- a plan file ----------------------------------------------------------------------------

def test_a_plan_file_parses_into_si_experiments(params, tmp_path):
    path = tmp_path / 'plan.yaml'
    path.write_text(yaml.safe_dump([
        STAIRS | {'load_pressure': [[0.5, 9.0e6]], 'seed': 4},
        {'name': 'check', 'duration': 0.8, 'held_out': True, 'aperture': [[0.2, 0.4]],
         'current': {'offset': 0.5, 'sine': {'amplitude': 0.05, 'frequency': 2.0}}}]))
    plan = load_plan(path, params)
    assert plan.warnings == [] and plan.held_out == ['check']
    stairs, check = plan.experiments
    assert stairs.load_pressure == ((0.5, 9.0e6),) and stairs.noise_seed == 4
    assert check.current.unit == 'A' and check.aperture == ((0.2, 0.4),)
    assert check.noise_seed == load_plan(path, params).experiments[1].noise_seed != 4
    h = held_inputs(stairs, params, dt=0.005)
    lo, hi = params.current_range
    levels = lo + (hi - lo) * np.array([0.4, 0.6, 0.5])
    np.testing.assert_allclose(h.current, np.repeat(levels, [60, 60, 80]), atol=1e-12)
    np.testing.assert_array_equal(h.load_pressure, np.repeat([params.line.P_u, 9.0e6],
                                                             [100, 100]))


@pytest.mark.parametrize('change, expected', [
    ({'held-out': True}, 'experiment 1 (stairs): held-out: unknown key (did you mean '
                         'held_out?); accepted: name, label, duration'),
    ({'current': {'staircase': {'levels': [40], 'dwel': 1.0}}},
     'experiment 1 (stairs): current.staircase.dwel: unknown key (did you mean dwell?); use '
     'levels, dwell'),
    ({'current': {'staircase': {'levels': [40]}}},
     'experiment 1 (stairs): current.staircase: missing dwell (a staircase takes levels, '
     'dwell)'),
    ({'duration': -1.0}, 'experiment 1 (stairs): duration = -1.0: expected a finite number > 0'
                         ' (s)'),
    ({'duration': math.nan}, 'experiment 1 (stairs): duration = nan: expected a finite number'),
    ({'duration': '1.5e1'}, "duration = '1.5e1': expected a finite number > 0 (s) (YAML read "
                            'it as text'),
    ({'current': {'staircase': {'levels': [0.5, 1.2], 'dwell': 0.3}}},
     "experiment 1 (stairs): current.staircase.levels[1] = 1.2 A: outside the plant's current "
     'range of eq. 2, [0.1, 0.9] A'),
    ({'current': {'staircase': {'levels': [40, 120], 'dwell': 0.3}, 'unit': 'percent'}},
     'experiment 1 (stairs): current.staircase.levels[1] = 120 %: outside [0, 100] % of '
     'displacement'),
    ({'current': {'steps': [[0, 0.5], [0.5, 0.95]]}},
     "experiment 1 (stairs): current.steps[1] value = 0.95 A: outside the plant's current"),
    ({'current': {'offset': 0.85, 'sine': {'amplitude': 0.1, 'frequency': 1.0}}},
     "current.offset + amplitude = 0.95 A: outside the plant's current range of eq. 2"),
    ({'current': {'ramp': [[0, 0.5], [0.5, 0.6]]}},
     'experiment 1 (stairs): current.ramp: not here; use steps, staircase, step, offset'),
    ({'current': {'steps': [[0, 0.5], [0.5, 0.6]], 'sine': {'amplitude': 0.1,
                                                           'frequency': 1.0}}},
     'current.sine: the controller runs a sine of amplitude and frequency > 0 about a '
     'constant offset'),
    ({'current': {'staircase': {'levels': [0.5, 0.6], 'dwell': 0.001}}},
     "current.staircase.dwell: 0.001 s between levels, shorter than the controller's update "
     'period (0.005 s)'),
    ({'current': {**STAIRS['current'], 'unit': '%'}},
     "current.unit = '%': expected A or percent (percent of displacement)"),
    ({'current': None}, 'experiment 1 (stairs): current: missing (a staircase:'),
    ({'load_pressure': [[0.5, 80]]},
     ('experiment 1 (stairs): load_pressure[0] value = 80 Pa: outside the accepted range '
      '[10000, 4.5e+07] Pa (', '(looks like a value in bar: 80 bar = 8e+06 Pa)')),
    ({'load_pressure': [[0.5, 9e6], [0.2, 8e6]]},
     'experiment 1 (stairs): load_pressure: times must increase (0.5, 0.2 s)'),
    ({'aperture': [[1.0, 0.4]]},
     'experiment 1 (stairs): aperture[0] time = 1 s: at or after the end of the experiment'),
    ({'aperture': [[0.2, 1.5]]}, 'experiment 1 (stairs): aperture[0] value = 1.5'),
    ({'aperture': [0.2, 0.4]}, 'experiment 1 (stairs): aperture: expected [[t, value], ...]'),
    ({'load_pressure': {'offset': 1.0e7, 'sine': {'amplitude': 5.0e6, 'frequency': 1.0}}},
     'experiment 1 (stairs): load_pressure.sine: not here; use steps, offset (no sine)'),
    ({'current': {'offset': 0.5, 'sine': {'amplitude': -0.05, 'frequency': 1.0}}},
     'current.sine: the controller runs a sine of amplitude and frequency > 0'),
    ({'current': {'shape': [1], 'levels': [1], 'dwell': 1.0}},
     'experiment 1 (stairs): current.shape = [1]: expected staircase or sine'),
    ({'name': 'a/b'}, "experiment 1 (a/b): name = 'a/b': use letters, digits, _ . -"),
    ({'name': 'logs'}, "name = 'logs': taken by the folder of the nodes' logs"),
    ({'seed': -3}, 'experiment 1 (stairs): seed = -3: expected an integer in [0, 2147483647]'),
    ({'held_out': 'yes'}, "held_out = 'yes': expected true or false"),
])
def test_a_bad_plan_is_one_line_naming_the_experiment_and_the_field(params, change, expected):
    lines = _errors([STAIRS | change], params)
    parts = expected if isinstance(expected, tuple) else (expected,)
    assert len(lines) == 1 and all(p in lines[0] for p in parts), lines


def test_every_problem_of_a_plan_at_once_and_duplicate_names(params):
    lines = _errors([STAIRS, STAIRS | {'duration': 0}, {'duration': 1}, 'x'], params)
    assert lines == [
        "experiment 2 (stairs): name: 'stairs' is the name of experiment 1 too; each "
        'experiment needs its own (it names the bag)',
        'experiment 2 (stairs): duration = 0: expected a finite number > 0 (s)',
        'experiment 3: name: missing (the bag name: letters, digits, _ . -)',
        'experiment 3: current: missing (a staircase: {staircase: {levels: [...], dwell: '
        '1.0}, unit: percent}, or a sine: {offset: 0.5, sine: {amplitude, frequency}, unit: '
        'A})',
        'experiment 4: expected a mapping (name: ..., duration: ..., current: ...)']
    assert _errors({'name': 'x'}, params) == [
        'expected a list of experiments (- name: ..., duration: ..., current: {...})']


def test_what_runs_but_looks_unmeant_is_a_warning(params):
    plan = parse_plan([STAIRS | {'duration': 0.5, 'aperture': [[0.123, 0.4]]}], params)
    assert plan.warnings == [
        'no experiment is held out (held_out: true): a calibration on every bag leaves none '
        'to validate on',
        'experiment stairs: duration 0.5 s ends before the last level: 1 of 3 levels are never '
        'reached',
        'experiment stairs: aperture[0] time = 0.123 s is not a whole number of control '
        'periods (0.005 s): it takes effect at 0.125 s']
    h = held_inputs(plan.experiments[0], params)
    assert h.aperture[124] == params.line.xi_u and h.aperture[125] == 0.4


# ---- through the nodes ----------------------------------------------------------------------

def _apply_one_at_a_time(config, values):
    """As the controller takes a parameter set: one at a time, each checked with the rest."""
    for name, value in values.items():
        config = config.replace({name: value})
    return config


def test_node_experiment_schedules_each_level_at_its_control_instant(params):
    plan = parse_plan([STAIRS | {'load_pressure': [[0.0, 9e6], [0.5, 1e7]], 'held_out': True}],
                      params)
    exp = node_experiment(plan.experiments[0], params)
    lo, hi = params.current_range
    a40, a60, a50 = (lo + (hi - lo) * f for f in (0.4, 0.6, 0.5))
    assert exp.sim['initial_current'] == pytest.approx(a40)
    assert exp.sim['line.P_u'] == 9e6 and exp.ctrl['excitation.repeat'] is False
    assert exp.ctrl['excitation.levels_min'] == pytest.approx(a40)
    assert [(t, node, list(v)) for t, node, v in exp.events] == [
        (pytest.approx(0.3), 'controller', ['excitation.levels_min']),
        (pytest.approx(0.6), 'controller', ['excitation.levels_min']),
        (0.5, 'simulator', ['line.P_u'])]
    assert [v['excitation.levels_min'] for _, _, v in exp.events[:2]] == \
        pytest.approx([a60, a50])


def test_every_experiment_passes_the_controller_checks_from_any_before(params):
    """The controller checks each parameter against the others as it comes: a plan's
    excitation (in A) must pass after the file's defaults (levels 20..80 %), after the demo's
    experiments and after each other."""
    plans = standard_plan(params).experiments + parse_plan([
        STAIRS | {'held_out': True},
        {'name': 's', 'duration': 1, 'current': {'offset': 0.5, 'unit': 'A', 'sine': {
            'amplitude': 0.1, 'frequency': 3.0}}}],
        params).experiments
    ours = [node_experiment(e, params) for e in plans]
    demo = identification_experiments(params, 3) + closed_loop_experiments(params)
    start = load_config(ROOT / 'config' / 'controller.yaml')
    for before in [None] + ours + demo:
        config = start if before is None else _apply_one_at_a_time(
            _apply_one_at_a_time(start, before.ctrl_first), before.ctrl)
        for exp in ours + demo:
            done = _apply_one_at_a_time(_apply_one_at_a_time(config, exp.ctrl_first), exp.ctrl)
            for _, node, values in exp.events:
                if node == 'controller':
                    done = _apply_one_at_a_time(done, values)
    assert set(EXCITATION_BASE) <= set(ours[0].ctrl_first)


# ---- the command, before any node starts ---------------------------------------------------

def _plan_file(tmp_path, doc=None):
    path = tmp_path / 'plan.yaml'
    path.write_text(yaml.safe_dump(doc or [STAIRS | {'held_out': True}]))
    return str(path)


def test_record_check_prints_the_plan_without_ros(capsys, monkeypatch):
    monkeypatch.setattr(record_cli, 'runner', lambda name: pytest.fail('no ROS for --check'))
    assert cli.main(['record', 'standard', '--check']) == 0
    out, err = capsys.readouterr()
    assert err == '' and out.splitlines()[0] == 'standard: 5 experiments, 26 s simulated'
    assert 'sine_load_step' in out and 'held out' in out


@pytest.mark.parametrize('argv, expected', [
    (['--out', '{file}'], '--out {file}: is a file; give a folder for the bags'),
    (['--out', '{full}'], '--out {full}: already holds stairs (bags of an earlier run?)'),
    ([], '--out DIR is needed: the folder the bags go to'),
    (['--out', '{dir}/o', '--attach', '--profile', 'config/bench.yaml'],
     '--params and --profile set up the graph that record starts; with --attach'),
    (['--out', '{dir}/o', '--params', '{dir}/none.yaml'], '--params {dir}/none.yaml: no such'),
    (['--out', '{dir}/o', '--attach', '--wait', 'nan'], '--wait nan: expected a finite number'),
])
def test_record_refuses_bad_options_in_one_line(tmp_path, capsys, argv, expected):
    plan = _plan_file(tmp_path)
    (tmp_path / 'file').write_text('')
    (tmp_path / 'full' / 'stairs').mkdir(parents=True)
    names = {'file': tmp_path / 'file', 'full': tmp_path / 'full', 'dir': tmp_path}
    argv = [a.format(**names) for a in argv]
    assert cli.main(['record', plan, *argv]) == 2
    out, err = capsys.readouterr()
    assert len(err.splitlines()) == 1 and expected.format(**names) in err, err
    assert 'hydropump record' not in out   # nothing started


def test_record_refuses_an_output_it_cannot_write(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(record_cli.os, 'access', lambda path, mode: False)
    assert cli.main(['record', _plan_file(tmp_path), '--out', str(tmp_path / 'a' / 'b')]) == 2
    assert capsys.readouterr().err == (f'error: --out {tmp_path}/a/b: cannot write in '
                                       f'{tmp_path} (no permission)\n')


def test_record_plan_errors_come_before_anything_starts(tmp_path, capsys):
    plan = _plan_file(tmp_path, [STAIRS | {'load_pressure': [[0.5, 120]]}])
    assert cli.main(['record', plan, '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f'error: {plan}: experiment 1 (stairs): '
                                               'load_pressure[0] value = 120 Pa')
    assert not (tmp_path / 'o').exists()


def test_record_without_ros_says_so_in_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(record_cli.metadata, 'entry_points', lambda **kw: [])
    assert cli.main(['record', _plan_file(tmp_path), '--out', str(tmp_path / 'o')]) == 2
    out, err = capsys.readouterr()
    assert err == ('error: hydropump record runs the ROS 2 nodes, and the ROS package '
                   'hydropump_ros is not installed here (make installs it; --check needs no '
                   'ROS)\n')


def test_record_finds_its_runner_through_the_entry_point():
    assert record_cli.runner('record').__module__ == 'hydropump_ros.record'
