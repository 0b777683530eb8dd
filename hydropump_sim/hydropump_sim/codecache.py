"""The on-disk home of generated circuit modules and their compiled machine code, kept private.

A generated module is imported, and numba loads its cached machine code (an index it
unpickles) from the ``__pycache__`` beside it: whoever can write there can run code in the
next process that compiles a circuit. So the cache lives in a per-user folder
(``$HYDROPUMP_CACHE``, else ``$XDG_CACHE_HOME/hydropump`` or ``~/.cache/hydropump``, else
``<tmp>/hydropump-cache-<uid>``) created owner-only (0700), and is used only when

- every folder on the way (``circuits/``, its ``__pycache__``) belongs to this user and no
  one else may write into it; a folder that fails is skipped for the next candidate, with a
  warning;
- every entry it would load (the module's source, numba's index and code files) belongs to
  this user and is writable by no one else; an entry that fails is removed and written anew,
  with a warning.

The module's source is compared with what the compiler generated before it is imported, so a
stale or altered module is never run.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
from pathlib import Path
import stat
import sys
import tempfile
import time
from typing import Any

from .errors import HydropumpError


class CacheError(HydropumpError, RuntimeError):
    head = 'compiled-circuit cache'


def warn(text: str) -> None:
    print(f'warning: {text}', file=sys.stderr, flush=True)


def cache_roots() -> list[Path]:
    """The candidate folders, in order of preference."""
    env = os.environ.get('HYDROPUMP_CACHE')
    if env:
        roots = [Path(env)]
    else:
        xdg = os.environ.get('XDG_CACHE_HOME')
        roots = [(Path(xdg) if xdg else Path.home() / '.cache') / 'hydropump']
    return roots + [Path(tempfile.gettempdir()) / f'hydropump-cache-{os.getuid()}']


def cache_dir() -> Path:
    """The first candidate folder (where the cache is kept when it can be)."""
    return cache_roots()[0]


def _why_unsafe(st: os.stat_result) -> str | None:
    """Why an entry with this ``lstat`` cannot be trusted, or ``None``."""
    if st.st_uid != os.getuid():
        return f'owned by uid {st.st_uid}, not by this user ({os.getuid()})'
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f'writable by others (mode {stat.S_IMODE(st.st_mode):o})'
    return None


def private_folder(path: Path) -> str | None:
    """Create ``path`` owner-only if it is missing; ``None`` if it is a folder this user
    alone may write into, else why not."""
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = path.lstat()
    except OSError as exc:
        return f'cannot create it ({exc.strerror or exc})'
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        return 'not a folder (a link or a file)'
    return _why_unsafe(st)


def _check_entry(path: Path) -> bool:
    """``True`` if ``path`` is missing or trusted; an untrusted entry is removed (warned)."""
    try:
        st = path.lstat()
    except FileNotFoundError:
        return True
    why = 'not a regular file' if not stat.S_ISREG(st.st_mode) else _why_unsafe(st)
    if why is None:
        return True
    warn(f'ignored the cache entry {path}: {why}; it is written anew')
    try:
        path.unlink()
    except OSError:
        return False
    return True


def _prepare(root: Path, name: str, code: str) -> Path | None:
    """The module's path under ``root``, its source written and its cache entries checked;
    ``None`` (warned) if ``root`` cannot be trusted."""
    folder = root / 'circuits'
    for f in (root, folder, folder / '__pycache__'):
        why = private_folder(f)
        if why is not None:
            warn(f'not using {f} for compiled circuits: {why}')
            return None
    path = folder / f'{name}.py'
    cached = sorted((folder / '__pycache__').glob(f'{name}.*'))
    if not all(_check_entry(p) for p in [path, *cached]):
        warn(f'not using {folder}: an untrusted entry there cannot be removed')
        return None
    try:
        if not path.is_file() or path.read_text() != code:
            fd, tmp = tempfile.mkstemp(prefix=f'.{name}.', suffix='.tmp', dir=folder)
            with os.fdopen(fd, 'w') as f:
                f.write(code)
            os.replace(tmp, path)
    except OSError as exc:
        warn(f'not using {folder} for compiled circuits: {exc.strerror or exc}')
        return None
    return path


_MODULES: dict[str, Any] = {}


def compile_module(code: str):
    """Import (compiling on first use, then from numba's cache) a generated module."""
    digest = hashlib.sha256(code.encode()).hexdigest()[:20]
    if digest in _MODULES:
        return _MODULES[digest]
    name = f'hydropump_circuit_{digest}'
    for root in cache_roots():
        path = _prepare(root, name, code)
        if path is not None:
            break
    else:
        raise CacheError(['no private, writable folder for the compiled circuit: set '
                          'HYDROPUMP_CACHE to a folder of your own'])
    # numba's index of the module's cached code: none yet, it compiles now (once per
    # structure, a few seconds whatever the size: see circuit._generate), and says so.
    fresh = not any(path.parent.glob(f'__pycache__/{name}.*.nbi'))
    if fresh:
        print("compiling the circuit's equations (once per structure: a few seconds) ...",
              file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    if fresh:
        print(f'compiled in {time.perf_counter() - t0:.1f} s', file=sys.stderr, flush=True)
    _MODULES[digest] = module
    return module
