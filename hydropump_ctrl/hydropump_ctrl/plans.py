"""Recording plans: the experiments of ``hydropump record``, and the same definitions offline.

A plan is a list of experiments, each a current schedule (held levels, or a sine about an
offset: what the controller runs) with optional load-pressure and aperture steps. The
standard calibration campaign is :func:`standard_plan` (``config/plans/calibration.yaml``
is the same plan for ``config/pump.yaml``); any other plan is a YAML file
(docs/recording.md)::

    - name: stairs                 # the bag's name: letters, digits, _ . -
      label: staircase up          # optional: free text for the progress lines
      duration: 5.0                # s, simulated
      current:                     # a schedule (hydropump_sim.schedule): a staircase ...
        staircase: {levels: [30, 40, 50, 60, 70], dwell: 1.0}   # s per level
        unit: percent              # percent of displacement (eq. 10) or A (absolute)
      load_pressure: [[0.0, 8.0e+6], [2.0, 1.2e+7]]   # Pa, gauge, held from t [s]
      aperture: [[3.0, 0.4]]       # -, 0..1, held from t [s]
      seed: 3                      # sensor noise seed (default: from the name)
    - name: check
      duration: 4.0
      current: {offset: 0.5, sine: {amplitude: 0.06, frequency: 0.5}}   # A
      held_out: true               # kept out of a calibration, to validate on

What each experiment holds, as arrays on a time grid, is :func:`held_inputs`: the absolute
current [A] as the controller commands it (levels change at its update instants, a sine is
sampled at them) and the gauge load pressure [Pa], so that an offline calibration uses the
definitions the nodes ran. :func:`node_experiment` turns an experiment into the live
parameters and timed changes of the node graph (:class:`.campaign.Experiment`).

Times are simulation time from the experiment's start. A change takes effect at the first
control instant at or after its time (the controller updates every :data:`CONTROL_PERIOD`);
a plan whose times are not whole control periods is run so, with a warning. Nothing here
imports ROS.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
import math
from pathlib import Path
import re
from typing import Any
import zlib

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.measure import suite_topics
from hydropump_sim.params import default_params_path, input_spec, Params
from hydropump_sim.schedule import parse_schedule, Schedule
from hydropump_sim.schema import (
    check_number,
    check_value,
    closest_name,
    fmt,
    ParamError,
    read_yaml,
)

from .control.schema import specs as controller_specs
from .experiment import EXCITATION_BASE, Experiment, operating_point

#: The plan that needs no file: :func:`standard_plan`.
STANDARD = 'standard'
#: The controller's update period [s] (200 Hz, config/controller.yaml): the instants at which
#: a commanded current can change.
CONTROL_PERIOD = 0.005
#: How much lower the load pressure of the low-load staircases is [Pa] (40 bar), at least
#: 30 % of the nominal load pressure left.
LOW_LOAD_DROP = 4.0e6
#: The standard staircase levels [% of displacement]: the regulating range's middle +- 10 and
#: 20 % of the range (``hydropump_ctrl.ident.design.candidate_inputs``).
STANDARD_LEVELS = (30.0, 40.0, 50.0, 60.0, 70.0)
#: Folder of the nodes' logs beside the bags; no experiment may take its name.
LOG_FOLDER = 'logs'

EXPERIMENT_KEYS = ('name', 'label', 'duration', 'current', 'load_pressure', 'aperture', 'seed',
                   'held_out')
#: A plan's current is run by the controller: levels held from their times, or its sine
#: about a constant offset; no ramp.
CURRENT_BASES = ('steps', 'staircase', 'step', 'offset')
UNITS = ('A', 'percent')
#: The spelling of a current before the schedule grammar, still read (with a warning).
OLD_SHAPES = {'staircase': ('levels', 'dwell'), 'sine': ('offset', 'amplitude', 'frequency')}
NAME = re.compile(r'[A-Za-z0-9][A-Za-z0-9_.-]{0,99}$')
SEED_MAX = 2 ** 31 - 1
STEP_INPUTS = {'load_pressure': 'line.P_u', 'aperture': 'line.xi_u'}


class PlanError(HydropumpError, ValueError):
    """An invalid plan: one line per problem, each naming the experiment and the field."""


# ---- the plan -------------------------------------------------------------------------------

def is_sine(current: Schedule) -> bool:
    """Whether a plan's current is the controller's sine (else held levels)."""
    return current.sine != (0.0, 0.0, 0.0, 0.0)


def _describe(current: Schedule) -> str:
    text = current.describe()
    return 'current ' + text if text.startswith('held') else text


@dataclass(frozen=True)
class PlanExperiment:
    """One experiment of a plan (see the module): SI units, times from its start [s]."""

    name: str
    duration: float
    current: Schedule             # A or percent of displacement
    load_pressure: tuple = ()     # ((t [s], P_u [Pa, gauge]), ...)
    aperture: tuple = ()          # ((t [s], xi_u [-]), ...)
    seed: int | None = None
    held_out: bool = False
    label: str = ''

    @property
    def noise_seed(self) -> int:
        """The sensor noise seed: the given one, or one made from the name (each experiment
        its own noise, whatever its place in the plan)."""
        return self.seed if self.seed is not None else zlib.crc32(self.name.encode()) % SEED_MAX

    def describe(self) -> str:
        parts = [_describe(self.current)]
        if self.load_pressure:
            parts.append('load ' + ', '.join(f'{fmt(v * 1e-5)} bar at {fmt(t)} s'
                                             for t, v in self.load_pressure))
        if self.aperture:
            parts.append('aperture ' + ', '.join(f'{fmt(v)} at {fmt(t)} s'
                                                 for t, v in self.aperture))
        return '; '.join(parts)


@dataclass
class Plan:
    """The experiments of a plan, where it came from and what looked odd in it."""

    experiments: list
    source: str = ''
    warnings: list = field(default_factory=list)

    @property
    def held_out(self) -> list[str]:
        return [e.name for e in self.experiments if e.held_out]

    @property
    def duration(self) -> float:
        """Simulated time of the whole plan [s]."""
        return float(sum(e.duration for e in self.experiments))

    def rows(self) -> list[list[str]]:
        """One row per experiment: name, duration, what it does, held out."""
        return [[e.name, f'{fmt(e.duration)} s', e.describe(), 'held out' if e.held_out else '']
                for e in self.experiments]


# ---- the standard campaign ------------------------------------------------------------------

def low_load_pressure(params: Params) -> float:
    """The load pressure of the low-load staircases [Pa, gauge]: 40 bar below the params
    file's, at least 30 % of it."""
    P_u = params.line.P_u
    return max(P_u - LOW_LOAD_DROP, 0.3 * P_u)


