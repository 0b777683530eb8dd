"""rosbag2 storage: open a bag in any accepted form, read raw messages, write bags.

Accepted: a bag directory (``metadata.yaml`` and ``.mcap`` or ``.db3`` files) as written by
the project's recorder (:mod:`.writer`) or by ``ros2 bag record``; a single ``.mcap`` or ``.db3``
file; a compressed bag; a bag whose recorder was killed (an MCAP file without footer and
summary, perhaps no ``metadata.yaml``), read with the ``mcap`` library's streaming reader up
to its last whole record and marked truncated. Topic names match exactly or by a unique
suffix (:func:`match_topic`).

This module knows storage formats and message types, not what the signals mean (that is
:mod:`.recording`). Every problem is a :class:`~.errors.BagReadError` with a one-line message.
Nothing here imports ROS.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import BagReadError
from .writer import typestore

MCAP_MAGIC = b'\x89MCAP0\r\n'
SQLITE_MAGIC = b'SQLite format 3\x00'


def one_line(text: Any) -> str:
    """``text`` (an exception, say) on one line, for an error message."""
    return ' '.join(str(text).split()) or type(text).__name__




@dataclass
class Stream:
    """The raw messages of one topic and their log times [ns], in storage order."""

    topic: str
    msgtype: str
    msgdef: str = ''
    log_ns: list = field(default_factory=list)
    raw: list = field(default_factory=list)


@dataclass
class Bag:
    """Messages of the wanted topics of one bag, however they were read."""

    path: Path
    topics: dict                     # topic -> msgtype
    truncated: bool = False
    truncation: str = ''
    notes: list = field(default_factory=list)


def _not_a_bag(path: Path, why: str = '') -> BagReadError:
    extra = f' ({why})' if why else ''
    return BagReadError(f'{path} is not a rosbag2 bag{extra}: give a bag directory with '
                    'metadata.yaml, an .mcap or .db3 file, or a saved .npz recording')


def _storage_files(path: Path) -> list[Path]:
    return sorted([*path.glob('*.mcap'), *path.glob('*.db3')])


def _magic(path: Path, n: int) -> bytes:
    try:
        with path.open('rb') as f:
            return f.read(n)
    except OSError as exc:
        raise BagReadError(f'{path}: cannot read: {exc.strerror or exc}') from None


def _read_rosbags(path: Path, want: list[str] | None):
    """Open with rosbags; returns ``(topics, streams)`` or raises the library's error."""
    from rosbags.rosbag2 import Reader
    with Reader(path) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        if want is None:
            return topics, {}
        conns = [c for c in reader.connections if c.topic in want]
        streams: dict[str, Stream] = {}
        for c in conns:
            streams.setdefault(c.topic, Stream(c.topic, c.msgtype, c.msgdef.data or ''))
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
    streams: dict[str, Stream] = {}
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
                        s = streams.setdefault(topic, Stream(topic, msgtype, text))
                        s.log_ns.append(rec.log_time)
                        s.raw.append(rec.data)
                elif isinstance(rec, (DataEnd, Footer)):
                    complete = True
                    break
        except Exception as exc:  # noqa: BLE001 - any decode failure ends the readable part
            where = (f'stopped after {n_msgs} messages at byte {f.tell()}: '
                     f'{type(exc).__name__} {one_line(exc) if str(exc) else ""}'.strip())
    if not chans and not complete:
        raise BagReadError(f'{path}: truncated MCAP with no readable channel ({where})')
    topics = {t: m for t, m, _ in chans.values()}
    return topics, streams, complete, where


def _metadata(path: Path) -> tuple[dict | None, str]:
    """``rosbag2_bagfile_information`` of a bag directory, or ``None`` and why not."""
    from hydropump_sim.schema import read_yaml
    meta = path / 'metadata.yaml'
    if not meta.is_file():
        return None, 'no metadata.yaml: the recorder did not finish'
    try:
        info = read_yaml(meta)['rosbag2_bagfile_information']
        files = [str(f) for f in info['relative_file_paths']]
        return {**info, 'relative_file_paths': files}, ''
    except Exception as exc:  # noqa: BLE001 - any YAML or layout problem
        return None, f'metadata.yaml not usable ({one_line(exc)}): read the storage files'


def open_bag(path: Path, want: list[str] | None) -> tuple[Bag, dict]:
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
                raise BagReadError(f'{path}: the storage files of metadata.yaml are missing: '
                               f'{", ".join(missing)}')
            notes = [f'storage files missing: {", ".join(missing)}'] if missing else []
            return _open_files(path, present, want, notes + _ended(info, want))
        return _open_files(path, files, want, [why])
    suffix = path.suffix.lower()
    if suffix in ('.mcap', '.db3'):
        return _open_files(path, [path], want, [])
    if path.name == 'metadata.yaml':
        return open_bag(path.parent, want)
    head = _magic(path, 16)
    if head.startswith(MCAP_MAGIC) or head.startswith(SQLITE_MAGIC):
        raise _not_a_bag(path, 'an MCAP or SQLite file needs the .mcap or .db3 suffix')
    raise _not_a_bag(path)


