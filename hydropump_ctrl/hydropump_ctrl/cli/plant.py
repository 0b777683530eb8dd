"""``hydropump analyze`` and ``hydropump simulate``: the plant library from the command line.

``analyze`` prints the equilibrium, the modes and the checks of eqs. 14-16 and plots the step
responses and the Bode diagram; ``simulate`` runs a scenario file and writes the result
(CSV or NPZ) with a plot.
"""

from __future__ import annotations

from pathlib import Path
import time

from hydropump_sim.files import pyplot, save_figure, write_text

from .options import add_params_option, float_in, output_file, plant_file, run_dir

RESULT_SUFFIXES = ('.csv', '.npz')
RESULT_KINDS = {'.csv': 'results CSV'}
PLOT_SUFFIXES = ('.png', '.pdf', '.svg', '.jpg', '.jpeg')


def register(sub) -> None:
    """Add ``analyze`` and ``simulate`` to the ``hydropump`` command line."""
    a = sub.add_parser('analyze', help='equilibrium, modes, eqs. 14-16, step and Bode plots')
    add_params_option(a)
    a.add_argument('--out', help='output folder (default: out/analyze-<time>)')
    # The range of the simulator's control_period.
    a.add_argument('--T', type=float_in(1.0e-4, 1.0, 's'), default=0.05,
                   help='control averaging period of section IV [s] (default 0.05)')
    a.set_defaults(func=cmd_analyze)
    s = sub.add_parser('simulate', help='run a scenario file, write CSV or NPZ and a plot')
    s.add_argument('scenario', help='scenario YAML file')
    s.add_argument('--out', help='result file, .csv or .npz')
    s.add_argument('--plot', help='plot file (default: beside the result)')
    s.set_defaults(func=cmd_simulate)


def cmd_analyze(args) -> int:
    from hydropump_sim import analysis
    from hydropump_sim.params import load_params
    T = args.T
    t0 = time.perf_counter()
    plant = plant_file(args)
    params = load_params(plant)
    out = run_dir(args.out, 'analyze')
    print(f'parameters: {plant}', flush=True)
    report, steps = analysis.format_report(params, T=T)
    print(report)
    write_text(out / 'analysis.txt', report + '\n', 'analysis')
    analysis.plot_steps(steps, params, out / 'steps.png')
    analysis.plot_bode(params, out / 'bode.png', T=T)
    print(f'\nwrote {out}/analysis.txt, steps.png, bode.png '
          f'({time.perf_counter() - t0:.1f} s)')
    return 0


def cmd_simulate(args) -> int:
    from hydropump_sim.scenario import load_scenario
    from hydropump_sim.simulate import simulate
    sc = load_scenario(args.scenario)
    # The output names are checked before the run, which may be long; the default folder is
    # made after it, so that a failed run leaves none behind.
    target = args.out or sc.output
    path = output_file(target, RESULT_SUFFIXES, 'output',
                       kind=RESULT_KINDS.get(Path(target).suffix)) if target else None
    plot = output_file(args.plot, PLOT_SUFFIXES, 'plot') if args.plot else None
    t0 = time.perf_counter()
    res = simulate(sc.params, sc.duration, model=sc.model, dt_out=sc.dt_out, **sc.inputs)
    el = time.perf_counter() - t0
    if res.n_clamped:
        print(f'warning: {res.n_clamped} current samples outside eq. 2 were clamped to '
              f'[{sc.params.I_limits[0]:.3g}, {sc.params.I_limits[1]:.3g}] A')
    if path is None:
        path = run_dir(None, 'simulate') / 'result.csv'
    plot = plot or path.with_suffix('.png')
    if path.suffix == '.npz':
        res.to_npz(path)
    else:
        res.to_csv(path)
    plot_result(res, sc.params, plot)
    print(f'simulated {sc.duration:g} s of the {sc.model} model in {el:.2f} s '
          f'({sc.duration / el:.0f}x real time)')
    print(f'wrote {path} and {plot}')
    return 0


def plot_result(res, params, path: Path) -> None:
    """Current, flows and pressures of a simulation, SI converted to bar and L/min."""
    plt = pyplot()
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    ax[0].plot(res.t, res.I_s, 'k')
    ax[0].set_ylabel('I_s [A]')
    for name in ('Q_p', 'q_l', 'Q_load'):
        ax[1].plot(res.t, getattr(res, name) * 60000.0, label=name)
    ax[1].set_ylabel('flow [L/min]')
    ax[1].legend(fontsize=8)
    for name in ('P_a', 'P_l'):
        ax[2].plot(res.t, getattr(res, name) / 1e5, label=name)
    ax[2].plot(res.t, res.P_u / 1e5, label='P_u', ls='--')
    ax[2].set_ylabel('pressure [bar]')
    ax[2].set_xlabel('time [s]')
    ax[2].legend(fontsize=8)
    for a in ax:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    try:
        save_figure(fig, path, dpi=100)
    finally:
        plt.close(fig)