def standard_plan(params: Params, dwell: float = 1.0, hold: float = 1.0) -> Plan:
    """The standard calibration campaign for the plant ``params``.

    Current staircases up and down in the regulating range (:data:`STANDARD_LEVELS`) at the
    params file's load pressure; the same up and down at a load pressure 40 bar lower; the
    load pressure stepped down and back at the range's middle, ``hold`` seconds a level; and,
    held out, a current sine with a load-pressure step. The labels of the first four are the
    names :func:`hydropump_ctrl.ident.design.candidate_inputs` gives them.
    """
    low = low_load_pressure(params)
    P_u = params.line.P_u
    up = list(STANDARD_LEVELS)
    both = up + up[::-1][1:]

    def stairs(levels):
        return Schedule('steps', tuple((k * dwell, v) for k, v in enumerate(levels)),
                        unit='percent', dwell=dwell)
    exps = [
        PlanExperiment('staircase_up', len(up) * dwell, stairs(up), label='staircase up'),
        PlanExperiment('staircase_down', len(up) * dwell, stairs(up[::-1]),
                       label='staircase down'),
        PlanExperiment('staircases_low_load', len(both) * dwell, stairs(both),
                       load_pressure=((0.0, low),),
                       label='staircases at a lower load pressure'),
        PlanExperiment('load_steps', 3.0 * hold, Schedule(offset=50.0, unit='percent'),
                       load_pressure=((0.0, P_u), (hold, low), (2.0 * hold, P_u)),
                       label='load-pressure steps'),
        PlanExperiment('sine_load_step', 4.0, Schedule(offset=50.0, sine=(15.0, 0.5, 0.0, 0.0),
                                                       unit='percent'),
                       load_pressure=((2.0, low),), held_out=True,
                       label='held out: current sine with a load-pressure step'),
    ]
    return Plan(exps, source=STANDARD)


def example_plan_path() -> Path:
    """``config/plans/calibration.yaml``: the standard plan as a file to copy and edit."""
    return default_params_path().parent / 'plans' / 'calibration.yaml'


