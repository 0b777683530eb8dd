"""Sweep specification files: the plant, the experiment, the parameters to vary, the outputs.

Example (SI units; see ``docs/sweeps.md``)::

    params: ../pump.yaml             # relative to this file, else to the working directory
    experiment:
      duration: 2.0                  # s
      current:                       # displacement fractions (0..1) of the nominal plant
        step: {from: 0.4, to: 0.6, at: 0.5}
    distributions:
      n: 40
      seed: 1
      parameters:
        actuator.mu_a: {normal: 0.05, relative: true}   # 1 sigma, 5 %
    outputs: [fopdt, {peak: P_l}]

Sampling methods: ``grid``, ``latin_hypercube``, ``distributions``, ``sobol`` (Saltelli, for
Sobol indices) and ``morris`` (trajectories, for Morris elementary effects), the last two
drawn by SALib.

Every problem is one line; all of them are reported at once (:class:`SweepError`), before any
run.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from hydropump_sim.errors import HydropumpError
from hydropump_sim.model import OUTPUTS
from hydropump_sim.params import load_params, Params
from hydropump_sim.schedule import CURRENT_UNITS, late_changes, parse_schedule
from hydropump_sim.schema import (
    check_number,
    check_value,
    fmt,
    ParamError,
    range_text,
    read_yaml,
    spec_map,
    unknown_key_line,
)


class SweepError(HydropumpError, ValueError):
    """Invalid sweep specification: one line per problem."""

    head = 'invalid sweep'


METHODS = ('grid', 'latin_hypercube', 'distributions', 'sobol', 'morris')
_TOP = {'params', 'experiment', 'outputs', 'keep_relations', *METHODS}
_EXPERIMENT = {'duration', 'current', 'scenario', 'model', 'dt_out', 'fidelity', 'bandwidth'}
OUTPUT_KINDS = ('fopdt', 'peak', 'final', 'step')
# Columns each output adds to the table, and their units.
FOPDT_COLUMNS = {'fopdt_G0': '%', 'fopdt_tau': 's', 'fopdt_td': 's'}
STEP_COLUMNS = {'step_rise': 's', 'step_overshoot': '%', 'step_settling': 's'}

# Relations the schema enforces between plant parameters (params.py cross-checks): when a
# sweep varies one side, the other follows, so that a tolerance on mu_a is a tolerance on the
# orifice, not a refused parameter set. Each entry: the parameter that follows, the ones it
# follows, the relation. The first entry that applies wins (one follower per relation).
RELATIONS = (
    ('actuator.mu_a', ('actuator.h_a', 'fluid.rho'), lambda h, rho: h * math.sqrt(2.0 / rho)),
    ('actuator.h_a', ('actuator.mu_a', 'fluid.rho'), lambda mu, rho: mu / math.sqrt(2.0 / rho)),
    ('actuator.S_a', ('actuator.d_a',), lambda d: math.pi * d ** 2 / 4.0),
    ('actuator.d_a', ('actuator.S_a',), lambda s: math.sqrt(4.0 * s / math.pi)),
    # Design condition D1, phi_s I_max = K_a x_a_max: the solenoid is matched to the spring.
    ('spool.phi_s', ('spool.K_a', 'pump.x_a_max', 'spool.I_max'), lambda k, x, i: k * x / i),
    ('spool.K_a', ('spool.phi_s', 'spool.I_max', 'pump.x_a_max'), lambda p, i, x: p * i / x),
)


@dataclass(frozen=True)
class Experiment:
    """What every run simulates: duration [s], model, and the inputs as
    :func:`hydropump_sim.simulate` keywords (absolute current [A], operating point)."""

    duration: float
    model: str = 'fine'
    dt_out: float = 1.0e-3
    inputs: dict = field(default_factory=dict)
    #: Times [s] at which the current steps (the step metrics use the first).
    step_times: tuple = ()
    #: What ``fidelity: simplified`` made of the model (its error bound), else empty.
    fidelity: str = ''


@dataclass(frozen=True)
class Sweep:
    """A checked sweep: the nominal plant, the experiment, the samples, the outputs."""

    plant: Params
    experiment: Experiment
    method: str
    names: tuple          # varied parameters, dotted
    samples: np.ndarray   # (runs, len(names)) SI values
    outputs: tuple        # (kind, signal or None)
    keep_relations: bool = True
    source: str = ''
    #: SALib problem of a ``sobol`` or ``morris`` sweep (bounds), else None.
    problem: dict | None = None
    #: Grid levels of a ``morris`` sweep (SALib's ``num_levels``).
    levels: int = 4

    @property
    def n_runs(self) -> int:
        return int(self.samples.shape[0])

    def columns(self) -> dict[str, str]:
        """Output columns and their units."""
        out: dict[str, str] = {}
        for kind, sig in self.outputs:
            if kind == 'fopdt':
                out.update(FOPDT_COLUMNS)
            elif kind == 'step':
                out.update(STEP_COLUMNS)
            else:
                unit = dict(zip(OUTPUTS, _output_units()))[sig]
                out[f'{kind}_{sig}'] = unit
        return out

    def fingerprint(self) -> str:
        """A hash of everything that decides the results: a resumed sweep must match it."""
        doc = {'plant': self.plant.flat(), 'experiment': repr(self.experiment),
               'names': self.names, 'samples': self.samples.tolist(),
               'outputs': self.outputs, 'keep_relations': self.keep_relations}
        if self.method == 'morris':      # the levels decide the analysis, not the runs alone
            doc['levels'] = self.levels
        return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode())\
            .hexdigest()[:16]


def _output_units():
    from hydropump_sim.model import OUTPUT_UNITS
    return OUTPUT_UNITS


#: The most runs a sweep may hold: at 30 ms a run, eight hours on one core, and 1e6 rows of
#: samples and results. Checked on the count before any sample is drawn (a grid of 1000^3,
#: a Sobol base of 2^30 allocated until the machine stopped the process).
MAX_RUNS = 1_000_000


def _too_many(runs: int, what: str, errors: list[str]) -> bool:
    """Whether ``runs`` is beyond :data:`MAX_RUNS` (an error line saying how many)."""
    if runs <= MAX_RUNS:
        return False
    errors.append(f'{what}: {runs:.3g} runs, more than the {MAX_RUNS:.0e} a sweep may hold '
                  f'(about {runs * 0.03 / 3600:.3g} h of one core at 30 ms a run): '
                  'fewer samples, or several sweeps')
    return True


def _count(v: Any, where: str, errors: list[str]) -> int | None:
    if isinstance(v, bool) or not isinstance(v, int):
        errors.append(f'{where} = {v!r}: expected a whole number of samples')
        return None
    if v < 1:
        errors.append(f'{where} = {v}: zero samples; give at least 1')
        return None
    if _too_many(v, f'{where} = {v}', errors):
        return None
    return v


def _seed(block: Mapping, where: str, errors: list[str]) -> int:
    s = block.get('seed', 0)
    if isinstance(s, bool) or not isinstance(s, int) or s < 0:
        errors.append(f'{where}.seed = {s!r}: expected a whole number >= 0')
        return 0
    return s


def _resolve(path: Any, base: Path, where: str, errors: list[str]) -> Path | None:
    if not isinstance(path, str) or not path:
        errors.append(f'{where} = {path!r}: expected a file name')
        return None
    for cand in (base / path, Path(path)):
        if cand.is_file():
            return cand
    errors.append(f'{where} = {path}: no such file (looked beside the spec and in the '
                  'working directory)')
    return None


# ---- experiment ---------------------------------------------------------------------------

def _current(block: Any, duration: float, plant: Params, errors: list[str]):
    """The current schedule in absolute amperes and its change times: a schedule
    (:mod:`hydropump_sim.schedule`), in fractions of displacement unless it says its unit."""
    where = 'experiment.current'
    cur = parse_schedule(block, where, errors, units=CURRENT_UNITS, unit='fraction',
                         time_sign='>= 0')
    if cur is None:
        return None, ()
    late = late_changes(cur, duration, where)
    lo, hi = {'fraction': (0.0, 1.0), 'percent': (0.0, 100.0)}.get(cur.unit, plant.I_limits)
    amp = abs(cur.sine[0])
    bad = [v for v in cur.levels if not lo - 1e-12 <= v - amp <= v + amp <= hi + 1e-12]
    if late or bad:
        unit = ' A' if cur.unit == 'A' else f' ({cur.unit} of displacement)'
        errors.extend(late + [f'{where}: level {fmt(v)} outside {fmt(lo)}..{fmt(hi)}{unit}'
                              for v in bad[:1]])
        return None, ()
    # Step metrics judge held steps: a ramp's break points are none.
    return cur.in_amperes(plant), cur.change_times if cur.kind == 'steps' else ()


def _experiment(doc: Any, base: Path, plant: Params | None, errors: list[str]):
    """The experiment and, from a scenario file, a plant to fall back on."""
    if not isinstance(doc, Mapping):
        errors.append('experiment: missing; expected duration and current (or scenario)')
        return None, None
    for key in set(doc) - _EXPERIMENT:
        errors.append(f'experiment.{key}: unknown key (use {", ".join(sorted(_EXPERIMENT))})')
    inputs, scen_plant, duration, model, dt_out = {}, None, None, 'fine', 1.0e-3
    step_times: tuple = ()
    if 'scenario' in doc:
        path = _resolve(doc['scenario'], base, 'experiment.scenario', errors)
        if path is not None:
            from hydropump_sim.scenario import load_scenario, ScenarioError
            try:
                sc = load_scenario(path)
            except ScenarioError as exc:
                errors.extend(f'{path}: {line}' for line in exc.lines)
                return None, None
            inputs = dict(sc.inputs)
            duration, model, dt_out, scen_plant = sc.duration, sc.model, sc.dt_out, sc.params
            cur = inputs.get('current')
            if cur is not None and cur.kind == 'steps':
                step_times = cur.change_times
    if 'duration' in doc:
        duration = check_number(doc['duration'], 'experiment.duration', errors, sign='> 0')
    elif duration is None:
        errors.append('experiment.duration: missing (s)')
    model = doc.get('model', model)
    if model not in ('fine', 'simplified', 'simplified_Kc'):
        errors.append(f'experiment.model = {model!r}: use fine, simplified or simplified_Kc')
    if 'dt_out' in doc:
        dt_out = check_number(doc['dt_out'], 'experiment.dt_out', errors, sign='> 0') or 1.0e-3
    nominal = plant or scen_plant
    model, fidelity = _fidelity(doc, model, nominal, errors)
    if 'current' in doc and duration and nominal is not None:
        fn, step_times = _current(doc['current'], duration, nominal, errors)
        if fn is not None:
            inputs['current'] = fn
    elif 'current' not in doc and 'scenario' not in doc:
        errors.append('experiment: give current (step or staircase) or a scenario file')
    if duration is None:
        return None, scen_plant
    return Experiment(duration=duration, model=model, dt_out=dt_out, inputs=inputs,
                      step_times=step_times, fidelity=fidelity), scen_plant


def _fidelity(doc: Mapping, model: str, nominal: Params | None, errors: list[str]
              ) -> tuple[str, str]:
    """``experiment.fidelity`` (and ``bandwidth`` [Hz]): the model every run simulates,
    section IV's simplified one where its modes lie beyond the bandwidth
    (:func:`hydropump_sim.reduction.with_fidelity` on the nominal plant), and what it is."""
    if 'fidelity' not in doc:
        if 'bandwidth' in doc:
            errors.append('experiment.bandwidth: goes with fidelity: simplified')
        return model, ''
    from hydropump_sim.errors import InputError
    from hydropump_sim.plant_model import PumpModel
    from hydropump_sim.reduction import FIDELITIES, with_fidelity
    fidelity = doc['fidelity']
    if 'model' in doc:
        errors.append('experiment: give model or fidelity, not both')
    elif fidelity not in FIDELITIES:
        errors.append(f'experiment.fidelity = {fidelity!r}: use {" or ".join(FIDELITIES)}')
    elif fidelity == 'simplified' and nominal is not None:
        bandwidth = check_number(doc.get('bandwidth', 0.0), 'experiment.bandwidth', errors,
                                 sign='>= 0')
        if bandwidth is not None:
            try:
                simple, fid = with_fidelity(PumpModel(nominal), 'simplified', bandwidth)
            except InputError as exc:
                errors.append(f'experiment.fidelity: {exc}')
            else:
                return simple.model, fid.text()
    return model, ''


# ---- samples ------------------------------------------------------------------------------

def _param(name: Any, where: str, specs: dict, errors: list[str]):
    if not isinstance(name, str) or name not in specs:
        errors.append(f'{where}: ' + unknown_key_line(str(name), specs))
        return None
    s = specs[name]
    if s.type is not float:
        errors.append(f'{where}: {name} is not a real-valued parameter ({s.type.__name__})')
        return None
    return s


def _in_range(s, value: float, what: str, errors: list[str]) -> bool:
    _, err = check_value(s, value)
    if err:
        errors.append(f'{what}: {err}')
        return False
    return True


def _grid(block: Mapping, plant: Params, specs: dict, errors: list[str]):
    rel = block.get('relative', False)
    params = block.get('parameters')
    if not isinstance(params, Mapping) or not params:
        errors.append('grid.parameters: expected a mapping of parameter -> values or '
                      '{from, to, n}')
        return (), None
    names, axes = [], []
    nominal = plant.flat()
    for name, vals in params.items():
        where = f'grid.parameters.{name}'
        s = _param(name, 'grid.parameters', specs, errors)
        if s is None:
            continue
        if isinstance(vals, Mapping):
            lo = check_number(vals.get('from'), f'{where}.from', errors)
            hi = check_number(vals.get('to'), f'{where}.to', errors)
            n = _count(vals.get('n'), f'{where}.n', errors)
            if None in (lo, hi, n):
                continue
            vals = list(np.linspace(lo, hi, n))
        elif not isinstance(vals, list) or not vals:
            errors.append(f'{where}: zero samples; expected a list of values or {{from, to, n}}')
            continue
        vs = [check_number(v, where, errors) for v in vals]
        if any(v is None for v in vs):
            continue
        vs = [v * nominal[name] if rel else v for v in vs]
        if all(_in_range(s, v, 'grid', errors) for v in vs):
            names.append(name)
            axes.append(vs)
    if errors or not axes:
        return tuple(names), None
    if _too_many(math.prod(len(a) for a in axes), 'grid', errors):
        return tuple(names), None
    mesh = np.meshgrid(*axes, indexing='ij')
    return tuple(names), np.column_stack([m.ravel() for m in mesh])


def _bounds(block: Mapping, key: str, plant: Params, specs: dict, errors: list[str]):
    rel = block.get('relative', False)
    raw = block.get('bounds')
    if not isinstance(raw, Mapping) or not raw:
        errors.append(f'{key}.bounds: expected a mapping of parameter -> [low, high]')
        return (), None
    nominal = plant.flat()
    names, lo, hi = [], [], []
    for name, pair in raw.items():
        s = _param(name, f'{key}.bounds', specs, errors)
        if s is None:
            continue
        where = f'{key}.bounds.{name}'
        if not isinstance(pair, list) or len(pair) != 2:
            errors.append(f'{where} = {pair!r}: expected [low, high]')
            continue
        a, b = (check_number(v, where, errors) for v in pair)
        if a is None or b is None:
            continue
        if rel:
            a, b = a * nominal[name], b * nominal[name]
        if not a < b:
            errors.append(f'{where}: low {fmt(a)} must be below high {fmt(b)}')
            continue
        if _in_range(s, a, key, errors) and _in_range(s, b, key, errors):
            names.append(name)
            lo.append(a)
            hi.append(b)
    return tuple(names), (np.array(lo), np.array(hi))


def _lhs(block: Mapping, plant, specs, errors):
    n = _count(block.get('n'), 'latin_hypercube.n', errors)
    seed = _seed(block, 'latin_hypercube', errors)
    names, b = _bounds(block, 'latin_hypercube', plant, specs, errors)
    if errors or n is None or not names:
        return names, None
    from scipy.stats import qmc
    unit = qmc.LatinHypercube(len(names), rng=np.random.default_rng(seed)).random(n)
    return names, b[0] + unit * (b[1] - b[0])


def _sobol(block: Mapping, plant, specs, errors):
    n = _count(block.get('n'), 'sobol.n', errors)
    if n is not None and n & (n - 1):
        errors.append(f'sobol.n = {n}: expected a power of 2 (Saltelli base sample)')
    seed = _seed(block, 'sobol', errors)
    names, b = _bounds(block, 'sobol', plant, specs, errors)
    if errors or n is None or not names:
        return names, None, None
    if _too_many(n * (len(names) + 2), f'sobol.n = {n} over {len(names)} parameters',
                 errors):
        return names, None, None
    from SALib.sample import sobol as salib_sobol
    problem = {'num_vars': len(names), 'names': list(names),
               'bounds': [[float(a), float(c)] for a, c in zip(*b)]}
    x = salib_sobol.sample(problem, n, calc_second_order=False, seed=seed)
    return names, x, problem


def _morris(block: Mapping, plant, specs, errors):
    """Morris trajectories (SALib): ``r`` of them, ``r (D + 1)`` runs, on a grid of
    ``levels`` (an even number) per input."""
    r = _count(block.get('r'), 'morris.r', errors)
    levels = block.get('levels', 4)
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 2 or levels % 2:
        errors.append(f'morris.levels = {levels!r}: expected an even whole number >= 2 '
                      '(grid levels per input)')
        levels = None
    bad = set(block) - {'r', 'levels', 'seed', 'relative', 'bounds'}
    if bad:
        errors.append(f'morris: unknown key(s) {", ".join(sorted(map(str, bad)))} (use r, '
                      'levels, seed, relative, bounds)')
    seed = _seed(block, 'morris', errors)
    names, b = _bounds(block, 'morris', plant, specs, errors)
    if errors or r is None or levels is None or not names:
        return names, None, None, 4
    if _too_many(r * (len(names) + 1), f'morris.r = {r} over {len(names)} parameters',
                 errors):
        return names, None, None, 4
    from SALib.sample import morris as salib_morris
    problem = {'num_vars': len(names), 'names': list(names),
               'bounds': [[float(a), float(c)] for a, c in zip(*b)]}
    x = salib_morris.sample(problem, r, num_levels=levels, seed=seed)
    return names, x, problem, levels


def _distributions(block: Mapping, plant, specs, errors):
    n = _count(block.get('n'), 'distributions.n', errors)
    seed = _seed(block, 'distributions', errors)
    raw = block.get('parameters')
    if not isinstance(raw, Mapping) or not raw:
        errors.append('distributions.parameters: expected a mapping of parameter -> '
                      '{normal: sigma} or {uniform: half-width}, relative: true|false')
        return (), None
    nominal = plant.flat()
    names, kinds, widths, rels = [], [], [], []
    for name, d in raw.items():
        s = _param(name, 'distributions.parameters', specs, errors)
        if s is None:
            continue
        where = f'distributions.parameters.{name}'
        if not isinstance(d, Mapping) or len([k for k in d if k in ('normal', 'uniform')]) != 1:
            errors.append(f'{where}: expected one of normal: SIGMA or uniform: HALF_WIDTH')
            continue
        bad = set(d) - {'normal', 'uniform', 'relative'}
        if bad:
            errors.append(f'{where}: unknown key(s) {", ".join(sorted(map(str, bad)))}')
        kind = 'normal' if 'normal' in d else 'uniform'
        w = check_number(d[kind], f'{where}.{kind}', errors, sign='> 0')
        rel = bool(d.get('relative', False))
        if w is None:
            continue
        # A uniform spread must stay inside the schema's range; a normal one may leave it in
        # its tails: such a run is recorded as refused (failed), not guessed at.
        if kind == 'uniform':
            span = w * abs(nominal[name]) if rel else w
            if not (_in_range(s, nominal[name] - span, 'distributions', errors)
                    and _in_range(s, nominal[name] + span, 'distributions', errors)):
                continue
        names.append(name)
        kinds.append(kind)
        widths.append(w)
        rels.append(rel)
    if errors or n is None or not names:
        return tuple(names), None
    rng = np.random.default_rng(seed)
    z = rng.standard_normal((n, len(names)))
    u = rng.uniform(-1.0, 1.0, (n, len(names)))
    x = np.empty((n, len(names)))
    for j, name in enumerate(names):
        draw = z[:, j] if kinds[j] == 'normal' else u[:, j]
        x0 = nominal[name]
        x[:, j] = x0 * (1.0 + widths[j] * draw) if rels[j] else x0 + widths[j] * draw
    return tuple(names), x


# ---- outputs ------------------------------------------------------------------------------

def _outputs(raw: Any, errors: list[str]) -> tuple:
    if not isinstance(raw, list) or not raw:
        errors.append('outputs: expected a list of fopdt, step, {peak: SIGNAL}, {final: SIGNAL}')
        return ()
    out = []
    for i, item in enumerate(raw):
        if item in ('fopdt', 'step'):
            out.append((item, None))
            continue
        if isinstance(item, Mapping) and len(item) == 1:
            kind, sig = next(iter(item.items()))
            if kind in ('peak', 'final'):
                if sig in OUTPUTS:
                    out.append((kind, sig))
                else:
                    errors.append(unknown_key_line(f'outputs[{i}].{kind} {sig}', OUTPUTS,
                                                   'signal').replace(
                        'did you mean ', f'did you mean {kind}: '))
                continue
        errors.append(f'outputs[{i}] = {item!r}: expected fopdt, step, {{peak: SIGNAL}} or '
                      f'{{final: SIGNAL}} (signals: {", ".join(OUTPUTS)})')
    if len(set(out)) != len(out):
        errors.append('outputs: an output is listed twice')
    return tuple(out)


# ---- the file -----------------------------------------------------------------------------

def load_sweep(path: str | Path) -> Sweep:
    """Read and check a sweep file; every problem at once, one line each.

    Raises
    ------
    SweepError
    """
    path = Path(path)
    try:
        doc = read_yaml(path)
    except ParamError as exc:
        raise SweepError(exc.lines, str(path)) from None
    if not isinstance(doc, Mapping):
        raise SweepError(['expected a mapping at the top level'], str(path))
    return sweep_from_dict(doc, path.parent, str(path))


def sweep_from_dict(doc: Mapping, base: Path = Path('.'), source: str = '') -> Sweep:
    """A :class:`Sweep` from its mapping; files are looked up beside ``base``."""
    errors: list[str] = []
    for key in set(doc) - _TOP:
        errors.append(unknown_key_line(str(key), sorted(_TOP), 'key'))
    plant = None
    if 'params' in doc:
        ppath = _resolve(doc['params'], base, 'params', errors)
        if ppath is not None:
            try:
                plant = load_params(ppath)
            except ParamError as exc:
                errors.extend(f'{ppath}: {line}' for line in exc.lines)
    experiment, scen_plant = _experiment(doc.get('experiment'), base, plant, errors)
    plant = plant or scen_plant
    if plant is None and 'params' not in doc:
        errors.append('params: missing (the plant file, e.g. config/pump.yaml)')
    outputs = _outputs(doc.get('outputs'), errors)
    if experiment is not None and not experiment.step_times and ('step', None) in outputs:
        errors.append('outputs: step needs a current that steps (steps, a staircase of two '
                      'levels or more, or step: {from, to, at})')
    keep = doc.get('keep_relations', True)
    if not isinstance(keep, bool):
        errors.append(f'keep_relations = {keep!r}: expected true or false')
    methods = [m for m in METHODS if m in doc]
    if len(methods) != 1:
        errors.append(f'give exactly one of {", ".join(METHODS)} (found '
                      f'{", ".join(methods) or "none"})')
    if plant is None or len(methods) != 1:
        raise SweepError(errors, source or None)
    method = methods[0]
    block = doc[method]
    if not isinstance(block, Mapping):
        errors.append(f'{method}: expected a mapping')
        raise SweepError(errors, source or None)
    specs = spec_map(Params)
    problem, levels = None, 4
    sample_errors: list[str] = []
    if method == 'grid':
        names, x = _grid(block, plant, specs, sample_errors)
    elif method == 'latin_hypercube':
        names, x = _lhs(block, plant, specs, sample_errors)
    elif method == 'sobol':
        names, x, problem = _sobol(block, plant, specs, sample_errors)
    elif method == 'morris':
        names, x, problem, levels = _morris(block, plant, specs, sample_errors)
    else:
        names, x = _distributions(block, plant, specs, sample_errors)
    errors += sample_errors
    if len(set(names)) != len(names):
        errors.append('a parameter is varied twice')
    if errors or x is None:
        raise SweepError(errors or [f'{method}: no samples'], source or None)
    return Sweep(plant=plant, experiment=experiment, method=method, names=tuple(names),
                 samples=np.asarray(x, dtype=float), outputs=outputs,
                 keep_relations=keep, source=source, problem=problem, levels=levels)


def followers(names: tuple, keep: bool = True) -> list[tuple]:
    """The relations that apply to a sweep of ``names``: (follower, inputs, function)."""
    if not keep:
        return []
    out, done = [], set()
    for follower, inputs, fn in RELATIONS:
        group = frozenset((follower, *inputs))
        if group in done or follower in names or not set(inputs) & set(names):
            continue
        done.add(group)
        out.append((follower, inputs, fn))
    return out


def describe_range(name: str) -> str:
    """The schema range of a parameter, as the messages show it."""
    return range_text(spec_map(Params)[name])
