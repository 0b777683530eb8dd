"""What the commands of ``hydropump`` share: the user error of a command, the options every
command has, checks of option values, and where the outputs go.

Every number on a command line is checked as the arguments are parsed (:class:`Number`, the
``type=`` of its option; :class:`Numbers` for options that take several): a value that is not
finite, or outside the option's range, ends at once with one ``error:`` line naming the option
and what it accepts, exit code 2, before any work. ``0`` is refused unless the range includes
it, where it means zero (or what the option's help says), never a default. A command checks
the rest of its options (files, combinations) before it starts work (:class:`UsageError`).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable
from datetime import datetime
import math
from pathlib import Path
import re

from hydropump_sim.errors import HydropumpError
from hydropump_sim.params import default_params_path


class UsageError(HydropumpError):
    """A user mistake found by a command (an option value, an output path): one line."""


class Number:
    """An argparse ``type=``: a finite number (a whole one with ``integer``) from ``lo`` to
    ``hi`` [``unit``], either end open (``lo_open``, ``hi_open``) or absent (``None``).

    ``float()`` takes ``nan``, ``inf`` and ``1e300`` from the command line; they are refused
    here, with the accepted range in the message (:attr:`accepts`).
    """

    def __init__(self, lo: float | None = None, hi: float | None = None, unit: str = '', *,
                 integer: bool = False, lo_open: bool = False, hi_open: bool = False):
        self.lo, self.hi, self.unit, self.integer = lo, hi, unit, integer
        self.lo_open, self.hi_open = lo_open, hi_open
        self.__name__ = 'integer' if integer else 'number'  # argparse's name of the type

    @property
    def accepts(self) -> str:
        """What the option accepts, as the error line says it."""
        what = 'a whole number' if self.integer else 'a finite number'
        unit = f' ({self.unit})' if self.unit else ''
        lo, hi = self.lo, self.hi
        if lo is not None and hi is not None and not (self.lo_open or self.hi_open):
            return f'{what} from {lo:g} to {hi:g}{unit}'
        parts = ([f'{">" if self.lo_open else ">="} {lo:g}'] if lo is not None else []) + \
            ([f'{"<" if self.hi_open else "<="} {hi:g}'] if hi is not None else [])
        return ' '.join([what, ' and '.join(parts)]).strip() + unit

    def contains(self, value: float) -> bool:
        # A whole number is finite however long (and too long for math.isfinite).
        return ((self.integer or math.isfinite(value))
                and (self.lo is None or (value > self.lo if self.lo_open else value >= self.lo))
                and (self.hi is None or (value < self.hi if self.hi_open else value <= self.hi)))

    def __call__(self, text: str) -> float:
        try:
            value = int(text, 10) if self.integer else float(text)
        except (TypeError, ValueError):
            value = None
        if value is None or not self.contains(value):
            raise argparse.ArgumentTypeError(f'{text}: expected {self.accepts}')
        return value

    def __repr__(self) -> str:
        return f'Number({self.accepts})'


def positive_float(unit: str = '', hi: float | None = None) -> Number:
    """A finite number above zero (and at most ``hi``) [``unit``]."""
    return Number(0.0, hi, unit, lo_open=True)


def float_in(lo: float, hi: float, unit: str = '') -> Number:
    """A finite number from ``lo`` to ``hi``, both included [``unit``]."""
    return Number(lo, hi, unit)


def int_in(lo: int, hi: int | None = None) -> Number:
    """A whole number from ``lo`` (to ``hi``)."""
    return Number(lo, hi, integer=True)


class Numbers(argparse.Action):
    """An argparse ``action=`` for an option of several numbers (``nargs`` of them): each
    checked by its own :class:`Number` (:attr:`checks`, one per position), and, with
    :attr:`increasing`, each above the one before (bounds ``LO HI``). Make one with
    :func:`numbers`."""

    checks: tuple[Number, ...] = ()
    increasing = False

    def __call__(self, parser, namespace, values, option_string=None):
        out = []
        for text, check, name in zip(values, self.checks, self._names()):
            try:
                out.append(check(text))
            except argparse.ArgumentTypeError:
                raise argparse.ArgumentError(self, f'{" ".join(values)}: {name} = {text}, '
                                             f'expected {check.accepts}') from None
        if self.increasing and any(b <= a for a, b in zip(out, out[1:])):
            raise argparse.ArgumentError(self, f'{" ".join(values)}: expected '
                                         f'{" < ".join(self._names())}')
        setattr(namespace, self.dest, out)

    def _names(self) -> list[str]:
        meta = self.metavar if isinstance(self.metavar, tuple) else ()
        return [meta[i] if i < len(meta) else f'value {i + 1}' for i in range(len(self.checks))]


def numbers(*checks: Number, increasing: bool = False) -> type[Numbers]:
    """A :class:`Numbers` action with one check per value (``nargs=len(checks)``)."""
    return type('Numbers', (Numbers,), {'checks': checks, 'increasing': increasing})


#: Checked numbers and groups of them by name, for ``type='<name>'`` and ``action='<name>'``
#: in ``add_argument``: every parser of ``hydropump`` registers them (:class:`Parser`).
NAMED_TYPES = {
    # fit: resampling well above the 1 kHz the bags are recorded at adds nothing but
    # memory (the fit's grid is the bag's duration over --dt); 0.1 s would not resolve the
    # 55 ms delay of eq. 19.
    'resampling period': float_in(1.0e-4, 0.1, 's'),
    'cut-off frequency': positive_float('Hz', 5.0e4),
}
NAMED_ACTIONS = {
    'FOPDT start': numbers(positive_float('%', 1000.0), positive_float('s', 10.0),
                           float_in(0.0, 2.0, 's')),
    'delay bounds': numbers(float_in(0.0, 2.0, 's'), float_in(0.0, 2.0, 's'),
                            increasing=True),
    'time-constant bounds': numbers(positive_float('s', 10.0), positive_float('s', 10.0),
                                    increasing=True),
}


# argparse's message of a refused number: 'argument --dt: nan: expected ...'.
_BAD_NUMBER = re.compile(r'argument (-\S+): (.+: .*expected .+)', re.DOTALL)


class Parser(argparse.ArgumentParser):
    """The parser of ``hydropump`` and of each of its commands (and of ``hydropump-demo`` and
    ``hydropump-graph``).

    A refused number is a :class:`UsageError` (``--dt nan: expected ...``): the caller prints
    it as the one ``error:`` line of every user mistake, exit code 2. Other mistakes
    (an unknown option, a missing argument) keep argparse's usage and message, exit code 2.
    ``type=`` and ``action=`` also take the names of :data:`NAMED_TYPES` and
    :data:`NAMED_ACTIONS`.
    """

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        for name, check in NAMED_TYPES.items():
            self.register('type', name, check)
        for name, action in NAMED_ACTIONS.items():
            self.register('action', name, action)

    def error(self, message: str):
        m = _BAD_NUMBER.fullmatch(message)
        if m:
            raise UsageError(f'{m[1]} {m[2]}')
        super().error(message)


def number_check(parser: argparse.ArgumentParser, action: argparse.Action):
    """The :class:`Number` (or :class:`Numbers` action) that checks ``action``'s values, a
    named one resolved; ``None`` for an option that takes no number."""
    if isinstance(action, Numbers):
        return action
    check = parser._registry_get('type', action.type, action.type)
    return check if isinstance(check, Number) or check in (int, float) else None


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


def add_where_options(parser, *, scheduler: str, workers: str, in_process: str) -> None:
    """Where the work of :mod:`hydropump_ctrl.batch` runs: ``--scheduler ADDRESS``, and
    either ``--workers N`` (a local cluster) or ``--in-process``; the help texts say what
    each default means for the command."""
    parser.add_argument('--scheduler', metavar='ADDRESS', help=scheduler)
    where = parser.add_mutually_exclusive_group()
    where.add_argument('--workers', type=int_in(1, 1024),
                       help=f'{workers}; at most twice the cores this process may use')
    where.add_argument('--in-process', action='store_true', help=in_process)


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
    """Output folder: the one given, or ``out/<prefix>-<timestamp>``; created if missing.
    A folder inside a bag (or a bag itself) is refused."""
    path = Path(base) if base else Path('out') / f'{prefix}-{datetime.now():%Y%m%d-%H%M%S}'
    _refuse_in_bag(path, 'output folder', path)
    _make_folder(path, 'output folder')
    return path


# The kinds of YAML file the suite reads or writes, by their top-level keys, so that an output
# replaces only a file of its own kind (a controller file never lands on a plant file).
BAG_METADATA = 'rosbag2_bagfile_information'
PLANT_GROUPS = frozenset({'fluid', 'pump', 'spool', 'actuator', 'plate', 'line'})
RESULTS_CSV_HEAD = 't [s],'


def file_kind(path: Path) -> str | None:
    """What an existing file holds, in words (``'plant params'``, ``'bag metadata'``,
    ``'results CSV'``, ...); ``None`` for an empty file (nothing to lose)."""
    suffix = path.suffix.lower()
    if suffix not in ('.csv', '.yaml', '.yml'):
        return suffix.lstrip('.') + ' file'
    try:
        text = path.read_text(encoding='utf-8', errors='replace')
    except OSError as exc:
        raise UsageError(f'cannot read the existing file {path}: {exc.strerror or exc}') \
            from None
    if not text.strip():
        return None
    if suffix == '.csv':
        return 'results CSV' if text.startswith(RESULTS_CSV_HEAD) else 'CSV of other data'
    from hydropump_sim.schema import ParamError, parse_yaml
    try:
        data = parse_yaml(text, str(path))
    except ParamError:
        return 'text that is not YAML'
    if not isinstance(data, dict):
        return 'YAML of another kind'
    if BAG_METADATA in data:
        return 'bag metadata'
    groups = set()
    for body in data.values():
        if isinstance(body, dict) and isinstance(body.get('ros__parameters'), dict):
            groups |= set(body['ros__parameters'])
    if 'controller' in groups:
        return 'controller params'
    if 'fmu_file' in groups:
        return 'FMU params'
    if groups & PLANT_GROUPS:
        return 'plant params'
    if 'components' in data:
        return 'circuit'
    if 'distributions' in data:
        return 'sweep'
    return 'ROS params of another kind' if groups else 'YAML of another kind'


def _refuse_in_bag(path: Path, what: str, shown: Path) -> None:
    for folder in [path.expanduser().resolve(), *path.expanduser().resolve().parents]:
        if (folder / 'metadata.yaml').is_file() and any(folder.glob('*.mcap')):
            raise UsageError(f'{what} {shown}: it lies in the bag {folder}; choose a path '
                             'outside it')


def output_file(path: str | Path, suffixes: Iterable[str], what: str, *,
                create: bool = True, kind: str | None = None) -> Path:
    """An output file of one of the ``suffixes`` (``'.csv'``), its folder created unless
    ``create`` is false (a dry run).

    Refused with one line: a folder, a path inside a bag, and an existing file that holds
    something else than ``kind`` (a :func:`file_kind`; with no ``kind``, any file of the
    right suffix is the output's kind). The file itself is written through a temporary file
    renamed into place (:mod:`hydropump_sim.files`).
    """
    path = Path(path)
    suffixes = tuple(suffixes)
    if path.suffix not in suffixes:
        names = ', '.join(suffixes[:-1]) + ' or ' * (len(suffixes) > 1) + suffixes[-1]
        raise UsageError(f'{what} {path}: use a {names} file name')
    if path.is_dir():
        raise UsageError(f'{what} {path}: is a folder, expected a file name')
    _refuse_in_bag(path.parent, what, path)
    if kind and path.is_file():
        found = file_kind(path)
        if found not in (None, kind):
            raise UsageError(f'{what} {path}: it exists and holds {found}, not {kind}; '
                             'choose another name (nothing was replaced)')
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
