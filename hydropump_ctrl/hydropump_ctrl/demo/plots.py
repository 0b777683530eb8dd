"""The figures of the demo report: Bode of the fit, the current-flow hysteresis, EMC against PI.

Each function draws one PNG with matplotlib (the Agg backend: no display needed), written
whole or not at all (:func:`save`), and closes it; the closed-loop plot draws what
:func:`.campaign.loop_figures` returns.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydropump_sim.files import pyplot, save_figure
from hydropump_sim.params import Params


def save(plt, fig, path, dpi: int = 100) -> Path:
    """``fig`` into ``path`` whole or not at all (a full disk: a
    :class:`~hydropump_sim.files.WriteError` naming the file), then closed either way."""
    try:
        return save_figure(fig, path, dpi=dpi, axes=True)
    finally:
        plt.close(fig)


def plot_bode_identified(params: Params, ident, path: Path) -> None:
    """Current to line flow: fine (growing flow), simplified and the identified eq. 19."""
    import control

    from hydropump_sim import equilibrium, linearize
    from hydropump_sim.linear import bode_data
    plt = pyplot()
    w = np.logspace(-0.5, 3.5, 400)
    norm = 100.0 * (params.current_range[1] - params.current_range[0]) / params.Q_max
    fig, (am, ap) = plt.subplots(2, 1, figsize=(8, 6.2), sharex=True)
    for name, model in (('fine model (x_c > 0)', 'fine'), ('simplified (K_c kept)',
                                                            'simplified_Kc')):
        ss = linearize(params, equilibrium(params, model=model), 'pos', model).ss(
            inputs=['i_s'], outputs=['q_l'])
        mag, ph = bode_data(ss, w)
        am.semilogx(w / (2 * np.pi), 20 * np.log10(mag * norm), label=name)
        ap.semilogx(w / (2 * np.pi), ph)
    G = control.tf([ident.G0], [ident.tau, 1.0])
    mag, ph = bode_data(G, w)
    ph = ph - np.degrees(w * ident.td)
    am.semilogx(w / (2 * np.pi), 20 * np.log10(mag), 'k--',
                label=f'identified eq. 19 (incl. t_d = {ident.td * 1e3:.1f} ms)')
    ap.semilogx(w / (2 * np.pi), ph, 'k--')
    am.set_ylabel('|q_l / I_s| [dB, % per current range]')
    ap.set_ylabel('phase [deg]')
    ap.set_ylim(-400, 10)
    ap.set_xlabel('frequency [Hz]')
    am.legend(fontsize=8)
    for ax in (am, ap):
        ax.grid(True, which='both', alpha=0.3)
    am.set_title('Fine vs simplified vs identified (growing flow)')
    fig.tight_layout()
    save(plt, fig, path)


def plot_hysteresis(params: Params, path: Path, levels: int = 13, hold: float = 1.5) -> dict:
    """The quasi-static current-flow loop: a staircase 20 -> 80 -> 20 % held ``hold`` s per
    level, with Coulomb friction (0.5 N spool, 20 N plate) and without. Each point is the mean
    flow over the last third of its hold, shown as the deviation from the static map of
    eq. 11, where the loop is visible. Returns the gap at mid range (up minus down, % FS)."""
    from hydropump_sim import simulate
    from hydropump_sim.scaling import (
        current_for_displacement,
        displacement_of_current,
        flow_percent,
    )
    plt = pyplot()
    d = np.linspace(0.2, 0.8, levels)
    seq = np.concatenate([d, d[-2::-1]])
    currents = current_for_displacement(params, seq)

    def stairs(t):
        return currents[np.minimum((np.asarray(t) // hold).astype(int), seq.size - 1)]

    out = {}
    fig, ax = plt.subplots(figsize=(7, 5))
    for label, p, style in (('no friction', params, 'o-'),
                            ('Coulomb 0.5 N spool, 20 N plate', params.replace(
                                {'spool.F_coul_c': 0.5, 'plate.F_coul_a': 20.0}), 's-')):
        r = simulate(p, hold * seq.size, stairs, dt_out=5e-3)
        k = np.arange(seq.size)
        sel = [(r.t >= (i + 2 / 3) * hold) & (r.t < (i + 1) * hold) for i in k]
        q = np.array([np.mean(flow_percent(params, r.q_l[m])) for m in sel])
        dev = q - 100.0 * displacement_of_current(params, currents)
        ax.plot(currents, dev, style, label=label, ms=4)
        mid = levels // 2
        out[label] = float(dev[mid] - dev[seq.size - 1 - mid])
    ax.axhline(0.0, color='grey', lw=0.8)
    ax.set_xlabel('solenoid current I_s [A]')
    ax.set_ylabel('settled q_l minus eq. 11 [% of V_p f_p]')
    ax.set_title(f'Current-flow hysteresis (staircase 20 -> 80 -> 20 %, {hold:g} s per level)')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save(plt, fig, path)
    return out


def plot_closed_loop(results: dict, path: Path) -> None:
    """EMC against PI on the three scenarios."""
    plt = pyplot()
    scen = ['flow_step', 'aperture_step', 'margin_step']
    titles = {'flow_step': 'flow step 30 -> 70 %', 'aperture_step':
              'aperture 0.5 -> 0.4 (margin 25 bar)', 'margin_step': 'margin 20 -> 25 bar'}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for ax, s in zip(axes, scen):
        for alg, style in (('emc', 'tab:blue'), ('pi', 'tab:orange')):
            f = results.get(f'{alg}_{s}')
            if f:
                t, y = f['y']
                ax.plot(t, y, color=style, label=alg.upper())
        ax.set_title(titles[s])
        ax.set_xlabel('simulation time [s]')
        unit = next((results[k]['unit'] for k in results if k.endswith(s)), '')
        ax.set_ylabel('flow [% FS]' if unit == '% FS' else 'margin P_l - P_u [bar]')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle('EMC against the PI baseline, real nodes, bench sensors (lock-step)')
    fig.tight_layout()
    save(plt, fig, path)