# ---- reading and checking -------------------------------------------------------------------

def load_plan(spec: str | Path, params: Params, period: float = CONTROL_PERIOD) -> Plan:
    """The plan named ``spec`` (:data:`STANDARD`) or in the YAML file ``spec``, checked
    against the plant ``params``.

    Raises
    ------
    PlanError
        One line per problem, each naming the experiment and the field.
    """
    if str(spec) == STANDARD:
        plan = standard_plan(params)
        plan.warnings = plan_warnings(plan, period)
        return plan
    path = Path(spec)
    if path.is_dir():
        raise PlanError([f'{path}: is a folder; give a plan file or {STANDARD!r}'])
    if not path.is_file():
        raise PlanError([f'{path}: no such plan file (give a YAML file or {STANDARD!r}, the '
                         'standard calibration campaign)'])
    try:
        doc = read_yaml(path)
    except ParamError as exc:
        raise PlanError(exc.lines, str(path)) from None
    return parse_plan(doc, params, source=str(path), period=period)


def parse_plan(doc: Any, params: Params, source: str = '', period: float = CONTROL_PERIOD
               ) -> Plan:
    """A plan from its YAML form (a list of experiments), checked against the plant
    ``params``; :class:`PlanError` with every problem found."""
    if not isinstance(doc, list) or not doc:
        raise PlanError(['expected a list of experiments (- name: ..., duration: ..., '
                         'current: {...})'], source or None)
    errors: list[str] = []
    notes: list[str] = []
    exps = []
    first: dict[str, int] = {}
    for i, item in enumerate(doc, 1):
        where = f'experiment {i}'
        if isinstance(item, Mapping) and isinstance(item.get('name'), str):
            where = f'experiment {i} ({item["name"]})'
            if item['name'] in first:
                errors.append(f'{where}: name: {item["name"]!r} is the name of experiment '
                              f'{first[item["name"]]} too; each experiment needs its own (it '
                              'names the bag)')
            first.setdefault(item['name'], i)
        before = len(errors)
        exp = _experiment(item, where, errors, notes)
        if exp is not None and len(errors) == before:
            errors += [f'{where}: {line}' for line in experiment_errors(exp, params, period)]
            exps.append(exp)
    if errors:
        raise PlanError(errors, source or None)
    plan = Plan(exps, source=source)
    plan.warnings = notes + plan_warnings(plan, period)
    return plan


def check_plan(plan: Plan, params: Params, period: float = CONTROL_PERIOD) -> None:
    """Check ``plan`` against another plant (a running simulator's): :class:`PlanError`."""
    errors = [f'experiment {i} ({e.name}): {line}' for i, e in enumerate(plan.experiments, 1)
              for line in experiment_errors(e, params, period)]
    if errors:
        raise PlanError(errors, plan.source or None)


def _unknown(key: Any, accepted: Sequence[str], what: str) -> str:
    close = closest_name(str(key), accepted)
    hint = f' (did you mean {close}?)' if close else ''
    return f'{key}: unknown {what}{hint}; accepted: {", ".join(accepted)}'


def _experiment(item: Any, where: str, errors: list[str], notes: list[str]
                ) -> PlanExperiment | None:
    """The fields of one experiment, checked alone (types, presence, signs)."""
    if not isinstance(item, Mapping):
        errors.append(f'{where}: expected a mapping (name: ..., duration: ..., current: ...)')
        return None
    for key in item:
        if key not in EXPERIMENT_KEYS:
            errors.append(f'{where}: {_unknown(key, EXPERIMENT_KEYS, "key")}')
    name = item.get('name')
    if name is None:
        errors.append(f'{where}: name: missing (the bag name: letters, digits, _ . -)')
    elif not isinstance(name, str) or not NAME.match(name):
        errors.append(f'{where}: name = {name!r}: use letters, digits, _ . - (it names the '
                      'bag folder), up to 100 characters')
    elif name == LOG_FOLDER:
        errors.append(f"{where}: name = {name!r}: taken by the folder of the nodes' logs; "
                      'choose another')
    duration = None
    if 'duration' not in item:
        errors.append(f'{where}: duration: missing (simulated time, s)')
    else:
        duration = check_number(item['duration'], f'{where}: duration', errors, unit='s',
                                sign='> 0')
    current = _current(item.get('current'), f'{where}: current', errors, notes)
    steps = {}
    for key in STEP_INPUTS:
        steps[key] = _steps(item.get(key), f'{where}: {key}', errors)
    seed = item.get('seed')
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)
                             or not 0 <= seed <= SEED_MAX):
        errors.append(f'{where}: seed = {seed!r}: expected an integer in [0, {SEED_MAX}]')
    held = item.get('held_out', False)
    if not isinstance(held, bool):
        errors.append(f'{where}: held_out = {held!r}: expected true or false')
    label = item.get('label', '')
    if not isinstance(label, str):
        errors.append(f'{where}: label = {label!r}: expected text')
    if not (isinstance(name, str) and duration is not None and current is not None
            and all(s is not None for s in steps.values())):
        return None
    return PlanExperiment(name, duration, current, steps['load_pressure'], steps['aperture'],
                          seed if isinstance(seed, int) else None, held is True,
                          label if isinstance(label, str) else '')


