"""The model analysis behind ``hydropump analyze``: design checks, equilibrium, modes, the
paper's linear models, step comparisons fine vs simplified vs linear, and their plots."""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import control
import numpy as np

from . import linear, paper
from .files import pyplot, save_figure
from .metrics import fast_fraction, step_figures
from .params import Params
from .scaling import current_for_displacement, flow_percent
from .simulate import simulate
from .trim import equilibrium

STEP_MODELS = ('fine', 'simplified', 'simplified_Kc')


@dataclass(frozen=True)
class DesignCheck:
    name: str
    value: float
    unit: str
    bound: str
    ok: bool
    note: str = ''


def design_checks(params: Params) -> list[DesignCheck]:
    """Section IV bounds, corrected where the paper's literal form cannot hold (I6, I7)."""
    sp, ac, pl = params.spool, params.actuator, params.plate
    eq = equilibrium(params)
    V_a = ac.V_a0
    tau_c = math.sqrt(sp.m_c / sp.K_c)
    tau_c_corr = math.sqrt(sp.m_c / (sp.K_a + sp.K_c))
    tau_b = math.sqrt(pl.m_a / pl.K_b)
    k_hyd = params.fluid.beta * ac.S_a ** 2 / V_a
    tau_h = math.sqrt(pl.m_a / (k_hyd + sp.K_a + pl.K_b))
    eps = (sp.K_a + pl.K_b) / k_hyd
    lo = equilibrium(params, params.current_range[0], load_pressure=params.line.P_u)
    hi = equilibrium(params, params.current_range[1], load_pressure=params.line.P_u)
    return [
        DesignCheck('D1 phi_s I_max / (K_a x_a_max)', sp.phi_s * sp.I_max /
                    (sp.K_a * params.pump.x_a_max), '-', '= 1', True),
        DesignCheck('tau_c = sqrt(m_c/K_c) (literal)', tau_c, 's', '<= 5 ms', tau_c <= 5e-3),
        DesignCheck('tau_c = sqrt(m_c/(K_a+K_c)) (I6)', tau_c_corr, 's', '<= 5 ms',
                    tau_c_corr <= 5e-3),
        DesignCheck('tau_b = sqrt(m_a/K_b)', tau_b, 's', '<= 5 ms', tau_b <= 5e-3),
        DesignCheck('tau_h hydro-mechanical (I7)', tau_h, 's', '~ 0.1 ms', tau_h <= 2e-4,
                    'replaces the literal tau_a, infinite at x_c = 0'),
        DesignCheck('epsilon = (K_a+K_b) V_a/(beta S_a^2) (I7)', eps, '-', '<< 1', eps < 0.01),
        DesignCheck('tau_z = S_a/b_p (D4)', paper.zero_time_constant(params), 's', '~ 10 ms',
                    abs(paper.zero_time_constant(params) - 0.01) < 0.005),
        DesignCheck('K_c/K_a', sp.K_c / sp.K_a, '-', '<< 1', sp.K_c / sp.K_a <= 0.1),
        DesignCheck('min P_a over the stroke (D5)', min(lo.P_a, hi.P_a), 'Pa', '> 0',
                    min(lo.P_a, hi.P_a) > 0),
        DesignCheck('eq. 11 at 50 %: Q_p / (V_p f_p (1/2 + i_s/I_max))',
                    eq.Q_p / (params.Q_max * 0.5), '-', '= 1',
                    abs(eq.Q_p / (params.Q_max * 0.5) - 1) < 1e-9),
    ]


@dataclass
class StepComparison:
    """One current step simulated on every model, with the linear model of the branch."""

    d0: float
    d1: float
    t: np.ndarray
    t_step: float
    q_l: dict = field(default_factory=dict)     # model -> flow [m^3/s]
    t63: dict = field(default_factory=dict)     # model -> s
    fast: dict = field(default_factory=dict)    # model -> instantaneous fraction of the step
    max_err: dict = field(default_factory=dict)  # model -> max |q - q_fine| / |step|
    max_err_late: dict = field(default_factory=dict)  # same, from 10 ms after the step
    step: float = 0.0


def step_comparison(params: Params, d0: float = 0.4, d1: float = 0.6,
                    duration: float = 1.2, t_step: float = 0.01,
                    dt: float = 1.0e-4) -> StepComparison:
    """Current step between displacements ``d0`` and ``d1`` on the fine and simplified models
    and on eq. 14/15 linearised at the initial operating point."""
    I0, I1 = current_for_displacement(params, [d0, d1])

    def cur(t):
        return np.where(np.asarray(t) < t_step, I0, I1)

    out = StepComparison(d0, d1, t=np.array([]), t_step=t_step)
    for name in STEP_MODELS:
        r = simulate(params, duration, cur, model=name, dt_out=dt)
        out.t = r.t
        out.q_l[name] = r.q_l
    branch = 'pos' if d1 > d0 else 'neg'
    eq0 = equilibrium(params, I0)
    ss = paper.paper_linear(params, eq0, branch).ss(inputs=['i_s'], outputs=['q_l'])
    resp = control.forced_response(ss, out.t, np.where(out.t < t_step, 0.0, I1 - I0))
    out.q_l[f'eq{14 if branch == "pos" else 15}'] = eq0.q_l + np.asarray(resp.outputs)
    fine = out.q_l['fine']
    final = equilibrium(params, I1).q_l
    out.step = final - eq0.q_l
    late = out.t >= t_step + 0.01
    for name, q in out.q_l.items():
        out.t63[name] = step_figures(out.t, q, t_step, final=final).t63
        out.max_err[name] = float(np.max(np.abs(q - fine)) / abs(out.step))
        out.max_err_late[name] = float(np.max(np.abs(q - fine)[late]) / abs(out.step))
        if branch == 'neg':
            out.fast[name] = fast_fraction(out.t, q, t_step, (0.015, 0.08))[0]
    return out


