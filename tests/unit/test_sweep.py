"""``hydropump sweep``: parameter sweeps on Dask distributed.

Truth from outside the sweep code: eq. 14 (tau = S_a (1 + K_c/K_a) / (mu_a sqrt(P_a)) at a
fixed operating point: tau proportional to 1/mu_a, independent of the line volume V_l), the
schema's cross-check of the actuator volume (params.py), and the runs themselves counted
from the files the sweep leaves.
"""

import os
from pathlib import Path
import signal
import time

import numpy as np
import pytest

from hydropump_ctrl.cli import main
from hydropump_ctrl.sweep import read_table, run_sweep, sensitivities, sweep_from_dict

from ..daskprocs import external_cluster

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / 'config'

pytestmark = pytest.mark.timeout(120)

EXPERIMENT = {'duration': 1.5, 'current': {'step': {'from': 0.4, 'to': 0.6, 'at': 0.3}}}


def spec(**kw):
    doc = {'params': 'pump.yaml', 'experiment': EXPERIMENT, 'outputs': ['fopdt']}
    doc.update(kw)
    return sweep_from_dict(doc, CONFIG, 'test')


@pytest.fixture(scope='module')
def client():
    from hydropump_ctrl.sweep import open_client
    c, cluster = open_client(None, 2)
    yield c
    c.close()
    cluster.close()


def test_tau_moves_as_one_over_mu_a(client, tmp_path):
    sw = spec(grid={'relative': True, 'parameters': {'actuator.mu_a': [0.9, 1.0, 1.1]}})
    run_sweep(sw, tmp_path, client=client, progress=False, report=False)
    cols = read_table(tmp_path / 'runs.parquet')
    assert list(cols['status']) == ['ok'] * 3
    mu = cols['actuator.mu_a']
    tau = cols['fopdt_tau']
    # eq. 14: tau * mu_a is the same for every run.
    for k in (0, 2):
        assert tau[k] / tau[1] == pytest.approx(mu[1] / mu[k], rel=0.02)
    assert tau[1] == pytest.approx(0.100, abs=0.003)   # the plant's design point (D2)


def test_the_simplified_fidelity_runs_eq_10_and_keeps_eq_14(client, tmp_path):
    # Section IV on the pump at 20 Hz: its spool and plate (about 2 ms) made static, eq. 10;
    # the actuator's lag of eq. 14 is kept, so tau still goes as 1/mu_a.
    sw = spec(experiment={**EXPERIMENT, 'fidelity': 'simplified'},
              grid={'relative': True, 'parameters': {'actuator.mu_a': [0.9, 1.0, 1.1]}})
    assert sw.experiment.model == 'simplified_Kc'
    assert 'pump made static; error bound' in sw.experiment.fidelity
    run_sweep(sw, tmp_path, client=client, progress=False, report=False)
    cols = read_table(tmp_path / 'runs.parquet')
    mu, tau = cols['actuator.mu_a'], cols['fopdt_tau']
    for k in (0, 2):
        assert tau[k] / tau[1] == pytest.approx(mu[1] / mu[k], rel=0.02)
    assert tau[1] == pytest.approx(0.100, abs=0.003)


def test_tornado_names_mu_a_for_tau_and_not_the_line_volume(client, tmp_path):
    # eq. 14 has no V_l: the line pole (~3.6 ms) is far faster than tau (100 ms).
    sw = spec(latin_hypercube={'n': 12, 'seed': 3, 'relative': True,
                               'bounds': {'actuator.mu_a': [0.85, 1.15],
                                          'line.V_l': [0.7, 1.3]}})
    run_sweep(sw, tmp_path, client=client, progress=False, report=True)
    cols = read_table(tmp_path / 'runs.parquet')
    s = sensitivities(sw, cols)['fopdt_tau']['src']
    assert s['actuator.mu_a'] < -0.9          # more orifice, faster
    assert abs(s['line.V_l']) < 0.1
    html = (tmp_path / 'report.html').read_text()
    assert 'tornado' in html and html.count('data:image/png') >= 3
    # Where it came from, on the page and in the numbers.
    import json

    from ..conftest import assert_provenance
    assert '<h2>Provenance</h2>' in html
    saved = json.loads((tmp_path / 'sensitivities.json').read_text())
    assert saved['outputs']['fopdt_tau']['src']['actuator.mu_a'] == pytest.approx(
        s['actuator.mu_a'])
    assert_provenance(saved['provenance'])


def _v_a0_spec():
    # The schema refuses an actuator volume that leaves no more than V_a_min at full stroke.
    return spec(grid={'parameters': {'actuator.V_a0': [8.0e-6, 2.0e-6, 7.0e-6]}},
                outputs=[{'peak': 'P_l'}, {'final': 'q_l'}])


