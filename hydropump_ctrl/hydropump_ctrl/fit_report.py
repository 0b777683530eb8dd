"""Reports of an identification: tables, JSON, a Markdown page and the paper's Fig. 5 and 6.

Fig. 5 of the paper shows, for one data set, the measured current (dash-dotted), the measured
flow (solid), the identified model's flow (dashed) and the simplified model's flow (dotted);
Fig. 6 the estimation error ``e_e = q_l,m - q_l,i``. Signals are normalised as in the paper.
The simplified-model flow comes from the plant library (``hydropump_sim.simulate``, eq. 10 as
printed), driven by the measured current delayed by the identified ``t_d``: the bench delay is
not part of the plant (model_notes I15).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .fopdt import FLAG_TEXT, FopdtFit, Identification, PAPER, PARAMS

SCHEMA = 'hydropump-fit/1'
UNITS = {'G0': '% of V_p f_p per unit current fraction', 'tau': 's', 'td': 's',
         'offset': '% of V_p f_p', 'fit_percent': '%', 'rmse': '% of V_p f_p', 'dt': 's'}


def _num(x: Any) -> Any:
    """JSON-safe number: NaN and infinities become ``None``."""
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, (int, np.integer)):
        return int(x)
    return x


def _check(c: dict) -> dict:
    return {k: _num(v) for k, v in c.items()}


def set_dict(fit: FopdtFit, rec=None) -> dict[str, Any]:
    """One data set's entry of the JSON result."""
    d: dict[str, Any] = {'name': fit.name}
    if rec is not None:
        d.update(bag=rec.source, topics=dict(rec.topics), truncated=bool(rec.truncated),
                 notes=list(rec.notes) + ([rec.truncation] if rec.truncation else []))
    d.update(method=fit.method, n_samples=fit.n, dt=_num(fit.dt))
    for p in PARAMS:
        d[p] = _num(fit.value(p))
    for p in PARAMS:
        d[f'{p}_se'] = _num(fit.se.get(p, math.nan))
    for p in PARAMS:
        d[f'{p}_se_white'] = _num(fit.se_white.get(p, math.nan))
    d.update(offset=_num(fit.offset), offset_se=_num(fit.se.get('offset', math.nan)),
             fit_percent=_num(fit.fit_percent), rmse=_num(fit.rmse), flags=list(fit.flags))
    if fit.checks:
        d['whiteness'] = _check({k: v for k, v in fit.checks['whiteness'].items()})
        d['cross'] = _check({k: v for k, v in fit.checks['cross'].items()})
    d['dither'] = [{'freq': _num(x['freq']), 'amp': _num(x['amp'])} for x in fit.dither]
    if fit.seed is not None:
        d['seed'] = [_num(x) for x in fit.seed]
    if fit.bounds:
        d['bounds'] = {k: [_num(x) for x in v] for k, v in fit.bounds.items()}
    d['nfev'] = int(fit.nfev)
    return d


def to_dict(ident: Identification) -> dict[str, Any]:
    """The JSON result: per set, pooled (mean, std, se of the mean), joint, the paper's."""
    recs = ident.recordings or [None] * len(ident.sets)
    po = ident.pooled
    pooled: dict[str, Any] = {'n_sets': po.n}
    for p in PARAMS:
        pooled[p] = _num(po.mean[p])
    for p in PARAMS:
        pooled[f'{p}_std'] = _num(po.std[p])
    for p in PARAMS:
        pooled[f'{p}_se'] = _num(po.se_mean[p])
    flags = []
    if po.n < 2:
        flags.append('single_set')
    if po.flagged:
        flags.append('some_sets_flagged')
    pooled.update(fit_percent=_num(po.fit_percent), flags=flags,
                  flagged_sets={f.name: list(f.flags) for f in ident.sets if f.flags})
    if po.joint is not None:
        j = po.joint
        jd = {p: _num(j.value(p)) for p in PARAMS}
        jd.update({f'{p}_se': _num(j.se[p]) for p in PARAMS})
        jd.update(fit_percent=_num(j.fit_percent), flags=list(j.flags), n_samples=j.n)
        pooled['joint'] = jd
    else:
        pooled['joint'] = None
    paper = {}
    for p in PARAMS:
        paper[p], paper[f'{p}_std'] = PAPER[p]
    return {'schema': SCHEMA, 'method': ident.method, 'units': UNITS,
            'normalisation': {k: _num(v) if not isinstance(v, list) else [_num(x) for x in v]
                              for k, v in ident.normalisation.items()},
            'sets': [set_dict(f, r) for f, r in zip(ident.sets, recs)],
            'pooled': pooled, 'paper': paper, 'seconds': _num(ident.seconds)}


