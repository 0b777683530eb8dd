"""``hydropump design`` and ``hydropump closed-loop``: the control sub-commands.

``design`` builds the controller from the plant's own model (its fine model's step, its
linearisation, eqs. 11, 15 and 17) and the sensor profile's flow delay, or from eq. 19 numbers
where given; it prints every model number with where it came from, the gains, the closed-loop
eigenvalues and the loop margins, and writes ``config/controller.yaml``.
``closed-loop`` runs the judged cases on the fine-model simulator with the bench sensors and
plots EMC beside the PI baseline.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
import time

import numpy as np

from hydropump_sim.files import pyplot, save_figure, write_text
from hydropump_sim.params import load_params

from .options import (
    add_params_option,
    float_in,
    output_file,
    overrides,
    plant_file,
    positive,
    positive_float,
    protect_output,
    run_dir,
    UsageError,
)

CONTROLLER_YAML = 'controller.yaml'
BENCH_YAML = 'bench.yaml'
PARAMS_SUFFIXES = ('.yaml', '.yml')


# --- design -----------------------------------------------------------------------------------

# Units of the model group, as printed.
MODEL_UNITS = {'gain': 'm^3/(s A)', 'I_nominal': 'A', 'I_max': 'A', 'Q_bar': 'm^3/s',
               'Q_max': 'm^3/s', 'tau': 's', 'tau_down': 's', 'tau_z': 's', 't_d': 's',
               'flow_error_max': 'm^3/s', 'C_l': 'm^3/Pa', 'gamma_u': '-'}


def model_lines(cfg, sources: dict) -> list[str]:
    """One line per model number: its value in the configuration and where it came from."""
    m = cfg.model
    out = []
    for name, unit in MODEL_UNITS.items():
        val = getattr(m, name)
        extra = ''
        if name == 't_d':
            n = cfg.delay_steps
            extra = f'; {n} period{"s" * (n != 1)} of {cfg.period * 1e3:g} ms'
        elif name == 'flow_error_max':
            extra = f'; {val / m.Q_max * 100:.1f} % FS'
        out.append(f'  {name:14s} = {val:<11.5g} {unit:9s} ({sources.get(name, "?")}{extra})')
    return out


def design_report(cfg, params, sources: dict, lines_of: dict | None = None) -> str:
    """Gains, eigenvalues and margins of a controller configuration, as text; ``sources``
    says where each model number came from. Against compensated loads the margin loop is
    judged on the modelled line and on each line capacitance of ``lines_of`` (label ->
    m^3/Pa: the circuit's line in other states)."""
    # The report's sections in reading order, each a few lines of text: long on purpose.
    from ..control import design as dz
    T, m, e = cfg.period, cfg.model, cfg.emc
    g = dz.emc_gains(cfg)
    lines = ['== Embedded model: every number and where it comes from ==']
    lines += model_lines(cfg, sources)
    lines.append('')
    lines.append(f'== Eigenvalues (chosen) and gains, T = {T * 1e3:g} ms ==')

    def ev(tau):
        return f'tau {tau * 1e3:6.1f} ms  z = {math.exp(-T / tau):.4f}'
    lines += [
        f'  reference generator (flow)    {ev(e.tau_reference)}   k_r = {g.k_r:.4f}, '
        f'|v_r - Q_r| <= {g.reference_limit / m.Q_max * 100:.1f} % FS',
        f'  reference generator (margin)  {ev(e.tau_margin_flow)}   k_r = {g.k_r_margin:.4f}',
        f'  margin set-point trajectory   {ev(e.tau_margin_reference)}',
        f'  state feedback                {ev(e.tau_control)}   k_x = {g.k_x:.4f}',
        f'  flow noise estimator          {ev(e.tau_estimator_fast)}',
        f'                                {ev(e.tau_estimator_slow)}',
        f'    growing branch (eq. 19):  l_Q = {g.up.l_Q:.4f}, l_d = {g.up.l_d:.4f}',
        f'    falling branch (eq. 15, zero c = {g.down.c:.3f}):  l_Q = {g.down.l_Q:.4f}, '
        f'l_d = {g.down.l_d:.4f}',
        f'  line noise estimator          {ev(e.tau_line_fast)}',
        f'                                {ev(e.tau_line_slow)}',
        '    gains follow the line pole of the operating point:']
    for xi, dp, _q, _, tl in dz.margin_operating_points(params, (0.08, 0.5, 0.96), (2.5e6,)):
        a = math.exp(-T / tl)
        l_p, l_k = dz.line_estimator_gains(a, m.gamma_u, g.poles['line_fast'],
                                          g.poles['line_slow'])
        lines.append(f'      xi {xi:4.2f}, {dp / 1e5:g} bar: tau_l {tl * 1e3:5.1f} ms, '
                     f'alpha {a:.3f}: l_p = {l_p:+.4f}, l_k = {l_k:+.4f}')
    lines.append('')
    lines.append('== Closed-loop eigenvalues, nominal flow loop on the linear model with the '
                 'delay ==')
    for branch in ('up', 'down'):
        z = dz.closed_loop_eigenvalues(cfg, branch)
        dom = sorted((p for p in z if abs(p) > 0.3), key=lambda p: -abs(p))
        txt = ', '.join(f'{p.real:.4f}' + (f'{p.imag:+.4f}j' if abs(p.imag) > 1e-6 else '')
                        + f' ({-T / math.log(abs(p)) * 1e3:.1f} ms)' for p in dom)
        rest = max((abs(p) for p in z if abs(p) <= 0.3), default=0.0)
        lines.append(f'  {branch:4s}: {txt}; {len(z) - len(dom)} more with |z| <= {rest:.2f} '
                     '(the delay line)')
    lines.append(f'  chosen: control {g.poles["control"]:.4f}, estimator '
                 f'{g.poles["estimator_fast"]:.4f}, {g.poles["estimator_slow"]:.4f}')
    lines.append('')
    lines.append(f'== Loop margins (loop broken at the command; {m.t_d * 1e3:g} ms delay in the '
                 'loop) ==')

    def mrow(name, mg):
        return (f'  {name:44s} GM {mg.gain_margin:5.1f} dB  PM {mg.phase_margin:5.1f} deg  '
                f'DM {mg.delay_margin * 1e3:5.1f} ms  w_c {mg.crossover:5.1f} rad/s'
                + ('' if mg.stable else '  UNSTABLE'))
    lines.append(mrow('EMC, growing flow (eq. 19)', dz.emc_flow_margins(cfg, 'up')))
    lines.append(mrow('EMC, falling flow (eq. 15 with its zero)',
                      dz.emc_flow_margins(cfg, 'down')))
    for label, kw in (('G0 +20 %', {'gain': 1.2}), ('G0 -20 %', {'gain': 0.8}),
                      ('tau +20 %', {'tau_scale': 1.2}), ('tau -20 %', {'tau_scale': 0.8}),
                      ('t_d +20 %', {'delay': 1.2 * m.t_d}),
                      ('t_d -20 %', {'delay': 0.8 * m.t_d})):
        lines.append(mrow(f'EMC, growing flow, plant {label}', dz.emc_flow_margins(cfg, 'up',
                                                                                 **kw)))
    lines.append(mrow('PI (SIMC), growing flow', dz.pi_flow_margins(cfg, 'up')))
    lines.append(mrow('PI (SIMC), falling flow', dz.pi_flow_margins(cfg, 'down')))
    if m.load_law == 'compensated':
        # The line an integrator of what the pump gives beyond the loads: its capacitance is
        # the loop gain, so a line smaller than the model's rings.
        lines.append(mrow('EMC margin loop, compensated loads', dz.emc_compensated_margins(cfg)))
        variants = {'a smaller line': 0.5 * m.C_l, 'a larger line': 2.0 * m.C_l,
                    **(lines_of or {})}
        for label, C in variants.items():
            lines.append(mrow(f'  {label}, C_l {C / m.C_l:.2g} x modelled',
                              dz.emc_compensated_margins(cfg, C)))
    else:
        ops = dz.margin_operating_points(params, (0.08, 0.5, 0.96), (2.0e6, 3.0e6))
        mm = [dz.emc_margin_margins(cfg, math.exp(-T / op[4])) for op in ops]
        lines.append(mrow('EMC margin loop, any aperture 0.08..0.96', min(
            mm, key=lambda x: x.phase_margin)))
        spread = max(x.phase_margin for x in mm) - min(x.phase_margin for x in mm)
        lines.append(f'  (margin loop: phase margin spread over the apertures {spread:.2g} '
                     'deg: one tuning)')
    lines.append('')
    lines.append('== PI baseline (control_toolbox names) ==')
    for grp, unit in (('pi.flow', 'A/(m^3/s)'), ('pi.margin', 'A/Pa')):
        pg = cfg.group(grp)
        lines.append(f'  {grp}: p = {pg.p:.5g} {unit}, i = {pg.i:.5g} {unit}/s, '
                     f'antiwindup {pg.antiwindup_strategy}, feedforward_gain '
                     f'{pg.feedforward_gain:g}')
    return '\n'.join(lines)


# The command every section's valve is opened to when the design tool looks at the line a
# working circuit presents (a fraction of the spool's stroke).
OPEN_COMMAND = 0.5


def _open_line(circuit, cfg) -> tuple[dict, list[str]]:
    """The capacitance the pump's outlet sees with every section's valve at
    :data:`OPEN_COMMAND` (the circuit file's other inputs held), against the modelled one
    (at rest): a label -> m^3/Pa for the report, and a note when it differs by more than
    2x. Nothing if that state has no steady state."""
    from hydropump_sim.errors import HydropumpError
    from hydropump_sim.reduction import line_capacitance
    from hydropump_sim.steady import equilibrium
    u = circuit.u0.copy()
    valves = [k for k, n in enumerate(circuit.inputs) if n.endswith('valve.command')]
    if not valves or cfg.model.load_law != 'compensated':
        return {}, []
    u[valves] = OPEN_COMMAND
    try:
        eq = equilibrium(circuit, u, strict=False)
        C = line_capacitance(circuit, eq, circuit.role('pump')[0].comp.ports['out'][0])
    except (HydropumpError, ArithmeticError, np.linalg.LinAlgError):
        return {}, []
    label = f'sections open at {OPEN_COMMAND:g}'
    notes = []
    ratio = C / cfg.model.C_l
    if not 0.5 <= ratio <= 2.0:
        notes.append(f'the line capacitance with every section open at {OPEN_COMMAND:g} is '
                     f'{C:.3g} m^3/Pa, {ratio:.2g} x the modelled {cfg.model.C_l:.3g} (at '
                     'rest): the margin loop is judged on both below')
    return {label: C}, notes


# A fit flagged so is no model to design on: its numbers sit on a bound, did not converge or
# do not describe a pump (the other flags are told as notes).
BLOCKING_FLAGS = ('td_on_lower_bound', 'td_on_upper_bound', 'tau_on_lower_bound',
                  'tau_on_upper_bound', 'not_converged', 'nonpositive_gain', 'poor_fit')


def fopdt_from_fit(path: str) -> tuple[float, float, float, str, list[str]]:
    """``(G0, tau, t_d, which, notes)`` of a ``hydropump fit`` result file (schema
    ``hydropump-fit/1``): the joint fit where there is one, else the pooled mean. Its flags
    are honoured: one of :data:`BLOCKING_FLAGS` on the estimate taken (on any set, for the
    pooled mean, which averages them) refuses the file with the flags in words; the others
    come back as notes."""
    from ..ident.diagnostics import FLAG_TEXT
    from ..ident.report import SCHEMA
    try:
        data = json.loads(Path(path).read_text(encoding='utf-8'))
    except FileNotFoundError:
        raise UsageError(f'--from-fit {path}: no such file') from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise UsageError(f'--from-fit {path}: not a JSON fit result ({exc})') from None
    got = data.get('schema') if isinstance(data, dict) else None
    if got != SCHEMA:
        raise UsageError(f'--from-fit {path}: not a `hydropump fit` result (schema '
                         f'{SCHEMA!r} expected, got {got!r})')
    pooled = data.get('pooled') or {}
    src, which = (pooled['joint'], 'joint fit') if pooled.get('joint') else (pooled, 'pooled mean')
    vals = [src.get(k) for k in ('G0', 'tau', 'td')]
    if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
        raise UsageError(f'--from-fit {path}: the {which} has no finite G0, tau, td ({vals})')
    flags = {str(f) for f in (src.get('flags') or [])}
    if which == 'pooled mean':
        flags |= {str(f) for fl in (pooled.get('flagged_sets') or {}).values() for f in fl}
    blocking = sorted(f for f in flags if f in BLOCKING_FLAGS)
    if blocking:
        raise UsageError(
            f'--from-fit {path}: the {which} is flagged ' + '; '.join(
                f'{f} ({FLAG_TEXT[f]})' for f in blocking)
            + ': its numbers are no model to design on; fit again (see the fit report), or '
            'give --G0, --tau and --t-d')
    notes = [f'the {which} of {Path(path).name} is flagged {f}: {FLAG_TEXT.get(f, f)}'
             for f in sorted(flags - set(blocking)) if f in FLAG_TEXT]
    return float(vals[0]), float(vals[1]), float(vals[2]), which, notes


def default_profile() -> Path:
    """The sensor profile shipped beside the reference plant file: config/bench.yaml."""
    from hydropump_sim.params import default_params_path
    return default_params_path().with_name(BENCH_YAML)


def design_profile(args, params):
    """``(profile, path)`` of ``--profile`` (default: the shipped config/bench.yaml)."""
    from hydropump_sim.schema import ParamError
    from hydropump_sim.sensors import load_profile
    path = Path(args.profile) if args.profile else default_profile()
    what = f'--profile {path}' if args.profile else f'the default sensor profile {path}'
    if not path.exists():
        raise UsageError(f'{what}: no such file')
    if path.is_dir():
        raise UsageError(f'{what}: is a folder, expected a sensor profile (.yaml)')
    profile = load_profile(path)
    # What is not a sensor is a plant parameter the profile sets (the dither): a file of
    # another kind (a controller's, say) shows here, rather than as a silent t_d = 0.
    try:
        params.replace(profile.plant_overrides or {})
    except ParamError as exc:
        more = f' and {len(exc.lines) - 1} more' if len(exc.lines) > 1 else ''
        raise UsageError(f'{what}: not a sensor profile ({exc.lines[0]}{more})') from None
    return profile, path


def identified_numbers(args) -> tuple[dict, list[str]]:
    """eq. 19 numbers that replace the plant's: from ``--from-fit``, else ``--G0``, ``--tau``,
    ``--t-d``; each ``name -> (value, source)``, and the notes on them (a fit's flags)."""
    notes: list[str] = []
    opts = {'G0': '--G0', 'tau': '--tau', 't_d': '--t-d'}
    units = {'G0': '% per current range', 'tau': 's', 't_d': 's'}
    if args.from_fit:
        G0, tau, t_d, which, notes = fopdt_from_fit(args.from_fit)
        vals = {'G0': G0, 'tau': tau, 't_d': t_d}
        src = {k: f'eq. 19, {which} of {Path(args.from_fit).name}' for k in vals}
        for k, v in vals.items():
            # The file's numbers, not the user's: no hint about units they never typed.
            if not (v > 0 or (k == 't_d' and v == 0)):
                raise UsageError(f'--from-fit {args.from_fit}: the {which} gives {k} = {v:g} '
                                 f'{units[k]}; a pump has a positive one')
    else:
        vals = {k: getattr(args, k) for k in opts if getattr(args, k) is not None}
        src = {k: f'eq. 19, {opts[k]} on the command line' for k in vals}
        for k, v in vals.items():
            positive(v, opts[k], units[k], zero=k == 't_d')
    return {k: (v, src[k]) for k, v in vals.items()}, notes


def cmd_design(args) -> int:
    from ..control.design import design_config, plant_model
    from ..control.schema import General
    t0 = time.perf_counter()
    identified, fit_notes = identified_numbers(args)
    base = overrides(args.set)
    plant = plant_file(args)
    default = (CONTROLLER_YAML if not args.circuit
               else f'controller_{Path(args.circuit).stem}.yaml')
    out = output_file(args.out or plant.with_name(default), PARAMS_SUFFIXES,
                      'params file', create=not args.dry_run, kind='controller params')
    if not args.dry_run:  # nothing is written then
        protect_output(out, [plant, *([args.profile] if args.profile else []),
                             *([args.circuit] if args.circuit else []),
                             *([args.from_fit] if args.from_fit else [])], 'params file')
    params = load_params(plant)
    profile, prof_path = design_profile(args, params)
    signal = base.get('controller.flow_signal', General().flow_signal)
    pm = plant_model(params, profile, identified=identified, flow_signal=signal,
                     plant_name=plant.name, profile_name=prof_path.name)
    cfg = design_config(params, base=base, model=pm)
    sources = dict(pm.sources)
    lines_of, line_notes = {}, []
    if args.circuit:
        # The circuit's line: the capacitance the pump's outlet sees, and compensated loads.
        from hydropump_sim.circuit import load_circuit

        from ..experiments.circuit_loop import controller_config
        circuit = load_circuit(args.circuit, plant=params)
        cfg = controller_config(circuit, config=cfg)
        sources['C_l'] = (f'{Path(args.circuit).name}: the capacitance at the pump outlet, '
                          'every node weighted by how it follows')
        sources['load_law'] = f'{Path(args.circuit).name}: compensated load sections'
        lines_of, line_notes = _open_line(circuit, cfg)
    for key in base:
        if key.startswith('model.'):
            sources[key[len('model.'):]] = f'--set {key}'
    print(f'plant: {plant}; sensor profile: {prof_path}'
          + (f'; eq. 19 from {args.from_fit}' if args.from_fit else ''))
    for note in [*fit_notes, *pm.notes, *line_notes]:
        print(f'note: {note}')
    print(flush=True)
    print(design_report(cfg, params, sources, lines_of))
    if args.dry_run:
        print(f'\n(dry run: {out} not written)')
        return 0
    m = cfg.model
    header = '\n'.join([
        '# Controller parameters (ROS 2 params file, SI units), written by `hydropump design`',
        f"# from {plant.name} (the plant's own model) and {prof_path.name} (the flow delay):",
        f'#   G0 {pm.G0:.2f} %: {sources["gain"].partition(": ")[2] or sources["gain"]}',
        f'#   tau {m.tau:.5g} s: {sources["tau"]}',
        f'#   tau_down {m.tau_down:.5g} s: {sources["tau_down"]}',
        f'#   t_d {m.t_d:.5g} s: {sources["t_d"]}',
        '# Load with hydropump_ctrl.control.schema.load_config(path); docs/control.md explains '
        'every group.',
        '# model.* is the embedded model; emc.* are closed-loop eigenvalues (time constants), '
        'the',
        '# EMC gains follow from them; pi.* is the baseline with control_toolbox names.'])
    write_text(out, cfg.to_ros_yaml(header), 'params file')
    print(f'\nwrote {out} ({time.perf_counter() - t0:.1f} s)')
    return 0


# --- closed-loop ------------------------------------------------------------------------------

def _load_setup(args):
    from hydropump_sim.sensors import load_profile

    from ..control.design import design_config
    from ..control.schema import load_config
    plant = plant_file(args)
    params = load_params(plant)
    profile = load_profile(Path(args.profile) if args.profile
                           else plant.with_name(BENCH_YAML))
    cfg_path = Path(args.config) if args.config else plant.with_name(CONTROLLER_YAML)
    if cfg_path.is_file():
        cfg = load_config(cfg_path, current_limits=params.I_limits)
        source = str(cfg_path)
    elif args.config:
        raise UsageError(f'--config {cfg_path}: controller parameters not found')
    else:
        cfg = design_config(params, profile)
        source = 'designed from the plant and the sensor profile (no controller.yaml found)'
    sets = overrides(args.set)
    if sets:
        cfg = cfg.replace(sets)
    return params, profile, cfg, source


def _plot_pair(path: Path, title: str, runs: dict, signal: str, scale: float, unit: str,
               reference, band=None) -> None:
    """EMC and PI side by side: controlled variable, what the controller saw, command."""
    plt = pyplot()
    fig, axes = plt.subplots(2, len(runs), figsize=(6.5 * len(runs), 6.5), sharex=True,
                             squeeze=False)
    for col, (name, res) in enumerate(runs.items()):
        ax, axu = axes[0, col], axes[1, col]
        y = res.smooth(signal) / scale
        if signal == 'q_l':
            seen = res.meas['line_flow'] / scale
        else:
            seen = (res.meas['line_pressure'] - res.meas['load_pressure']) / scale
        ax.plot(res.t_ctrl, seen, color='0.75', lw=0.8, label='measured (bench sensor)')
        ax.plot(res.t, y, color='C0', lw=1.6, label=f'{signal} (true, dither averaged)')
        ref = reference(res)
        if ref is not None:
            ax.plot(res.t_ctrl, ref / scale, 'k--', lw=1.0, label='reference')
            if band is not None:
                ax.fill_between(res.t_ctrl, (ref - band) / scale, (ref + band) / scale,
                                color='C2', alpha=0.12, lw=0, label='target band')
        ax.set_title(f'{name}: {title}')
        ax.set_ylabel(unit)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc='best')
        axu.plot(res.t, res.command, color='C3', lw=1.0)
        axu.set_ylabel('command I_s [A]')
        axu.set_xlabel('time [s]')
        axu.grid(True, alpha=0.3)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=100)
    finally:
        plt.close(fig)


