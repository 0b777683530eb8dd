"""``hydropump sweep`` on Dask: speed-up of 2 workers over 1, and the cost of a task.

200 runs of a 5 s open-loop staircase (30 -> 70 % in 10 % steps of 1 s; fine model, FOPDT
fit and peak line pressure per run; actuator.mu_a normal 5 %), three ways in the same run:

- a plain loop in this process (the baseline: no Dask at all);
- a local cluster of 1 worker process, one run per task (the per-task overhead);
- local clusters of 1 and 2 worker processes with the default batching (the speed-up).

Cluster start-up and each worker's first import are left out of the sweep times (a warm-up
sweep runs first) and reported on their own: with them, the crossover below which the plain
loop wins.

Goals: speed-up 2 vs 1 worker >= 1.7; per-task overhead <= 5 % of a run.
"""

from pathlib import Path
import sys
import tempfile
import time

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hydropump_ctrl.sweep import open_client, sweep_from_dict  # noqa: E402
from hydropump_ctrl.sweep.engine import context, execute, prepare_out  # noqa: E402
from hydropump_ctrl.sweep.runs import run_one  # noqa: E402

from common import emit, row  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
N = 200


def make(n):
    return sweep_from_dict({
        'params': 'pump.yaml',
        'experiment': {'duration': 5.0,
                       'current': {'staircase': {'levels': [0.3, 0.4, 0.5, 0.6, 0.7],
                                                 'dwell': 1.0}}},
        'distributions': {'n': n, 'seed': 1,
                          'parameters': {'actuator.mu_a': {'normal': 0.05, 'relative': True}}},
        'outputs': ['fopdt', {'peak': 'P_l'}]}, ROOT / 'config', 'bench')


def on_cluster(workers, sweep, batch, tmp):
    t0 = time.perf_counter()
    client, cluster = open_client(None, workers)
    try:
        execute(make(2 * workers), prepare_out(tmp / f'warm{workers}-{batch}', make(2 * workers)),
                client, batch=1, progress=False)                # imports and JIT load
        start = time.perf_counter() - t0
        t1 = time.perf_counter()
        execute(sweep, prepare_out(tmp / f'w{workers}-{batch}', sweep), client, batch=batch,
                progress=False)
        return time.perf_counter() - t1, start
    finally:
        client.close()
        cluster.close()


def main() -> None:
    sweep = make(N)
    ctx = context(sweep)
    run_one(0, sweep.samples[0], ctx)                           # warm-up
    t0 = time.perf_counter()
    rows = [run_one(i, sweep.samples[i], ctx) for i in range(N)]
    t_loop = time.perf_counter() - t0
    assert all(r['status'] == 'ok' for r in rows), rows[0]
    t_run = t_loop / N
    print(f'plain loop: {N} runs in {t_loop:.2f} s, {1e3 * t_run:.1f} ms a run')
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        t_task1, _ = on_cluster(1, sweep, 1, tmp)
        t_w1, start1 = on_cluster(1, sweep, None, tmp)
        t_w2, start2 = on_cluster(2, sweep, None, tmp)
    overhead = (t_task1 - t_loop) / N / t_run
    speedup = t_w1 / t_w2
    print(f'1 worker, 1 run a task: {t_task1:.2f} s; 1 worker batched: {t_w1:.2f} s; '
          f'2 workers batched: {t_w2:.2f} s; start-up {start1:.1f} s / {start2:.1f} s')
    # The plain loop wins below n runs where n t_run = start + n t_run / speedup(2 vs loop).
    s_loop = t_loop / t_w2
    cross = start2 / (t_run * (1.0 - 1.0 / s_loop)) if s_loop > 1.0 else float('inf')
    note = f'{N} runs of a 5 s staircase, {1e3 * t_run:.0f} ms a run; 2-core machine'
    emit([
        row('sweep speed-up, 2 workers vs 1', speedup, 'x', '>= 1.7', speedup >= 1.7, note),
        row('sweep per-task overhead vs a run (1 run a task)', 100.0 * overhead, '%', '<= 5',
            overhead <= 0.05, note),
        row('sweep 2 workers vs plain loop', s_loop, 'x', '', None, note),
        row('sweep local cluster start-up (2 workers, warm)', start2, 's', '', None,
            'cluster start and first import on each worker'),
        row('sweep crossover: runs below which the plain loop wins', cross, 'runs', '', None,
            'start-up / (run time x (1 - 1/speed-up vs loop))'),
    ])


if __name__ == '__main__':
    main()
