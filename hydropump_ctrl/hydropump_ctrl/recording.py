"""Recordings of the current-to-flow path: read from rosbag2 bags, save and load as ``.npz``.

A :class:`Recording` holds two uniformly sampled SI signals, the absolute solenoid current
[A] and a flow [m^3/s], with their topic names, units, labels and where their times came
from. :func:`read_recording` reads them from

- a rosbag2 bag directory (``metadata.yaml`` and ``.mcap`` or ``.db3`` files), as written by
  the project's recorder (``rosbags``) or by ``ros2 bag record``;
- a single ``.mcap`` or ``.db3`` file;
- a bag whose recorder was killed: an MCAP file without footer and summary, and perhaps no
  ``metadata.yaml``. The readable messages are read with the ``mcap`` library's streaming
  reader and the recording is marked ``truncated``;
- a ``.npz`` file saved by :meth:`Recording.save`.

Times are the messages' ``header.stamp`` where the type has a header, the bag's log time
otherwise. Both signals are put on one uniform grid: the current is held (it is a commanded,
piecewise-constant signal), the flow is interpolated linearly; when both topics are stamped at
the same instants (the simulator publishes them in one step) nothing is interpolated.

Every problem is a :class:`BagError` with a one-line message. Nothing here imports ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import functools
import json
from pathlib import Path
from typing import Any

import numpy as np

UNITS = {'t': 's', 'current': 'A', 'flow': 'm^3/s'}
# Labels of the contract's topics, named as in the paper.
TOPIC_LABELS = {
    'solenoid_current': 'solenoid current I_s',
    'solenoid_current_cmd': 'solenoid current command I_s,ref',
    'line_flow': 'line flow q_l',
    'pump_flow': 'pump flow Q_p',
    'load_flow': 'load flow Q_load',
}
DEFAULT_CURRENT_TOPIC = 'solenoid_current'
DEFAULT_FLOW_TOPIC = 'line_flow'
MCAP_MAGIC = b'\x89MCAP0\r\n'
SQLITE_MAGIC = b'SQLite format 3\x00'


class BagError(ValueError):
    """A bag that cannot be read as asked (one line, for the ``error:`` output)."""


def _one_line(text: Any) -> str:
    return ' '.join(str(text).split()) or type(text).__name__


@dataclass
class Recording:
    """Current and flow on one uniform time grid, SI units.

    Attributes
    ----------
    t : ndarray
        Time [s] from the first common sample (``t0_ns`` is its bag time).
    current : ndarray
        Absolute solenoid current [A], held from ``t[k]`` to ``t[k+1]``.
    flow : ndarray
        Flow [m^3/s] at ``t[k]``.
    name, source : str
        Short label and the path read.
    topics, labels, time_source : dict
        Per signal (``'current'``, ``'flow'``): bag topic, readable label, and ``'header'``
        or ``'log'`` for where the times came from.
    truncated : bool
        The bag was cut short (killed recorder); ``truncation`` says how.
    notes : list of str
        Warnings about the data (gaps, jitter, missing metadata).
    filters : dict
        Per signal, the filter applied after recording (``None``: raw).
    """

    t: np.ndarray
    current: np.ndarray
    flow: np.ndarray
    name: str = ''
    source: str = ''
    topics: dict = field(default_factory=lambda: {'current': '', 'flow': ''})
    labels: dict = field(default_factory=lambda: {'current': TOPIC_LABELS['solenoid_current'],
                                                  'flow': TOPIC_LABELS['line_flow']})
    time_source: dict = field(default_factory=lambda: {'current': 'log', 'flow': 'log'})
    truncated: bool = False
    truncation: str = ''
    notes: list = field(default_factory=list)
    filters: dict = field(default_factory=lambda: {'current': None, 'flow': None})
    t0_ns: int = 0

    units = UNITS

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=float)
        self.current = np.asarray(self.current, dtype=float)
        self.flow = np.asarray(self.flow, dtype=float)
        if not (self.t.ndim == 1 and self.t.shape == self.current.shape == self.flow.shape):
            raise BagError(f'{self.name or "recording"}: time, current and flow must be 1-D '
                           'arrays of equal length')
        if self.t.size < 2:
            raise BagError(f'{self.name or "recording"}: fewer than 2 common samples')

    @property
    def dt(self) -> float:
        """Sample period [s]."""
        return float((self.t[-1] - self.t[0]) / (self.t.size - 1))

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0] + self.dt)

    def _meta(self) -> dict:
        return {'name': self.name, 'source': self.source, 'topics': self.topics,
                'labels': self.labels, 'time_source': self.time_source,
                'truncated': self.truncated, 'truncation': self.truncation,
                'notes': self.notes, 'filters': self.filters, 't0_ns': int(self.t0_ns),
                'units': UNITS}

    def save(self, path: str | Path) -> Path:
        """Save arrays and metadata (JSON) to ``.npz``."""
        path = Path(path)
        np.savez_compressed(path, t=self.t, current=self.current, flow=self.flow,
                            meta=np.array(json.dumps(self._meta())))
        return path if path.suffix == '.npz' else path.with_name(path.name + '.npz')

    @classmethod
    def load(cls, path: str | Path) -> Recording:
        """Load a recording saved by :meth:`save`."""
        try:
            with np.load(path, allow_pickle=False) as d:
                meta = json.loads(str(d['meta']))
                arrays = {k: d[k] for k in ('t', 'current', 'flow')}
        except (OSError, KeyError, ValueError) as exc:
            raise BagError(f'{path}: not a saved recording: {_one_line(exc)}') from None
        meta.pop('units', None)
        return cls(**arrays, **meta)

    def lowpass(self, cutoff: float, signals=('current', 'flow'), order: int = 2,
                zero_phase: bool = False) -> Recording:
        """Butterworth low-pass of the named signals (e.g. to remove dither).

        Causal by default, like a measurement filter; ``zero_phase`` filters forwards and
        backwards. Filtering both signals with the same filter keeps the current-to-flow
        relation (linear filters commute). Filtering the flow alone does not (a causal
        filter's lag adds to ``t_d``): the fit refuses it.
        """
        from scipy import signal as sg
        nyq = 0.5 / self.dt
        if not 0 < cutoff < nyq:
            raise BagError(f'low-pass cutoff must be in (0, {nyq:g}) Hz, got {cutoff!r}')
        sos = sg.butter(order, cutoff / nyq, output='sos')
        out = {'current': self.current, 'flow': self.flow}
        filters = dict(self.filters)
        for s in signals:
            if s not in out:
                raise BagError(f'unknown signal {s!r}: use current or flow')
            if zero_phase:
                out[s] = sg.sosfiltfilt(sos, out[s])
            else:
                # Start from the steady state of the first sample, not from zero.
                out[s] = sg.sosfilt(sos, out[s], zi=sg.sosfilt_zi(sos) * out[s][0])[0]
            kind = 'zero-phase' if zero_phase else 'causal'
            filters[s] = f'butterworth order {order}, {cutoff:g} Hz, {kind}'
        return self._replace(current=out['current'], flow=out['flow'], filters=filters)

    def decimate(self, q: int) -> Recording:
        """Every ``q``-th sample, as a slower logger would sample (no anti-alias filter).

        The held-input assumption of the fit then needs current steps on the coarse grid.
        """
        q = int(q)
        if q < 1:
            raise BagError(f'decimation factor must be a positive integer, got {q}')
        return self._replace(t=self.t[::q], current=self.current[::q], flow=self.flow[::q])

    def _replace(self, **kw) -> Recording:
        data = {'t': self.t, 'current': self.current, 'flow': self.flow, **self._meta()}
        data.pop('units')
        data.update(kw)
        data['notes'] = list(data['notes'])
        return Recording(**data)


# --------------------------------------------------------------------------------------------
# Normalisation (the paper's units, only at the edge)
# --------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def load_default_params():
    """Plant parameters of ``config/pump.yaml`` (or ``$HYDROPUMP_PARAMS``)."""
    from hydropump_sim.params import default_params_path, load_params
    return load_params(default_params_path())


def normalise(rec: Recording, params=None) -> tuple[np.ndarray, np.ndarray]:
    """Current as a fraction of the 0..100 % displacement range, flow in % of ``V_p f_p``.

    With these units a full-range gain is ``G0 = 100``, as in the paper.
    """
    from hydropump_sim.scaling import displacement_of_current, flow_percent
    params = load_default_params() if params is None else params
    return (np.asarray(displacement_of_current(params, rec.current)),
            np.asarray(flow_percent(params, rec.flow)))


# --------------------------------------------------------------------------------------------
# Bag access
# --------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=1)
def _typestore():
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


@dataclass
class _Stream:
    topic: str
    msgtype: str
    msgdef: str = ''
    log_ns: list = field(default_factory=list)
    raw: list = field(default_factory=list)


@dataclass
class _Bag:
    """Messages of the wanted topics of one bag, however they were read."""

    path: Path
    topics: dict                     # topic -> msgtype
    truncated: bool = False
    truncation: str = ''
    notes: list = field(default_factory=list)


def _not_a_bag(path: Path, why: str = '') -> BagError:
    extra = f' ({why})' if why else ''
    return BagError(f'{path} is not a rosbag2 bag{extra}: give a bag directory with '
                    'metadata.yaml, an .mcap or .db3 file, or a saved .npz recording')


def _storage_files(path: Path) -> list[Path]:
    return sorted([*path.glob('*.mcap'), *path.glob('*.db3')])


def _magic(path: Path, n: int) -> bytes:
    try:
        with path.open('rb') as f:
            return f.read(n)
    except OSError as exc:
        raise BagError(f'{path}: cannot read: {exc.strerror or exc}') from None


def _read_rosbags(path: Path, want: list[str] | None):
    """Open with rosbags; returns ``(topics, streams)`` or raises the library's error."""
    from rosbags.rosbag2 import Reader
    with Reader(path) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        if want is None:
            return topics, {}
        conns = [c for c in reader.connections if c.topic in want]
        streams: dict[str, _Stream] = {}
        for c in conns:
            streams.setdefault(c.topic, _Stream(c.topic, c.msgtype, c.msgdef.data or ''))
        for conn, t_ns, raw in reader.messages(connections=conns):
            s = streams[conn.topic]
            s.log_ns.append(t_ns)
            s.raw.append(bytes(raw))
        return topics, streams


def _stream_mcap(path: Path, want: list[str] | None):
    """Read an MCAP file sequentially, up to where it ends or breaks.

    Returns ``(topics, streams, complete, where)``: ``complete`` is False when the footer
    was never reached (killed recorder), ``where`` says what stopped the reading.
    """
    from mcap.records import Channel, DataEnd, Footer, Message, Schema
    from mcap.stream_reader import StreamReader
    schemas: dict[int, Schema] = {}
    chans: dict[int, tuple[str, str, str]] = {}
    streams: dict[str, _Stream] = {}
    complete, where, n_msgs = False, '', 0
    with path.open('rb') as f:
        try:
            for rec in StreamReader(f, record_size_limit=1 << 30).records:
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    sch = schemas.get(rec.schema_id)
                    name = sch.name if sch else ''
                    text = sch.data.decode(errors='replace') if sch else ''
                    chans[rec.id] = (rec.topic, name, text)
                elif isinstance(rec, Message):
                    n_msgs += 1
                    if want is None or rec.channel_id not in chans:
                        continue
                    topic, msgtype, text = chans[rec.channel_id]
                    if topic in want:
                        s = streams.setdefault(topic, _Stream(topic, msgtype, text))
                        s.log_ns.append(rec.log_time)
                        s.raw.append(rec.data)
                elif isinstance(rec, (DataEnd, Footer)):
                    complete = True
                    break
        except Exception as exc:  # noqa: BLE001 - any decode failure ends the readable part
            where = (f'stopped after {n_msgs} messages at byte {f.tell()}: '
                     f'{type(exc).__name__} {_one_line(exc) if str(exc) else ""}'.strip())
    if not chans and not complete:
        raise BagError(f'{path}: truncated MCAP with no readable channel ({where})')
    topics = {t: m for t, m, _ in chans.values()}
    return topics, streams, complete, where


def _metadata(path: Path) -> tuple[dict | None, str]:
    """``rosbag2_bagfile_information`` of a bag directory, or ``None`` and why not."""
    import yaml
    meta = path / 'metadata.yaml'
    if not meta.is_file():
        return None, 'no metadata.yaml: the recorder did not finish'
    try:
        info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
        files = [str(f) for f in info['relative_file_paths']]
        return {**info, 'relative_file_paths': files}, ''
    except Exception as exc:  # noqa: BLE001 - any YAML or layout problem
        return None, f'metadata.yaml not usable ({_one_line(exc)}): read the storage files'


def _open(path: Path, want: list[str] | None) -> tuple[_Bag, dict]:
    """Topics and wanted streams of a bag in any of the accepted forms.

    Storage files are read one by one: MCAP and rosbag2 sqlite3 files describe their own
    topics, so ``metadata.yaml`` only gives the file order of a split bag (and a killed
    recorder may not have written it).
    """
    if path.is_dir():
        info, why = _metadata(path)
        files = _storage_files(path)
        if info is None and not files:
            raise _not_a_bag(path, 'no metadata.yaml, .mcap or .db3 inside')
        if info is not None:
            if (info.get('compression_mode') or '').lower() not in ('', 'none'):
                return _open_compressed(path, want)
            listed = [path / Path(f).name for f in info['relative_file_paths']]
            missing = [f.name for f in listed if not f.exists()]
            present = [f for f in listed if f.exists()]
            if not present:
                raise BagError(f'{path}: the storage files of metadata.yaml are missing: '
                               f'{", ".join(missing)}')
            notes = [f'storage files missing: {", ".join(missing)}'] if missing else []
            return _open_files(path, present, want, notes)
        return _open_files(path, files, want, [why])
    suffix = path.suffix.lower()
    if suffix in ('.mcap', '.db3'):
        return _open_files(path, [path], want, [])
    if path.name == 'metadata.yaml':
        return _open(path.parent, want)
    head = _magic(path, 16)
    if head.startswith(MCAP_MAGIC) or head.startswith(SQLITE_MAGIC):
        raise _not_a_bag(path, 'an MCAP or SQLite file needs the .mcap or .db3 suffix')
    raise _not_a_bag(path)


def _open_compressed(path: Path, want) -> tuple[_Bag, dict]:
    """A compressed bag through the rosbags directory reader (it decompresses)."""
    try:
        topics, streams = _read_rosbags(path, want)
    except Exception as exc:  # noqa: BLE001 - yaml, sqlite3, zstd and rosbags errors
        raise BagError(f'{path}: cannot read the compressed bag: {_one_line(exc)}') from None
    return _Bag(path, topics), streams


def _open_files(path: Path, files: list[Path], want, notes) -> tuple[_Bag, dict]:
    """Read storage files one by one (split bags), streaming MCAPs that lack a footer."""
    bag = _Bag(path, {}, notes=list(notes))
    streams: dict[str, _Stream] = {}
    for f in files:
        if f.suffix == '.db3':
            if not _magic(f, 16).startswith(SQLITE_MAGIC):
                raise BagError(f'{f}: not an SQLite database (corrupt or not a bag)')
            try:
                topics, part = _read_rosbags(f, want)
            except Exception as exc:  # noqa: BLE001 - sqlite3 raises several kinds
                raise BagError(f'{f}: cannot read the sqlite3 bag: {_one_line(exc)}') from None
        else:
            if not _magic(f, 8).startswith(MCAP_MAGIC):
                raise BagError(f'{f}: not an MCAP file (bad magic): corrupt or not a bag')
            try:
                topics, part = _read_rosbags(f, want)
            except Exception:  # noqa: BLE001 - no footer, bad index: stream what is there
                topics, part, complete, where = _stream_mcap(f, want)
                if not complete:
                    bag.truncated = True
                    bag.truncation = (f'{f.name} has no footer or summary (recorder killed?); '
                                      f'{where}')
        bag.topics.update(topics)
        for t, s in part.items():
            if t in streams:
                streams[t].log_ns += s.log_ns
                streams[t].raw += s.raw
            else:
                streams[t] = s
    return bag, streams


def list_topics(path: str | Path) -> dict[str, str]:
    """Topics of a bag and their message types."""
    path = _existing(path)
    bag, _ = _open(path, None)
    return dict(sorted(bag.topics.items()))


def _existing(path) -> Path:
    path = Path(path)
    if not path.exists():
        raise BagError(f'{path}: no such file or directory')
    return path


def match_topic(name: str, topics, where: str = 'the bag') -> str:
    """The topic ``name`` names: exact (with or without leading ``/``) or unique suffix.

    ``line_flow`` matches ``/line_flow`` and ``/pump1/line_flow``, never
    ``/solenoid_line_flow``: the suffix must start at a ``/``.
    """
    bare = name.strip('/')
    if not bare:
        raise BagError('empty topic name')
    for cand in (name, '/' + bare):
        if cand in topics:
            return cand
    hits = sorted(t for t in topics if t.endswith('/' + bare))
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise BagError(f"topic '{name}' is ambiguous in {where}: {', '.join(hits)}; "
                       'give the full name')
    have = ', '.join(f'{t} ({m})' for t, m in sorted(dict(topics).items())) or 'no topics'
    raise BagError(f"{where} has no topic '{name}'; it has: {have}")


# --------------------------------------------------------------------------------------------
# Decoding and the common time grid
# --------------------------------------------------------------------------------------------

def _decoder(msgtype: str, msgdef: str):
    ts = _typestore()
    if msgtype not in ts.types and msgdef:
        from rosbags.typesys import get_types_from_msg
        try:
            ts.register(get_types_from_msg(msgdef, msgtype))
        except Exception:  # noqa: BLE001 - an unusable definition is reported below
            pass
    if msgtype not in ts.types:
        raise BagError(f'message type {msgtype} is unknown and the bag carries no definition')
    return lambda raw: ts.deserialize_cdr(raw, msgtype)


_SCALAR_FIELDS = ('data', 'fluid_pressure', 'temperature', 'illuminance', 'range')


def _decode(stream: _Stream, where: str) -> tuple[np.ndarray, np.ndarray, str]:
    """Times [ns] and values of a scalar topic, and ``'header'`` or ``'log'``."""
    if not stream.raw:
        raise BagError(f'{where}: topic {stream.topic} has no messages')
    dec = _decoder(stream.msgtype, stream.msgdef)
    try:
        msgs = [dec(r) for r in stream.raw]
    except Exception as exc:  # noqa: BLE001 - corrupt payloads raise many kinds
        raise BagError(f'{where}: cannot decode {stream.topic} ({stream.msgtype}): '
                       f'{_one_line(exc)}') from None
    field_name = next((f for f in _SCALAR_FIELDS if isinstance(getattr(msgs[0], f, None),
                                                                (int, float))), None)
    if field_name is None:
        raise BagError(f'{where}: topic {stream.topic} ({stream.msgtype}) carries no single '
                       'number: use a std_msgs/msg/Float64 topic')
    vals = np.fromiter((getattr(m, field_name) for m in msgs), float, len(msgs))
    log = np.asarray(stream.log_ns, dtype=np.int64)
    if hasattr(msgs[0], 'header'):
        st = np.fromiter((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                          for m in msgs), np.int64, len(msgs))
        # Unset stamps are all zero; a simulation starting at t = 0 stamps only its first.
        if np.count_nonzero(st) > st.size // 2:
            return st, vals, 'header'
    return log, vals, 'log'


def _clean(t_ns: np.ndarray, v: np.ndarray, topic: str, where: str, notes: list
           ) -> tuple[np.ndarray, np.ndarray]:
    order = np.argsort(t_ns, kind='stable')
    t_ns, v = t_ns[order], v[order]
    bad = ~np.isfinite(v)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise BagError(f'{where}: {topic} has {int(bad.sum())} NaN or infinite values (first '
                       f'at t = {(t_ns[k] - t_ns[0]) * 1e-9:.6g} s)')
    # Repeated stamps: keep the last message of each instant.
    keep = np.ones(t_ns.size, bool)
    keep[:-1] = t_ns[1:] != t_ns[:-1]
    if not keep.all():
        notes.append(f'{topic}: {int((~keep).sum())} repeated time stamps dropped')
    return t_ns[keep], v[keep]


def _grid(tc, vc, tf, vf, dt, where, notes) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Common uniform grid: the current held, the flow interpolated.

    The grid is built in integer nanoseconds, so a flow stamped on the grid is taken as is
    (interpolation at a node returns the node's value exactly). The current is rounded to
    the nearest grid time, so that stamp jitter below half a period does not shift it.
    """
    if dt is None:
        # The flow's own period: the current is held, so it may be published at any rate
        # (a command published on change included).
        if tf.size < 2:
            raise BagError(f'{where}: too few flow messages to find the sample period')
        # The mean of the regular steps (gaps left out) telescopes: exact for stamps on a
        # grid, and within jitter / N for receive times, where the median drifts.
        d = np.diff(tf)
        med = float(np.median(d))
        reg = d[(d > 0.5 * med) & (d < 1.5 * med)]
        p_ns = int(round(float(reg.mean()) if reg.size else med))
    else:
        p_ns = int(round(dt * 1e9))
    if p_ns <= 0:
        raise BagError(f'{where}: the sample period must be positive')
    # The grid starts on the first flow sample that has a current (within half a period)
    # and ends with the flow: the current holds its last value.
    first = int(np.searchsorted(tf, tc[0] - p_ns // 2))
    if first >= tf.size:
        raise BagError(f'{where}: the current and flow topics do not overlap in time')
    t0 = int(tf[first])
    t1 = int(tf[-1])
    if t1 <= t0:
        raise BagError(f'{where}: the current and flow topics do not overlap in time')
    n = (t1 - t0) // p_ns + 1
    g = t0 + np.arange(n, dtype=np.int64) * p_ns
    for topic, x in (('flow', tf),):
        d = np.diff(x[(x >= t0 - p_ns // 2) & (x <= g[-1] + p_ns // 2)]) / p_ns
        if d.size:
            gaps = int(np.count_nonzero(d > 1.5))
            if gaps:
                notes.append(f'{topic}: {gaps} gaps (longest {p_ns * 1e-6 * d.max():.3g} ms) '
                             'bridged')
            jit = float(np.std(d))
            if jit > 0.1:
                notes.append(f'{topic}: time stamps jitter by {100 * jit:.0f} % of the period')
    if g[-1] - tc[-1] > 10 * p_ns:
        notes.append(f'current: last message {(g[-1] - tc[-1]) * 1e-9:.3g} s before the end '
                     'of the flow, held since')
    # The current of grid time g is the last one stamped up to g + T/2: exact for stamps on
    # the grid, and a current stamped at receive time just after the flow of its own step
    # (ros2 bag record without simulation time) still pairs with that step.
    k = np.searchsorted(tc, g + p_ns // 2, side='right') - 1
    cur = vc[np.clip(k, 0, vc.size - 1)]
    flow = np.interp((g - t0) * 1e-9, (tf - t0) * 1e-9, vf)
    return t0, (g - t0) * 1e-9, cur, flow


def read_recording(path: str | Path, *, current_topic: str = DEFAULT_CURRENT_TOPIC,
                   flow_topic: str = DEFAULT_FLOW_TOPIC, dt: float | None = None,
                   name: str | None = None) -> Recording:
    """Read the current and the flow of one bag into a :class:`Recording`.

    Parameters
    ----------
    path : path-like
        Bag directory, ``.mcap`` or ``.db3`` file, or a ``.npz`` saved recording.
    current_topic, flow_topic : str
        Topic names (relative, absolute or a unique suffix such as ``line_flow`` for
        ``/pump1/line_flow``). The current may be the command (``solenoid_current_cmd``)
        or the applied current (``solenoid_current``, the default).
    dt : float, optional
        Grid period [s]; default the flow topic's median period.
    name : str, optional
        Label; default the bag's name.

    Raises
    ------
    BagError
        Missing path, not a bag, corrupt file, missing or ambiguous topic (the message lists
        the bag's topics), NaNs, no overlap.
    """
    path = _existing(path)
    label = name or (path.stem if path.is_file() else path.name)
    if path.suffix == '.npz':
        rec = Recording.load(path)
        rec.name = name or rec.name or label
        return rec
    bag, _ = _open(path, None)
    where = str(path)
    t_cur = match_topic(current_topic, bag.topics, where)
    t_flow = match_topic(flow_topic, bag.topics, where)
    if t_cur == t_flow:
        raise BagError(f'{where}: current and flow are the same topic {t_cur}')
    bag, streams = _open(path, [t_cur, t_flow])
    notes = list(bag.notes)
    data = {}
    for key, topic in (('current', t_cur), ('flow', t_flow)):
        if topic not in streams:
            why = f' before the bag was cut ({bag.truncation})' if bag.truncated else ''
            raise BagError(f'{where}: topic {topic} has no readable messages{why}')
        t_ns, v, src = _decode(streams[topic], where)
        t_ns, v = _clean(t_ns, v, topic, where, notes)
        data[key] = (t_ns, v, src)
    t0, t, cur, flow = _grid(data['current'][0], data['current'][1], data['flow'][0],
                             data['flow'][1], dt, where, notes)
    if t.size < 2:
        raise BagError(f'{where}: fewer than 2 common samples of {t_cur} and {t_flow}')
    labels = {k: TOPIC_LABELS.get(tp.rsplit('/', 1)[-1], tp)
              for k, tp in (('current', t_cur), ('flow', t_flow))}
    return Recording(t=t, current=cur, flow=flow, name=label, source=str(path),
                     topics={'current': t_cur, 'flow': t_flow}, labels=labels,
                     time_source={k: data[k][2] for k in data}, truncated=bag.truncated,
                     truncation=bag.truncation, notes=notes, t0_ns=t0)


# --------------------------------------------------------------------------------------------
# Writing bags (tests, conversions): the recorder's format, written with rosbags
# --------------------------------------------------------------------------------------------

def write_bag(path: str | Path, streams: dict[str, tuple[str, np.ndarray, np.ndarray]], *,
              storage: str = 'mcap', log_offset_ns: int = 0) -> Path:
    """Write scalar topics as a rosbag2 bag (version 9) with ``rosbags``.

    Parameters
    ----------
    path : path-like
        Bag directory to create (must not exist).
    streams : dict
        ``topic -> (msgtype, t [s], values)``; ``msgtype`` is ``std_msgs/msg/Float64`` or
        ``sensor_msgs/msg/FluidPressure`` (stamped with ``t``). Log times are ``t`` plus
        ``log_offset_ns``, written in time order across topics.
    storage : {'mcap', 'sqlite3'}
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    ts = _typestore()
    plugin = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}[storage]
    path = Path(path)
    events = []
    with Writer(path, version=9, storage_plugin=plugin) as w:
        for topic, (msgtype, t, vals) in streams.items():
            conn = w.add_connection(topic, msgtype, typestore=ts)
            cls = ts.types[msgtype]
            for tk, vk in zip(np.asarray(t, float), np.asarray(vals, float)):
                ns = int(round(tk * 1e9))
                if msgtype == 'sensor_msgs/msg/FluidPressure':
                    stamp = ts.types['builtin_interfaces/msg/Time'](
                        sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
                    hdr = ts.types['std_msgs/msg/Header'](stamp=stamp, frame_id='')
                    msg = cls(header=hdr, fluid_pressure=float(vk), variance=0.0)
                else:
                    msg = cls(data=float(vk))
                events.append((ns + log_offset_ns, len(events), conn,
                               ts.serialize_cdr(msg, msgtype)))
        events.sort(key=lambda e: (e[0], e[1]))
        for ns, _, conn, raw in events:
            w.write(conn, ns, raw)
    return path


def recording_to_bag(rec: Recording, path: str | Path, *, storage: str = 'mcap',
                     namespace: str = '', current_topic: str = DEFAULT_CURRENT_TOPIC,
                     flow_topic: str = DEFAULT_FLOW_TOPIC, start_s: float = 0.0) -> Path:
    """Write a recording as the project's recorder would (Float64 topics, sim-time ns)."""
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    t = rec.t + start_s
    return write_bag(path, {f'{ns}/{current_topic}': ('std_msgs/msg/Float64', t, rec.current),
                            f'{ns}/{flow_topic}': ('std_msgs/msg/Float64', t, rec.flow)},
                     storage=storage)
