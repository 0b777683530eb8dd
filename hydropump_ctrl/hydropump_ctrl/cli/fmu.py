"""``hydropump fmu``: a circuit file (the paper's pump by default) as an FMI 2.0 or 3.0
co-simulation FMU for other tools (Amesim, Simscape, OpenModelica, FMPy), checked by FMPy's
validation before it is written; ``--check FILE.fmu`` reads any FMU as the suite would run
it and lists its variables (docs/fmi.md)."""

from __future__ import annotations

from .options import output_file, overrides, positive_float, UsageError


def register(sub) -> None:
    c = sub.add_parser('fmu', help="export a circuit (default: the paper's pump) as an FMI "
                       '2.0 or 3.0 co-simulation FMU')
    c.add_argument('file', nargs='?', help='circuit file (default config/circuits/paper.yaml, '
                   "the paper's pump and load)")
    c.add_argument('--out', help='the FMU file to write (.fmu)')
    c.add_argument('--check', metavar='FMU', help="read an FMU instead (any tool's): one line "
                   'per problem, else its inputs, outputs and parameters with their units')
    c.add_argument('--fmi', choices=('2', '3'), default='2',
                   help='FMI version: 2 (the tools of today) or 3')
    c.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='a parameter or a held input by its dotted name (repeatable)')
    c.add_argument('--step', type=positive_float('s', 1.0), default=1.0e-3,
                   help="the FMU's step [s]: it steps in whole multiples of it (default 1 ms)")
    c.add_argument('--stop-time', type=positive_float('s', 1.0e6), default=1.0,
                   help="the default experiment's stop time [s] (default 1)")
    c.set_defaults(func=cmd_fmu)


def cmd_fmu(args) -> int:
    if args.check:
        if args.file or args.out:
            raise UsageError('--check reads an FMU: give no circuit file and no --out')
        return _check(args.check)
    if not args.out:
        raise UsageError('--out: give the FMU file to write (or --check FMU to read one)')
    from ..fmi.export import export_fmu
    out = output_file(args.out, ('.fmu',), 'FMU')
    print(f'building {out} (the circuit is compiled if it is not in the cache) ...',
          flush=True)
    done = export_fmu(out, args.file, sets=overrides(args.set), step=args.step,
                      stop_time=args.stop_time, fmi=int(args.fmi))
    print(f'{done.path}: FMI {args.fmi}.0 co-simulation, {len(done.inputs)} inputs, '
          f'{len(done.outputs)} outputs, {len(done.parameters)} parameters; FMPy '
          'validation: no problem')
    print(f'  inputs: {", ".join(done.inputs)}')
    print(f'  outputs: {", ".join(done.outputs)}')
    return 0


def _check(path: str) -> int:
    from ..fmi.reading import read_fmu
    info = read_fmu(path)
    md = info.description
    how = ('model exchange (integrated by the suite)' if info.model_exchange
           else 'co-simulation')
    print(f'{path}: FMI {info.fmi_version} {how}, model {info.model_identifier} '
          f'({md.generationTool or "tool not named"})')
    for causality in ('input', 'output', 'parameter'):
        names = info.of(causality)
        print(f'  {len(names)} {causality}s')
        for name in names:
            v = info.variables[name]
            unit = f' [{v.unit}]' if v.unit else ''
            rng = f' in [{v.min:g}, {v.max:g}]' if v.min is not None and v.max is not None \
                else ''
            start = f', start {v.start:g}' if v.start is not None else ''
            kind = '' if v.real else f' ({v.type}{" array" if v.array else ""})'
            print(f'    {name}{kind}{unit}{rng}{start}')
    return 0
