"""The model inside an exported FMI 3.0 co-simulation FMU (through PythonFMU3): the same
:class:`hydropump_sim.block.CircuitBlock` as the FMI 2.0 script (hydropump_fmu.py), its
variables as FMI 3.0 declares them: ``Float64`` with their SI units and ranges, and the
independent variable ``time``.

This file is copied into the FMU as it is, beside the data it reads from the FMU's
resources (the circuit, its plant file, ``hydropump_fmu.yaml``): no file of the user becomes
code. The host needs Python with the suite installed (``hydropump_sim``).
"""

from __future__ import annotations

from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

from pythonfmu3 import (
    DefaultExperiment,
    Float64,
    Fmi3Causality,
    Fmi3Slave,
    Fmi3Status,
    Fmi3Variability,
)

#: The manifest beside the circuit in the FMU's resources.
MANIFEST = 'hydropump_fmu.yaml'

# PythonFMU3 0.3.4's library frees its interpreter state twice when its process ends: the
# static shared_ptr that holds it is destroyed first, then the library's destructor assigns
# to it again, releasing a freed block (valgrind: an invalid read in
# finalizePythonInterpreter), and glibc may abort the process at its exit. An instance that
# is never freed holds a second reference: the static's destruction then only drops one,
# and the destructor's assignment frees the state once. One such anchor per process: the
# library handle, its logger callback and the instance, kept for the life of the process.
_ANCHOR: list = []
_ANCHORING = [False]


def _anchor(resources: str) -> None:
    """The anchor instance made through this FMU's own library (see above); nothing where
    the library is not found or the instantiation fails."""
    import ctypes
    import sys
    if _ANCHOR or _ANCHORING[0] or not sys.platform.startswith('linux'):
        return
    libs = sorted((Path(resources).parent / 'binaries' / 'x86_64-linux').glob('*.so'))
    if len(libs) != 1:
        return
    lib = ctypes.CDLL(str(libs[0]))             # the library already loaded, not a new one
    instantiate = lib.fmi3InstantiateCoSimulation
    log = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p,
                           ctypes.c_char_p)
    instantiate.restype = ctypes.c_void_p
    instantiate.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p] + \
        [ctypes.c_bool] * 4 + [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_void_p, log,
                               ctypes.c_void_p]
    quiet = log(lambda *args: None)
    _ANCHORING[0] = True
    try:
        made = instantiate(b'anchor', b'', str(resources).encode(), False, False, False, False,
                           None, 0, None, quiet, None)
    finally:
        _ANCHORING[0] = False
    if made:
        _ANCHOR.extend([lib, quiet, made])


class Hydropump(Fmi3Slave):
    """A circuit of the suite as an FMI 3.0 co-simulation slave (see the module)."""

    author = 'hydropump'
    description = 'An electro-hydraulic circuit of the hydropump suite (SI units)'

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        if _ANCHORING[0]:       # the anchor: an instance that is never used
            return
        _anchor(self.resources)
        import yaml

        from hydropump_sim.block import CircuitBlock
        self.modelName = 'hydropump'
        res = Path(self.resources)
        manifest = yaml.safe_load((res / MANIFEST).read_text())
        plant = res / 'plant.yaml'
        self.block = b = CircuitBlock(res / 'circuit.yaml', manifest.get('sets'),
                                      plant if plant.is_file() else None, manifest['step'])
        self.default_experiment = DefaultExperiment(0.0, float(manifest['stop_time']), b.dt)
        self.time = 0.0
        self._ranges: dict[str, tuple] = {}
        self.register_variable(Float64('time', causality=Fmi3Causality.independent,
                                       variability=Fmi3Variability.continuous,
                                       getter=lambda: self.time))
        for k, (name, unit, lo, hi) in enumerate(b.inputs):
            self._add(name, unit, lo, hi, causality=Fmi3Causality.input,
                      variability=Fmi3Variability.continuous, start=float(b.u[k]),
                      getter=lambda k=k: float(b.u[k]),
                      setter=lambda v, k=k: b.set_input(k, v))
        for j, (name, unit, label) in enumerate(b.outputs):
            self._add(name, unit, None, None, causality=Fmi3Causality.output,
                      variability=Fmi3Variability.continuous, description=label,
                      getter=lambda j=j: b.output(j))
        for name, value in b.values.items():
            self._add(name, b.units[name], *b.ranges[name],
                      causality=Fmi3Causality.parameter, variability=Fmi3Variability.fixed,
                      start=value, getter=lambda n=name: b.values[n],
                      setter=lambda v, n=name: b.values.__setitem__(n, float(v)))

    def _add(self, name, unit, lo, hi, **kwargs) -> None:
        """A Float64 with its SI unit (none for '-') and its range."""
        self.register_variable(Float64(name, unit=unit if unit and unit != '-' else None,
                                       **kwargs), nested=False)
        self._ranges[name] = (lo, hi)

    def to_xml(self, model_options=None) -> Element:
        root = super().to_xml(model_options or {})
        for var in root.find('ModelVariables'):
            lo, hi = self._ranges.get(var.get('name'), (None, None))
            if lo is not None:
                var.set('min', f'{lo:.16g}')
            if hi is not None:
                var.set('max', f'{hi:.16g}')
        units = sorted({v.get('unit') for v in root.find('ModelVariables') if v.get('unit')})
        if units and root.find('UnitDefinitions') is None:
            defs = Element('UnitDefinitions')
            for u in units:
                SubElement(defs, 'Unit', name=u)
            # UnitDefinitions come right after CoSimulation (FMI 3.0, 2.4.1).
            at = [child.tag for child in root].index('CoSimulation') + 1
            root.insert(at, defs)
        return root

    def exit_initialization_mode(self):
        from hydropump_sim.errors import HydropumpError
        try:
            self.block.start()
        except HydropumpError as exc:
            self.log(str(exc), Fmi3Status.error)
            raise

    def terminate(self):
        # The compiled circuit and its stepper go with the instance, not at the host's exit.
        self.block = None
        self.vars.clear()

    def do_step(self, current_time: float, step_size: float) -> bool:
        why = self.block.advance(step_size)
        if why:
            self.log(why, Fmi3Status.error)
            return False
        self.time = current_time + step_size
        return True
