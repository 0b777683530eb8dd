"""``hydropump calibrate --fleet``: many pumps, each one task, one table at the end.

The truth is ``tests/independent.py``: each pump's bags are its plant's equations integrated
by scipy's Radau with the bench's own sensor chain (the 12.4 ms flow-meter delay off the
1 kHz grid, noise, quantisation), written as rosbag2 bags. The pumps differ from
config/pump.yaml (the start) by 12-45 % in the four usual parameters, each in its own way.
Judged: every pump's parameters in the table within 2 % of its own truth (the bound of
``test_calibrate.py``), each well determined with a standard error that is finite and the
same as the pump's own report gives; the same table from an external ``dask scheduler`` and
``dask worker`` started as processes; a pump that cannot be calibrated recorded as such while
the others go on; bad input refused in one line before any calibration.
"""

import json
import shutil
import time

import numpy as np
import pytest

from hydropump_ctrl.cli import main
from hydropump_ctrl.ident.calibrate import params_with
from hydropump_ctrl.ident.calibrate.fleet import read_fleet_table
from hydropump_sim.params import load_params

from .. import independent as ind
from ..conftest import ROOT
from ..daskprocs import external_cluster

pytestmark = pytest.mark.timeout(300)

USUAL = ('actuator.mu_a', 'actuator.P_a_bar', 'line.V_l', 'line.mu_u')
BENCH = ['line_flow', 'line_pressure', 'actuator_pressure']
# Each pump's truth: factors on config/pump.yaml's values of USUAL.
PUMPS = {'pump_a': (1.3, 0.8, 1.45, 0.88), 'pump_b': (0.85, 1.15, 0.8, 1.12),
         'pump_c': (1.12, 0.88, 1.25, 0.9)}


def _designs(params):
    """Staircases at the nominal load pressure and 40 bar lower, and load-pressure steps
    with the current held at two levels (so that every compared signal moves)."""
    lo, hi = params.current_range
    stairs = ind.staircase([lo + x * (hi - lo) for x in (0.3, 0.45, 0.6, 0.4, 0.55, 0.7, 0.5)],
                           0.8)
    steps = ind.staircase([12e6, 9e6, 13e6, 10e6], 1.0)
    held = np.where(np.arange(steps.size) < steps.size // 2 + 500, lo + 0.45 * (hi - lo),
                    lo + 0.6 * (hi - lo))
    return {'stairs_120bar': (stairs, None), 'stairs_80bar': (stairs, np.full(stairs.size, 8e6)),
            'load_steps': (held, steps)}


def _truth(base, factors):
    return params_with(base, USUAL, [base.flat()[n] * f for n, f in zip(USUAL, factors)])


@pytest.fixture(scope='module')
def base():
    return load_params(ROOT / 'config' / 'pump.yaml')


@pytest.fixture(scope='module')
def fleet(base, tmp_path_factory):
    """Three pump folders with three bags each, every pump's own truth."""
    root = tmp_path_factory.mktemp('fleet')
    truths = {}
    for p, (name, factors) in enumerate(PUMPS.items()):
        truth = truths[name] = _truth(base, factors)
        for k, (bag, (cur, load)) in enumerate(_designs(base).items()):
            rec = ind.measure(ind.run(truth, cur, load), ind.BENCH, seed=(p, k))
            ind.write(root / name / bag, 1e-3, rec, truth.fluid.p_atm)
    return root, truths


