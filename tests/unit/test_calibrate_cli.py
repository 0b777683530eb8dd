"""``hydropump calibrate`` and ``validate`` as a user runs them: one ``error:`` line and exit
code 2 for every bad input, nothing written over what the user gave, and ``--help`` for
both. The bags are written as the recorder writes them."""

import subprocess
import sys

import numpy as np
import pytest

from hydropump_ctrl.bag import write_bag
from hydropump_ctrl.batch import cores
from hydropump_ctrl.cli import main

from ..conftest import ROOT

F64, PRESSURE = 'std_msgs/msg/Float64', 'sensor_msgs/msg/FluidPressure'


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """A small bag: a current step and a flat flow and line pressure."""
    path = tmp_path_factory.mktemp('bags') / 'run'
    t = 1.0 + np.arange(1500) * 1e-3
    write_bag(path, {'/solenoid_current': (F64, t, np.where(t < 1.5, 0.46, 0.54)),
                     '/line_flow': (F64, t, np.full(t.size, 5.6e-4)),
                     '/line_pressure': (PRESSURE, t, np.full(t.size, 1.5e7))})
    return path


def _copy(src, folder):
    out = folder / src.name
    out.write_text(src.read_text())
    return out


def _run(capsys, *args):
    code = main(list(args))
    err = capsys.readouterr().err
    return code, err


def _mine(folder, name):
    """``folder`` with a file of the user's own called ``name``."""
    (folder / name).write_text('my own notes\n')
    return folder


@pytest.mark.parametrize('make, text', [
    (lambda tmp, bag: ['--out', str(bag / 'metadata.yaml')], 'lies inside the input'),
    (lambda tmp, bag: ['--params', str(tmp / 'start.yaml'), '--out', str(tmp / 'start.yaml')],
     'it is one of the inputs'),
    (lambda tmp, bag: ['--report', str(bag)], 'it is one of the inputs'),
    (lambda tmp, bag: ['--prior', 'line.V_l=5e-4'], '--prior line.V_l=5e-4: expected'),
    (lambda tmp, bag: ['--prior', 'line.V_l=5e-4+-10%'], 'not a free parameter'),
    # An existing file of another kind is never replaced by a params file.
    (lambda tmp, bag: ['--out', str(_copy(ROOT / 'config' / 'controller.yaml', tmp))],
     'holds controller params, not plant params'),
    (lambda tmp, bag: ['--out', str(_copy(ROOT / 'config' / 'bench.yaml', tmp))],
     'not plant params'),
    (lambda tmp, bag: ['--workers', '0'], '--workers 0: expected a whole number from 1'),
    # A local cluster of 1000 processes on this machine's cores is refused, not spawned.
    (lambda tmp, bag: ['--workers', '1000'],
     f'--workers 1000: a local cluster of at most {2 * cores()} workers here'),
    (lambda tmp, bag: ['--in-process', '--scheduler', 'tcp://127.0.0.1:9'], 'choose one'),
    (lambda tmp, bag: ['--fleet', str(tmp)], 'not both'),
    (lambda tmp, bag: ['--bandwidth', '5'], '--bandwidth goes with --fidelity simplified'),
    (lambda tmp, bag: ['--fidelity', 'simplified', '--fmu', str(tmp / 'pump.fmu')],
     'goes with the bags of one pump'),
    (lambda tmp, bag: ['--fidelity', 'simplified', '--free', 'spool.m_c'],
     'spool.m_c: not in the simplified pump (eq. 10 makes the spool and plate static)'),
    # A report folder holding the user's own report.md: refused before any calibration.
    (lambda tmp, bag: ['--report', str(_mine(tmp, 'report.md'))],
     'exists and is not a calibration report this suite wrote: not replaced'),
    (lambda tmp, bag: ['--report', str(_mine(tmp, 'result.json'))],
     'exists and is not a calibration result this suite wrote'),
])
def test_bad_calibrate_options_get_one_line_and_nothing_is_written(bag, tmp_path, capsys,
                                                                  make, text):
    start = tmp_path / 'start.yaml'
    start.write_text((ROOT / 'config' / 'pump.yaml').read_text())
    extra = make(tmp_path, bag)
    before = {p: p.read_bytes() for p in [*tmp_path.iterdir(), *bag.iterdir()] if p.is_file()}
    code, err = _run(capsys, 'calibrate', str(bag), '--free', 'line.mu_u',
                     '--report', str(tmp_path / 'rep'), *extra)
    assert code == 2 and err.startswith('error: ') and text in err, err
    assert len(err.strip().splitlines()) == 1
    assert {p: p.read_bytes() for p in before} == before   # nothing over an input
    assert set(bag.iterdir()) == {p for p in before if p.parent == bag}