def to_json(ident: Identification, indent: int | None = 2) -> str:
    return json.dumps(to_dict(ident), indent=indent, allow_nan=False)


# --------------------------------------------------------------------------------------------
# Text and Markdown tables
# --------------------------------------------------------------------------------------------

def _pm(v: float, e: float, scale: float = 1.0, fmt: str = '.2f') -> str:
    if not math.isfinite(e):
        return f'{v * scale:{fmt}}'
    return f'{v * scale:{fmt}} ± {e * scale:{fmt}}'


def table_rows(ident: Identification) -> tuple[list[str], list[list[str]]]:
    """Header and rows: per set (± standard error), pooled (± std), joint, paper (± spread)."""
    head = ['set', 'G0 [%]', 'tau [ms]', 't_d [ms]', 'fit [%]', 'flags']
    rows = []
    for f in ident.sets:
        rows.append([f.name, _pm(f.G0, f.se['G0']), _pm(f.tau, f.se['tau'], 1e3),
                     _pm(f.td, f.se['td'], 1e3), f'{f.fit_percent:.1f}',
                     ', '.join(f.flags) or '-'])
    po = ident.pooled
    rows.append([f'pooled mean ± std (n={po.n})', _pm(po.mean['G0'], po.std['G0']),
                 _pm(po.mean['tau'], po.std['tau'], 1e3), _pm(po.mean['td'], po.std['td'], 1e3),
                 f'{po.fit_percent:.1f}', f'{len(po.flagged)} sets flagged' if po.flagged
                 else '-'])
    if po.n > 1:
        rows.append(['pooled mean ± se of mean', _pm(po.mean['G0'], po.se_mean['G0']),
                     _pm(po.mean['tau'], po.se_mean['tau'], 1e3),
                     _pm(po.mean['td'], po.se_mean['td'], 1e3), '', ''])
    if po.joint is not None:
        j = po.joint
        rows.append(['joint fit ± se', _pm(j.G0, j.se['G0']), _pm(j.tau, j.se['tau'], 1e3),
                     _pm(j.td, j.se['td'], 1e3), f'{j.fit_percent:.1f}',
                     ', '.join(j.flags) or '-'])
    rows.append(['paper (9 sets, ± spread)', _pm(*PAPER['G0'], fmt='.1f'),
                 _pm(*PAPER['tau'], 1e3, '.0f'), _pm(*PAPER['td'], 1e3, '.1f'), '', ''])
    return head, rows


def format_table(ident: Identification) -> str:
    """Plain-text table for the terminal."""
    head, rows = table_rows(ident)
    w = [max(len(r[i]) for r in [head, *rows]) for i in range(len(head))]
    line = '  '.join(h.ljust(w[i]) for i, h in enumerate(head))
    out = [line, '-' * len(line)]
    out += ['  '.join(c.ljust(w[i]) for i, c in enumerate(r)).rstrip() for r in rows]
    return '\n'.join(out)


def _md_table(head: list[str], rows: list[list[str]]) -> str:
    out = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    out += ['| ' + ' | '.join(c.replace('|', '/') for c in r) + ' |' for r in rows]
    return '\n'.join(out)


