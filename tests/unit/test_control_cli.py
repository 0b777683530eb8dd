"""``hydropump design`` and ``hydropump closed-loop``."""

from pathlib import Path

import pytest

from hydropump_ctrl.cli import main
from hydropump_ctrl.control.schema import load_config

ROOT = Path(__file__).resolve().parents[2]
PUMP = str(ROOT / 'config' / 'pump.yaml')


def test_design_prints_gains_eigenvalues_margins_and_writes_the_params_file(tmp_path, capsys,
                                                                          params):
    out = tmp_path / 'controller.yaml'
    assert main(['design', '--params', PUMP, '--out', str(out)]) == 0
    text = capsys.readouterr().out
    for words in ('k_x =', 'l_Q =', 'Closed-loop eigenvalues', 'GM', 'PM', 'DM',
                  'falling flow (eq. 15', 'any aperture', f'wrote {out}'):
        assert words in text
    written = load_config(out, current_limits=params.I_limits)
    committed = load_config(ROOT / 'config' / 'controller.yaml')
    assert written == committed


def test_design_takes_the_identified_model_and_overrides(tmp_path, capsys):
    out = tmp_path / 'c.yaml'
    assert main(['design', '--params', PUMP, '--G0', '90', '--tau', '0.12', '--t-d', '0.06',
                 '--set', 'emc.tau_control=0.02', '--out', str(out)]) == 0
    cfg = load_config(out)
    assert cfg.model.tau == 0.12 and cfg.model.t_d == 0.06 and cfg.emc.tau_control == 0.02
    assert cfg.delay_steps == 12


@pytest.mark.parametrize('argv, words', [
    (['design', '--params', PUMP, '--set', 'emc.tau_control=0', '--dry-run'],
     'emc.tau_control'),
    (['design', '--params', PUMP, '--set', 'emc.tau_control', '--dry-run'], 'NAME=VALUE'),
    (['closed-loop', '--params', PUMP, '--config', '/nonexistent/c.yaml'], 'not found'),
    (['design', '--params', PUMP, '--G0', 'nan', '--dry-run'],
     '--G0 nan: expected a finite number > 0 (% per current range)'),
    (['design', '--params', PUMP, '--tau', '0', '--dry-run'],
     '--tau 0: expected a finite number > 0 (s)'),
    (['design', '--params', PUMP, '--t-d', '-0.01', '--dry-run'],
     '--t-d -0.01: expected a finite number >= 0 (s)'),
    (['design', '--params', PUMP, '--set', 'emc.tau_control=[', '--dry-run'],
     "--set 'emc.tau_control=[': the value is not valid YAML"),
    (['design', '--params', PUMP, '--out', '/tmp/controller.txt', '--dry-run'],
     'params file /tmp/controller.txt: use a .yaml or .yml file name'),
    (['closed-loop', '--params', PUMP, '--set', 'controller.update_rate=300', '--no-table'],
     'controller period 0.00333333 s is not a multiple of dt_sim 0.001 s'),
])
def test_user_errors_are_one_line(capsys, argv, words):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith('error: ') and words in err[0]


def test_closed_loop_plots_emc_beside_pi(tmp_path, capsys):
    assert main(['closed-loop', '--params', PUMP, '--out', str(tmp_path), '--no-table']) == 0
    pngs = sorted(p.name for p in tmp_path.glob('*.png'))
    assert 'flow_step_30_70.png' in pngs and 'unreachable.png' in pngs
    assert any(p.startswith('aperture_') for p in pngs)
    assert all((tmp_path / p).stat().st_size > 10_000 for p in pngs)


def test_design_from_a_fit_result_equals_design_with_its_numbers(tmp_path, capsys):
    """--from-fit takes G0, tau, t_d from a `hydropump fit` result: the joint fit where there
    is one, else the pooled mean; the file written is the one the numbers give."""
    import json

    from hydropump_ctrl.ident.report import SCHEMA
    res = tmp_path / 'result.json'
    res.write_text(json.dumps({'schema': SCHEMA, 'pooled': {
        'G0': 98.0, 'tau': 0.11, 'td': 0.05,
        'joint': {'G0': 97.0, 'tau': 0.105, 'td': 0.052}}}))
    a, b = tmp_path / 'a.yaml', tmp_path / 'b.yaml'
    assert main(['design', '--params', PUMP, '--from-fit', str(res), '--out', str(a)]) == 0
    assert 'joint fit' in capsys.readouterr().out
    assert main(['design', '--params', PUMP, '--G0', '97', '--tau', '0.105', '--t-d', '0.052',
                 '--out', str(b)]) == 0
    assert load_config(a) == load_config(b)
    bad = tmp_path / 'bad.json'
    for text, words in (('{"schema": "other"}', 'not a `hydropump fit` result'),
                        ('not json', 'not a JSON fit result')):
        bad.write_text(text)
        assert main(['design', '--params', PUMP, '--from-fit', str(bad), '--dry-run']) == 2
        assert words in capsys.readouterr().err
