"""What a bag says of itself: the ``custom_data`` its recorder wrote (how it was closed,
what was lost, the events), read from ``metadata.yaml`` or, for a bag whose recorder was
killed, from the last ``rosbag2`` metadata record of its MCAP file.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path


def custom_data(path: str | Path) -> Mapping[str, str] | None:
    """The ``custom_data`` of a bag (a directory, or one of its storage files), from its
    ``metadata.yaml`` or else from the last ``rosbag2`` metadata record of an MCAP file;
    ``None`` when the bag has none (a bag of another recorder, a killed one, not a bag)."""
    from hydropump_sim.schema import read_yaml
    path = Path(path)
    meta = path / 'metadata.yaml' if path.is_dir() else path.with_name('metadata.yaml')
    try:
        if meta.is_file() and (path.is_dir() or path.name in meta.read_text()):
            info = read_yaml(meta)['rosbag2_bagfile_information']
            return info.get('custom_data') or None
        if path.suffix == '.mcap' and path.is_file():
            return _mcap_custom_data(path)
    except Exception:  # noqa: BLE001 - an unreadable record tells nothing; reading says why
        return None
    return None


def _mcap_custom_data(path: Path) -> Mapping[str, str] | None:
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    from hydropump_sim.schema import parse_yaml
    last = None
    with path.open('rb') as f:
        try:
            for rec in StreamReader(f, record_size_limit=1 << 30).records:
                if isinstance(rec, Metadata) and rec.name == 'rosbag2':
                    last = rec.metadata.get('serialized_metadata')
        except Exception:  # noqa: BLE001 - a truncated file: what was read before counts
            pass
    if last is None:
        return None
    return (parse_yaml(last, str(path)) or {}).get('custom_data') or None
