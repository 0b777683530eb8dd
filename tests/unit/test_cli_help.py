"""Every command line of the suite as a careless user tries it: ``--help`` of ``hydropump`` and
of each of its commands (found in the parser), of ``hydropump-demo`` and ``hydropump-graph``
works; every number an option takes is checked as the arguments are parsed (``nan``, ``inf``,
``0``, negative, huge: one ``error:`` line naming the option and what it accepts, exit code
2, nothing started); ``hydropump-demo`` refuses a run folder it could not write and caps
``--jobs`` at the machine's CPUs, before anything starts."""

import argparse
import os
from pathlib import Path
import subprocess
import sys

import pytest

from hydropump_ctrl import cli
from hydropump_ctrl.cli.options import Number, number_check, Numbers
from hydropump_ros import campaign, graph

BIN = Path(sys.executable).parent


def _subcommands(ap: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    sub = next(a for a in ap._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


COMMANDS = _subcommands(cli.build_parser())
# Program name -> (its parser, the extra arguments it needs (a command, its positionals)).
PARSERS = {f'hydropump {name}': (p, [name]) for name, p in COMMANDS.items()}
PARSERS['hydropump-demo'] = (campaign.build_parser(), [])
PARSERS['hydropump-graph'] = (graph.build_parser(), [])


def _run(*argv):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    return subprocess.run([str(BIN / argv[0]), *argv[1:]], capture_output=True, text=True,
                          timeout=60, env=env)


# ---- --help -----------------------------------------------------------------------------------

@pytest.mark.parametrize('argv', [['hydropump', '--help']]
                         + [['hydropump', name, '--help'] for name in COMMANDS]
                         + [['hydropump-demo', '--help'], ['hydropump-graph', '--help']],
                         ids=' '.join)
def test_help_of_every_command(argv):
    proc = _run(*argv)
    assert proc.returncode == 0, proc.stderr
    assert 'Traceback' not in proc.stdout + proc.stderr and proc.stderr == ''
    prog = argv[0] if argv[1] == '--help' else f'{argv[0]} {argv[1]}'
    assert proc.stdout.startswith(f'usage: {prog}') and len(proc.stdout.splitlines()) > 3


def test_every_command_is_walked():
    # The parametrisation above comes from the parser: it must find the commands.
    assert {'analyze', 'simulate', 'fit', 'calibrate', 'validate', 'design'} <= set(COMMANDS)


# ---- the numbers of every option ------------------------------------------------------------

def _yields_a_number(type_) -> bool:
    try:
        return isinstance(type_('1'), (int, float))
    except Exception:  # noqa: BLE001 - any refusal: not a number type
        return False


def _numeric_options():
    """``(program, option, check, nargs)`` for every option that takes numbers: checked ones
    (:class:`Number`, :class:`Numbers`), plain ``type=float``/``int`` and any other type that
    yields a number."""
    out = []
    for prog, (parser, _) in PARSERS.items():
        for action in parser._actions:
            if not action.option_strings:
                continue
            check = number_check(parser, action)
            if check is None and callable(action.type) and _yields_a_number(action.type):
                check = action.type
            if check is not None:
                out.append((prog, action.option_strings[-1], check, action.nargs))
    return out


NUMERIC = _numeric_options()
# Options whose range holds 0, which then means zero (or what the help says), not a default.
ZERO_MEANS_ZERO = {('hydropump design', '--t-d'), ('hydropump fit', '--td-bounds'),
                   ('hydropump-graph', '--real-time-factor')}
# No upper end: more graphs than CPUs are capped, with a note (tested below).
UNBOUNDED = {('hydropump-demo', '--jobs')}


def test_the_numeric_options_are_found_and_each_checked():
    found = {(prog, opt) for prog, opt, _, _ in NUMERIC}
    assert len(found) >= 15
    assert {('hydropump fit', '--dt'), ('hydropump-demo', '--sets'),
            ('hydropump-demo', '--dwell'), ('hydropump-demo', '--jobs'),
            ('hydropump fit', '--start')} <= found
    assert ZERO_MEANS_ZERO | UNBOUNDED <= found
    unchecked = [(prog, opt) for prog, opt, check, _ in NUMERIC
                 if not isinstance(check, (Number, Numbers))]
    assert not unchecked, f'type=float or int without a range check: {unchecked}'


class AcceptedError(Exception):
    """A bad number got through the parser: the command would have run."""


def _accepted(*args, **kwargs):
    raise AcceptedError


@pytest.fixture
def guarded(monkeypatch, tmp_path):
    """The programs' ``main`` with their work replaced by :class:`AcceptedError`."""
    real = cli.build_parser

    def build():
        ap = real()
        for p in _subcommands(ap).values():
            p.set_defaults(func=_accepted)
        return ap
    monkeypatch.setattr(cli, 'build_parser', build)
    monkeypatch.setattr(campaign, 'run_folder', lambda out: tmp_path)
    monkeypatch.setattr(campaign, 'run', _accepted)
    monkeypatch.setattr(graph, 'graph_commands', _accepted)
    return {'hydropump': cli.main, 'hydropump-demo': campaign.main,
            'hydropump-graph': graph.main}


def _positionals(parser) -> list[str]:
    """A made-up value of each required positional, so that only the number can be wrong."""
    return [f'/nonexistent/{a.dest}' for a in parser._actions
            if not a.option_strings and a.required]


def _argv(prog: str, option: str, values: list[str]) -> tuple:
    parser, head = PARSERS[prog]
    return prog.split()[0], [*head, option, *values, *_positionals(parser)]


HUGE_INT = '9' * 400  # a whole number, too large for a float
CASES = [(prog, opt, bad) for prog, opt, check, nargs in NUMERIC
         for bad in ('nan', 'inf', '0', '-1', '1e300', HUGE_INT)
         if not (bad == '0' and (prog, opt) in ZERO_MEANS_ZERO and nargs is None)
         and not ((prog, opt) in UNBOUNDED and bad == HUGE_INT)]


@pytest.mark.parametrize('prog, option, bad', CASES,
                         ids=[f'{p} {o} {b if b != HUGE_INT else "9...9"}' for p, o, b in CASES])
def test_a_bad_number_is_one_error_line_naming_the_option(guarded, capsys, prog, option, bad):
    nargs = next(n for p, o, _, n in NUMERIC if (p, o) == (prog, option))
    # Every value of a multi-value option is the bad one: 0 0 fails LO < HI where 0 is fine.
    program, argv = _argv(prog, option, [bad] * (nargs if isinstance(nargs, int) else 1))
    code = guarded[program](argv)
    out, err = capsys.readouterr()
    assert code == 2 and out == ''
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f'error: {option} {bad}'), err
    assert 'expected' in lines[0] and 'Traceback' not in err


@pytest.mark.parametrize('prog, option', sorted(ZERO_MEANS_ZERO))
def test_zero_is_taken_as_zero_where_the_range_holds_it(prog, option):
    parser, head = PARSERS[prog]
    action = next(a for a in parser._actions if option in a.option_strings)
    values = ['0', '0.1'][:action.nargs if isinstance(action.nargs, int) else 1]
    args = parser.parse_args([option, *values, *_positionals(parser)])
    value = getattr(args, action.dest)
    assert (value[0] if isinstance(value, list) else value) == 0.0


def test_the_error_line_says_what_is_accepted(guarded, capsys):
    assert guarded['hydropump'](['fit', '--dt', '1e-9', 'bag']) == 2
    assert capsys.readouterr().err == \
        'error: --dt 1e-9: expected a finite number from 0.0001 to 0.1 (s)\n'
    assert guarded['hydropump'](['fit', '--td-bounds', '0.2', '0.1', 'bag']) == 2
    assert capsys.readouterr().err == 'error: --td-bounds 0.2 0.1: expected LO < HI\n'
    assert guarded['hydropump-demo'](['--sets', '-3']) == 2
    assert capsys.readouterr().err == 'error: --sets -3: expected a whole number from 1 to 100\n'


def test_the_installed_command_refuses_a_number_in_one_line():
    proc = _run('hydropump', 'fit', '--dt', '1e-9', 'bag')
    assert proc.returncode == 2 and proc.stdout == ''
    assert proc.stderr == 'error: --dt 1e-9: expected a finite number from 0.0001 to 0.1 (s)\n'


# ---- hydropump-demo: the run folder and --jobs, before anything starts ----------------------

def _readonly(tmp_path):
    if os.geteuid() == 0:
        pytest.skip('root writes in a read-only folder')
    path = tmp_path / 'ro'
    path.mkdir(mode=0o555)
    return path


@pytest.mark.parametrize('where, words', [
    ('file', 'is a file'), ('/proc', 'cannot write there'), ('/proc/1/new', 'cannot write'),
    ('readonly', 'cannot write there'), ('bags', 'already holds the bags of an earlier run'),
])
def test_demo_refuses_a_run_folder_it_cannot_use(tmp_path, where, words):
    if where == 'file':
        where = tmp_path / 'file'
        where.write_text('')
    elif where == 'readonly':
        where = _readonly(tmp_path) / 'run'
    elif where == 'bags':
        where = tmp_path / 'old'
        (where / 'bags' / 'ident_1').mkdir(parents=True)
    proc = _run('hydropump-demo', '--quick', '--out', str(where))
    assert proc.returncode == 2 and proc.stdout == '', proc.stdout  # no run folder line
    assert proc.stderr.splitlines() == [proc.stderr.strip()], proc.stderr
    assert proc.stderr.startswith(f'error: --out {where}: {words}'), proc.stderr


def test_demo_caps_jobs_at_the_cpus_with_a_note(tmp_path):
    (tmp_path / 'file').write_text('')
    # The folder check comes after the note and ends the run before anything starts.
    proc = _run('hydropump-demo', '--jobs', '100000', '--out', str(tmp_path / 'file'))
    cpus = os.cpu_count() or 1
    assert proc.returncode == 2 and proc.stdout == ''
    assert proc.stderr.splitlines() == [
        f'note: --jobs 100000: this machine runs {cpus} graph{"s" * (cpus != 1)} at once; '
        f'using {cpus}', f'error: --out {tmp_path / "file"}: is a file; give a folder for the '
        'run'], proc.stderr


def test_a_closed_pipe_ends_the_output_quietly():
    # `hydropump design --dry-run | head -1`: the report comes after the reader has gone.
    proc = subprocess.Popen([str(BIN / 'hydropump'), 'design', '--dry-run'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().startswith('plant: ')
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=60) == 141 and 'Traceback' not in err, err
