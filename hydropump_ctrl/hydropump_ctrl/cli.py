"""The ``hydropump`` command line.

User mistakes (bad parameters, bad scenario, missing files) end with a one-line ``error:``
per problem and exit code 2, never a traceback.
"""

from __future__ import annotations

import argparse
from datetime import datetime
from pathlib import Path
import sys
import time

from hydropump_sim.params import default_params_path, load_params, ParamError
from hydropump_sim.scenario import load_scenario, ScenarioError
from hydropump_sim.simulate import IntegrationError
from hydropump_sim.trim import TrimError

USER_ERRORS = (ParamError, ScenarioError, TrimError, IntegrationError, FileNotFoundError,
               ValueError)


class UsageError(Exception):
    """A user mistake detected by a command: printed as one line."""


def run_dir(base: str | None, prefix: str) -> Path:
    """Output folder: the one given, or ``out/<prefix>-<timestamp>``."""
    path = Path(base) if base else Path('out') / f'{prefix}-{datetime.now():%Y%m%d-%H%M%S}'
    path.mkdir(parents=True, exist_ok=True)
    return path


def cmd_analyze(args) -> int:
    from hydropump_sim import analysis
    t0 = time.perf_counter()
    params = load_params(args.params or default_params_path())
    print(f'parameters: {args.params or default_params_path()}', flush=True)
    report, steps = analysis.format_report(params, T=args.T)
    print(report)
    out = run_dir(args.out, 'analyze')
    (out / 'analysis.txt').write_text(report + '\n')
    analysis.plot_steps(steps, params, out / 'steps.png')
    analysis.plot_bode(params, out / 'bode.png', T=args.T)
    print(f'\nwrote {out}/analysis.txt, steps.png, bode.png '
          f'({time.perf_counter() - t0:.1f} s)')
    return 0


def cmd_simulate(args) -> int:
    from hydropump_sim.simulate import simulate
    sc = load_scenario(args.scenario)
    t0 = time.perf_counter()
    res = simulate(sc.params, sc.duration, model=sc.model, dt_out=sc.dt_out, **sc.inputs)
    el = time.perf_counter() - t0
    if res.n_clamped:
        print(f'warning: {res.n_clamped} current samples outside eq. 2 were clamped to '
              f'[{sc.params.I_limits[0]:.3g}, {sc.params.I_limits[1]:.3g}] A')
    target = args.out or sc.output
    if target:
        path = Path(target)
        path.parent.mkdir(parents=True, exist_ok=True)
    else:
        path = run_dir(None, 'simulate') / 'result.csv'
    if path.suffix == '.npz':
        res.to_npz(path)
    elif path.suffix == '.csv':
        res.to_csv(path)
    else:
        raise UsageError(f'output {path}: use a .csv or .npz file name')
    plot = Path(args.plot) if args.plot else path.with_suffix('.png')
    plot_result(res, sc.params, plot)
    print(f'simulated {sc.duration:g} s of the {sc.model} model in {el:.2f} s '
          f'({sc.duration / el:.0f}x real time)')
    print(f'wrote {path} and {plot}')
    return 0


def plot_result(res, params, path) -> None:
    """Current, flows and pressures of a simulation, SI converted to bar and L/min."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
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
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _register_plant_commands(sub) -> None:
    a = sub.add_parser('analyze', help='equilibrium, modes, eqs. 14-16, step and Bode plots')
    a.add_argument('--params', help='plant params file (default: config/pump.yaml)')
    a.add_argument('--out', help='output folder (default: out/analyze-<time>)')
    a.add_argument('--T', type=float, default=0.05,
                   help='control averaging period of section IV [s] (default 0.05)')
    a.set_defaults(func=cmd_analyze)
    s = sub.add_parser('simulate', help='run a scenario file, write CSV or NPZ and a plot')
    s.add_argument('scenario', help='scenario YAML file')
    s.add_argument('--out', help='result file, .csv or .npz')
    s.add_argument('--plot', help='plot file (default: beside the result)')
    s.set_defaults(func=cmd_simulate)


# Each entry adds its sub-commands to the parser; a command's ``func(args)`` returns the exit
# code. Other modules register here with a ``register(subparsers)`` function.
COMMANDS = [_register_plant_commands, __import__('hydropump_ctrl.fit_cli').fit_cli.register,
            __import__('hydropump_ctrl.control_cli').control_cli.register]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='hydropump', description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest='command', required=True)
    for register in COMMANDS:
        register(sub)
    return ap


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ParamError, ScenarioError) as exc:
        for line in exc.lines:
            print(f'error: {line}', file=sys.stderr)
        return 2
    except (UsageError, *USER_ERRORS) as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print('interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
