"""Sensitivities of a sweep and its report (``report.html``, figures embedded as PNG).

- Standardised regression coefficients (SRC): the least-squares fit of each output, both
  sides scaled to zero mean and unit standard deviation, on the varied inputs
  (``numpy.linalg.lstsq``). For a model close to linear over the sweep
  (``R^2`` near 1) ``SRC_j^2`` is the share of the output's variance due to input ``j``.
- Sobol indices (first order ``S1``, total ``ST``, SALib) for a ``sobol`` sweep whose runs
  all succeeded.
- Morris elementary effects (SALib): ``mu*`` (the mean absolute effect of moving an input
  across its range, in the output's unit), ``sigma`` (their spread: interaction or
  non-linearity) and the 95 % bootstrap interval of ``mu*``, for a ``morris`` sweep whose
  runs all succeeded (a trajectory needs every one of its points).
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path

import numpy as np

from hydropump_sim import files

from .. import provenance
from .runs import STATUS_OK
from .spec import Sweep


def src(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float]:
    """Standardised regression coefficients of ``y`` on the columns of ``x``, and ``R^2``.

    An input that does not vary gets 0; an output that does not vary gets zeros.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    sx = x.std(axis=0)
    sy = y.std()
    coef = np.zeros(x.shape[1])
    if sy == 0.0 or x.shape[0] < 2:
        return coef, math.nan
    live = sx > 0
    xs = (x[:, live] - x[:, live].mean(axis=0)) / sx[live]
    ys = (y - y.mean()) / sy
    a = np.column_stack([np.ones(len(ys)), xs])
    beta, *_ = np.linalg.lstsq(a, ys, rcond=None)
    coef[live] = beta[1:]
    resid = ys - a @ beta
    return coef, float(1.0 - resid @ resid / (ys @ ys))


def read_table(path: Path) -> dict:
    """``runs.parquet`` as numpy columns, plus its units."""
    import pyarrow.parquet as pq
    t = pq.read_table(path)
    meta = t.schema.metadata or {}
    cols = {name: t.column(name).to_numpy(zero_copy_only=False) for name in t.column_names}
    cols['__units__'] = json.loads(meta.get(b'units', b'{}'))
    return cols


def sensitivities(sweep: Sweep, cols: dict) -> dict:
    """``{output: {'src': {input: value}, 'r2': float, 'S1': {...}, 'ST': {...},
    'mu_star': {...}, 'sigma': {...}, 'mu_star_conf': {...}}}`` (Sobol and Morris entries only
    for a sweep of that kind whose runs all succeeded)."""
    ok = cols['status'] == STATUS_OK
    x = np.column_stack([cols[n] for n in sweep.names])[ok]
    out = {}
    for name in sweep.columns():
        y = cols[name][ok]
        good = np.isfinite(y)
        entry: dict = {'src': {}, 'r2': math.nan}
        if good.sum() > len(sweep.names) + 1:
            coef, r2 = src(x[good], y[good])
            entry = {'src': dict(zip(sweep.names, coef.tolist())), 'r2': r2}
        complete = ok.all() and np.isfinite(cols[name]).all()
        if sweep.method == 'sobol' and complete:
            from SALib.analyze import sobol
            si = sobol.analyze(sweep.problem, cols[name], calc_second_order=False, seed=0)
            entry['S1'] = dict(zip(sweep.names, np.asarray(si['S1']).tolist()))
            entry['ST'] = dict(zip(sweep.names, np.asarray(si['ST']).tolist()))
        elif sweep.method == 'morris' and complete:
            from SALib.analyze import morris
            si = morris.analyze(sweep.problem, sweep.samples, np.asarray(cols[name], float),
                                num_levels=sweep.levels, seed=0)
            for key in ('mu_star', 'sigma', 'mu_star_conf'):
                entry[key] = dict(zip(sweep.names, np.asarray(si[key], float).tolist()))
        out[name] = entry
    return out


def _png(fig) -> str:
    fig.tight_layout()      # panels apart: each tornado panel names its own inputs
    buf = io.BytesIO()
    fig.savefig(buf, format='png', dpi=90, bbox_inches='tight')
    import matplotlib.pyplot as plt
    plt.close(fig)
    return '<img src="data:image/png;base64,' + base64.b64encode(buf.getvalue()).decode() + '">'


