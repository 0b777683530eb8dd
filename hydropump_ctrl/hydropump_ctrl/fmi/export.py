"""``hydropump fmu``: a circuit file (the paper's pump by default) as an FMI 2.0 or 3.0
co-simulation FMU, built by PythonFMU (PythonFMU3) around :mod:`.hydropump_fmu`
(:mod:`.hydropump_fmu3`) and checked by FMPy's validation.

The FMU holds the circuit file, its plant file and a manifest (the ``--set`` values, the
step, the stop time) as data, and the model script as it ships: nothing of the user's files
becomes code. It is written whole or not at all.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
import shutil
import tempfile
from typing import Any

import yaml

from hydropump_sim.circuit import CircuitError, default_circuit_path, load_circuit
from hydropump_sim.errors import HydropumpError
from hydropump_sim.files import replacing
from hydropump_sim.schema import ParamError, read_yaml

#: The model script copied into an FMU of each FMI version built, and the PythonFMU that
#: builds it.
SCRIPTS = {2: (Path(__file__).with_name('hydropump_fmu.py'), 'pythonfmu'),
           3: (Path(__file__).with_name('hydropump_fmu3.py'), 'pythonfmu3')}
MANIFEST = 'hydropump_fmu.yaml'
VERSIONS = tuple(SCRIPTS)


class FmuError(HydropumpError, ValueError):
    """An FMU that cannot be built or read: one line per problem."""

    head = 'FMU'


@dataclass(frozen=True)
class Exported:
    """What was built: the file, its variables by causality, FMPy's findings."""

    path: Path
    inputs: tuple
    outputs: tuple
    parameters: tuple
    problems: tuple = ()


def plant_file(circuit_path: Path) -> Path | None:
    """The plant params file a circuit file names (``plant:``), or ``None``."""
    doc = read_yaml(circuit_path)
    plant = doc.get('plant') if isinstance(doc, Mapping) else None
    return None if plant is None else circuit_path.parent / str(plant)


def export_fmu(out: str | Path, circuit: str | Path | None = None, *,
               sets: Mapping[str, Any] | None = None, step: float = 1.0e-3,
               stop_time: float = 1.0, fmi: int = 2, validate: bool = True) -> Exported:
    """Build the FMU of ``circuit`` (default: the paper's pump, ``config/circuits/
    paper.yaml``) at ``out``.

    Raises
    ------
    FmuError
        An FMI version not built, a circuit that does not load, a step or stop time that
        is not a positive number, an output that cannot be written, or an FMU FMPy's
        validation refuses.
    """
    if fmi not in VERSIONS:
        raise FmuError([f'--fmi {fmi}: this suite builds FMI 2.0 and 3.0 co-simulation FMUs '
                        '(--fmi 2 or 3)'])
    for what, v in (('step', step), ('stop time', stop_time)):
        if not (isinstance(v, (int, float)) and v > 0 and v < float('inf')):
            raise FmuError([f'{what} = {v!r}: expected a positive number of seconds'])
    if stop_time < step:
        raise FmuError([f'stop time {stop_time:g} s is shorter than one step ({step:g} s)'])
    circuit = Path(circuit) if circuit is not None else default_circuit_path()
    sets = dict(sets or {})
    try:
        plant = plant_file(circuit)
        c = load_circuit(circuit, sets, plant)        # every problem of the file, first
    except (CircuitError, ParamError) as exc:
        raise FmuError(exc.lines, str(circuit)) from None
    if c.external():
        raise FmuError([f'{circuit}: {", ".join(c.external())}: FMUs of their own: an FMU '
                        'of this suite does not carry them (export the circuit without them)'])
    out = Path(out)
    if out.suffix != '.fmu':
        raise FmuError([f'{out}: an FMU file ends in .fmu'])
    if out.is_dir():
        raise FmuError([f'{out}: is a folder; give the FMU file to write'])
    import importlib
    script, builder = SCRIPTS[fmi]
    FmuBuilder = importlib.import_module(f'{builder}.builder').FmuBuilder

    from hydropump_sim.block import parameters
    problems: tuple = ()
    # Whole or not at all (hydropump_sim.files): a refused FMU or a full disk leaves ``out``
    # as it was; an OSError anywhere here is one line.
    with replacing(out, 'FMU') as built, \
            tempfile.TemporaryDirectory(prefix='hydropump_fmu_') as tmp:
        out.parent.mkdir(parents=True, exist_ok=True)
        data = Path(tmp) / 'data'
        data.mkdir()
        shutil.copyfile(circuit, data / 'circuit.yaml')
        if plant is not None:
            shutil.copyfile(plant, data / 'plant.yaml')
        (data / MANIFEST).write_text(yaml.safe_dump(
            {'sets': sets, 'step': float(step), 'stop_time': float(stop_time),
             'circuit': c.name}))
        # PythonFMU writes the file it is given; PythonFMU3 writes <model>.fmu into a folder.
        made = FmuBuilder.build_FMU(script, dest=built if fmi == 2 else Path(tmp) / 'fmu',
                                    project_files=sorted(data.iterdir()),
                                    needsExecutionTool='true')
        if Path(made) != Path(built):
            shutil.move(made, built)
        if validate:
            from fmpy.validation import validate_fmu
            problems = tuple(validate_fmu(str(built)))
            if problems:
                raise FmuError([f'{out}: FMPy validation: {p}' for p in problems])
    measured = c.measured()
    from hydropump_sim.measure import SIGNALS
    return Exported(out, tuple(c.inputs), tuple(n for n in SIGNALS if n in measured),
                    tuple(p[0] for p in parameters(c) if p[0] not in c.inputs), problems)
