"""Many pumps at once (``hydropump calibrate --fleet FOLDER``): a fleet folder holds one
folder per pump, each with that pump's bags; every pump is calibrated on its own bags as one
task of the execution layer (:mod:`hydropump_ctrl.batch`: threads of this process, a local
Dask cluster or a scheduler's workers), and one table gathers every pump's parameters and
standard errors.

The bags are read and checked in this process before any task starts (every problem of every
pump at once, one line each); the tasks get the recordings, not paths, so that workers on
other machines need no shared disk. Each pump's params file and report are written here as
its result arrives. A pump whose calibration fails is a row with its reason; the others go
on. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
import json
import math
from pathlib import Path
import time
from typing import Any

from hydropump_sim import files
from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import Params
from hydropump_sim.schema import spec_map

from ... import provenance
from ...batch import cluster_pays, cores, Executor, InProcess, open_executor
from .data import CalibrationError
from .engine import THREADS

STATUS_OK, STATUS_FAILED = 'ok', 'failed'
#: Speed-up per worker of a local cluster over this process's threads, on pumps: the
#: calibration is mostly compiled loops, which threads run in parallel too
#: (``bench/bench_calibrate.py``: 2 workers 1.07x a pump on each of 2 threads).
CLUSTER_EFFICIENCY = 0.55
BAG_SUFFIXES = ('.mcap', '.db3', '.npz')


class FleetError(CalibrationError):
    """A fleet folder that cannot be calibrated as given (one line per problem)."""


def _is_bag_dir(path: Path) -> bool:
    return path.is_dir() and ((path / 'metadata.yaml').is_file()
                              or any(path.glob('*.mcap')) or any(path.glob('*.db3')))


def find_pumps(folder: str | Path) -> dict[str, list[Path]]:
    """The pumps of a fleet folder: pump (its folder's name) -> its bags (bag folders,
    ``.mcap``, ``.db3`` or ``.npz`` files in it), in name order. A folder with a
    ``metadata.yaml`` is a bag, never a pump; hidden entries are left out.

    Raises
    ------
    FleetError
        Not a folder, a bag given instead of a fleet, no pump folder, a pump folder without
        bags: every problem at once.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FleetError(f'--fleet {folder}: no such folder (a fleet folder holds one folder '
                         'per pump, each with its bags)')
    if (folder / 'metadata.yaml').is_file():
        raise FleetError(f'--fleet {folder}: it is a bag; a fleet folder holds one folder '
                         'per pump, each with its bags')
    errors, pumps, loose = [], {}, []
    for sub in sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith('.')):
        # A folder of .mcap files alone is a pump's; one with a metadata.yaml is a bag.
        if (sub / 'metadata.yaml').is_file():
            loose.append(sub.name)
            continue
        bags = sorted(p for p in sub.iterdir() if not p.name.startswith('.') and (
            _is_bag_dir(p) or (p.is_file() and p.suffix in BAG_SUFFIXES)))
        if not bags:
            errors.append(f'{sub}: no bag in this pump folder (bag folders, .mcap, .db3 or '
                          '.npz files)')
        pumps[sub.name] = bags
    if loose:
        what = 'is a bag, not a pump folder' if len(loose) == 1 else \
            'are bags, not pump folders'
        errors.insert(0, f'--fleet {folder}: {", ".join(loose)} {what}; put each pump\'s '
                         'bags in a folder of its own')
    if not pumps and not errors:
        errors.append(f'--fleet {folder}: no pump folder in it; a fleet folder holds one '
                      'folder per pump, each with its bags')
    if errors:
        raise FleetError(errors)
    return pumps


def read_fleet(pumps: Mapping[str, Sequence[Path]], read: Callable[[Sequence[Path]], list]
               ) -> dict[str, list]:
    """Every pump's recordings by ``read`` (a list of bags -> recordings, raising a
    :class:`HydropumpError`); the problems of every pump at once, each line naming its
    pump."""
    out, errors = {}, []
    for name, bags in pumps.items():
        try:
            out[name] = read(bags)
        except HydropumpError as exc:
            errors += [f'{name}: {line}' for line in exc.lines]
    if errors:
        raise FleetError(errors)
    return out


