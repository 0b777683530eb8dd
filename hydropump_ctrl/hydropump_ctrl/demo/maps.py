"""Beyond the paper's one operating point: the plant's eq. 19 over the operating range, and
its sensitivity to the dither, from the noise-free fine model.

Each point is a current step up and one down (by default 2 % of the 0..100 % displacement
range, held 0.8 s, from the equilibrium) on the fine model, fitted with the eq. 16 step models of
:mod:`hydropump_ctrl.ident.matrix`: ``G0`` and ``tau`` of growing flow, ``tau`` of falling
flow. Gains are in the paper's units (% of ``V_p f_p`` per unit current fraction).

- :func:`operating_map`: over load pressure and displacement;
- :func:`dither_sensitivity`: growing-flow ``tau`` over dither amplitude and frequency, around
  the spool's resonance, at the nominal point.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hydropump_sim.files import save_figure
from hydropump_sim.params import Params
from hydropump_sim.simulate import simulate

from ..ident.matrix import fit_element

STEP = 0.02     # current fraction of the 0..100 % displacement range
DWELL = 0.8     # s per level (eight time constants)
DT = 1e-3


def step_figures(params: Params, displacement: float = 0.5, *,
                 load_pressure: float | None = None, step: float = STEP) -> dict[str, float]:
    """``G0`` [%/unit], ``tau_up`` and ``tau_down`` [s] of the noise-free fine model for small
    steps around ``displacement`` (a fraction of 0..100 %) at ``load_pressure`` (gauge Pa;
    default the params file's)."""
    lo, hi = params.current_range
    i0 = lo + displacement * (hi - lo)
    di = step * (hi - lo)
    n = int(round(DWELL / DT))
    cur = np.concatenate([np.full(n, i0), np.full(n, i0 + di), np.full(n, i0)])
    res = simulate(params, (cur.size - 1) * DT, cur,
                   load_pressure=load_pressure, dt_out=DT)
    q = res.q_l[:cur.size]
    up = fit_element('G21_up', [(cur, q)], DT)
    down = fit_element('G21_down', [(cur, q)], DT, fixed={'td': up.values['td']})
    return {'G0': up.values['G0'] * (hi - lo) / params.Q_max * 100.0,
            'tau_up': up.values['tau'], 'tau_down': down.values['tau']}


def operating_map(params: Params, load_pressures: Sequence[float],
                  displacements: Sequence[float]) -> dict[str, np.ndarray]:
    """:func:`step_figures` on a grid: arrays ``[load pressure, displacement]`` of ``G0``,
    ``tau_up``, ``tau_down``, with the axes."""
    out = {k: np.full((len(load_pressures), len(displacements)), np.nan)
           for k in ('G0', 'tau_up', 'tau_down')}
    for i, pu in enumerate(load_pressures):
        for j, d in enumerate(displacements):
            for k, v in step_figures(params, d, load_pressure=pu).items():
                out[k][i, j] = v
    out['load_pressure'] = np.asarray(load_pressures, float)
    out['displacement'] = np.asarray(displacements, float)
    return out


def dither_sensitivity(params: Params, amplitudes: Sequence[float],
                       frequencies: Sequence[float], step: float = 0.1
                       ) -> dict[str, np.ndarray]:
    """Growing-flow ``tau`` [s] and ``G0`` at the nominal point over dither amplitude [A] and
    frequency [Hz] (arrays ``[amplitude, frequency]``), for steps of ``step`` (the campaign's
    staircases step by 10 %: the rectification at the pilot valve's kink weighs more, the
    smaller the step is against the dither)."""
    tau = np.full((len(amplitudes), len(frequencies)), np.nan)
    g0 = np.full_like(tau, np.nan)
    for i, a in enumerate(amplitudes):
        for j, f in enumerate(frequencies):
            if a == 0.0 and j > 0:  # no dither: one point for every frequency
                tau[i, j], g0[i, j] = tau[i, 0], g0[i, 0]
                continue
            fig = step_figures(params.replace({'input.dither_amp': float(a),
                                               'input.dither_freq': float(f)}), step=step)
            tau[i, j], g0[i, j] = fig['tau_up'], fig['G0']
    return {'tau_up': tau, 'G0': g0, 'amplitude': np.asarray(amplitudes, float),
            'frequency': np.asarray(frequencies, float), 'step': step}


def spool_resonance(params: Params) -> float:
    """Natural frequency [Hz] of the spool on its springs, ``sqrt((K_a + K_c) / m_c) / 2 pi``
    (eq. 1 with the actuator held)."""
    sp = params.spool
    return float(np.sqrt((sp.K_a + sp.K_c) / sp.m_c) / (2 * np.pi))


def plot_operating_map(m: dict, path) -> None:
    from .plots import pyplot
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    d = 100 * m['displacement']
    for ax, key, label, scale in ((axes[0], 'G0', 'G0 [% per unit current]', 1.0),
                                  (axes[1], 'tau_up', 'tau, growing flow [ms]', 1e3),
                                  (axes[2], 'tau_down', 'tau, falling flow [ms]', 1e3)):
        for i, pu in enumerate(m['load_pressure']):
            ax.plot(d, m[key][i] * scale, 'o-', label=f'P_u = {pu / 1e5:.0f} bar')
        ax.set_xlabel('displacement [%]')
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle('eq. 19 of the plant (noise-free fine model) over the operating range',
                 fontsize=10)
    fig.tight_layout()
    save_figure(fig, path, 'figure', axes=True, dpi=90)
    plt.close(fig)


def plot_dither_sensitivity(s: dict, path, resonance: float | None = None) -> None:
    from .plots import pyplot
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    for i, a in enumerate(s['amplitude']):
        ax.plot(s['frequency'], 1e3 * s['tau_up'][i], 'o-', label=f'{1e3 * a:.0f} mA')
    if resonance:
        ax.axvline(resonance, color='0.5', ls='--', lw=0.8)
        ax.text(resonance, ax.get_ylim()[0], ' spool resonance', fontsize=8, color='0.4',
                va='bottom')
    ax.set_xlabel('dither frequency [Hz]')
    ax.set_ylabel('tau, growing flow [ms]')
    ax.set_title('dither amplitude and frequency against the identified time constant',
                 fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, title='dither amplitude')
    fig.tight_layout()
    save_figure(fig, path, 'figure', axes=True, dpi=90)
    plt.close(fig)


#: Grids of the figures: the docs' (fine) and the demo report's (coarse, about 3 s).
GRIDS = {
    'fine': {'load_pressures': [8.0e6, 1.2e7, 1.6e7], 'displacements': [0.2, 0.35, 0.5, 0.65, 0.8],
             'amplitudes': [0.0, 0.004, 0.008, 0.012],
             'frequencies': [80.0, 120.0, 140.0, 153.0, 170.0, 200.0, 300.0]},
    'coarse': {'load_pressures': [8.0e6, 1.2e7, 1.6e7], 'displacements': [0.25, 0.5, 0.75],
               'amplitudes': [0.0, 0.002, 0.004],
               'frequencies': [80.0, 120.0, 153.0, 200.0, 300.0, 400.0]},
}


def draw_figures(params: Params, folder, grid: str = 'coarse') -> tuple[dict, dict]:
    """``operating_map.png`` and ``dither_sensitivity.png`` in ``folder``, on one of
    :data:`GRIDS`; the two results."""
    from pathlib import Path
    g = GRIDS[grid]
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    m = operating_map(params, g['load_pressures'], g['displacements'])
    plot_operating_map(m, folder / 'operating_map.png')
    s = dither_sensitivity(params, g['amplitudes'], g['frequencies'])
    plot_dither_sensitivity(s, folder / 'dither_sensitivity.png', spool_resonance(params))
    return m, s
