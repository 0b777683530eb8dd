"""The main job's Fig. 1 duty cycle: the circuit of ``config/circuits/fig1.yaml`` through the
nodes, under electronic load sensing (EMC and PI in margin mode) and under the classic
hydromechanical compensator, with pre- and post-compensated sections.

:data:`DUTY` is one operator's cycle of 4 s (:data:`PHASES`): the priority steering alone;
the boom switched on; the motor switched on above it; the boom's load rising through the
motor's; every command at its maximum, asking more than the pump's maximum flow; the boom
switched off. :func:`fig1_experiments` makes one :class:`~.experiment.Experiment` of it per
control and compensator kind (:data:`VARIANTS`), all on one simulator: the compensator kind
and the pump's compensator are the simulator's live ``circuit_sets``, the operator's
commands and the boom's force its ``inputs.<name>`` parameters, set at their instants.

:func:`duty_figures` judges a run from its bag, on what load sensing exists for:

- the margin held, ``P_l - P_LS`` against the set-point where the pump can hold it;
- the load flows against those demanded, where the pump cannot give them all: each section's
  demand is the flow it took, unsaturated, in the 0.5 s before, scaled by its command
  (a compensated section's flow is proportional to its command);
- the pressure peaks, and the time the relief valve stood open;
- the throttling power lost: what the valves dissipate (metering edges, compensators, the
  relief, the signal line), from the simulator's energy account (``energy/loss`` less the
  actuators' friction and leakage, :mod:`hydropump_sim.energy`), and the share of the
  pump's hydraulic power that did not go there. The balance ``P_l Q_p - sum P_i Q_i``
  would count as lost the energy a section's volumes store while they charge (it dipped
  to -40 kW as they gave it back).

The flows in a bag come through the bench's flow sensors (``config/bench.yaml``: delayed by
55 ms); they are moved back by the profile's configured delay to line up with the pressures.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
import textwrap

import numpy as np

from hydropump_sim.sensors import SensorProfile

from ..experiment import EXCITATION_BASE, Experiment
from .duty import filled, mean20
from .duty import held_inputs as duty_held
from .duty import recorder_topics as duty_recorder_topics
from .duty import schedule as duty_schedule

#: The loads of Fig. 1 (section names in fig1.yaml).
LOADS = ('steering', 'boom', 'motor')
#: The margin every control holds [Pa].
MARGIN = 2.5e6
#: The duty cycle's length [s] and the settling run before it, not recorded [s].
DURATION, PREROLL = 4.0, 0.5
#: Inputs at the start of the cycle (the preroll runs on them).
START = {'steering.command': 0.3, 'boom.command': 0.0, 'boom.force': 6.0e4,
         'motor.command': 0.0, 'motor.torque': 40.0}
#: ``(t, input, value)``: the operator's commands and the boom's load. The boom's force
#: rises 60 -> 90 kN (119 -> 179 bar) in eight steps, through the motor's 137 bar.
DUTY = ([(0.3, 'boom.command', 0.6), (1.0, 'motor.command', 0.5)]
        + [(round(1.8 + 0.1 * k, 3), 'boom.force', 6.0e4 + 3.75e3 * (k + 1)) for k in range(8)]
        + [(2.6, 'steering.command', 0.6), (2.6, 'boom.command', 1.0),
           (2.6, 'motor.command', 1.0),
           (3.4, 'steering.command', 0.3), (3.4, 'boom.command', 0.0),
           (3.4, 'motor.command', 0.3)])
#: ``(name, start, end)`` of the cycle's phases [s].
PHASES = (('steering alone', 0.0, 0.3), ('boom on', 0.3, 1.0),
          ('motor on, above the boom', 1.0, 1.8), ('boom load rising above the motor', 1.8, 2.6),
          ('demand beyond the pump', 2.6, 3.4), ('boom off, motor back', 3.4, 4.0))
#: Windows where the margin is judged: the last 0.2 s of each phase the pump can serve.
SETTLED = ((0.1, 0.3), (0.8, 1.0), (1.6, 1.8), (2.4, 2.6), (3.8, 4.0))
#: The saturated window (the last half of the phase beyond the pump) and the unsaturated one
#: before it that sets each section's demand.
SATURATED, BEFORE = (3.0, 3.4), (2.3, 2.6)
#: ``(control, compensator kind)`` of each run: the three controls with pre-compensated
#: sections, and flow sharing under EMC and the hydromechanical compensator.
VARIANTS = (('emc', 'pre'), ('pi', 'pre'), ('hydromechanical', 'pre'),
            ('emc', 'post'), ('hydromechanical', 'post'))
LABELS = {'emc': 'EMC', 'pi': 'PI', 'hydromechanical': 'hydromechanical'}


def circuit_sets(control: str, kind: str) -> str:
    """The simulator's ``circuit_sets`` of a run: the sections' compensator kind, and the
    hydromechanical compensator on the pump for that control."""
    out = [f'boom.compensator={kind}', f'motor.compensator={kind}']
    if control == 'hydromechanical':
        # A signed exponent: YAML reads 2.5e6 as text.
        out += ['pump.type=ls_pump', f'pump.ls.margin={MARGIN:.6e}']
    return ' '.join(out)


def schedule(duty: Sequence[tuple] = DUTY) -> list[tuple[float, str, dict]]:
    """The duty cycle as the simulator's parameter events (:func:`.duty.schedule`)."""
    return duty_schedule(duty)


