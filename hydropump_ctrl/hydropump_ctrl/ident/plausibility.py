"""Plausibility of a recording against the pump, before any fit: units, length, types, runs.

A bag in the wrong units reads without complaint and fits to a confident number (a flow in
L/min gives ``G0`` 6e4 times too large). :func:`problems` compares each signal a command uses
with the ranges the params file gives the pump, one line per problem:

- a **current** outside the pump's ``I_limits`` (eq. 2) widened by a tenth of their span
  (``looks like mA`` when a thousandth of it lies inside);
- a **pressure** (absolute, as ``FluidPressure`` carries it) of at most ``BAR_MAX`` Pa
  (``looks like bar``), or below atmospheric where an absolute pressure cannot be
  (``looks like gauge``);
- a **flow** above ``FLOW_FACTOR`` times the pump's maximum ``Q_max = V_p f_p`` (``looks
  like L/min`` when a 6e4th of it fits);
- **too few samples** for a fit (:data:`MIN_SAMPLES`).

- what the **recorder** wrote into the bag's ``custom_data`` (:func:`recorder_report`):
  safe-current engagements and lock-step timeouts (``events.<kind>``: the plant did not get
  the commands the record shows), and messages lost on the way or left unwritten by a stop
  cut at its bound (``messages_lost``, ``drain``). A fit of such a bag would look as good as
  any other, so it is refused, with one line saying what, how many and when the first was.

The wrong message type on a contract topic and a bag holding two runs (time going back) are
found while the bag is read (:mod:`.recording`, with :func:`wrong_type` and
:func:`two_runs`). :func:`check_recordings` raises every problem of every recording at once
as a :class:`~.errors.PlausibilityError`; ``read_recordings(..., params=...)`` calls it, so
that ``hydropump fit``, ``calibrate`` and ``validate`` check in one place.

Robust extremes (the 1st and 99th percentiles) are compared, so that a single spike does not
refuse a bag. Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from hydropump_sim.measure import SIGNALS as MEASURED

from ..bag.metadata import custom_data
from .errors import PlausibilityError

# The least record a fit or a calibration takes (a few time constants of the plant at 1 kHz).
MIN_SAMPLES = 50
# A current may leave I_limits by this fraction of their span (sensor noise, dither peaks).
CURRENT_SLACK = 0.1
# An absolute pressure no higher than this [Pa] is a pressure in bar (1 bar = 1e5 Pa): no
# hydraulic line runs at a hundredth of atmospheric pressure.
BAR_MAX = 1.0e3
# Below this fraction of atmospheric pressure for more than GAUGE_SHARE of the samples (or
# below zero at all), a pressure is gauge: the pressure floor lets an absolute pressure dip
# there in a transient only.
GAUGE_FRACTION = 0.5
GAUGE_SHARE = 0.1
# A flow above this multiple of Q_max = V_p f_p is not in m^3/s (one order of magnitude:
# relief and load flows stay near the pump's maximum).
FLOW_FACTOR = 10.0
L_PER_MIN = 6.0e4           # m^3/s -> L/min
MILLI = 1.0e3               # A -> mA

# Signal name -> kind (current, flow, pressure) of the signals checked against the pump.
KINDS = {name: info.kind for name, info in MEASURED.items() if info.kind != 'position'}
KINDS['solenoid_current_cmd'] = 'current'


def _robust_range(v: np.ndarray) -> tuple[float, float] | None:
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    return float(np.percentile(v, 1.0)), float(np.percentile(v, 99.0))


def _current(name: str, v: np.ndarray, params) -> str | None:
    ext = _robust_range(v)
    if ext is None:
        return None
    lo, hi = params.I_limits
    slack = CURRENT_SLACK * (hi - lo)
    if lo - slack <= ext[0] and ext[1] <= hi + slack:
        return None
    head = (f"{name} spans {ext[0]:.4g} .. {ext[1]:.4g}, outside the pump's current limits "
            f'I_limits = {lo:g} .. {hi:g} A')
    if ext[1] > hi + slack and ext[1] / MILLI <= hi + slack and ext[0] >= 0.0:
        return f'{head}: looks like mA; the topic carries A (divide by {MILLI:g})'
    if ext[0] < lo - slack and ext[1] <= hi:
        return (f'{head}: looks like a current relative to the nominal one; the topic '
                'carries the absolute current [A]')
    return f'{head}: not a current in A'


def _pressure(name: str, v: np.ndarray, params) -> str | None:
    ext = _robust_range(v)
    if ext is None:
        return None
    p_atm = params.fluid.p_atm
    if abs(ext[0]) <= BAR_MAX and abs(ext[1]) <= BAR_MAX and ext[1] > 0.0:
        return (f'{name} spans {ext[0]:.4g} .. {ext[1]:.4g} Pa: looks like bar; the topic '
                'carries Pa absolute (multiply by 1e5 and add the atmospheric pressure '
                f'{p_atm:g} Pa)')
    ok = v[np.isfinite(v)]
    share = float(np.mean(ok < GAUGE_FRACTION * p_atm))
    if ext[0] < 0.0 or share > GAUGE_SHARE:
        return (f'{name} is below atmospheric pressure ({p_atm:g} Pa) in {100 * share:.0f} % '
                f'of the samples (down to {ext[0]:.4g} Pa): looks like gauge; the topic '
                f'carries Pa absolute (add {p_atm:g} Pa)')
    return None


def _flow(name: str, v: np.ndarray, params) -> str | None:
    ext = _robust_range(v)
    if ext is None:
        return None
    q_max = params.Q_max
    top = max(abs(ext[0]), abs(ext[1]))
    if top <= FLOW_FACTOR * q_max:
        return None
    head = (f"{name} reaches {top:.4g}, {top / q_max:.3g} times the pump's maximum flow "
            f'Q_max = V_p f_p = {q_max:.4g} m^3/s')
    if top / L_PER_MIN <= FLOW_FACTOR * q_max:
        return f'{head}: looks like L/min; the topic carries m^3/s (divide by 6e4)'
    return f'{head}: not a flow in m^3/s'


CHECKS = {'current': _current, 'pressure': _pressure, 'flow': _flow}


def problems(rec, params, signals: Iterable[str] | None = None, recorder: bool = True
             ) -> list[str]:
    """One line per implausible signal of ``rec`` (a :class:`~.recording.Recording`), each
    naming the recording.

    ``signals`` are the signals to check (default: every one :data:`KINDS` knows); the
    signals acting as current and flow are always checked, as a current and a flow, whatever
    their names. With ``recorder``, what the recorder reported in the bag ``rec`` was read
    from comes first (:func:`recorder_report`).
    """
    where = rec.source or rec.name or 'recording'
    told = recorder_report(rec.source) if recorder and rec.source else None
    head = [told] if told else []
    n = rec.t.size
    if n < MIN_SAMPLES:
        return head + [f'{where}: {n} samples of {rec.roles["current"]} and '
                       f'{rec.roles["flow"]} ({n * rec.dt:.3g} s); a fit needs at least '
                       f'{MIN_SAMPLES}: record longer']
    kinds = {s: KINDS[s] for s in (KINDS if signals is None else signals)
             if s in KINDS and s in rec}
    kinds.update({rec.roles['current']: 'current', rec.roles['flow']: 'flow'})
    out = head
    for s, kind in kinds.items():
        line = CHECKS[kind](s, np.asarray(rec[s], dtype=float), params)
        if line:
            topic = rec.topics.get(s)
            out.append(f'{where}: {line}' + (f' ({topic})' if topic and topic != s.strip('/')
                                             and not topic.endswith('/' + s) else ''))
    return out


def check_recordings(recs: Sequence, params, signals: Iterable[str] | None = None,
                     recorder: bool = True) -> None:
    """Raise :class:`~.errors.PlausibilityError` with every problem of :func:`problems`."""
    signals = None if signals is None else list(signals)
    lines = [line for rec in recs for line in problems(rec, params, signals, recorder)]
    if lines:
        raise PlausibilityError(lines)


# ---- what the recorder told ----------------------------------------------------------------

#: Events that make a record unfit, as the recorder counts them (``events.<kind>``), and
#: what they mean for the record.
EVENT_WORDS = {'safe_current': ('safe-current engagement', 'safe-current engagements'),
               'lock_step_timeout': ('lock-step timeout', 'lock-step timeouts')}


def _count(value) -> int:
    try:
        return int(str(value))
    except ValueError:
        return 0


def recorder_report(path: str | Path) -> str | None:
    """One line naming what the recorder of the bag at ``path`` reported that makes its
    record unfit for a fit, or ``None``: events (safe-current engagements, lock-step
    timeouts, any other kind), with the simulation time of the first, and messages lost
    (on the way, or left unwritten by a stop whose drain was cut at its bound)."""
    cd = custom_data(path)
    if not cd:
        return None
    told = []
    for key, value in cd.items():
        kind = key.removeprefix('events.')
        if not key.startswith('events.') or kind.endswith('.first'):
            continue
        n = _count(value)
        if n:
            one, many = EVENT_WORDS.get(kind, (f'{kind} event', f'{kind} events'))
            first = cd.get(f'events.{kind}.first')
            told.append(f'{n} {one if n == 1 else many}'
                        + (f' (the first at {float(first):g} s)' if first else ''))
    lost = _count(cd.get('messages_lost', 0))
    drain = cd.get('drain', 'complete')
    if lost:
        per = sorted(((k.removeprefix('lost.'), _count(v)) for k, v in cd.items()
                      if k.startswith('lost.')), key=lambda x: -x[1])
        told.append(f'{lost} messages lost (' + ', '.join(f'{t} {n}' for t, n in per[:3])
                    + (', ...' if len(per) > 3 else '') + ')'
                    + ('' if drain == 'complete' else f'; its stop was {drain}'))
    elif drain.startswith('cut'):
        told.append(f'a stop that was {drain}')
    if not told:
        return None
    return (f'{path}: its recorder reports ' + '; '.join(told) + ': the record is not the '
            'experiment as commanded; record it again')


# ---- found while reading -------------------------------------------------------------------

def wrong_type(where: str, topic: str, msgtype: str, signal: str, expected: str) -> str | None:
    """The line for a contract topic of another message type than the suite publishes it
    with (``None`` when it is that type)."""
    if msgtype == expected:
        return None
    return (f'{where}: topic {topic} ({msgtype}) is not a {expected}: wrong message type for '
            f'{signal}, which the suite publishes as {expected} (topics swapped or another '
            'publisher?)')


def two_runs(t_ns: np.ndarray, tolerance_ns: int) -> tuple[int, int, int] | None:
    """Where time goes back in stamps ``t_ns`` in storage order, by more than
    ``tolerance_ns`` (a late message is not that late): ``(index, stamp, latest before)`` of
    the first such message, or ``None``."""
    if t_ns.size < 2:
        return None
    latest = np.maximum.accumulate(t_ns)
    back = np.flatnonzero(latest[:-1] - t_ns[1:] > tolerance_ns)
    if back.size == 0:
        return None
    k = int(back[0]) + 1
    return k, int(t_ns[k]), int(latest[k - 1])


def repeated_block(t_sorted: np.ndarray, min_count: int = 10, density: float = 0.9
                   ) -> tuple[int, int, int] | None:
    """Sorted stamps of which a stretch occurs twice, as two runs of one simulator step
    interleaved by a reader that sorts by time give: ``(index of its first stamp, first
    stamp, last stamp, number of repeats)``, or ``None``.

    A stamp repeated here and there (a message re-sent) is not a second run: the repeats must
    be at least ``min_count`` and cover ``density`` of the distinct stamps between the first
    and the last repeat.
    """
    if t_sorted.size < 2:
        return None
    same = t_sorted[1:] == t_sorted[:-1]
    if int(same.sum()) < min_count:
        return None
    uniq, counts = np.unique(t_sorted, return_counts=True)
    rep = np.flatnonzero(counts > 1)
    span = rep[-1] - rep[0] + 1
    if rep.size < density * span:
        return None
    first = int(uniq[rep[0]])
    return (int(np.searchsorted(t_sorted, first)), first, int(uniq[rep[-1]]),
            int(same.sum()))