@dataclass
class PumpResult:
    """One pump of a fleet: its calibration, or why it has none."""

    name: str
    sources: list[str]
    calibration: Any = None            # Calibration
    reason: str = ''
    wall_s: float = math.nan
    files: list[Path] = field(default_factory=list)

    @property
    def status(self) -> str:
        return STATUS_OK if self.calibration is not None and not self.reason else STATUS_FAILED


@dataclass
class FleetResult:
    """What a fleet calibration found, pump by pump (in the fleet's order)."""

    free: tuple[str, ...]
    pumps: list[PumpResult]
    where: str = ''
    wall_time: float = 0.0
    table: dict[str, Path] = field(default_factory=dict)
    #: The free parameters' units where they are not the suite's (an FMU's).
    units: dict[str, str] = field(default_factory=dict)

    @property
    def failed(self) -> int:
        return sum(p.status == STATUS_FAILED for p in self.pumps)


def _sources(recs) -> list[str]:
    return [str(getattr(r, 'source', '') or getattr(r, 'name', '')) for r in recs]


#: The FMUs a process was given by a fleet's tasks: their content's digest -> its file.
_FMU_FILES: dict[str, Path] = {}


def fmu_file(name: str, data: bytes) -> Path:
    """An FMU a task was given as bytes (``name``, its content), as a file of this process:
    written once, in a folder of its own removed at the process's exit. A worker on another
    machine needs no shared disk."""
    import atexit
    import hashlib
    import shutil
    import tempfile
    digest = hashlib.sha256(data).hexdigest()
    path = _FMU_FILES.get(digest)
    if path is None or not path.is_file():
        folder = Path(tempfile.mkdtemp(prefix='hydropump-fmu-'))
        atexit.register(shutil.rmtree, folder, True)
        path = folder / Path(name).name
        path.write_bytes(data)
        _FMU_FILES[digest] = path
    return path


def calibrate_pump(item, job: dict) -> PumpResult:
    """One pump's calibration (what a task runs): ``item`` is ``(name, recordings)``,
    ``job`` the shared start, free parameters and options, and ``fmu`` (its file's name and
    bytes) where the model is a user's FMU. A calibration the data refuse is the result's
    ``reason``, not an exception."""
    from .calibration import calibrate
    name, recs = item
    t0 = time.perf_counter()
    sources = _sources(recs)
    try:
        if job.get('fmu'):
            from ...fmi.calibration import calibrate_fmu
            cal = calibrate_fmu(fmu_file(*job['fmu']), recs, job['base'], job['free'],
                                **job['options'])
        else:
            cal = calibrate(recs, job['base'], job['free'], workers=job['threads'],
                            **job['options'])
    except HydropumpError as exc:
        return PumpResult(name, sources, None, '; '.join(exc.lines),
                          time.perf_counter() - t0)
    return PumpResult(name, sources, cal, '', time.perf_counter() - t0)


