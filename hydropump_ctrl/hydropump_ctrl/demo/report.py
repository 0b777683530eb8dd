"""The demo report: the tables (text and HTML), the self-contained HTML page, ``summary.json``.

Numbers come in SI from the fit (:class:`~hydropump_ctrl.ident.Identification`), the plant's
own answer (:func:`.campaign.plant_truth`) and the closed-loop figures
(:func:`.campaign.loop_figures`); milliseconds, percent and bar appear only here, in text.
The paper's figures are :data:`hydropump_ctrl.ident.PAPER`.
"""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

from hydropump_sim.files import write_text

from .. import pages
from ..ident import PAPER

# ---- tables ---------------------------------------------------------------------------------

def identification_rows(ident, truth: dict, paper_fit=None) -> list[list[str]]:
    """The paper, this run's pooled fit (robust, and the paper's Nelder-Mead if given) and
    the plant's own answer: G0, tau, t_d as text."""
    def pm(m, s, k=1.0, f='.1f'):
        return f'{m * k:{f}} ± {s * k:{f}}'

    def run_row(fit, how):
        p = fit.pooled
        return [f'this run, {how} ({len(fit.sets)} sets, mean ± std)',
                pm(p.mean['G0'], p.std['G0'], 1, '.2f'), pm(p.mean['tau'], p.std['tau'], 1e3),
                pm(p.mean['td'], p.std['td'], 1e3)]
    twin = f'{truth["tau"] * 1e3:.1f}'
    if 'tau_std' in truth:
        twin += f' ± {truth["tau_std"] * 1e3:.1f}'
    return [
        ['paper (9 sets)', pm(*PAPER['G0']), pm(*PAPER['tau'], 1e3), pm(*PAPER['td'], 1e3)],
        run_row(ident, 'robust fit'),
        *([run_row(paper_fit, "the paper's Nelder-Mead")] if paper_fit is not None else []),
        ['plant: fine model + bench dither, no sensors', f'{truth["G0"]:.2f}', twin,
         f'{truth["td_plant"] * 1e3:.2f}'],
        ['plant: configured sensor delay', '', '', f'{truth["td_configured"] * 1e3:.1f}'],
        ['plant: fine model 63 % time, no dither', '', f'{truth["tau_nominal"] * 1e3:.1f}',
         ''],
    ]


def loop_table(results: dict) -> tuple[list[str], list[list[str]]]:
    """Head and rows of the closed-loop figures, one row a run (empty where not defined)."""
    head = ['run', 'rise [s]', 'overshoot [%]', 'settling [s]', 'peak dev. [bar]',
            'recovery [s]', 'IAE']
    rows = []
    for name, f in results.items():
        rows.append([name, _fmt(f.get('rise_s')), _fmt(f.get('overshoot_pct')),
                     _fmt(f.get('settling_s')), _fmt(f.get('peak_bar')),
                     _fmt(f.get('recovery_s')), f'{f["iae"]:.4g} {f["iae_unit"]}'])
    return head, rows


def _fmt(v) -> str:
    """A figure in three digits; ``''`` where it does not apply, ``never`` for infinity."""
    return '' if v is None else ('never' if v == math.inf else f'{v:.3g}')


def text_table(head, rows) -> str:
    """Columns padded to their widest cell, a rule under the head (for the terminal)."""
    cols = [head] + rows
    w = [max(len(str(r[i])) for r in cols) for i in range(len(head))]

    def line(r):
        return '  '.join(str(x).ljust(w[i]) for i, x in enumerate(r))
    return '\n'.join([line(head), line(['-' * x for x in w])] + [line(r) for r in rows])


CALIBRATION_HEAD = ['parameter', 'start', 'calibrated', 'plant', 'error']


