"""Files written whole or not at all.

Every file the suite writes goes through :func:`replacing`: the content goes to a temporary
file beside the target (same folder, so the same file system), which is renamed over the
target only once it is complete. A full disk, a crash or a Ctrl-C therefore leaves the old
file as it was (or no file), never a half-written one, and never an empty one in its place.
A failure to write is a :class:`WriteError`: one line naming the file and the reason.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
import os
from pathlib import Path

from .errors import HydropumpError


class WriteError(HydropumpError):
    """A file could not be written (full disk, read-only folder, ...); the target is as it
    was."""


def part_path(path: str | Path) -> Path:
    """The temporary file of ``path``: hidden, beside it, with the same suffix (so that a
    writer choosing its format by the name, as matplotlib does, writes the right one)."""
    path = Path(path)
    return path.with_name(f'.{path.stem}.part-{os.getpid()}{path.suffix}')


@contextmanager
def replacing(path: str | Path, what: str = 'file') -> Iterator[Path]:
    """Yield a temporary path to write; on leaving, rename it over ``path``.

    On any error (an ``OSError`` becomes a :class:`WriteError`) the temporary file is removed
    and ``path`` is left untouched.
    """
    path = Path(path)
    tmp = part_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        raise WriteError(f'cannot write the {what} {path}: {exc.strerror or exc}') from None
    finally:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:
            pass


def write_text(path: str | Path, text: str, what: str = 'file') -> Path:
    """``text`` (UTF-8) into ``path``, whole or not at all."""
    with replacing(path, what) as tmp:
        tmp.write_text(text, encoding='utf-8')
    return Path(path)


def save_figure(fig, path: str | Path, what: str = 'figure', **kwargs) -> Path:
    """A matplotlib figure into ``path`` (format from its suffix), whole or not at all."""
    with replacing(path, what) as tmp:
        fig.savefig(tmp, **kwargs)
    return Path(path)


def refuse_foreign(path: str | Path, mark: str, what: str) -> None:
    """Refuse to replace a file this suite did not write: one that exists and lacks
    ``mark`` (what every such file of the suite holds in its first 4 KiB) is the user's,
    and a report written into its folder must not take its place."""
    path = Path(path)
    try:
        with open(path, 'rb') as f:
            head = f.read(4096)
    except FileNotFoundError:
        return
    except OSError as exc:
        raise WriteError(f'cannot write the {what} {path}: {exc.strerror or exc}') from None
    if mark.encode() not in head:
        raise WriteError(f'{path} exists and is not a {what} this suite wrote: not replaced '
                         '(write into another folder, or move it away)')
