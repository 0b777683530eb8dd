"""The main job's excavator duty cycle: ``config/circuits/excavator.yaml`` (a 15-20 t
machine on one load-sensing pump, post-compensated sections: flow sharing) through the
nodes under EMC margin control, one dig - lift - swing - dump cycle of 14 s loading a truck
at 90 degrees (:data:`PHASES`; a practiced operator's 10-17 s in the makers' handbooks).

:data:`DUTY` holds the operator's lever commands (+ boom up, arm in, bucket curl, swing
toward the truck) and the loads: the attachment's weight at each rod, empty and loaded, the
digging forces rising as the arm and the bucket cut (to 300 kN on the arm, 150 kN on the
bucket) and the bucket's breakout. Its phases ask what an excavator is built for: the boom
lowered through its counterbalance valve; the pump saturated by the arm and the bucket
digging (flow sharing); the bucket driven onto its end stop (its port relief); the loaded
swing accelerated at the cross-port relief's pressure, so the pump rides its cut-off, then
braked by it; boom and swing together asking more than the pump's 420 L/min.

:func:`excavator_experiments` makes the run through the nodes; :func:`run_offline` runs the
same cycle in the offline twin (:func:`.circuit_loop.run_circuit`). :func:`cycle_figures`
judges a run, from its bag or the twin (:class:`ExcavatorRun`):

- each actuator's speed against the operator's demand, per phase: the demand is the flow
  its valve's meter-in edge passes at the command's opening with the metering pressure the
  margin leaves (margin less the compensator's spring), over the area it fills (the motor:
  its displacement);
- the margin held where the pump can hold it (not saturated, below its cut-off);
- the pressure peaks: the pump's, and each chamber's against its port relief;
- the energy account (:mod:`hydropump_sim.energy`): supplied by the pump, delivered to the
  loads, stored, and lost in metering, compensators, relief, holding valves, lines,
  actuators and the signal network, with what is unaccounted for.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import math
from pathlib import Path

import numpy as np

from ..experiment import Experiment
from .duty import filled, mean20, schedule
from .duty import held_inputs as duty_held
from .duty import recorder_topics as duty_recorder_topics

#: The actuators (section names in excavator.yaml); the swing's is a motor.
LOADS = ('boom', 'arm', 'bucket', 'swing')
CYLINDERS = ('boom', 'arm', 'bucket')
#: The margin [Pa]: 20 bar, as excavators' load-sensing pumps hold (a Cat 374D's 19.6 bar).
MARGIN = 2.0e6
#: The cycle's length and the settling run before it [s].
DURATION, PREROLL = 14.0, 0.5
#: The attachment's weight at each rod [N] (against extension), bucket empty and loaded.
EMPTY = {'boom.force': 2.5e5, 'arm.force': 5.0e4, 'bucket.force': 3.0e4}
LOADED = {'boom.force': 4.2e5, 'arm.force': 1.5e5, 'bucket.force': 5.0e4}
#: Inputs at the start of the cycle: levers centred, the bucket empty, level ground (the
#: swing's friction is the motor's own).
START = {**{f'{n}.command': 0.0 for n in LOADS}, **EMPTY, 'swing.torque': 0.0}


def _ramp(t0: float, span: float, start: Mapping[str, float], end: Mapping[str, float],
          steps: int = 5) -> list[tuple[float, str, float]]:
    """Forces changing from ``start`` to ``end`` in ``steps`` equal steps over ``span`` [s]
    from ``t0`` (a load taken on or dumped, a cut deepening: not at once, which would ring
    the attachment's oil springs)."""
    return [(round(t0 + span * k / steps, 6), name, start[name] + (end[name] - start[name])
             * (k + 1) / steps) for k in range(steps) for name in end
            if end[name] != start[name]]


#: ``(t, input, value)``.
DUTY = (
    # 1. lower into the cut, open the bucket
    [(0.0, 'boom.command', -0.6), (0.0, 'arm.command', -0.3), (0.0, 'bucket.command', -0.3),
     # 2. dig: the arm crowds and the bucket curls as the cut deepens
     (1.5, 'boom.command', 0.0), (1.5, 'arm.command', 0.8), (1.5, 'bucket.command', 0.5),
     (3.0, 'bucket.command', 0.7)]
    + _ramp(1.5, 3.0, EMPTY, {'arm.force': 3.0e5, 'bucket.force': 1.5e5}, steps=6)
    # 3. curl and break out, start lifting: the bucket onto its end stop
    + [(4.5, 'boom.command', 0.7), (4.5, 'arm.command', 0.3), (4.5, 'bucket.command', 1.0),
       (4.5, 'bucket.force', 2.0e5), (4.5, 'arm.force', LOADED['arm.force'])]
    # ... the bucket full as it leaves the ground
    + _ramp(5.5, 1.0, {'boom.force': EMPTY['boom.force'], 'bucket.force': 2.0e5},
            {'boom.force': LOADED['boom.force'], 'bucket.force': LOADED['bucket.force']})
    + [
       # 4. the loaded swing toward the truck, the boom raised; swing braked from 7.7 s
       (6.0, 'boom.command', 1.0), (6.0, 'arm.command', 0.0), (6.0, 'bucket.command', 0.0),
       (6.0, 'swing.command', 1.0), (7.7, 'swing.command', 0.0),
       (8.0, 'boom.command', 0.3), (8.0, 'arm.command', -0.3),
       # 5. dump: arm out, bucket open; the load leaves over a second from 9.8 s
       (9.5, 'boom.command', 0.0), (9.5, 'arm.command', -0.5), (9.5, 'bucket.command', -1.0)]
    + _ramp(9.8, 1.0, LOADED, EMPTY)
    # 6. swing back, then lower the boom as the swing brakes (lowered while the swing's
    # acceleration holds the pump at its cut-off, the starved boom would hunt on its
    # counterbalance valve: the operator's sequence spares it)
    + [(11.0, 'arm.command', -0.4), (11.0, 'bucket.command', 0.3),
       (11.0, 'swing.command', -1.0), (12.7, 'swing.command', 0.0),
       (12.7, 'boom.command', -0.7)])
#: ``(name, start, end)`` [s].
PHASES = (('lower into the cut', 0.0, 1.5), ('dig', 1.5, 4.5),
          ('curl and break out', 4.5, 6.0), ('loaded swing, boom up', 6.0, 9.5),
          ('dump', 9.5, 11.0), ('swing back', 11.0, 12.7), ('boom down', 12.7, DURATION))
#: A speed is judged from this long after its command last changed [s] (the spool's and the
#: load's transient).
SETTLE = 0.4
#: The margin is judged this long after any command changed [s], where the pump can hold it.
MARGIN_SETTLE = 0.3
#: Labels of the energy account's loss groups in the report.
LOSS_LABELS = {'metering': 'metering edges', 'compensators': 'compensators',
               'relief': 'reliefs', 'holding': 'holding valves', 'lines': 'lines',
               'actuators': 'actuators (friction, leakage)', 'signal': 'LS signal'}


def held_inputs(t: np.ndarray) -> dict[str, np.ndarray]:
    """Every duty-cycle input on the times ``t`` [s from the cycle's start]."""
    return duty_held(t, DUTY, START)


def demand(circuit, load: str, command: np.ndarray, margin: float = MARGIN) -> np.ndarray:
    """The speed the operator's ``command`` asks of ``load`` [m/s, or rad/s of the swing
    motor]: its valve's meter-in edge at the command's opening, with the metering pressure
    the margin leaves (``margin`` less the compensator's spring), over the area it fills."""
    from hydropump_sim.components.valve_4_3 import openings
    parts = {pt.comp.name: pt.comp.params for pt in circuit.parts}
    valve, comp = parts[f'{load}.valve'], parts[f'{load}.comp']
    rho = circuit.fluid.rho
    dp = max(margin - comp.dp_set, 0.0)
    s = np.asarray(command, dtype=float)
    a_pa = valve.A_PA or valve.A_max
    a_pb = valve.A_PB or valve.A_max
    area = np.where(s >= 0.0, a_pa, a_pb) * openings(np.abs(s), valve.overlap_P)
    q = valve.C_d * area * math.sqrt(2.0 * dp / rho)
    if f'{load}.motor' in parts:
        return np.sign(s) * q / parts[f'{load}.motor'].D
    cyl = parts[f'{load}.cylinder']
    return np.where(s >= 0.0, q / cyl.A_a, -q / cyl.A_b)


def excavator_experiments(circuit, topics: Sequence[str] = ()) -> list[Experiment]:
    """The cycle through the nodes under EMC margin control, on the simulator running
    ``circuit`` (:class:`~hydropump_sim.circuit.Circuit` of excavator.yaml)."""
    sim = {'initial_current': circuit.plant_params().current_range[0], 'sensors.seed': 1,
           **{f'inputs.{n}': float(v) for n, v in START.items()}}
    ctrl = {'controller.algorithm': 'emc', 'controller.mode': 'margin',
            'reference.margin': MARGIN}
    return [Experiment(name='excavator_emc', label='excavator dig-lift-swing-dump cycle, EMC',
                       duration=DURATION, sim=sim, ctrl=ctrl, topics=list(topics),
                       events=schedule(DUTY), preroll=PREROLL)]


def bag_topics(circuit) -> list[str]:
    """The topics :func:`cycle_figures` reads besides the current and the pump flow."""
    from hydropump_sim.energy import topics as energy_topics
    out = ['line_pressure', 'ls_pressure', 'solenoid_current_cmd']
    for n in LOADS:
        keys = ('pressure', 'pressure_b', 'speed') if n == 'swing' else \
            ('pressure', 'pressure_b', 'position', 'velocity')
        out += [f'loads/{n}/{k}' for k in keys]
    return out + [t for t, _ in energy_topics(circuit)]


def recorder_topics(circuit, topics: Sequence[str]) -> list[str]:
    """Of a circuit's recorded ``topics``, those the cycle's bag keeps
    (:func:`.duty.recorder_topics`)."""
    return duty_recorder_topics(topics, bag_topics(circuit))


# ---- judging a run -------------------------------------------------------------------------

@dataclass
class ExcavatorRun:
    """One cycle on its time ``t`` [s]: gauge pressures [Pa], the pump's flow [m^3/s], each
    load's chamber pressures, speed (m/s, the swing motor's rad/s) and position, the
    current commanded [A] and the energies so far [J] by ``energy/...`` topic."""

    t: np.ndarray
    p_l: np.ndarray
    p_ls: np.ndarray
    q_p: np.ndarray
    command: np.ndarray
    p: dict
    p_b: dict
    v: dict
    x: dict
    energy: dict = field(default_factory=dict)

    @property
    def margin(self) -> np.ndarray:
        return self.p_l - self.p_ls

    @classmethod
    def from_recording(cls, rec, t0: float, p_atm: float, flow_delay: float) -> ExcavatorRun:
        """From a bag read with ``topics=bag_topics(...)`` (flow ``pump_flow``): time from
        the cycle's start ``t0`` [s of simulation], pressures made gauge, the pump flow moved
        back by the bench sensor's ``flow_delay`` [s]."""
        t = rec.t + rec.t0_ns * 1e-9 - t0
        sig = rec.signals

        def gauge(topic):
            return sig[topic] - p_atm
        speed = {n: sig[f'loads/{n}/speed' if n == 'swing' else f'loads/{n}/velocity']
                 for n in LOADS}
        return cls(t, gauge('line_pressure'), gauge('ls_pressure'),
                   np.interp(t + flow_delay, t, sig['pump_flow'], right=np.nan),
                   sig['solenoid_current_cmd'],
                   {n: gauge(f'loads/{n}/pressure') for n in LOADS},
                   {n: gauge(f'loads/{n}/pressure_b') for n in LOADS}, speed,
                   {n: sig[f'loads/{n}/position'] for n in CYLINDERS},
                   {k: filled(t, v) for k, v in sig.items() if k.startswith('energy/')})

    @classmethod
    def from_loop(cls, run) -> ExcavatorRun:
        """From the offline twin (:class:`~.circuit_loop.CircuitRun`): true signals, the
        energies integrated as a simulator integrates them (every step)."""
        from hydropump_sim.energy import cumulative
        return cls(run.t, run['pump.P_l'], run['ls.pressure'], run['pump.Q_p'], run.command,
                   {n: run[f'{n}.pressure'] for n in LOADS},
                   {n: run[f'{n}.pressure_b'] for n in LOADS},
                   {n: run[f'{n}.speed' if n == 'swing' else f'{n}.velocity'] for n in LOADS},
                   {n: run[f'{n}.position'] for n in CYLINDERS},
                   cumulative(run.model, run.t, run.y))


def _since_change(t: np.ndarray, names: Sequence[str]) -> np.ndarray:
    """Time [s] since any of the inputs ``names`` last changed, at each sample."""
    changes = sorted({te for te, n, _ in DUTY if n in names})
    last = np.full(t.shape, -np.inf)
    for te in changes:
        last[t >= te] = te
    return t - last


def cycle_figures(run: ExcavatorRun, circuit, current_max: float, p_cutoff: float,
                  margin: float = MARGIN) -> dict:
    """What a cycle did (SI).

    Returns
    -------
    dict
        ``speeds``: per phase, per load commanded in it, ``(speed, demand)`` means over the
        samples :data:`SETTLE` after its command last changed; ``margin_error`` (mean
        |P_l - P_LS - margin| of the 20 ms means where the pump can hold the margin: below
        its current limit and 10 bar under its cut-off, :data:`MARGIN_SETTLE` after any
        command changed) and ``margin_held`` (the share of those samples within 2 bar);
        ``p_peak`` (the pump's, 20 ms mean) and ``chamber_peak`` (per load, its highest
        chamber pressure); ``energy`` (per term and loss group over the cycle [J]) and
        ``balance`` (what is unaccounted for, over the energy supplied).
    """
    t = run.t
    cmd = held_inputs(t)
    speeds = {}
    for name, a, b in PHASES:
        row = {}
        for n in LOADS:
            c = cmd[f'{n}.command']
            sel = ((t >= a) & (t < b) & (c != 0.0)
                   & (_since_change(t, [f'{n}.command']) >= SETTLE))
            if sel.sum() < 10:
                continue
            row[n] = (float(np.mean(run.v[n][sel])),
                      float(np.mean(demand(circuit, n, c[sel], margin))))
        speeds[name] = row
    err = mean20(t, run.margin) - margin
    can = ((run.command < current_max - 1.0e-3) & (mean20(t, run.p_l) < p_cutoff - 1.0e6)
           & (_since_change(t, [f'{n}.command' for n in LOADS]) >= MARGIN_SETTLE)
           & np.isfinite(err))
    out = {'speeds': speeds,
           'margin_error': float(np.mean(np.abs(err[can]))) if can.any() else math.nan,
           'margin_held': float(np.mean(np.abs(err[can]) < 2.0e5)) if can.any() else math.nan,
           'margin_samples': float(np.mean(can)),
           'p_peak': float(np.max(mean20(t, run.p_l))),
           'chamber_peak': {n: float(max(np.max(run.p[n]), np.max(run.p_b[n])))
                            for n in LOADS}}
    if run.energy:
        at0 = int(np.searchsorted(t, 0.0))
        span = {k: float(v[-1] - v[at0]) for k, v in run.energy.items()}
        terms = {k[len('energy/'):]: v for k, v in span.items() if k.count('/') == 1}
        groups = {k[len('energy/loss/'):]: v for k, v in span.items()
                  if k.startswith('energy/loss/')}
        unaccounted = terms['supply'] - terms['work'] - terms['stored'] - terms['loss']
        out['energy'] = {**terms, 'groups': groups}
        out['balance'] = abs(unaccounted) / max(abs(terms['supply']), 1e-300)
    return out


SPEED_HEAD = ['phase', *(f'{n} [{"rad/s" if n == "swing" else "mm/s"}]: speed / demand'
                         for n in LOADS)]


def speed_rows(f: Mapping) -> list[list[str]]:
    """The speed table: per phase, each commanded load's mean speed, its demand and the
    ratio (mm/s; the swing motor's rad/s)."""
    rows = []
    for name, _, _ in PHASES:
        row = [name]
        for n in LOADS:
            if n not in f['speeds'][name]:
                row.append('')
                continue
            v, d = f['speeds'][name][n]
            k = 1.0 if n == 'swing' else 1.0e3
            row.append(f'{v * k:.0f} / {d * k:.0f} ({100.0 * v / d:.0f} %)')
        rows.append(row)
    return rows


ENERGY_HEAD = ['supplied [kJ]', 'to the loads [kJ]', 'stored [kJ]',
               *(f'{label} [kJ]' for label in LOSS_LABELS.values()), 'unaccounted']


def energy_row(f: Mapping) -> list[str]:
    """The energy account of the cycle, one row."""
    e = f['energy']
    return ([f'{e[k] / 1e3:.1f}' for k in ('supply', 'work', 'stored')]
            + [f'{e["groups"].get(g, 0.0) / 1e3:.2f}' for g in LOSS_LABELS]
            + [f'{f["balance"]:.1e}'])


def circuit_path() -> Path:
    """The shipped ``config/circuits/excavator.yaml``."""
    from hydropump_sim.circuit import default_circuit_path
    return default_circuit_path().with_name('excavator.yaml')


def controller_path() -> Path:
    """The controller ``hydropump design --circuit`` wrote for it,
    ``config/controller_excavator.yaml``."""
    from hydropump_sim.params import default_params_path
    return default_params_path().with_name('controller_excavator.yaml')


def analyse(bag: Path, t0: float, profile) -> tuple[object, ExcavatorRun, dict]:
    """The shipped circuit, a cycle's :class:`ExcavatorRun` and its :func:`cycle_figures`
    from its bag and the simulation time it started at."""
    from hydropump_sim.circuit import load_circuit

    from ..control import load_config
    from ..ident import read_recording
    circuit = load_circuit(circuit_path(), compile=False)
    limits = circuit.plant_params().I_limits
    current_max = load_config(controller_path(), current_limits=limits).limits.current_max
    rec = read_recording(bag, flow_topic='pump_flow', signals=None,
                         topics=bag_topics(circuit))
    run = ExcavatorRun.from_recording(rec, t0, circuit.fluid.p_atm,
                                      profile.spec('pump_flow').delay)
    return circuit, run, cycle_figures(run, circuit, current_max,
                                       circuit.pump().comp.params.cutoff.p_set)


def run_offline(circuit, config=None, profile=None):
    """The cycle in the offline twin, under EMC margin control (``config``: the
    controller's, default the design :func:`.circuit_loop.run_circuit` makes)."""
    from ..experiments.circuit_loop import run_circuit
    from ..experiments.harness import Event
    events = [Event(t, name, value) for t, name, value in DUTY]
    # No settling run: the events of t = 0 would hold through it (the loop starts from
    # the steady state of the levers centred).
    return run_circuit(circuit, DURATION, START, control='margin', algorithm='emc',
                       margin=MARGIN, config=config, profile=profile, settle=0.0,
                       events=events)


def plot(run: ExcavatorRun, circuit, path: Path, margin: float = MARGIN) -> None:
    """The cycle: lever commands; speeds against demand; pressures; margin; energy."""
    from .plots import pyplot, save
    plt = pyplot()
    fig, axes = plt.subplots(5, 1, figsize=(10, 14), sharex=True)
    t = run.t
    cmd = held_inputs(t)
    for j, n in enumerate(LOADS):
        col = f'C{j}'
        axes[0].plot(t, cmd[f'{n}.command'], col, lw=1, label=n)
        k = 1.0 if n == 'swing' else 1.0e3
        scale = 0.01 if n == 'swing' else 1.0   # the swing motor's rad/s over 100
        axes[1].plot(t, run.v[n] * k * scale, col, lw=1,
                     label=f'{n} [{"100 rad/s" if n == "swing" else "mm/s"}]')
        axes[1].plot(t, demand(circuit, n, cmd[f'{n}.command'], margin) * k * scale, col,
                     lw=0.8, ls='--')
        axes[2].plot(t, run.p[n] / 1e5, col, lw=0.8, label=f'{n} A')
        axes[2].plot(t, run.p_b[n] / 1e5, col, lw=0.8, ls=':', label=f'{n} B')
    axes[2].plot(t, mean20(t, run.p_l) / 1e5, 'k', lw=1.2, label='pump P_l')
    axes[3].plot(t, mean20(t, run.margin) / 1e5, 'k', lw=1, label='P_l - P_LS')
    axes[3].axhline(margin / 1e5, color='C3', lw=0.6, ls=':', label='set-point')
    if run.energy:
        at0 = int(np.searchsorted(t, 0.0))
        for k, v in run.energy.items():
            if k.startswith('energy/loss/'):
                g = k[len('energy/loss/'):]
                axes[4].plot(t, (v - v[at0]) / 1e3, lw=1, label=LOSS_LABELS.get(g, g))
        for k, style in (('supply', 'k'), ('work', 'k--')):
            v = run.energy[f'energy/{k}']
            axes[4].plot(t, (v - v[at0]) / 1e3, style, lw=1.2,
                         label={'supply': 'pump', 'work': 'to the loads'}[k])
    axes[0].set_ylabel('lever command [-]')
    axes[1].set_ylabel('speed (dashed: demand)')
    axes[2].set_ylabel('pressure [bar]')
    axes[3].set_ylabel('margin [bar]')
    axes[3].set_ylim(0, 3 * margin / 1e5)
    axes[4].set_ylabel('energy since the start [kJ]')
    axes[4].set_xlabel('time in the cycle [s]')
    for ax in axes:
        for _, a, _ in PHASES[1:]:
            ax.axvline(a, color='0.85', lw=0.6, zorder=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, ncol=4, loc='upper left')
    axes[0].set_title('excavator cycle, EMC margin control: '
                      + '; '.join(f'{a:g} s {name}' for name, a, _ in PHASES), fontsize=8)
    fig.tight_layout()
    save(plt, fig, path)