def bode_set(params: Params, omega: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Current-to-``q_l`` frequency responses in % of ``V_p f_p`` per unit of current range:
    fine (both branches), simplified (both variants) and eqs. 14/15."""
    norm = 100.0 * (params.current_range[1] - params.current_range[0]) / params.Q_max
    out = {}
    for name in ('fine', 'simplified', 'simplified_Kc'):
        for br in ('pos', 'neg'):
            ss = linear.linearize(params, equilibrium(params, model=name), br, name).ss(
                inputs=['i_s'], outputs=['q_l'])
            mag, ph = linear.bode_data(ss, omega)
            out[f'{name} ({br})'] = (mag * norm, ph)
    for br, label in (('pos', 'eq. 14'), ('neg', 'eq. 15')):
        mag, ph = linear.bode_data(paper.paper_linear(params, branch=br).ss(
            inputs=['i_s'], outputs=['q_l']), omega)
        out[label] = (mag * norm, ph)
    return out


def format_report(params: Params, T: float = 0.05) -> tuple[str, dict]:
    """Text report and the step comparisons (for plotting) of ``hydropump analyze``."""
    lines = []
    add = lines.append
    eq = equilibrium(params)
    add('== Equilibrium at the nominal operating point (50 %, eq. 11) ==')
    add(f'  I_s = {eq.I_s:.4f} A   P_u = {eq.u[1] / 1e5:.2f} bar   xi_u = {eq.u[2]:.3f}   '
        f'f_p = {eq.u[3]:.2f} Hz')
    add(f'  x_c = {eq.x_c * 1e3:.4f} mm   x_a = {eq.x_a * 1e3:.4f} mm   '
        f'P_a = {eq.P_a / 1e5:.3f} bar   P_l = {eq.P_l / 1e5:.3f} bar')
    add(f'  Q_p = {eq.Q_p:.6e} m^3/s ({flow_percent(params, eq.Q_p):.2f} % of V_p f_p)   '
        f'q_l = {eq.q_l:.6e} m^3/s   Q_load = {eq.Q_load:.6e} m^3/s')
    add('')
    add('== Design checks (section IV; docs/reference.md I6, I7) ==')
    for d in design_checks(params):
        val = f'{d.value * 1e3:.4g} ms' if d.unit == 's' else (
            f'{d.value / 1e5:.4g} bar' if d.unit == 'Pa' else f'{d.value:.4g}')
        add(f'  {"ok  " if d.ok else "FAIL"} {d.name:48s} {val:>12s}  (want {d.bound})'
            + (f'  {d.note}' if d.note else ''))
    add('')
    for br, side in (('pos', 'growing flow, x_c > 0'), ('neg', 'falling flow, x_c < 0')):
        add(f'== Fine-model modes, branch {br} ({side}); T = {T * 1e3:.0f} ms ==')
        add(f'  {"eigenvalue [1/s]":>26s} {"tau [ms]":>9s} {"f_n [Hz]":>9s} {"zeta":>6s} '
            f'{"eps=tau/T":>10s}  {"in model":10s} dominant states')
        for pm in paper.singular_perturbation_check(params, T, br):
            m = pm.mode
            ev = (f'{m.eigenvalue.real:.2f} +- {m.eigenvalue.imag:.1f}j' if m.oscillatory
                  else f'{m.eigenvalue.real:.3f}')
            add(f'  {ev:>26s} {m.tau * 1e3:9.3f} {m.f_n:9.1f} {m.zeta:6.3f} {pm.epsilon:10.4f}'
                f'  {"fast" if pm.neglected else "slow":10s} '
                + ', '.join(f'{s} ({w:.2f})' for s, w in zip(m.dominant, m.participation)))
        add('')
    add('== Paper linear models (eqs. 14-18) at the nominal point ==')
    for br, num in (('pos', 14), ('neg', 15)):
        pl = paper.paper_linear(params, branch=br)
        add(f'  eq. {num}: A = {np.array2string(pl.A, precision=5)}'.replace('\n', ' '))
        add(f'          B = {np.array2string(pl.B, precision=5)}'.replace('\n', ' '))
        add(f'          C = {np.array2string(pl.C, precision=5)}   D = '
            f'{np.array2string(pl.D, precision=5)}'.replace('\n', ' '))
        tau = paper.eq14_time_constant(params, branch=br)
        add(f'          time constant S_a/(mu_a r) = {tau * 1e3:.3f} ms '
            f'({paper.eq14_time_constant(params, branch=br, keep_Kc=True) * 1e3:.3f} ms keeping '
            f'K_c); poles {np.array2string(np.sort(np.linalg.eigvals(pl.A).real), precision=3)}'
            ' 1/s')
    add(f'  zero of eq. 17 (falling flow): tau_z = S_a/b_p = '
        f'{paper.zero_time_constant(params) * 1e3:.3f} ms')
    G = paper.transfer_matrix(params, branch='pos')
    dc = float(np.real(G(0)[1, 0]))
    add(f'  eq. 16 G21(0) = {dc:.6e} m^3/(s A) = V_p f_p / I_max x '
        f'{dc * params.spool.I_max / params.Q_max:.6f}  (G0 = '
        f'{dc * (params.current_range[1] - params.current_range[0]) / params.Q_max * 100:.3f})')
    add('')
    steps = {'up': step_comparison(params, 0.4, 0.6), 'down': step_comparison(params, 0.6, 0.4)}
    add('== Current steps 40 -> 60 % (up) and 60 -> 40 % (down): q_l ==')
    add(f'  {"model":16s} {"63% up [ms]":>12s} {"max err up":>11s} {"(>10 ms)":>9s} '
        f'{"63% down [ms]":>14s} {"fast drop":>10s} {"max err down":>13s} {"(>10 ms)":>9s}')
    names = list(steps['up'].q_l)
    for i, name in enumerate(names):
        dname = list(steps['down'].q_l)[i]
        up, dn = steps['up'], steps['down']
        label = name if name == dname else f'{name}/{dname}'
        add(f'  {label:16s} {up.t63[name] * 1e3:12.2f} {up.max_err[name] * 100:10.2f}% '
            f'{up.max_err_late[name] * 100:8.2f}% {dn.t63[dname] * 1e3:14.2f} '
            f'{dn.fast[dname] * 100:9.1f}% {dn.max_err[dname] * 100:12.2f}% '
            f'{dn.max_err_late[dname] * 100:8.2f}%')
    add('  (max err: largest |q_l - q_l,fine| in % of the step; linear models are linearised'
        ' at the initial point of each step)')
    return '\n'.join(lines), steps


def plot_steps(steps: dict, params: Params, path) -> None:
    """Step responses up and down, fine vs simplified vs linear, in % of ``V_p f_p``."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=False)
    styles = {'fine': ('k', '-'), 'simplified': ('tab:blue', '--'),
              'simplified_Kc': ('tab:green', '-.'), 'eq14': ('tab:red', ':'),
              'eq15': ('tab:red', ':')}
    for ax, (key, sc) in zip(axes, steps.items()):
        for name, q in sc.q_l.items():
            col, ls = styles[name]
            ax.plot((sc.t - sc.t_step) * 1e3, flow_percent(params, q), color=col, ls=ls,
                    label=f'{name} (63 %: {sc.t63[name] * 1e3:.1f} ms)')
        ax.set_xlim(-5, 400 if key == 'up' else 200)
        ax.set_xlabel('time after the current step [ms]')
        ax.set_ylabel('q_l [% of V_p f_p]')
        ax.set_title(f'{key}: {sc.d0 * 100:.0f} -> {sc.d1 * 100:.0f} % displacement')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=110, axes=True)  # a figure of the demo's report
    plt.close(fig)