def test_a_refused_run_is_recorded_and_the_sweep_goes_on_and_resumes(client, tmp_path):
    from hydropump_sim import load_params
    p = load_params(CONFIG / 'pump.yaml')
    left = np.array([8.0e-6, 2.0e-6, 7.0e-6]) - p.actuator.S_a * p.x_a_stop
    refused = left <= p.actuator.V_a_min
    assert list(refused) == [False, True, False]

    res = run_sweep(_v_a0_spec(), tmp_path, client=client, progress=False, report=True)
    assert (res.executed, res.reused, res.failed) == (3, 0, 1)
    cols = read_table(tmp_path / 'runs.parquet')
    assert list(cols['status']) == ['ok', 'failed', 'ok']
    assert 'V_a_min' in cols['reason'][1] and cols['reason'][0] == ''
    assert np.isnan(cols['peak_P_l'][1]) and np.all(np.isfinite(cols['peak_P_l'][[0, 2]]))
    # Steady flow at 60 % displacement: 0.6 V_p f_p, whatever the actuator volume.
    assert cols['final_q_l'][[0, 2]] == pytest.approx(0.6 * p.Q_max, rel=0.01)

    stamps = {f.name: f.stat().st_mtime_ns for f in (tmp_path / 'runs').iterdir()}
    again = run_sweep(_v_a0_spec(), tmp_path, client=client, progress=False, report=False)
    assert (again.executed, again.reused) == (0, 3)
    assert stamps == {f.name: f.stat().st_mtime_ns for f in (tmp_path / 'runs').iterdir()}
    (tmp_path / 'runs' / '000002.json').unlink()
    third = run_sweep(_v_a0_spec(), tmp_path, client=client, progress=False, report=False)
    assert (third.executed, third.reused) == (1, 2)
    assert list(read_table(tmp_path / 'runs.parquet')['status']) == ['ok', 'failed', 'ok']


def test_same_seed_same_table_on_a_local_cluster_and_on_a_separate_scheduler(client, tmp_path):
    doc = {'distributions': {'n': 6, 'seed': 7, 'parameters': {
        'actuator.mu_a': {'normal': 0.05, 'relative': True},
        'spool.K_a': {'uniform': 0.05, 'relative': True}}},
        'outputs': ['fopdt', 'step', {'peak': 'P_l'}]}
    run_sweep(spec(**doc), tmp_path / 'local', client=client, progress=False, report=False)

    with external_cluster(1) as address:
        run_sweep(spec(**doc), tmp_path / 'remote', address=address, progress=False,
                  report=False)
    # And in this process, no Dask at all.
    here = run_sweep(spec(**doc), tmp_path / 'here', workers=0, progress=False, report=False)
    assert here.where == 'this process'
    a = read_table(tmp_path / 'local' / 'runs.parquet')
    assert list(a['status']) == ['ok'] * 6
    for other in ('remote', 'here'):
        b = read_table(tmp_path / other / 'runs.parquet')
        for name in a:
            if name not in ('wall_s', '__units__'):    # wall time is the only one that differs
                np.testing.assert_array_equal(a[name], b[name], err_msg=f'{other}: {name}')


def test_a_sweep_too_short_for_a_cluster_stays_in_this_process_and_resumes(tmp_path,
                                                                          monkeypatch):
    """Four runs of 1.5 s of simulated time take well under a second each: a local cluster
    could not win back its start-up, so the sweep runs here; the first two runs (the probe)
    count among those executed, and a resumed sweep probes nothing."""
    monkeypatch.delenv('DASK_SCHEDULER_ADDRESS', raising=False)
    sw = spec(grid={'relative': True, 'parameters': {'actuator.mu_a': [0.9, 0.95, 1.0, 1.1]}},
              outputs=[{'final': 'q_l'}])
    res = run_sweep(sw, tmp_path, progress=False, report=False)
    assert res.where == 'this process'
    assert (res.executed, res.reused, res.failed) == (4, 0, 0)
    (tmp_path / 'runs' / '000003.json').unlink()
    again = run_sweep(sw, tmp_path, progress=False, report=False)
    assert (again.executed, again.reused) == (1, 3)
    from hydropump_sim import load_params
    q = read_table(tmp_path / 'runs.parquet')['final_q_l']
    # Steady flow at 60 % displacement whatever the orifice: 0.6 V_p f_p.
    assert q == pytest.approx(0.6 * load_params(CONFIG / 'pump.yaml').Q_max, rel=0.01)


def _cli(capsys, *argv):
    code = main(['sweep', *map(str, argv)])
    return code, capsys.readouterr().err.strip().splitlines()


