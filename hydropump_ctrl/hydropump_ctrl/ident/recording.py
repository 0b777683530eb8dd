"""Recordings: a bag decoded once into named SI signals on one time grid, saved as ``.npz``.

A :class:`Recording` holds a time axis and a dict of named signals in SI units, each with its
unit, label, topic and time source. :data:`SIGNALS` lists the signals of the project's topic
contract: the solenoid current and its command, the line, pump and load flows, the line, load
and actuator pressures, the spool and actuator positions of ``joint_states`` and the
controller's ``controller/state`` entries. Two of the signals have a role: the one that acts as
the ``current`` and the one that acts as the ``flow`` of the FOPDT fit (by default
``solenoid_current`` and ``line_flow``; :meth:`Recording.with_roles` picks others).

Pressures stay **absolute**, as ``sensor_msgs/FluidPressure`` carries them (unit
``'Pa (absolute)'``): the gauge value needs the plant's atmospheric pressure, which a bag does
not carry. Differences of pressures (the margin ``P_l - P_u``) are the same either way.

:func:`read_recording` reads one bag (any form :mod:`.bags` accepts) or a ``.npz`` saved by
:meth:`Recording.save`; :func:`read_recordings` several, refusing truncated bags unless
allowed. Times are the messages' ``header.stamp`` where the type has a header, the bag's log
time otherwise. The grid is uniform in integer nanoseconds with the flow's period, from the
first flow sample that has a current to the last flow sample. The current and the other held
signals (commands, the controller's state) take the last value stamped up to half a period
after each grid time; the flow and the other sampled signals are interpolated linearly, so a
signal stamped on the grid (the simulator publishes every topic in one step) is taken as it
is. A signal other than the current and the flow is NaN where it has no value (before its
first message, or outside its span) and may carry NaN itself (an undefined controller state).

Every problem is a :class:`~.errors.BagReadError` with a one-line message. Nothing here imports
ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
import json
from pathlib import Path

import numpy as np

from hydropump_sim.measure import FLOAT64, JOINT_STATE
from hydropump_sim.measure import SIGNALS as MEASURED

from ..bag import (
    Bag,
    BagReadError,
    decode,
    existing,
    header_stamps,
    match_topic,
    one_line,
    open_bag,
    Stream,
    write_bag,
)
from .errors import PlausibilityError
from .plausibility import check_recordings, MIN_SAMPLES, repeated_block, two_runs, wrong_type

DEFAULT_CURRENT_TOPIC = 'solenoid_current'
DEFAULT_FLOW_TOPIC = 'line_flow'
DEFAULT_ROLES = {'current': DEFAULT_CURRENT_TOPIC, 'flow': DEFAULT_FLOW_TOPIC}
# What the fit assumes of a signal outside the contract that acts as current or flow.
ROLE_UNITS = {'current': 'A', 'flow': 'm^3/s'}
PRESSURE_UNIT = 'Pa (absolute)'
MODE_UNIT = 'm^3/s in flow mode, Pa in margin mode'


@dataclass(frozen=True)
class SignalSpec:
    """A signal of the topic contract: its topic (relative), unit, label and message type.

    ``held`` signals are taken as piecewise constant between their messages: commands, the
    controller's state, and the applied current, which the fit treats as held (so it reads
    the same whether it acts as the current or not). The others are samples of a continuous
    quantity. ``entry`` names the ``sensor_msgs/JointState`` entry whose position the signal
    is.
    """

    topic: str
    unit: str
    label: str
    held: bool = False
    entry: str | None = None
    msgtype: str = FLOAT64


def _joint(topic: str, entry: str, unit: str, label: str, held: bool = False) -> SignalSpec:
    return SignalSpec(topic, unit, label, held=held, entry=entry, msgtype=JOINT_STATE)


def _state(entry: str, unit: str, label: str) -> SignalSpec:
    return _joint('controller/state', entry, unit, label, held=True)


# The plant's signals from the one table (hydropump_sim.measure), pressures absolute as
# FluidPressure carries them; the controller's state entries are those its node publishes.
SIGNALS = {
    **{name: SignalSpec(i.topic, PRESSURE_UNIT if i.kind == 'pressure' else i.unit, i.label,
                        held=i.held, entry=i.entry, msgtype=i.msgtype)
       for name, i in MEASURED.items()},
    'solenoid_current_cmd': SignalSpec('solenoid_current_cmd', 'A',
                                       'solenoid current command I_s,ref', held=True),
    'controller_reference': _state('reference', MODE_UNIT, 'controller reference'),
    'controller_estimate': _state('estimate', MODE_UNIT,
                                  'controller estimate of the controlled variable'),
    'controller_disturbance': _state('disturbance', 'depends on the algorithm',
                                     'controller disturbance estimate'),
    'controller_command': _state('command', 'A', 'controller command'),
    'controller_command_desired': _state('command_desired', 'A',
                                         'controller command before the limits'),
}


@dataclass
class Recording:
    """Named SI signals on one uniform time grid.

    Attributes
    ----------
    t : ndarray
        Time [s] from the first sample of the grid (``t0_ns`` is its bag time).
    signals : dict of ndarray
        Signal name -> values at ``t`` (see :data:`SIGNALS`); pressures absolute [Pa].
    roles : dict
        ``'current'`` and ``'flow'``: the signals that act as the absolute current [A], held
        from ``t[k]`` to ``t[k+1]``, and the flow [m^3/s] at ``t[k]``.
    units, labels : dict
        Per signal (``units`` also has ``'t'``); filled from :data:`SIGNALS` where not given.
    topics, time_source : dict
        Per signal read from a bag: its topic, and ``'header'`` or ``'log'`` for where its
        times came from.
    filters : dict
        Per signal, the filter applied after recording (``None``: raw).
    name, source : str
        Short label and the path read.
    truncated : bool
        The bag was cut short (killed recorder); ``truncation`` says how.
    notes : list of str
        Warnings about the data (gaps, jitter, missing metadata, signals left out).
    """

    t: np.ndarray
    signals: dict
    name: str = ''
    source: str = ''
    roles: dict = field(default_factory=lambda: dict(DEFAULT_ROLES))
    units: dict = field(default_factory=dict)
    labels: dict = field(default_factory=dict)
    topics: dict = field(default_factory=dict)
    time_source: dict = field(default_factory=dict)
    filters: dict = field(default_factory=dict)
    truncated: bool = False
    truncation: str = ''
    notes: list = field(default_factory=list)
    t0_ns: int = 0

    def __post_init__(self):
        what = self.name or 'recording'
        self.t = np.asarray(self.t, dtype=float)
        self.signals = {k: np.asarray(v, dtype=float) for k, v in self.signals.items()}
        if self.t.ndim != 1 or any(v.shape != self.t.shape for v in self.signals.values()):
            raise BagReadError(f'{what}: time and signals must be 1-D arrays of equal length')
        if self.t.size < 2:
            raise BagReadError(f'{what}: fewer than 2 common samples')
        for role, sig in self.roles.items():
            if sig not in self.signals:
                raise BagReadError(f'{what}: no signal {sig!r} to act as the {role}; it has: '
                               f'{", ".join(self.signals) or "none"}')
        role_of = {sig: role for role, sig in self.roles.items()}
        for k in self.signals:
            spec = SIGNALS.get(k)
            self.units.setdefault(k, spec.unit if spec else ROLE_UNITS.get(role_of.get(k), ''))
            self.labels.setdefault(k, spec.label if spec else k)
            self.filters.setdefault(k, None)
        self.units['t'] = 's'

    def __getitem__(self, name: str) -> np.ndarray:
        return self.signals[name]

    def __contains__(self, name: str) -> bool:
        return name in self.signals

    @property
    def current(self) -> np.ndarray:
        """The signal that acts as the current [A] (``roles['current']``)."""
        return self.signals[self.roles['current']]

    @property
    def flow(self) -> np.ndarray:
        """The signal that acts as the flow [m^3/s] (``roles['flow']``)."""
        return self.signals[self.roles['flow']]

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0] + self.dt)

    def with_roles(self, current: str | None = None, flow: str | None = None) -> Recording:
        """The same record with other signals acting as current and flow (``None``: kept)."""
        roles = {'current': current or self.roles['current'],
                 'flow': flow or self.roles['flow']}
        return self if roles == self.roles else self._replace(roles=roles)

    # ---- derived records ---------------------------------------------------------------

    def lowpass(self, cutoff: float, signals=('current', 'flow'), order: int = 2,
                zero_phase: bool = False) -> Recording:
        """Butterworth low-pass of the named signals (e.g. to remove dither).

        ``signals`` holds signal names or the roles ``'current'`` and ``'flow'``. Causal by
        default, like a measurement filter; ``zero_phase`` filters forwards and backwards.
        Filtering current and flow with the same filter keeps the current-to-flow relation
        (linear filters commute). Filtering the flow alone does not (a causal filter's lag
        adds to ``t_d``): the fit refuses it.
        """
        from scipy import signal as sg
        nyq = 0.5 / self.dt
        if not 0 < cutoff < nyq:
            raise BagReadError(f'low-pass cutoff must be in (0, {nyq:g}) Hz, got {cutoff!r}')
        sos = sg.butter(order, cutoff / nyq, output='sos')
        out = dict(self.signals)
        filters = dict(self.filters)
        for s in signals:
            name = self.roles.get(s, s)
            if name not in out:
                raise BagReadError(f'unknown signal {s!r}: use current, flow or one of '
                               f'{", ".join(out)}')
            x = out[name]
            if zero_phase:
                out[name] = sg.sosfiltfilt(sos, x)
            else:
                # Start from the steady state of the first sample, not from zero.
                out[name] = sg.sosfilt(sos, x, zi=sg.sosfilt_zi(sos) * x[0])[0]
            kind = 'zero-phase' if zero_phase else 'causal'
            filters[name] = f'butterworth order {order}, {cutoff:g} Hz, {kind}'
        return self._replace(signals=out, filters=filters)

    def decimate(self, q: int) -> Recording:
        """Every ``q``-th sample, as a slower logger would sample (no anti-alias filter).

        The held-input assumption of the fit then needs current steps on the coarse grid.
        """
        q = int(q)
        if q < 1:
            raise BagReadError(f'decimation factor must be a positive integer, got {q}')
        return self._replace(t=self.t[::q], signals={k: v[::q] for k, v in self.signals.items()})

    def _replace(self, **kw) -> Recording:
        """A new record with ``kw`` changed and every other container copied."""
        data = {f.name: getattr(self, f.name) for f in fields(self)}
        data = {k: (type(v)(v) if isinstance(v, (dict, list)) else v) for k, v in data.items()}
        data.update(kw)
        return Recording(**data)

    # ---- .npz ---------------------------------------------------------------------------

    def _meta(self) -> dict:
        meta = {f.name: getattr(self, f.name) for f in fields(self)
                if f.name not in ('t', 'signals')}
        meta['t0_ns'] = int(self.t0_ns)
        meta['signals'] = list(self.signals)
        return meta

    def save(self, path: str | Path) -> Path:
        """Save arrays and metadata (JSON) to ``.npz``."""
        path = Path(path)
        arrays = {f'signal.{k}': v for k, v in self.signals.items()}
        np.savez_compressed(path, t=self.t, meta=np.array(json.dumps(self._meta())), **arrays)
        return path if path.suffix == '.npz' else path.with_name(path.name + '.npz')

    @classmethod
    def load(cls, path: str | Path) -> Recording:
        """Load a recording saved by :meth:`save` (or the current-and-flow form of earlier
        versions)."""
        try:
            with np.load(path, allow_pickle=False) as d:
                meta = json.loads(str(d['meta']))
                t = d['t']
                if 'signals' in meta:
                    signals = {k: d[f'signal.{k}'] for k in meta.pop('signals')}
                else:
                    signals = _two_signal_form(meta, d)
            units = meta.pop('units', {})
            return cls(t=t, signals=signals, units=units, **meta)
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise BagReadError(f'{path}: not a saved recording: {one_line(exc)}') from None


def _two_signal_form(meta: dict, d) -> dict:
    """Signals of a file with ``current`` and ``flow`` arrays; ``meta`` is changed in place
    to the named form."""
    names = {role: _name_of(meta.get('topics', {}).get(role, ''), default)
             for role, default in DEFAULT_ROLES.items()}
    for key in ('topics', 'labels', 'time_source', 'filters'):
        meta[key] = {names[r]: v for r, v in meta.get(key, {}).items() if r in names}
    meta.pop('units', None)
    meta['roles'] = names
    return {names[r]: d[r] for r in names}


def _name_of(topic: str, default: str) -> str:
    """The contract signal a topic carries, ``default`` for another topic."""
    last = topic.rsplit('/', 1)[-1]
    return last if last in SIGNALS and SIGNALS[last].entry is None else default


# --------------------------------------------------------------------------------------------
# Decoding and the common time grid
# --------------------------------------------------------------------------------------------

_SCALAR_FIELDS = ('data', 'fluid_pressure', 'temperature', 'illuminance', 'range')


# How far a topic's time may fall behind its latest message before the bag counts as holding
# two runs (a simulator restarted under one recording): late messages are not this late.
TIME_BACK_NS = 500_000_000
# What a bag of two runs is told: the fit cannot tell the runs apart, so it is refused.
TWO_RUNS = ('the bag holds two runs (a restarted simulator): record each run in its own bag '
            '(restart the recorder with the simulator) and give both bags')


def _messages(stream: Stream, where: str) -> tuple[np.ndarray, list, str]:
    """Times [ns] and messages of a topic, and ``'header'`` or ``'log'``; a time that goes
    back (beyond a late message) is refused: the bag then holds more than one run."""
    msgs = decode(stream, where)
    st = header_stamps(msgs)
    t, kind = (st, 'header') if st is not None else \
        (np.asarray(stream.log_ns, dtype=np.int64), 'log')
    back = two_runs(t, TIME_BACK_NS)
    if back is not None:
        k, tk, latest = back
        first = int(t.min())
        raise PlausibilityError(
            f'{where}: time goes back on {stream.topic} at message {k + 1} of {t.size}: '
            f'stamped {(tk - first) * 1e-9:.6g} s after {(latest - first) * 1e-9:.6g} s; '
            f'{TWO_RUNS}')
    return t, msgs, kind


def _scalars(msgs: list, stream: Stream, where: str) -> np.ndarray:
    field_name = next((f for f in _SCALAR_FIELDS if isinstance(getattr(msgs[0], f, None),
                                                                (int, float))), None)
    if field_name is None:
        raise BagReadError(f'{where}: topic {stream.topic} ({stream.msgtype}) carries no single '
                       'number: use a std_msgs/msg/Float64 topic')
    return np.fromiter((getattr(m, field_name) for m in msgs), float, len(msgs))


def _entries(msgs: list, entries: Sequence[str], stream: Stream, where: str
             ) -> list[np.ndarray]:
    """Positions of the named entries of ``sensor_msgs/JointState`` messages (NaN where a
    message lacks one)."""
    if not hasattr(msgs[0], 'position'):
        raise BagReadError(f'{where}: topic {stream.topic} ({stream.msgtype}) is not a '
                       'sensor_msgs/msg/JointState')
    out = np.full((len(entries), len(msgs)), np.nan)
    for k, m in enumerate(msgs):
        at = {n: i for i, n in enumerate(m.name) if i < len(m.position)}
        for j, e in enumerate(entries):
            if e in at:
                out[j, k] = m.position[at[e]]
    return list(out)


def _clean(t_ns: np.ndarray, cols: list[np.ndarray], topic: str, where: str, notes: list,
           finite: bool) -> tuple[np.ndarray, list[np.ndarray]]:
    """Sorted times without repeats (the last message of an instant kept); with ``finite``
    a NaN or infinite value is an error."""
    order = np.argsort(t_ns, kind='stable')
    t_ns, cols = t_ns[order], [c[order] for c in cols]
    # A reader that sorts by log time interleaves two runs of one simulator step: the second
    # run's stamps repeat a stretch of the first's.
    block = repeated_block(t_ns)
    if block is not None:
        k, a, b, n = block
        raise PlausibilityError(
            f'{where}: time goes back on {topic} to {(a - t_ns[0]) * 1e-9:.6g} s: {n} '
            f'messages repeat the times {(a - t_ns[0]) * 1e-9:.6g} s to '
            f'{(b - t_ns[0]) * 1e-9:.6g} s (from message {k + 1} of {t_ns.size} in time '
            f'order); {TWO_RUNS}')
    if finite:
        bad = ~np.isfinite(cols[0])
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise BagReadError(f'{where}: {topic} has {int(bad.sum())} NaN or infinite values '
                           f'(first at t = {(t_ns[k] - t_ns[0]) * 1e-9:.6g} s)')
    keep = np.ones(t_ns.size, bool)
    keep[:-1] = t_ns[1:] != t_ns[:-1]
    repeated = int((~keep).sum())
    if repeated > max(10, 0.05 * t_ns.size):
        raise BagReadError(f'{where}: {repeated} of the {t_ns.size} messages of {topic} repeat '
                       'the time of another: the bag holds more than one run (a restarted '
                       'simulator, time going back); record one run per bag, or cut it '
                       'where time goes back')
    if repeated:
        notes.append(f'{topic}: {repeated} repeated time stamps dropped')
    return t_ns[keep], [c[keep] for c in cols]


def _grid(tc: np.ndarray, tf: np.ndarray, dt: float | None, where: str, notes: list
          ) -> tuple[np.ndarray, int]:
    """The common uniform grid [ns] of current stamps ``tc`` and flow stamps ``tf``, and its
    period [ns].

    The grid is built in integer nanoseconds, so a signal stamped on the grid is taken as is
    (interpolation at a node returns the node's value exactly).
    """
    if dt is None:
        # The flow's own period: the current is held, so it may be published at any rate
        # (a command published on change included).
        if tf.size < 2:
            raise PlausibilityError(f'{where}: {tf.size} flow message(s); a fit needs at least '
                                    f'{MIN_SAMPLES} samples: record longer')
        # The mean of the regular steps (gaps left out) telescopes: exact for stamps on a
        # grid, and within jitter / N for receive times, where the median drifts.
        d = np.diff(tf)
        med = float(np.median(d))
        reg = d[(d > 0.5 * med) & (d < 1.5 * med)]
        p_ns = int(round(float(reg.mean()) if reg.size else med))
    else:
        p_ns = int(round(dt * 1e9))
    if p_ns <= 0:
        raise BagReadError(f'{where}: the sample period must be positive')
    # The grid starts on the first flow sample that has a current (within half a period)
    # and ends with the flow: the current holds its last value.
    first = int(np.searchsorted(tf, tc[0] - p_ns // 2))
    if first >= tf.size or int(tf[-1]) <= int(tf[first]):
        raise BagReadError(f'{where}: the current and flow topics do not overlap in time')
    t0 = int(tf[first])
    n = (int(tf[-1]) - t0) // p_ns + 1
    g = t0 + np.arange(n, dtype=np.int64) * p_ns
    d = np.diff(tf[(tf >= t0 - p_ns // 2) & (tf <= g[-1] + p_ns // 2)]) / p_ns
    if d.size:
        gaps = int(np.count_nonzero(d > 1.5))
        if gaps:
            notes.append(f'flow: {gaps} gaps (longest {p_ns * 1e-6 * d.max():.3g} ms) bridged')
        jit = float(np.std(d))
        if jit > 0.1:
            notes.append(f'flow: time stamps jitter by {100 * jit:.0f} % of the period')
    if g[-1] - tc[-1] > 10 * p_ns:
        notes.append(f'current: last message {(g[-1] - tc[-1]) * 1e-9:.3g} s before the end '
                     'of the flow, held since')
    return g, p_ns


def _held(t_ns: np.ndarray, v: np.ndarray, g: np.ndarray, p_ns: int) -> np.ndarray:
    """A held signal on the grid: the last value stamped up to half a period after each grid
    time (NaN before the first).

    Exact for stamps on the grid, and a value stamped at receive time just after the flow of
    its own step (``ros2 bag record`` without simulation time) still pairs with that step.
    """
    k = np.searchsorted(t_ns, g + p_ns // 2, side='right') - 1
    out = v[np.clip(k, 0, v.size - 1)]
    return np.where(k >= 0, out, np.nan)


def _sampled(t_ns: np.ndarray, v: np.ndarray, g: np.ndarray) -> np.ndarray:
    """A sampled signal on the grid, interpolated linearly (NaN outside its span)."""
    return np.interp((g - g[0]) * 1e-9, (t_ns - g[0]) * 1e-9, v, left=np.nan, right=np.nan)


def _signal_name(topic: str, taken: set) -> str:
    """Signal name of a topic read for a role: its last component, or the whole name (without
    the leading ``/``) when that is taken."""
    last = topic.rsplit('/', 1)[-1]
    return topic.strip('/') if last in taken else last


def _saved_signal(rec: Recording, topic: str) -> str | None:
    """The signal of a saved recording that a topic name names, if it has one."""
    for cand in (topic, topic.strip('/'), topic.rsplit('/', 1)[-1]):
        if cand in rec.signals:
            return cand
    return None


def _contract_topic(spec: SignalSpec, topics: dict, ns: str, where: str, strict: bool
                    ) -> str | None:
    """The bag topic of a contract signal: in the flow's namespace first, then by name."""
    near = f'{ns}/{spec.topic}'
    if near in topics:
        return near
    try:
        return match_topic(spec.topic, topics, where)
    except BagReadError:
        if strict:
            raise
        return None


def _extras(signals, bag: Bag, roles: dict, where: str) -> dict[str, str]:
    """Contract signals to read besides the roles: name -> topic."""
    if signals is None:
        return {}
    strict = not isinstance(signals, str)
    if not strict and signals != 'all':
        raise BagReadError(f"signals must be 'all', None or a list of names, got {signals!r}")
    names = list(SIGNALS) if not strict else list(signals)
    unknown = [n for n in names if n not in SIGNALS]
    if unknown:
        raise BagReadError(f'unknown signal {unknown[0]!r}: choose from {", ".join(SIGNALS)}')
    ns = roles['flow'].rpartition('/')[0]
    out = {}
    for n in names:
        topic = _contract_topic(SIGNALS[n], bag.topics, ns, where, strict)
        if topic is not None and topic not in roles.values():
            _check_type(where, topic, bag.topics[topic], n, SIGNALS[n])
            out[n] = topic
    return out


def _check_type(where: str, topic: str, msgtype: str, signal: str, spec: SignalSpec) -> None:
    """Refuse a contract topic of another type than the suite publishes it with: read all the
    same (a ``FluidPressure`` as a flow), its numbers would be taken for what they are not."""
    line = wrong_type(where, topic, msgtype, signal, spec.msgtype)
    if line:
        raise PlausibilityError(line)


def read_recording(path: str | Path, *, current_topic: str = DEFAULT_CURRENT_TOPIC,
                   flow_topic: str = DEFAULT_FLOW_TOPIC, signals: str | Sequence[str] | None
                   = 'all', dt: float | None = None, name: str | None = None,
                   topics: Sequence[str] = ()) -> Recording:
    """Read one bag into a :class:`Recording`: its current, its flow and its other signals.

    Parameters
    ----------
    path : path-like
        Bag directory, ``.mcap`` or ``.db3`` file, or a ``.npz`` saved recording (whose
        roles become ``current_topic`` and ``flow_topic`` where it has signals so named).
    current_topic, flow_topic : str
        Topics of the signals that act as current and flow (relative, absolute or a unique
        suffix such as ``line_flow`` for ``/pump1/line_flow``). The current may be the
        command (``solenoid_current_cmd``) or the applied current (``solenoid_current``, the
        default).
    signals : 'all', sequence of str, or None
        Other signals of :data:`SIGNALS` to read: ``'all'`` those the bag has (one that
        cannot be decoded is left out with a note), a list exactly those (a missing one is an
        error), ``None`` none. Contract topics are looked up in the flow topic's namespace
        first.
    dt : float, optional
        Grid period [s]; default the flow topic's period.
    name : str, optional
        Label; default the bag's name.
    topics : sequence of str
        More topics of one number a message (``loads/boom/pressure``, a circuit's), read as
        they are (FluidPressure absolute) under the names given.

    Raises
    ------
    BagReadError
        Missing path, not a bag, corrupt file, missing or ambiguous topic (the message lists
        the bag's topics), NaNs in the current or flow, no overlap.
    """
    path = existing(path)
    label = name or (path.stem if path.is_file() else path.name)
    if path.suffix == '.npz':
        rec = Recording.load(path)
        rec.name = name or rec.name or label
        return rec.with_roles(current=_saved_signal(rec, current_topic),
                              flow=_saved_signal(rec, flow_topic))
    bag, _ = open_bag(path, None)
    where = str(path)
    roles = {'current': match_topic(current_topic, bag.topics, where),
             'flow': match_topic(flow_topic, bag.topics, where)}
    if roles['current'] == roles['flow']:
        raise BagReadError(f'{where}: current and flow are the same topic {roles["current"]}')
    for topic in roles.values():
        spec = SIGNALS.get(topic.rsplit('/', 1)[-1])
        if spec is not None and spec.entry is None:
            _check_type(where, topic, bag.topics[topic], topic.rsplit('/', 1)[-1], spec)
    extras = _extras(signals, bag, roles, where)
    wanted = {t: match_topic(t, bag.topics, where) for t in topics}
    bag, streams = open_bag(path, sorted({*roles.values(), *extras.values(),
                                          *wanted.values()}))
    notes = list(bag.notes)
    data = {}
    for role, topic in roles.items():
        if topic not in streams:
            why = f' before the bag was cut ({bag.truncation})' if bag.truncated else ''
            raise BagReadError(f'{where}: topic {topic} has no readable messages{why}')
        t_ns, msgs, src = _messages(streams[topic], where)
        t_ns, (v,) = _clean(t_ns, [_scalars(msgs, streams[topic], where)], topic, where,
                            notes, finite=True)
        data[role] = (t_ns, v, src)
    g, p_ns = _grid(data['current'][0], data['flow'][0], dt, where, notes)
    if g.size < 2:
        raise PlausibilityError(f'{where}: {g.size} common sample(s) of {roles["current"]} and '
                                f'{roles["flow"]}; a fit needs at least {MIN_SAMPLES}: record '
                                'longer')
    flow_name = _signal_name(roles['flow'], set())
    names = {'current': _signal_name(roles['current'], {flow_name}), 'flow': flow_name}
    cols = [(names['current'], roles['current'], _held(*data['current'][:2], g, p_ns),
             data['current'][2]),
            (names['flow'], roles['flow'], _sampled(*data['flow'][:2], g), data['flow'][2])]
    others = {sig: topic for sig, topic in extras.items() if sig not in names.values()}
    cols += _other_signals(others, streams, g, p_ns, where, notes,
                           strict=not isinstance(signals, str))
    for label_, topic in wanted.items():
        if topic not in streams:
            raise BagReadError(f'{where}: topic {topic} has no readable messages')
        t_ns, msgs, src = _messages(streams[topic], where)
        t_ns, (v,) = _clean(t_ns, [_scalars(msgs, streams[topic], where)], topic, where,
                            notes, finite=False)
        cols.append((label_, topic, _sampled(t_ns, v, g), src))
    return Recording(t=(g - g[0]) * 1e-9, signals={c[0]: c[2] for c in cols}, name=label,
                     source=where, roles=names,
                     labels={c[0]: SIGNALS[c[0]].label if c[0] in SIGNALS else c[1]
                             for c in cols},
                     topics={c[0]: c[1] for c in cols}, time_source={c[0]: c[3] for c in cols},
                     truncated=bag.truncated, truncation=bag.truncation, notes=notes,
                     t0_ns=int(g[0]))


def _other_signals(signals: dict[str, str], streams: dict, g: np.ndarray, p_ns: int,
                   where: str, notes: list, strict: bool) -> list[tuple]:
    """``(name, topic, values on the grid, time source)`` of contract signals besides the
    roles; without ``strict`` a topic that cannot be read is left out with a note."""
    by_topic: dict[str, list[str]] = {}
    for sig, topic in signals.items():
        by_topic.setdefault(topic, []).append(sig)
    out = []
    for topic, sigs in by_topic.items():
        try:
            if topic not in streams:
                raise BagReadError(f'{where}: topic {topic} has no readable messages')
            t_ns, msgs, src = _messages(streams[topic], where)
            entries = [SIGNALS[s].entry for s in sigs]
            cols = (_entries(msgs, entries, streams[topic], where) if entries[0] else
                    [_scalars(msgs, streams[topic], where)])
            t_ns, cols = _clean(t_ns, cols, topic, where, notes, finite=False)
        except BagReadError as exc:
            if strict:
                raise
            notes.append(f'{", ".join(sigs)} left out: {exc}')
            continue
        out += [(sig, topic, _held(t_ns, v, g, p_ns) if SIGNALS[sig].held else
                 _sampled(t_ns, v, g), src) for sig, v in zip(sigs, cols)]
    return out


def read_recordings(paths, *, allow_truncated: bool = False, progress: bool | None = False,
                    params=None, check: Sequence[str] | None = None, **kw) -> list[Recording]:
    """Read several bags with :func:`read_recording` (keywords ``kw``).

    A truncated bag raises :class:`~.errors.BagReadError` unless ``allow_truncated`` (then its
    readable part is returned, marked ``truncated``). ``progress`` shows a tqdm bar
    (``None``: only on a terminal). With ``params`` (the pump's), every recording is checked
    against it before it is returned (:func:`.plausibility.check_recordings`: units, length),
    ``check`` naming the signals checked besides the current and the flow (default: all):
    every problem of every bag is raised at once as a
    :class:`~.errors.PlausibilityError`.
    """
    from tqdm import tqdm

    if isinstance(paths, (str, bytes)) or hasattr(paths, '__fspath__'):
        paths = [paths]
    recs = []
    for p in tqdm(paths, desc='read', unit='bag', disable=not progress if progress
                  is not None else None, leave=False):
        rec = read_recording(p, **kw)
        if rec.truncated and not allow_truncated:
            raise BagReadError(f'{p}: the bag is truncated ({rec.truncation}); use '
                           'allow_truncated (--allow-truncated) to read its readable part')
        recs.append(rec)
    if params is not None:
        check_recordings(recs, params, check)
    return recs


# --------------------------------------------------------------------------------------------
# Records to bags (tests, conversions): the recorder's topics and types
# --------------------------------------------------------------------------------------------

def recording_to_bag(rec: Recording, path: str | Path, *, storage: str = 'mcap',
                     namespace: str = '', current_topic: str | None = None,
                     flow_topic: str | None = None, start_s: float = 0.0) -> Path:
    """Write every signal of a recording as the project's recorder would (sim-time ns).

    Contract signals go to their topics and types (``Float64``, ``FluidPressure`` with
    absolute pressures, ``JointState`` for positions and the controller's state), another
    signal to a ``Float64`` topic of its name; ``current_topic`` and ``flow_topic`` rename
    the topics of the signals that act as current and flow.
    """
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    t = rec.t + start_s
    rename = {rec.roles['current']: current_topic, rec.roles['flow']: flow_topic}
    streams: dict[str, tuple] = {}
    for sig, v in rec.signals.items():
        spec = SIGNALS.get(sig)
        topic = f'{ns}/{(rename.get(sig) or (spec.topic if spec else sig)).strip("/")}'
        if spec is not None and spec.entry is not None:
            streams.setdefault(topic, (spec.msgtype, t, {}))[2][spec.entry] = v
        else:
            streams[topic] = (spec.msgtype if spec else FLOAT64, t, v)
    return write_bag(path, streams, storage=storage)
