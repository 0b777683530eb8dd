"""Parameter schema and loader: every bad value gives one clear line; the files load."""

import math
from pathlib import Path
import subprocess
import sys

import pytest
import yaml

from hydropump_sim.params import iter_specs, load_params, ParamError, params_from_dict

from ..conftest import PUMP_YAML, REFERENCE_YAML


def _reference_dict():
    doc = yaml.safe_load(PUMP_YAML.read_text())
    return doc['/**']['ros__parameters']


def _errors(data):
    with pytest.raises(ParamError) as exc:
        params_from_dict(data)
    return exc.value.lines


def test_project_file_matches_reference_set():
    """config/pump.yaml holds the reference set (tests/data): same groups, keys and values."""
    ref = yaml.safe_load(REFERENCE_YAML.read_text())
    ours = _reference_dict()
    for group, values in ref.items():
        for key, val in values.items():
            assert ours[group][key] == val, f'{group}.{key}'
    assert load_params(REFERENCE_YAML) == load_params(PUMP_YAML)


def test_every_parameter_has_unit_description_and_range():
    for s in iter_specs():
        assert s.unit and s.desc, s.name
        if s.type is float:
            lo, hi = s.range
            assert lo is not None and hi is not None and lo < hi, s.name


def test_derived_quantities_follow_the_paper(params):
    assert math.isclose(params.Q_max, 45e-6 * 25.0)
    assert math.isclose(params.b_p, params.Q_max / params.pump.x_a_max)
    # Paper map (docs/reference.md I1): 0..100 % displacement is I_s in [0.3, 0.7] A.
    assert params.current_range == pytest.approx((0.3, 0.7))
    assert params.I_limits == pytest.approx((0.1, 0.9))


@pytest.mark.parametrize('key, value, expect', [
    ('spool.m_c', -0.0045, ['spool.m_c = -0.0045 kg', 'outside', '[0.0001, 1] kg']),
    ('line.P_u', 120.0, ['line.P_u = 120 Pa', 'bar', '1.2e+07 Pa']),
    ('pump.f_p', 1500.0, ['rpm', '25 Hz']),
    ('spool.K_a', '4.0e3', ['not a number', 'signed exponent']),
    ('spool.K_a', 'stiff', ['not a number']),
    ('pump.flow_map', 'linear', ['paper, consistent']),
    ('relief.enabled', 'yes', ['true or false']),
])
def test_bad_value_is_one_clear_line(key, value, expect):
    data = _reference_dict()
    group, name = key.split('.')
    data[group][name] = value
    lines = _errors(data)
    assert len(lines) == 1
    for fragment in expect:
        assert fragment in lines[0], lines[0]


def test_unknown_key_suggests_the_likely_one():
    data = _reference_dict()
    data['spool']['mc'] = 0.004
    (line,) = _errors(data)
    assert 'spool.mc' in line and 'did you mean spool.m_c' in line


def test_missing_key_is_named_with_its_unit():
    data = _reference_dict()
    del data['plate']['K_b']
    (line,) = _errors(data)
    assert line.startswith('plate.K_b: missing') and 'N/m' in line


def test_all_problems_are_reported_at_once():
    data = _reference_dict()
    data['spool']['m_c'] = -1.0
    data['line']['V_l'] = 'big'
    del data['fluid']['rho']
    assert len(_errors(data)) == 3


def test_design_condition_D1_is_checked_with_numbers():
    data = _reference_dict()
    data['spool']['phi_s'] = 150.0
    (line,) = _errors(data)
    assert 'D1' in line and '60 N' in line and '64 N' in line


def test_redundant_pairs_must_agree():
    data = _reference_dict()
    data['actuator']['S_a'] = 8.0e-4
    assert any('pi*d_a^2/4' in ln for ln in _errors(data))


def test_replace_revalidates(params):
    assert params.replace({'line.xi_u': 0.3}).line.xi_u == 0.3
    with pytest.raises(ParamError):
        params.replace({'line.xi_u': 1.3})


def test_bad_file_gives_no_traceback(tmp_path: Path):
    bad = tmp_path / 'pump.yaml'
    text = PUMP_YAML.read_text().replace('m_c: 0.0045', 'm_c: -0.0045')
    bad.write_text(text)
    proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'analyze', '--params',
                           str(bad), '--out', str(tmp_path / 'o')], capture_output=True,
                          text=True)
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    assert proc.stderr.strip() == ('error: spool.m_c = -0.0045 kg: outside the accepted range '
                                   '[0.0001, 1] kg (spool and armature moving mass (eq. 1))')


def test_unreadable_and_malformed_files(tmp_path: Path):
    with pytest.raises(ParamError, match='cannot read'):
        load_params(tmp_path / 'nope.yaml')
    broken = tmp_path / 'broken.yaml'
    broken.write_text('spool: [1, 2\n')
    with pytest.raises(ParamError, match='not valid YAML'):
        load_params(broken)
