"""``hydropump circuit``: a circuit file simulated from its steady state, every signal's
final value printed (``<component>.<signal>``), the paper's method applied on request.

The pump runs under margin control against the highest load by default (EMC, or PI with
``--algorithm pi``), in open loop (its current as set or scheduled) or under the
hydromechanical load-sensing compensator (``--control``). ``--set NAME=VALUE`` sets a
parameter or holds an input by its dotted name (``boom.compensator=post``,
``boom.command=0.8``, ``pump.actuator.mu_a=6e-6``, ``fluid.beta=1.6e+9``); a scenario file
schedules inputs in time.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from .options import float_in, output_file, overrides, positive_float, UsageError

UNITS = {'Pa': (1e-5, 'bar'), 'm^3/s': (60000.0, 'L/min')}


def register(sub) -> None:
    c = sub.add_parser('circuit', help='simulate a circuit file (config/circuits/*.yaml) and '
                       "print every signal; --analyze for the paper's method on it")
    c.add_argument('file', help='circuit file, e.g. config/circuits/fig1.yaml')
    c.add_argument('--duration', type=positive_float('s', 3600.0),
                   help="simulated time [s] after the start (default: the scenario's, else 1)")
    c.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='a parameter or a held input by its dotted name (repeatable)')
    c.add_argument('--control', choices=('margin', 'open', 'hydromechanical'),
                   help="the pump's control (default: margin against the highest load, "
                   'open loop for a circuit with nothing to sense)')
    c.add_argument('--algorithm', choices=('emc', 'pi'), help="margin control's law "
                   "(default: the controller configuration's)")
    # The range of the controller's margin set-point.
    c.add_argument('--margin', type=float_in(1.0e5, 1.0e7, 'Pa'), help='margin P_l - P_LS '
                   "[Pa] (default: the controller configuration's)")
    c.add_argument('--scenario', help='YAML file: duration, set (dotted values) and inputs '
                   'scheduled in time (the scenario format of hydropump simulate)')
    c.add_argument('--fidelity', choices=('fine', 'simplified'), default='fine',
                   help="the circuit run: fine, or section IV's simplified one (the modes "
                   "beyond the bandwidth made static, its error bound printed)")
    c.add_argument('--bandwidth', type=positive_float('Hz', 1.0e4),
                   help='control bandwidth [Hz] of --fidelity simplified (default: margin '
                   "control's, else section IV's 20 Hz)")
    c.add_argument('--json', action='store_true', help='the final values as JSON on stdout')
    c.add_argument('--csv', help='write every signal over time to this CSV file')
    c.add_argument('--analyze', action='store_true', help='steady state, modes, section IV '
                   'component by component, the simplified circuit and the transfer matrix')
    c.add_argument('--check', action='store_true', help="check the run's physical "
                   'invariants (no pressure above every source, none below the cavitation '
                   'floor, no component making energy): each broken one in a line, exit 1')
    c.set_defaults(func=cmd_circuit)


def _scenario(path: str) -> tuple[float | None, dict, dict]:
    from hydropump_sim.schema import ParamError, read_yaml
    try:
        doc = read_yaml(path)
    except ParamError as exc:
        raise UsageError(f'--scenario {path}: {exc.lines[0]}') from None
    if not isinstance(doc, dict):
        raise UsageError(f'--scenario {path}: expected a mapping (duration, set, inputs)')
    bad = set(doc) - {'duration', 'set', 'inputs'}
    if bad:
        raise UsageError(f'--scenario {path}: unknown key(s) {", ".join(sorted(bad))} (use '
                         'duration, set, inputs)')
    duration = doc.get('duration')
    if duration is not None and not (isinstance(duration, (int, float))
                                     and not isinstance(duration, bool)
                                     and np.isfinite(duration) and duration > 0):
        raise UsageError(f'--scenario {path}: duration = {duration!r}: expected seconds > 0')
    sets = doc.get('set') or {}
    if not isinstance(sets, dict):
        raise UsageError(f'--scenario {path}: set: expected a mapping of dotted names')
    return duration, sets, doc.get('inputs')


def _fmt(value: float, unit: str) -> str:
    if unit in UNITS:
        k, u = UNITS[unit]
        return f'{value:.6g} {unit} ({value * k:.4g} {u})'
    return f'{value:.6g} {unit}'


def cmd_circuit(args) -> int:
    from hydropump_sim.circuit import load_circuit
    from hydropump_sim.scenario import parse_inputs, ScenarioError

    from ..experiments.circuit_loop import run_circuit
    csv = output_file(args.csv, ('.csv',), 'CSV', kind='results CSV') if args.csv else None
    sets = overrides(args.set)
    inputs_raw, duration = None, args.duration
    if args.scenario:
        d, s, inputs_raw = _scenario(args.scenario)
        duration = d if duration is None else duration  # the command line's wins
        sets = {**s, **sets}
    duration = 1.0 if duration is None else duration
    t0 = time.perf_counter()
    circuit = load_circuit(args.file, sets)
    errors: list[str] = []
    inputs = parse_inputs(inputs_raw, errors, circuit.all_inputs())
    if errors:
        raise ScenarioError(errors, args.scenario)
    control = args.control
    m = circuit.measured()
    if control is None:
        control = 'margin' if ('ls_pressure' in m or 'load_pressure' in m) and \
            circuit.electric_pump() else 'open'
    if control != 'margin' and (args.algorithm or (args.margin is not None and control == 'open')):
        raise UsageError(f'--algorithm and --margin go with --control margin (not {control})')
    if args.bandwidth is not None and args.fidelity == 'fine':
        raise UsageError('--bandwidth goes with --fidelity simplified')
    run = run_circuit(circuit, duration, inputs, control=control, algorithm=args.algorithm,
                      margin=args.margin, fidelity=args.fidelity,
                      bandwidth=args.bandwidth or 0.0)
    fid = run.info['fidelity']
    elapsed = time.perf_counter() - t0
    final = run.final()
    units = {n: run.circuit.signal_units[run.circuit.signal_index(n)] for n in final}
    if csv is not None:
        from hydropump_sim.system import Result
        Result(run.circuit, run.t, run.y, run.y[:, :0], run.u).to_csv(csv)
    how = control + (f' ({run.algorithm}, margin {run.margin / 1e5:.4g} bar)'
                     if control == 'margin' else f' (margin {run.margin / 1e5:.4g} bar)'
                     if control == 'hydromechanical' else '')
    if args.json:
        print(json.dumps({'circuit': run.circuit.name, 'control': control,
                          'algorithm': run.algorithm, 'margin': run.margin,
                          'duration': duration, 'fidelity': {
                              'name': fid.name, 'bandwidth': fid.bandwidth,
                              'static': list(fid.components), 'error_bound': fid.bound},
                          'signals': final, 'units': units}, indent=2))
    else:
        print(f'{run.circuit.name}: {duration:g} s under {how}, {elapsed:.1f} s')
        if fid.name != 'fine':
            print(f'fidelity: {fid.text()}')
        width = max(len(n) for n in final)
        for name, value in final.items():
            print(f'  {name:<{width}}  {_fmt(value, units[name])}')
        if csv is not None:
            print(f'wrote {csv}')
    if args.analyze:
        print(analysis_text(run.circuit))
    if args.check:
        from hydropump_sim.invariants import report
        violations = run.info['violations']
        print(report(violations), file=sys.stderr if violations else sys.stdout)
        return 1 if violations else 0
    return 0


def analysis_text(circuit) -> str:
    """The paper's method on a circuit (see :mod:`hydropump_sim.reduction`)."""
    from hydropump_sim.linear import linearize, modal_analysis, transfer_matrix
    from hydropump_sim.reduction import (
        EPSILON_STATIC,
        singular_perturbation,
        T_CONTROL,
    )
    from hydropump_sim.steady import equilibrium
    eq = equilibrium(circuit)
    lines = [f'\nsteady state of {circuit.name} at the held inputs (residual '
             f'{eq.residual:.1e})']
    for name in circuit.judged_signals():
        unit = circuit.signal_units[circuit.signal_index(name)]
        lines.append(f'  {name:<28} {_fmt(eq[name], unit)}')
    lin = linearize(circuit, eq, inputs=[], outputs=[])
    lines.append(f'\nmodes (linearisation at that state, growing-flow branch), {len(lin.states)} '
                 'states:')
    lines.append(f'  {"tau [ms]":>10} {"f_n [Hz]":>9} {"zeta":>6}  dominant state')
    for m in modal_analysis(lin, n_dominant=1):
        tau = f'{m.tau * 1e3:10.3g}' if m.tau != float('inf') else f'{"inf":>10}'
        lines.append(f'  {tau} {m.f_n:9.3g} {m.zeta:6.2f}  {m.dominant[0]}')
    checks, simple = singular_perturbation(circuit, eq)
    lines.append(f'\nsection IV component by component (T = {T_CONTROL * 1e3:g} ms; tau: the '
                 'slowest mode its static form removes, else its own; error: the largest '
                 'deviation of the judged signals with it static alone, as a fraction of '
                 'their excursion):')
    for c in checks:
        err = max(c.error.values()) if c.error else None
        what = ('no static form' if not c.static else
                f'static: error {err:.2%}' if err is not None else 'kept')
        lines.append(f'  {c.component:<28} tau {c.tau * 1e3:8.3g} ms  eps {c.epsilon:7.3g}  '
                     + ('outside' if c.epsilon < 1 else 'inside') + f' the bandwidth, {what}')
    lines.append(f'  (made static: eps below {EPSILON_STATIC:g}, a mode well outside the '
                 'bandwidth)')
    err = max(simple['error'].values()) if simple['error'] else 0.0
    lines.append(f'simplified circuit: {", ".join(simple["components"]) or "nothing"} made '
                 f'static; error {err:.2%}')
    tf = transfer_matrix(circuit, eq)
    f = 1.0
    lines.append(f'\ntransfer matrix at {f:g} Hz (gain, SI units per unit of input; '
                 'eq. 16 generalised; integrating paths have no DC gain):')
    g = tf(2j * np.pi * f)
    for i, out in enumerate(tf.output_labels):
        row = ', '.join(f'{inp}: {abs(g[i][j]):.4g}' for j, inp in enumerate(tf.input_labels))
        lines.append(f'  {out}: {row}')
    return '\n'.join(lines)
