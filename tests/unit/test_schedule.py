"""The input schedule grammar (hydropump_sim.schedule): each form against its closed form, a
current's units through the static map of eqs. 8 and 10, one staircase meaning the same in a
scenario, a recording plan and a sweep, and one-line errors naming where."""

import numpy as np
import pytest
import yaml

from hydropump_ctrl.plans import held_inputs, parse_plan
from hydropump_ctrl.sweep.spec import sweep_from_dict
from hydropump_sim.scenario import load_scenario
from hydropump_sim.schedule import parse_schedule

from ..conftest import ROOT


def _parse(raw, **kw):
    errors = []
    out = parse_schedule(raw, 'x', errors, **kw)
    return out, errors


@pytest.mark.parametrize('raw, t, expected', [
    (0.5, [0.0, 7.0], [0.5, 0.5]),
    ([[0.0, 1.0], [0.5, 2.0]], [0.0, 0.49, 0.5, 3.0], [1.0, 1.0, 2.0, 2.0]),
    ({'steps': [[0.2, 1.0], [0.5, 2.0]]}, [0.0, 0.3, 0.6], [1.0, 1.0, 2.0]),
    ({'ramp': [[0.0, 1.0], [2.0, 3.0]]}, [-1.0, 0.5, 1.0, 5.0], [1.0, 1.5, 2.0, 3.0]),
    ({'staircase': {'levels': [3, 1, 2], 'dwell': 0.25}}, [0.0, 0.26, 0.5, 9.0],
     [3.0, 1.0, 2.0, 2.0]),
    ({'step': {'from': 1.0, 'to': 4.0, 'at': 0.1}}, [0.0, 0.09, 0.1, 1.0], [1.0, 1.0, 4.0, 4.0]),
    ({'offset': 2.0, 'sine': {'amplitude': 0.5, 'frequency': 2.0, 'phase': 0.5, 'start': 0.1}},
     [0.05, 0.1, 0.2], [2.0, 2.0 + 0.5 * np.sin(0.5),
                        2.0 + 0.5 * np.sin(2 * np.pi * 2.0 * 0.1 + 0.5)]),
    ({'sine': {'amplitude': 1.0, 'frequency': 1.0}}, [0.25], [1.0]),
    ({'steps': [[0.0, 1.0], [1.0, 2.0]], 'sine': {'amplitude': 1.0, 'frequency': 0.5}},
     [0.5, 1.5], [1.0 + np.sin(0.5 * np.pi), 2.0 + np.sin(1.5 * np.pi)]),
])
def test_each_form_is_its_closed_form(raw, t, expected):
    sched, errors = _parse(raw)
    assert errors == []
    np.testing.assert_allclose(sched(np.array(t)), expected, rtol=0, atol=1e-12)
    assert sched(t[0]) == pytest.approx(expected[0])          # a scalar time, a float back


def test_a_current_in_percent_or_fraction_goes_through_the_static_map(params):
    """Eqs. 8 and 10 at x_c = 0: 0 % of displacement at I_nominal - i_full, 100 % at
    I_nominal + i_full, affine between; a sine's amplitude through the slope alone."""
    lo, hi = params.I_nominal - params.i_full, params.I_nominal + params.i_full
    for unit, scale in (('percent', 100.0), ('fraction', 1.0)):
        sched, errors = _parse({'offset': 0.5 * scale, 'sine': {'amplitude': 0.25 * scale,
                                                                  'frequency': 1.0},
                                'unit': unit}, units=('A', 'percent', 'fraction'))
        assert errors == [] and sched.unit == unit
        amps = sched.in_amperes(params)
        assert amps.unit == 'A' and amps.offset == pytest.approx(params.I_nominal)
        assert amps.sine[0] == pytest.approx(0.25 * (hi - lo))
        assert amps(0.25) == pytest.approx(params.I_nominal + 0.25 * (hi - lo))
    stairs, _ = _parse({'staircase': {'levels': [0, 100], 'dwell': 1.0}, 'unit': 'percent'},
                       units=('A', 'percent'))
    assert stairs.in_amperes(params).levels == pytest.approx((lo, hi))
    plain, _ = _parse(0.42, units=('A', 'percent'))
    assert plain.in_amperes(params).offset == 0.42              # A stays A


