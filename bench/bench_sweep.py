"""``hydropump sweep`` on the execution layer: speed-up of 2 workers over 1, the cost of Dask
against a plain loop, and where a local cluster starts to pay.

200 runs of a 5 s open-loop staircase (30 -> 70 % in 10 % steps of 1 s; fine model, FOPDT
fit and peak line pressure per run; actuator.mu_a normal 5 %), in the same run:

- a plain loop in a process of its own (the baseline: no Dask at all);
- a local cluster of 1 worker process with the sweep's default batching (the overhead of
  Dask per run against the loop), and with one run a task (the cost of a task);
- local clusters of 1 and 2 worker processes with the default batching (the speed-up).

Each is timed ``REPEAT`` times, the four ways interleaved on warm clusters, each started
once the machine's cores have been idle for 2 s (a shared machine: another's work falls on
the 2-worker runs more than on the others), and the median kept. Cluster start-up and
each worker's first import are left out of the sweep times (a warm-up sweep runs first) and
reported on their own: with them, the crossover below which the plain loop wins, which
:data:`hydropump_ctrl.batch.LOCAL_START` takes.

Goals: speed-up 2 vs 1 worker >= 1.7; overhead <= 5 % of a run.
"""

from concurrent.futures import ProcessPoolExecutor
import math
import multiprocessing
from pathlib import Path
import statistics
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.batch import DaskExecutor, open_client  # noqa: E402
from hydropump_ctrl.sweep import sweep_from_dict  # noqa: E402
from hydropump_ctrl.sweep.engine import context, done_runs, execute, prepare_out  # noqa: E402
from hydropump_ctrl.sweep.runs import run_one  # noqa: E402

from common import emit, row  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
N = 200
REPEAT = 5


def idle_fraction(window: float) -> float:
    """The share of the machine's CPU time that was idle over the next ``window`` s."""
    def sample():
        with open('/proc/stat') as f:
            v = [int(x) for x in f.readline().split()[1:]]
        return v[3] + v[4], sum(v)
    i0, t0 = sample()
    time.sleep(window)
    i1, t1 = sample()
    return (i1 - i0) / max(t1 - t0, 1)


def wait_idle(need: float = 0.9, window: float = 2.0, timeout: float = 120.0) -> float:
    """Wait (at most ``timeout`` s) until the cores have been ``need`` idle for ``window``
    s: on a shared machine another's work would fall on the 2-worker runs more than on the
    others. Returns the idle share seen last."""
    if not Path('/proc/stat').exists():
        return math.nan
    t_end = time.monotonic() + timeout
    while True:
        idle = idle_fraction(window)
        if idle >= need or time.monotonic() > t_end:
            return idle


def make(n, seed=1):
    return sweep_from_dict({
        'params': 'pump.yaml',
        'experiment': {'duration': 5.0,
                       'current': {'staircase': {'levels': [0.3, 0.4, 0.5, 0.6, 0.7],
                                                 'dwell': 1.0}}},
        'distributions': {'n': n, 'seed': seed,
                          'parameters': {'actuator.mu_a': {'normal': 0.05, 'relative': True}}},
        'outputs': ['fopdt', {'peak': 'P_l'}]}, ROOT / 'config', 'bench')


def loop(seed: int) -> float:
    """The plain loop over the sweep of ``seed``: its wall time."""
    sweep = make(N, seed=seed)
    ctx = context(sweep)
    t0 = time.perf_counter()
    rows = [run_one(i, sweep.samples[i], ctx) for i in range(sweep.n_runs)]
    t = time.perf_counter() - t0
    assert all(r['status'] == 'ok' for r in rows), rows[0]
    return t


def cluster(workers, tmp):
    """A warm local cluster (every worker has imported and run a simulation) and the
    seconds it took."""
    t0 = time.perf_counter()
    client, cluster = open_client(None, workers)
    ex = DaskExecutor(client, cluster, own_client=True)
    warm = make(2 * workers, seed=99)
    execute(warm, prepare_out(tmp / f'warm{workers}', warm), ex, batch=1, progress=False)
    return ex, time.perf_counter() - t0