def plot_bode(params: Params, path, omega: np.ndarray | None = None, T: float = 0.05) -> None:
    """Bode plot of current to ``q_l``: fine vs simplified vs eqs. 14/15; a line marks the
    control bandwidth ``1/T`` of section IV."""
    plt = pyplot()
    omega = np.logspace(-0.5, 4.5, 400) if omega is None else omega
    data = bode_set(params, omega)
    f = omega / (2 * np.pi)
    fig, (am, ap) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    for name, (mag, ph) in data.items():
        ls = '-' if name.startswith('fine') else ('--' if 'simplified' in name else ':')
        col = 'tab:blue' if 'pos' in name or name == 'eq. 14' else 'tab:orange'
        if 'Kc' in name:
            col = 'tab:green' if 'pos' in name else 'tab:olive'
        am.semilogx(f, 20 * np.log10(mag), ls=ls, color=col, label=name)
        ap.semilogx(f, ph, ls=ls, color=col)
    am.set_ylabel('|q_l / I_s| [dB, % per current range]')
    ap.set_ylabel('phase [deg]')
    ap.set_xlabel('frequency [Hz]')
    f_T = 1.0 / (2 * np.pi * T)
    for ax in (am, ap):
        ax.axvline(f_T, color='grey', lw=0.8)
    am.text(f_T, am.get_ylim()[0], ' 1/T', color='grey', va='bottom')
    am.legend(fontsize=7, ncol=2)
    for ax in (am, ap):
        ax.grid(True, which='both', alpha=0.3)
    am.set_title('Current to line flow: fine vs simplified vs eqs. 14/15')
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
