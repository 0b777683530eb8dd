"""``hydropump calibrate BAG... --free NAME...`` and ``hydropump validate --params FILE BAG...``.

``calibrate`` fits chosen plant parameters of the fine model to several bags at once
(:mod:`hydropump_ctrl.ident.calibrate`), writes the calibrated params file (loadable by
``load_params`` and by the simulator node's ``params_file``), a report folder (``result.json``,
``report.md``, before/after and residual plots, the correlation heat map) and prints the
table, or the JSON result with ``--json``. ``validate`` gives the fit % per signal of a params
file on bags it was not fitted to, with the same plots.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time

from ._common import add_params_option, add_progress_option, output_file, plant_file, run_dir

PARAMS_SUFFIXES = ('.yaml', '.yml')


def _progress_printer(enabled: bool | None):
    if enabled is False or (enabled is None and not sys.stderr.isatty()):
        return None
    t0 = time.perf_counter()

    def show(text: str) -> None:
        print(f'\r  calibrating: {text}, {time.perf_counter() - t0:.1f} s', end='',
              file=sys.stderr, flush=True)
    return show


def _read(args):
    from ..ident import read_recordings
    return read_recordings(args.bags, allow_truncated=args.allow_truncated,
                           progress=args.progress)


def _common(p) -> None:
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='bag directory, .mcap or .db3 file, or a saved .npz recording')
    p.add_argument('--profile', metavar='FILE',
                   help='sensor profile the bags were recorded with (e.g. config/bench.yaml): '
                        'its plant settings (the dither) are layered over --params, as the '
                        'simulator node layers them')
    p.add_argument('--signals', nargs='+', metavar='SIGNAL',
                   help='compare only these signals (default: every measured one the bags '
                        'have)')
    p.add_argument('--no-delays', action='store_true',
                   help='fit no measurement delays (every signal taken as undelayed)')
    p.add_argument('--allow-truncated', action='store_true',
                   help='use the readable part of truncated bags')
    p.add_argument('--no-plots', action='store_true', help='report without figures')
    add_progress_option(p)


def register(sub) -> None:
    """Add ``calibrate`` and ``validate`` to the ``hydropump`` command line."""
    c = sub.add_parser('calibrate', help='fit plant parameters of the fine model to bags '
                       '(grey box) and write a calibrated params file',
                       description=__doc__.splitlines()[0],
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _common(c)
    add_params_option(c, 'to start from')
    c.add_argument('--free', nargs='+', metavar='NAME', required=True,
                   help='plant parameters to fit, dotted as in config/pump.yaml (e.g. '
                        'actuator.mu_a line.V_l)')
    c.add_argument('--offset', nargs='+', default=[], metavar='SIGNAL',
                   help='also fit an offset per bag on these signals')
    c.add_argument('--out', help='calibrated params file (default: calibrated.yaml in the '
                   'report folder)')
    c.add_argument('--report', help='report folder (default: out/calibrate-<time>)')
    c.add_argument('--json', action='store_true', help='print the JSON result on stdout')
    c.add_argument('--no-multistart', action='store_true',
                   help='one start only (by default two more when the first does not reach '
                        'the noise level)')
    c.set_defaults(func=cmd_calibrate)
    v = sub.add_parser('validate', help='fit % of a params file on bags it was not fitted to',
                       description='fit % per signal of a params file on bags, with plots',
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _common(v)
    add_params_option(v, 'to validate')
    v.add_argument('--out', help='report folder (default: out/validate-<time>)')
    v.add_argument('--json', action='store_true', help='print the JSON result on stdout')
    v.set_defaults(func=cmd_validate)


def _check_signals(args) -> None:
    from ..ident.calibrate import OUTPUT_SIGNALS
    from ._common import UsageError
    bad = [s for s in args.signals or () if s not in OUTPUT_SIGNALS]
    if bad:
        raise UsageError(f'--signals {" ".join(bad)}: not a compared signal (choose from '
                         f'{", ".join(OUTPUT_SIGNALS)})')


def _plant(args):
    """The params file, with the plant settings of ``--profile`` layered over it."""
    from hydropump_sim.params import load_params
    from hydropump_sim.sensors import load_profile
    plant = plant_file(args)
    params = load_params(plant)
    if args.profile:
        over = load_profile(args.profile).plant_overrides or {}
        if over:
            params = params.replace(over)
    return plant, params


def cmd_calibrate(args) -> int:

    from ..ident.calibrate import calibrate, write_params
    from ..ident.calibration_report import fit_table, write_calibration_report
    from ..ident.design import suggest
    _check_signals(args)
    plant, base = _plant(args)
    report = run_dir(args.report, 'calibrate')
    out = output_file(args.out or report / 'calibrated.yaml', PARAMS_SUFFIXES, 'params file')
    recs = _read(args)
    show = _progress_printer(args.progress)
    cal = calibrate(recs, base, args.free, offsets=args.offset, fit_delays=not args.no_delays,
                    signals=args.signals, multistart=not args.no_multistart, progress=show)
    if show:
        print(file=sys.stderr)
    suggest(cal)
    write_params(cal, out, [f'start: {plant}'] + ([f'layered with the plant settings of '
                                                   f'{args.profile}'] if args.profile else []))
    write_calibration_report(cal, report, plots=not args.no_plots)
    if args.json:
        print(json.dumps(cal.to_dict(), indent=2))
        return 0
    print(f'calibrated {len(cal.free)} parameters on {len(recs)} recordings '
          f'({cal.n_simulations} simulations, {cal.wall_time:.1f} s)\n')
    w = max(len(n) for n in cal.free)
    for p in cal.estimates:
        se = ('NOT DETERMINED by these recordings' if not p.determined else
              f'+- {p.stderr:.3g} ({100 * p.stderr / abs(p.value):.2f} %)' if p.stderr else '')
        print(f'  {p.name:<{w}}  {p.initial:12.6g} -> {p.value:12.6g}  {se}'
              + (f'  [{p.on_bound} bound]' if p.on_bound else ''))
    for n, v in cal.tied.items():
        print(f'  {n:<{w}}  tied: {v:.6g}')
    print('\nfit % (start -> calibrated):')
    print(fit_table(cal.fit, cal.fit_before))
    for f in cal.flags:
        print(f'warning: {f}', file=sys.stderr)
    print(f'\nwrote {out} and {report}/report.md')
    return 0


def cmd_validate(args) -> int:
    from ..ident.calibrate import validate
    from ..ident.calibration_report import fit_table, write_validation_report
    _check_signals(args)
    plant, params = _plant(args)
    out = run_dir(args.out, 'validate')
    recs = _read(args)
    fit, delays, exps, preds = validate(recs, params, signals=args.signals,
                                        fit_delays=not args.no_delays)
    write_validation_report(fit, delays, exps, preds, out, str(plant), plots=not args.no_plots)
    if args.json:
        print(json.dumps({'params': str(plant), 'fit_percent': fit, 'delays_s': delays},
                         indent=2))
        return 0
    print(f'fit % of {plant} on {len(recs)} recordings:')
    print(fit_table(fit))
    print(f'\nwrote {Path(out) / "validation.md"}')
    return 0
