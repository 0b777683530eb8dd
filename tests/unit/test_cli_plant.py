"""`hydropump analyze` and `hydropump simulate` as a user runs them."""

from pathlib import Path
import subprocess
import sys

import numpy as np

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
