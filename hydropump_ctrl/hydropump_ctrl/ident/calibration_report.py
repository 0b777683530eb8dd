"""The calibration report: measured against the model before and after, per recording and
signal, the residuals, the correlation heat map (PNG), and a Markdown page that ties them
together with the tables of :class:`.calibrate.Calibration`."""

from __future__ import annotations

from collections.abc import Sequence
import json
from pathlib import Path

import numpy as np

# Display units of the compared signals: (scale from SI, unit).
DISPLAY = {'line_flow': (6.0e4, 'L/min'), 'pump_flow': (6.0e4, 'L/min'),
           'load_flow': (6.0e4, 'L/min'), 'line_pressure': (1e-5, 'bar'),
           'actuator_pressure': (1e-5, 'bar'), 'spool_position': (1e3, 'mm'),
           'actuator_position': (1e3, 'mm')}


def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _safe(name: str) -> str:
    return ''.join(c if c.isalnum() or c in '-_' else '_' for c in name)[:60]


def plot_comparison(exp, after: dict, path: Path, before: dict | None = None,
                    title: str = '') -> Path:
    """One recording: per signal, measured, the model before (dashed) and after, and the
    residual below it."""
    plt = _pyplot()
    sigs = list(exp.measured)
    fig, axes = plt.subplots(len(sigs), 2, figsize=(11, 1.9 * len(sigs) + 0.6), squeeze=False,
                             gridspec_kw={'width_ratios': [3, 1.2]})
    t = np.arange(exp.n) * exp.dt
    for row, s in enumerate(sigs):
        k, unit = DISPLAY.get(s, (1.0, ''))
        ax, axr = axes[row]
        ax.plot(t, exp.measured[s] * k, color='0.6', lw=0.6, label='measured')
        if before is not None:
            ax.plot(t, before[s] * k, 'C1--', lw=0.9, label='model, start')
        ax.plot(t, after[s] * k, 'C0', lw=1.0, label='model, calibrated')
        ax.set_ylabel(f'{s}\n[{unit}]', fontsize=8)
        ax.grid(alpha=0.3)
        res = (exp.measured[s] - after[s]) * k
        axr.plot(t, res, 'C3', lw=0.5)
        axr.set_title(f'residual [{unit}]', fontsize=8)
        axr.grid(alpha=0.3)
        if row == 0:
            ax.legend(fontsize=7, loc='best')
    axes[-1][0].set_xlabel('t [s]')
    axes[-1][1].set_xlabel('t [s]')
    fig.suptitle(title or exp.name, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_correlation(names: Sequence[str], corr: np.ndarray, path: Path) -> Path:
    plt = _pyplot()
    n = len(names)
    fig, ax = plt.subplots(figsize=(1.2 * n + 2.5, 1.0 * n + 1.8))
    im = ax.imshow(np.nan_to_num(corr), vmin=-1, vmax=1, cmap='RdBu_r')
    ax.set_xticks(range(n), [s.split('.')[-1] for s in names], rotation=45, ha='right')
    ax.set_yticks(range(n), [s.split('.')[-1] for s in names])
    for i in range(n):
        for j in range(n):
            v = corr[i, j]
            ax.text(j, i, '-' if not np.isfinite(v) else f'{v:.2f}', ha='center', va='center',
                    fontsize=8)
    fig.colorbar(im, ax=ax, shrink=0.8, label='correlation')
    ax.set_title('parameter correlations')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _table(head, rows) -> str:
    out = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    out += ['| ' + ' | '.join(str(c) for c in r) + ' |' for r in rows]
    return '\n'.join(out)


def fit_table(fit: dict, before: dict | None = None) -> str:
    sigs = sorted({s for per in fit.values() for s in per})
    rows = []
    for name, per in fit.items():
        cells = []
        for s in sigs:
            if s not in per:
                cells.append('')
            elif before is not None:
                cells.append(f'{before[name][s]:.1f} -> {per[s]:.2f}')
            else:
                cells.append(f'{per[s]:.2f}')
        rows.append([name] + cells)
    return _table(['recording'] + sigs, rows)


def write_calibration_report(cal, out: Path, *, plots: bool = True) -> Path:
    """``result.json``, ``report.md`` and the figures of a calibration into ``out``."""
    out = Path(out)
    (out / 'result.json').write_text(json.dumps(cal.to_dict(), indent=2))
    figs = []
    if plots:
        for k, (e, a, b) in enumerate(zip(cal.experiments, cal.predictions,
                                           cal.predictions_before)):
            figs.append(plot_comparison(e, a, out / f'compare_{k + 1}_{_safe(e.name)}.png', b))
        figs.append(plot_correlation(cal.free, cal.correlation, out / 'correlation.png'))
    rows = []
    for p in cal.estimates:
        se = ('not determined' if not p.determined else
              f'{p.stderr:.3g} ({100 * p.stderr / abs(p.value):.2f} %)' if p.stderr else '')
        rows.append([p.name, f'{p.initial:.6g}', f'{p.value:.6g}', se, p.on_bound or ''])
    md = ['# Calibration', '', f'Recordings: {", ".join(cal.sources)}', '',
          f'Method: {cal.method}; {cal.n_simulations} simulations, {cal.wall_time:.1f} s.', '',
          '## Parameters', '',
          _table(['parameter', 'start', 'calibrated', 'standard error', 'bound'], rows), '']
    if cal.tied:
        md += ['Tied (moved with the free ones): ' + ', '.join(
            f'{n} = {v:.6g}' for n, v in cal.tied.items()), '']
    md += ['## Identifiability', '',
           'Singular values of the scaled sensitivity matrix (relative sensitivities, noise-'
           'weighted, delays projected out): '
           + ', '.join(f'{v:.3g}' for v in cal.singular_values), '']
    for u in cal.undetermined:
        md.append(f'- **Not determined:** {", ".join(u["parameters"])}; determined: '
                  f'{u["determined_combination"]}; separated by: '
                  f'{", ".join(u.get("separated_by") or []) or "-"}')
    md += ['', '## Fit per recording and signal (%, start -> calibrated)', '',
           fit_table(cal.fit, cal.fit_before), '', '## Measurement delays [ms]', '',
           _table(['recording'] + sorted({s for v in cal.delays.values() for s in v}),
                  [[n] + [f'{1e3 * v[s]:.1f}' if s in v else '' for s in
                          sorted({s for v in cal.delays.values() for s in v})]
                   for n, v in cal.delays.items()]), '']
    if cal.flags:
        md += ['## Flags', ''] + [f'- {f}' for f in cal.flags] + ['']
    if cal.notes:
        md += ['## Notes', ''] + [f'- {n}' for n in cal.notes] + ['']
    if figs:
        md += ['## Figures', ''] + [f'![{f.stem}]({f.name})' for f in figs]
    (out / 'report.md').write_text('\n'.join(md) + '\n')
    return out / 'report.md'


def write_validation_report(fit: dict, delays: dict, exps, preds, out: Path, params_file: str,
                            *, plots: bool = True) -> Path:
    out = Path(out)
    (out / 'validation.json').write_text(json.dumps(
        {'params': params_file, 'fit_percent': fit, 'delays_s': delays}, indent=2))
    figs = []
    if plots:
        for k, (e, p) in enumerate(zip(exps, preds)):
            figs.append(plot_comparison(e, p, out / f'validate_{k + 1}_{_safe(e.name)}.png',
                                        title=f'{e.name}: {params_file}'))
    md = ['# Validation', '', f'Params file: {params_file}', '', fit_table(fit), '']
    md += [f'![{f.stem}]({f.name})' for f in figs]
    (out / 'validation.md').write_text('\n'.join(md) + '\n')
    return out / 'validation.md'