def report_sections(ident, truth, rows, loops, modal, analysis_text, hyst, walls, fit_paths,
                    figs, bag_dir, calibration=None, duty=None, dig=None
                    ) -> list[tuple[str, str]]:
    """The sections of the page, ``(title, HTML body)``: identification, Bode, steps,
    hysteresis, closed loop, model analysis and the run's wall times.

    ``rows`` are :func:`identification_rows`, ``loops`` the closed-loop figures, ``modal`` and
    ``analysis_text`` the model analysis (its modal part and all of it), ``hyst`` the gaps of
    :func:`.plots.plot_hysteresis`, ``fit_paths`` what :func:`~hydropump_ctrl.ident.write_report`
    wrote, ``figs`` the folder of the PNG figures, ``calibration`` the rows and the figure of
    :func:`.campaign.bench_calibration` (or ``None``), ``duty`` the Fig. 1 duty cycle's
    figures (:func:`.fig1.duty_figures` by run) and its PNG files (or ``None``), ``dig``
    the excavator cycle's (:func:`.excavator.cycle_figures`) and its PNG file (or ``None``).
    """
    head, lrows = loop_table(loops)
    return [
        ('Identification (section V, eq. 19): the paper against this run',
         pages.table(['', 'G0 [% per range]', 'tau [ms]', 't_d [ms]'], rows)
         + "<p>The paper's protocol: nine growing-flow current staircases at the nominal "
           'operating point (120 bar, aperture 0.5), differing in levels (centred on 45, 50 '
           'and 55 % of displacement), step sizes (5, 10 and 15 %) and noise seeds, through '
           'the real nodes (simulator with the bench profile of config/bench.yaml, controller '
           "in open loop, recorder), fitted with the robust method and with the paper's "
           'Nelder-Mead. The plant rows show what a perfect fit should find: the fine model '
           'under the same dither without sensors, and the configured delay.</p>'
           "<p>The spread between sets is mostly the plant's: the growing-flow time "
           'constant is S_a (1 + K_c/K_a) / (mu_a sqrt(P_a)) (eq. 14), and the actuator '
           'pressure P_a falls as the plate strokes out, so a staircase centred lower or '
           'with larger steps sees another tau. The noise-free twin of the nine sets shows '
           "that part alone (its ± above); the sensors' noise adds the rest. The delay is "
           "one configured 55 ms for every set here; the paper's ±5.5 ms suggests its "
           'acquisition chain varied between sets, which this bench does not model.</p>'
         + _img(Path(fit_paths['fig5'])) + _img(Path(fit_paths['fig6']))),
        *([('The bench plant calibrated from the same bags (hydropump calibrate)',
            "<p>The fine model's parameters that growing-flow staircases determine, fitted to "
            'the nine bags (every recorded signal, one delay each) from a start 20 % off, '
            'against the plant the simulator ran.</p>'
            + pages.table(CALIBRATION_HEAD, calibration[0]) + _img(calibration[1]))]
          if calibration else []),
        ('Bode: fine vs simplified vs identified', _img(figs / 'bode.png')),
        *([('Beyond the paper: the operating map and the dither sensitivity',
            '<p>eq. 19 of the noise-free fine model over load pressure and displacement '
            '(2 % steps, no dither), and the growing-flow time constant against dither '
            "amplitude and frequency around the spool's 153.8 Hz corner (10 % steps at the "
            "nominal point). A dither below the corner rectifies at the pilot valve's "
            'kink and shortens tau by about 2 ms per mA; the spool filters it out above.</p>'
            + _img(figs / 'operating_map.png') + _img(figs / 'dither_sensitivity.png'))]
          if (figs / 'operating_map.png').is_file() else []),
        ('Step responses up and down', _img(figs / 'steps.png')),
        ('Current-flow hysteresis with friction', pages.table(
            ['model', 'settled q_l, from below minus from above, at 50 % [% FS]'],
            [[k, f'{v:.3f}'] for k, v in hyst.items()]) + _img(figs / 'hysteresis.png')),
        ('EMC against PI (closed loop through the nodes)', pages.table(head, lrows)
         + _img(figs / 'emc_vs_pi.png')),
        *([('The circuit of Fig. 1: load sensing against the highest load, through the nodes',
            _fig1_text(duty))] if duty else []),
        *([('An excavator: one dig, lift, swing and dump cycle, through the nodes',
            _excavator_text(dig))] if dig else []),
        ('Model analysis (section IV)', f'<pre>{html.escape(modal)}</pre>'
         f'<details><summary>full analysis</summary><pre>{html.escape(analysis_text)}'
         f'</pre></details>'),
        ('Run', pages.table(STAGE_HEAD, stage_rows(walls))
         + f'<p>Bags (rosbag2, MCAP): <code>{html.escape(str(bag_dir.resolve()))}</code>; '
           '<code>ros2 bag info</code> and <code>ros2 bag play</code> read them.</p>'),
    ]