def test_empty_truncated_and_two_run_bags_get_one_line(bag, tmp_path, capsys):
    empty = tmp_path / 'empty'
    empty.mkdir()
    cut = tmp_path / 'cut'
    cut.mkdir()
    data = next(bag.glob('*.mcap')).read_bytes()
    (cut / 'cut_0.mcap').write_bytes(data[:200])
    two = tmp_path / 'two'
    t = 1.0 + np.arange(1500) * 1e-3
    tt = np.concatenate([t, t])              # a restarted simulator: time goes back
    write_bag(two, {'/solenoid_current': (F64, tt, np.where(tt < 1.5, 0.46, 0.54)),
                    '/line_flow': (F64, tt, np.full(tt.size, 5.6e-4))}, storage='sqlite3')
    for path, text in ((empty, ''), (cut, ''), (two, 'time goes back')):
        code, err = _run(capsys, 'calibrate', str(path), '--free', 'line.mu_u', '--report',
                         str(tmp_path / 'rep'))
        assert code == 2 and err.startswith('error: '), (path, err)
        assert len(err.strip().splitlines()) == 1 and text in err, (path, err)


def test_help_of_both_commands_works():
    for cmd in ('calibrate', 'validate'):
        proc = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', cmd, '--help'],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0 and 'usage: hydropump' in proc.stdout, proc.stderr


def test_the_reports_say_where_they_came_from(bag, tmp_path, capsys):
    """calibrate and validate: the JSON on stdout, result.json / validation.json and the
    report pages carry the provenance (date, command, commit, versions, the params file's
    SHA-256); the calibrated file's header carries it as a comment."""
    import json

    from ..conftest import assert_provenance
    start = tmp_path / 'start.yaml'
    start.write_text((ROOT / 'config' / 'pump.yaml').read_text())
    rep = tmp_path / 'rep'
    code = main(['calibrate', str(bag), '--free', 'line.mu_u', '--params', str(start),
                 '--report', str(rep), '--no-plots', '--no-progress', '--json',
                 '--no-multistart'])     # what is judged is the provenance, not the fit
    out = capsys.readouterr().out
    assert code == 0
    for prov in (json.loads(out)['provenance'],
                 json.loads((rep / 'result.json').read_text())['provenance']):
        assert_provenance(prov, [start], ['calibrate', '--free line.mu_u'])
    assert '## Provenance' in (rep / 'report.md').read_text()
    header = (rep / 'calibrated.yaml').read_text().split('/**')[0]
    assert '# command: hydropump calibrate' in header and '# date 20' in header
    val = tmp_path / 'val'
    code = main(['validate', str(bag), '--params', str(rep / 'calibrated.yaml'), '--out',
                 str(val), '--no-plots', '--json'])
    out = capsys.readouterr().out
    assert code == 0
    for prov in (json.loads(out)['provenance'],
                 json.loads((val / 'validation.json').read_text())['provenance']):
        assert_provenance(prov, [rep / 'calibrated.yaml', start], ['validate'])
    assert '## Provenance' in (val / 'validation.md').read_text()


def test_the_bench_profile_stays_out_of_the_calibrated_file(bag, tmp_path, capsys):
    """calibrate --profile config/bench.yaml: the bench's dither is layered over the start
    for the fit, as the simulator node layers it, but the calibrated file describes the pump:
    its dither is the start's, and the header says why."""
    from hydropump_sim.params import load_params
    from hydropump_sim.sensors import load_profile
    profile = ROOT / 'config' / 'bench.yaml'
    over = load_profile(profile).plant_overrides
    start = load_params(ROOT / 'config' / 'pump.yaml').flat()
    assert any(over[k] != start[k] for k in over)   # the bench does change the plant
    code = main(['calibrate', str(bag), '--free', 'line.mu_u', '--profile', str(profile),
                 '--report', str(tmp_path / 'rep'), '--no-plots', '--no-progress',
                 '--no-multistart'])     # what is judged is the file, not the fit
    capsys.readouterr()
    assert code == 0
    out = tmp_path / 'rep' / 'calibrated.yaml'
    written = load_params(out).flat()
    assert all(written[k] == start[k] for k in over), {k: written[k] for k in over}
    assert 'the profile keeps the bench' in out.read_text().split('/**')[0]
