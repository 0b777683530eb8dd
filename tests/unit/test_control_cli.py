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
    text = capsys.readouterr().out
    assert _line(text, 'tau') == '0.12 s (eq. 19, --tau on the command line)'
    assert _line(text, 't_d').startswith('0.06 s (eq. 19, --t-d on the command line')
    assert 'G0 = 90.00 %: eq. 19, --G0 on the command line' in _line(text, 'gain')


def _line(text: str, name: str) -> str:
    """``value unit (source)`` of a model number in the design's printout."""
    for ln in text.splitlines():
        head, sep, tail = ln.partition('=')
        if sep and head.strip() == name:
            return ' '.join(tail.split())
    raise AssertionError(f'no line for {name} in\n{text}')


@pytest.fixture
def slow_plant_file(tmp_path, params):
    """A plant file whose pilot orifice is 15 % smaller (eq. 4, mu_a with h_a): by eq. 14,
    tau = S_a (1 + K_c/K_a)/(mu_a sqrt(P_a_bar)), the growing flow is 1/0.85 slower."""
    from hydropump_sim.schema import dump_ros_yaml
    ac = params.actuator
    slow = params.replace({'actuator.mu_a': 0.85 * ac.mu_a, 'actuator.h_a': 0.85 * ac.h_a})
    path = tmp_path / 'calibrated.yaml'
    path.write_text(dump_ros_yaml(slow.flat()))
    return path, slow


def test_design_of_a_plant_file_is_that_plant_s_model(tmp_path, capsys, slow_plant_file):
    import math
    path, p = slow_plant_file
    out = tmp_path / 'c.yaml'
    assert main(['design', '--params', str(path), '--out', str(out)]) == 0
    text = capsys.readouterr().out
    ac, sp = p.actuator, p.spool
    eq14 = ac.S_a * (1 + sp.K_c / sp.K_a) / (ac.mu_a * math.sqrt(ac.P_a_bar))
    eq15 = ac.S_a * (1 + sp.K_c / sp.K_a) / (ac.mu_a * math.sqrt(p.line.P_l_bar - ac.P_a_bar))
    m = load_config(out).model
    assert m.tau == pytest.approx(eq14, rel=0.02) and m.tau > 0.115
    # P_l sits 2 kPa off P_l_bar (the load orifice's laminar regularisation): 1e-4.
    assert m.tau_down == pytest.approx(eq15, rel=5e-4)
    assert m.t_d == 0.055
    assert _line(text, 'tau') == (f"{m.tau:g} s (63 % time of the fine model's 40 -> 60 % "
                                  'step, calibrated.yaml)')
    assert _line(text, 't_d').startswith('0.055 s (delay of the line_flow sensor, bench.yaml')
    for name in ('tau_down', 'tau_z', 'Q_bar', 'C_l', 'flow_error_max'):
        assert 'calibrated.yaml' in _line(text, name), name
    assert 'calibrated.yaml' in out.read_text().split('/**:')[0]