def held_inputs(t: np.ndarray, duty: Sequence[tuple] = DUTY,
                start: Mapping[str, float] = START) -> dict[str, np.ndarray]:
    """Every duty-cycle input on the times ``t`` [s from the cycle's start]."""
    return duty_held(t, duty, start)


def fig1_experiments(circuit, variants: Sequence[tuple[str, str]] = VARIANTS,
                     topics: Sequence[str] = ()) -> list[Experiment]:
    """The duty cycle once per ``(control, kind)`` on the simulator running ``circuit``
    (:class:`~hydropump_sim.circuit.Circuit` of fig1.yaml: it gives each run's start
    current)."""
    from hydropump_sim.steady import equilibrium

    from ..experiments.circuit_loop import start_current
    out = []
    for control, kind in variants:
        c = circuit.with_values({**START, 'boom.compensator': kind, 'motor.compensator': kind})
        # A start where the loads starve a little: a rest the simulator's reset finds
        # (at exactly their flow the line pressure would be free); the preroll closes
        # the margin.
        current = start_current(c, equilibrium(c), share=0.9)
        sim = {'circuit_sets': circuit_sets(control, kind), 'initial_current': current,
               'sensors.seed': 1, **{f'inputs.{n}': float(v) for n, v in START.items()}}
        if control == 'hydromechanical':
            # The solenoid has no say: the controller holds its command.
            ctrl = {'controller.mode': 'open_loop'}
            first = dict(EXCITATION_BASE)
        else:
            ctrl = {'controller.algorithm': control, 'controller.mode': 'margin',
                    'reference.margin': MARGIN}
            first = {}
        out.append(Experiment(
            name=f'fig1_{control}_{kind}', label=f'Fig. 1 duty cycle, {LABELS[control]}, '
            f'{kind}-compensated', duration=DURATION, sim=sim, ctrl=ctrl,
            topics=list(topics), events=schedule(), preroll=PREROLL, ctrl_first=first))
    return out


def bag_topics() -> list[str]:
    """The topics :func:`duty_figures` reads besides the current and the pump flow."""
    return ['line_pressure', 'ls_pressure', *(f'loads/{n}/{k}' for n in LOADS
                                              for k in ('pressure', 'flow')), *THROTTLING]


def recorder_topics(topics: Sequence[str]) -> list[str]:
    """Of a circuit's recorded ``topics`` (:func:`hydropump_sim.measure.recorded_topics`),
    those the duty cycle's bags keep (:func:`.duty.recorder_topics`)."""
    return duty_recorder_topics(topics, bag_topics())


# ---- judging a run -------------------------------------------------------------------------

# The energy account's topics [J, cumulative] whose difference is the throttling loss.
THROTTLING = ('energy/loss', 'energy/loss/actuators')
# s: the window over which the throttling power is the slope of its energy.
LOSS_WINDOW = 0.02

@dataclass
class DutyRun:
    """One run on the cycle's time ``t`` [s]: gauge pressures [Pa] and flows [m^3/s]."""

    t: np.ndarray
    p_l: np.ndarray
    p_ls: np.ndarray
    q_p: np.ndarray
    p: dict
    q: dict
    e_loss: np.ndarray   # throttling energy dissipated since the bag's start [J]

    @classmethod
    def from_recording(cls, rec, t0: float, p_atm: float, flow_delay: float) -> DutyRun:
        """From a bag read with ``topics=bag_topics()`` (flow ``pump_flow``): time from the
        cycle's start ``t0`` [s of simulation], pressures made gauge, flows moved back by
        ``flow_delay`` [s], the bench sensor's configured delay."""
        t = rec.t + rec.t0_ns * 1e-9 - t0
        sig = rec.signals

        def early(x):
            return np.interp(t + flow_delay, t, x, right=np.nan)
        total, actuators = (filled(t, sig[k]) for k in THROTTLING)
        return cls(t, sig['line_pressure'] - p_atm, sig['ls_pressure'] - p_atm,
                   early(sig['pump_flow']),
                   {n: sig[f'loads/{n}/pressure'] - p_atm for n in LOADS},
                   {n: early(sig[f'loads/{n}/flow']) for n in LOADS}, total - actuators)

    def window(self, a: float, b: float) -> np.ndarray:
        return (self.t >= a) & (self.t < b) & np.isfinite(self.q_p)

    @property
    def margin(self) -> np.ndarray:
        return self.p_l - self.p_ls

    @property
    def loss(self) -> np.ndarray:
        """Throttling power lost [W]: the slope of its energy over :data:`LOSS_WINDOW`
        (never negative: the energy only grows)."""
        t, h = self.t, 0.5 * LOSS_WINDOW
        a, b = np.maximum(t - h, t[0]), np.minimum(t + h, t[-1])
        return (np.interp(b, t, self.e_loss) - np.interp(a, t, self.e_loss)) / (b - a)