def test_one_staircase_means_the_same_in_a_scenario_a_plan_and_a_sweep(params, tmp_path):
    """The same staircase written for each format (its own top-level keys, its own default
    unit) is the same current in amperes: the levels eq. 10 gives at 30, 50 and 70 %."""
    lo, hi = params.current_range
    truth = [lo + (hi - lo) * f for f in (0.3, 0.5, 0.7)]
    t = np.array([0.1, 0.6, 1.1, 1.4])
    want = [truth[0], truth[1], truth[2], truth[2]]
    stairs = {'staircase': {'levels': [30, 50, 70], 'dwell': 0.5}, 'unit': 'percent'}
    path = tmp_path / 'scenario.yaml'
    path.write_text(yaml.safe_dump({'duration': 1.5, 'inputs': {'current': stairs}}))
    scenario = load_scenario(path).inputs['current']
    np.testing.assert_allclose(scenario(t), want, atol=1e-12)
    plan = parse_plan([{'name': 'a', 'duration': 1.5, 'current': stairs}], params)
    held = held_inputs(plan.experiments[0], params, dt=0.1, period=None)
    np.testing.assert_allclose(held.current[[1, 6, 11, 14]], want, atol=1e-12)
    rest = {'params': str(ROOT / 'config' / 'pump.yaml'), 'outputs': [{'final': 'q_l'}],
            'grid': {'parameters': {'line.V_l': [params.line.V_l]}}}
    sweep = sweep_from_dict({'experiment': {'duration': 1.5, 'current': stairs}, **rest},
                            tmp_path)
    np.testing.assert_allclose(sweep.experiment.inputs['current'](t), want, atol=1e-12)
    assert sweep.experiment.step_times == (0.5, 1.0)
    # A sweep's current is in fractions unless it says otherwise (its files of before).
    frac = sweep_from_dict({'experiment': {'duration': 1.5, 'current': {'staircase': {
        'levels': [0.3, 0.5, 0.7], 'dwell': 0.5}}}, **rest}, tmp_path)
    np.testing.assert_allclose(frac.experiment.inputs['current'](t), want, atol=1e-12)


@pytest.mark.parametrize('raw, kw, line', [
    ({'staircase': {'levels': [1], 'dwel': 1.0}}, {},
     'x.staircase.dwel: unknown key (did you mean dwell?); use levels, dwell'),
    ({'steps': [[0, 1]], 'ramp': [[0, 1]]}, {}, 'x: give one of steps, ramp, not both'),
    ({'ramp': [[0, 1], [0, 2]]}, {}, 'x.ramp: times must increase (0, 0 s)'),
    ({'steps': [[-1, 1]]}, {'time_sign': '>= 0'},
     'x.steps[0] time = -1: expected a finite number >= 0 (s)'),
    ({'staircase': {'levels': [], 'dwell': 1.0}}, {}, 'x.staircase.levels: expected a list'),
    ({'staircase': {'levels': [1, 2], 'dwell': 0}}, {},
     'x.staircase.dwell = 0: expected a finite number > 0 (s)'),
    ({'step': {'from': 1, 'to': 2}}, {}, 'x.step: missing at (a step takes from, to, at)'),
    ({'sine': {'amplitude': 1}}, {}, 'x.sine: expected amplitude and frequency'),
    ({'offset': '1.5e6'}, {}, "x.offset = '1.5e6': expected a finite number"),
    ({'offset': 1, 'unit': 'percent'}, {}, 'x.unit: unknown key'),
    ({'offset': 1, 'unit': 'mA'}, {'units': ('A', 'percent')},
     "x.unit = 'mA': expected A or percent"),
    ({'ramp': [[0, 1], [1, 2]]}, {'bases': ('steps', 'offset')},
     'x.ramp: not here; use steps, offset (and a sine)'),
    ({}, {}, 'x: expected one of steps, ramp, staircase, step, offset'),
    ('fast', {}, "x = 'fast': expected a finite number"),
])
def test_a_bad_schedule_is_one_line_naming_where(raw, kw, line):
    sched, errors = _parse(raw, **kw)
    assert sched is None and len(errors) == 1 and errors[0].startswith(line), errors