def _current(data: Any, where: str, errors: list[str], notes: list[str]) -> Schedule | None:
    if data is None:
        errors.append(f'{where}: missing (a staircase: {{staircase: {{levels: [...], dwell: '
                      '1.0}, unit: percent}, or a sine: {offset: 0.5, sine: {amplitude, '
                      'frequency}, unit: A})')
        return None
    if isinstance(data, Mapping) and 'shape' in data:
        data = _new_spelling(data, where, errors, notes)
        if data is None:
            return None
    cur = parse_schedule(data, where, errors, units=UNITS, time_sign='>= 0',
                         bases=CURRENT_BASES)
    if cur is not None and is_sine(cur) and (cur.kind != 'constant' or cur.sine[2:] != (0, 0)
                                             or cur.sine[1] <= 0 or cur.sine[0] <= 0):
        errors.append(f'{where}.sine: the controller runs a sine of amplitude and frequency > 0 '
                      'about a constant offset, from the start (no steps under it, no phase '
                      'or start)')
        return None
    return cur


def _new_spelling(data: Mapping, where: str, errors: list[str], notes: list[str]
                  ) -> dict | None:
    """A current in the spelling before the schedule grammar (``shape: staircase`` or
    ``shape: sine``) in today's, with a note naming it."""
    shape = data['shape']
    if not isinstance(shape, str) or shape not in OLD_SHAPES:
        errors.append(f'{where}.shape = {shape!r}: expected staircase or sine (or write the '
                      'schedule itself: staircase: {levels, dwell}, or offset and sine)')
        return None
    keys = OLD_SHAPES[shape]
    before = len(errors)
    for key in data:
        if key not in ('shape', 'unit') + keys:
            other = [s for s, k in OLD_SHAPES.items() if key in k]
            errors.append(f'{where}.{key}: ' + (
                f'belongs to a {other[0]}, not a {shape} (a {shape} takes {", ".join(keys)})'
                if other else _unknown(key, ('shape', 'unit') + keys, 'key')))
    if len(errors) > before:
        return None
    out = {'unit': data['unit']} if 'unit' in data else {}
    if shape == 'staircase':
        out['staircase'] = {k: data[k] for k in keys if k in data}
        new = 'staircase: {levels: [...], dwell: ...}'
    else:
        out['offset'] = data.get('offset')
        out['sine'] = {k: data[k] for k in ('amplitude', 'frequency') if k in data}
        new = 'offset: ..., sine: {amplitude: ..., frequency: ...}'
    notes.append(f'{where}: shape: {shape} is the old spelling; write {new}')
    return out


def _steps(data: Any, where: str, errors: list[str]) -> tuple | None:
    """Load-pressure or aperture steps ``[[t, value], ...]`` (or one value from the start);
    values are checked with the plant."""
    if data is None:
        return ()
    sched = parse_schedule(data, where, errors, time_sign='>= 0', bases=('steps', 'offset'),
                           sine=False)
    if sched is None:
        return None
    return sched.points or ((0.0, sched.offset),)


