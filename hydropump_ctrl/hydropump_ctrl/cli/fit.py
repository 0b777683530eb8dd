"""``hydropump fit BAG...``: identify eq. 19 from rosbag2 bags (section V of the paper).

Reads the current and flow topics of each bag, fits the FOPDT model per bag (robust method by
default, ``--method paper`` for the paper's Nelder-Mead procedure), pools the sets, prints a
table (or the JSON result with ``--json``) and writes a report folder: ``result.json``,
``report.md`` and the Fig. 5 / Fig. 6 plots per set.

Bad input (a missing topic, a flat current, NaNs, a truncated bag without
``--allow-truncated``, a path that is not a bag) ends with one ``error:`` line and exit code 2,
and so does a bag that cannot be the pump's (checked against ``--params`` before any fit: a
current in mA, a flow in L/min, the wrong message type, two runs in one bag, too few samples;
see ``docs/identification.md``).
"""

from __future__ import annotations

import argparse
import sys
import time

from hydropump_sim.files import write_text

from ..provenance import collect
from .options import add_params_option, add_progress_option, plant_file, positive, run_dir


def register(subparsers) -> None:
    """Add the ``fit`` sub-command to the ``hydropump`` parser."""
    p = subparsers.add_parser(
        'fit', help='identify G0, tau, t_d (eq. 19) from rosbag2 bags',
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='bag directory, .mcap or .db3 file, or a saved .npz recording')
    p.add_argument('--method', choices=('robust', 'paper'), default='robust',
                   help="robust fit, or the paper's Nelder-Mead from step seeds")
    p.add_argument('--current-topic', default='solenoid_current',
                   help='current topic (absolute A); solenoid_current_cmd for the command')
    p.add_argument('--flow-topic', default='line_flow', help='flow topic (m^3/s)')
    add_params_option(p, 'for the normalisation')
    p.add_argument('--json', action='store_true',
                   help='print the JSON result on stdout instead of the table')
    p.add_argument('--out', help='report folder (default: out/fit-<time>)')
    p.add_argument('--no-report', action='store_true', help='write no report folder')
    p.add_argument('--no-plots', action='store_true', help='report without figures')
    p.add_argument('--plots-per-set', action='store_true',
                   help='also write Fig. 5 and Fig. 6 of every set on its own')
    p.add_argument('--start', nargs=3, action='FOPDT start', metavar=('G0', 'TAU', 'TD'),
                   help='starting point (tau, t_d in s)')
    p.add_argument('--td-bounds', nargs=2, action='delay bounds', metavar=('LO', 'HI'),
                   help='delay bounds [s] (default 0 .. min(0.25, record/8))')
    p.add_argument('--tau-bounds', nargs=2, action='time-constant bounds', metavar=('LO', 'HI'),
                   help='time-constant bounds [s] (default dt/4 .. min(2, record/4))')
    p.add_argument('--dt', type='resampling period',
                   help="resampling period [s] (default: the topics')")
    p.add_argument('--lowpass', type='cut-off frequency', metavar='HZ',
                   help='zero-phase low-pass of current and flow before the fit')
    p.add_argument('--lowpass-flow', type='cut-off frequency', metavar='HZ',
                   help='low-pass of the flow alone: biases t_d, refused without '
                        '--allow-flow-filter')
    p.add_argument('--allow-flow-filter', action='store_true',
                   help='fit a flow-only filtered record anyway (flagged flow_only_filter)')
    p.add_argument('--allow-truncated', action='store_true',
                   help='fit the readable part of truncated bags (flagged truncated_bag)')
    p.add_argument('--no-dither', action='store_true',
                   help='robust: do not take dither lines out of the current')
    p.add_argument('--no-joint', action='store_true', help='skip the joint fit of all sets')
    p.add_argument('--matrix', action='store_true',
                   help='fit the whole of eq. 16 instead (G21 on both branches, G11, G12), '
                        'beside the linearisation of the --params file')
    add_progress_option(p, 'progress bar')
    p.set_defaults(func=cmd_fit)


