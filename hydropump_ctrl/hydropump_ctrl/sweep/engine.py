"""Running a sweep on Dask distributed, with one small file per finished run for resuming.

Without a scheduler address (argument or ``DASK_SCHEDULER_ADDRESS``) a
:class:`~dask.distributed.LocalCluster` runs in this process: ``workers`` worker processes of
one thread each (the simulation is single-threaded numba; threads would share the GIL's
Python parts). With an address the runs go to that scheduler's workers, which need this
project installed in the same version.

The output folder holds ``sweep.json`` (the sweep's fingerprint), ``runs/<id>.json`` (one
per finished run, written by this process as results arrive, never by the workers, which may
be on other machines), then ``runs.parquet`` and the report. Running the same sweep into the
same folder again runs only what has no file yet.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import json
import logging
import math
import os
from pathlib import Path
import sys

import numpy as np

from .runs import run_batch, STATUS_FAILED
from .spec import followers, Sweep, SweepError

#: Seconds to wait for a scheduler before giving up.
CONNECT_TIMEOUT = 5.0


@dataclass
class SweepResult:
    """What a sweep did: runs executed now, runs taken from an earlier call, failures."""

    out: Path
    executed: int
    reused: int
    failed: int
    table: Path
    report: Path | None = None


def open_client(address: str | None = None, workers: int | None = None):
    """A Dask client: to ``address`` (or ``DASK_SCHEDULER_ADDRESS``), else to a new local
    cluster of ``workers`` processes (default one per core). Returns ``(client, cluster)``;
    ``cluster`` is None for an external scheduler.

    Raises
    ------
    SweepError
        The scheduler cannot be reached within :data:`CONNECT_TIMEOUT`.
    """
    from dask.distributed import Client, LocalCluster
    address = address or os.environ.get('DASK_SCHEDULER_ADDRESS') or None
    if address:
        try:
            return Client(address, timeout=CONNECT_TIMEOUT, set_as_default=False), None
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError (address)
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise SweepError(f'cannot reach the Dask scheduler at {address} within '
                             f'{CONNECT_TIMEOUT:g} s ({why})') from None
    workers = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=logging.ERROR)
    return Client(cluster, set_as_default=False), cluster


def prepare_out(out: str | Path, sweep: Sweep) -> Path:
    """Create and check the output folder; refuse one that holds another sweep."""
    out = Path(out)
    try:
        (out / 'runs').mkdir(parents=True, exist_ok=True)
        probe = out / '.write-test'
        probe.write_text('')
        probe.unlink()
    except OSError as exc:
        raise SweepError(f'--out {out}: cannot write there ({exc.strerror or exc})') from None
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
        meta.write_text(json.dumps({'fingerprint': fp, 'source': sweep.source,
                                    'method': sweep.method, 'names': sweep.names,
                                    'runs': sweep.n_runs}, indent=1))
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
    path = out / 'runs' / f'{row["run_id"]:06d}.json'
    tmp = path.with_suffix('.tmp')
    tmp.write_text(json.dumps(row))
    tmp.replace(path)   # atomic: a crash leaves no half-written run


def context(sweep: Sweep) -> dict:
    """What every task needs besides its samples."""
    return {'plant': sweep.plant, 'names': sweep.names, 'experiment': sweep.experiment,
            'outputs': sweep.outputs,
            'relations': followers(sweep.names, sweep.keep_relations)}


def batches(ids: list[int], samples: np.ndarray, n_workers: int, batch: int | None):
    """Runs grouped into tasks: ``batch`` runs each (default: at least 4 tasks per worker so
    that the load balances, at most 8 runs per task so that a lost worker costs little)."""
    if batch is None:
        batch = max(1, min(8, len(ids) // max(4 * n_workers, 1)))
    return [[(i, samples[i].tolist()) for i in ids[k:k + batch]]
            for k in range(0, len(ids), batch)]


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


def execute(sweep: Sweep, out: Path, client, *, batch: int | None = None,
            progress: bool | None = None,
            on_result: Callable[[dict], None] | None = None) -> tuple[int, int]:
    """Run what ``out`` lacks on ``client``'s workers; ``(executed, reused)``."""
    from dask.distributed import as_completed
    done = done_runs(out)
    todo = [i for i in range(sweep.n_runs) if i not in done]
    if not todo:
        return 0, len(done)
    n_workers = max(len(client.scheduler_info(n_workers=-1).get('workers', {})), 1) \
        if hasattr(client, 'scheduler_info') else 1
    ctx = client.scatter(context(sweep), broadcast=True)
    groups = batches(todo, sweep.samples, n_workers, batch)
    futures = client.map(run_batch, groups, ctx=ctx, pure=False,
                         retries=2)  # a worker lost twice on a task is not a run's fault
    owner = {f.key: g for f, g in zip(futures, groups)}
    bar = _Progress(sweep.n_runs, len(done), progress)
    try:
        for fut in as_completed(futures, loop=client.loop):
            try:
                rows = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: recorded per run
                rows = [{'run_id': i, 'status': STATUS_FAILED, 'wall_s': math.nan,
                         'reason': f'{type(exc).__name__}: {exc}'} for i, _ in owner[fut.key]]
            for r in rows:
                _store(out, r)
                if on_result is not None:
                    on_result(r)
            bar.update(rows)
            fut.release()
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
    pq.write_table(table, path)
    return path


def _unit(name: str) -> str:
    from hydropump_sim.params import Params
    from hydropump_sim.schema import spec_map
    return spec_map(Params)[name].unit


def run_sweep(sweep: Sweep, out: str | Path, *, address: str | None = None,
              workers: int | None = None, client=None, batch: int | None = None,
              progress: bool | None = None, report: bool = True) -> SweepResult:
    """Run ``sweep`` into ``out`` (resuming what is there), write the table and the report.

    ``client``: an open Dask client to use (else one is opened, see :func:`open_client`).
    """
    out = prepare_out(out, sweep)
    own = client is None
    cluster = None
    if own:
        client, cluster = open_client(address, workers)
    try:
        executed, reused = execute(sweep, out, client, batch=batch, progress=progress)
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()
    table = write_table(sweep, out)
    failed = sum(r['status'] == STATUS_FAILED for r in done_runs(out).values())
    rep = None
    if report:
        from .report import write_report
        rep = write_report(sweep, table, out)
    return SweepResult(out=out, executed=executed, reused=reused, failed=failed, table=table,
                       report=rep)
