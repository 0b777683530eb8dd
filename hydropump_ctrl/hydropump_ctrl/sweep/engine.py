"""Running a sweep on the suite's execution layer, with one small file per finished run for
resuming.

Where the runs go (:mod:`hydropump_ctrl.batch`): to the scheduler at an address (argument or
``DASK_SCHEDULER_ADDRESS``), whose workers need this project installed in the same version;
to a :class:`~dask.distributed.LocalCluster` of ``workers`` processes of one thread each
(the run is single-threaded numba and Python, and threads would share the GIL's Python
parts); or to a plain loop in this process (``workers=0``). Without either, the first runs
are made in this process and timed, and the rest go to a local cluster only when it would
finish them sooner, its start-up included (:func:`hydropump_ctrl.batch.cluster_pays`).

Runs are grouped into tasks of several runs, the largest first and single runs at the end
(guided self-scheduling): few messages while there is much to do, and no worker left with a
long task when the others are done.

The output folder holds ``sweep.json`` (the sweep's fingerprint), ``runs/<id>.json`` (one
per finished run, written by this process as results arrive, never by the workers, which may
be on other machines), then ``runs.parquet`` and the report. Running the same sweep into the
same folder again runs only what has no file yet.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import json
import math
import os
from pathlib import Path
import sys

import numpy as np

from hydropump_sim import files

from ..batch import (
    cluster_pays,
    cores,
    DaskExecutor,
    Executor,
    InProcess,
    open_client,
    open_executor,
)
from .runs import run_batch, STATUS_FAILED
from .spec import followers, Sweep, SweepError

__all__ = ['SweepResult', 'execute', 'open_client', 'prepare_out', 'run_sweep']

#: Runs timed in this process before a sweep without a worker count chooses where the rest
#: go (the first pays for the imports, the second is timed).
PROBE_RUNS = 2
#: Most runs in one task: a lost worker costs little, and progress shows.
MAX_BATCH = 16


@dataclass
class SweepResult:
    """What a sweep did: runs executed now, runs taken from an earlier call, failures, and
    where the runs went."""

    out: Path
    executed: int
    reused: int
    failed: int
    table: Path
    report: Path | None = None
    where: str = ''


def prepare_out(out: str | Path, sweep: Sweep) -> Path:
    """Create and check the output folder; refuse one that holds another sweep."""
    out = Path(out)
    try:
        (out / 'runs').mkdir(parents=True, exist_ok=True)
        probe = files.write_text(out / '.write-test', '', 'probe file')
        probe.unlink()
    except OSError as exc:
        raise SweepError(f'--out {out}: cannot write there ({exc.strerror or exc})') from None
    except files.WriteError as exc:
        raise SweepError(f'--out {out}: cannot write there ({exc.lines[0]})') from None
    meta = out / 'sweep.json'
    fp = sweep.fingerprint()
    if meta.exists():
        try:
            old = json.loads(meta.read_text()).get('fingerprint')
        except (OSError, ValueError):
            old = None
        if old != fp:
            raise SweepError(f'--out {out}: holds the runs of another sweep (spec, plant or '
                             'samples differ): give another folder')
    else:
        files.write_text(meta, json.dumps({'fingerprint': fp, 'source': sweep.source,
                                           'method': sweep.method, 'names': sweep.names,
                                           'runs': sweep.n_runs}, indent=1), 'sweep file')
    return out


def done_runs(out: Path) -> dict[int, dict]:
    """Rows of the runs already stored in ``out/runs``."""
    rows = {}
    for f in (out / 'runs').glob('*.json'):
        try:
            row = json.loads(f.read_text())
        except (OSError, ValueError):
            continue  # a file cut short by a crash: the run is redone
        rows[int(row['run_id'])] = row
    return rows


def _store(out: Path, row: dict) -> None:
    # Renamed into place: a crash leaves no half-written run.
    files.write_text(out / 'runs' / f'{row["run_id"]:06d}.json', json.dumps(row), 'run')


def context(sweep: Sweep) -> dict:
    """What every task needs besides its samples."""
    return {'plant': sweep.plant, 'names': sweep.names, 'experiment': sweep.experiment,
            'outputs': sweep.outputs,
            'relations': followers(sweep.names, sweep.keep_relations)}


def batches(ids: list[int], samples: np.ndarray, n_workers: int, batch: int | None):
    """Runs grouped into tasks: ``batch`` runs each, or by default guided: a task takes an
    eighth of what is left per worker (at most :data:`MAX_BATCH`), so that the tasks shrink
    to single runs towards the end."""
    out, k = [], 0
    while k < len(ids):
        left = len(ids) - k
        size = batch or max(1, min(MAX_BATCH, left // (8 * max(n_workers, 1))))
        out.append([(i, samples[i].tolist()) for i in ids[k:k + size]])
        k += size
    return out


class _Progress:
    """A tqdm bar on a terminal, else a line every tenth of the sweep, on stderr."""

    def __init__(self, total: int, done: int, show: bool | None):
        self.total, self.done, self.failed = total, done, 0
        self.bar = None
        self.every = max(1, (total - done) // 10)
        self.quiet = show is False
        if show or (show is None and sys.stderr.isatty()):
            from tqdm import tqdm
            self.bar = tqdm(total=total, initial=done, desc='sweep', unit='run',
                            file=sys.stderr, leave=False)

    def update(self, rows: list[dict]) -> None:
        before = self.done
        self.done += len(rows)
        self.failed += sum(r['status'] == STATUS_FAILED for r in rows)
        if self.bar is not None:
            self.bar.update(len(rows))
        elif not self.quiet and (self.done // self.every != before // self.every
                                 or self.done == self.total):
            print(f'sweep: {self.done}/{self.total} runs ({self.failed} failed now)',
                  file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _executor(client_or_executor) -> Executor:
    if isinstance(client_or_executor, Executor):
        return client_or_executor
    return DaskExecutor(client_or_executor)     # a Dask client the caller owns


def execute(sweep: Sweep, out: Path, executor, *, batch: int | None = None,
            progress: bool | None = None, limit: int | None = None,
            on_result: Callable[[dict], None] | None = None) -> tuple[int, int]:
    """Run what ``out`` lacks (at most ``limit`` runs) on ``executor`` (an
    :class:`~hydropump_ctrl.batch.Executor` or a Dask client); ``(executed, reused)``."""
    ex = _executor(executor)
    done = done_runs(out)
    todo = [i for i in range(sweep.n_runs) if i not in done][:limit]
    if not todo:
        return 0, len(done)
    groups = batches(todo, sweep.samples, ex.workers,
                     1 if isinstance(ex, InProcess) and batch is None else batch)
    ctx = ex.share(context(sweep))
    bar = _Progress(sweep.n_runs, len(done), progress)
    try:
        # A worker lost twice on a task is not a run's fault: retries.
        for k, rows in ex.stream(run_batch, groups, retries=2, ctx=ctx):
            if isinstance(rows, BaseException):   # e.g. KilledWorker: recorded per run
                rows = [{'run_id': i, 'status': STATUS_FAILED, 'wall_s': math.nan,
                         'reason': f'{type(rows).__name__}: {rows}'} for i, _ in groups[k]]
            for r in rows:
                _store(out, r)
                if on_result is not None:
                    on_result(r)
            bar.update(rows)
    finally:
        bar.close()
    return len(todo), len(done)


def write_table(sweep: Sweep, out: Path) -> Path:
    """``out/runs.parquet``: run id, sampled inputs, outputs, status, reason, wall time."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    rows = done_runs(out)
    ids = list(range(sweep.n_runs))
    cols: dict[str, object] = {'run_id': pa.array(ids, pa.int64())}
    for j, name in enumerate(sweep.names):
        cols[name] = pa.array(sweep.samples[:, j], pa.float64())
    for name in sweep.columns():
        cols[name] = pa.array([float(rows.get(i, {}).get(name, math.nan)) for i in ids],
                              pa.float64())
    cols['status'] = pa.array([rows.get(i, {}).get('status', 'missing') for i in ids])
    cols['reason'] = pa.array([rows.get(i, {}).get('reason', '') for i in ids])
    cols['wall_s'] = pa.array([float(rows.get(i, {}).get('wall_s', math.nan)) for i in ids],
                              pa.float64())
    units = {**{n: _unit(n) for n in sweep.names}, **sweep.columns(), 'wall_s': 's'}
    table = pa.table(cols).replace_schema_metadata(
        {'units': json.dumps(units), 'method': sweep.method, 'source': sweep.source})
    path = out / 'runs.parquet'
    with files.replacing(path, 'table') as tmp:
        pq.write_table(table, tmp)
    return path


