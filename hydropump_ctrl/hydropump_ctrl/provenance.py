"""Where a report came from: one home for the provenance every report and JSON of the suite
carries (calibration, validation, fit, sweep, the demo).

:func:`collect` gives the date (UTC), the command line, the suite's commit (with ``-dirty``
when its tracked files differ from it; ``None`` outside a git checkout), the versions of
Python and of the libraries the results depend on, and each input file with its size and
SHA-256 (a bag folder with its size only: hashing gigabytes would cost more than the run).
:func:`markdown` and :func:`html` render it; every text is escaped where it is rendered.
The commit and the versions are read once a process (a fleet writes a report per pump).
Nothing here imports ROS.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, UTC
import functools
import hashlib
import html as html_
from importlib import metadata
import os
from pathlib import Path
import platform
import shlex
import subprocess
import sys

ROOT = Path(__file__).resolve().parents[2]
#: Libraries whose versions a result depends on.
LIBRARIES = ('hydropump_sim', 'hydropump_ctrl', 'numpy', 'scipy', 'numba', 'matplotlib',
             'rosbags', 'mcap', 'dask')
#: A file larger than this is listed with its size, not hashed.
HASHED_BYTES = 64 << 20
#: The command of the run when it is not this process's command line (``hydropump``'s
#: ``main`` called with its words from Python); empty otherwise.
COMMAND: list[str] = []


@functools.cache
def _commit() -> str | None:
    """The suite's commit, ``-dirty`` when tracked files differ; None outside a checkout."""
    if not (ROOT / '.git').exists():
        return None
    env = {**os.environ, 'GIT_OPTIONAL_LOCKS': '0'}
    try:
        head = subprocess.run(['git', '-C', str(ROOT), 'rev-parse', 'HEAD'], env=env,
                              capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(['git', '-C', str(ROOT), 'status', '--porcelain',
                                '--untracked-files=no'], env=env, capture_output=True,
                               text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ('-dirty' if dirty.stdout.strip() else '')


@functools.cache
def _versions() -> dict[str, str]:
    out = {'python': platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return out


def _file(path: Path) -> dict:
    entry = {'path': str(path.resolve())}
    try:
        if path.is_dir():
            entry['bytes'] = sum(f.stat().st_size for f in path.rglob('*') if f.is_file())
            entry['kind'] = 'folder'
            return entry
        size = path.stat().st_size
    except OSError as exc:
        entry['error'] = exc.strerror or str(exc)
        return entry
    entry['bytes'] = size
    if size > HASHED_BYTES:
        return entry
    digest = hashlib.sha256()
    try:
        with path.open('rb') as f:
            for block in iter(lambda: f.read(1 << 20), b''):
                digest.update(block)
    except OSError as exc:
        entry['error'] = exc.strerror or str(exc)
        return entry
    entry['sha256'] = digest.hexdigest()
    return entry


def collect(inputs: Sequence = (), argv: Sequence[str] | None = None) -> dict:
    """The provenance of a run reading ``inputs`` (files or folders; ``None`` entries are
    skipped), started with ``argv`` (default this process's command line)."""
    if argv is None:
        argv = COMMAND or [Path(sys.argv[0]).name, *sys.argv[1:]]
    seen, files = set(), []
    for p in inputs:
        if p is None or str(p) in seen:
            continue
        seen.add(str(p))
        files.append(_file(Path(p)))
    return {'date': datetime.now(UTC).isoformat(timespec='seconds'),
            'command': shlex.join(str(a) for a in argv), 'commit': _commit(),
            'versions': dict(_versions()), 'inputs': files}


def _input_text(f: dict) -> str:
    size = f'{f["bytes"]} bytes' if 'bytes' in f else f.get('error', '')
    hashed = f', sha256 {f["sha256"]}' if 'sha256' in f else ''
    return f'{f["path"]} ({size}{hashed})'


def lines(prov: dict) -> list[tuple[str, str]]:
    """``(what, text)`` rows of the provenance, unescaped."""
    rows = [('date (UTC)', prov['date']), ('command', prov['command']),
            ('commit', prov['commit'] or 'not a git checkout'),
            ('versions', ', '.join(f'{k} {v}' for k, v in prov['versions'].items()))]
    rows += [('input', _input_text(f)) for f in prov['inputs']]
    return rows


def markdown(prov: dict) -> list[str]:
    """A ``## Provenance`` section (code spans: nothing in it renders as markup)."""
    out = ['## Provenance', '']
    for what, text in lines(prov):
        plain = text.replace('`', "'")
        out.append(f'- {what}: `{plain}`')
    return out + ['']


def html(prov: dict) -> str:
    """The provenance as an HTML list, every text escaped."""
    items = ''.join(f'<li>{html_.escape(what)}: <code>{html_.escape(text)}</code></li>'
                    for what, text in lines(prov))
    return f'<ul class="provenance">{items}</ul>'
