"""The model inside an exported FMU (FMI 2.0 co-simulation, through PythonFMU): a circuit of
the suite stepped by :class:`hydropump_sim.Simulator`.

This file is copied into the FMU as it is (the circuit's logic is the plant library's
:class:`hydropump_sim.block.CircuitBlock`), beside the data it reads from the FMU's
resources: ``circuit.yaml``, the plant file ``plant.yaml`` (when the circuit names one) and
``hydropump_fmu.yaml`` (the set values, the step and the stop time). No file of the user
becomes code: names and values are read as data when the FMU is instantiated, and the
model description holds them as XML attributes.

Inputs are the circuit's inputs, outputs the suite's measured signals the circuit has, and
parameters the numeric parameters of its top-level components (applied when the
initialisation ends, the circuit then made again with them), all in SI units. The host
needs Python with the suite installed (``hydropump_sim`` and what it imports).
"""

from __future__ import annotations

from pathlib import Path
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.enums import Fmi2Status

#: The manifest beside the circuit in the FMU's resources.
MANIFEST = 'hydropump_fmu.yaml'


class _SIReal(Real):
    """A Real with its SI unit and range in the model description."""

    def __init__(self, name, unit='', lo=None, hi=None, **kwargs):
        super().__init__(name, **kwargs)
        self.si = (unit, lo, hi)

    def to_xml(self) -> Element:
        node = super().to_xml()
        real = node.find('Real')
        unit, lo, hi = self.si
        if unit and unit != '-':
            real.set('unit', unit)
        if lo is not None:
            real.set('min', f'{lo:.16g}')
        if hi is not None:
            real.set('max', f'{hi:.16g}')
        return node


class Hydropump(Fmi2Slave):
    """A circuit of the suite as a co-simulation slave (see the module)."""

    author = 'hydropump'
    description = 'An electro-hydraulic circuit of the hydropump suite (SI units)'

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        import yaml

        from hydropump_sim.block import CircuitBlock
        self.modelName = 'hydropump'
        res = Path(self.resources)
        manifest = yaml.safe_load((res / MANIFEST).read_text())
        plant = res / 'plant.yaml'
        self.block = b = CircuitBlock(res / 'circuit.yaml', manifest.get('sets'),
                                      plant if plant.is_file() else None, manifest['step'])
        self.default_experiment = DefaultExperiment(0.0, float(manifest['stop_time']), b.dt)
        for k, (name, unit, lo, hi) in enumerate(b.inputs):
            self.register_variable(_SIReal(
                name, unit, lo, hi, causality=Fmi2Causality.input,
                variability=Fmi2Variability.continuous, start=float(b.u[k]),
                getter=lambda k=k: float(b.u[k]),
                setter=lambda v, k=k: b.set_input(k, v)))
        for j, (name, unit, label) in enumerate(b.outputs):
            self.register_variable(_SIReal(
                name, unit, causality=Fmi2Causality.output,
                variability=Fmi2Variability.continuous, description=label,
                getter=lambda j=j: b.output(j)))
        for name, value in b.values.items():
            self.register_variable(_SIReal(
                name, b.units[name], *b.ranges[name], causality=Fmi2Causality.parameter,
                variability=Fmi2Variability.fixed, start=value,
                getter=lambda n=name: b.values[n],
                setter=lambda v, n=name: b.values.__setitem__(n, float(v))))

    def to_xml(self, model_options=None) -> Element:
        root = super().to_xml(model_options or {})
        units = sorted({v.si[0] for v in self.vars.values()
                        if isinstance(v, _SIReal) and v.si[0] and v.si[0] != '-'})
        if units:
            defs = Element('UnitDefinitions')
            for u in units:
                SubElement(defs, 'Unit', name=u)
            # UnitDefinitions come right after CoSimulation (FMI 2.0, 2.2.1).
            at = [child.tag for child in root].index('CoSimulation') + 1
            root.insert(at, defs)
        # Outputs computed at initialisation are its initial unknowns too (FMI 2.0, 2.2.8).
        structure = root.find('ModelStructure')
        outputs = structure.find('Outputs') if structure is not None else None
        if outputs is not None:
            initial = SubElement(structure, 'InitialUnknowns')
            for unknown in outputs:
                SubElement(initial, 'Unknown', index=unknown.get('index'))
        return root

    def exit_initialization_mode(self):
        from hydropump_sim.errors import HydropumpError
        try:
            self.block.start()
        except HydropumpError as exc:
            self.log(str(exc), Fmi2Status.error)
            raise

    def do_step(self, current_time: float, step_size: float) -> bool:
        why = self.block.advance(step_size)
        if why:
            self.log(why, Fmi2Status.error)
        return why is None