# The page fits a laptop's window: figures scale down, a wide table scrolls in its own box
# (a sweep of many inputs and outputs has many columns).
PAGE_CSS = ('body{font-family:sans-serif;max-width:1300px;margin:auto;padding:0 1em}'
            'img{max-width:100%;height:auto}table{display:block;max-width:100%;'
            'overflow-x:auto;border-collapse:collapse}td,th{padding:3px 6px}')


def write_report(sweep: Sweep, table: Path, out: Path) -> Path:
    """``out/report.html`` and ``out/sensitivities.json``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    cols = read_table(table)
    units = cols['__units__']
    sens = sensitivities(sweep, cols)
    prov = provenance.collect([sweep.source])
    files.write_text(out / 'sensitivities.json', json.dumps(
        {'outputs': sens, 'provenance': prov}, indent=1), 'sensitivities')
    outputs = list(sweep.columns())
    ok = cols['status'] == STATUS_OK
    n_ok, n = int(ok.sum()), len(ok)
    parts = [f'<h1>Sweep {html.escape(sweep.source or "")}</h1>',
             f'<p>{sweep.method}, {n} runs: {n_ok} ok, {n - n_ok} failed. Inputs: '
             + ', '.join(f'<code>{html.escape(v)}</code>' for v in sweep.names) + '</p>']

    parts.append('<h2>Outputs</h2><table border=1 cellpadding=3><tr><th>output</th><th>unit'
                 '</th><th>mean</th><th>std</th><th>min</th><th>max</th></tr>')
    for name in outputs:
        y = cols[name][ok]
        y = y[np.isfinite(y)]
        stats = [y.mean(), y.std(), y.min(), y.max()] if y.size else [math.nan] * 4
        parts.append(f'<tr><td>{name}</td><td>{units.get(name, "")}</td>'
                     + ''.join(f'<td>{v:.5g}</td>' for v in stats) + '</tr>')
    parts.append('</table>')

    if n_ok:
        fig, axes = plt.subplots(1, len(outputs), figsize=(3.2 * len(outputs), 2.6),
                                 squeeze=False)
        for ax, name in zip(axes[0], outputs):
            y = cols[name][ok]
            ax.hist(y[np.isfinite(y)], bins='auto', color='tab:blue')
            ax.set_xlabel(f'{name} [{units.get(name, "")}]')
        axes[0][0].set_ylabel('runs')
        parts += ['<h2>Histograms</h2>', _png(fig)]

        # Tornado: one panel per output, inputs sorted by |SRC|.
        fig, axes = plt.subplots(1, len(outputs), figsize=(4.2 * len(outputs), 0.5 +
                                 0.45 * len(sweep.names)), squeeze=False)
        for ax, name in zip(axes[0], outputs):
            s = sens[name]['src']
            order = sorted(s, key=lambda k: abs(s[k]))
            ax.barh(range(len(order)), [s[k] for k in order],
                    color=['tab:red' if s[k] < 0 else 'tab:green' for k in order])
            # Each panel has its own order: each names its inputs.
            ax.set_yticks(range(len(order)), order, fontsize=7)
            ax.axvline(0.0, color='k', lw=0.8)
            ax.set_xlim(-1.05, 1.05)
            ax.set_title(f'{name}\nR² = {sens[name]["r2"]:.3f}', fontsize=9)
        parts += ['<h2>Sensitivities (tornado, standardised regression coefficients)</h2>',
                  _png(fig)]
        if any('mu_star' in sens[o] for o in outputs):
            parts += ['<h2>Morris elementary effects (tornado of mu*, 95 % interval; '
                      "the output's unit)</h2>", _png(_morris_tornado(plt, sweep, sens,
                                                                         outputs, units))]
        rows = ''.join(
            f'<tr><td>{o}</td><td>{i}</td><td>{sens[o]["src"].get(i, math.nan):+.3f}</td>'
            + (f'<td>{sens[o]["S1"][i]:.3f}</td><td>{sens[o]["ST"][i]:.3f}</td>'
               if 'S1' in sens[o] else '<td></td><td></td>') + '</tr>'
            for o in outputs for i in sweep.names)
        parts.append('<table border=1 cellpadding=3><tr><th>output</th><th>input</th>'
                     '<th>SRC</th><th>Sobol S1</th><th>Sobol ST</th></tr>' + rows + '</table>')
        if any('mu_star' in sens[o] for o in outputs):
            rows = ''.join(
                f'<tr><td>{o}</td><td>{i}</td><td>{sens[o]["mu_star"][i]:.4g}</td>'
                f'<td>{sens[o]["mu_star_conf"][i]:.3g}</td><td>{sens[o]["sigma"][i]:.4g}</td>'
                f'<td>{units.get(o, "")}</td></tr>'
                for o in outputs if 'mu_star' in sens[o] for i in sweep.names)
            parts.append('<table border=1 cellpadding=3><tr><th>output</th><th>input</th>'
                         '<th>Morris mu*</th><th>95 % +-</th><th>sigma</th><th>unit</th></tr>'
                         + rows + '</table>')

        fig, axes = plt.subplots(1, len(outputs), figsize=(3.2 * len(outputs), 2.6),
                                 squeeze=False)
        for ax, name in zip(axes[0], outputs):
            s = sens[name]['src']
            top = max(s, key=lambda k: abs(s[k])) if s else sweep.names[0]
            ax.plot(cols[top][ok], cols[name][ok], '.', ms=4)
            ax.set_xlabel(f'{top} [{units.get(top, "")}]', fontsize=8)
            ax.set_ylabel(f'{name} [{units.get(name, "")}]', fontsize=8)
        parts += ['<h2>Strongest input against each output</h2>', _png(fig)]

    # Worst runs: the failed ones, then the largest deviation from the mean in standard
    # deviations over any output.
    z = np.zeros(n)
    for name in outputs:
        y = cols[name]
        good = ok & np.isfinite(y)
        if good.sum() > 1 and y[good].std() > 0:
            z[good] = np.maximum(z[good], np.abs(y[good] - y[good].mean()) / y[good].std())
    z[~ok] = np.inf
    worst = np.argsort(-z)[:min(10, n)]
    head = ''.join(f'<th>{h}</th>' for h in ['run', *sweep.names, *outputs, 'status',
                                             'deviation [sd]', 'reason'])
    body = ''
    for k in worst:
        cells = [str(cols['run_id'][k])] + [f'{cols[c][k]:.5g}' for c in sweep.names] + \
            [f'{cols[c][k]:.5g}' for c in outputs] + \
            [cols['status'][k], f'{z[k]:.2f}', html.escape(str(cols['reason'][k]))]
        body += '<tr>' + ''.join(f'<td>{c}</td>' for c in cells) + '</tr>'
    parts.append('<h2>Worst runs</h2><table border=1 cellpadding=3><tr>' + head + '</tr>'
                 + body + '</table>')
    parts.append('<h2>Provenance</h2>' + provenance.html(prov))
    return files.write_text(out / 'report.html',
                            '<!doctype html><meta charset="utf-8"><title>hydropump sweep'
                            '</title><style>' + PAGE_CSS + '</style><body>' + '\n'.join(parts)
                            + '</body>', 'report')


def _morris_tornado(plt, sweep: Sweep, sens: dict, outputs: list, units: dict):
    """One panel per output with Morris indices: inputs sorted by mu*, its 95 % interval as
    an error bar, sigma marked beside."""
    names = [o for o in outputs if 'mu_star' in sens[o]]
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 0.5 + 0.45 *
                             len(sweep.names)), squeeze=False)
    for ax, name in zip(axes[0], names):
        mu, conf, sd = (sens[name][k] for k in ('mu_star', 'mu_star_conf', 'sigma'))
        order = sorted(mu, key=lambda k: mu[k])
        ax.barh(range(len(order)), [mu[k] for k in order], xerr=[conf[k] for k in order],
                color='tab:blue', label='mu*')
        ax.plot([sd[k] for k in order], range(len(order)), 'k|', ms=10, label='sigma')
        ax.set_yticks(range(len(order)), order, fontsize=7)
        ax.set_title(f'{name} [{units.get(name, "")}]', fontsize=9)
    axes[0][0].legend(fontsize=7, loc='lower right')
    return fig