def _cli(capsys, *argv):
    code = main(['calibrate', *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err.strip().splitlines()


def _fleet_args(folder, report, *more):
    return ['--fleet', folder, '--free', *USUAL, '--signals', *BENCH, '--report', report,
            '--no-plots', *more]


@pytest.fixture(scope='module')
def local(fleet, tmp_path_factory):
    """The fleet calibrated in this process (threads, a pump each)."""
    root, _ = fleet
    report = tmp_path_factory.mktemp('local')
    assert main(['calibrate', *map(str, _fleet_args(root, report, '--no-progress'))]) == 0
    return report


def test_every_pump_is_recovered_and_the_table_says_so(fleet, local):
    _, truths = fleet
    cols = read_fleet_table(local / 'fleet.parquet')
    assert list(cols['pump']) == list(PUMPS) and set(cols['status']) == {'ok'}
    for i, name in enumerate(cols['pump']):
        tf = truths[name].flat()
        result = json.loads((local / name / 'result.json').read_text())['parameters']
        for n in USUAL:
            assert abs(cols[n][i] / tf[n] - 1) < 0.02, (name, n, cols[n][i], tf[n])
            assert cols[n + '_well_determined'][i]
            # The table's standard error is the pump's own report's, finite and small.
            assert cols[n + '_stderr'][i] == pytest.approx(result[n]['stderr'], rel=1e-12)
            assert 0 < cols[n + '_rel_stderr'][i] < 100 * 0.02 / 3
        # Each pump's params file loads and holds its own values.
        own = load_params(local / name / 'calibrated.yaml').flat()
        for n in USUAL:
            assert own[n] == pytest.approx(cols[n][i], rel=1e-5)
    # The pumps differ from each other by more than the calibration's error: the table does
    # not give every pump the same values.
    assert np.ptp(cols['line.V_l']) > 0.3 * np.mean(cols['line.V_l'])
    units = cols['__units__']
    assert units['line.V_l'] == units['line.V_l_stderr'] == 'm^3'
    csv = (local / 'fleet.csv').read_text().splitlines()
    assert csv[0].split(',')[:4] == ['pump', 'status', 'reason', 'bags']
    assert len(csv) == 1 + len(PUMPS)
    md = (local / 'fleet.md').read_text()
    assert all(f'| {name} | ok |' in md for name in PUMPS)


def test_an_external_scheduler_gives_the_same_table(fleet, local, tmp_path, capsys):
    root, _ = fleet
    with external_cluster(2) as address:
        from dask.distributed import Client
        with Client(address, timeout=10, set_as_default=False) as c:
            code, _, err = _cli(capsys, *_fleet_args(root, tmp_path, '--scheduler', address))
            # Each pump one task (the pump's bags and options shared once): both workers
            # took part.
            counts = c.run(lambda dask_worker: dask_worker.state.executed_count)
    assert code == 0, err
    assert sum(ln.startswith('fleet: ') for ln in err) == len(PUMPS)   # one line a pump
    assert sorted(counts.values())[0] >= 1 and sum(counts.values()) >= len(PUMPS), counts
    a = read_fleet_table(local / 'fleet.parquet')
    b = read_fleet_table(tmp_path / 'fleet.parquet')
    for name in a:
        if name not in ('wall_s', '__units__'):     # wall time is the only one that may differ
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_a_pump_that_cannot_be_calibrated_is_a_row_and_the_others_go_on(fleet, base, tmp_path,
                                                                        capsys):
    root, truths = fleet
    mixed = tmp_path / 'mixed'
    shutil.copytree(root / 'pump_a', mixed / 'good')
    # A pump recorded with the current held: nothing to calibrate on.
    lo, hi = base.current_range
    n = 3000
    flat = ind.run(truths['pump_b'], np.full(n, lo + 0.5 * (hi - lo)), None)
    rec = ind.measure(flat, ind.BENCH, seed=5)
    ind.write(mixed / 'still' / 'held', 1e-3, rec, base.fluid.p_atm)
    code, out, err = _cli(capsys, *_fleet_args(mixed, tmp_path / 'rep', '--in-process'))
    assert code == 1, err
    cols = read_fleet_table(tmp_path / 'rep' / 'fleet.parquet')
    assert list(cols['pump']) == ['good', 'still']
    assert list(cols['status']) == ['ok', 'failed']
    assert 'no excitation' in cols['reason'][1]
    assert np.isnan(cols['line.V_l'][1])
    tf = truths['pump_a'].flat()
    assert abs(cols['line.V_l'][0] / tf['line.V_l'] - 1) < 0.02
    assert not (tmp_path / 'rep' / 'still' / 'calibrated.yaml').exists()
    assert any(ln.startswith('warning: still:') and 'no excitation' in ln for ln in err)


BAD = {
    'not a folder': (lambda r, t: ['--fleet', t / 'nothing'], 'no such folder'),
    'a bag': (lambda r, t: ['--fleet', r / 'pump_a' / 'load_steps'], 'it is a bag'),
    'a folder of bags': (lambda r, t: ['--fleet', r / 'pump_a'],
                         'load_steps, stairs_120bar, stairs_80bar are bags, not pump'),
    'an empty pump': (lambda r, t: ['--fleet', _empty_pump(r, t)], 'no bag in this pump'),
    'a bad bag': (lambda r, t: ['--fleet', _bad_bag(r, t)], 'broken: '),
    'bags and a fleet': (lambda r, t: [r / 'pump_a' / 'load_steps', '--fleet', r], 'not both'),
    'out': (lambda r, t: ['--fleet', r, '--out', t / 'x.yaml'], 'give --report instead'),
    'unknown parameter': (lambda r, t: ['--fleet', r, '--free', 'line.V'],
                          'did you mean line.V_l?'),
}


def _empty_pump(root, tmp):
    f = tmp / 'f'
    shutil.copytree(root / 'pump_a', f / 'a')
    (f / 'b').mkdir()
    return f


def _bad_bag(root, tmp):
    f = tmp / 'f'
    shutil.copytree(root / 'pump_a', f / 'good')
    (f / 'broken').mkdir()
    (f / 'broken' / 'run.mcap').write_bytes(b'not an mcap file')
    return f


@pytest.mark.parametrize('case', list(BAD))
def test_bad_input_is_one_line_before_any_calibration(fleet, tmp_path, capsys, case):
    root, _ = fleet
    make, text = BAD[case]
    extra = make(root, tmp_path)
    free = [] if '--free' in extra else ['--free', *USUAL]
    code, out, err = _cli(capsys, *extra, *free, '--report', tmp_path / 'rep', '--no-plots')
    assert code == 2
    assert len(err) == 1 and err[0].startswith('error: ') and text in err[0], err
    assert not list(tmp_path.glob('rep/*'))       # not a file, not a pump's folder


def test_an_unreachable_scheduler_and_an_unwritable_report_are_one_line(fleet, tmp_path,
                                                                       capsys, short_connect):
    root, _ = fleet
    (tmp_path / 'file').write_text('')
    code, _, err = _cli(capsys, *_fleet_args(root, tmp_path / 'file' / 'sub'))
    assert code == 2 and len(err) == 1 and 'file' in err[0], err
    address = 'tcp://127.0.0.1:9'
    t0 = time.monotonic()
    code, _, err = _cli(capsys, *_fleet_args(root, tmp_path / 'rep', '--scheduler', address))
    assert time.monotonic() - t0 < 10.0
    assert code == 2 and len(err) == 1 and address in err[0], err
    assert not list((tmp_path / 'rep').glob('*/calibrated.yaml'))


def test_one_pump_with_its_simulations_as_dask_tasks_is_the_same_calibration(fleet, local,
                                                                            tmp_path, capsys):
    """``calibrate BAG... --workers 2``: the per-bag simulations and the sensitivity columns
    run as tasks of a local Dask cluster; the params file is the one the fleet wrote for that
    pump in this process, to the last digit."""
    root, _ = fleet
    bags = sorted((root / 'pump_b').iterdir())
    code, out, err = _cli(capsys, *bags, '--free', *USUAL, '--signals', *BENCH, '--workers', 2,
                          '--out', tmp_path / 'b.yaml', '--report', tmp_path / 'rep',
                          '--no-plots', '--no-progress')
    assert code == 0, err
    assert load_params(tmp_path / 'b.yaml').flat() == \
        load_params(local / 'pump_b' / 'calibrated.yaml').flat()