BAD = {
    'unknown': ({'grid': {'parameters': {'actuator.mu': [1.0e-6]}}},
                'did you mean actuator.mu_a?'),
    'range': ({'latin_hypercube': {'n': 4, 'bounds': {'actuator.mu_a': [1.0e-10, 1.0e-5]}}},
              'outside the accepted range'),
    'zero': ({'distributions': {'n': 0, 'parameters': {'line.V_l': {'normal': 0.05}}}},
             'zero samples'),
    # Too many runs to hold, said before a sample is drawn (each allocated to the OOM).
    'grid': ({'grid': {'parameters': {k: {'from': 0.9, 'to': 1.1, 'n': 1000}
                                      for k in ('actuator.mu_a', 'line.V_l', 'spool.K_a')},
                       'relative': True}},
             'grid: 1e+09 runs, more than the 1e+06 a sweep may hold'),
    'sobol': ({'sobol': {'n': 2 ** 30, 'relative': True,
                         'bounds': {'actuator.mu_a': [0.9, 1.1]}}},
              'sobol.n = 1073741824: 1.07e+09 runs'),
    'lhs': ({'latin_hypercube': {'n': 10 ** 9, 'bounds': {'actuator.mu_a': [1.0e-4, 2.0e-4]}}},
            'latin_hypercube.n = 1000000000: 1e+09 runs'),
    'fidelity': ({'experiment': {**EXPERIMENT, 'fidelity': 'simplified', 'model': 'fine'},
                  'grid': {'parameters': {'actuator.mu_a': [1.0e-6]}}},
                 'experiment: give model or fidelity, not both'),
}


@pytest.mark.parametrize('case', list(BAD))
def test_bad_specs_give_one_line_and_exit_2(case, tmp_path, capsys):
    import yaml
    body, text = BAD[case]
    doc = {'params': str(CONFIG / 'pump.yaml'), 'experiment': EXPERIMENT, 'outputs': ['fopdt'],
           **body}
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(doc))
    code, err = _cli(capsys, path, '--out', tmp_path / 'o', '--no-progress')
    assert code == 2
    assert len(err) == 1 and err[0].startswith('error:') and text in err[0], err
    assert not (tmp_path / 'o').exists()     # refused before any run


def test_unwritable_out_and_unreachable_scheduler(tmp_path, capsys, short_connect):
    (tmp_path / 'file').write_text('')
    code, err = _cli(capsys, CONFIG / 'sweeps' / 'tolerance.yaml', '--out',
                     tmp_path / 'file' / 'sub', '--no-progress')
    assert code == 2 and len(err) == 1 and 'cannot write' in err[0], err
    t0 = time.monotonic()
    address = 'tcp://127.0.0.1:9'
    code, err = _cli(capsys, CONFIG / 'sweeps' / 'tolerance.yaml', '--scheduler', address,
                     '--out', tmp_path / 'o', '--no-progress')
    assert time.monotonic() - t0 < 10.0
    assert code == 2 and len(err) == 1 and address in err[0], err
    assert 'cannot reach the Dask scheduler' in err[0] and 'cannot write' not in err[0]
    assert not list((tmp_path / 'o' / 'runs').glob('*.json'))


def test_a_worker_killed_mid_sweep_loses_no_run(client, tmp_path):
    import threading
    sw = spec(latin_hypercube={'n': 40, 'seed': 5, 'relative': True,
                               'bounds': {'actuator.mu_a': [0.9, 1.1]}},
              outputs=[{'final': 'q_l'}])
    killed = []

    def kill_one():
        t0 = time.monotonic()
        while time.monotonic() - t0 < 20:
            n = len(list((tmp_path / 'runs').glob('*.json')))
            if n >= 4:
                pid = next(iter(client.run(os.getpid).values()))  # a worker of this cluster
                os.kill(pid, signal.SIGKILL)
                killed.append(len(list((tmp_path / 'runs').glob('*.json'))))
                return
            time.sleep(0.005)

    th = threading.Thread(target=kill_one)
    th.start()
    res = run_sweep(sw, tmp_path, client=client, batch=1, progress=False, report=False)
    th.join()
    assert killed and killed[0] < 40, 'no worker was killed in the middle of the sweep'
    assert res.executed == 40 and res.failed == 0
    cols = read_table(tmp_path / 'runs.parquet')
    assert list(cols['run_id']) == list(range(40)) and set(cols['status']) == {'ok'}
    assert len(list((tmp_path / 'runs').glob('*.json'))) == 40


