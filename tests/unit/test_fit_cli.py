"""``hydropump fit BAG...``: JSON result, report folder, progress bar and bad input."""

import json
import math
from pathlib import Path
import subprocess
import sys

import numpy as np
import pytest

from hydropump_ctrl.cli import main
from hydropump_ctrl.ident import recording_to_bag, write_bag
from hydropump_ctrl.ident import synthetic as syn

TRUTH = syn.Truth(100.0, 0.100, 0.055)
HYDROPUMP = Path(sys.executable).parent / 'hydropump'


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    base = tmp_path_factory.mktemp('bags')
    recs, _ = syn.paper_set(seed=21, n=3, duration=8.0)
    paths = []
    for i, rec in enumerate(recs):
        paths.append(str(recording_to_bag(rec, base / f'run{i}', start_s=50.0,
                                          storage='sqlite3' if i == 2 else 'mcap',
                                          namespace='bench' if i == 1 else '')))
    return paths


def _run(capsys, *argv):
    code = main(['fit', *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_json_result_per_bag_and_pooled(bags, capsys):
    code, out, err = _run(capsys, *bags, '--json', '--no-report', '--no-progress')
    assert code == 0
    res = json.loads(out)
    assert res['schema'] == 'hydropump-fit/1' and res['method'] == 'robust'
    assert res['units']['tau'] == 's' and res['units']['td'] == 's'
    assert res['normalisation'] == {'current_range_A': [0.3, 0.7],
                                    'flow_full_scale_m3s': pytest.approx(1.125e-3)}
    assert [s['name'] for s in res['sets']] == ['run0', 'run1', 'run2']
    for s in res['sets']:
        for p in ('G0', 'tau', 'td'):
            assert abs(s[p] - getattr(TRUTH, p)) <= 4 * s[f'{p}_se'], (s['name'], p)
            assert s[f'{p}_se'] > 0 and s[f'{p}_se_white'] > 0
        assert s['fit_percent'] > 90 and s['flags'] == [] and s['truncated'] is False
        assert s['whiteness']['ok'] and s['cross']['ok']
        assert s['dither'][0]['freq'] == pytest.approx(150.0, abs=0.05)
    assert res['sets'][1]['topics']['flow'] == '/bench/line_flow'
    po = res['pooled']
    assert po['n_sets'] == 3 and po['flags'] == []
    for p in ('G0', 'tau', 'td'):
        vals = [s[p] for s in res['sets']]
        assert po[p] == pytest.approx(np.mean(vals))
        assert po[f'{p}_std'] == pytest.approx(np.std(vals, ddof=1))
        assert po[f'{p}_se'] == pytest.approx(po[f'{p}_std'] / math.sqrt(3))
        assert abs(po['joint'][p] - getattr(TRUTH, p)) <= 4 * po['joint'][f'{p}_se']
    assert res['paper'] == {'G0': 100.0, 'G0_std': 0.7, 'tau': 0.1, 'tau_std': 0.002,
                            'td': 0.055, 'td_std': 0.0055}


def test_report_folder_and_progress_bar(bags, capsys, tmp_path):
    out_dir = tmp_path / 'report'
    code, out, err = _run(capsys, *bags[:2], '--out', str(out_dir), '--progress')
    assert code == 0
    assert 'pooled mean ± std (n=2)' in out and 'paper (9 sets' in out
    assert 'read' in err and 'bag' in err            # the tqdm bar went to stderr
    res = json.loads((out_dir / 'result.json').read_text())
    assert len(res['sets']) == 2
    md = (out_dir / 'report.md').read_text()
    assert '| run0 |' in md and '![fig5](fig5.png)' in md and '![fig6](fig6.png)' in md
    for name in ('fig5.png', 'fig6.png'):
        data = (out_dir / name).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 10_000
    assert not list(out_dir.glob('fig5_*.png'))


@pytest.mark.parametrize('name', ['report.md', 'result.json'])
def test_a_folder_with_the_users_own_report_is_not_written_into(bags, capsys, tmp_path, name):
    """A folder that holds a report.md or result.json the fit did not write: one line,
    nothing replaced, no figure written; the fit's own files are replaced on a re-run."""
    mine = tmp_path / name
    mine.write_text('my own notes\n')
    code, _, err = _run(capsys, bags[0], '--out', str(tmp_path), '--no-progress')
    assert code == 2 and err.strip().count('\n') == 0, err
    assert f'{mine} exists and is not a fit' in err and 'not replaced' in err
    assert mine.read_text() == 'my own notes\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]
    mine.unlink()
    for _ in range(2):
        assert _run(capsys, bags[0], '--out', str(tmp_path), '--no-progress')[0] == 0


def test_per_set_figures_on_request(bags, capsys, tmp_path):
    code, _, _ = _run(capsys, bags[0], '--out', str(tmp_path), '--plots-per-set',
                      '--no-progress')
    assert code == 0
    for name in ('fig5.png', 'fig6.png', 'fig5_run0.png', 'fig6_run0.png'):
        assert (tmp_path / name).read_bytes()[:4] == b'\x89PNG'
    assert '![fig5_run0](fig5_run0.png)' in (tmp_path / 'report.md').read_text()


def test_paper_method_from_the_command_line(bags, capsys):
    code, out, _ = _run(capsys, bags[0], '--method', 'paper', '--json', '--no-report',
                        '--no-progress')
    assert code == 0
    res = json.loads(out)
    s = res['sets'][0]
    assert res['method'] == 'paper' and len(s['seed']) == 3
    assert abs(s['td'] - TRUTH.td) <= 1e-3 and abs(s['tau'] - TRUTH.tau) <= 2e-3
    assert res['pooled']['flags'] == ['single_set'] and res['pooled']['G0_std'] is None


@pytest.fixture(scope='module')
def bad_inputs(tmp_path_factory, bags):
    base = tmp_path_factory.mktemp('bad')
    flat = syn.make_record(TRUTH, seed=1, duration=4.0, steps=[(-math.inf, 0.5)])
    recording_to_bag(flat, base / 'flat')
    t = np.arange(2000) * 1e-3
    cur = 0.46 + 0.08 * (t > 1.0)
    flow = 1e-4 * np.ones_like(t)
    flow[1500] = np.nan
    write_bag(base / 'nan', {'/solenoid_current': ('std_msgs/msg/Float64', t, cur),
                             '/line_flow': ('std_msgs/msg/Float64', t, flow)})
    src = Path(bags[0])
    cut = base / 'cut'
    cut.mkdir()
    rec = syn.make_record(TRUTH, seed=2, duration=30.0)
    full = recording_to_bag(rec, base / 'full')
    data = next(full.glob('*.mcap')).read_bytes()
    (cut / 'cut.mcap').write_bytes(data[:int(0.75 * len(data))])
    (base / 'notes.txt').write_text('not a bag\n')
    return {'flat': base / 'flat', 'nan': base / 'nan', 'cut': cut,
            'text': base / 'notes.txt', 'missing': base / 'nothing-here', 'good': src}


@pytest.mark.parametrize('case, extra, expect', [
    ('good', ['--flow-topic', 'pump_flow'],
     "has no topic 'pump_flow'; it has: /line_flow (std_msgs/msg/Float64), /solenoid_current"),
    ('flat', [], 'no excitation'),
    ('nan', [], '/line_flow has 1 NaN'),
    ('cut', [], 'truncated'),
    ('text', [], 'is not a rosbag2 bag'),
    ('missing', [], 'no such file or directory'),
    ('good', ['--lowpass-flow', '20'], 'flow alone is filtered'),
    ('good', ['--td-bounds', '0.3', '0.1'], '--td-bounds 0.3 0.1: expected LO < HI'),
    ('good', ['--tau-bounds', '0.01', 'inf'],
     '--tau-bounds 0.01 inf: HI = inf, expected a finite number > 0 and <= 10 (s)'),
    ('good', ['--start', 'nan', '0.1', '0.05'], '--start nan 0.1 0.05: G0 = nan, expected a '
     'finite number > 0'),
    ('good', ['--start', '100', '-0.1', '0.05'], '--start 100 -0.1 0.05: TAU = -0.1, expected '
     'a finite number > 0 and <= 10 (s)'),
    ('good', ['--dt', 'nan'], '--dt nan: expected a finite number from 0.0001 to 0.1 (s)'),
    ('good', ['--dt', '0'], '--dt 0: expected a finite number from 0.0001 to 0.1 (s)'),
    ('good', ['--dt', '1e-9'], '--dt 1e-9: expected a finite number from 0.0001 to 0.1 (s)'),
])
def test_bad_input_is_one_line_and_exit_code_2(bad_inputs, capsys, case, extra, expect):
    code, out, err = _run(capsys, str(bad_inputs[case]), *extra, '--no-report',
                          '--no-progress')
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('error: '), err
    assert expect in lines[0]
    assert 'Traceback' not in err and out == ''


def test_truncated_bag_is_fitted_when_allowed(bad_inputs, capsys):
    code, out, err = _run(capsys, str(bad_inputs['cut']), '--allow-truncated', '--json',
                          '--no-report', '--no-progress')
    assert code == 0
    s = json.loads(out)['sets'][0]
    assert s['truncated'] is True and 'truncated_bag' in s['flags']
    assert any('no footer' in n for n in s['notes'])
    assert abs(s['td'] - TRUTH.td) <= 1e-3
    assert err.startswith('warning: ') and 'truncated' in err


def test_flow_only_filter_is_flagged_when_allowed(bad_inputs, capsys):
    code, out, _ = _run(capsys, str(bad_inputs['good']), '--lowpass-flow', '20',
                        '--allow-flow-filter', '--json', '--no-report', '--no-progress')
    assert code == 0
    s = json.loads(out)['sets'][0]
    assert 'flow_only_filter' in s['flags'] and s['td'] > TRUTH.td + 5e-3


def test_installed_command_exits_2_without_traceback(tmp_path):
    (tmp_path / 'x.txt').write_text('hello')
    proc = subprocess.run([str(HYDROPUMP), 'fit', str(tmp_path / 'x.txt')],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().startswith('error: ') and len(proc.stderr.splitlines()) == 1
    assert 'Traceback' not in proc.stderr


def test_the_fit_report_says_where_it_came_from(bags, capsys, tmp_path):
    from ..conftest import assert_provenance, ROOT
    code, out, _ = _run(capsys, *bags, '--json', '--out', str(tmp_path / 'rep'), '--no-plots',
                        '--no-progress')
    assert code == 0
    for prov in (json.loads(out)['provenance'],
                 json.loads((tmp_path / 'rep' / 'result.json').read_text())['provenance']):
        assert_provenance(prov, [ROOT / 'config' / 'pump.yaml'], ['fit'])
    assert '## Provenance' in (tmp_path / 'rep' / 'report.md').read_text()


def test_growing_and_falling_flow_sets_are_not_pooled(tmp_path, capsys):
    """A set whose steps all go up (eq. 14's branch) and one whose steps all go down (eq.
    15's) have different time constants: pooled, their mean is neither. Refused in one line
    naming the sets of each branch; each branch alone fits."""
    up = syn.make_record(TRUTH, seed=3, duration=8.0, name='up',
                         steps=[(0.0, 0.3), (2.0, 0.45), (4.0, 0.6), (6.0, 0.75)])
    down = syn.make_record(TRUTH, seed=4, duration=8.0, name='down',
                           steps=[(0.0, 0.75), (2.0, 0.6), (4.0, 0.45), (6.0, 0.3)])
    bags = [str(recording_to_bag(r, tmp_path / r.name, start_s=50.0)) for r in (up, down)]
    code, _, err = _run(capsys, *bags, '--no-report', '--no-progress')
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert 'mix growing-flow steps (up) and falling-flow steps (down)' in err, err
    for bag in bags:
        code, _, err = _run(capsys, bag, '--no-report', '--no-progress')
        assert code == 0, err
