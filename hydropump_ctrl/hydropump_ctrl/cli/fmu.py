"""``hydropump fmu``: a circuit file (the paper's pump by default) as an FMI 2.0
co-simulation FMU for other tools (Amesim, Simscape, OpenModelica, FMPy), checked by FMPy's
validation before it is written (docs/fmi.md)."""

from __future__ import annotations

from .options import output_file, overrides, positive_float


def register(sub) -> None:
    c = sub.add_parser('fmu', help="export a circuit (default: the paper's pump) as an FMI "
                       '2.0 co-simulation FMU')
    c.add_argument('file', nargs='?', help='circuit file (default config/circuits/paper.yaml, '
                   "the paper's pump and load)")
    c.add_argument('--out', required=True, help='the FMU file to write (.fmu)')
    c.add_argument('--fmi', choices=('2', '3'), default='2',
                   help='FMI version (2; 3 needs pythonfmu3, not installed)')
    c.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='a parameter or a held input by its dotted name (repeatable)')
    c.add_argument('--step', type=positive_float('s', 1.0), default=1.0e-3,
                   help="the FMU's step [s]: it steps in whole multiples of it (default 1 ms)")
    c.add_argument('--stop-time', type=positive_float('s', 1.0e6), default=1.0,
                   help="the default experiment's stop time [s] (default 1)")
    c.set_defaults(func=cmd_fmu)


def cmd_fmu(args) -> int:
    from ..fmi.export import export_fmu
    out = output_file(args.out, ('.fmu',), 'FMU')
    print(f'building {out} (the circuit is compiled if it is not in the cache) ...',
          flush=True)
    done = export_fmu(out, args.file, sets=overrides(args.set), step=args.step,
                      stop_time=args.stop_time, fmi=int(args.fmi))
    print(f'{done.path}: FMI 2.0 co-simulation, {len(done.inputs)} inputs, '
          f'{len(done.outputs)} outputs, {len(done.parameters)} parameters; FMPy '
          'validation: no problem')
    print(f'  inputs: {", ".join(done.inputs)}')
    print(f'  outputs: {", ".join(done.outputs)}')
    return 0
