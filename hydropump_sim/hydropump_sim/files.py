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


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display), imported on first use: half a
    second that commands which draw nothing do without."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


# The PNG text key under which a figure keeps where its axes are (:func:`axes_boxes`).
AXES_KEY = 'hydropump:axes'


def save_figure(fig, path: str | Path, what: str = 'figure', axes: bool = False,
                **kwargs) -> Path:
    """A matplotlib figure into ``path`` (format from its suffix), whole or not at all. With
    ``axes`` (the figures an HTML report embeds) a PNG keeps :func:`axes_boxes` in its text,
    so that a reader can check that every axes shows something; it costs a layout pass
    (about a fifth of the save), which the other figures do without."""
    if axes and Path(path).suffix.lower() == '.png' and 'bbox_inches' not in kwargs:
        import json
        kwargs['metadata'] = {**kwargs.get('metadata', {}),
                              AXES_KEY: json.dumps(axes_boxes(fig))}
    with replacing(path, what) as tmp:
        fig.savefig(tmp, **kwargs)
    return Path(path)


def axes_boxes(fig) -> list[dict]:
    """Where each visible axes of ``fig`` is, as fractions of the image from its top left
    ``[x0, y0, x1, y1]`` (``box``), with the boxes of its legend and texts (``skip``): what
    is left of the box is where its data are drawn. Colour bars are left out."""
    fig.draw_without_rendering()  # the layout and the legends' sizes, no pixels
    w, h = fig.bbox.width, fig.bbox.height

    def frac(bb):
        return [round(bb.x0 / w, 4), round(1.0 - bb.y1 / h, 4), round(bb.x1 / w, 4),
                round(1.0 - bb.y0 / h, 4)]
    out = []
    for ax in fig.axes:
        if not (ax.get_visible() and ax.axison) or ax.get_label() == '<colorbar>':
            continue
        extra = [a for a in (ax.get_legend(), *ax.texts) if a is not None and a.get_visible()]
        out.append({'box': frac(ax.bbox), 'skip': [frac(a.get_window_extent()) for a in extra]})
    return out


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