def experiment_errors(exp: PlanExperiment, params: Params, period: float = CONTROL_PERIOD
                      ) -> list[str]:
    """What the plant ``params`` and the controller refuse in ``exp``: currents outside the
    range of eq. 2, load pressures and apertures outside their parameters' ranges (a value
    typed in bar is named so), times at or after the end, a dwell or a sine too fast for the
    controller's updates."""
    out = []
    cur = exp.current
    lo, hi = params.I_limits
    eq2 = f"the plant's current range of eq. 2, [{fmt(lo)}, {fmt(hi)}] A"

    def current_line(what: str, value: float) -> str | None:
        if cur.unit == 'percent':
            if not 0.0 <= value <= 100.0:
                return (f'current.{what} = {fmt(value)} %: outside [0, 100] % of displacement'
                        + (' (a fraction? write percent: 0.5 -> 50)' if 0 < value < 1 else ''))
            value = Schedule(offset=value, unit='percent').in_amperes(params).offset
        if not lo - 1e-12 <= value <= hi + 1e-12:
            return f'current.{what} = {fmt(value)} A: outside {eq2}'
        return None
    if is_sine(cur):
        amp = cur.sine[0]
        extremes = [('offset - amplitude', cur.offset - amp),
                    ('offset + amplitude', cur.offset + amp)]
    elif cur.dwell:
        extremes = [(f'staircase.levels[{k}]', v) for k, v in enumerate(cur.levels)]
    elif cur.points:
        extremes = [(f'steps[{k}] value', v) for k, v in enumerate(cur.levels)]
    else:
        extremes = [('offset', cur.offset)]
    out += [line for what, v in extremes if (line := current_line(what, v))]
    gaps = np.diff([0.0] + [t for t, _ in cur.points])
    if cur.points and np.any(gaps[1:] < period - 1e-12):
        what = 'staircase.dwell' if cur.dwell else 'steps'
        out.append(f"current.{what}: {fmt(float(np.min(gaps[1:])))} s between levels, shorter "
                   f"than the controller's update period ({fmt(period)} s)")
    if is_sine(cur):
        fs = controller_specs()['excitation.frequency']
        freq = cur.sine[1]
        if not fs.range[0] <= freq <= min(fs.range[1], 0.5 / period):
            out.append(f"current.sine.frequency = {fmt(freq)} Hz: outside the controller's "
                       f'[{fmt(fs.range[0])}, {fmt(min(fs.range[1], 0.5 / period))}] Hz')
    for key in STEP_INPUTS:
        spec = input_spec(key)
        for k, (t, v) in enumerate(getattr(exp, key)):
            if t >= exp.duration:
                out.append(f'{key}[{k}] time = {fmt(t)} s: at or after the end of the '
                           f'experiment ({fmt(exp.duration)} s)')
            _, err = check_value(spec, v)
            if err:
                # check_value's line names the schema entry (load_pressure = ...): say where.
                out.append(f'{key}[{k}] value{err[len(key):]}' if err.startswith(key)
                           else f'{key}[{k}]: {err}')
    return out


def plan_warnings(plan: Plan, period: float = CONTROL_PERIOD) -> list[str]:
    """What runs but is probably not meant: no held-out experiment, levels the duration cuts
    off, times that are not whole control periods (they take effect at the next instant)."""
    out = []
    if not plan.held_out:
        out.append('no experiment is held out (held_out: true): a calibration on every bag '
                   'leaves none to validate on')
    for e in plan.experiments:
        cur = e.current
        late = sum(t >= e.duration - 1e-9 for t in cur.change_times)
        if late:
            out.append(f'experiment {e.name}: duration {fmt(e.duration)} s ends before the last'
                       f' level: {late} of {len(cur.levels)} levels are never reached')
        times = [('duration', e.duration)]
        times += ([('current.staircase.dwell', cur.dwell)] if cur.dwell else
                  [(f'current.steps[{k}] time', t) for k, (t, _) in enumerate(cur.points)])
        times += [(f'{key}[{k}] time', t) for key in STEP_INPUTS
                  for k, (t, _) in enumerate(getattr(e, key))]
        for what, t in times:
            if abs(t / period - round(t / period)) > 1e-6:
                out.append(f'experiment {e.name}: {what} = {fmt(t)} s is not a whole number '
                           f'of control periods ({fmt(period)} s): it takes effect at '
                           f'{fmt(control_instant(t, period))} s')
    return out


# ---- what an experiment holds ---------------------------------------------------------------

def control_instant(t: float, period: float | None = CONTROL_PERIOD) -> float:
    """The first control instant at or after ``t`` [s] (``t`` itself without a period)."""
    if not period:
        return float(t)
    return math.ceil(t / period - 1e-6) * period