def _excavator_text(dig) -> str:
    from . import excavator as m
    f, png = dig
    return (
        '<p>config/circuits/excavator.yaml: a 15-20 t excavator on one load-sensing pump '
        '(420 L/min, cut-off 300 bar, main relief 330 bar, load-sensing relief 285 bar); boom, '
        'arm and bucket cylinders and the swing motor on post-compensated 4/3 sections (flow '
        'sharing), counterbalance valves holding the boom and the arm, brake valves and '
        'cross-port reliefs on the swing, hoses to the boom, a reduced pilot supply with its '
        f'accumulator. One cycle of {m.DURATION:g} s through the simulator (the bench '
        'sensors, published at 200 Hz), the controller (config/controller_excavator.yaml: '
        f'EMC, margin {m.MARGIN / 1e5:g} bar) and the recorder: '
        + '; '.join(f'{a:g} s {n}' for n, a, _ in m.PHASES) + '.</p>'
        "<p>Speed against demand: each actuator's mean speed from "
        f'{m.SETTLE:g} s after its lever last moved, against what its lever asks: its '
        "valve's meter-in edge at that opening with the metering pressure the margin leaves "
        '(margin less the compensator spring), over the area it fills. Below 100 %: the '
        'pump saturated and every section shares what it gives alike (flow sharing), or a '
        'load that accelerates (the swing, torque-limited by its cross-port relief) or '
        'stops on its end (the bucket at breakout).</p>'
        + pages.table(m.SPEED_HEAD, m.speed_rows(f))
        + f'<p>Margin: mean |P_l - P_LS - {m.MARGIN / 1e5:g} bar| '
          f'{f["margin_error"] / 1e5:.2f} bar, within 2 bar {100 * f["margin_held"]:.0f} % '
          f'of the time the pump can hold it ({100 * f["margin_samples"]:.0f} % of the '
          'cycle: not saturated, under its cut-off, settled). Pressure peaks: pump '
          f'{f["p_peak"] / 1e5:.0f} bar (20 ms mean); chambers '
        + ', '.join(f'{n} {p / 1e5:.0f}' for n, p in f['chamber_peak'].items())
        + " bar (port reliefs 350 bar, the swing's cross-port 280 bar).</p>"
          "<p>The energy account over the cycle, from the simulator's energy/* topics "
          "(every component's own terms, summed): what the pump supplied, what reached the "
          'loads (negative when they drive: a boom let down), what is stored (kinetic, '
          'oil springs, gas), and where the rest was lost; unaccounted: what the sum leaves '
          'over the energy supplied.</p>'
        + pages.table(m.ENERGY_HEAD, [m.energy_row(f)]) + _img(png))


def _fig1_text(duty) -> str:
    from . import fig1
    results, pngs = duty
    settled = fig1.SETTLED[0][1] - fig1.SETTLED[0][0]
    sat, before = fig1.SATURATED, fig1.BEFORE
    return (
        '<p>The circuit of config/circuits/fig1.yaml: the pump and its relief valve (250 bar) '
        'feeding a priority steering cylinder behind a priority valve, and a boom cylinder '
        'and a motor on demand with pressure compensators before their valves (pre) or '
        'after them (post, flow sharing); a shuttle network senses the highest load. One '
        f'operator cycle of {fig1.DURATION:g} s, through the simulator (the bench sensors, no '
        'dither), the controller (config/controller_fig1.yaml, margin mode against the '
        f'load-sensing pressure, {fig1.MARGIN / 1e5:g} bar) and the recorder, after a '
        f'{fig1.PREROLL:g} s settling run: '
        + '; '.join(f'{a:g} s {n}' for n, a, _ in fig1.PHASES) + '. The hydromechanical '
        'rows put the classic load-sensing compensator on the pump instead of the solenoid '
        f'(its spring at the same {fig1.MARGIN / 1e5:g} bar).</p>'
        f'<p>Margin error: mean |P_l - P_LS - {fig1.MARGIN / 1e5:g} bar| over the last '
        f'{settled:g} s of each phase the pump can serve (20 ms means); worst: the largest '
        "20 ms mean outside the saturated phase. Delivered / demanded: each load's flow "
        f'over {sat[0]:g}-{sat[1]:g} s (the demand beyond the pump) over the flow it took '
        f'unsaturated over {before[0]:g}-{before[1]:g} s, scaled by its command. Throttling '
        "loss: P_l Q_p - sum P_i Q_i over the cycle (the relief's included); to the loads: "
        "the loads' share of the pump's hydraulic energy. Flows are moved back by the flow "
        "sensors' configured delay to line up with the pressures.</p>"
        + pages.table(fig1.TABLE_HEAD, fig1.table_rows(results))
        + ''.join(_img(p) for p in pngs))


STAGE_HEAD = ['stage', 'simulated [s]', 'wall [s]', 'orchestration overhead [% of wall]']