def test_design_with_a_profile_without_flow_delay(tmp_path, capsys):
    out = tmp_path / 'c.yaml'
    sensors = str(ROOT / 'config' / 'sensors.yaml')
    assert main(['design', '--params', PUMP, '--profile', sensors, '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert load_config(out).model.t_d == 0.0
    assert 'note: sensors.yaml has no delay on line_flow: t_d = 0' in text
    assert _line(text, 't_d').startswith('0 s (delay of the line_flow sensor, sensors.yaml')


@pytest.mark.parametrize('argv, words', [
    (['design', '--params', PUMP, '--set', 'emc.tau_control=0', '--dry-run'],
     'emc.tau_control'),
    (['design', '--params', PUMP, '--set', 'emc.tau_control', '--dry-run'], 'NAME=VALUE'),
    (['closed-loop', '--params', PUMP, '--config', '/nonexistent/c.yaml'], 'not found'),
    (['design', '--params', PUMP, '--G0', 'nan', '--dry-run'],
     '--G0 nan: expected a finite number > 0 and <= 1000 (% per current range)'),
    (['design', '--params', PUMP, '--tau', '0', '--dry-run'],
     '--tau 0: expected a finite number from 0.001 to 10 (s)'),
    (['design', '--params', PUMP, '--t-d', '-0.01', '--dry-run'],
     '--t-d -0.01: expected a finite number from 0 to 2 (s)'),
    (['design', '--params', PUMP, '--set', 'emc.tau_control=[', '--dry-run'],
     "--set 'emc.tau_control=[': the value is not valid YAML"),
    (['design', '--params', PUMP, '--out', '/tmp/controller.txt', '--dry-run'],
     'params file /tmp/controller.txt: use a .yaml or .yml file name'),
    (['closed-loop', '--params', PUMP, '--set', 'controller.update_rate=300', '--no-table'],
     'controller period 0.00333333 s is not a multiple of dt_sim 0.001 s'),
    (['design', '--params', PUMP, '--profile', '/nonexistent/bench.yaml', '--dry-run'],
     '--profile /nonexistent/bench.yaml: no such file'),
    (['design', '--params', PUMP, '--profile', str(ROOT / 'config' / 'controller.yaml'),
      '--dry-run'], 'controller.yaml: not a sensor profile (controller.algorithm: unknown'),
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
    text = capsys.readouterr().out
    assert _line(text, 'tau') == '0.105 s (eq. 19, joint fit of result.json)'
    assert _line(text, 't_d').startswith('0.052 s (eq. 19, joint fit of result.json')
    assert 'G0 = 97.00 %: eq. 19, joint fit of result.json' in _line(text, 'gain')
    assert 'tau x eq. 15 / eq. 14' in _line(text, 'tau_down')
    assert main(['design', '--params', PUMP, '--G0', '97', '--tau', '0.105', '--t-d', '0.052',
                 '--out', str(b)]) == 0
    assert load_config(a) == load_config(b)
    bad = tmp_path / 'bad.json'
    for text, words in (('{"schema": "other"}', 'not a `hydropump fit` result'),
                        ('not json', 'not a JSON fit result')):
        bad.write_text(text)
        assert main(['design', '--params', PUMP, '--from-fit', str(bad), '--dry-run']) == 2
        assert words in capsys.readouterr().err


def test_design_from_a_flagged_fit_honours_its_flags(tmp_path, capsys):
    """A fit whose delay sits on its bound (or that did not converge) is no model to design
    on: refused in one line that names the flags in words, nothing written; a set of the
    pooled mean so flagged refuses it too; a non-white residual is a note beside a design;
    a file's non-positive number is refused without a unit hint the user never typed."""
    import json

    from hydropump_ctrl.ident.report import SCHEMA
    res = tmp_path / 'result.json'
    out = tmp_path / 'c.yaml'
    cases = [
        ({'G0': 98.0, 'tau': 0.11, 'td': 0.05,
          'joint': {'G0': 97.0, 'tau': 0.105, 'td': 0.001, 'flags': ['td_on_lower_bound']}},
         2, 'joint fit is flagged td_on_lower_bound (t_d is on its lower bound'),
        ({'G0': 98.0, 'tau': 0.11, 'td': 0.05, 'joint': None,
          'flagged_sets': {'run2': ['not_converged']}},
         2, 'pooled mean is flagged not_converged (the optimiser stopped'),
        ({'G0': 98.0, 'tau': -0.11, 'td': 0.05, 'joint': None},
         2, 'the pooled mean gives tau = -0.11 s; a pump has a positive one'),
        ({'G0': 98.0, 'tau': 0.11, 'td': 0.05,
          'joint': {'G0': 97.0, 'tau': 0.105, 'td': 0.052, 'flags': ['residuals_not_white']}},
         0, 'note: the joint fit of result.json is flagged residuals_not_white'),
    ]
    for pooled, code, words in cases:
        res.write_text(json.dumps({'schema': SCHEMA, 'pooled': pooled}))
        assert main(['design', '--params', PUMP, '--from-fit', str(res), '--out',
                     str(out)]) == code
        o, err = capsys.readouterr()
        text = err if code else o
        assert words in text, text
        if code:
            assert len(err.strip().splitlines()) == 1 and 'looks like' not in err
            assert not out.exists()


def test_design_for_a_circuit_judges_its_margin_loop_on_the_line_it_has(capsys):
    """A load-sensing circuit's compensated sections make the line an integrator: the margin
    loop is judged on that model (not on the paper's load orifice), on a smaller and a
    larger line, and on the line the circuit presents with its sections open, which the
    design tool measures and names when it is far from the modelled one (at rest: the
    pump's outlet volume over beta, the load chambers behind closed valves left out)."""
    import re

    import yaml
    fig1 = ROOT / 'config' / 'circuits' / 'fig1.yaml'
    assert main(['design', '--params', PUMP, '--circuit', str(fig1), '--dry-run']) == 0
    out = capsys.readouterr().out
    assert 'any aperture' not in out
    rows = re.findall(r'^ +(.*?)\s+GM\s+(\S+) dB\s+PM\s+(\S+) deg', out, re.M)
    rows = {name.strip(): (float(gm), float(pm)) for name, gm, pm in rows}
    assert rows['EMC margin loop, compensated loads'][1] > 30.0
    smaller = next(v for k, v in rows.items() if k.startswith('a smaller line'))
    assert smaller[0] < rows['EMC margin loop, compensated loads'][0]
    # The outlet's volume is the plant's line (fig1.yaml: V = plant.line.V_l).
    assert yaml.safe_load(fig1.read_text())['components']['supply_line']['V'] == \
        'plant.line.V_l'
    plant = yaml.safe_load(Path(PUMP).read_text())['/**']['ros__parameters']
    outlet = plant['line']['V_l'] / plant['fluid']['beta']
    c_l = float(re.search(r'C_l\s+= (\S+)', out)[1])
    assert outlet <= c_l <= 1.2 * outlet
    (note,) = [line for line in out.splitlines() if 'every section open' in line]
    assert float(re.search(r'(\S+) x the modelled', note)[1]) > 2.0
    assert any(k.startswith('sections open at') for k in rows)