def calibrate_fleet(recordings: Mapping[str, Sequence], base: Params, free: Sequence[str], *,
                    executor: Executor | None = None,
                    on_result: Callable[[PumpResult], None] | None = None,
                    fmu: str | Path | None = None, **options) -> FleetResult:
    """Calibrate every pump of ``recordings`` (pump -> its recordings) from ``base`` with the
    same free parameters and ``options`` (those of :func:`..calibrate`), each pump one task
    on ``executor``; ``on_result`` gets each pump's result as it arrives (to write its
    files). With ``fmu`` the model of every pump is that FMU (the free names its
    parameters; :func:`hydropump_ctrl.fmi.calibration.calibrate_fmu`): it goes to the tasks
    as bytes, as the recordings do.

    Without an executor the first pump is calibrated here (its simulations on threads) and
    timed; the others go to a local Dask cluster when it would finish them sooner, its
    start-up included (:func:`hydropump_ctrl.batch.cluster_pays`, with
    :data:`CLUSTER_EFFICIENCY`), else they follow here, a pump on each core's thread.
    """
    from ..fit import blas_single_threaded
    t0 = time.perf_counter()
    items = list(recordings.items())
    results: dict[int, PumpResult] = {}
    shared = {'base': base, 'free': tuple(free), 'options': options,
              'fmu': (Path(fmu).name, Path(fmu).read_bytes()) if fmu else None}

    def run(ex: Executor, first: int, last: int) -> None:
        # On threads of this process, the threads the fleet leaves idle go to each
        # calibration's own simulations; a worker of a cluster has one thread.
        inner = max(1, THREADS // ex.workers) if isinstance(ex, InProcess) else 1
        job = ex.share({**shared, 'threads': inner})
        for k, res in ex.stream(calibrate_pump, items[first:last], retries=1, job=job):
            k += first
            if isinstance(res, BaseException):   # a lost worker, say: recorded per pump
                name, recs = items[k]
                res = PumpResult(name, _sources(recs), None, f'{type(res).__name__}: {res}')
            results[k] = res
            if on_result is not None:
                on_result(res)

    own = None
    start = 0
    try:
        if executor is None:
            own = executor = InProcess()
            blas_single_threaded(run)(own, 0, min(1, len(items)))
            start = min(1, len(items))
            left = len(items) - start
            own.close()
            if left and cluster_pays(left * results[0].wall_s, cores(),
                                     efficiency=CLUSTER_EFFICIENCY):
                own = executor = open_executor(None, cores())
            else:       # a pump on each core's thread: measured sooner than one by one
                own = executor = InProcess(cores())
        # BLAS limited once around the whole fleet: threads entering and leaving the limit
        # each on its own would restore each other's settings.
        blas_single_threaded(run)(executor, start, len(items))
    finally:
        if own is not None:
            own.close()
    units = {}
    if fmu:
        from ...fmi.reading import read_fmu
        variables = read_fmu(fmu).variables
        units = {n: variables[n].unit for n in free}
    return FleetResult(tuple(free), [results[k] for k in range(len(items))], executor.where,
                       time.perf_counter() - t0, units=units)


# ---- the table -----------------------------------------------------------------------------

def table_columns(result: FleetResult) -> tuple[dict[str, list], dict[str, str]]:
    """The fleet table as columns, and the units of its columns: per pump its status and
    reason, then per free parameter its value, standard error (both SI), relative standard
    error and whether it is well determined, then the worst fit %, the number of flags and
    the wall time."""
    specs = spec_map(Params)
    cols: dict[str, list] = {'pump': [], 'status': [], 'reason': [], 'bags': []}
    units = {'bags': ''}
    for n in result.free:
        si = result.units[n] if n in result.units else specs[n].unit
        for suffix, unit in (('', si), ('_stderr', si),
                             ('_rel_stderr', '%'), ('_well_determined', '')):
            cols[n + suffix] = []
            units[n + suffix] = unit
    cols.update(worst_fit_percent=[], flags=[], wall_s=[])
    units.update(worst_fit_percent='%', flags='', wall_s='s')
    for p in result.pumps:
        cal = p.calibration
        cols['pump'].append(p.name)
        cols['status'].append(p.status)
        cols['reason'].append(p.reason)
        cols['bags'].append(len(p.sources))
        est = {e.name: e for e in cal.estimates} if cal is not None else {}
        for n in result.free:
            e = est.get(n)
            cols[n].append(e.value if e else math.nan)
            cols[n + '_stderr'].append(e.stderr if e else math.nan)
            cols[n + '_rel_stderr'].append(100.0 * e.relative_stderr if e else math.nan)
            cols[n + '_well_determined'].append(bool(e.well_determined) if e else False)
        fits = [v for per in cal.fit.values() for v in per.values() if v is not None] \
            if cal else []
        cols['worst_fit_percent'].append(min(fits) if fits else math.nan)
        cols['flags'].append(len(cal.flags) if cal else 0)
        cols['wall_s'].append(p.wall_s)
    return cols, units


def _csv_cell(v) -> str:
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, float):
        return '' if not math.isfinite(v) else repr(v)
    text = str(v)
    return '"' + text.replace('"', '""') + '"' if any(c in text for c in ',"\n') else text


