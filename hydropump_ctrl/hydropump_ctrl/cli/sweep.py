"""``hydropump sweep SPEC.yaml``: a parameter sweep or tolerance study on Dask distributed.

Runs the plant once per sample of the spec's parameters (grid, Latin hypercube, normal or
uniform tolerances, Sobol, Morris), in this process, on a local cluster or on an existing
scheduler (a small sweep stays in this process: a cluster would not pay for its start), and
writes
``runs.parquet`` and ``report.html`` (histograms, tornado of sensitivities, worst runs) to
``--out``. Finished runs are kept there: the same command again runs only what is missing.
A bad spec, an unwritable ``--out`` or an unreachable scheduler ends with ``error:`` lines and
exit code 2 before any run; a failed run is recorded with its reason and the sweep goes on.
"""

from __future__ import annotations

import argparse
import sys

from .options import add_progress_option, add_where_options, int_in, run_dir, UsageError


def register(subparsers) -> None:
    """Add the ``sweep`` sub-command to the ``hydropump`` parser."""
    p = subparsers.add_parser(
        'sweep', help='parameter sweep / tolerance study on Dask (runs.parquet, report)',
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('spec', metavar='SPEC.yaml', help='sweep file (docs/sweeps.md)')
    add_where_options(
        p, scheduler='Dask scheduler, e.g. tcp://host:8786 (default: $DASK_SCHEDULER_ADDRESS, '
                     'else a local cluster)',
        workers='worker processes of a local cluster (default: this process for a sweep too '
                'short to pay for a cluster, else one worker per core)',
        in_process='every run in this process, no Dask at all')
    p.add_argument('--batch', type=int_in(1, 10000),
                   help='runs per Dask task (default: an eighth of what is left per worker, '
                        'at most 16, down to single runs at the end)')
    p.add_argument('--out', help='output folder (default: out/sweep-<time>); reuse it to '
                                 'resume')
    p.add_argument('--no-report', action='store_true', help='write the table only')
    add_progress_option(p, 'progress bar')
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args) -> int:
    """Run the ``sweep`` sub-command; user errors propagate as one-line exceptions."""
    from hydropump_sim.files import WriteError

    from ..batch import SchedulerError
    from ..sweep import load_sweep, run_sweep
    from ..sweep.engine import prepare_out

    if args.in_process and args.scheduler:
        raise UsageError(f'--in-process and --scheduler {args.scheduler}: choose one')
    sweep = load_sweep(args.spec)           # every spec problem before any work
    out = prepare_out(args.out or run_dir(None, 'sweep'), sweep)
    try:
        res = run_sweep(sweep, out, address=args.scheduler,
                        workers=0 if args.in_process else args.workers,
                        batch=args.batch, progress=args.progress,
                        report=not args.no_report)
    except SchedulerError:
        raise   # a ConnectionError, so an OSError, but not the disk's: its own line
    except (OSError, WriteError) as exc:
        # A full disk, say: every run stored before is whole (each is renamed into place),
        # and the same command resumes from them.
        why = exc.lines[0] if isinstance(exc, WriteError) else exc.strerror or exc
        raise UsageError(f'{out}: cannot write ({why}); the runs finished before are kept '
                         'there, and the same command resumes') from None
    print(f'sweep: {sweep.n_runs} runs, {res.executed} executed now ({res.where}), '
          f'{res.reused} from earlier, {res.failed} failed', file=sys.stderr)
    if sweep.experiment.fidelity:
        print(f'fidelity: {sweep.experiment.fidelity}', file=sys.stderr)
    print(res.table)
    if res.report:
        print(res.report)
    return 0
