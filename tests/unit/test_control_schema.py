"""Controller parameter schema: the committed params file, ranges, one-line reasons, round trip."""

from pathlib import Path

import pytest
import yaml

from hydropump_ctrl.control import schema
from hydropump_ctrl.control.design import design_config
from hydropump_sim.schema import ParamError, ParamSpec, ros_parameters

ROOT = Path(__file__).resolve().parents[2]
CONTROLLER_YAML = ROOT / 'config' / 'controller.yaml'



def test_committed_params_file_is_a_valid_ros_params_file(cfg, params):
    doc = yaml.safe_load(CONTROLLER_YAML.read_text())
    assert list(doc) == ['/**'] and 'ros__parameters' in doc['/**']
    # Commands stay inside the current range of eq. 2.
    lo, hi = params.I_limits
    assert lo <= cfg.limits.current_min < cfg.limits.current_max <= hi
    # The embedded model is the plant's: eq. 11 gain V_p f_p / I_max and the full flow.
    assert cfg.model.gain == pytest.approx(params.Q_max / params.spool.I_max, rel=1e-9)
    assert cfg.model.Q_max == pytest.approx(params.Q_max, rel=1e-9)
    # 55 ms at 200 Hz is 11 whole periods of the embedded delay line.
    assert cfg.period == pytest.approx(0.005) and cfg.delay_steps == 11


def test_committed_file_matches_a_fresh_design(cfg, params, bench):
    fresh = design_config(params, bench)
    for key, val in fresh.flat().items():
        got = cfg.flat()[key]
        if isinstance(val, float):
            assert got == pytest.approx(val, rel=1e-8, abs=1e-30), key
        else:
            assert got == val, key


def test_every_parameter_has_unit_description_and_range():
    specs = list(schema.iter_specs())
    assert len(specs) > 50
    for s in specs:
        assert isinstance(s, ParamSpec)
        assert s.type in (float, int, bool, str)
        assert s.unit and s.desc, s.name
        if s.type in (float, int):
            assert s.range[0] is not None and s.range[1] is not None, s.name
        if s.type is str:
            assert s.choices, s.name
    names = [s.name for s in specs]
    assert len(names) == len(set(names))
    # The PI uses control_toolbox's vocabulary.
    for key in ('p', 'i', 'd', 'i_clamp_max', 'i_clamp_min', 'u_clamp_max', 'u_clamp_min',
                'feedforward_gain', 'antiwindup_strategy', 'tracking_time_constant',
                'error_deadband'):
        assert f'pi.flow.{key}' in names and f'pi.margin.{key}' in names


def test_gains_are_live_and_the_model_structure_is_read_only():
    sp = schema.specs()
    assert sp['emc.tau_control'].live and sp['pi.flow.p'].live and sp['limits.rate_limit'].live
    assert not sp['model.t_d'].live and not sp['controller.update_rate'].live


@pytest.mark.parametrize('name, value, words', [
    ('emc.tau_control', 0.0, ['emc.tau_control', 'outside the accepted range']),
    ('emc.tau_control', 0.002, ['faster than the update period']),
    ('reference.margin', 25.0, ['looks like a value in bar']),
    ('reference.flow', 40.0, ['L/min']),
    ('pi.flow.antiwindup_strategy', 'clamp', ['expected one of']),
    ('limits.current_max', 0.05, ['current_min']),
    ('limits.safe_current', 0.95, ['safe_current']),
    ('excitation.n_levels', 2.5, ['expected an integer']),
    ('model.t_d', 0.06, ['read-only']),
    ('emc.tau_contrl', 0.01, ['did you mean emc.tau_control']),
])
def test_a_bad_value_gets_a_one_line_reason(cfg, name, value, words):
    reason = schema.validate_parameter(cfg, name, value)
    assert reason is not None and '\n' not in reason
    for w in words:
        assert w in reason, reason


def test_a_good_value_is_accepted(cfg):
    assert schema.validate_parameter(cfg, 'emc.tau_control', 0.02) is None
    assert schema.validate_parameter(cfg, 'pi.margin.p', 3e-8) is None


def test_limits_must_stay_inside_eq2(params):
    with pytest.raises(ParamError) as exc:
        design_config(params, base={'limits.current_max': 1.2})
    assert any('eq. 2' in line for line in exc.value.lines)


def test_ros_yaml_round_trip(cfg):
    text = cfg.to_ros_yaml('# header')
    again = schema.config_from_dict(ros_parameters(yaml.safe_load(text)))
    assert again == cfg
    # Every float comes back as a float (YAML 1.1 reads 1e-5 as text).
    for line in text.splitlines():
        if ':' in line and not line.strip().startswith('#'):
            val = line.split(':', 1)[1].split('#')[0].strip()
            if val and val[0].isdigit() and 'e' in val:
                assert isinstance(yaml.safe_load(val), float), line


def test_missing_model_group_is_reported():
    with pytest.raises(ParamError) as exc:
        schema.config_from_dict({})
    assert any(line.startswith('model.gain: missing') for line in exc.value.lines)


def test_eq2_range_is_checked_from_the_model_alone(cfg):
    """Without the plant file the model group still bounds the commands to eq. 2."""
    lo, hi = cfg.model.I_nominal - cfg.model.I_max, cfg.model.I_nominal + cfg.model.I_max
    assert (cfg.limits.current_min, cfg.limits.current_max) == pytest.approx((lo, hi))
    reason = schema.validate_parameter(cfg, 'limits.current_max', hi + 0.05)
    assert reason is not None and 'eq. 2' in reason


def test_make_controller_follows_the_algorithm(cfg):
    from hydropump_ctrl.control import EMCController, make_controller, PIController
    assert isinstance(make_controller(cfg), EMCController)
    assert isinstance(make_controller(cfg.replace({'controller.algorithm': 'pi'})),
                      PIController)