def test_a_full_disk_ends_with_one_line_and_keeps_the_runs_stored(tmp_path, capsys,
                                                                 monkeypatch):
    """The disk fills after the first run is stored: one line, exit 2, and the stored run is
    whole, so the same command resumes from it."""
    import errno

    import yaml

    from hydropump_ctrl.sweep import engine
    store = engine._store
    calls = []

    def store_once(out, row):
        calls.append(row['run_id'])
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        store(out, row)
    monkeypatch.setattr(engine, '_store', store_once)
    path = tmp_path / 'spec.yaml'
    path.write_text(yaml.safe_dump({
        'params': str(CONFIG / 'pump.yaml'), 'experiment': EXPERIMENT, 'outputs': ['fopdt'],
        'grid': {'relative': True, 'parameters': {'actuator.mu_a': [0.95, 1.0, 1.05]}}}))
    code, err = _cli(capsys, path, '--out', tmp_path / 'out', '--workers', 1, '--no-report')
    errors = [ln for ln in err if ln.startswith('error: ')]
    assert code == 2 and len(errors) == 1 and 'No space left on device' in errors[0], err
    assert 'Traceback' not in '\n'.join(err)
    stored = list((tmp_path / 'out' / 'runs').glob('*.json'))
    assert len(stored) == 1 and stored[0].read_text().startswith('{')


def test_morris_screening_by_salib_matches_eq_14(tmp_path):
    """Morris trajectories of mu_a and V_l: r (D + 1) runs; the elementary effects of tau
    follow eq. 14 (tau = tau_0 mu_a0 / mu_a, no V_l), computed here from the sampled inputs
    alone, and V_l screens out."""
    r = 4
    sw = spec(morris={'r': r, 'levels': 4, 'seed': 2, 'relative': True,
                      'bounds': {'actuator.mu_a': [0.85, 1.15], 'line.V_l': [0.7, 1.3]}})
    assert sw.n_runs == r * (2 + 1)
    run_sweep(sw, tmp_path, workers=0, progress=False, report=True)
    cols = read_table(tmp_path / 'runs.parquet')
    assert set(cols['status']) == {'ok'}
    s = sensitivities(sw, cols)['fopdt_tau']
    mu0 = sw.plant.actuator.mu_a
    (lo, hi), _ = sw.problem['bounds']
    effects = []
    for t in range(r):
        x = sw.samples[3 * t:3 * t + 3]
        for a, b in zip(x[:-1], x[1:]):
            if a[0] != b[0]:                      # this step moved mu_a
                tau = [0.100 * mu0 / v for v in (a[0], b[0])]   # eq. 14 at the design point
                effects.append(abs((tau[1] - tau[0]) / ((b[0] - a[0]) / (hi - lo))))
    assert len(effects) == r
    assert s['mu_star']['actuator.mu_a'] == pytest.approx(np.mean(effects), rel=0.05)
    assert s['mu_star']['line.V_l'] < 0.05 * s['mu_star']['actuator.mu_a']
    html = (tmp_path / 'report.html').read_text()
    assert 'Morris' in html and html.count('data:image/png') >= 4


def test_bad_morris_blocks_are_refused_in_one_line_each():
    from hydropump_ctrl.sweep import SweepError
    with pytest.raises(SweepError) as exc:
        spec(morris={'r': 0, 'levels': 3, 'bounds': {'line.V_l': [1e-4, 2e-4]}, 'steps': 2})
    lines = exc.value.lines
    assert any('morris.r = 0: zero samples' in ln for ln in lines), lines
    assert any('morris.levels = 3: expected an even whole number' in ln for ln in lines)
    assert any('unknown key(s) steps' in ln for ln in lines)


@pytest.mark.skipif(__import__('shutil').which('chromium') is None,
                    reason='no Chromium on this machine (make installs it)')
def test_the_report_of_a_wide_sweep_fits_a_1400_px_window(client, tmp_path):
    """Fourteen inputs and nine outputs: the worst-runs table has many columns. Opened in
    Chromium at 1400 px, the page is no wider than the window (a wide table scrolls in its
    own box) and every figure decodes."""
    import shutil

    from playwright.sync_api import sync_playwright
    names = ['actuator.mu_a', 'line.V_l', 'line.mu_u', 'actuator.P_a_bar', 'spool.K_a',
             'plate.K_b', 'plate.c_a', 'fluid.beta', 'spool.c_c', 'spool.m_c', 'plate.m_a',
             'actuator.V_a0', 'plate.S_d', 'spool.K_c']
    sw = spec(latin_hypercube={'n': 8, 'seed': 5, 'relative': True,
                               'bounds': {n: [0.95, 1.05] for n in names}},
              outputs=['fopdt', {'peak': 'P_l'}, {'final': 'q_l'}, {'peak': 'P_a'},
                       {'final': 'P_a'}])
    run_sweep(sw, tmp_path, client=client, progress=False, report=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=shutil.which('chromium'),
                                    args=['--no-sandbox'])
        try:
            page = browser.new_page(viewport={'width': 1400, 'height': 900})
            page.goto((tmp_path / 'report.html').resolve().as_uri(), wait_until='load')
            width = page.evaluate('document.documentElement.scrollWidth')
            images = page.eval_on_selector_all('img', 'els => els.map(e => e.naturalWidth)')
        finally:
            browser.close()
    assert width <= 1400, width
    assert images and all(w > 300 for w in images), images
