"""``hydropump circuit`` as a user runs it: every signal's final value named
``<component>.<signal>``, the JSON form, the paper's method on request, and one ``error:``
line for a bad file or a bad value (never a traceback)."""

import json
import subprocess
import sys

import pytest

from hydropump_ctrl.cli import main

from ..conftest import ROOT

FIG1 = str(ROOT / 'config' / 'circuits' / 'fig1.yaml')


def test_prints_every_signal_and_holds_the_margin(capsys):
    code = main(['circuit', FIG1, '--duration', '0.5', '--set', 'boom.command=0.5',
                 '--json'])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out['control'] == 'margin'
    sig = out['signals']
    for name in ('boom.flow', 'boom.pressure', 'pump.P_l', 'ls.pressure', 'motor.speed',
                 'steering.flow', 'relief.flow'):
        assert name in sig, name
    # The margin of the controller's configuration, over the highest fed load.
    assert sig['pump.P_l'] - sig['ls.pressure'] == pytest.approx(out['margin'], abs=0.5e5)
    assert sig['boom.flow'] > 1e-4 and out['units']['boom.flow'] == 'm^3/s'


def test_open_loop_and_the_hydromechanical_compensator(capsys):
    assert main(['circuit', FIG1, '--duration', '0.3', '--control', 'hydromechanical',
                 '--margin', '2.0e6', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    assert out['signals']['pump.margin'] == pytest.approx(2.0e6, abs=0.5e5)
    assert main(['circuit', FIG1, '--duration', '0.2', '--control', 'open', '--set',
                 'pump.current=0.3']) == 0
    text = capsys.readouterr().out
    assert 'under open' in text and 'pump.current' in text and '0.3 A' in text


def test_analyze_prints_the_method(capsys):
    assert main(['circuit', str(ROOT / 'config' / 'circuits' / 'paper.yaml'), '--duration',
                 '0.1', '--analyze']) == 0
    text = capsys.readouterr().out
    assert 'section IV component by component' in text and 'pump' in text
    assert 'transfer matrix' in text and 'simplified circuit: pump made static' in text


@pytest.mark.parametrize('args, words', [
    (['--set', 'boom.compensator=mid'], ['boom.compensator', 'pre, post, none']),
    (['--set', 'bom.command=0.5'], ['did you mean boom']),
    (['--duration', 'nan'], ['--duration', 'finite']),
    (['--control', 'open', '--algorithm', 'pi'], ['--algorithm', 'margin']),
])
def test_bad_input_is_one_line(capsys, args, words):
    assert main(['circuit', FIG1, *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and all(w in err for w in words), err


def test_a_bad_file_from_the_installed_command(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('components:\n  p: {type: pump, ports: {out: l}}\n')
    proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'circuit', str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and 'Traceback' not in proc.stderr
    assert proc.stderr.startswith('error: ') and 'p: a pump takes its parameters' in proc.stderr
