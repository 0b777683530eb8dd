"""Reports of an identification: tables, JSON, a Markdown page and the paper's Fig. 5 and 6.

Fig. 5 of the paper shows, for one data set, the measured current (dash-dotted), the measured
flow (solid), the identified model's flow (dashed) and the simplified model's flow (dotted);
Fig. 6 the estimation error ``e_e = q_l,m - q_l,i``. Signals are normalised as in the paper.
The simplified-model flow comes from the plant library (``hydropump_sim.simulate``, eq. 10 as
printed), driven by the measured current delayed by the identified ``t_d``: the bench delay is
not part of the plant (docs/reference.md I15).

Owns the JSON result (schema ``hydropump-fit/1``, :func:`to_dict`), the text and Markdown
tables, the figures and the report folder (:func:`write_report`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hydropump_sim.files import pyplot, refuse_foreign, save_figure, write_text

from .. import provenance
from .diagnostics import FLAG_TEXT, FopdtFit
from .model import PAPER, PARAMS
from .pooling import Identification
from .signals import find_steps, load_default_params, smooth

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
        topics = {role: rec.topics.get(sig, '') for role, sig in rec.roles.items()}
        d.update(bag=rec.source, topics=topics, truncated=bool(rec.truncated),
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
            'pooled': pooled, 'paper': paper, 'seconds': _num(ident.seconds),
            **({'provenance': ident.provenance} if ident.provenance else {})}


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
    if ident.provenance:
        lines += provenance.markdown(ident.provenance)
    if figures:
        lines += ['## Figures', '']
        for name, files in figures.items():
            lines += [f'### {name}', ''] + [f'![{Path(p).stem}]({Path(p).name})'
                                             for p in files] + ['']
    return '\n'.join(lines)


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------

def simplified_flow(rec, fit: FopdtFit, params, until: float | None = None
                    ) -> np.ndarray | None:
    """Flow [%] of the plant library's simplified model at the fit's sample times.

    Driven by the recorded current held between samples and delayed by the identified
    ``t_d``; simulated up to ``until`` [s of the fit's time axis] (default the end), NaN
    after it; ``None`` when the simulation fails (for example a current outside eq. 2).
    """
    from hydropump_sim.scaling import flow_percent
    from hydropump_sim.simulate import IntegrationError, simulate
    t_rec = rec.t - rec.t[0]
    cur = rec.current

    def current(t):
        k = np.searchsorted(t_rec, np.asarray(t) - fit.td + 1e-9 * rec.dt, side='right') - 1
        return cur[np.clip(k, 0, cur.size - 1)]

    end = float(t_rec[-1]) if until is None else min(float(t_rec[-1]), until - rec.t[0])
    try:
        res = simulate(params, max(end, 2 * rec.dt), current, model='simplified',
                       dt_out=rec.dt)
    except (IntegrationError, ValueError):
        return None
    q = np.asarray(flow_percent(params, res.q_l))
    k = np.round((fit.t - rec.t[0]) / rec.dt).astype(int)
    out = np.full(k.size, np.nan)
    ok = k < q.size
    out[ok] = q[k[ok]]
    return out


# Points per plotted line: enough for a 800-pixel-wide figure, and fast to render.
MAX_POINTS = 2500


def _thin(*arrays, n: int = MAX_POINTS):
    """Every k-th point of smooth signals, so that at most ``n`` are drawn."""
    k = max(1, int(math.ceil(arrays[0].size / n)))
    return [a[::k] for a in arrays]


def _envelope(t: np.ndarray, x: np.ndarray, n: int = MAX_POINTS):
    """Minimum and maximum of a noisy signal over ``n`` buckets (what the pixels show)."""
    k = max(1, int(math.ceil(x.size / n)))
    m = x.size // k * k
    if m == 0:
        return t, x, x
    tb = t[:m].reshape(-1, k)[:, 0]
    xb = x[:m].reshape(-1, k)
    return tb, xb.min(axis=1), xb.max(axis=1)


def draw_envelope(ax, t: np.ndarray, x: np.ndarray) -> None:
    """A noisy signal as its :func:`_envelope`, its edges stroked: where a bucket holds one
    sample (fewer samples than pixels, a 200 Hz record) the band has no height, and a fill
    alone drew nothing."""
    tb, lo, hi = _envelope(t, x)
    ax.fill_between(tb, lo, hi, color='k', lw=0.0, step='post')
    ax.step(tb, lo, 'k-', where='post', lw=0.6)
    ax.step(tb, hi, 'k-', where='post', lw=0.6)


def _zoom(fit: FopdtFit) -> tuple[float, float]:
    """Time span around the largest up-step of the current (the zone the paper fits)."""
    idx, size = find_steps(fit.u, fit.dt)
    if not idx.size:
        return float(fit.t[0]), float(fit.t[-1])
    k = int(idx[int(np.argmax(size))])
    t0 = fit.t[k]
    return float(t0 - 0.3 * (fit.tau + fit.td) - 0.05), float(t0 + 5 * fit.tau + fit.td)


def _save(plt, fig, path, dpi: int) -> Path:
    try:
        return save_figure(fig, path, dpi=dpi, axes=True)
    finally:
        plt.close(fig)


def _figure(rows: int, height: float):
    plt = pyplot()
    fig, ax = plt.subplots(rows, 1, figsize=(8, height), squeeze=False)
    fig.subplots_adjust(left=0.09, right=0.98, top=0.94, bottom=0.08, hspace=0.32)
    return plt, fig, ax[:, 0]


def plot_fig5(fit: FopdtFit, path, simplified: np.ndarray | None = None) -> Path:
    """Fig. 5 style: measured current and flow, identified and simplified-model flow.

    Top: the whole record; bottom: the largest up-step. The measured signals are shown with
    the dither averaged out (20 ms centred mean), as the paper shows them filtered.
    """
    plt, fig, axes = _figure(2, 6.4)
    label = (f'identified: G0={fit.G0:.1f}, tau={1e3 * fit.tau:.1f} ms, '
             f't_d={1e3 * fit.td:.1f} ms')
    for ax, zoom in zip(axes, (False, True)):
        sel = np.ones(fit.t.size, bool)
        if zoom:
            lo, hi = _zoom(fit)
            sel = (fit.t >= lo) & (fit.t <= hi)
        _fig5_lines(ax, fit, sel, simplified, model_label=label)
        ax.set_ylabel('normalised [%]')
    axes[0].set_title(f'{fit.name}: pump responses, measured and identified ({fit.method})')
    axes[0].legend(fontsize=7, loc='best')
    axes[1].set_xlabel('time [s] (bottom: the largest up-step; dither averaged for display)')
    return _save(plt, fig, path, 100)


def plot_fig6(fit: FopdtFit, path) -> Path:
    """Fig. 6 style: estimation error, with its autocorrelation and input cross-correlation."""
    plt, fig, ax = _figure(2, 5.0)
    draw_envelope(ax[0], fit.t, fit.residual)
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
    return _save(plt, fig, path, 100)


def _grid(n: int, top: bool):
    """Figure with an optional full-width top panel and ``n`` panels in up to 3 columns."""
    plt = pyplot()
    cols = min(3, n)
    rows = int(math.ceil(n / cols))
    extra = 1 if top else 0
    fig = plt.figure(figsize=(9, 2.3 * (rows + 1.3 * extra) + 0.6))
    gs = fig.add_gridspec(rows + extra, cols, height_ratios=[1.3] * extra + [1] * rows,
                          left=0.07, right=0.98, top=0.95, bottom=0.06, hspace=0.55,
                          wspace=0.25)
    head = fig.add_subplot(gs[0, :]) if top else None
    axes = [fig.add_subplot(gs[extra + i // cols, i % cols]) for i in range(n)]
    return plt, fig, head, axes


def _fig5_lines(ax, fit: FopdtFit, sel: np.ndarray, simplified: np.ndarray | None, *,
                legend: bool = False, model_label: str = 'identified model (eq. 19)'):
    """The lines of Fig. 5 on the samples ``sel``, the measured ones with the dither averaged
    out."""
    series = [fit.t[sel]] + [smooth(x, fit.dt)[sel] for x in (100.0 * fit.u, fit.y, fit.y_hat)]
    if simplified is not None:
        series.append(smooth(simplified, fit.dt)[sel])
    t, c, m, yh, *rest = _thin(*series)
    ax.plot(t, c, '-.', color='0.45', lw=0.9, label='measured current [% of range]')
    ax.plot(t, m, 'k-', lw=1.0, label='measured flow [% of V_p f_p]')
    ax.plot(t, yh, 'C3--', lw=1.2, label=model_label)
    if rest:
        ax.plot(t, rest[0], 'C0:', lw=1.5, label='simplified model (Fig. 4), input delayed '
                                                 'by t_d')
    ax.grid(True, alpha=0.3)
    if legend:
        ax.legend(fontsize=7, loc='best')


def plot_fig5_all(fits, path, simplified=None) -> Path:
    """Fig. 5 for a set of records: the first one whole, then every set's largest up-step.

    Measured signals are shown with the dither averaged out (20 ms centred mean), as the
    paper shows them filtered.
    """
    simplified = simplified or [None] * len(fits)
    plt, fig, head, axes = _grid(len(fits), True)
    f0 = fits[0]
    _fig5_lines(head, f0, np.ones(f0.t.size, bool), simplified[0], legend=True)
    head.set_title(f'Pump responses, measured and identified ({f0.method}): {f0.name} '
                   f'(G0={f0.G0:.1f}, tau={1e3 * f0.tau:.1f} ms, t_d={1e3 * f0.td:.1f} ms)',
                   fontsize=9)
    head.set_xlabel('time [s]', fontsize=8)
    head.set_ylabel('normalised [%]', fontsize=8)
    for ax, fit, simp in zip(axes, fits, simplified):
        lo, hi = _zoom(fit)
        _fig5_lines(ax, fit, (fit.t >= lo) & (fit.t <= hi), simp)
        ax.set_title(f'{fit.name}: G0 {fit.G0:.1f}, tau {1e3 * fit.tau:.1f}, '
                     f't_d {1e3 * fit.td:.1f} ms', fontsize=8)
        ax.tick_params(labelsize=7)
        ax.locator_params(nbins=4)
    return _save(plt, fig, path, 90)


def plot_fig6_all(fits, path) -> Path:
    """Fig. 6 for a set of records: the estimation error of each set."""
    plt, fig, _, axes = _grid(len(fits), False)
    for ax, fit in zip(axes, fits):
        draw_envelope(ax, fit.t, fit.residual)
        ax.set_title(f'{fit.name}: e_e rms {fit.rmse:.3g} %, fit {fit.fit_percent:.1f} %',
                     fontsize=8)
        ax.tick_params(labelsize=7)
        ax.locator_params(nbins=4)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel('q_l,m - q_l,i [%]', fontsize=8)
    return _save(plt, fig, path, 90)


def _safe(name: str) -> str:
    return ''.join(ch if ch.isalnum() or ch in '-_' else '_' for ch in name) or 'set'


def write_report(ident: Identification, out_dir, *, params=None, plots: bool = True,
                 per_set: bool = False) -> dict[str, Path]:
    """Write the report folder and return the paths by role.

    ``result.json``, ``report.md``, ``fig5.png`` (the first set's record and every set's
    largest up-step with the identified and simplified-model flow) and ``fig6.png`` (every
    set's estimation error); with ``per_set`` also ``fig5_<set>.png`` and
    ``fig6_<set>.png`` (whole record, up-step, error with its correlation tests).
    """
    out = Path(out_dir)
    paths = {'json': out / 'result.json', 'markdown': out / 'report.md'}
    # A folder that holds the user's own result.json or report.md: nothing written.
    refuse_foreign(paths['json'], f'"schema": "{SCHEMA}"', 'fit result')
    refuse_foreign(paths['markdown'], '# Identification of eq. 19', 'fit report')
    out.mkdir(parents=True, exist_ok=True)
    write_text(paths['json'], to_json(ident) + '\n', 'result')
    figures: dict[str, list[str]] = {}
    if plots:
        params = load_default_params() if params is None else params
        recs = ident.recordings or [None] * len(ident.sets)
        # Fig. 5 shows the first record whole and the others up to their largest up-step.
        simp = [simplified_flow(r, f, params, None if i == 0 or per_set else _zoom(f)[1])
                if r is not None else None
                for i, (f, r) in enumerate(zip(ident.sets, recs))]
        paths['fig5'] = plot_fig5_all(ident.sets, out / 'fig5.png', simp)
        paths['fig6'] = plot_fig6_all(ident.sets, out / 'fig6.png')
        figures['All sets'] = [str(paths['fig5']), str(paths['fig6'])]
        used: set[str] = set()
        for fit, sf in zip(ident.sets if per_set else [], simp):
            stem = _safe(fit.name)
            while stem in used:
                stem += '_'
            used.add(stem)
            f5 = plot_fig5(fit, out / f'fig5_{stem}.png', sf)
            f6 = plot_fig6(fit, out / f'fig6_{stem}.png')
            figures[fit.name] = [str(f5), str(f6)]
            paths[f'fig5_{stem}'] = f5
            paths[f'fig6_{stem}'] = f6
    write_text(paths['markdown'], markdown(ident, figures) + '\n', 'report')
    return paths