def _warn(msg: str) -> None:
    print(f'warning: {msg}', file=sys.stderr)


def cmd_fit(args) -> int:
    """Run the ``fit`` sub-command; user errors propagate as one-line exceptions."""
    from hydropump_sim.params import load_params

    from ..ident import fit_recordings, format_table, read_recordings, to_json, write_report

    if args.dt is not None:
        positive(args.dt, '--dt', 's')
    if args.matrix:
        return cmd_matrix(args)
    t0 = time.perf_counter()
    plant = plant_file(args)
    params = load_params(plant)
    recs = []
    for path, rec in zip(args.bags, read_recordings(
            args.bags, current_topic=args.current_topic, flow_topic=args.flow_topic,
            dt=args.dt, allow_truncated=args.allow_truncated, progress=args.progress,
            params=params, check=())):
        if rec.truncated:
            _warn(f'{path}: truncated bag, fitting its readable part ({rec.truncation})')
        for note in rec.notes:
            _warn(f'{path}: {note}')
        if args.lowpass:
            rec = rec.lowpass(args.lowpass)
        if args.lowpass_flow:
            rec = rec.lowpass(args.lowpass_flow, signals=('flow',))
        recs.append(rec)
    kw = {}
    if args.no_dither:
        kw['dither'] = None
    ident = fit_recordings(
        recs, method=args.method, params=params, start=args.start, td_bounds=args.td_bounds,
        tau_bounds=args.tau_bounds, joint=False if args.no_joint else None,
        progress=args.progress, allow_flow_filter=args.allow_flow_filter, **kw)
    ident.provenance = collect([plant, *args.bags])
    if args.json:
        print(to_json(ident))
    else:
        print(format_table(ident))
    if not args.no_report:
        out = run_dir(args.out, 'fit')
        write_report(ident, out, params=params, plots=not args.no_plots,
                     per_set=args.plots_per_set)
        print(f'wrote {out}/result.json, report.md'
              f'{"" if args.no_plots else " and figures"} ({time.perf_counter() - t0:.1f} s)',
              file=sys.stderr if args.json else sys.stdout)
    return 0


MATRIX_UNITS = {'G21_up': 'm^3/s per A', 'G21_down': 'm^3/s per A', 'G11': 'Pa per A',
                'G12': 'Pa per Pa'}


def cmd_matrix(args) -> int:
    """``fit --matrix``: the elements of eq. 16 from the bags, beside the linearisation."""
    import json

    import numpy as np

    from hydropump_sim.params import load_params

    from ..ident import read_recordings
    from ..ident.matrix import fit_matrix, linear_elements
    plant = plant_file(args)
    params = load_params(plant)
    recs = read_recordings(args.bags, allow_truncated=args.allow_truncated,
                           progress=args.progress, params=params)
    fits = fit_matrix(recs, params=params)
    current = float(np.mean([np.mean(r['solenoid_current']) for r in recs
                             if 'solenoid_current' in r]))
    lin = linear_elements(params, current)
    result = {'schema': 'hydropump-matrix/1', 'params': str(plant),
              'operating_current_A': current, 'units': MATRIX_UNITS,
              'elements': {k: dict(e.to_dict(), linearisation=lin.get(k))
                           for k, e in fits.items()},
              'provenance': collect([plant, *args.bags])}
    if args.out:
        out = run_dir(args.out, 'matrix')
        write_text(out / 'matrix.json', json.dumps(result, indent=2), 'result')
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f'eq. 16 from {len(recs)} bags; linearisation of {plant} at {current:.4g} A\n')
    print(f'{"element":9s} {"figure":6s} {"fitted":>13s} {"+-":>10s} {"linearised":>13s}')
    for k, e in fits.items():
        for name, v in e.values.items():
            ref = (lin.get(k) or {}).get(name)
            print(f'{k:9s} {name:6s} {v:13.6g} {e.stderr.get(name, float("nan")):10.2g} '
                  + (f'{ref:13.6g}' if ref is not None else f'{"":13s}'))
        for note in e.notes:
            print(f'          ({note})')
    return 0
