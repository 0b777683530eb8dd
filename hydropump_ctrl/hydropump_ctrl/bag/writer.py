"""rosbag2 bags as rosbag2 Jazzy writes them (MCAP storage), without rosbag2.

A bag is a folder ``<bag>/`` holding ``<bag>_0.mcap`` and, once closed, ``metadata.yaml``
(version 9). Written with Foxglove's ``mcap`` writer, to rosbag2's layout:

- MCAP header profile ``ros2``; one schema per type (``ros2msg``, the full concatenated
  definition) and one channel per topic (``cdr``), whose metadata holds
  ``offered_qos_profiles`` (a YAML list, one profile per publisher, as rosbag2 records them
  from the graph) and ``topic_type_hash`` (``RIHS01_...``);
- a ``rosbag2`` metadata record with ``serialized_metadata`` written at open and again at
  close, so that ``ros2 bag reindex`` rebuilds ``metadata.yaml`` of a bag whose recorder was
  killed (it finds ``<name>_<N>.mcap`` files only);
- chunks closed at fixed periods of log time (data-dependent, so two identical runs give
  identical files), zstd-compressed or not (``compression: zstd | none``, as rosbag2's MCAP
  presets do: ``metadata.yaml`` then still says ``compression_format: ""``);
- ``metadata.yaml`` in yaml-cpp's block layout, written atomically at close, with
  ``ros_distro: jazzy`` and ``custom_data`` (string to string).

Every problem a user can cause (an existing or unwritable folder) is a
:class:`~.errors.BagOutputError`.
A write that fails (disk full, a file-size limit, an I/O error) is a
:class:`~.errors.BagWriteError`,
raised once the bag is closed with what it had: the MCAP bytes reach the file only at chunk
boundaries, so the file is cut back to the last whole chunk and ended there (a valid MCAP,
with ``metadata.yaml`` if there is room for it), and the writer takes nothing more.
Nothing here imports ROS.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping, Sequence
import errno
import functools
import os
from pathlib import Path
import re
from typing import Any

from mcap.data_stream import RecordBuilder
from mcap.records import DataEnd, Footer, Metadata
from mcap.writer import CompressionType, MCAP0_MAGIC, Writer
import numpy as np

from hydropump_sim.measure import FLUID_PRESSURE, JOINT_STATE

from .errors import BagExistsError, BagOutputError, BagWriteError

INT64_MAX = 2 ** 63 - 1
INFINITE = {'sec': 9223372036, 'nsec': 854775807}   # RMW_DURATION_INFINITE
ROS_DISTRO = 'jazzy'
CHUNK_SIZE = 768 * 1024                             # rosbag2's MCAP default
COMPRESSION = {'none': CompressionType.NONE, 'zstd': CompressionType.ZSTD}


def os_reason(exc: OSError) -> str:
    """``'No space left on device (ENOSPC)'``."""
    name = errno.errorcode.get(exc.errno or 0)
    text = exc.strerror or str(exc) or type(exc).__name__
    return f'{text} ({name})' if name else text


class _FileSink:
    """The MCAP writer's output stream: bytes stay in memory until :meth:`flush` hands them
    to the file, at record boundaries only, so the size of the file at the last successful
    flush is known exactly and a failed write can be cut back to it."""

    def __init__(self, fd: int):
        self.fd = fd
        self.size = 0                   # bytes in the file, every one written whole
        self._buf = bytearray()

    def write(self, data) -> int:
        self._buf += data
        return len(data)

    def tell(self) -> int:
        return self.size + len(self._buf)

    def flush(self) -> None:
        with memoryview(self._buf) as view:
            done = 0
            while done < len(view):
                done += os.write(self.fd, view[done:])  # OSError: the caller salvages
        self.size += len(self._buf)
        self._buf.clear()

    def drop(self) -> None:
        self._buf.clear()


def qos_profile(history: str = 'unknown', depth: int = 0, reliability: str = 'reliable',
                durability: str = 'volatile', liveliness: str = 'automatic',
                deadline: Mapping | None = None, lifespan: Mapping | None = None,
                lease: Mapping | None = None, avoid_ros_namespace_conventions: bool = False
                ) -> dict[str, Any]:
    """One offered QoS profile in rosbag2's version-9 layout (enum names in lower case,
    durations as ``{sec, nsec}``, infinite by default)."""
    return {'history': history, 'depth': int(depth), 'reliability': reliability,
            'durability': durability, 'deadline': dict(deadline or INFINITE),
            'lifespan': dict(lifespan or INFINITE), 'liveliness': liveliness,
            'liveliness_lease_duration': dict(lease or INFINITE),
            'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions)}


# ---- yaml-cpp's block layout ---------------------------------------------------------------

_PLAIN = re.compile(r'^[A-Za-z_/][A-Za-z0-9_./+\-]*$')
_TYPED = re.compile(r'^(?:true|false|yes|no|on|off|null|y|n|~)$', re.IGNORECASE)


def _scalar(v: Any) -> str:
    if v is None:
        return '~'
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, int):
        return str(v)
    text = str(v)
    if _PLAIN.match(text) and not _TYPED.match(text):
        return text
    return '"' + text.replace('\\', '\\\\').replace('"', '\\"').replace('\n', '\\n') + '"'


def _block(node: Any, indent: int, out: list[str], lead: str | None = None) -> None:
    pad = ' ' * indent
    if isinstance(node, Mapping):
        for i, (k, v) in enumerate(node.items()):
            head = (lead if i == 0 and lead is not None else pad) + f'{_scalar(k)}:'
            if isinstance(v, Mapping) and v:
                out.append(head)
                _block(v, indent + 2, out)
            elif isinstance(v, (list, tuple)):
                out.append(head)
                if v:
                    _block(v, indent + 2, out)
                else:
                    out.append(' ' * (indent + 2) + '[]')
            elif isinstance(v, Mapping):
                out.append(head + ' ~')
            else:
                out.append(f'{head} {_scalar(v)}')
    else:
        for item in node:
            if isinstance(item, Mapping) and item:
                _block(item, indent + 2, out, lead=pad + '- ')
            else:
                out.append(f'{pad}- {_scalar(item)}')


def yaml_cpp(node: Any) -> str:
    """YAML text in yaml-cpp's block layout, as rosbag2 writes it (no trailing newline)."""
    if isinstance(node, (list, tuple)) and not node:
        return '[]'
    out: list[str] = []
    _block(node, 0, out)
    return '\n'.join(out)