def cmd_closed_loop(args) -> int:
    from ..control.emc import EMCController
    from ..control.pi import PIController
    from ..experiments import cases as cs
    t0 = time.perf_counter()
    params, profile, cfg, source = _load_setup(args)
    out = run_dir(args.out, 'closed-loop')
    print(f'controller: {source}; sensors: {args.profile or BENCH_YAML}', flush=True)
    make = {'EMC': lambda: EMCController(cfg), 'PI': lambda: PIController(cfg)}
    FS = params.Q_max
    steps = {}
    for a, b in cs.FLOW_STEPS:
        runs = {n: cs.flow_step_case(f(), params, profile, a * FS, b * FS).result
                for n, f in make.items()}
        name = f'flow_step_{a * 100:.0f}_{b * 100:.0f}.png'
        _plot_pair(out / name, f'flow step {a:.0%} -> {b:.0%}', runs, 'q_l', FS / 100.0,
                   'flow [% of V_p f_p]',
                   lambda r, a=a, b=b: np.where(r.t_ctrl >= 0.1, b * FS, a * FS),
                   band=0.02 * abs(b - a) * FS)
        steps[name] = runs
    for dp, xi, k in ((2.5e6, 0.1, 1.2), (2.5e6, 0.8, 0.8), (3.0e6, 0.5, 1.2)):
        runs = {n: cs.aperture_case(f(), params, profile, dp, xi, k).result
                for n, f in make.items()}
        _plot_pair(out / f'aperture_{xi:g}x{k:g}_{dp / 1e5:.0f}bar.png',
                   f'aperture {xi:g} -> {xi * k:.2f} at {dp / 1e5:g} bar', runs, 'margin', 1e5,
                   'margin P_l - P_u [bar]', lambda r, dp=dp: np.full(r.t_ctrl.size, dp),
                   band=1.0e5)
    for xi in (0.1, 0.8):
        runs = {n: cs.setpoint_case(f(), params, profile, xi=xi).result
                for n, f in make.items()}
        _plot_pair(out / f'setpoint_20_25bar_xi{xi:g}.png',
                   f'margin set-point 20 -> 25 bar, xi {xi:g}', runs, 'margin', 1e5,
                   'margin P_l - P_u [bar]',
                   lambda r: np.where(r.t_ctrl >= 0.1, 2.5e6, 2.0e6), band=0.5e5)
    runs = {n: cs.unreachable_case(f(), params, profile, 0.6 * FS, 1.1 * FS).result
            for n, f in make.items()}
    _plot_pair(out / 'unreachable.png', 'demand 110 % for 1 s, then 60 %', runs, 'q_l',
               FS / 100.0, 'flow [% of V_p f_p]',
               lambda r: np.where((r.t_ctrl >= 0.1) & (r.t_ctrl < 1.1), 1.1 * FS, 0.6 * FS),
               band=0.01 * FS)
    runs = {n: cs.shaft_speed_case(f(), params, profile, 0.5 * FS, 0.9).result
            for n, f in make.items()}
    _plot_pair(out / 'shaft_speed.png', 'shaft speed -10 % at 50 % flow', runs, 'q_l',
               FS / 100.0, 'flow [% of V_p f_p]', lambda r: np.full(r.t_ctrl.size, 0.5 * FS),
               band=0.01 * FS)
    print(f'plots written in {out} ({time.perf_counter() - t0:.1f} s); evaluating the '
          'targets...', flush=True)
    if args.no_table:
        return 0
    rows = cs.evaluate(make, params, profile, cfg)
    table = cs.format_table(rows)
    print(table)
    write_text(out / 'targets.txt', f'controller: {source}\n\n{table}\n', 'targets table')
    n_miss = sum(r.ok is False for r in rows)
    print(f'\n{sum(r.ok is True for r in rows)} targets met, {n_miss} missed; wrote '
          f'{out}/targets.txt ({time.perf_counter() - t0:.1f} s)')
    return 0


