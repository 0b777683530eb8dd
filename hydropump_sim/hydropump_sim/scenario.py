"""Scenario files: input signals scheduled in simulation time (SI units).

One format serves ``hydropump simulate`` and the ROS simulator node. Example::

    duration: 2.0                # s
    model: fine                  # fine | simplified | simplified_Kc
    params: pump.yaml            # optional, relative to this file
    overrides: {spool.F_coul_c: 0.5}
    inputs:
      current:                   # absolute solenoid current, A
        steps: [[0.0, 0.46], [0.5, 0.54]]
        sine: {amplitude: 0.01, frequency: 2.0, start: 1.0}
      aperture: {steps: [[0.0, 0.5], [1.0, 0.6]]}
      load_pressure: 1.2e+7      # Pa (gauge)
      shaft_speed: 25.0          # Hz

A signal is a number, or a mapping with ``steps`` (held values) or ``ramp`` (linear
interpolation) as ``[t, value]`` pairs, or ``offset``, plus an optional ``sine``
(``amplitude``, ``frequency`` [Hz], ``phase`` [rad], ``start`` [s]); the parts add up.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import HydropumpError
from .inputs import held
from .params import check_input, default_params_path, INPUTS, load_params, Params
from .schema import check_number, fmt, ParamError, read_yaml, unknown_key_line

SIGNALS = {
    'current': ('A', 'absolute solenoid current'),
    'load_pressure': ('Pa', 'load pressure P_u (gauge)'),
    'aperture': ('-', 'load aperture xi_u'),
    'shaft_speed': ('Hz', 'shaft frequency f_p'),
}
_TOP_KEYS = {'duration', 'model', 'params', 'overrides', 'inputs', 'dt_out', 'output'}
_SIGNAL_KEYS = {'steps', 'ramp', 'offset', 'sine'}
_SINE_KEYS = {'amplitude', 'frequency', 'phase', 'start'}


class ScenarioError(HydropumpError, ValueError):
    """Invalid scenario: ``lines`` holds one line per problem."""

    head = 'invalid scenario'


@dataclass(frozen=True)
class Signal:
    """A scheduled signal; call it with a time or an array of times [s]."""

    kind: str = 'constant'            # constant | steps | ramp
    points: tuple = ()                # ((t, value), ...)
    offset: float = 0.0
    sine: tuple = (0.0, 0.0, 0.0, 0.0)  # amplitude, frequency, phase, start

    def __call__(self, t):
        t = np.asarray(t, dtype=float)
        if self.kind == 'constant':
            v = np.full(t.shape, self.offset)
        else:
            ts = np.array([pt[0] for pt in self.points])
            vs = np.array([pt[1] for pt in self.points])
            v = np.interp(t, ts, vs) if self.kind == 'ramp' else np.asarray(held(ts, vs)(t))
        amp, freq, phase, start = self.sine
        if amp:
            v = v + np.where(t >= start, amp * np.sin(2 * np.pi * freq * (t - start) + phase),
                             0.0)
        return v if v.ndim else float(v)


@dataclass
class Scenario:
    duration: float
    model: str = 'fine'
    params: Params | None = None
    inputs: dict = field(default_factory=dict)
    dt_out: float = 1.0e-3
    output: str | None = None


def time_value_pairs(raw: Any, where: str, errors: list[str], *, time_sign: str = '',
                     unit: str = '') -> tuple | None:
    """``[[t, value], ...]`` with increasing times (``time_sign``: ``'>= 0'`` where time
    counts from a start; ``unit``: the value's unit, named in the messages), else ``None``
    and one line in ``errors``: the one reader of held and ramped points, for scenarios and
    recording plans alike."""
    of = f', the value in {unit}' if unit else ''
    form = f'{where}: expected [[t, value], ...] (t in s{of}'
    if not isinstance(raw, list) or not raw:
        errors.append(f'{form}; a list of pairs)')
        return None
    out = []
    for k, pair in enumerate(raw):
        if not (isinstance(pair, (list, tuple)) and len(pair) == 2):
            errors.append(f'{form}); item {k} is {pair!r}')
            return None
        t = check_number(pair[0], f'{where}[{k}] time', errors, unit='s', sign=time_sign)
        v = check_number(pair[1], f'{where}[{k}] value', errors, unit=unit)
        if t is None or v is None:
            return None
        out.append((t, v))
    if any(b[0] <= a[0] for a, b in zip(out, out[1:])):
        errors.append(f'{where}: times must increase ({", ".join(fmt(t) for t, _ in out)} s)')
        return None
    return tuple(out)


def parse_signal(spec: Any, name: str, errors: list[str]) -> Signal | None:
    """Build a :class:`Signal` from its YAML form, appending problems to ``errors``."""
    where = f'inputs.{name}'
    if not isinstance(spec, Mapping):
        v = check_number(spec, where, errors)
        return None if v is None else Signal(offset=v)
    unknown = set(spec) - _SIGNAL_KEYS
    if unknown:
        errors.append(f'{where}: unknown key(s) {", ".join(sorted(map(str, unknown)))} '
                      f'(use {", ".join(sorted(_SIGNAL_KEYS))})')
    if 'steps' in spec and 'ramp' in spec:
        errors.append(f'{where}: give steps or ramp, not both')
        return None
    kind, points = 'constant', ()
    for key in ('steps', 'ramp'):
        if key in spec:
            kind = key
            points = time_value_pairs(spec[key], f'{where}.{key}', errors)
            if points is None:
                return None
    offset = 0.0
    if 'offset' in spec:
        if kind != 'constant':
            errors.append(f'{where}: offset only goes with a sine, not with {kind}')
        offset = check_number(spec['offset'], f'{where}.offset', errors) or 0.0
    sine = (0.0, 0.0, 0.0, 0.0)
    if 'sine' in spec:
        s = spec['sine']
        if not isinstance(s, Mapping) or 'amplitude' not in s or 'frequency' not in s:
            errors.append(f'{where}.sine: expected amplitude and frequency')
            return None
        bad = set(s) - _SINE_KEYS
        if bad:
            errors.append(f'{where}.sine: unknown key(s) {", ".join(sorted(map(str, bad)))}')
        vals = [check_number(s.get(k, 0.0), f'{where}.sine.{k}', errors) for k in
                ('amplitude', 'frequency', 'phase', 'start')]
        if any(v is None for v in vals):
            return None
        sine = tuple(vals)
    return Signal(kind=kind, points=points, offset=offset, sine=sine)


def parse_inputs(data: Any, errors: list[str], names: Collection[str] | None = None
                 ) -> dict[str, Signal]:
    """Parse the ``inputs`` mapping of a scenario; ``names``: the inputs accepted (default
    the pump's; a circuit adds its own, ``boom.command``)."""
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        errors.append('inputs: expected a mapping of signals')
        return {}
    names = list(SIGNALS) if names is None else list(names)
    out = {}
    for name, spec in data.items():
        if name not in names:
            errors.append(unknown_key_line(f'inputs.{name}', [f'inputs.{n}' for n in names],
                                           'input'))
            continue
        sig = parse_signal(spec, name, errors)
        if sig is not None:
            out[name] = sig
    return out


def check_signals(inputs: dict[str, Signal], duration: float) -> list[str]:
    """One line per operating-point input that leaves its accepted range (the range of its
    plant parameter: ``line.P_u``, ``line.xi_u``, ``pump.f_p``) within ``duration`` [s];
    the same check :func:`hydropump_sim.simulate` makes on its inputs."""
    out = []
    for name, sig in inputs.items():
        if name not in INPUTS:
            continue
        n = int(min(duration / 1.0e-3, 2.0e5)) + 1
        t = np.union1d(np.linspace(0.0, duration, n),
                       [pt[0] for pt in sig.points if 0.0 <= pt[0] <= duration])
        err = check_input(name, sig(t), t)
        if err:
            out.append(f'inputs.{err}')
    return out


# The inputs are held over increments of at most this [s] (simulate's dt_max, the node's
# step): a sine at or above half its rate is sampled into something else.
INPUT_PERIOD = 1.0e-3


def _aliased(inputs: Mapping[str, Signal], period: float) -> list[str]:
    """A line per sine the input sampling cannot carry (at or above its Nyquist rate)."""
    nyquist = 0.5 / period
    return [f'inputs.{name}.sine.frequency = {sig.sine[1]:g} Hz: at or above half the input '
            f'sampling rate ({nyquist:g} Hz, inputs held every {period * 1e3:g} ms), it would '
            'be sampled into another signal (at a multiple of that rate, into its zeros)'
            for name, sig in inputs.items() if abs(sig.sine[1]) >= nyquist and sig.sine[0]]


def load_scenario(path: str | Path, names: Collection[str] | None = None) -> Scenario:
    """Read and validate a scenario file (``names``: the inputs accepted, see
    :func:`parse_inputs`).

    Raises
    ------
    ScenarioError
        One line per problem; parameter-file problems come through as well.
    """
    path = Path(path)
    try:
        doc = read_yaml(path)
    except ParamError as exc:
        raise ScenarioError(exc.lines, str(path)) from None
    if not isinstance(doc, Mapping):
        raise ScenarioError(['expected a mapping at the top level'], str(path))
    errors: list[str] = []
    for key in set(doc) - _TOP_KEYS:
        errors.append(f'{key}: unknown key (use {", ".join(sorted(_TOP_KEYS))})')
    duration = check_number(doc.get('duration'), 'duration', errors) if 'duration' in doc else None
    if 'duration' not in doc:
        errors.append('duration: missing (s)')
    elif duration is not None and duration <= 0:
        errors.append(f'duration = {duration}: must be positive (s)')
    dt_out = check_number(doc.get('dt_out', 1.0e-3), 'dt_out', errors)
    if dt_out is not None and dt_out <= 0:
        errors.append(f'dt_out = {dt_out}: must be positive (s)')
    model = doc.get('model', 'fine')
    if model not in ('fine', 'simplified', 'simplified_Kc'):
        errors.append(f'model = {model!r}: use fine, simplified or simplified_Kc')
    inputs = parse_inputs(doc.get('inputs'), errors, names)
    if duration is not None and duration > 0:
        errors += check_signals(inputs, duration)
    if dt_out is not None and dt_out > 0:
        errors += _aliased(inputs, min(dt_out, INPUT_PERIOD))
    params = None
    try:
        ppath = (path.parent / doc['params']) if 'params' in doc else default_params_path()
        params = load_params(ppath)
        overrides = doc.get('overrides') or {}
        if not isinstance(overrides, Mapping):
            errors.append('overrides: expected a mapping of dotted parameter names')
        elif overrides:
            params = params.replace(overrides)
    except ParamError as exc:
        errors.extend(exc.lines)
    if errors:
        raise ScenarioError(errors, str(path))
    return Scenario(duration=duration, model=model, params=params, inputs=inputs,
                    dt_out=dt_out, output=doc.get('output'))

