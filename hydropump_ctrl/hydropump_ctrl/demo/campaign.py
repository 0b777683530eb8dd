"""The demo campaign (``hydropump-demo``): its experiments and what is made of their bags.

The ROS package runs each :class:`Experiment` through the node graph into a bag; everything
before and after that is here, pure:

- :func:`identification_experiments`, :func:`closed_loop_experiments` - the runs (node
  parameters, recorded topics, the schedule of changes);
- :func:`plant_truth` - what a perfect fit should find: each identification run replayed on a
  noise-free, delay-free twin of the plant and fitted;
- :func:`loop_figures` - rise, overshoot, settling, peak and IAE of a closed-loop run from
  its :class:`~hydropump_ctrl.ident.Recording`;
- :func:`analyse_campaign` - stages 2, 4 and 5: the fit, the model analysis and the report
  (figures in :mod:`.plots`, tables and the HTML page in :mod:`.report`);
- :func:`stage` - a failure (a full disk, a node that exits) named by the stage it ended:
  :class:`StageError`, one line.

Every file written here is written whole or not at all (:mod:`hydropump_sim.files`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
import json
from pathlib import Path
import time

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.files import write_text
from hydropump_sim.measure import LOAD_FLOW_SIGNAL, suite_topics
from hydropump_sim.metrics import moving_average, step_figures
from hydropump_sim.model import pump_flow
from hydropump_sim.params import Params
from hydropump_sim.scaling import current_for_displacement
from hydropump_sim.sensors import SensorProfile

from .. import provenance
from ..experiment import EXCITATION_BASE, Experiment, operating_point  # noqa: F401
from ..experiments.closed_loop import disturbance_figures, trim_current
from ..ident import Recording

# What the closed-loop experiments record: every topic of the suite (measure.suite_topics);
# the identification leaves out the load's flow and the controller's state, which no fit of
# eq. 19 reads.
LOOP_TOPICS = suite_topics()
IDENT_TOPICS = [t for t in LOOP_TOPICS if t not in (LOAD_FLOW_SIGNAL, 'controller/state')]
STAGES = ('identification', 'fitting', 'closed loop', 'model analysis', 'report')
#: The stage names of a graph that ran beside the campaign's (the Fig. 1 duty cycle).
BESIDE = 'Fig. 1 (beside): '
BESIDE_EXCAVATOR = 'excavator (beside): '


# ---- a stage that fails ---------------------------------------------------------------------

class StageError(HydropumpError):
    """A stage of the demo failed (a full disk, a node that exited): one line naming the
    stage and why. What earlier stages wrote (the bags) is left as it is."""


def one_line(exc: HydropumpError) -> str:
    """A user-facing error in one line: its problems joined, with its source."""
    if exc.head is not None:
        return ' '.join(str(exc).split())
    text = '; '.join(exc.lines)
    return f'{exc.source}: {text}' if exc.source else text


@contextmanager
def stage(name: str) -> Iterator[None]:
    """Run a stage of the demo: a user-facing error (:class:`HydropumpError`: a file that
    could not be written, a node that failed) or an ``OSError`` (a folder that could not be
    made) inside becomes a :class:`StageError` naming ``name``, in one line."""
    try:
        yield
    except StageError:
        raise  # named by the stage it came from (a worker's graph)
    except HydropumpError as exc:
        raise StageError(f'the {name} stage failed: {one_line(exc)}') from None
    except OSError as exc:
        where = f'{exc.filename}: ' if exc.filename else ''
        raise StageError(f'the {name} stage failed: {where}{exc.strerror or exc}') from None


# ---- experiments ----------------------------------------------------------------------------

#: The nine identification sets: (step size, centre) of a growing-flow staircase in % of
#: displacement, at the nominal operating point (the paper: nine data sets of current steps
#: in the regulating range, growing flow only). The first three share the centre.
SETS = [(step, centre) for centre in (50.0, 45.0, 55.0) for step in (10.0, 5.0, 15.0)]


def identification_experiments(params: Params, n: int = 9, dwell: float = 1.0,
                               levels: int = 4) -> list[Experiment]:
    """The paper's protocol: ``n`` growing-flow staircases of ``levels`` stairs at the
    nominal load pressure and aperture, differing in levels, step size and noise seed
    (:data:`SETS`)."""
    out = []
    for i in range(n):
        step, centre = SETS[i % len(SETS)]
        lo = centre - step * (levels - 1) / 2.0
        hi = lo + step * (levels - 1)
        out.append(Experiment(
            name=f'ident_{i + 1}',
            label=f'staircase {lo:g} -> {hi:g} % in {step:g} % steps, seed {i + 1}',
            duration=levels * dwell,
            sim=operating_point(params, current_for_displacement(params, lo / 100.0), i + 1),
            # Growing flow only: direction up, and no repeat (a staircase that starts again
            # steps back down to its first level).
            ctrl={'controller.mode': 'open_loop', 'excitation.direction': 'up',
                  'excitation.unit': 'percent', 'excitation.levels_min': lo,
                  'excitation.levels_max': hi, 'excitation.n_levels': levels,
                  'excitation.dwell': dwell, 'excitation.repeat': False,
                  'excitation.signal': 'staircase'},
            topics=IDENT_TOPICS, ctrl_first=dict(EXCITATION_BASE)))
    return out


def closed_loop_experiments(params: Params, algorithms: Sequence[str] = ('emc', 'pi'),
                            t_step: float = 0.5, duration: float = 1.2,
                            preroll: float = 0.5) -> list[Experiment]:
    """The three judged scenarios for each algorithm: a 30 -> 70 % flow step, a load
    aperture step 0.5 -> 0.4 at a 25 bar margin, and a margin set-point step 20 -> 25 bar.
    Each starts settled: the plant at the equilibrium of its initial reference (trimmed), the
    controller restarting bumplessly from it, and ``preroll`` seconds, not recorded, for the
    loop to settle on the reference (the trim knows neither the dither's static offset nor
    the embedded model's), so that EMC and PI are compared on the step alone."""
    q30, q70 = 0.3 * params.Q_max, 0.7 * params.Q_max
    out = []
    for alg in algorithms:
        base = {'controller.algorithm': alg}
        out += [
            Experiment(f'{alg}_flow_step', f'{alg.upper()}: flow step 30 -> 70 %', duration,
                       operating_point(params, trim_current(params, flow=q30)),
                       {**base, 'controller.mode': 'flow', 'reference.flow': q30},
                       LOOP_TOPICS, [(t_step, 'controller', {'reference.flow': q70})],
                       preroll=preroll),
            Experiment(f'{alg}_aperture_step', f'{alg.upper()}: aperture 0.5 -> 0.4 at 25 bar',
                       duration, operating_point(params, trim_current(params, margin=2.5e6),
                                                  **{'line.xi_u': 0.5}),
                       {**base, 'controller.mode': 'margin', 'reference.margin': 2.5e6},
                       LOOP_TOPICS, [(t_step, 'simulator', {'line.xi_u': 0.4})],
                       preroll=preroll),
            Experiment(f'{alg}_margin_step', f'{alg.upper()}: margin 20 -> 25 bar', duration,
                       operating_point(params, trim_current(params, margin=2.0e6)),
                       {**base, 'controller.mode': 'margin', 'reference.margin': 2.0e6},
                       LOOP_TOPICS, [(t_step, 'controller', {'reference.margin': 2.5e6})],
                       preroll=preroll),
        ]
    return out


# ---- the plant's own answer -----------------------------------------------------------------

def plant_truth(params: Params, profile: SensorProfile, recordings: Sequence[Recording]
                ) -> dict:
    """The plant's own eq. 19 under the bench conditions: each experiment replayed on the fine
    model with the commanded current, dither on, no sensor delay or noise, and fitted.

    Parameters
    ----------
    params : Params
        Nominal plant; the profile's ``plant_overrides`` (the dither) are applied.
    profile : SensorProfile
        The bench profile of the runs: its dither and its configured line-flow delay.
    recordings : sequence of Recording
        The runs (e.g. an identification's ``recordings``, one per bag): their commanded
        current.

    Returns
    -------
    dict
        ``G0``, ``tau`` (and ``tau_std``, between the runs), ``td_plant`` of the twin's fit,
        ``td_configured`` (the sensor delay) and ``tau_nominal`` (:func:`nominal_tau`).
    """
    from hydropump_sim import held, simulate

    from ..ident import fit_recordings
    plant = params.replace(profile.plant_overrides or {})
    recs = []
    for rec in recordings:
        # The command starts with the controller's first update; time from there, in the
        # grid's whole nanoseconds.
        ok = np.isfinite(rec['solenoid_current_cmd'])
        ns = np.round(rec.t[ok] * 1e9).astype(np.int64)
        t, u = (ns - ns[0]) * 1e-9, rec['solenoid_current_cmd'][ok]
        command = held(t, u)
        res = simulate(plant, float(t[-1]) + 1e-3, command, dt_out=1e-3)
        recs.append(Recording(res.t, {'solenoid_current': command(res.t), 'line_flow': res.q_l},
                              name=f'{rec.name} twin'))
    twin = fit_recordings(recs, params=params, joint=False)
    return {'G0': twin.G0, 'tau': twin.tau, 'tau_std': twin.pooled.std['tau'],
            'td_plant': twin.td,
            'td_configured': profile.spec('line_flow').delay,
            'tau_nominal': nominal_tau(params)}


def nominal_tau(params: Params) -> float:
    """63 % time [s] of the fine model's own 40 -> 60 % up-step, no dither (100.4 ms in
    docs/reference.md)."""
    from hydropump_sim import equilibrium, simulate
    I0, I1 = current_for_displacement(params, [0.4, 0.6])
    r = simulate(params, 1.2, lambda t: np.where(t < 0.01, I0, I1), dt_out=1e-4)
    return step_figures(r.t, r.q_l, 0.01, final=equilibrium(params, I1).q_l).t63


# ---- the bench plant from the campaign's bags ----------------------------------------------

#: What growing-flow staircases determine (docs/experiment_design.md): the actuator orifice and
#: pressure of eq. 14's time constant, and the load law.
CALIBRATED = ('actuator.mu_a', 'actuator.P_a_bar', 'line.mu_u')


def bench_calibration(params: Params, profile: SensorProfile, recordings: Sequence[Recording],
                      out: Path, start_factor: float = 1.2) -> tuple[list[list[str]], Path]:
    """Calibrate :data:`CALIBRATED` of the bench plant (``params`` with the profile's
    dither) from the identification bags, from a start ``start_factor`` off; the table rows
    (parameter, start, calibrated, plant, error) and the validation figure of the first bag
    (before and after)."""
    from ..ident.calibrate import calibrate, params_with, write_calibration_report
    plant = params.replace(profile.plant_overrides or {})
    truth = {n: float(plant.flat()[n]) for n in CALIBRATED}
    start = params_with(plant, CALIBRATED, [start_factor * truth[n] for n in CALIBRATED])
    cal = calibrate(recordings, start, CALIBRATED)
    out.mkdir(parents=True, exist_ok=True)
    write_calibration_report(cal, out)
    rows = [[e.name, f'{e.initial:.6g}', f'{e.value:.6g}', f'{truth[e.name]:.6g}',
             f'{100.0 * (e.value / truth[e.name] - 1.0):+.3f} %'] for e in cal.estimates]
    return rows, sorted(out.glob('compare_1_*.png'))[0]


# ---- figures of a closed-loop run -----------------------------------------------------------

def _average(t: np.ndarray, x: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Centred moving average over ``width`` seconds, where a whole window fits."""
    k = max(1, int(round(width / float(np.median(np.diff(t))))))
    y = moving_average(x, k, edges='valid')
    return t[k // 2:k // 2 + y.size], y


def loop_figures(params: Params, exp: Experiment, rec: Recording, t_step: float = 0.5,
                 t0: float = 0.0) -> dict:
    """Figures of one closed-loop run of :func:`closed_loop_experiments`.

    The flow is the pump flow of eq. 8 at the recorded plate position (the true flow, not the
    delayed sensor), averaged over one dither period; the margin ``P_l - P_u`` is measured,
    averaged over 20 ms, as the paper filters the dither.

    Parameters
    ----------
    params : Params
        The plant of the run.
    exp : Experiment
        The run: its mode, reference and events say what was stepped.
    rec : Recording
        The run's bag (:func:`hydropump_ctrl.ident.read_recording`).
    t_step : float
        Time of the step from the experiment's start [s].
    t0 : float
        Simulation time of the experiment's start [s].

    Returns
    -------
    dict
        A reference step: ``rise_s``, ``overshoot_pct``, ``settling_s``; a disturbance:
        ``peak_bar`` and ``recovery_s`` (back within 1 bar of the set-point). Both: ``iae``
        with its ``iae_unit``, the averaged output ``y = (t, value)`` in ``unit``.
    """
    t = rec.t + rec.t0_ns * 1e-9 - t0   # from the experiment's start, as the schedule
    if exp.ctrl['controller.mode'] == 'flow':
        t, y = _average(t, pump_flow(params, rec['actuator_position']),
                        1.0 / params.input.dither_freq)
        y0, y1 = exp.ctrl['reference.flow'], exp.events[0][2]['reference.flow']
        scale, unit, band = 100.0 / params.Q_max, '% FS', 0.02 * abs(y1 - y0)
    else:
        # Absolute pressures in the bag: their difference is the gauge margin.
        t, y = _average(t, rec['line_pressure'] - rec['load_pressure'], 0.02)
        y0 = exp.ctrl['reference.margin']
        y1 = next((v['reference.margin'] for _, _, v in exp.events
                   if 'reference.margin' in v), y0)
        scale, unit, band = 1e-5, 'bar', 0.5e5
    # Settled before the step: the output's mean error over the 0.5 s before it [% of y0]
    # (the pre-roll settled the loop before the record). The window averages out what the
    # sensors' noise does: the pressure noise on the measured margin, and the wander that the
    # flow sensor's noise drives through a flow loop (0.19-0.25 % std of 0.3 s means at 30 %
    # flow under the bench profile, for either law).
    window = 0.5
    pre = (t >= t_step - window) & (t < t_step)
    pre_pct = float(100.0 * abs(np.mean(y[pre]) - y0) / abs(y0)) if pre.any() else np.nan
    sel = t >= t_step - 0.1
    t, y = t[sel], y[sel]
    if y1 != y0:
        f = step_figures(t, y, t_step, initial=y0, final=y1, band_abs=band)
        return {'rise_s': f.rise, 'overshoot_pct': f.overshoot, 'settling_s': f.settling,
                'iae': f.iae * scale, 'iae_unit': f'{unit} s', 'y': (t, y * scale),
                'unit': unit, 'pre_step_error_pct': pre_pct}
    d = disturbance_figures(t, y, t_step, y0, band=1.0e5)
    return {'peak_bar': abs(d.peak) * 1e-5, 'recovery_s': d.recovery, 'iae': d.iae * 1e-5,
            'iae_unit': 'bar s', 'y': (t, y * 1e-5), 'unit': 'bar',
            'pre_step_error_pct': pre_pct}


def stage_times(wall: float, simulated: float = 0.0, overhead: float = 0.0) -> dict:
    """One row of the stage table: wall time, simulated time and orchestration overhead [s]."""
    return {'simulated_s': simulated, 'wall_s': wall, 'overhead_s': overhead}


# ---- after the runs -------------------------------------------------------------------------

@dataclass
class CampaignRun:
    """What the demo ran, as its analysis reads it.

    Attributes
    ----------
    run_dir : Path
        The run folder: ``identification/``, ``figures/``, ``report.html`` and
        ``summary.json`` are written there.
    bag_dir : Path
        The folder of the bags (:meth:`Experiment.bag`).
    params, profile : Params, SensorProfile
        The plant and the bench sensor profile of the runs.
    idents, loops : sequence of Experiment
        The identification and the closed-loop experiments that were run.
    walls : dict
        Times of the stages so far, ``{stage: {'simulated_s', 'wall_s', 'overhead_s'}}``
        (:func:`stage_times`); the analysis adds the others and ``total``.
    started : float
        ``time.perf_counter()`` at the start of the run, for the total.
    starts : dict
        Simulation time [s] each experiment started at, by name (default 0).
    fig1, excavator : sequence of Experiment
        The Fig. 1 duty cycles (:mod:`.fig1`) and the excavator's cycle (:mod:`.excavator`)
        that were run, each judged and drawn in a section of its own.
    prov : dict, optional
        Where the run came from (:func:`..provenance.collect`): in ``summary.json`` and at
        the end of the page.
    """

    run_dir: Path
    bag_dir: Path
    params: Params
    profile: SensorProfile
    idents: Sequence[Experiment]
    loops: Sequence[Experiment]
    walls: dict
    started: float
    starts: dict = field(default_factory=dict)
    fig1: Sequence[Experiment] = ()
    excavator: Sequence[Experiment] = ()
    prov: dict | None = None


def analyse_campaign(run: CampaignRun, echo: Callable[[str], None] = print, pool=None,
                     calibrate: bool = False) -> Path:
    """Stages 2, 4 and 5 of the demo on its bags: fit, model analysis, report.

    ``echo`` takes the progress lines and tables (one string a call); ``pool`` (a
    ``concurrent.futures.Executor``) runs the work that waits for nothing here beside the
    fit (the operating map and dither figures, the plant's twin), else all of it runs in
    turn; ``calibrate`` also calibrates the bench plant from the identification bags
    (:func:`bench_calibration`, about 25 s). Returns the report page.

    Raises
    ------
    StageError
        A stage that failed (a full disk: a file it could not write), named in one line;
        the files of the stages before it are left whole, none is left half-written.
    """
    from .maps import draw_figures
    figs = run.run_dir / 'figures'
    with stage('figures'):
        figs.mkdir(parents=True, exist_ok=True)

    def later(fn, *args):
        # Without a pool, the work runs when its result is asked for, in that stage.
        if pool is None:
            return lambda: fn(*args)
        return pool.submit(fn, *args).result
    maps = later(draw_figures, run.params, figs)
    fitted = _fit_stage(run, echo, later, calibrate)
    duty, dig = _duty_stages(run, echo)
    return _report_stages(run, echo, fitted, duty, dig, maps)


def _fit_stage(run: CampaignRun, echo, later, calibrate: bool) -> dict:
    """Stage 3: eq. 19 on the identification bags (both methods), the plant's own answer,
    the calibration if asked, and the closed-loop figures of the loop bags."""
    from ..ident import fit_bags, fit_recordings, format_table, read_recording, write_report
    from . import report
    params, walls = run.params, run.walls
    t0 = time.perf_counter()
    echo('[3/5 fitting] eq. 19 on the identification bags ...')
    with stage('fitting'):
        ident = fit_bags([exp.bag(run.bag_dir) for exp in run.idents], params=params,
                         progress=None)
        truth = later(plant_truth, params, run.profile, ident.recordings)
        fit_paths = write_report(ident, run.run_dir / 'identification', params=params)
        truth = truth()
        paper_fit = fit_recordings(ident.recordings, params=params, method='paper',
                                   joint=False)
    walls['fitting'] = stage_times(time.perf_counter() - t0)
    calibration = None
    if calibrate:
        t0 = time.perf_counter()
        echo(f'[3/5 fitting] calibration of {", ".join(CALIBRATED)} from the same bags ...')
        with stage('calibration'):
            calibration = bench_calibration(params, run.profile, ident.recordings,
                                            run.run_dir / 'calibration')
        echo(report.text_table(report.CALIBRATION_HEAD, calibration[0]))
        walls['calibration'] = stage_times(time.perf_counter() - t0)
    echo(format_table(ident))
    rows = report.identification_rows(ident, truth, paper_fit)
    echo(report.text_table(['', 'G0 [%/range]', 'tau [ms]', 't_d [ms]'], rows))
    with stage('closed-loop analysis'):
        loops = {exp.name: loop_figures(params, exp, read_recording(exp.bag(run.bag_dir)),
                                        t0=run.starts.get(exp.name, 0.0)) for exp in run.loops}
    echo(report.text_table(*report.loop_table(loops)))
    return {'ident': ident, 'truth': truth, 'rows': rows, 'fit_paths': fit_paths,
            'calibration': calibration, 'loops': loops}


def _duty_stages(run: CampaignRun, echo) -> tuple:
    """The Fig. 1 and excavator cycles judged from their bags: ``(duty, dig)``, each
    ``None`` when it was not run, else its figures with what draws them."""
    from . import report
    figs = run.run_dir / 'figures'
    duty = dig = None
    if run.fig1:
        from hydropump_sim.circuit import default_circuit_path, load_circuit

        from . import fig1 as cycle
        with stage('Fig. 1 analysis'):
            overlap = cycle.overlaps(load_circuit(default_circuit_path().with_name('fig1.yaml'),
                                                  compile=False))
            runs, results = cycle.analyse({e.name: e.bag(run.bag_dir) for e in run.fig1},
                                          run.starts, run.profile, run.params.fluid.p_atm,
                                          run.params.relief.p_crack, overlap)
        echo(report.text_table(cycle.TABLE_HEAD, cycle.table_rows(results)))
        kinds = sorted({e.name.rsplit('_', 1)[1] for e in run.fig1}, reverse=True)
        paths = [figs / f'fig1_{kind}.png' for kind in kinds]

        def draw_fig1():
            for kind, path in zip(kinds, paths):
                cycle.plot(runs, kind, path, overlap)
        duty = (results, paths, draw_fig1)
    if run.excavator:
        from . import excavator as machine
        exp = run.excavator[0]
        with stage('excavator analysis'):
            circuit, dig_run, dig_figures = machine.analyse(
                exp.bag(run.bag_dir), run.starts.get(exp.name, 0.0), run.profile)
        echo(report.text_table(machine.SPEED_HEAD, machine.speed_rows(dig_figures)))
        echo(report.text_table(machine.ENERGY_HEAD, [machine.energy_row(dig_figures)]))
        path = figs / 'excavator.png'
        dig = (dig_figures, path, lambda: machine.plot(dig_run, circuit, path))
    return duty, dig


def _report_stages(run: CampaignRun, echo, fitted: dict, duty, dig, maps) -> Path:
    """Stages 4 and 5: the modes and the singular-perturbation check, then every figure,
    ``report.html`` and ``summary.json``."""
    from hydropump_sim import analysis

    from . import plots, report
    params, walls, figs = run.params, run.walls, run.run_dir / 'figures'
    t0 = time.perf_counter()
    echo('[4/5 model analysis] modes and the singular-perturbation check ...')
    with stage('model analysis'):
        text, steps = analysis.format_report(params)
    modal = text[text.index('== Fine-model modes'):text.index('== Paper linear models')]
    echo(modal)
    walls['model analysis'] = stage_times(time.perf_counter() - t0)
    t0 = time.perf_counter()
    echo('[5/5 report] figures and report.html ...')
    with stage('figures'):
        analysis.plot_steps(steps, params, figs / 'steps.png')
        plots.plot_bode_identified(params, fitted['ident'], figs / 'bode.png')
        hyst = plots.plot_hysteresis(params, figs / 'hysteresis.png')
        plots.plot_closed_loop(fitted['loops'], figs / 'emc_vs_pi.png')
        for cycle in (duty, dig):
            if cycle is not None:
                cycle[2]()
        maps()
    walls['report'] = stage_times(time.perf_counter() - t0)
    # A graph beside the campaign's adds its simulated time, not its idle time.
    walls['total'] = stage_times(time.perf_counter() - run.started,
                                 sum(v['simulated_s'] for v in walls.values()),
                                 sum(v['overhead_s'] for k, v in walls.items()
                                     if not k.startswith((BESIDE, BESIDE_EXCAVATOR))))
    with stage('report'):
        sections = report.report_sections(
            fitted['ident'], fitted['truth'], fitted['rows'], fitted['loops'], modal, text,
            hyst, walls, fitted['fit_paths'], figs, run.bag_dir, fitted['calibration'],
            duty[:2] if duty else None, dig[:2] if dig else None)
        if run.prov:
            sections.append(('Provenance', provenance.html(run.prov)))
        page = report.write_html(run.run_dir, sections)
        write_text(run.run_dir / 'summary.json', json.dumps({**report.summary(
            fitted['ident'], fitted['truth'], fitted['loops'], walls,
            duty[0] if duty else None, dig[0] if dig else None),
            **({'provenance': run.prov} if run.prov else {})}, indent=2) + '\n', 'summary')
    echo(report.text_table(report.STAGE_HEAD, report.stage_rows(walls)))
    return page
