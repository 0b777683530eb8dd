"""What a calibration writes: the calibrated params file, ``result.json``, the report page
with its figures (measured against the model before and after, residuals, the correlation
heat map), and the same for a validation.

A file is written through a temporary file renamed into place, so that a full disk or an
interrupted run never leaves half a params file where a good one was. Nothing here imports
ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
import json
import math
from pathlib import Path

import numpy as np

from hydropump_sim import files
from hydropump_sim.measure import SIGNALS
from hydropump_sim.params import Params
from hydropump_sim.schema import dump_ros_yaml, spec_map

from ... import provenance
from .data import CalibrationError
from .engine import DERIVED

#: The kind and version of a calibration's result.json (its first key).
SCHEMA = 'hydropump-calibration/1'

# Display and SI units of the compared signals, from the one table of the signals.
DISPLAY = {name: info.display for name, info in SIGNALS.items()}
SI_UNITS = {name: info.unit for name, info in SIGNALS.items()}


def write_text(path, text: str, what: str) -> Path:
    """``text`` into ``path`` through a temporary file renamed into place."""
    try:
        return files.write_text(path, text, what)
    except files.WriteError as exc:
        raise CalibrationError(exc.lines) from None


def estimate_text(p) -> str:
    """One parameter's estimate in words: value, standard error, interval, and the flag."""
    if p.held:
        return f'{p.reason}'
    rel = 100 * p.relative_stderr
    text = (f'+- {p.stderr:.3g} ({rel:.2g} %), 95 % in [{p.ci95[0]:.6g}, {p.ci95[1]:.6g}]'
            if math.isfinite(rel) else 'no standard error')
    if not p.well_determined:
        text += ' POORLY DETERMINED: ' + p.reason
    if p.prior:
        text += f'; prior {p.prior}'
    return text


def calibration_header(cal, header_lines: Sequence[str] = ()) -> str:
    """The comment lines a calibrated file starts with: the recordings, each free parameter
    with its start and error, the ties, the fit, the flags, ``header_lines`` and where the
    calibration was made."""
    lines = ['Calibrated by hydropump calibrate from:']
    lines += [f'  {s}' for s in cal.sources]
    for p in cal.estimates:
        lines.append(f'free {p.name} = {p.value:.6g} (start {p.initial:.6g}) '
                     + estimate_text(p))
    for n, v in cal.tied.items():
        lines.append(f'tied {n} = {v:.6g} ({DERIVED[n][1]})')
    for name, per in cal.fit.items():
        lines.append(f'fit % {name}: ' + ', '.join(f'{s} {_pct(v)}' for s, v in per.items()))
    lines += [f'flag: {f}' for f in cal.flags]
    lines += list(header_lines)
    if cal.provenance:
        prov = cal.provenance
        lines += [f'date {prov["date"]}, commit {prov["commit"] or "-"}',
                  f'command: {prov["command"]}']
    return '\n'.join('# ' + ln for ln in lines)


def write_params(cal, path, header_lines: Sequence[str] = (), params: Params | None = None
                 ) -> Path:
    """The calibrated parameters (``params``, default ``cal.params``) as a params file in
    the form of ``config/pump.yaml``, with a header that says where they came from."""
    comments = {p.name: f'calibrated (start {p.initial:.6g})' for p in cal.estimates}
    comments.update({n: f'tied: {DERIVED[n][1]}' for n in cal.tied})
    text = dump_ros_yaml((params or cal.params).flat(),
                         header=calibration_header(cal, header_lines),
                         comments=comments, specs=spec_map(Params))
    return write_text(path, text, 'params file')


def _safe(name: str) -> str:
    return ''.join(c if c.isalnum() or c in '-_' else '_' for c in name)[:60]


# Points per drawn line: a longer record is drawn as the minimum and maximum of each of this
# many spans (its envelope, as it would look anyway at the figure's resolution): the figures
# of a long recording cost what a short one's do.
DRAWN = 1500