def overlaps(circuit) -> dict[str, float]:
    """Each load's valve overlap (``overlap_P``, a fraction of the spool's stroke): its
    metering edge opens as ``(command - overlap) / (1 - overlap)``."""
    parts = {pt.comp.name: pt.comp.params for pt in circuit.parts}
    return {n: parts[f'{n}.valve'].overlap_P for n in LOADS}


def demand_ratio(c0, c1, overlap: float):
    """How much more a compensated section takes at command ``c1`` than at ``c0``: the
    ratio of its edge's openings (its flow is proportional to its opening)."""
    from hydropump_sim.components.valve_4_3 import openings
    o0 = openings(c0, overlap)
    return openings(c1, overlap) / o0 if o0 > 0 else np.zeros(np.shape(c1))


def duty_figures(run: DutyRun, p_crack: float, overlap: Mapping[str, float],
                 margin: float = MARGIN) -> dict:
    """What a run did (SI). ``p_crack`` is the relief valve's cracking pressure [Pa],
    ``overlap`` each load valve's overlap (:func:`overlaps`).

    Returns
    -------
    dict
        ``margin_error`` (mean |P_l - P_LS - margin| over :data:`SETTLED`), ``margin_worst``
        (the largest 20 ms-mean error outside the saturated phase), ``delivered``
        (per load, flow over demand in :data:`SATURATED`), ``demand``, ``flow`` (per load
        in the saturated window), ``pump_flow_saturated``, ``p_peak`` (largest 20 ms-mean
        P_l), ``relief_s`` (time P_l stood above ``p_crack``), ``loss_mean`` and
        ``loss_min`` [W] (the throttling power), ``efficiency`` (the share of the pump's
        energy not throttled).
    """
    t = run.t
    ok = np.isfinite(run.q_p)
    err = mean20(t, run.margin) - margin
    settled = np.zeros(t.shape, bool)
    for a, b in SETTLED:
        settled |= run.window(a, b)
    sat_phase = (t >= PHASES[4][1]) & (t < PHASES[4][2])
    out = {'margin_error': float(np.mean(np.abs(err[settled]))),
           'margin_worst': float(np.max(np.abs(err[~sat_phase])))}
    before, sat = run.window(*BEFORE), run.window(*SATURATED)
    cmd = held_inputs(t)
    demand, flow, delivered = {}, {}, {}
    for n in LOADS:
        c0, c1 = cmd[f'{n}.command'][before].mean(), cmd[f'{n}.command'][sat].mean()
        demand[n] = float(run.q[n][before].mean() * demand_ratio(c0, c1, overlap[n]))
        flow[n] = float(run.q[n][sat].mean())
        delivered[n] = flow[n] / demand[n] if demand[n] > 0 else np.nan
    p_l = mean20(t, run.p_l)
    dt = float(np.median(np.diff(t)))
    pump_energy = float(np.sum((run.p_l * run.q_p)[ok]) * dt)
    out.update(demand=demand, flow=flow, delivered=delivered,
               pump_flow_saturated=float(run.q_p[sat].mean()),
               p_peak=float(np.max(p_l)), relief_s=float(np.sum(p_l > p_crack) * dt),
               loss_mean=float(np.mean(run.loss[ok])), loss_min=float(np.min(run.loss)),
               efficiency=float(1.0 - np.sum(run.loss[ok]) * dt / pump_energy))
    return out


TABLE_HEAD = ['run', 'margin error [bar]', 'worst [bar]', 'P_l peak [bar]', 'relief open [s]',
              'saturated: delivered / demanded, steering, boom, motor [%]',
              'pump flow saturated [L/min]', 'throttling loss [kW]', 'to the loads [%]']


