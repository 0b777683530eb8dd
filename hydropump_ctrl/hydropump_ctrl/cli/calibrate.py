"""``hydropump calibrate BAG... --free NAME...`` and ``hydropump validate --params FILE BAG...``.

``calibrate`` fits chosen plant parameters of the fine model to several bags at once
(:mod:`hydropump_ctrl.ident.calibrate`), writes the calibrated params file (loadable by
``load_params`` and by the simulator node's ``params_file``), a report folder (``result.json``,
``report.md``, before/after and residual plots, the correlation heat map) and prints the
table, or the JSON result with ``--json``. ``validate`` gives the residual (RMS in SI units)
and the fit percentage per signal of a params file on bags it was not fitted to, with
overlays of the measured signals, the params file's prediction and, with ``--before``, another
file's.

``calibrate --fleet FOLDER`` calibrates many pumps: FOLDER holds one folder per pump, each
with its bags; every pump is one task (on a cluster's workers with ``--scheduler ADDRESS``,
a local Dask cluster with ``--workers N``, this process with ``--in-process``; by default
the first pump here, timed, and the rest on a local cluster only if that is sooner), and one
table of every pump's parameters and standard errors is written (``fleet.csv``,
``fleet.parquet``, ``fleet.md``) beside a folder per pump (its params file and report).
A single calibration takes ``--scheduler`` and ``--workers`` too: its simulations and
sensitivity columns become Dask tasks (by default they run on threads of this process).

Both check every bag against the params file before any simulation (a current in mA, a
pressure in bar or gauge, a flow in L/min, the wrong message type, two runs in one bag, too
few samples: one ``error:`` line each, exit code 2); a fleet checks every bag of every pump
first, and an unwritable report folder or a scheduler that does not answer within 5 s ends
in one line before any calibration. A calibration writes its params file whenever it fits the
bags better than the start, its flags in the file's header and on stderr; where a signal is
not fitted to its noise, it names the parameters left fixed that would explain the most
(``what the model may lack``). One that does not improve on the start writes its report but
no params file, and exits with 2; in a fleet that pump is a failed row, and the command exits
with 1 when any pump failed.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import re
import sys
import time

from ..provenance import collect
from .options import (
    add_params_option,
    add_progress_option,
    add_where_options,
    output_file,
    plant_file,
    positive_float,
    protect_output,
    run_dir,
    UsageError,
)

PARAMS_SUFFIXES = ('.yaml', '.yml')


def _progress_printer(enabled: bool | None):
    if enabled is False or (enabled is None and not sys.stderr.isatty()):
        return None
    t0 = time.perf_counter()

    def show(text: str) -> None:
        # Back to the line's start, and cleared after the text (a shorter line follows).
        print(f'\r  calibrating: {text}, {time.perf_counter() - t0:.1f} s\033[K', end='',
              file=sys.stderr, flush=True)
    return show


def _read(args, params, bags=None, **kw):
    """The bags (default: the command's), each checked against the pump of ``params`` on the
    signals the model takes (its inputs and the compared outputs); ``kw`` to the reader."""
    from hydropump_sim.measure import CURRENT_SIGNAL, LOAD_PRESSURE_SIGNAL

    from ..ident import read_recordings
    from ..ident.calibrate.data import COMMAND_SIGNAL
    check = None if args.signals is None else [CURRENT_SIGNAL, COMMAND_SIGNAL,
                                               LOAD_PRESSURE_SIGNAL, *args.signals]
    return read_recordings(args.bags if bags is None else bags,
                           allow_truncated=args.allow_truncated, progress=args.progress,
                           params=params, check=check, **kw)


def _negative_fits(fit: dict) -> list[tuple[str, str, float]]:
    """``(recording, signal, fit %)`` of every fit below zero, worst first."""
    return sorted(((e, s, v) for e, per in fit.items() for s, v in per.items()
                   if v is not None and v < 0.0), key=lambda x: x[2])


def _not_improved(cal) -> str:
    return (f'the calibrated model fits the bags no better than the start (mean weighted '
            f'squared residual {cal.cost:.4g}, at the start {cal.cost_start:.4g})')


def _common(p, bags: str = '+') -> None:
    from hydropump_sim.measure import BENCH_OUTPUT_SIGNALS, OUTPUT_SIGNALS
    p.add_argument('bags', nargs=bags, metavar='BAG',
                   help='bag directory, .mcap or .db3 file, or a saved .npz recording')
    p.add_argument('--profile', metavar='FILE',
                   help='sensor profile the bags were recorded with (e.g. config/bench.yaml): '
                        'its plant settings (the dither) are layered over --params, as the '
                        'simulator node layers them, and left out of the calibrated file '
                        '(it describes the pump; the profile keeps the bench)')
    p.add_argument('--signals', nargs='+', metavar='SIGNAL', choices=OUTPUT_SIGNALS,
                   help='compare these signals (default: those a bench measures that the bags '
                        f'have: {", ".join(BENCH_OUTPUT_SIGNALS)}; the simulator\'s exact '
                        'spool_position and actuator_position only when named here)')
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
    _common(c, '*')
    add_params_option(c, 'to start from')
    c.add_argument('--free', nargs='+', metavar='NAME', required=True,
                   help='plant parameters to fit, dotted as in config/pump.yaml (e.g. '
                        'actuator.mu_a line.V_l); with --fmu, Real parameters of the FMU')
    c.add_argument('--prior', nargs='+', default=[], metavar='NAME=VALUE+-REL',
                   help='a Gaussian prior in log coordinates on a free parameter, e.g. '
                        'line.V_l=5e-4+-10%%: for a direction the bags leave weak; reported '
                        'as such')
    c.add_argument('--offset', nargs='+', default=[], metavar='SIGNAL',
                   help='also fit an offset per bag on these signals')
    c.add_argument('--out', help='calibrated params file (default: calibrated.yaml in the '
                   'report folder); never one of the inputs')
    c.add_argument('--report', help='report folder (default: out/calibrate-<time>)')
    c.add_argument('--json', action='store_true', help='print the JSON result on stdout')
    c.add_argument('--no-multistart', action='store_true',
                   help='one start only (by default two more when the first does not reach '
                        'the noise level)')
    c.add_argument('--fidelity', choices=('fine', 'simplified'), default='fine',
                   help="the model fitted: the fine pump, or section IV's simplified one (eq. "
                   '10 where the spool and plate lie beyond the bandwidth; its error bound '
                   'in the report)')
    c.add_argument('--bandwidth', type=positive_float('Hz', 1.0e4),
                   help="control bandwidth [Hz] of --fidelity simplified (default section "
                   "IV's 20 Hz)")
    c.add_argument('--fmu', metavar='MODEL.fmu',
                   help="fit the real parameters of this FMI 2.0 or 3.0 FMU instead "
                        "of the suite's model: its input current takes the recorded "
                        'command, its outputs named after measured signals are compared; '
                        'writes a params file of the simulator node (fmu_file and the '
                        'calibrated fmu_parameters; docs/fmi.md)')
    c.add_argument('--fleet', metavar='FOLDER',
                   help='calibrate many pumps: FOLDER holds one folder per pump with its bags '
                        '(instead of BAG...); writes fleet.csv, fleet.parquet, fleet.md and a '
                        'folder per pump into --report')
    add_where_options(
        c, scheduler='run on this Dask scheduler, e.g. tcp://host:8786 (default: '
                     '$DASK_SCHEDULER_ADDRESS, else this process)',
        workers='worker processes of a local Dask cluster (default: this process, its '
                'simulations on threads; a fleet: the first pump here, timed, the rest on a '
                'local cluster if that is sooner, start-up included)',
        in_process='this process alone, no Dask (a fleet: one pump after the other)')
    c.set_defaults(func=cmd_calibrate)
    v = sub.add_parser('validate', help='residual and fit %% of a params file on bags it was '
                       'not fitted to', description=__doc__.splitlines()[0],
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    _common(v)
    add_params_option(v, 'to validate')
    v.add_argument('--before', metavar='FILE',
                   help='a second params file to overlay and compare (e.g. the start of a '
                        "calibration; default: the start named in a calibrated file's "
                        'header, if it exists)')
    v.add_argument('--out', help='report folder (default: out/validate-<time>)')
    v.add_argument('--json', action='store_true', help='print the JSON result on stdout')
    v.set_defaults(func=cmd_validate)


def _plant(path, profile):
    """The params file, with the plant settings of ``profile`` layered over it."""
    from hydropump_sim.params import load_params
    from hydropump_sim.sensors import load_profile
    params = load_params(path)
    if profile:
        over = load_profile(profile).plant_overrides or {}
        if over:
            params = params.replace(over)
    return params


def _plant_only(cal, plant, profile) -> tuple[object, list[str]]:
    """What the calibrated file holds: ``cal.params`` with the bench's settings that
    ``profile`` layered over the plant (its dither) back at the start file's values, unless
    they were free (the file describes the pump; the profile keeps the bench), and the
    header's line about it."""
    if not profile:
        return None, []
    from hydropump_sim.params import load_params
    from hydropump_sim.sensors import load_profile
    over = load_profile(profile).plant_overrides or {}
    own = load_params(plant).flat()
    back = {k: own[k] for k in over if k not in cal.free}
    if not back:
        return None, []
    return cal.params.replace(back), [
        f'calibrated with the bench settings of {profile} layered over the start '
        f'({", ".join(sorted(back))}); written here as the start has them: the profile '
        'keeps the bench']


def _priors(args):
    from ..ident.calibrate import parse_prior
    out = []
    for text in args.prior:
        try:
            out.append(parse_prior(text))
        except ValueError as exc:
            raise UsageError(str(exc)) from None
    return out


def _executor(args):
    """Where the work goes: the scheduler of ``--scheduler`` (or $DASK_SCHEDULER_ADDRESS), a
    local cluster of ``--workers`` processes, this process with ``--in-process``; else None:
    the library's default (one calibration: threads of this process; a fleet: its first
    pump here, timed, then the rest here or on a local cluster, whichever is sooner)."""
    from ..batch import InProcess, open_executor
    if args.in_process and args.scheduler:
        raise UsageError(f'--in-process and --scheduler {args.scheduler}: choose one')
    if args.in_process:
        return InProcess()
    if args.scheduler or os.environ.get('DASK_SCHEDULER_ADDRESS') or args.workers:
        return open_executor(args.scheduler, args.workers)
    return None


def cmd_calibrate(args) -> int:
    if args.fmu and not args.fleet and (args.scheduler or args.workers):
        given = ' '.join(o for o, v in (('--scheduler', args.scheduler),
                                         ('--workers', args.workers)) if v)
        raise UsageError(f'--fmu with {given}: one FMU is calibrated in this process (a '
                         'fleet of them, --fleet, goes to a cluster)')
    if args.bandwidth is not None and args.fidelity == 'fine':
        raise UsageError('--bandwidth goes with --fidelity simplified')
    if args.fidelity != 'fine' and (args.fmu or args.fleet):
        raise UsageError(f'--fidelity {args.fidelity} goes with the bags of one pump (an FMU '
                         'is fitted as it is; a fleet at the fine fidelity)')
    if args.fleet:
        return _fleet(args)
    if not args.bags:
        raise UsageError('calibrate: give the bags (BAG ...) or a fleet folder (--fleet FOLDER)')
    return _single(args)


def _single_fmu(args, priors, plant, report, out, show) -> int:
    """``calibrate --fmu MODEL.fmu``: the FMU's parameters (hydropump_ctrl.fmi.calibration)."""
    from ..fmi.calibration import calibrate_fmu, write_fmu_params
    from ..ident.calibrate import CalibrationError, write_calibration_report
    from ..ident.calibrate.data import COMMAND_SIGNAL
    base = _plant(plant, args.profile)
    # The FMU's current is the commanded one, as the simulator node gives it.
    recs = _read(args, base, current_topic=COMMAND_SIGNAL)
    cal = calibrate_fmu(args.fmu, recs, base, args.free, offsets=args.offset,
                        fit_delays=not args.no_delays, signals=args.signals, priors=priors,
                        multistart=not args.no_multistart, progress=show)
    if show:
        print(file=sys.stderr)
    cal.provenance = collect([args.fmu, *args.bags])
    write_calibration_report(cal, report, plots=not args.no_plots)
    if not cal.improved:
        raise CalibrationError(f'{_not_improved(cal)}: no params file written; see '
                               f'{report}/report.md')
    write_fmu_params(cal, args.fmu, out, [f'FMU: {args.fmu}'])
    return _print_calibration(args, cal, recs, out, report)


def _single(args) -> int:
    from ..ident.calibrate import (
        calibrate,
        CalibrationError,
        refuse_foreign_report,
        write_calibration_report,
        write_params,
    )
    from ..ident.design import suggest
    priors = _priors(args)
    plant = plant_file(args)
    inputs = [plant, *args.bags] + [f for f in (args.profile, args.fmu) if f]
    if args.out:
        protect_output(args.out, inputs, 'calibrated params file')
    if args.report:
        protect_output(args.report, inputs, 'report folder')
    report = run_dir(args.report, 'calibrate')
    refuse_foreign_report(report)
    out = output_file(Path(args.out) if args.out else report / 'calibrated.yaml',
                      PARAMS_SUFFIXES, 'params file',
                      kind='FMU params' if args.fmu else 'plant params')
    show = _progress_printer(args.progress)
    if args.fmu:
        return _single_fmu(args, priors, plant, report, out, show)
    base = _plant(plant, args.profile)
    recs = _read(args, base)
    ex = _executor(args)
    try:
        cal = calibrate(recs, base, args.free, offsets=args.offset,
                        fit_delays=not args.no_delays, signals=args.signals, priors=priors,
                        multistart=not args.no_multistart, progress=show, executor=ex,
                        fidelity=args.fidelity, bandwidth=args.bandwidth or 0.0)
    finally:
        if ex is not None:
            ex.close()
    if args.fidelity == 'fine':     # the next experiments are designed on the fine model
        suggest(cal, show)
    if show:
        print(file=sys.stderr)
    cal.provenance = collect(inputs)
    if not cal.improved:
        # No better than the start is no calibration: the report says why, and no params
        # file is left for a simulator to load. (Units were checked with the bags.)
        write_calibration_report(cal, report, plots=not args.no_plots)
        raise CalibrationError(f'{_not_improved(cal)}: no params file written; see '
                               f'{report}/report.md')
    own, bench = _plant_only(cal, plant, args.profile)
    fitted = [] if args.fidelity == 'fine' else [f'fitted at the fidelity {cal.fidelity}']
    write_params(cal, out, [f'start: {plant}', *bench, *fitted], own)
    write_calibration_report(cal, report, plots=not args.no_plots)
    return _print_calibration(args, cal, recs, out, report)


def _print_calibration(args, cal, recs, out, report) -> int:
    """The calibration on stdout (the JSON result with ``--json``), its flags on stderr."""
    from ..ident.calibrate.writers import estimate_text, fit_table
    if args.json:
        print(json.dumps(cal.to_dict(), indent=2))
        return 0
    print(f'calibrated {len(cal.free)} parameters on {len(recs)} recordings '
          f'({cal.n_simulations} simulated runs, {cal.wall_time:.1f} s)\n')
    w = max(len(n) for n in cal.free)
    for p in cal.estimates:
        print(f'  {p.name:<{w}}  {p.initial:12.6g} -> {p.value:12.6g}  {estimate_text(p)}'
              + (f'  [{p.on_bound} bound]' if p.on_bound else ''))
    for n, v in cal.tied.items():
        print(f'  {n:<{w}}  tied: {v:.6g}')
    print('\nfit % (start -> calibrated):')
    print(fit_table(cal.fit, cal.fit_before))
    if cal.timing:
        print(f'\ntiming: {cal.timing}')
    if cal.missing:
        print('\nwhat the model may lack (signals not fitted to their noise):')
        for k, c in enumerate(cal.missing):
            print(f'  {k + 1}. {c["text"]}')
    for f in cal.flags:
        print(f'warning: {f}', file=sys.stderr)
    print(f'\nwrote {out} and {report}/report.md')
    return 0


def _fleet(args) -> int:
    """``calibrate --fleet FOLDER``: every pump of the folder, one task each (see the
    module)."""
    # The command's steps in the order a user sees them (checks, tasks, progress, report):
    # long on purpose, each step a few lines that say what the user is told.
    from ..ident.calibrate import (
        CalibrationError,
        check_free,
        write_calibration_report,
        write_params,
    )
    from ..ident.calibrate.fleet import (
        calibrate_fleet,
        find_pumps,
        fleet_markdown,
        read_fleet,
        write_fleet_table,
    )
    from ..ident.design import suggest
    if args.bags:
        raise UsageError(f'calibrate: give the bags ({" ".join(args.bags)}) or --fleet '
                         f'{args.fleet}, not both')
    if args.out:
        raise UsageError(f'--out {args.out}: a fleet writes one params file per pump, into '
                         '--report FOLDER/<pump>/calibrated.yaml; give --report instead')
    priors = _priors(args)
    plant = plant_file(args)
    pumps = find_pumps(args.fleet)
    inputs = [plant, args.fleet] + [f for f in (args.profile, args.fmu) if f]
    if args.report:
        protect_output(args.report, inputs, 'report folder')
    base = _plant(plant, args.profile)
    # The free names checked (against the FMU: it is read and loaded once) before the
    # report folder is made; each pump's params file before the tasks, its folder made when
    # its result arrives.
    if args.fmu:
        from ..fmi.calibration import check_fmu_free, write_fmu_params
        from ..ident.calibrate.data import COMMAND_SIGNAL
        errors = check_fmu_free(args.fmu, base, args.free)
        read = {'current_topic': COMMAND_SIGNAL}    # the FMU's current is the commanded one
    else:
        errors, read = check_free(base, args.free), {}
    if errors:
        raise CalibrationError(errors)
    report = run_dir(args.report, 'calibrate-fleet')
    outs = {name: output_file(report / name / 'calibrated.yaml', PARAMS_SUFFIXES,
                              f'params file of {name}', create=False,
                              kind='FMU params' if args.fmu else 'plant params')
            for name in pumps}
    recs = read_fleet(pumps, lambda bags: _read(args, base, bags, **read))
    header = [f'start: {plant}']
    done = []

    def store(res):
        # As each pump's result arrives: its params file (not when it fits no better than
        # the start) and its report.
        cal = res.calibration
        if cal is not None:
            if not args.fmu:        # the next experiments are designed for the suite's model
                suggest(cal)
            cal.provenance = collect([plant, args.profile, args.fmu, *res.sources])
            folder = outs[res.name].parent
            try:
                folder.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise UsageError(f'cannot create the folder of {res.name} {folder}: '
                                 f'{exc.strerror or exc}') from None
            if not cal.improved:
                res.reason = f'{_not_improved(cal)}: no params file written'

            elif args.fmu:
                res.files.append(write_fmu_params(cal, args.fmu, outs[res.name], [
                    f'FMU: {args.fmu}', f'pump {res.name} of the fleet {args.fleet}']))
            else:
                own, bench = _plant_only(cal, plant, args.profile)
                res.files.append(write_params(cal, outs[res.name], [
                    *header, *bench, f'pump {res.name} of the fleet {args.fleet}'], own))
            write_calibration_report(cal, folder, plots=not args.no_plots)
            res.files.append(folder / 'report.md')
        done.append(res.name)
        if args.progress is not False:
            print(f'fleet: {res.name} {res.status} ({len(done)}/{len(pumps)}, '
                  f'{res.wall_s:.1f} s){": " + res.reason if res.reason else ""}',
                  file=sys.stderr, flush=True)

    ex = _executor(args)
    try:
        result = calibrate_fleet(recs, base, args.free, executor=ex, on_result=store,
                                 fmu=args.fmu,
                                 offsets=args.offset, fit_delays=not args.no_delays,
                                 signals=args.signals, priors=priors,
                                 multistart=not args.no_multistart)
    finally:
        if ex is not None:
            ex.close()
    paths = write_fleet_table(result, report, collect(inputs))
    if args.json:
        print(json.dumps({p.name: p.calibration.to_dict() if p.status == 'ok'
                          else {'status': p.status, 'reason': p.reason}
                          for p in result.pumps}, indent=2))
    else:
        print(fleet_markdown(result))
        print(f'wrote {paths["md"]}, {paths["csv"].name} and {paths["parquet"].name}, and a '
              f'folder per pump in {report}')
    for p in result.pumps:
        if p.status != 'ok':
            print(f'warning: {p.name}: {p.reason}', file=sys.stderr)
    return 1 if result.failed else 0


def _start_of(path: Path) -> Path | None:
    """The start file a calibrated params file names in its header, if it still exists."""
    try:
        head = path.read_text(encoding='utf-8').split('\n/**', 1)[0]
    except OSError:
        return None
    m = re.search(r'^# start: (.+)$', head, re.MULTILINE)
    p = Path(m.group(1).strip()) if m else None
    return p if p is not None and p.is_file() else None


def cmd_validate(args) -> int:
    from ..ident.calibrate import write_validation_report
    from ..ident.calibrate.writers import fit_table, misfit_table, validation_dict
    plant = plant_file(args)
    before_file = Path(args.before) if args.before else _start_of(plant)
    if args.out:
        protect_output(args.out, [plant, *args.bags], 'report folder')
    out = run_dir(args.out, 'validate')
    params = _plant(plant, args.profile)
    before = _plant(before_file, args.profile) if before_file else None
    recs = _read(args, params)
    from ..ident.calibrate import validate
    val = validate(recs, params, signals=args.signals, fit_delays=not args.no_delays,
                   before=before)
    prov = collect([plant, before_file, args.profile, *args.bags])
    before_name = str(before_file) if before_file else None
    write_validation_report(val, out, str(plant), before_name, plots=not args.no_plots,
                            prov=prov)
    if args.json:
        print(json.dumps(validation_dict(val, str(plant), before_name, prov), indent=2))
        _warn_negative(val['fit'])
        return 0
    print(f'{plant} on {len(recs)} recordings' + (f' (before: {before_file})' if before_file
                                                   else '') + ':\n')
    print(misfit_table(val['misfit'], val.get('misfit_before')))
    print('\nfit %' + (' (before -> after)' if before is not None else '') + ':')
    print(fit_table(val['fit'], val.get('fit_before')))
    _warn_negative(val['fit'])
    print(f'\nwrote {Path(out) / "validation.md"}')
    return 0


def _warn_negative(fit: dict) -> None:
    """A ``warning:`` line per signal the params file predicts worse than its mean."""
    for e, s, v in _negative_fits(fit):
        print(f'warning: {e}: {s} fit {v:.4g} % is below zero: the params file predicts it '
              'worse than its mean (wrong units, params file or bag?)', file=sys.stderr)