def _ended(info: dict, want: list[str] | None) -> list[str]:
    """A note per wanted topic (all with ``want`` None) that its recorder saw stop before the
    bag's end (``custom_data`` ``ended.<topic>``)."""
    cd = info.get('custom_data')
    if not isinstance(cd, dict):
        return []
    ended = {str(k).removeprefix('ended.'): v for k, v in cd.items()
             if str(k).startswith('ended.')}
    return [f'{topic}: its recorder saw it stop at t = {at} s, before the bag ended, its '
            'publisher still in the graph (a publisher that stopped, or samples DDS had yet '
            'to repair)' for topic, at in ended.items() if want is None or topic in want]


def _open_compressed(path: Path, want) -> tuple[Bag, dict]:
    """A compressed bag through the rosbags directory reader (it decompresses)."""
    try:
        topics, streams = _read_rosbags(path, want)
    except Exception as exc:  # noqa: BLE001 - yaml, sqlite3, zstd and rosbags errors
        raise BagReadError(f'{path}: cannot read the compressed bag: {one_line(exc)}') from None
    return Bag(path, topics), streams


def _open_files(path: Path, files: list[Path], want, notes) -> tuple[Bag, dict]:
    """Read storage files one by one (split bags), streaming MCAPs that lack a footer."""
    bag = Bag(path, {}, notes=list(notes))
    streams: dict[str, Stream] = {}
    for f in files:
        if f.suffix == '.db3':
            if not _magic(f, 16).startswith(SQLITE_MAGIC):
                raise BagReadError(f'{f}: not an SQLite database (corrupt or not a bag)')
            try:
                topics, part = _read_rosbags(f, want)
            except Exception as exc:  # noqa: BLE001 - sqlite3 raises several kinds
                raise BagReadError(f'{f}: cannot read the sqlite3 bag: {one_line(exc)}') from None
        else:
            if not _magic(f, 8).startswith(MCAP_MAGIC):
                raise BagReadError(f'{f}: not an MCAP file (bad magic): corrupt or not a bag')
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
    path = existing(path)
    bag, _ = open_bag(path, None)
    return dict(sorted(bag.topics.items()))


def existing(path) -> Path:
    """``path`` as a ``Path``; :class:`~.errors.BagReadError` when there is nothing there."""
    path = Path(path)
    if not path.exists():
        raise BagReadError(f'{path}: no such file or directory')
    return path


def match_topic(name: str, topics, where: str = 'the bag') -> str:
    """The topic ``name`` names: exact (with or without leading ``/``) or unique suffix.

    ``line_flow`` matches ``/line_flow`` and ``/pump1/line_flow``, never
    ``/solenoid_line_flow``: the suffix must start at a ``/``.
    """
    bare = name.strip('/')
    if not bare:
        raise BagReadError('empty topic name')
    for cand in (name, '/' + bare):
        if cand in topics:
            return cand
    hits = sorted(t for t in topics if t.endswith('/' + bare))
    if len(hits) == 1:
        return hits[0]
    if hits:
        raise BagReadError(f"topic '{name}' is ambiguous in {where}: {', '.join(hits)}; "
                       'give the full name')
    have = ', '.join(f'{t} ({m})' for t, m in sorted(dict(topics).items())) or 'no topics'
    raise BagReadError(f"{where} has no topic '{name}'; it has: {have}")


# --------------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------------

def _decoder(msgtype: str, msgdef: str):
    ts = typestore()
    if msgtype not in ts.types and msgdef:
        from rosbags.typesys import get_types_from_msg
        try:
            ts.register(get_types_from_msg(msgdef, msgtype))
        except Exception:  # noqa: BLE001 - an unusable definition is reported below
            pass
    if msgtype not in ts.types:
        raise BagReadError(f'message type {msgtype} is unknown and the bag carries no definition')
    return lambda raw: ts.deserialize_cdr(raw, msgtype)


def decode(stream: Stream, where: str) -> list:
    """The messages of ``stream``, deserialised.

    A type the store does not know is registered from the definition the bag carries.
    """
    if not stream.raw:
        raise BagReadError(f'{where}: topic {stream.topic} has no messages')
    dec = _decoder(stream.msgtype, stream.msgdef)
    try:
        return [dec(r) for r in stream.raw]
    except Exception as exc:  # noqa: BLE001 - corrupt payloads raise many kinds
        raise BagReadError(f'{where}: cannot decode {stream.topic} ({stream.msgtype}): '
                       f'{one_line(exc)}') from None


def header_stamps(msgs: list) -> np.ndarray | None:
    """``header.stamp`` [ns] of stamped messages, ``None`` when they carry no usable stamp."""
    if not hasattr(msgs[0], 'header'):
        return None
    st = np.fromiter((m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                      for m in msgs), np.int64, len(msgs))
    # Unset stamps are all zero; a simulation starting at t = 0 stamps only its first.
    return st if np.count_nonzero(st) > st.size // 2 else None
