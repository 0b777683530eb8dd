"""The model inside an exported FMU (FMI 2.0 co-simulation, through PythonFMU): a circuit of
the suite stepped by :class:`hydropump_sim.Simulator`.

This file is copied into the FMU as it is, beside the data it reads from the FMU's
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
        import numpy as np
        import yaml

        from hydropump_sim.circuit import load_circuit
        from hydropump_sim.measure import SIGNALS
        self.modelName = 'hydropump'
        res = Path(self.resources)
        manifest = yaml.safe_load((res / MANIFEST).read_text())
        plant = res / 'plant.yaml'
        self._plant = plant if plant.is_file() else None
        self._sets = dict(manifest.get('sets') or {})
        self._circuit_file = res / 'circuit.yaml'
        self.circuit = load_circuit(self._circuit_file, self._sets, self._plant)
        self.dt = float(manifest['step'])
        self.default_experiment = DefaultExperiment(0.0, float(manifest['stop_time']),
                                                    self.dt)
        c = self.circuit
        self.u = c.u0.copy()
        for k, name in enumerate(c.inputs):
            lo, hi = c.input_ranges[k]
            self.register_variable(_SIReal(
                name, c.input_units[k], lo, hi, causality=Fmi2Causality.input,
                variability=Fmi2Variability.continuous, start=float(self.u[k]),
                getter=lambda k=k: float(self.u[k]),
                setter=lambda v, k=k: self._set_input(k, v)))
        measured = c.measured()
        self.y = np.zeros(len(c.signals))
        self._outputs = []
        for name, info in SIGNALS.items():
            if name in measured:
                j = c.signal_index(measured[name])
                self._outputs.append(j)
                self.register_variable(_SIReal(
                    name, info.unit, causality=Fmi2Causality.output,
                    variability=Fmi2Variability.continuous, description=info.label,
                    getter=lambda j=j: float(self._outputs_now()[j])))
        self.values = {}
        for name, unit, lo, hi, value in parameters(c):
            if name in c.inputs:      # the start of an input of the same name: the input
                continue
            self.values[name] = value
            self.register_variable(_SIReal(
                name, unit, lo, hi, causality=Fmi2Causality.parameter,
                variability=Fmi2Variability.fixed, start=value,
                getter=lambda n=name: self.values[n],
                setter=lambda v, n=name: self.values.__setitem__(n, float(v))))
        self._given = dict(self.values)
        self.sim = None
        self._fresh = False

    def _set_input(self, k: int, value: float) -> None:
        lo, hi = self.circuit.input_ranges[k]
        self.u[k] = min(max(float(value), lo), hi)
        self._fresh = False

    def _outputs_now(self):
        """The signals at the present state and inputs: an input set after a step shows in
        the outputs that pass it through (the current), as FMI 2.0 asks."""
        if self.sim is not None and not self._fresh:
            self.sim.u[:] = self.u
            self.y[:] = self.sim.outputs()
            self._fresh = True
        return self.y

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
        from hydropump_sim.simulate import Simulator
        changed = {n: v for n, v in self.values.items() if v != self._given[n]}
        try:
            if changed:
                self.circuit = self.circuit.with_values(changed)
        except HydropumpError as exc:
            self.log(str(exc), Fmi2Status.error)
            raise
        self.sim = Simulator(self.circuit, dt=self.dt,
                             inputs=dict(zip(self.circuit.inputs, self.u)))
        self._fresh = False

    def do_step(self, current_time: float, step_size: float) -> bool:
        n = round(step_size / self.dt)
        if n < 1 or abs(n * self.dt - step_size) > 1e-9 * self.dt:
            self.log(f'step {step_size:g} s: the FMU steps in whole {self.dt:g} s '
                     'increments (the step of its default experiment)', Fmi2Status.error)
            return False
        self.sim.u[:] = self.u
        for _ in range(n):
            self.sim.step()
        self._fresh = False
        return True


def parameters(circuit) -> list[tuple[str, str, float | None, float | None, float]]:
    """``(name, unit, min, max, value)`` of each real parameter of the circuit's top-level
    primitive components (``<component>.<parameter>``, the names ``--set`` takes)."""
    import math

    from hydropump_sim.schema import to_flat
    out = []
    for part in circuit.parts:
        comp = part.comp
        if '.' in comp.name:      # a part of a composite: set through its composite
            continue
        specs = type(comp).param_specs()
        # The pump's parameters are its plant params file's (the paper's groups).
        own = getattr(comp.params, 'plant', comp.params)
        for key, value in to_flat(own).items():
            s = specs.get(key)
            if s is None or s.type is not float or isinstance(value, bool) \
                    or not isinstance(value, (int, float)) or not math.isfinite(value):
                continue
            lo, hi = s.range
            out.append((f'{comp.name}.{key}', s.unit, lo, hi, float(value)))
    return out
