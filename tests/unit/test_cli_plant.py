"""`hydropump analyze` and `hydropump simulate` as a user runs them."""

from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from hydropump_ctrl.cli import main
from hydropump_sim.model import OUTPUTS


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', *args],
                          capture_output=True, text=True, cwd=cwd, timeout=240)


def test_analyze_prints_the_figures_and_writes_plots(tmp_path: Path):
    proc = _run('analyze', '--out', str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout
    assert 'P_a = 19.999 bar' in out and 'P_l = 150.017 bar' in out
    assert 'time constant S_a/(mu_a r) = 95.239 ms' in out
    assert 'tau_z = S_a/b_p = 10.053 ms' in out
    assert 'G0 = 100.000' in out
    for name in ('analysis.txt', 'steps.png', 'bode.png'):
        assert (tmp_path / name).stat().st_size > 1000


def test_simulate_scenario_to_csv_and_npz(tmp_path: Path):
    sc = tmp_path / 'step.yaml'
    sc.write_text('duration: 0.3\ninputs:\n  current: {steps: [[0.0, 0.46], [0.05, 0.54]]}\n')
    proc = _run('simulate', str(sc), '--out', str(tmp_path / 'r.csv'))
    assert proc.returncode == 0, proc.stderr
    data = np.genfromtxt(tmp_path / 'r.csv', delimiter=',', names=True)
    assert len(data) == 301
    assert (tmp_path / 'r.png').stat().st_size > 1000
    proc = _run('simulate', str(sc), '--out', str(tmp_path / 'r.npz'))
    assert proc.returncode == 0, proc.stderr
    with np.load(tmp_path / 'r.npz') as d:
        assert list(d['outputs']) == list(OUTPUTS)
        q_l = d['y'][:, OUTPUTS.index('q_l')]
    assert np.allclose(q_l, data[data.dtype.names[OUTPUTS.index('q_l') + 1]], rtol=1e-8)


def test_simulate_bad_scenario_is_one_line_per_problem(tmp_path: Path):
    sc = tmp_path / 'bad.yaml'
    sc.write_text('duration: 0.3\ninputs:\n  current: fast\n  aperture: 1.5\n')
    proc = _run('simulate', str(sc))
    assert proc.returncode == 2
    assert 'Traceback' not in proc.stderr
    assert "error: inputs.current = 'fast': expected a finite number" in proc.stderr
    proc = _run('simulate', str(tmp_path / 'missing.yaml'))
    assert proc.returncode == 2 and 'cannot read' in proc.stderr


# ---- bad input: one line naming the value and what is accepted, exit code 2 -------------------

def _main(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err.strip().splitlines()


@pytest.mark.parametrize('value', ['0', '-1', 'nan', 'inf', '2'])
def test_analyze_refuses_a_period_that_is_not_a_positive_number(capsys, tmp_path, value):
    code, out, err = _main(capsys, 'analyze', '--T', value, '--out', str(tmp_path / 'a'))
    assert code == 2 and out == ''
    assert err == [f'error: --T {value}: expected a finite number from 0.0001 to 1 (s)']
    assert not (tmp_path / 'a').exists()


@pytest.mark.parametrize('grid', ['dt_out: 1.0e-9\nduration: 0.3', 'duration: 1.0e+7'])
def test_simulate_refuses_a_grid_too_large_for_memory(capsys, tmp_path, grid):
    sc = tmp_path / 'big.yaml'
    sc.write_text(f'{grid}\ninputs:\n  current: 0.5\n')
    code, out, err = _main(capsys, 'simulate', str(sc), '--out', str(tmp_path / 'r.csv'))
    assert code == 2 and out == ''
    assert len(err) == 1 and err[0].startswith('error: duration = ')
    assert 'samples' in err[0] and 'at most' in err[0]
    assert not (tmp_path / 'r.csv').exists()


@pytest.mark.parametrize('option, name, words', [
    ('--out', 'r.txt', 'output {}: use a .csv or .npz file name'),
    ('--out', 'folder.csv', 'output {}: is a folder, expected a file name'),
    ('--plot', 'p.gif', 'plot {}: use a .png, .pdf, .svg, .jpg or .jpeg file name'),
    ('--out', 'file/r.csv', 'cannot create the folder of the output {}: a file of that name'),
])
def test_simulate_checks_its_output_names_before_the_run(capsys, tmp_path, option, name,
                                                          words):
    sc = tmp_path / 'step.yaml'
    sc.write_text('duration: 0.05\ninputs:\n  current: 0.5\n')
    (tmp_path / 'folder.csv').mkdir()
    (tmp_path / 'file').write_text('')
    target = tmp_path / name
    code, out, err = _main(capsys, 'simulate', str(sc), option, str(target))
    what = target.parent if name.startswith('file/') else target
    assert code == 2 and out == '' and len(err) == 1
    assert err[0].startswith('error: ' + words.format(what)), err


def test_analyze_refuses_an_output_folder_that_is_a_file(capsys, tmp_path):
    (tmp_path / 'taken').write_text('')
    code, out, err = _main(capsys, 'analyze', '--out', str(tmp_path / 'taken'))
    assert code == 2 and out == ''
    assert err == [f'error: cannot create the output folder {tmp_path / "taken"}: a file of '
                   'that name exists']