def on(ex, batch, sweep, out) -> float:
    t0 = time.perf_counter()
    execute(sweep, prepare_out(out, sweep), ex, batch=batch, progress=False)
    t = time.perf_counter() - t0
    rows = done_runs(out)
    bad = [r for r in rows.values() if r['status'] != 'ok']
    assert len(rows) == sweep.n_runs and not bad, (len(rows), bad[:1])
    return t


def warm_loop() -> None:
    run_one(0, make(1).samples[0], context(make(1)))         # imports and JIT load


def main() -> None:
    times: dict[str, list[float]] = {}
    load = []
    # The plain loop runs in a process of its own, with no Dask in it (this one hosts the
    # clusters' schedulers and nannies, whose threads would take its time).
    plain = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'))
    plain.submit(warm_loop).result()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        one, start1 = cluster(1, tmp)
        two, start2 = cluster(2, tmp)
        try:
            # Interleaved, so that a change of the machine's load falls on every way alike.
            for rep in range(REPEAT):
                sweep = make(N, seed=10 + rep)                  # new samples: nothing resumed
                load.append(wait_idle())
                times.setdefault('loop', []).append(plain.submit(loop, 10 + rep).result())
                for name, ex, batch in (('w1', one, None), ('task1', one, 1), ('w2', two, None)):
                    load.append(wait_idle())
                    times.setdefault(name, []).append(on(ex, batch, sweep,
                                                         tmp / f'{name}-{rep}'))
        finally:
            two.close()     # the last started first: each restores the log levels it found
            one.close()
            plain.shutdown()
    t = {k: statistics.median(v) for k, v in times.items()}
    t_loop, t_w1, t_task1, t_w2 = t['loop'], t['w1'], t['task1'], t['w2']
    t_run = t_loop / N
    overhead = (t_w1 - t_loop) / t_loop
    per_task = (t_task1 - t_loop) / N / t_run
    speedup = t_w1 / t_w2
    for k, v in times.items():
        print(f'{k:6s} ' + ', '.join(f'{x:.2f}' for x in v) + f' s: median {t[k]:.2f} s')
    print(f'plain loop {1e3 * t_run:.1f} ms a run; start-up of a warm cluster {start1:.1f} s '
          f'(1 worker), {start2:.1f} s (2 workers)')
    # The plain loop wins below n runs where n t_run = start + n t_run / speedup(2 vs loop).
    s_loop = t_loop / t_w2
    cross = start2 / (t_run * (1.0 - 1.0 / s_loop)) if s_loop > 1.0 else float('inf')
    note = (f'{N} runs of a 5 s staircase, {1e3 * t_run:.0f} ms a run; medians of {REPEAT}, '
            f'interleaved, each started on cores {100 * min(load):.0f}-'
            f'{100 * max(load):.0f} % idle')
    emit([
        row('sweep speed-up, 2 workers vs 1', speedup, 'x', '>= 1.7', speedup >= 1.7, note),
        row('sweep overhead vs a plain loop (1 worker, default batching)', 100.0 * overhead,
            '%', '<= 5', overhead <= 0.05, 'extra wall time per run, in % of a run'),
        row('sweep cost of a task of one run (1 worker, 1 run a task)', 100.0 * per_task, '%',
            '', None, 'in % of a run'),
        row('sweep 2 workers vs plain loop', s_loop, 'x', '', None, note),
        row('sweep local cluster start-up (2 workers, warm)', start2, 's', '', None,
            'cluster start and first import on each worker'),
        row('sweep crossover: runs below which the plain loop wins', cross, 'runs', '', None,
            'start-up / (run time x (1 - 1/speed-up vs loop))'),
    ])


if __name__ == '__main__':
    main()
