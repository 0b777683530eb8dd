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

A signal is a schedule (:mod:`hydropump_sim.schedule`, the grammar plans and sweeps share):
a number, or ``steps`` or ``ramp`` as ``[t, value]`` pairs, a ``staircase``, or an
``offset``, plus an optional ``sine``; the current may be given in ``unit: percent``.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import HydropumpError
from .params import check_input, default_params_path, INPUTS, load_params, Params
from .schedule import CURRENT_UNITS, parse_schedule, Schedule
from .schema import check_number, ParamError, read_yaml, unknown_key_line

SIGNALS = {
    'current': ('A', 'absolute solenoid current'),
    'load_pressure': ('Pa', 'load pressure P_u (gauge)'),
    'aperture': ('-', 'load aperture xi_u'),
    'shaft_speed': ('Hz', 'shaft frequency f_p'),
}
_TOP_KEYS = {'duration', 'model', 'params', 'overrides', 'inputs', 'dt_out', 'output'}


class ScenarioError(HydropumpError, ValueError):
    """Invalid scenario: ``lines`` holds one line per problem."""

    head = 'invalid scenario'


@dataclass
class Scenario:
    duration: float
    model: str = 'fine'
    params: Params | None = None
    inputs: dict = field(default_factory=dict)
    dt_out: float = 1.0e-3
    output: str | None = None


def parse_signal(spec: Any, name: str, errors: list[str]) -> Schedule | None:
    """The schedule of input ``name`` (a current may be written in A, percent or fraction of
    displacement), appending problems to ``errors``."""
    return parse_schedule(spec, f'inputs.{name}', errors,
                          units=CURRENT_UNITS if name == 'current' else ())


def parse_inputs(data: Any, errors: list[str], names: Collection[str] | None = None
                 ) -> dict[str, Schedule]:
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


def check_signals(inputs: dict[str, Schedule], duration: float) -> list[str]:
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


def _aliased(inputs: Mapping[str, Schedule], period: float) -> list[str]:
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
    if 'current' in inputs:
        inputs['current'] = inputs['current'].in_amperes(params)
    return Scenario(duration=duration, model=model, params=params, inputs=inputs,
                    dt_out=dt_out, output=doc.get('output'))