def stage_rows(stages: dict) -> list[list[str]]:
    """Rows of the stage table from ``{stage: {'simulated_s', 'wall_s', 'overhead_s'}}``:
    the overhead is the graph's wall time not spent stepping (start-up, parameter sets,
    service calls between experiments)."""
    rows = []
    for name, st in stages.items():
        wall = st['wall_s']
        share = f'{100.0 * st["overhead_s"] / wall:.0f}' if wall > 0 else ''
        rows.append([name, f'{st["simulated_s"]:g}' if st['simulated_s'] else '',
                     f'{wall:.1f}', share])
    return rows


def summary(ident, truth: dict, loops: dict, walls: dict, duty: dict | None = None,
            dig: dict | None = None) -> dict:
    """The run's numbers for ``summary.json`` (SI; the closed-loop traces left out; the Fig. 1
    duty cycle's figures under ``fig1``, the excavator's under ``excavator``)."""
    p = ident.pooled
    return {'identification': {'G0': p.mean['G0'], 'G0_std': p.std['G0'],
                               'tau': p.mean['tau'], 'tau_std': p.std['tau'],
                               'td': p.mean['td'], 'td_std': p.std['td'],
                               'sets': len(ident.sets)},
            'plant': truth,
            'closed_loop': {k: {kk: vv for kk, vv in v.items() if kk != 'y'}
                            for k, v in loops.items()},
            'wall_time_s': {k: v['wall_s'] for k, v in walls.items()}, 'stages': walls,
            **({'fig1': duty} if duty else {}), **({'excavator': dig} if dig else {})}


# ---- the page -------------------------------------------------------------------------------

# What each figure of the page shows, by its file's stem (or the stem's start).
CAPTIONS = {
    'fig5': "Fig. 5: each set's flow with the identified eq. 19 and the simplified model's "
            '(the first set whole, the others around their largest up-step)',
    'fig6': 'Fig. 6: the estimation error of every set (its envelope over the record)',
    'compare_': 'A calibration bag: measured, the model from the start (dashed) and '
                'calibrated, and the residuals',
    'bode': 'Current to line flow: the fine model, the simplified one (section IV) and the '
            'identified eq. 19',
    'operating_map': 'eq. 19 of the noise-free fine model over load pressure and '
                     'displacement',
    'dither_sensitivity': 'The growing-flow time constant against dither amplitude and '
                          'frequency',
    'steps': 'Step responses up and down: the fine and the simplified model',
    'hysteresis': 'Current-flow hysteresis with and without Coulomb friction',
    'emc_vs_pi': 'EMC against PI through the nodes: the flow step, the aperture step and the '
                 'margin step',
    'fig1_pre': 'Fig. 1 with pre-compensated sections, under EMC and under the '
                'hydromechanical compensator: pressures, flows, commands',
    'fig1_post': 'Fig. 1 with post-compensated sections (flow sharing), under EMC and under '
                 'the hydromechanical compensator: pressures, flows, commands',
    'excavator': "The excavator's cycle: pressures, actuator speeds against demand, the "
                 'energy account',
}


def caption(path: Path) -> str:
    """What a figure shows (:data:`CAPTIONS`), else its file's name."""
    stem = path.stem
    key = max((k for k in CAPTIONS if stem == k or stem.startswith(k)), key=len, default=None)
    return CAPTIONS[key] if key else path.name


def _img(path: Path) -> str:
    """A PNG file inlined as a figure (the page stands on its own), captioned with what it
    shows."""
    from PIL import Image

    from hydropump_sim.files import AXES_KEY
    data = base64.b64encode(path.read_bytes()).decode()
    with Image.open(path) as im:
        axes = getattr(im, 'text', {}).get(AXES_KEY)
    where = f' data-axes="{html.escape(axes)}"' if axes else ''
    return (f'<figure><img src="data:image/png;base64,{data}" alt="{html.escape(path.name)}"'
            f'{where}><figcaption>{html.escape(caption(path))}</figcaption></figure>')


def write_html(run_dir: Path, sections: list[tuple[str, str]]) -> Path:
    """Write ``report.html`` in ``run_dir`` from ``(title, HTML body)`` sections (whole or not
    at all)."""
    css = ('body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}'
           'table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;'
           'padding:3px 8px;text-align:right}th{background:#eee}img{max-width:100%}'
           'pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:12px}')
    parts = ['<h1>hydropump: the paper end to end</h1>',
             *(pages.section(title, body) for title, body in sections)]
    return write_text(run_dir / 'report.html', pages.page('hydropump report', css, parts),
                      'report')