def register(sub) -> None:
    """Add ``design`` and ``closed-loop`` to the ``hydropump`` command line."""
    d = sub.add_parser('design', help="EMC and PI design from the plant's own model and the "
                       "sensor profile's flow delay: gains, eigenvalues, margins; writes "
                       'config/controller.yaml')
    add_params_option(d, 'whose model the design takes')
    d.add_argument('--profile', help='sensor profile whose flow-sensor delay is t_d (default: '
                   'config/bench.yaml as shipped)')
    # The ranges of the controller's embedded model (model.tau, model.t_d); 0 delay is no
    # delay.
    d.add_argument('--G0', type=positive_float('% per current range', 1000.0),
                   help="eq. 19 DC gain [%% per current range] in place of the plant's")
    d.add_argument('--tau', type=float_in(1.0e-3, 10.0, 's'), help='eq. 19 time constant [s] '
                   "in place of the plant's 63 %% time")
    d.add_argument('--t-d', dest='t_d', type=float_in(0.0, 2.0, 's'),
                   help="eq. 19 delay [s] in place of the profile's flow delay (0: none)")
    d.add_argument('--from-fit', metavar='RESULT.json',
                   help='take G0, tau, t_d from a `hydropump fit` result (the joint fit where '
                        'there is one, else the pooled mean); overrides --G0 --tau --t-d')
    d.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='override a controller parameter, e.g. emc.tau_control=0.02')
    d.add_argument('--circuit', help='design for the pump in this circuit (its line '
                   'capacitance, its compensated loads): config/circuits/fig1.yaml')
    d.add_argument('--out', help='params file to write (default: controller.yaml beside the '
                   'plant file; controller_<circuit>.yaml with --circuit); never an input')
    d.add_argument('--dry-run', action='store_true', help='print only, write nothing')
    d.set_defaults(func=cmd_design)
    c = sub.add_parser('closed-loop', help='EMC and PI against the fine model with the bench '
                       'sensors: side-by-side plots and the target table')
    add_params_option(c)
    c.add_argument('--profile', help='sensor profile (default: bench.yaml beside the plant '
                   'file)')
    c.add_argument('--config', help='controller params (default: controller.yaml beside the '
                   'plant file, else designed on the fly)')
    c.add_argument('--set', action='append', metavar='NAME=VALUE',
                   help='override a controller parameter')
    c.add_argument('--out', help='output folder (default: out/closed-loop-<time>)')
    c.add_argument('--no-table', action='store_true', help='plots only, skip the target table')
    c.set_defaults(func=cmd_closed_loop)