def markdown(ident: Identification, figures: dict[str, list[str]] | None = None) -> str:
    """The report page."""
    n = ident.normalisation
    lo, hi = n.get('current_range_A', [math.nan, math.nan])
    lines = [f'# Identification of eq. 19 ({ident.method} method)', '',
             'G(s) = G0 / (1 + tau s) exp(-s t_d), fitted by minimising eq. 20. Current in '
             f'fraction of {lo:g}..{hi:g} A (0..100 % displacement), flow in % of '
             f'V_p f_p = {n.get("flow_full_scale_m3s", math.nan):.6g} m^3/s.', '',
             'Per set: estimate ± standard error (Jacobian covariance, Newey-West corrected). '
             "Pooled: mean ± standard deviation across sets (the paper's ±) and ± standard "
             'error of the mean. Joint: one fit of shared parameters to all sets.', '']
    head, rows = table_rows(ident)
    lines += [_md_table(head, rows), '']
    lines += ['## Residual tests', '',
              'Largest normalised residual autocorrelation (lags 1..25) and input-residual '
              'cross-correlation (lags -25..25) against their 99 % family-wise levels.', '']
    rt = []
    for f in ident.sets:
        w, c = f.checks['whiteness'], f.checks['cross']
        rt.append([f.name, f'{w["z_max"]:.2f} / {w["z_crit"]:.2f} (lag {w["lag"]})',
                   f'{c["z_max"]:.2f} / {c["z_crit"]:.2f} (lag {c["lag"]})',
                   ', '.join(f'{d["freq"]:.1f} Hz, {100 * d["amp"]:.2g} %' for d in f.dither)
                   or '-'])
    lines += [_md_table(['set', 'whiteness z / crit', 'cross z / crit', 'dither removed'],
                        rt), '']
    used = sorted({fl for f in ident.sets for fl in f.flags})
    if used:
        lines += ['## Flags', ''] + [f'- `{fl}`: {FLAG_TEXT[fl]}' for fl in used] + ['']
    notes = [(r.name, x) for r in ident.recordings for x in
             ([r.truncation] if r.truncation else []) + list(r.notes)]
    if notes:
        lines += ['## Data notes', ''] + [f'- {nm}: {x}' for nm, x in notes] + ['']
    if figures:
        lines += ['## Figures', '']
        for name, files in figures.items():
            lines += [f'### {name}', ''] + [f'![{Path(p).stem}]({Path(p).name})'
                                             for p in files] + ['']
    return '\n'.join(lines)


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------

def simplified_flow(rec, fit: FopdtFit, params) -> np.ndarray | None:
    """Flow [%] of the plant library's simplified model at the fit's sample times.

    Driven by the recorded current held between samples and delayed by the identified
    ``t_d``; ``None`` when the simulation fails (for example a current outside eq. 2).
    """
    from hydropump_sim.scaling import flow_percent
    from hydropump_sim.simulate import IntegrationError, simulate
    t_rec = rec.t - rec.t[0]
    cur = rec.current

    def current(t):
        k = np.searchsorted(t_rec, np.asarray(t) - fit.td + 1e-9 * rec.dt, side='right') - 1
        return cur[np.clip(k, 0, cur.size - 1)]

    try:
        res = simulate(params, float(t_rec[-1]), current, model='simplified', dt_out=rec.dt)
    except (IntegrationError, ValueError):
        return None
    q = np.asarray(flow_percent(params, res.q_l))
    k = np.clip(np.round((fit.t - rec.t[0]) / rec.dt).astype(int), 0, q.size - 1)
    return q[k]


def _display(x: np.ndarray, dt: float) -> np.ndarray:
    """Dither taken out for display, as the paper filters its plotted signals."""
    from .fopdt import _smooth_width, moving_average
    return moving_average(x, _smooth_width(dt))


def _zoom(fit: FopdtFit) -> tuple[float, float]:
    """Time span around the largest up-step of the current (the zone the paper fits)."""
    from .fopdt import _steps
    idx, size = _steps(fit.u, fit.dt)
    if not idx.size:
        return float(fit.t[0]), float(fit.t[-1])
    k = int(idx[int(np.argmax(size))])
    t0 = fit.t[k]
    return float(t0 - 0.3 * (fit.tau + fit.td) - 0.05), float(t0 + 5 * fit.tau + fit.td)


