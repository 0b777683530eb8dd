"""What the commands of ``hydropump`` share: the user error of a command, the options every
command has, checks of option values, and where the outputs go.

A command checks its options before it starts work, so that a bad value ends at once with one
``error:`` line naming the value and what is accepted (:class:`UsageError`).
"""

from __future__ import annotations

from collections.abc import Iterable
from datetime import datetime
import math
from pathlib import Path

from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import default_params_path


class UsageError(HydropumpError):
    """A user mistake found by a command (an option value, an output path): one line."""


def add_params_option(parser, purpose: str = '') -> None:
    """``--params``: the plant parameters file (``purpose`` says what for, in the help)."""
    parser.add_argument('--params', help=f'plant params file{" " + purpose if purpose else ""} '
                        '(default: config/pump.yaml)')


def add_progress_option(parser, what: str = 'progress') -> None:
    """``--progress`` / ``--no-progress`` (default: on a terminal), into ``args.progress``."""
    prog = parser.add_mutually_exclusive_group()
    prog.add_argument('--progress', dest='progress', action='store_true', default=None,
                      help=f'show the {what} (default: on a terminal)')
    prog.add_argument('--no-progress', dest='progress', action='store_false')


def plant_file(args) -> Path:
    """The plant parameters file of ``--params``, or the default one."""
    return Path(args.params) if args.params else default_params_path()


def positive(value: float, option: str, unit: str, *, zero: bool = False) -> float:
    """``value`` of ``option`` if it is a finite number above zero (or zero, with ``zero``),
    else a :class:`UsageError` naming the value and the range.

    ``float`` options take ``nan`` and ``inf`` from the command line: they are refused here.
    """
    if not (math.isfinite(value) and (value >= 0.0 if zero else value > 0.0)):
        raise UsageError(f'{option} {value:g}: expected a finite number {">=" if zero else ">"} '
                         f'0 ({unit})')
    return value


def overrides(items: Iterable[str] | None) -> dict:
    """``--set NAME=VALUE`` pairs, values read as YAML (``0.02``, ``true``, ``pi``)."""
    from hydropump_sim.schema import assignments, ParamError
    try:
        return assignments(items or ())
    except ParamError as exc:
        raise UsageError(exc.lines[0]) from None


def run_dir(base: str | None, prefix: str) -> Path:
    """Output folder: the one given, or ``out/<prefix>-<timestamp>``; created if missing."""
    path = Path(base) if base else Path('out') / f'{prefix}-{datetime.now():%Y%m%d-%H%M%S}'
    _make_folder(path, 'output folder')
    return path


def output_file(path: str | Path, suffixes: Iterable[str], what: str, *,
                create: bool = True) -> Path:
    """An output file of one of the ``suffixes`` (``'.csv'``), its folder created unless
    ``create`` is false (a dry run)."""
    path = Path(path)
    suffixes = tuple(suffixes)
    if path.suffix not in suffixes:
        names = ', '.join(suffixes[:-1]) + ' or ' * (len(suffixes) > 1) + suffixes[-1]
        raise UsageError(f'{what} {path}: use a {names} file name')
    if path.is_dir():
        raise UsageError(f'{what} {path}: is a folder, expected a file name')
    if create:
        _make_folder(path.parent, f'folder of the {what}')
    return path


def _make_folder(path: Path, what: str) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise UsageError(f'cannot create the {what} {path}: a file of that name exists') \
            from None
    except OSError as exc:
        raise UsageError(f'cannot create the {what} {path}: {exc.strerror or exc}') from None


def protect_output(path: str | Path, inputs: Iterable[str | Path], what: str) -> None:
    """Refuse, with one line, an output that would overwrite what the user gave: one of the
    ``inputs``, a file inside an input folder (a bag's ``metadata.yaml``), or a folder an
    input lies in."""
    out = Path(path).expanduser().resolve()
    for item in inputs:
        src = Path(item).expanduser().resolve()
        if out == src:
            raise UsageError(f'{what} {path}: it is one of the inputs; choose another name')
        if src.is_dir() and src in out.parents:
            raise UsageError(f'{what} {path}: it lies inside the input {item}; choose a '
                             'path outside it')
