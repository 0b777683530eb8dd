"""Bad inputs to the plant library: one clear error, in bounded time, never a traceback of
numpy or an hour of integration."""

import math

import numpy as np
import pytest

from hydropump_sim import equilibrium, IntegratorConfig, simulate
from hydropump_sim.errors import HydropumpError, InputError
from hydropump_sim.params import check_input
from hydropump_sim.scenario import load_scenario, ScenarioError
from hydropump_sim.simulate import IntegrationError
from hydropump_sim.trim import TrimError


@pytest.mark.parametrize('duration, dt_out', [(1.0, 1.0e-9), (1.0e7, 1.0e-3)])
def test_a_grid_too_large_is_refused_before_any_memory_is_taken(params, duration, dt_out):
    with pytest.raises(InputError, match=r'needs .* samples, about .* GiB; at most 2e\+07'):
        simulate(params, duration, dt_out=dt_out)


@pytest.mark.parametrize('duration, dt_out, what', [
    (0.0, 1e-3, 'duration = 0.0: expected a positive'),
    (math.nan, 1e-3, 'duration = nan'),
    (1.0, -1e-3, 'dt_out = -0.001: expected a step in'),
    (1.0, 2.0, 'dt_out = 2.0: expected a step in'),
])
def test_bad_grids_name_the_value(params, duration, dt_out, what):
    with pytest.raises(InputError, match=what):
        simulate(params, duration, dt_out=dt_out)


def test_the_step_budget_stops_a_stiff_run_with_a_clear_error(params):
    # A budget far below what this run needs stands for a parameter set that makes the
    # model a hundred times stiffer than nominal.
    cfg = IntegratorConfig(steps_per_second=200.0)
    with pytest.raises(IntegrationError, match='too stiff to integrate: 1000 solver steps'):
        simulate(params.replace({'input.dither_amp': 0.01}), 5.0, 0.5, config=cfg)


def test_the_time_budget_stops_a_long_run(params):
    cfg = IntegratorConfig(time_budget=0.0)
    with pytest.raises(IntegrationError, match=r'time budget 0 s'):
        simulate(params, 60.0, 0.5, dt_out=0.01, config=cfg)


def test_input_signals_take_the_ranges_of_their_plant_parameters(params):
    assert check_input('aperture', [0.0, 0.5, 1.0]) is None
    err = check_input('load_pressure', [1e7, 120.0], [0.0, 0.25])
    assert err.startswith('load_pressure = 120 Pa at t = 0.25 s: outside the accepted range '
                          '[10000, 4.5e+07] Pa')
    assert 'looks like a value in bar' in err
    with pytest.raises(InputError, match=r'shaft_speed = -25 Hz at t = 0 s'):
        simulate(params, 0.1, shaft_speed=-25.0)
    with pytest.raises(InputError, match=r'aperture = 5 at t = 0\.05 s'):
        simulate(params, 0.1, aperture=lambda t: np.where(t < 0.05, 0.5, 5.0))


@pytest.mark.parametrize('signal, value, line', [
    ('aperture', -3.0, 'inputs.aperture = -3 at t = 0 s: outside the accepted range [0, 1]'),
    ('aperture', 5.0, 'inputs.aperture = 5 at t = 0 s'),
    ('load_pressure', -1.0e7, 'inputs.load_pressure = -1e+07 Pa at t = 0 s'),
    ('load_pressure', 1.0e12, 'inputs.load_pressure = 1e+12 Pa at t = 0 s'),
    ('shaft_speed', -25.0, 'inputs.shaft_speed = -25 Hz at t = 0 s'),
])
def test_scenario_inputs_out_of_range_are_refused(tmp_path, signal, value, line):
    path = tmp_path / 'scenario.yaml'
    path.write_text(f'duration: 1.0\ninputs:\n  {signal}: {value!r}\n')
    with pytest.raises(ScenarioError) as exc:
        load_scenario(path)
    assert any(ln.startswith(line) for ln in exc.value.lines), exc.value.lines
    assert isinstance(exc.value, HydropumpError)


def test_a_scenario_step_out_of_range_is_found_at_its_time(tmp_path):
    path = tmp_path / 'scenario.yaml'
    path.write_text('duration: 2.0\ninputs:\n  aperture: {steps: [[0.0, 0.5], [1.25, 1.5]]}\n')
    with pytest.raises(ScenarioError, match=r'inputs.aperture = 1.5 at t = 1.25 s'):
        load_scenario(path)


def test_trim_error_names_the_failed_check(params):
    closed = params.replace({'relief.enabled': False})
    with pytest.raises(TrimError, match='the pump flow has nowhere to go'):
        equilibrium(closed, 0.5, aperture=0.0)