def table_rows(results: Mapping[str, dict]) -> list[list[str]]:
    """One row per run of :func:`duty_figures` results keyed by experiment name."""
    rows = []
    for name, f in results.items():
        _, control, kind = name.split('_', 2)
        rows.append([f'{LABELS[control]}, {kind}', f'{f["margin_error"] / 1e5:.2f}',
                     f'{f["margin_worst"] / 1e5:.1f}', f'{f["p_peak"] / 1e5:.0f}',
                     f'{f["relief_s"]:.3f}',
                     ' / '.join(f'{100.0 * f["delivered"][n]:.0f}' for n in LOADS),
                     f'{f["pump_flow_saturated"] * 6e4:.1f}', f'{f["loss_mean"] / 1e3:.2f}',
                     f'{100.0 * f["efficiency"]:.0f}'])
    return rows


def analyse(bags: Mapping[str, Path], starts: Mapping[str, float], profile: SensorProfile,
            p_atm: float, p_crack: float, overlap: Mapping[str, float]
            ) -> tuple[dict, dict]:
    """Every run's :class:`DutyRun` and :func:`duty_figures`, by experiment name, from its
    bag and the simulation time it started at."""
    from ..ident import read_recording
    runs, figures = {}, {}
    delay = profile.spec('pump_flow').delay
    for name, bag in bags.items():
        rec = read_recording(bag, flow_topic='pump_flow', signals=None, topics=bag_topics())
        runs[name] = DutyRun.from_recording(rec, starts.get(name, 0.0), p_atm, delay)
        figures[name] = duty_figures(runs[name], p_crack, overlap)
    return runs, figures


def plot(runs: Mapping[str, DutyRun], kind: str, path: Path, overlap: Mapping[str, float],
         margin: float = MARGIN) -> None:
    """The cycle under each control for one compensator kind: pressures, margin, load flows
    (EMC's, against each section's demand), throttling power lost."""
    from .plots import pyplot, save
    plt = pyplot()
    fig, axes = plt.subplots(4, 1, figsize=(10, 11), sharex=True)
    styles = {'emc': 'C0', 'pi': 'C1', 'hydromechanical': 'C2'}
    for name, run in runs.items():
        _, control, k = name.split('_', 2)
        if k != kind:
            continue
        col = styles[control]
        axes[0].plot(run.t, mean20(run.t, run.p_l) / 1e5, col, lw=1,
                     label=f'P_l, {LABELS[control]}')
        axes[1].plot(run.t, mean20(run.t, run.margin) / 1e5, col, lw=1,
                     label=LABELS[control])
        axes[3].plot(run.t, run.loss / 1e3, col, lw=1, label=LABELS[control])
        if control == 'emc':
            for j, n in enumerate(LOADS):
                axes[0].plot(run.t, mean20(run.t, run.p[n]) / 1e5, color='0.5', lw=0.8,
                             ls=('-', '--', ':')[j], label=f'{n} pressure (EMC run)')
                axes[2].plot(run.t, run.q[n] * 6e4, f'C{j + 3}', lw=1, label=f'{n}')
            axes[2].plot(run.t, run.q_p * 6e4, 'k', lw=1, label='pump')
            cmd = held_inputs(run.t)
            before = run.window(*BEFORE)
            for j, n in enumerate(LOADS):
                c = cmd[f'{n}.command']
                k0 = c[before].mean()
                if k0 > 0:
                    demand = run.q[n][before].mean() * demand_ratio(k0, c, overlap[n])
                    span = run.t >= BEFORE[0]
                    axes[2].plot(run.t[span], demand[span] * 6e4, f'C{j + 3}', ls='--', lw=1)
    axes[1].axhline(margin / 1e5, color='k', lw=0.6, ls=':')
    for ax in axes:
        for _, a, _ in PHASES[1:]:
            ax.axvline(a, color='0.85', lw=0.6, zorder=0)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel('pressure [bar]')
    axes[1].set_ylabel('P_l - P_LS [bar]')
    axes[1].set_ylim(0, 3 * margin / 1e5)
    axes[2].set_ylabel('flow [L/min] (dashed: demand)')
    axes[3].set_ylabel('throttling loss [kW]')
    axes[3].set_xlabel('time in the duty cycle [s]')
    for ax in axes:
        ax.legend(fontsize=7, ncol=3, loc='upper left')
    # Wrapped: the phases in one line ran off both ends of the figure.
    title = (f'Fig. 1 duty cycle, {kind}-compensated sections: '
             + '; '.join(f'{a:g} s {name}' for name, a, _ in PHASES[1:]))
    axes[0].set_title('\n'.join(textwrap.wrap(title, 110)), fontsize=8)
    fig.tight_layout()
    save(plt, fig, path)