# ---- message definitions -------------------------------------------------------------------

@functools.cache
def typestore():
    """The ROS 2 Jazzy message types of ``rosbags`` (one store per process)."""
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def message_definition(msgtype: str) -> tuple[str, str]:
    """``(ros2msg text with its dependencies, RIHS01 type hash)`` of ``pkg/msg/Type``."""
    store = typestore()
    try:
        text, _ = store.generate_msgdef(msgtype, ros_version=2)
        return text, store.hash_rihs01(msgtype)
    except Exception as exc:  # rosbags raises its own errors for unknown types
        raise BagOutputError(f'message type {msgtype}: unknown to the bag writer ({exc})') \
            from None


# ---- the writer ----------------------------------------------------------------------------

class BagWriter:
    """Write one rosbag2 bag (see the module).

    Parameters
    ----------
    path : path-like
        The bag folder; it must not exist (a bag is never overwritten).
    compression : {'zstd', 'none'}
        MCAP chunk compression.
    chunk_period : float
        Close a chunk whenever log time crosses a multiple of this [s]: what a hard kill can
        cost, and data-dependent, so identical runs give identical files.
    custom_data : mapping of str to str, optional
        ``custom_data`` of the metadata (more can be set before :meth:`close`).
    """

    def __init__(self, path: str | os.PathLike, *, compression: str = 'zstd',
                 chunk_period: float = 0.25, custom_data: Mapping[str, str] | None = None):
        if compression not in COMPRESSION:
            raise BagOutputError(f'compression = {compression!r}: use one of '
                                 f'{", ".join(COMPRESSION)}')
        self.path = Path(path)
        self.file_name = f'{self.path.name}_0.mcap'
        self.compression = compression
        self._period_ns = max(1, int(round(chunk_period * 1e9)))
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self.count = 0
        self.start: int | None = None
        self.end: int | None = None
        self._topics: dict[str, dict] = {}
        self._schemas: dict[str, int] = {}
        self._chunk_end: int | None = None
        self._fh: _FileSink | None = None
        self._mcap: Writer | None = None
        # (file size, counts) after the latest whole chunks: where a failed write cuts back to
        self._marks: deque = deque(maxlen=8)
        self.failed: BagWriteError | None = None

    # ---- opening -------------------------------------------------------------------------

    def open(self) -> BagWriter:
        """Create the folder and the MCAP file; raise :class:`BagError` with the reason."""
        exists = BagExistsError(f'{self.path}: exists already (a bag is never overwritten)')
        if unique_path(self.path) != self.path:
            raise exists
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagOutputError(f'{self.path}: cannot create the bag: {exc.strerror or exc}') \
                from None
        try:
            self.path.mkdir()  # atomic: two recorders never share a folder
        except FileExistsError:
            raise exists from None
        except OSError as exc:
            raise BagOutputError(f'{self.path}: cannot create the bag: {exc.strerror or exc}') \
                from None
        try:
            fd = os.open(self.path / self.file_name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except OSError as exc:
            raise BagOutputError(f'{self.path}: cannot create the bag: {exc.strerror or exc}') \
                from None
        self._fh = _FileSink(fd)
        self._mcap = Writer(self._fh, chunk_size=CHUNK_SIZE,
                            compression=COMPRESSION[self.compression])
        self._mcap.start(profile='ros2', library='hydropump recorder (mcap)')
        self._mcap.add_metadata('rosbag2', {'serialized_metadata': yaml_cpp(self._metadata())})
        try:
            self._mcap.flush()
        except OSError as exc:
            os.close(fd)
            self._fh = self._mcap = None
            raise BagOutputError(f'{self.path}: cannot write the bag: {os_reason(exc)}') from None
        self._mark()
        return self

    def __enter__(self) -> BagWriter:
        return self.open() if self._mcap is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    def add_topic(self, name: str, msgtype: str,
                  offered_qos_profiles: Sequence[Mapping[str, Any]] = ()) -> None:
        """Register a topic (once) with its type and the QoS of its publishers."""
        if name in self._topics:
            return
        text, type_hash = message_definition(msgtype)
        if msgtype not in self._schemas:
            self._schemas[msgtype] = self._mcap.register_schema(msgtype, 'ros2msg',
                                                                text.encode())
        profiles = [dict(p) for p in offered_qos_profiles]
        channel = self._mcap.register_channel(
            topic=name, message_encoding='cdr', schema_id=self._schemas[msgtype],
            metadata={'offered_qos_profiles': yaml_cpp(profiles),
                      'topic_type_hash': type_hash})
        self._topics[name] = {'channel': channel, 'count': 0, 'meta': {
            'name': name, 'type': msgtype, 'serialization_format': 'cdr',
            'offered_qos_profiles': profiles, 'type_description_hash': type_hash}}

    @property
    def topics(self) -> list[str]:
        return list(self._topics)

    # ---- writing -------------------------------------------------------------------------

    def write(self, topic: str, log_ns: int, data: bytes, publish_ns: int | None = None
              ) -> None:
        """One serialized message at log time ``log_ns`` [ns]; :class:`BagWriteError` if the
        file cannot take it (the bag is then closed, see the module)."""
        if self._mcap is None:
            raise self.failed or BagOutputError(f'{self.path}: the bag is closed')
        t = self._topics[topic]
        if self._chunk_end is None:
            self._chunk_end = (log_ns // self._period_ns + 1) * self._period_ns
        elif log_ns >= self._chunk_end:
            self.flush()
            self._chunk_end = (log_ns // self._period_ns + 1) * self._period_ns
        self._mcap.add_message(channel_id=t['channel'], log_time=log_ns, data=data,
                               publish_time=log_ns if publish_ns is None else publish_ns,
                               sequence=0)
        t['count'] += 1
        self.count += 1
        self.start = log_ns if self.start is None else min(self.start, log_ns)
        self.end = log_ns if self.end is None else max(self.end, log_ns)

    def flush(self) -> None:
        """Close the open chunk and hand it to the operating system."""
        try:
            self._mcap.flush()
        except OSError as exc:
            self._salvage(exc)
        self._mark()

    def close(self) -> Path:
        """Write the final metadata record, the summary and ``metadata.yaml``."""
        if self._mcap is None:
            if self.failed is not None:
                raise self.failed
            return self.path
        try:
            self._mcap.flush()
            self._mark()
            self._mcap.add_metadata('rosbag2', {'serialized_metadata': yaml_cpp(
                self._metadata(final=True))})
            self._mcap.finish()
            self._fh.flush()
        except OSError as exc:
            self._salvage(exc)
        os.close(self._fh.fd)
        self._mcap = None
        try:
            self._write_info()
        except OSError as exc:
            self.failed = self._error(exc, 'metadata.yaml not written')
            raise self.failed from None
        return self.path

    def _write_info(self) -> None:
        text = yaml_cpp({'rosbag2_bagfile_information': self._metadata(final=True)})
        tmp = self.path / 'metadata.yaml.tmp'
        try:
            tmp.write_text(text, encoding='utf-8')
            os.replace(tmp, self.path / 'metadata.yaml')
        except OSError:
            tmp.unlink(missing_ok=True)
            raise

    # ---- a failed write ------------------------------------------------------------------

    def _mark(self) -> None:
        self._marks.append((self._fh.size, self.count, self.start, self.end,
                            {k: t['count'] for k, t in self._topics.items()}))

    def _error(self, exc: OSError, what: str) -> BagWriteError:
        reason = os_reason(exc)
        return BagWriteError(f'{self.path}: cannot write: {reason}; {what}', self.path, reason,
                             self.count)

    def _salvage(self, exc: OSError) -> None:
        """After a failed write: cut the file back to its last whole chunk, end it there as
        a valid MCAP (going back a chunk at a time until the ending fits), write
        ``metadata.yaml`` for what is in it, and raise :class:`BagWriteError`."""
        self._fh.drop()
        fd, self._mcap = self._fh.fd, None
        self.custom_data['closed_by'] = f'write error: {os_reason(exc)}'
        latest = self._marks[-1] if self._marks else None
        ended = False
        while self._marks and not ended:
            self._restore(self._marks[-1])
            ended = self._end_at(fd, self._marks[-1][0])
            if not ended:
                self._marks.pop()  # drop the last chunk to make room for the ending
        if not ended and latest is not None:
            # No room even for an ending: keep every whole chunk (a streaming reader and
            # ros2 bag reindex read a file without one).
            self._restore(latest)
            os.ftruncate(fd, latest[0])
        os.close(fd)
        info = 'no room for metadata.yaml: ros2 bag reindex rebuilds it'
        if ended:
            try:
                self._write_info()
                info = 'metadata.yaml written'
            except OSError:
                pass
        what = (f'closed with the {self.count} messages written before' if ended
                else f'left without an ending after {self.count} messages')
        self.failed = self._error(exc, f'the bag is {what} ({info})')
        raise self.failed from None

    def _restore(self, mark) -> None:
        """The counts of a mark: what the file holds when cut back to it."""
        _, self.count, self.start, self.end, counts = mark
        for name, t in self._topics.items():
            t['count'] = counts.get(name, 0)

    def _end_at(self, fd: int, size: int) -> bool:
        """Cut the file to ``size`` and end it (the final ``rosbag2`` metadata record if there
        is room, a data end, a footer without summary, the magic); whether it fitted."""
        b = RecordBuilder()
        Metadata(name='rosbag2', metadata={'serialized_metadata': yaml_cpp(
            self._metadata(final=True))}).write(b)
        record = b.end()
        DataEnd(data_section_crc=0).write(b)
        Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(b)
        bare = b.end() + MCAP0_MAGIC
        for data in (record + bare, bare):
            try:
                os.ftruncate(fd, size)
                os.lseek(fd, size, os.SEEK_SET)
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view):]
                return True
            except OSError:
                continue
        return False

    def _metadata(self, final: bool = False) -> dict[str, Any]:
        start = self.start if final and self.start is not None else INT64_MAX
        duration = (self.end - self.start) if final and self.start is not None else 0
        count = self.count if final else 0
        return {
            'version': 9,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [{'topic_metadata': t['meta'],
                                           'message_count': t['count'] if final else 0}
                                          for t in self._topics.values()] if final else [],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name,
                       'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration}, 'message_count': count}],
            'custom_data': dict(self.custom_data) or None,
            'ros_distro': ROS_DISTRO,
        }


def unique_path(path: str | os.PathLike) -> Path:
    """``path``, or ``path_1``, ``path_2``, ... if it exists (a bag is never overwritten)."""
    path = Path(path)
    base, n = path, 1
    try:
        while path.exists():
            path = base.with_name(f'{base.name}_{n}')
            n += 1
    except OSError as exc:  # a name too long, a path through a file: exists() raises
        raise BagOutputError(f'{path}: cannot create the bag: {exc.strerror or exc}') from None
    return path


def open_unique(path: str | os.PathLike, **kw) -> BagWriter:
    """An open :class:`BagWriter` at ``path`` or the first free ``path_<n>``, also when
    another recorder picks a name at the same moment."""
    path = unique_path(path)
    base, n = path, 1
    while True:
        try:
            return BagWriter(path, **kw).open()
        except BagExistsError:
            path = unique_path(base.with_name(f'{base.name}_{n}'))
            n += 1


# ---- bags of arrays (offline tools, tests) --------------------------------------------------

def write_bag(path: str | os.PathLike, streams: Mapping[str, tuple[str, Any, Any]], *,
              storage: str = 'mcap', log_offset_ns: int = 0,
              custom_data: Mapping[str, str] | None = None) -> Path:
    """Write topics of numbers as a rosbag2 bag: with :class:`BagWriter` (MCAP, what the
    recorder node writes) or, for ``storage='sqlite3'``, with ``rosbags`` (rosbag2's other
    storage, for readers that must take both).

    Parameters
    ----------
    path : path-like
        Bag directory to create (must not exist).
    streams : mapping
        ``topic -> (msgtype, t [s], values)``. ``sensor_msgs/msg/FluidPressure`` and a type
        with a ``data`` number (``std_msgs/msg/Float64``) take an array of values;
        ``sensor_msgs/msg/JointState`` takes a dict ``entry name -> positions``. The first
        two kinds with a header are stamped with ``t``. Log times are ``t`` plus
        ``log_offset_ns``, written in time order across topics. A value that is NaN in a
        Float64 stream is a message with a NaN (a dropped message is a missing time).
    storage : {'mcap', 'sqlite3'}
    """
    if storage not in ('mcap', 'sqlite3'):
        raise BagOutputError(f'storage = {storage!r}: use mcap or sqlite3')
    ts = typestore()
    events = []
    for topic, (msgtype, t, vals) in streams.items():
        for k, ns in enumerate(int(round(tk * 1e9)) for tk in np.asarray(t, float)):
            raw = ts.serialize_cdr(_message(ts, msgtype, ns, vals, k), msgtype)
            events.append((ns + log_offset_ns, len(events), topic, msgtype, raw))
    events.sort(key=lambda e: (e[0], e[1]))
    path = Path(path)
    if storage == 'sqlite3':
        from rosbags.rosbag2 import StoragePlugin, Writer
        with Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
            conns = {topic: w.add_connection(topic, msgtype, typestore=ts)
                     for topic, (msgtype, _, _) in streams.items()}
            for ns, _, topic, _, raw in events:
                w.write(conns[topic], ns, raw)
        return path
    with BagWriter(path, compression='none', custom_data=custom_data) as w:
        for topic, (msgtype, _, _) in streams.items():
            w.add_topic(topic, msgtype, [qos_profile(history='keep_last', depth=10)])
        for ns, _, topic, _, raw in events:
            w.write(topic, ns, raw)
    return path


def _message(ts, msgtype: str, ns: int, vals, k: int):
    """Message ``k`` of a stream of :func:`write_bag`, stamped ``ns`` where the type has a
    header."""
    cls = ts.types[msgtype]
    if msgtype not in (FLUID_PRESSURE, JOINT_STATE):
        return cls(data=float(vals[k]))
    stamp = ts.types['builtin_interfaces/msg/Time'](sec=ns // 1_000_000_000,
                                                    nanosec=ns % 1_000_000_000)
    hdr = ts.types['std_msgs/msg/Header'](stamp=stamp, frame_id='')
    if msgtype == FLUID_PRESSURE:
        return cls(header=hdr, fluid_pressure=float(vals[k]), variance=0.0)
    empty = np.zeros(0)
    return cls(header=hdr, name=list(vals), position=np.array([float(v[k]) for v in
                                                                 vals.values()]),
               velocity=empty, effort=empty)