def test_a_plan_in_the_spelling_of_before_still_runs_with_a_note(params):
    old = [{'name': 'a', 'duration': 1.0, 'current': {'shape': 'staircase', 'unit': 'percent',
                                                       'levels': [40, 60], 'dwell': 0.5}},
           {'name': 'b', 'duration': 1.0, 'held_out': True, 'current': {
               'shape': 'sine', 'unit': 'A', 'offset': 0.5, 'amplitude': 0.05,
               'frequency': 2.0}}]
    new = [{'name': 'a', 'duration': 1.0, 'current': {
               'staircase': {'levels': [40, 60], 'dwell': 0.5}, 'unit': 'percent'}},
           {'name': 'b', 'duration': 1.0, 'held_out': True, 'current': {
               'offset': 0.5, 'sine': {'amplitude': 0.05, 'frequency': 2.0}}}]
    before, today = parse_plan(old, params), parse_plan(new, params)
    assert today.warnings == []
    assert before.warnings == [
        'experiment 1 (a): current: shape: staircase is the old spelling; write staircase: '
        '{levels: [...], dwell: ...}',
        'experiment 2 (b): current: shape: sine is the old spelling; write offset: ..., '
        'sine: {amplitude: ..., frequency: ...}']
    for a, b in zip(before.experiments, today.experiments, strict=True):
        np.testing.assert_array_equal(held_inputs(a, params).current,
                                      held_inputs(b, params).current)
    # ... and each is what the old spelling said: 40 then 60 % of eq. 10's range, 0.5 s
    # each; 0.5 A + 0.05 A sin(2 pi 2 t), sampled at the controller's 5 ms updates.
    lo, hi = params.current_range
    np.testing.assert_allclose(held_inputs(before.experiments[0], params).current,
                               np.repeat([lo + 0.4 * (hi - lo), lo + 0.6 * (hi - lo)], 500),
                               atol=1e-12)
    tk = np.floor(np.arange(1000) * 1e-3 / 0.005 + 1e-6) * 0.005
    np.testing.assert_allclose(held_inputs(before.experiments[1], params).current,
                               0.5 + 0.05 * np.sin(2 * np.pi * 2.0 * tk), atol=1e-12)
    with pytest.raises(ValueError) as info:
        parse_plan([{**old[0], 'current': {**old[0]['current'], 'frequency': 1.0}}], params)
    assert 'current.frequency: belongs to a sine, not a staircase' in str(info.value)


def test_a_sweep_with_step_metrics_needs_a_current_that_steps(params, tmp_path):
    from hydropump_ctrl.sweep.spec import SweepError
    rest = {'params': str(ROOT / 'config' / 'pump.yaml'), 'outputs': ['step'],
            'grid': {'parameters': {'line.V_l': [params.line.V_l]}}}
    for current in (0.5, {'ramp': [[0.0, 0.3], [1.0, 0.6]]},
                    {'staircase': {'levels': [0.4], 'dwell': 0.5}}):
        with pytest.raises(SweepError) as info:
            sweep_from_dict({'experiment': {'duration': 1.0, 'current': current}, **rest},
                            tmp_path)
        assert info.value.lines == ['outputs: step needs a current that steps (steps, a '
                                    'staircase of two levels or more, or step: {from, to, '
                                    'at})'], current
    # A ramp may end where the run ends: no change of it is "late".
    ok = sweep_from_dict({'experiment': {'duration': 1.0, 'current': {
        'ramp': [[0.0, 0.3], [1.0, 0.6]]}}, **rest, 'outputs': [{'final': 'q_l'}]}, tmp_path)
    assert ok.experiment.step_times == ()
