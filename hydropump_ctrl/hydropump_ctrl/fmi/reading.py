"""Reading a user's FMU before anything runs it: one line per problem, naming the file and
what is missing, and a bound on what the file can make this process allocate.

An FMU is a zip archive with a ``modelDescription.xml`` and a binary per platform. The
archive's table is read first: a description larger than :data:`MAX_DESCRIPTION`, an
archive of more than :data:`MAX_ENTRIES` entries or :data:`MAX_UNPACKED` bytes unpacked is
refused before FMPy parses or extracts anything.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
import zipfile

from .export import FmuError

#: The largest model description read [bytes] (a description of 100 000 variables is
#: about 30 MB).
MAX_DESCRIPTION = 64 * 2 ** 20
#: The most entries and unpacked bytes an FMU may hold.
MAX_ENTRIES = 100_000
MAX_UNPACKED = 4 * 2 ** 30


#: The FMI versions the suite runs, and the types of their 64-bit reals.
VERSIONS = ('2.0', '3.0')
REAL_TYPES = ('Real', 'Float64')


@dataclass(frozen=True)
class Variable:
    """One scalar variable of an FMU: name, causality, unit, start, range (SI as the FMU
    declares them)."""

    name: str
    causality: str
    type: str
    unit: str = ''
    start: float | None = None
    min: float | None = None
    max: float | None = None
    array: bool = False             # an FMI 3.0 array variable

    @property
    def real(self) -> bool:
        """Whether the suite sets and reads it: a scalar 64-bit real (FMI 2.0 ``Real``,
        FMI 3.0 ``Float64`` without dimensions)."""
        return self.type in REAL_TYPES and not self.array


@dataclass(frozen=True)
class FmuInfo:
    """A checked FMU: its path, FMI version, model identifier, variables by name, and
    whether the suite integrates it (model exchange only) or it steps itself."""

    path: Path
    fmi_version: str
    model_identifier: str
    description: object       # fmpy's ModelDescription
    variables: dict
    model_exchange: bool = False

    def of(self, causality: str) -> list[str]:
        return [n for n, v in self.variables.items() if v.causality == causality]


def _number(value) -> float | None:
    try:
        return None if value is None else float(value)
    except (TypeError, ValueError):
        return None


def _fail(path: Path, lines: list[str]) -> FmuError:
    """The error of an FMU: each line names the file."""
    return FmuError([f'{path}: {ln}' for ln in lines])


def read_fmu(path: str | Path, *, inputs: Iterable[str] = (), outputs: Iterable[str] = ()
             ) -> FmuInfo:
    """The FMU at ``path`` checked for this machine and for the variables a mapping names.

    Its co-simulation interface is the one run where it has one; a model-exchange FMU is
    integrated by the suite (:mod:`.instance`).

    Parameters
    ----------
    inputs, outputs : iterable of str
        Variables the caller's mapping names, which the FMU must have with that causality.

    Raises
    ------
    FmuError
        One line per problem, naming the file: not a zip, no model description, a
        description or an archive beyond the bounds, an FMI version other than 2.0 or 3.0, no
        interface the suite runs, no binary for this platform, a named variable missing.
    """
    import fmpy
    path = Path(path)
    if not path.is_file():
        raise FmuError([f'{path}: no such file' if not path.exists()
                        else f'{path}: not a file'])
    if not zipfile.is_zipfile(path):
        raise _fail(path, ['not an FMU: not a zip archive'])
    try:
        with zipfile.ZipFile(path) as z:
            entries = z.infolist()
            if len(entries) > MAX_ENTRIES:
                raise _fail(path, [f'{len(entries)} entries: more than an FMU holds (at most '
                                   f'{MAX_ENTRIES} read)'])
            unpacked = sum(e.file_size for e in entries)
            if unpacked > MAX_UNPACKED:
                raise _fail(path, [f'{unpacked / 2 ** 30:.3g} GiB unpacked: more than an FMU '
                                   f'holds (at most {MAX_UNPACKED / 2 ** 30:g} GiB read)'])
            md_entry = next((e for e in entries if e.filename == 'modelDescription.xml'), None)
            if md_entry is None:
                raise _fail(path, ['no modelDescription.xml: not an FMU'])
            if md_entry.file_size > MAX_DESCRIPTION:
                raise _fail(path, [f'modelDescription.xml is '
                                   f'{md_entry.file_size / 2 ** 20:.3g} MiB: more than '
                                   f'{MAX_DESCRIPTION / 2 ** 20:g} MiB read'])
    except zipfile.BadZipFile as exc:
        raise _fail(path, [f'not an FMU: {exc}']) from None
    try:
        md = fmpy.read_model_description(str(path), validate=False)
    except Exception as exc:        # FMPy's parser says what is wrong, in its own words
        raise _fail(path, [f'modelDescription.xml: {exc}']) from None
    problems = []
    if md.fmiVersion not in VERSIONS:
        problems.append(f'FMI {md.fmiVersion}: the suite runs FMI 2.0 and 3.0 FMUs')
    interface = md.coSimulation or md.modelExchange
    if interface is None:
        problems.append('neither co-simulation nor model exchange: nothing the suite runs '
                        '(scheduled execution is not run)')
    platforms = fmpy.supported_platforms(str(path))
    if fmpy.platform not in platforms:
        problems.append(f'no binary for this platform ({fmpy.platform}): built for '
                        f'{", ".join(platforms) or "no platform"}')
    variables = {v.name: Variable(v.name, v.causality or 'local', v.type, v.unit or '',
                                  _number(v.start), _number(v.min), _number(v.max),
                                  bool(getattr(v, 'dimensions', None)))
                 for v in md.modelVariables}
    for causality, names in (('input', inputs), ('output', outputs)):
        have = [n for n, v in variables.items() if v.causality == causality]
        for name in names:
            if name not in have:
                problems.append(f'no {causality} named {name} (its {causality}s: '
                                f'{", ".join(have) or "none"})')
    if problems:
        raise _fail(path, problems)
    return FmuInfo(path, md.fmiVersion, interface.modelIdentifier, md, variables,
                   model_exchange=md.coSimulation is None)
