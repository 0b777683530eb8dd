"""How ``hydropump`` ends: a user error in one line a problem (exit code 2), Ctrl-C with 130,
and any other exception as the bug it is, with its traceback."""

import pytest

from hydropump_ctrl import cli
from hydropump_ctrl.cli.options import UsageError
from hydropump_ctrl.ident import BagError
from hydropump_sim.errors import HydropumpError, InputError
from hydropump_sim.params import ParamError


def _with_command(monkeypatch, action):
    def register(sub):
        sub.add_parser('boom').set_defaults(func=lambda args: action())
    monkeypatch.setattr(cli, 'COMMANDS', (*cli.COMMANDS, register))


def _raise(exc):
    def action():
        raise exc
    return action


@pytest.mark.parametrize('exc, lines', [
    (ParamError(['spool.m_c = -1 kg: expected > 0', 'pump.f_p: missing'], 'p.yaml'),
     ['spool.m_c = -1 kg: expected > 0', 'pump.f_p: missing']),
    (InputError('duration = 1e+07 s needs 1e+10 samples'),
     ['duration = 1e+07 s needs 1e+10 samples']),
    (BagError('topic /line_flow has 1 NaN', source='run1'),
     ['run1: topic /line_flow has 1 NaN']),
    (UsageError('--T 0: expected a finite number > 0 (s)'),
     ['--T 0: expected a finite number > 0 (s)']),
])
def test_a_user_error_is_one_line_a_problem_and_exit_code_2(monkeypatch, capsys, exc, lines):
    _with_command(monkeypatch, _raise(exc))
    assert cli.main(['boom']) == 2
    out, err = capsys.readouterr()
    assert out == '' and err.splitlines() == [f'error: {line}' for line in lines]


def test_every_user_error_of_a_command_is_a_hydropump_error():
    assert issubclass(UsageError, HydropumpError)
    assert issubclass(BagError, HydropumpError) and issubclass(InputError, HydropumpError)


@pytest.mark.parametrize('exc', [ValueError('a bug'), FileNotFoundError('a bug'),
                                 ZeroDivisionError('a bug')])
def test_anything_else_is_a_bug_and_keeps_its_traceback(monkeypatch, exc):
    _with_command(monkeypatch, _raise(exc))
    with pytest.raises(type(exc), match='a bug'):
        cli.main(['boom'])


def test_ctrl_c_exits_with_130(monkeypatch, capsys):
    _with_command(monkeypatch, _raise(KeyboardInterrupt()))
    assert cli.main(['boom']) == 130
    assert capsys.readouterr().err == 'interrupted\n'


def test_the_parser_has_every_command():
    sub = next(a for a in cli.build_parser()._actions if a.dest == 'command')
    assert set(sub.choices) == {'analyze', 'simulate', 'circuit', 'fit', 'calibrate',
                                'validate', 'design', 'closed-loop', 'record', 'sweep',
                                'fmu'}
