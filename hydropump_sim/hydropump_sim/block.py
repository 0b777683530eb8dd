"""A circuit as a block stepped in fixed increments: its inputs by name, held; the suite's
measured signals it has, out; the real parameters of its top-level components by name,
applied when it starts (the circuit made again with them). What an exported FMU wraps
(hydropump_ctrl/fmi/hydropump_fmu.py): the FMU's model script registers these as its
variables and calls :meth:`CircuitBlock.start` and :meth:`CircuitBlock.advance`, so that a
script for another FMI version wraps the same block.

The block reads its files as data (a circuit file, a plant file, the set values): nothing of
them becomes code.
"""

from __future__ import annotations

from collections.abc import Mapping
import math
from pathlib import Path
from typing import Any

import numpy as np

from .circuit import load_circuit
from .errors import HydropumpError
from .measure import SIGNALS
from .schema import to_flat


def parameters(circuit) -> list[tuple[str, str, float | None, float | None, float]]:
    """``(name, unit, min, max, value)`` of each real parameter of the circuit's top-level
    primitive components (``<component>.<parameter>``, the names ``--set`` takes)."""
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


class CircuitBlock:
    """The circuit of ``circuit_file`` (with ``sets`` over it and ``plant`` as its plant
    file) stepped in increments of ``step`` [s] (see the module).

    ``inputs``: ``(name, unit, min, max)`` per input; ``outputs``: ``(name, unit, label)``
    per measured signal; ``values``: the parameters by name (set them before :meth:`start`).
    """

    def __init__(self, circuit_file: str | Path, sets: Mapping[str, Any] | None,
                 plant: str | Path | None, step: float):
        self.circuit = c = load_circuit(circuit_file, dict(sets or {}), plant)
        self.dt = float(step)
        self.u = c.u0.copy()
        self.inputs = [(name, c.input_units[k], *c.input_ranges[k])
                       for k, name in enumerate(c.inputs)]
        measured = c.measured()
        self.outputs = [(name, info.unit, info.label) for name, info in SIGNALS.items()
                        if name in measured]
        self._index = [c.signal_index(measured[name]) for name, _, _ in self.outputs]
        own = parameters(c)
        self.units = {name: unit for name, unit, *_ in own}
        self.ranges = {name: (lo, hi) for name, _, lo, hi, _ in own}
        # The start of an input of the same name is the input.
        self.values = {name: v for name, _, _, _, v in own if name not in c.inputs}
        self._given = dict(self.values)
        self.y = np.zeros(len(c.signals))
        self.sim = None
        self._fresh = False

    def set_input(self, k: int, value: float) -> None:
        """Hold input ``k`` from the next increment, limited to its range."""
        lo, hi = self.circuit.input_ranges[k]
        self.u[k] = min(max(float(value), lo), hi)
        self._fresh = False

    def output(self, j: int) -> float:
        """Output ``j`` at the present state and inputs: an input set after a step shows at
        once in the outputs that pass it through (the current), as FMI asks."""
        if self.sim is not None and not self._fresh:
            self.sim.u[:] = self.u
            self.y[:] = self.sim.outputs()
            self._fresh = True
        return float(self.y[self._index[j]])

    def start(self) -> None:
        """The steady state at the held inputs, with the parameters set since the block was
        made (:class:`HydropumpError` if they break the circuit)."""
        from .simulate import Simulator
        changed = {n: v for n, v in self.values.items() if v != self._given[n]}
        if changed:
            self.circuit = self.circuit.with_values(changed)
        self.sim = Simulator(self.circuit, dt=self.dt,
                             inputs=dict(zip(self.circuit.inputs, self.u)))
        self._fresh = False

    def advance(self, step_size: float) -> str | None:
        """Step ``step_size`` [s], a whole number of increments; why not, else ``None``."""
        n = round(step_size / self.dt)
        if n < 1 or abs(n * self.dt - step_size) > 1e-9 * self.dt:
            return (f'step {step_size:g} s: the FMU steps in whole {self.dt:g} s increments '
                    '(the step of its default experiment)')
        self.sim.u[:] = self.u
        try:
            for _ in range(n):
                self.sim.step()
        except HydropumpError as exc:
            return str(exc)
        finally:
            self._fresh = False
        return None