def _unit(name: str) -> str:
    from hydropump_sim.params import Params
    from hydropump_sim.schema import spec_map
    return spec_map(Params)[name].unit


def run_sweep(sweep: Sweep, out: str | Path, *, address: str | None = None,
              workers: int | None = None, client=None, executor: Executor | None = None,
              batch: int | None = None, progress: bool | None = None,
              report: bool = True) -> SweepResult:
    """Run ``sweep`` into ``out`` (resuming what is there), write the table and the report.

    Where the runs go: ``executor`` or ``client`` (an open Dask client), else see
    :func:`hydropump_ctrl.batch.open_executor` (``address``; ``workers`` >= 1: a local
    cluster; 0: this process); with neither an address nor a worker count, the first
    :data:`PROBE_RUNS` runs are timed here and decide (see the module).

    Raises
    ------
    hydropump_ctrl.batch.SchedulerError
        The scheduler at ``address`` does not answer.
    """
    out = prepare_out(out, sweep)
    executed = 0
    own = None
    ex = executor or (DaskExecutor(client) if client is not None else None)
    try:
        if ex is None:
            ex, executed = _choose(sweep, out, address, workers, progress)
            own = ex
        n, reused = execute(sweep, out, ex, batch=batch, progress=progress)
        executed += n
        reused -= executed - n
    finally:
        if own is not None:
            own.close()
    table = write_table(sweep, out)
    failed = sum(r['status'] == STATUS_FAILED for r in done_runs(out).values())
    rep = None
    if report:
        from .report import write_report
        rep = write_report(sweep, table, out)
    return SweepResult(out=out, executed=executed, reused=reused, failed=failed, table=table,
                       report=rep, where=ex.where)


def _choose(sweep: Sweep, out: Path, address, workers, progress) -> tuple[Executor, int]:
    """The executor of a sweep (see :func:`run_sweep`) and the runs made here to choose."""
    if address or os.environ.get('DASK_SCHEDULER_ADDRESS') or workers is not None:
        return open_executor(address, workers), 0
    here = InProcess()
    probe: list[dict] = []
    probed, _ = execute(sweep, out, here, progress=progress, limit=PROBE_RUNS,
                        on_result=probe.append)
    left = sweep.n_runs - len(done_runs(out))
    # The first run in this process pays for the imports: the last one is timed.
    t_run = probe[-1]['wall_s'] if probe else 0.0
    if left and cluster_pays(left * t_run, cores()):
        return open_executor(None, cores()), probed
    return here, probed
