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

from .. import pages, provenance
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
    files.pyplot().close(fig)
    return '<img src="data:image/png;base64,' + base64.b64encode(buf.getvalue()).decode() + '">'


# The page fits a laptop's window: figures scale down, a wide table scrolls in its own box
# (a sweep of many inputs and outputs has many columns).
PAGE_CSS = ('body{font-family:sans-serif;max-width:1300px;margin:auto;padding:0 1em}'
            'img{max-width:100%;height:auto}table{display:block;max-width:100%;'
            'overflow-x:auto;border-collapse:collapse}td,th{padding:3px 6px;'
            'border:1px solid #bbb}')


def write_report(sweep: Sweep, table: Path, out: Path) -> Path:
    """``out/report.html`` and ``out/sensitivities.json``."""
    plt = files.pyplot()

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
             f'<p>{html.escape(sweep.method)}, {n} runs: {n_ok} ok, {n - n_ok} failed. '
             'Inputs: ' + ', '.join(f'<code>{html.escape(v)}</code>' for v in sweep.names)
             + '</p>',
             pages.section('Outputs', pages.table(
                 ['output', 'unit', 'mean', 'std', 'min', 'max'],
                 [[name, units.get(name, ''), *(f'{v:.5g}' for v in _stats(cols[name][ok]))]
                  for name in outputs]))]
    if n_ok:
        parts += _sensitivity_parts(plt, sweep, cols, ok, sens, outputs, units)
    parts.append(pages.section('Worst runs', _worst_runs(sweep, cols, ok, outputs)))
    parts.append(pages.section('Provenance', provenance.html(prov)))
    return files.write_text(out / 'report.html',
                            pages.page('hydropump sweep', PAGE_CSS, parts), 'report')


def _stats(y: np.ndarray) -> list[float]:
    """Mean, standard deviation, minimum and maximum of the finite values of ``y``."""
    y = y[np.isfinite(y)]
    return [y.mean(), y.std(), y.min(), y.max()] if y.size else [math.nan] * 4


def _sensitivity_parts(plt, sweep: Sweep, cols: dict, ok, sens: dict, outputs: list,
                       units: dict) -> list[str]:
    """Histograms, the tornado of SRC (and of Morris mu*), the tables of the indices, and
    each output against its strongest input."""
    fig, axes = plt.subplots(1, len(outputs), figsize=(3.2 * len(outputs), 2.6),
                             squeeze=False)
    for ax, name in zip(axes[0], outputs):
        y = cols[name][ok]
        ax.hist(y[np.isfinite(y)], bins='auto', color='tab:blue')
        ax.set_xlabel(f'{name} [{units.get(name, "")}]')
    axes[0][0].set_ylabel('runs')
    parts = [pages.section('Histograms', _png(fig))]

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
    parts.append(pages.section('Sensitivities (tornado, standardised regression '
                               'coefficients)', _png(fig)))
    morris = [o for o in outputs if 'mu_star' in sens[o]]
    if morris:
        parts.append(pages.section(
            "Morris elementary effects (tornado of mu*, 95 % interval; the output's unit)",
            _png(_morris_tornado(plt, sweep, sens, outputs, units))))
    parts.append(pages.table(
        ['output', 'input', 'SRC', 'Sobol S1', 'Sobol ST'],
        [[o, i, f'{sens[o]["src"].get(i, math.nan):+.3f}',
          *((f'{sens[o]["S1"][i]:.3f}', f'{sens[o]["ST"][i]:.3f}') if 'S1' in sens[o]
            else ('', ''))] for o in outputs for i in sweep.names]))
    if morris:
        parts.append(pages.table(
            ['output', 'input', 'Morris mu*', '95 % +-', 'sigma', 'unit'],
            [[o, i, f'{sens[o]["mu_star"][i]:.4g}', f'{sens[o]["mu_star_conf"][i]:.3g}',
              f'{sens[o]["sigma"][i]:.4g}', units.get(o, '')]
             for o in morris for i in sweep.names]))

    fig, axes = plt.subplots(1, len(outputs), figsize=(3.2 * len(outputs), 2.6),
                             squeeze=False)
    for ax, name in zip(axes[0], outputs):
        s = sens[name]['src']
        top = max(s, key=lambda k: abs(s[k])) if s else sweep.names[0]
        ax.plot(cols[top][ok], cols[name][ok], '.', ms=4)
        ax.set_xlabel(f'{top} [{units.get(top, "")}]', fontsize=8)
        ax.set_ylabel(f'{name} [{units.get(name, "")}]', fontsize=8)
    parts.append(pages.section('Strongest input against each output', _png(fig)))
    return parts


def _worst_runs(sweep: Sweep, cols: dict, ok, outputs: list) -> str:
    """The failed runs, then those deviating most from the mean in standard deviations over
    any output: a table of at most ten."""
    n = len(ok)
    z = np.zeros(n)
    for name in outputs:
        y = cols[name]
        good = ok & np.isfinite(y)
        if good.sum() > 1 and y[good].std() > 0:
            z[good] = np.maximum(z[good], np.abs(y[good] - y[good].mean()) / y[good].std())
    z[~ok] = np.inf
    worst = np.argsort(-z)[:min(10, n)]
    return pages.table(
        ['run', *sweep.names, *outputs, 'status', 'deviation [sd]', 'reason'],
        [[str(cols['run_id'][k]), *(f'{cols[c][k]:.5g}' for c in sweep.names),
          *(f'{cols[c][k]:.5g}' for c in outputs), cols['status'][k], f'{z[k]:.2f}',
          str(cols['reason'][k])] for k in worst])


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