def plot_fig5(fit: FopdtFit, path, simplified: np.ndarray | None = None) -> Path:
    """Fig. 5 style: measured current and flow, identified and simplified-model flow.

    Top: the whole record; bottom: the largest up-step. The measured signals are shown with
    the dither averaged out (20 ms centred mean), as the paper shows them filtered.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 1, figsize=(8, 6.4))
    cur = _display(100.0 * fit.u, fit.dt)
    meas = _display(fit.y, fit.dt)
    for ax, zoom in zip(axes, (False, True)):
        sel = slice(None)
        if zoom:
            lo, hi = _zoom(fit)
            sel = (fit.t >= lo) & (fit.t <= hi)
        t = fit.t[sel]
        ax.plot(t, cur[sel], '-.', color='0.45', lw=0.9, label='measured current [% of range]')
        ax.plot(t, meas[sel], 'k-', lw=1.0, label='measured flow [% of V_p f_p]')
        ax.plot(t, fit.y_hat[sel], 'C3--', lw=1.2,
                label=f'identified: G0={fit.G0:.1f}, tau={1e3 * fit.tau:.1f} ms, '
                      f't_d={1e3 * fit.td:.1f} ms')
        if simplified is not None:
            ax.plot(t, simplified[sel], 'C0:', lw=1.5,
                    label='simplified model (Fig. 4), input delayed by t_d')
        ax.set_ylabel('normalised [%]')
        ax.grid(True, alpha=0.3)
    axes[0].set_title(f'{fit.name}: pump responses, measured and identified ({fit.method})')
    axes[0].legend(fontsize=7, loc='best')
    axes[1].set_xlabel('time [s] (bottom: the largest up-step; dither averaged for display)')
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_fig6(fit: FopdtFit, path) -> Path:
    """Fig. 6 style: estimation error, with its autocorrelation and input cross-correlation."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 1, figsize=(8, 5), gridspec_kw={'height_ratios': [2, 1]})
    e = fit.residual
    ax[0].plot(fit.t, e, 'k-', lw=0.6)
    ax[0].set_xlabel('time [s]')
    ax[0].set_ylabel('e_e = q_l,m - q_l,i [%]')
    ax[0].set_title(f'{fit.name}: estimation error (rms {fit.rmse:.3g} %, fit '
                    f'{fit.fit_percent:.1f} %)')
    ax[0].grid(True, alpha=0.3)
    c = fit.checks
    L = c['lags']
    ax[1].stem(np.arange(1, L + 1), c['acf'][1:], linefmt='C0-', markerfmt='C0.',
               basefmt=' ', label='residual autocorrelation')
    ax[1].plot(np.arange(-L, L + 1), c['ccf'], 'C3.', ms=3, label='input-residual')
    band = c['whiteness']['z_crit'] / math.sqrt(fit.n)
    ax[1].axhline(band, color='0.5', lw=0.8, ls='--')
    ax[1].axhline(-band, color='0.5', lw=0.8, ls='--')
    ax[1].set_xlabel('lag [samples]')
    ax[1].legend(fontsize=7)
    ax[1].grid(True, alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _safe(name: str) -> str:
    return ''.join(ch if ch.isalnum() or ch in '-_' else '_' for ch in name) or 'set'


def write_report(ident: Identification, out_dir, *, params=None, plots: bool = True,
                 max_plots: int | None = None) -> dict[str, Path]:
    """Write ``result.json``, ``report.md`` and, per set, ``fig5_<set>.png`` and
    ``fig6_<set>.png`` to ``out_dir``. Returns the paths by role."""
    from .recording import load_default_params
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {'json': out / 'result.json', 'markdown': out / 'report.md'}
    paths['json'].write_text(to_json(ident) + '\n')
    figures: dict[str, list[str]] = {}
    if plots:
        params = load_default_params() if params is None else params
        recs = ident.recordings or [None] * len(ident.sets)
        used: set[str] = set()
        for i, (fit, rec) in enumerate(zip(ident.sets, recs)):
            if max_plots is not None and i >= max_plots:
                break
            stem = _safe(fit.name)
            while stem in used:
                stem += '_'
            used.add(stem)
            simp = simplified_flow(rec, fit, params) if rec is not None else None
            f5 = plot_fig5(fit, out / f'fig5_{stem}.png', simp)
            f6 = plot_fig6(fit, out / f'fig6_{stem}.png')
            figures[fit.name] = [str(f5), str(f6)]
            paths[f'fig5_{stem}'] = f5
            paths[f'fig6_{stem}'] = f6
    paths['markdown'].write_text(markdown(ident, figures) + '\n')
    return paths