def _index(t: float, dt: float) -> int:
    return max(0, math.ceil(t / dt - 1e-6))


def _held(n: int, initial: float, changes: Sequence[tuple[int, float]]) -> np.ndarray:
    out = np.full(n, float(initial))
    for i, v in changes:
        out[min(i, n):] = v
    return out


@dataclass(frozen=True)
class HeldInputs:
    """An experiment's inputs held per sample: ``t[k] = k dt`` from the start [s], the
    absolute current [A], the gauge load pressure [Pa] and the aperture [-], each held from
    ``t[k]`` to ``t[k + 1]``."""

    t: np.ndarray
    current: np.ndarray
    load_pressure: np.ndarray
    aperture: np.ndarray

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else 0.0


def held_inputs(exp: PlanExperiment, params: Params, dt: float = 1.0e-3,
                period: float | None = CONTROL_PERIOD) -> HeldInputs:
    """What ``exp`` holds on a grid of ``dt`` [s] over its duration, as the nodes run it.

    Parameters
    ----------
    exp : PlanExperiment
        The experiment.
    params : Params
        The plant: its static map (levels in percent), load pressure and aperture (before the
        experiment's first step).
    dt : float
        Grid step [s]; ``round(duration / dt)`` samples.
    period : float or None
        The controller's update period [s]: changes take effect at its instants and a sine
        is held between them, as the commanded current is; ``None``: at the times given, the
        sine sampled on the grid.

    Returns
    -------
    HeldInputs
    """
    n = int(round(exp.duration / dt))
    t = np.arange(n) * dt
    cur = exp.current.in_amperes(params)
    if is_sine(cur):
        amp, freq, _, _ = cur.sine
        tc = t if not period else np.floor(t / period + 1e-6) * period
        current = cur.offset + amp * np.sin(2.0 * np.pi * freq * tc)
    else:
        current = _held(n, cur.levels[0], [(_index(control_instant(ts, period), dt), a)
                                           for ts, a in cur.points])

    def steps(key: str, initial: float) -> np.ndarray:
        return _held(n, initial, [(_index(control_instant(ts, period), dt), v)
                                  for ts, v in getattr(exp, key)])
    return HeldInputs(t, current, steps('load_pressure', params.line.P_u),
                      steps('aperture', params.line.xi_u))


# ---- through the node graph -----------------------------------------------------------------

def node_experiment(exp: PlanExperiment, params: Params, period: float = CONTROL_PERIOD
                    ) -> Experiment:
    """``exp`` as the node graph runs it: the controller in open loop with a one-level
    staircase per level (``excitation.repeat`` false, so nothing restarts), each next level
    set at its control instant; a sine as the controller's own; load-pressure and aperture
    steps as the simulator's live ``line.P_u`` and ``line.xi_u``."""
    cur = exp.current.in_amperes(params)
    base = {'controller.mode': 'open_loop', 'excitation.unit': 'A',
            'excitation.direction': 'up', 'excitation.repeat': False}
    events = []
    if is_sine(cur):
        start = cur.offset
        ctrl = {**base, 'excitation.frequency': cur.sine[1], 'excitation.amplitude': cur.sine[0],
                'excitation.offset': start, 'excitation.signal': 'sine'}
    else:
        amps = cur.levels
        start = amps[0]
        # One level, held (no repeat): its dwell does not matter. The next levels are set
        # on levels_min, at or below levels_max.
        ctrl = {**base, 'excitation.levels_min': start, 'excitation.levels_max': max(amps),
                'excitation.n_levels': 1, 'excitation.signal': 'staircase'}
        for ts, a in cur.points[1:]:
            t = control_instant(ts, period)
            if t < exp.duration - 1e-9:
                events.append((t, 'controller', {'excitation.levels_min': a}))
    inputs = {}
    for key, name in STEP_INPUTS.items():
        for ts, v in getattr(exp, key):
            t = control_instant(ts, period)
            if t < 1e-9:
                inputs[name] = v
            else:
                events.append((t, 'simulator', {name: v}))
    sim = operating_point(params, start, exp.noise_seed, **inputs)
    return Experiment(exp.name, exp.label or exp.describe(), control_instant(exp.duration,
                                                                             period),
                      sim, ctrl, suite_topics(), events, ctrl_first=dict(EXCITATION_BASE))