def fleet_markdown(result: FleetResult) -> str:
    """The table as Markdown: per pump and free parameter, value +- standard error (relative
    standard error), a poorly determined one marked."""
    head = ['pump', 'status', *result.free, 'worst fit %', 'flags']
    lines = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    for p in result.pumps:
        cal = p.calibration
        if cal is None or p.reason:
            cells = [p.name, p.status] + [''] * len(result.free) + ['', '']
            lines.append('| ' + ' | '.join(cells) + ' |')
            continue
        est = {e.name: e for e in cal.estimates}
        cells = [p.name, p.status]
        for n in result.free:
            e = est[n]
            rel = 100 * e.relative_stderr
            text = (f'{e.value:.6g} +- {e.stderr:.3g} ({rel:.2g} %)' if math.isfinite(rel)
                    else f'{e.value:.6g} (held)')
            cells.append(text if e.well_determined else f'**{text}**')
        fits = [v for per in cal.fit.values() for v in per.values() if v is not None]
        cells += [f'{min(fits):.2f}' if fits else '', str(len(cal.flags))]
        lines.append('| ' + ' | '.join(cells) + ' |')
    failed = [p for p in result.pumps if p.status == STATUS_FAILED]
    notes = [f'- {p.name}: {p.reason}' for p in failed]
    return '\n'.join(lines + ([''] + notes if notes else [])) + '\n'


def write_fleet_table(result: FleetResult, out: str | Path, prov: dict | None = None
                      ) -> dict[str, Path]:
    """``fleet.csv``, ``fleet.parquet`` (units and ``prov``, the provenance, in its
    metadata) and ``fleet.md`` in ``out``, each written whole or not at all."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    out = Path(out)
    cols, units = table_columns(result)
    csv = [','.join(cols)] + [','.join(_csv_cell(cols[c][i]) for c in cols)
                              for i in range(len(result.pumps))]
    paths = {'csv': files.write_text(out / 'fleet.csv', '\n'.join(csv) + '\n', 'fleet table')}
    table = pa.table({c: pa.array(v) for c, v in cols.items()}).replace_schema_metadata(
        {'units': json.dumps(units), 'free': json.dumps(list(result.free)),
         **({'provenance': json.dumps(prov)} if prov else {})})
    with files.replacing(out / 'fleet.parquet', 'fleet table') as tmp:
        pq.write_table(table, tmp)
    paths['parquet'] = out / 'fleet.parquet'
    md = ['# Fleet calibration', '',
          f'{len(result.pumps)} pumps, {result.failed} failed; free: '
          + ', '.join(result.free) + f'; run on {result.where}, {result.wall_time:.1f} s.',
          '', 'Value +- standard error (relative standard error), SI units; in bold a '
          "parameter the pump's bags leave poorly determined (see its report.md).", '',
          fleet_markdown(result)] + (provenance.markdown(prov) if prov else [])
    paths['md'] = files.write_text(out / 'fleet.md', '\n'.join(md), 'fleet table')
    result.table = paths
    return paths


def read_fleet_table(path: str | Path) -> dict[str, Any]:
    """``fleet.parquet`` as numpy columns, with ``__units__``."""
    import pyarrow.parquet as pq
    t = pq.read_table(path)
    cols = {c: t.column(c).to_numpy(zero_copy_only=False) for c in t.column_names}
    cols['__units__'] = json.loads((t.schema.metadata or {}).get(b'units', b'{}'))
    return cols
