"""The execution layer (``hydropump_ctrl.batch``): one interface, in this process or on Dask.

Truth from outside the layer: what a plain loop over the same tasks gives (the layer may only
change where the tasks run, never what they return), the closed form of the crossover, the
simulations of ``hydropump_sim.simulate`` called directly, and the address the user gave.
"""

import time

import numpy as np
import pytest

from hydropump_ctrl.batch import (
    cluster_pays,
    DaskExecutor,
    InProcess,
    open_client,
    open_executor,
    SchedulerError,
)
from hydropump_ctrl.ident.calibrate.engine import Engine, params_with, simulate_runs
from hydropump_sim.errors import InputError
from hydropump_sim.params import load_params

from ..conftest import ROOT

pytestmark = pytest.mark.timeout(180)


def _square_plus(x, shared):
    if x == 3:
        raise InputError('three refused')   # a user error: its class must come back
    return x * x + shared['add']


@pytest.fixture(scope='module')
def cluster():
    client, cl = open_client(None, 2)
    ex = DaskExecutor(client, cl, own_client=True)
    yield ex
    ex.close()


@pytest.fixture(params=['loop', 'threads', 'dask'])
def executor(request, cluster):
    if request.param == 'dask':
        yield cluster
        return
    with InProcess(1 if request.param == 'loop' else 2) as ex:
        yield ex


def test_map_and_stream_return_what_a_plain_loop_returns(executor):
    items = [0, 1, 2, 4, 5, 6, 7]
    shared = executor.share({'add': 10})
    assert executor.map(_square_plus, items, shared=shared) == [x * x + 10 for x in items]
    got = dict(executor.stream(_square_plus, [*items, 3], shared=shared))
    # Every task reported once, under its own index; the one that raised gives its error and
    # the others go on.
    assert sorted(got) == list(range(len(items) + 1))
    assert all(got[k] == x * x + 10 for k, x in enumerate(items))
    assert isinstance(got[len(items)], InputError) and 'three refused' in str(got[len(items)])
    with pytest.raises(InputError, match='three refused'):
        executor.map(_square_plus, [1, 3], shared=shared)


def test_consecutive_batches_each_see_their_own_shared_data(executor):
    """A mapping shared by one batch and another of the same keys by the next: each batch's
    tasks see their own (Dask scatters a dict's values under the dict's keys, so a dict is
    shared whole, under a key of its own)."""
    for k in range(4):
        shared = executor.share({'add': 100 * k})
        assert executor.map(_square_plus, [1, 2], shared=shared) == [1 + 100 * k, 4 + 100 * k]


def test_the_calibration_engine_gives_the_same_runs_wherever_its_jobs_go(executor):
    """A calibration's per-bag simulations and sensitivity copies as tasks: the very runs
    ``simulate_runs`` gives in a plain call, nominal and perturbed."""
    from hydropump_ctrl.ident import Recording
    from hydropump_ctrl.ident.calibrate.data import experiment_from
    base = load_params(ROOT / 'config' / 'pump.yaml')
    lo, hi = base.current_range
    exps = []
    for k, (a, b) in enumerate(((0.3, 0.6), (0.5, 0.4), (0.45, 0.7))):
        t = np.arange(1200) * 1e-3
        cur = np.where(t < 0.4, lo + a * (hi - lo), lo + b * (hi - lo))
        flow = np.linspace(4e-4, 6e-4, t.size) + 1e-6 * np.sin(50 * t)
        rec = Recording(t, {'solenoid_current': cur, 'line_flow': flow}, name=f'r{k}')
        exps.append(experiment_from(rec, base))
    free = ('actuator.mu_a', 'line.V_l')
    theta = np.array([base.flat()[n] for n in free])
    perturbed = [theta * [1.001, 1.0], theta * [1.0, 0.999]]
    engine = Engine(base, free, exps, executor=executor)
    try:
        nominal, copies = engine.sensitivity_runs(theta, perturbed)
        again = engine.outputs(theta * 1.01)
    finally:
        engine.close()
    for e, exp in enumerate(exps):
        plist = [params_with(base, free, th) for th in (theta, *perturbed)]
        want = simulate_runs(plist, exp, 1e-5)
        np.testing.assert_array_equal(nominal[e]['line_flow'], want[0]['line_flow'])
        for j in range(2):
            np.testing.assert_array_equal(copies[j][e]['line_flow'], want[j + 1]['line_flow'])
        alone = simulate_runs([params_with(base, free, theta * 1.01)], exp, 1e-5)[0]
        np.testing.assert_array_equal(again[e]['line_flow'], alone['line_flow'])
        # A perturbed copy differs from the nominal run: the columns are not all zero.
        assert np.any(copies[0][e]['line_flow'] != nominal[e]['line_flow'])


def test_the_crossover_is_the_start_up_against_the_time_saved():
    # serial s on w workers of efficiency e: the cluster saves s (1 - 1 / (w e)).
    assert not cluster_pays(100.0, 1)                          # one worker never pays
    assert not cluster_pays(3.0, 2, start=2.0, efficiency=1.0)  # saves 1.5 s < 2 s
    assert cluster_pays(5.0, 2, start=2.0, efficiency=1.0)      # saves 2.5 s > 2 s
    s = 2.0 / (1.0 - 1.0 / (4 * 0.8))                           # the break-even time
    assert not cluster_pays(0.99 * s, 4, start=2.0) and cluster_pays(1.01 * s, 4, start=2.0)


def test_open_executor_chooses_by_address_and_worker_count(monkeypatch, short_connect):
    monkeypatch.delenv('DASK_SCHEDULER_ADDRESS', raising=False)
    for workers in (None, 0):
        ex = open_executor(None, workers, threads=3)
        assert isinstance(ex, InProcess) and ex.workers == 3
        ex.close()
    address = 'tcp://127.0.0.1:9'        # the discard port: nothing answers there
    for how in ('argument', 'environment'):
        if how == 'environment':
            monkeypatch.setenv('DASK_SCHEDULER_ADDRESS', address)
        t0 = time.monotonic()
        with pytest.raises(SchedulerError) as exc:
            open_executor(address if how == 'argument' else None, None)
        assert time.monotonic() - t0 < 10.0
        assert len(exc.value.lines) == 1 and address in exc.value.lines[0]


def test_a_local_cluster_has_its_workers_and_says_where(cluster):
    assert cluster.workers == 2
    assert 'local Dask cluster (2 workers)' in cluster.where
    # One thread a worker, and without the malloc trim threshold that slows a task thread.
    import os
    info = cluster.client.run(lambda: os.environ.get('MALLOC_TRIM_THRESHOLD_'))
    assert list(info.values()) == [None, None]
