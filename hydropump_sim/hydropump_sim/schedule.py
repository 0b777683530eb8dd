"""Input schedules: the one grammar of scheduled inputs, for scenarios, recording plans and
sweeps alike (each keeps only its own top-level keys and its own limits).

A schedule is a number (held), a list ``[[t, value], ...]`` (held from each ``t``, the same
as ``steps``), or a mapping of one base and an optional sine::

    steps: [[0.0, 0.46], [0.5, 0.54]]       # held from each t [s]
    ramp: [[0.0, 0.46], [1.0, 0.54]]        # linear between the points
    staircase: {levels: [30, 50, 70], dwell: 1.0}   # level k held from k * dwell
    step: {from: 0.3, to: 0.7, at: 0.1}     # steps [[0, from], [at, to]]
    offset: 0.5                             # a constant, under a sine
    sine: {amplitude: 0.05, frequency: 2.0, phase: 0.0, start: 0.0}   # Hz, rad, s
    unit: percent                           # currents: A, percent or fraction of displacement

Values are SI in the signal's unit, except a current's: ``A`` (absolute), ``percent`` or
``fraction`` of displacement, through the static map of eqs. 8 and 10
(:meth:`Schedule.in_amperes`). Problems come back as one line each through the parameter
schema's :func:`~hydropump_sim.schema.check_number`, naming where they are.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .inputs import held
from .schema import check_number, fmt, unknown_key_line

#: The bases of a schedule, one at most; a ``sine`` adds to any of them.
BASES = ('steps', 'ramp', 'staircase', 'step', 'offset')
KEYS = BASES + ('sine', 'unit')
SINE_KEYS = ('amplitude', 'frequency', 'phase', 'start')
#: Units of a current schedule: absolute amperes, or percent or fraction of displacement.
CURRENT_UNITS = ('A', 'percent', 'fraction')
_PER_UNIT = {'percent': 100.0, 'fraction': 1.0}
_UNIT_WORDS = {'A': 'A', 'percent': '% of displacement', 'fraction': 'fraction of displacement'}


@dataclass(frozen=True)
class Schedule:
    """A scheduled signal; call it with a time or an array of times [s].

    ``kind``: ``constant`` (``offset``), ``steps`` (held ``points``) or ``ramp`` (linear
    between ``points``); ``sine``: amplitude, frequency [Hz], phase [rad], start [s], added
    from ``start`` on; ``unit``: ``''`` (the signal's SI unit) or a current's unit;
    ``dwell``: seconds a level when written as a staircase (else 0). Frozen and made of
    tuples: picklable, and its repr is the same in every process.
    """

    kind: str = 'constant'
    points: tuple = ()
    offset: float = 0.0
    sine: tuple = (0.0, 0.0, 0.0, 0.0)
    unit: str = ''
    dwell: float = 0.0

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

    @property
    def levels(self) -> tuple:
        """The values of the points, or the offset of a constant."""
        return tuple(v for _, v in self.points) if self.points else (self.offset,)

    @property
    def change_times(self) -> tuple:
        """Times [s] at which a held or ramped schedule changes course (after its first)."""
        return tuple(t for t, _ in self.points[1:])

    def affine(self, gain: float, bias: float, unit: str) -> Schedule:
        """The schedule through ``gain * value + bias`` (a sine's amplitude through the gain
        alone), its values then in ``unit``."""
        amp, freq, phase, start = self.sine
        return replace(self, points=tuple((t, gain * v + bias) for t, v in self.points),
                       offset=gain * self.offset + bias, sine=(gain * amp, freq, phase, start),
                       unit=unit)

    def in_amperes(self, params) -> Schedule:
        """A current schedule in absolute amperes, through the plant's static map (eqs. 8
        and 10, ``x_c = 0``: affine from 0 to 100 % of displacement)."""
        if self.unit not in _PER_UNIT:
            return replace(self, unit='A') if self.unit == '' else self
        lo, hi = params.current_range
        return self.affine((hi - lo) / _PER_UNIT[self.unit], lo, 'A')

    def describe(self) -> str:
        u = {'A': ' A', 'percent': ' %', 'fraction': ''}.get(self.unit, '')
        amp, freq, _, _ = self.sine
        if self.kind == 'constant':
            base = f'{fmt(self.offset)}'
            if amp:
                return f'sine {base} +- {fmt(amp)}{u} at {fmt(freq)} Hz'
            return f'held at {base}{u}'
        if self.dwell:
            text = (f'staircase {" -> ".join(fmt(v) for v in self.levels)}{u}, '
                    f'{fmt(self.dwell)} s each')
        else:
            text = f'{self.kind} ' + ', '.join(f'{fmt(v)}{u} at {fmt(t)} s'
                                                for t, v in self.points)
        return text + (f' + sine {fmt(amp)}{u} at {fmt(freq)} Hz' if amp else '')


def time_value_pairs(raw: Any, where: str, errors: list[str], *, time_sign: str = '',
                     unit: str = '') -> tuple | None:
    """``[[t, value], ...]`` with increasing times (``time_sign``: ``'>= 0'`` where time
    counts from a start; ``unit``: the value's unit, named in the messages), else ``None``
    and one line in ``errors``."""
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


def parse_schedule(raw: Any, where: str, errors: list[str], *, units: Sequence[str] = (),
                   unit: str = '', time_sign: str = '', bases: Sequence[str] = BASES,
                   sine: bool = True) -> Schedule | None:
    """A :class:`Schedule` from its YAML form (see the module), else ``None`` with one line
    per problem in ``errors``.

    Parameters
    ----------
    units : sequence of str
        The units the signal may be written in (:data:`CURRENT_UNITS` for a current); empty:
        its SI unit only, and no ``unit`` key.
    unit : str
        The unit when the file gives none (the first of ``units`` if empty).
    time_sign : str
        ``'>= 0'`` where time counts from an experiment's start.
    bases : sequence of str
        The bases this format can run (a plan's controller cannot ramp).
    sine : bool
        Whether a sine may add to them (a plan's load steps: no).
    """
    unit = unit or (units[0] if units else '')
    if isinstance(raw, list) and 'steps' in bases:   # the short form of steps
        points = time_value_pairs(raw, where, errors, time_sign=time_sign,
                                  unit=_UNIT_WORDS.get(unit, ''))
        return None if points is None else Schedule('steps', points, unit=unit)
    if not isinstance(raw, Mapping):
        v = check_number(raw, where, errors, unit=_UNIT_WORDS.get(unit, ''))
        return None if v is None else Schedule(offset=v, unit=unit)
    keys = [k for k in KEYS if k != 'unit' or units]
    if _unknown(raw, keys, where, errors):
        return None
    if 'unit' in raw:
        if raw['unit'] not in units:
            hint = ' (percent of displacement)' if raw['unit'] in ('%', 'pct') else ''
            errors.append(f'{where}.unit = {raw["unit"]!r}: expected '
                          f'{" or ".join(units)}{hint}')
            return None
        unit = raw['unit']
    given = [k for k in BASES if k in raw]
    if len(given) > 1:
        errors.append(f'{where}: give one of {", ".join(given)}, not both (a sine adds to any)')
        return None
    if 'sine' in raw and not sine:
        errors.append(f'{where}.sine: not here; use {", ".join(bases)} (no sine)')
        return None
    if given and given[0] not in bases:
        errors.append(f'{where}.{given[0]}: not here; use {", ".join(bases)}'
                      + (' (and a sine)' if sine else ''))
        return None
    if not given and 'sine' not in raw:
        errors.append(f'{where}: expected one of {", ".join(bases)} (and an optional sine)')
        return None
    base = _base(raw, given[0] if given else 'offset', where, errors, unit, time_sign)
    if base is None:
        return None
    if 'sine' not in raw:
        return base
    sine = _sine(raw['sine'], f'{where}.sine', errors, unit)
    return None if sine is None else replace(base, sine=sine)


def _base(raw: Mapping, key: str, where: str, errors: list[str], unit: str, time_sign: str
          ) -> Schedule | None:
    words = _UNIT_WORDS.get(unit, '')
    at = f'{where}.{key}'
    if key == 'offset':
        v = check_number(raw.get('offset', 0.0), at, errors, unit=words)
        return None if v is None else Schedule(offset=v, unit=unit)
    if key in ('steps', 'ramp'):
        points = time_value_pairs(raw[key], at, errors, time_sign=time_sign, unit=words)
        return None if points is None else Schedule(key, points, unit=unit)
    body = raw[key]
    fields = ('levels', 'dwell') if key == 'staircase' else ('from', 'to', 'at')
    if not isinstance(body, Mapping):
        errors.append(f'{at}: expected a mapping of {", ".join(fields)}')
        return None
    if _unknown(body, fields, at, errors):
        return None
    missing = [k for k in fields if k not in body]
    if missing:
        errors.append(f'{at}: missing {", ".join(missing)} (a {key} takes {", ".join(fields)})')
        return None
    if key == 'step':
        vals = [check_number(body[k], f'{at}.{k}', errors, unit=words) for k in ('from', 'to')]
        t = check_number(body['at'], f'{at}.at', errors, unit='s', sign='> 0')
        if t is None or None in vals:
            return None
        return Schedule('steps', ((0.0, vals[0]), (t, vals[1])), unit=unit)
    levels = body['levels']
    if not isinstance(levels, list) or not levels:
        errors.append(f'{at}.levels: expected a list of levels ({words or "SI"}), e.g. '
                      '[30, 40, 50]')
        return None
    vals = [check_number(v, f'{at}.levels[{k}]', errors, unit=words) for k, v in
            enumerate(levels)]
    dwell = check_number(body['dwell'], f'{at}.dwell', errors, unit='s', sign='> 0')
    if dwell is None or None in vals:
        return None
    return Schedule('steps', tuple((k * dwell, v) for k, v in enumerate(vals)), unit=unit,
                    dwell=dwell)


def _sine(raw: Any, where: str, errors: list[str], unit: str) -> tuple | None:
    if not isinstance(raw, Mapping) or 'amplitude' not in raw or 'frequency' not in raw:
        errors.append(f'{where}: expected amplitude and frequency (and phase [rad], start [s])')
        return None
    if _unknown(raw, SINE_KEYS, where, errors):
        return None
    units = {'amplitude': _UNIT_WORDS.get(unit, ''), 'frequency': 'Hz', 'phase': 'rad',
             'start': 's'}
    vals = [check_number(raw.get(k, 0.0), f'{where}.{k}', errors, unit=units[k],
                         sign='>= 0' if k == 'frequency' else '')
            for k in SINE_KEYS]
    return None if None in vals else tuple(vals)


def _unknown(raw: Mapping, keys: Sequence[str], where: str, errors: list[str]) -> bool:
    """A line per key of ``raw`` not in ``keys``, with the closest one; whether any."""
    lines = [f'{where}.{unknown_key_line(str(k), keys, "key")}; use {", ".join(keys)}'
             for k in raw if k not in keys]
    errors.extend(lines)
    return bool(lines)


def late_changes(schedule: Schedule, duration: float, where: str) -> list[str]:
    """A line per held change of ``schedule`` at or after ``duration`` [s]: it would never
    act (a ramp's last point may well be the end)."""
    if schedule.kind != 'steps':
        return []
    return [f'{where}: the change at {fmt(t)} s is not before the end ({fmt(duration)} s)'
            for t in schedule.change_times if t >= duration]