def _thin(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = t.size // DRAWN
    if n < 2:
        return t, y
    m = n * DRAWN
    yy = y[:m].reshape(DRAWN, n)
    tt = t[:m].reshape(DRAWN, n)
    lo, hi = np.nanargmin(np.where(np.isnan(yy), np.inf, yy), axis=1), \
        np.nanargmax(np.where(np.isnan(yy), -np.inf, yy), axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    rows = np.arange(DRAWN)
    return (np.column_stack([tt[rows, first], tt[rows, second]]).ravel(),
            np.column_stack([yy[rows, first], yy[rows, second]]).ravel())


def plot_comparison(exp, after: dict, path: Path, before: dict | None = None,
                    title: str = '', labels=('model, start', 'model, calibrated')) -> Path:
    """One recording: per signal, measured, the model before (dashed) and after, and the
    residual beside it."""
    plt = files.pyplot()
    sigs = list(exp.measured)
    height = 1.9 * len(sigs) + 0.6
    fig, axes = plt.subplots(len(sigs), 2, figsize=(11, height), squeeze=False,
                             gridspec_kw={'width_ratios': [3, 1.2]})
    # Fixed margins (in inches) rather than a layout engine: measuring every label costs more
    # than drawing the figure.
    fig.subplots_adjust(left=0.09, right=0.985, bottom=0.55 / height, top=1 - 0.45 / height,
                        hspace=0.45, wspace=0.16)
    t = np.arange(exp.n) * exp.dt

    def line(ax, y, *style, **kw):
        ax.plot(*_thin(t, y), *style, **kw)
    for row, s in enumerate(sigs):
        k, unit = DISPLAY.get(s, (1.0, ''))
        ax, axr = axes[row]
        line(ax, exp.measured[s] * k, color='0.6', lw=0.6, label='measured')
        if before is not None:
            line(ax, before[s] * k, 'C1--', lw=0.9, label=labels[0])
        line(ax, after[s] * k, 'C0', lw=1.0, label=labels[1])
        ax.set_ylabel(f'{s}\n[{unit}]', fontsize=8)
        ax.grid(alpha=0.3)
        if before is not None:
            line(axr, (exp.measured[s] - before[s]) * k, 'C1', lw=0.4, alpha=0.6)
        line(axr, (exp.measured[s] - after[s]) * k, 'C3', lw=0.5)
        axr.set_title(f'measured - model [{unit}]', fontsize=8)
        axr.grid(alpha=0.3)
        if row == 0:
            ax.legend(fontsize=7, loc='best')
    axes[-1][0].set_xlabel('t [s]')
    axes[-1][1].set_xlabel('t [s]')
    fig.suptitle(title or exp.name, fontsize=10)
    try:
        return files.save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)


def plot_correlation(names: Sequence[str], corr: np.ndarray, path: Path) -> Path:
    plt = files.pyplot()
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
    try:
        return files.save_figure(fig, path, dpi=90)
    finally:
        plt.close(fig)


# ---- tables ------------------------------------------------------------------------------

def _table(head, rows) -> str:
    out = ['| ' + ' | '.join(head) + ' |', '|' + '---|' * len(head)]
    out += ['| ' + ' | '.join(str(c) for c in r) + ' |' for r in rows]
    return '\n'.join(out)


#: How a fit % that means nothing (a signal that hardly moves in a recording) is shown.
NOT_MEANINGFUL = 'n/m'


def _pct(v, digits: int = 2) -> str:
    return NOT_MEANINGFUL if v is None else f'{v:.{digits}f}'


def fit_table(fit: dict, before: dict | None = None) -> str:
    """Fit % per recording and signal (with ``before``: start -> calibrated); ``n/m`` where
    the signal hardly moves in the recording (its fit % is not meaningful)."""
    sigs = sorted({s for per in fit.values() for s in per})
    rows = []
    for name, per in fit.items():
        cells = []
        for s in sigs:
            if s not in per:
                cells.append('')
            elif before is not None:
                cells.append(f'{_pct(before[name][s], 1)} -> {_pct(per[s])}')
            else:
                cells.append(_pct(per[s]))
        rows.append([name] + cells)
    return _table(['recording'] + sigs, rows)


def misfit_rows(misfit: dict, before: dict | None = None) -> list[list[str]]:
    """Per recording and signal: the residual rms in SI units (and in display units), the
    noise level, their ratio, and the largest residual."""
    rows = []
    for name, per in misfit.items():
        for s, m in per.items():
            k, unit = DISPLAY.get(s, (1.0, ''))
            cells = [name, s, f'{m["rms"]:.4g} {SI_UNITS.get(s, "")} ({m["rms"] * k:.3g} '
                     f'{unit})', f'{m["noise"] * k:.3g} {unit}', f'{m["ratio"]:.2f}',
                     f'{m["max_abs"] * k:.3g} {unit}']
            if before is not None:
                b = before[name][s]
                cells.insert(2, f'{b["rms"]:.4g} {SI_UNITS.get(s, "")}')
            rows.append(cells)
    return rows


def misfit_table(misfit: dict, before: dict | None = None) -> str:
    head = ['recording', 'signal', 'rms residual', 'noise', 'rms / noise', 'max |residual|']
    if before is not None:
        head.insert(2, 'rms before')
    return _table(head, misfit_rows(misfit, before))


def refuse_foreign_report(out: Path) -> None:
    """A report folder that holds the user's own ``result.json`` or ``report.md`` (not a
    calibration's) is refused, before anything is written."""
    try:
        files.refuse_foreign(out / 'result.json', f'"schema": "{SCHEMA}"', 'calibration result')
        files.refuse_foreign(out / 'report.md', '# Calibration', 'calibration report')
    except files.WriteError as exc:
        raise CalibrationError(exc.lines) from None


def write_calibration_report(cal, out: Path, *, plots: bool = True) -> Path:
    """``result.json``, ``report.md`` and the figures of a calibration into ``out``."""
    out = Path(out)
    refuse_foreign_report(out)
    write_text(out / 'result.json', json.dumps(cal.to_dict(), indent=2), 'result')
    figs = []
    if plots:
        for k, (e, a, b) in enumerate(zip(cal.experiments, cal.predictions,
                                           cal.predictions_before)):
            figs.append(plot_comparison(e, a, out / f'compare_{k + 1}_{_safe(e.name)}.png', b))
        figs.append(plot_correlation(cal.free, cal.correlation, out / 'correlation.png'))
    rows = []
    for p in cal.estimates:
        rel = 100 * p.relative_stderr
        rows.append([p.name, f'{p.initial:.6g}', f'{p.value:.6g}',
                     f'{p.stderr:.3g} ({rel:.2g} %)' if math.isfinite(rel) else '-',
                     f'[{p.ci95[0]:.6g}, {p.ci95[1]:.6g}]',
                     'held' if p.held else 'yes' if p.well_determined else '**no**',
                     p.on_bound or '', p.prior or ''])
    md = ['# Calibration', '', f'Recordings: {", ".join(cal.sources)}', '',
          f'Method: {cal.method}; {cal.n_simulations} simulated runs, {cal.wall_time:.1f} s.',
          *([] if cal.fidelity == 'fine' else ['', f'Model fitted: {cal.fidelity}.']),
          '', '## Parameters', '',
          _table(['parameter', 'start', 'calibrated', 'standard error', '95 % interval',
                  'well determined', 'bound', 'prior'], rows), '']
    for p in cal.estimates:
        if p.reason:
            md.append(f'- {p.name}: {p.reason}')
    if cal.tied:
        md += ['', 'Tied (moved with the free ones): ' + ', '.join(
            f'{n} = {v:.6g}' for n, v in cal.tied.items()), '']
    md += ['', '## Identifiability', '',
           'Singular values of the scaled sensitivity matrix (relative sensitivities, noise-'
           'weighted, delays projected out): '
           + ', '.join(f'{v:.3g}' for v in cal.singular_values), '']
    for u in cal.weak:
        md.append(f'- **Weak direction** ({100 * u["relative_stderr"]:.2g} % standard error): '
                  f'{", ".join(u["parameters"])}; determined: {u["determined_combination"]}; '
                  f'separated by: {", ".join(u.get("separated_by") or []) or "-"}')
    for u in cal.held:
        md.append(f'- **Held** (singular): {", ".join(u["parameters"])}; determined: '
                  f'{u["determined_combination"]}')
    md += ['', '## Misfit per recording and signal', '',
           "The residual (measured - model) after calibration, beside each signal's noise "
           'level: a ratio near 1 is a fit to the noise; above 1.5 the model leaves out '
           'something the data have.', '', misfit_table(cal.misfit), '',
           *_missing_section(cal),
           '## Fit per recording and signal (%, start -> calibrated)', '',
           fit_table(cal.fit, cal.fit_before), '',
           f'{NOT_MEANINGFUL}: the signal moves less than a few times its noise in that '
           'recording, so a fit % says nothing there (the misfit table does).', '',
           '## Measurement delays [ms]', '',
           'Each measured signal against the recorded current (negative: it leads the '
           f'current). {(cal.timing[:1].upper() + cal.timing[1:] + ".") if cal.timing else ""}',
           '',
           _table(['recording'] + sorted({s for v in cal.delays.values() for s in v}),
                  [[n] + [f'{1e3 * v[s]:.2f}' if s in v else '' for s in
                          sorted({s for v in cal.delays.values() for s in v})]
                   for n, v in cal.delays.items()]), '']
    if cal.flags:
        md += ['## Flags', ''] + [f'- {f}' for f in cal.flags] + ['']
    if cal.notes:
        md += ['## Notes', ''] + [f'- {n}' for n in cal.notes] + ['']
    if cal.provenance:
        md += provenance.markdown(cal.provenance)
    if figs:
        md += ['## Figures', ''] + [f'![{f.stem}]({f.name})' for f in figs]
    return write_text(out / 'report.md', '\n'.join(md) + '\n', 'report')


def _missing_section(cal) -> list[str]:
    """What the model may lack (:mod:`.lacks`), when the misfit says it lacks something."""
    if not cal.missing:
        return []
    return ['## What the model may lack', '',
            'Signals are not fitted to their noise. Each parameter left fixed was tried as if '
            'freed alone (a score test at the solution, the free parameters and delays moving '
            'with it); these would explain the most:', '',
            *[f'{k + 1}. {c["text"]}' for k, c in enumerate(cal.missing)], '',
            'Free the first (with --free) and calibrate again; an effect at zero starts from '
            'the value the data suggest.', '']


def validation_dict(val: dict, params_file: str, before_file: str | None = None,
                    prov: dict | None = None) -> dict:
    """The JSON form of a validation (``validation.json``, ``validate --json``)."""
    data = {'params': params_file, 'fit_percent': val['fit'], 'misfit': val['misfit'],
            'delays_s': val['delays']}
    if before_file:
        data.update(before=before_file, fit_percent_before=val['fit_before'],
                    misfit_before=val['misfit_before'])
    if prov:
        data['provenance'] = prov
    return data


def write_validation_report(val: dict, out: Path, params_file: str,
                            before_file: str | None = None, *, plots: bool = True,
                            prov: dict | None = None) -> Path:
    """``validation.json``, ``validation.md`` and the overlays of :func:`..validate`."""
    out = Path(out)
    data = validation_dict(val, params_file, before_file, prov)
    write_text(out / 'validation.json', json.dumps(data, indent=2), 'validation result')
    figs = []
    if plots:
        for k, e in enumerate(val['experiments']):
            b = val['predictions_before'][k] if before_file else None
            figs.append(plot_comparison(e, val['predictions'][k],
                                        out / f'validate_{k + 1}_{_safe(e.name)}.png', b,
                                        title=f'{e.name}: {params_file}',
                                        labels=(f'model, {before_file}',
                                                f'model, {params_file}')))
    md = ['# Validation', '', f'Params file: {params_file}'
          + (f' (before: {before_file})' if before_file else ''), '',
          '## Residual per recording and signal', '',
          misfit_table(val['misfit'], val.get('misfit_before') if before_file else None), '',
          '## Fit %', '', fit_table(val['fit'], val.get('fit_before') if before_file else None),
          '']
    if prov:
        md += provenance.markdown(prov)
    md += [f'![{f.stem}]({f.name})' for f in figs]
    return write_text(out / 'validation.md', '\n'.join(md) + '\n', 'validation report')
