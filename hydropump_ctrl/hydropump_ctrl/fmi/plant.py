"""A user's FMU as the simulator's plant: an FMI 2.0 or 3.0 co-simulation FMU stepped by FMPy with
the node's step, behind the same interface as :class:`hydropump_sim.Simulator`.

How the FMU meets the suite, by name:

- its inputs ``current`` (or ``pump.current``) [A] and, where it has them,
  ``load_pressure`` (``load.load_pressure``) [Pa gauge], ``aperture`` (``load.aperture``)
  and ``shaft_speed`` (``pump.shaft_speed``) are the operating point's: the current the
  controller commands, the rest the simulator's parameters and scenario; its other inputs
  hold their starts;
- its outputs named after the suite's measured signals (``line_pressure``, ``line_flow``,
  ``spool_position`` ...) are published on their topics, SI and gauge as the FMU gives them;
  every output is published besides on ``fmu/<name>`` (a ``.`` in a name is a ``/``);
- its parameters are the node's read-only ``fmu_parameters.<name>`` parameters.

A step that fails stops the simulator with the FMU's own message.
"""

from __future__ import annotations

import math
import re

import numpy as np

from hydropump_sim.measure import SIGNALS, Topic
from hydropump_sim.schema import unknown_key_line
from hydropump_sim.simulate import Simulator
from hydropump_sim.system import Model

from .export import FmuError
from .instance import FmuInstance
from .reading import FmuInfo, read_fmu

#: The operating point's inputs and the FMU input names each is looked for under.
PLANT_INPUTS = {'current': ('current', 'pump.current'),
                'load_pressure': ('load_pressure', 'load.load_pressure'),
                'aperture': ('aperture', 'load.aperture'),
                'shaft_speed': ('shaft_speed', 'pump.shaft_speed')}
#: The pump's joints and pressures the simulator's readout takes, and the measured signal
#: each is when the FMU does not output ``pump.<name>`` itself (velocities: 0).
PUMP_SIGNALS = {'x_c': 'spool_position', 'v_c': None, 'x_a': 'actuator_position',
                'v_a': None, 'P_a': 'actuator_pressure', 'P_l': 'line_pressure'}
#: The prefix of the FMU's parameters among the simulator node's parameters, and of a
#: circuit's FMU loads' (``fmu_loads.<component>.<name>``, read-only).
FMU_PARAMETERS = 'fmu_parameters.'
FMU_LOADS = 'fmu_loads.'
_TOKEN = re.compile(r'[A-Za-z][A-Za-z0-9_]*\Z')


def ros_name(name: str) -> bool:
    """Whether an FMU's variable name makes a ROS name: dotted parts, each a letter then
    letters, digits and ``_`` (a topic ``fmu/<name>``, a parameter
    ``fmu_parameters.<name>``)."""
    return all(_TOKEN.match(p) for p in name.split('.'))


def topic_of(name: str) -> str | None:
    """``fmu/<name>`` with ``.`` as ``/``, or ``None`` if the name makes no ROS topic."""
    return 'fmu/' + name.replace('.', '/') if ros_name(name) else None


class FmuModel(Model):
    """An FMU's names as a :class:`~hydropump_sim.system.Model` (no states of its own: the
    FMU keeps them)."""

    def __init__(self, info: FmuInfo, params):
        self.info = info
        # The FMU's own dither, if any, is in its current: the node adds none.
        self.params = params.replace({'input.dither_amp': 0.0})
        self.name = info.model_identifier
        self.fluid = params.fluid
        v = info.variables
        # Value references count per type in FMI 2.0: only the real ones meet the suite.
        self.inputs = [n for n in info.of('input') if v[n].real]
        self.input_units = [v[n].unit for n in self.inputs]
        self.input_ranges = [(-math.inf if v[n].min is None else v[n].min,
                              math.inf if v[n].max is None else v[n].max) for n in self.inputs]
        self.u0 = np.array([v[n].start or 0.0 for n in self.inputs], dtype=float)
        self.outputs = [n for n in info.of('output') if v[n].real]
        own = [f'pump.{k}' for k in PUMP_SIGNALS if f'pump.{k}' not in self.outputs]
        self.signals = self.outputs + own
        self.signal_units = [v[n].unit for n in self.outputs] + [''] * len(own)
        self.states, self.state_units = [], []
        self.state_scale = np.zeros(0)
        self.integrating = np.zeros(0, dtype=bool)
        self.p = np.zeros(0)
        self.dither = 0.0
        self._plant = {k: next(n for n in names if n in self.inputs)
                       for k, names in PLANT_INPUTS.items()
                       if any(n in self.inputs for n in names)}

    def measured(self) -> dict[str, str]:
        return {n: n for n in SIGNALS if n in self.outputs}

    def plant_inputs(self) -> dict[str, str]:
        return dict(self._plant)

    def plant_params(self):
        return self.params

    def pump_name(self) -> str:
        return 'pump'

    def own_topics(self) -> list:
        out = []
        for n, unit in zip(self.outputs, self.signal_units):
            topic = topic_of(n)
            if topic is not None:
                out.append(Topic(topic, n, 'pressure' if unit == 'Pa' else 'value', None))
        return out

    def parameters(self) -> dict[str, float]:
        """The FMU's real parameters and their starts."""
        return {n: v.start for n, v in self.info.variables.items()
                if v.causality == 'parameter' and v.real and v.start is not None}


def check_plant(info: FmuInfo) -> None:
    """:class:`FmuError` unless the FMU can be the plant: a current input, one measured
    signal out."""
    names = [n for n in info.of('input') if info.variables[n].real]
    outputs = [n for n in info.of('output') if info.variables[n].real]
    problems = []
    if not any(n in names for n in PLANT_INPUTS['current']):
        problems.append(f'{info.path}: no input current or pump.current (the solenoid current '
                        f'[A] the controller commands; its inputs: {", ".join(names) or "none"})')
    if not any(n in SIGNALS for n in outputs):
        problems.append(f'{info.path}: no output named after a measured signal of the suite '
                        f'({", ".join(SIGNALS)}); its outputs: {", ".join(outputs) or "none"}')
    if problems:
        raise FmuError(problems)


class FmuSimulator:
    """An FMU stepped in increments of ``dt`` [s], as :class:`hydropump_sim.Simulator`
    steps a model: ``t``, ``steps``, the inputs ``u``, :meth:`step`, :meth:`outputs`,
    :meth:`reset`."""

    #: It steps as the FMU does: no simplified fidelity, no fixed step of the suite's.
    fidelity = None
    step_check = None

    def __init__(self, path, params, dt: float = 1.0e-3):
        info = read_fmu(path)
        check_plant(info)
        self.model = FmuModel(info, params)
        self.dt = float(dt)
        self.u = self.model.u0.copy()
        self.t, self.steps = 0.0, 0
        self.stats = np.zeros(2, dtype=np.int64)
        self.reset_note = None
        self.parameter_values: dict[str, float] = {}
        self.y = np.zeros(len(self.model.signals))
        self.fmu = FmuInstance(info)
        self._in = self.fmu.refs(self.model.inputs)
        self._out = self.fmu.refs(self.model.outputs)
        try:
            self.reset()
        except BaseException:
            self.close()
            raise

    @property
    def params(self):
        return self.model.params

    @property
    def messages(self) -> list[str]:
        return self.fmu.messages

    def set_parameters(self, values) -> None:
        """Real parameters of the FMU by name, set from the next :meth:`reset` on (FMI
        sets parameters before the initialisation); :class:`FmuError` with a line per name
        that is not one."""
        known = self.model.parameters()
        bad = [unknown_key_line(n, known, f'real parameter of {self.model.info.path.name}')
               for n in values if n not in known]
        if bad:
            raise FmuError(bad)
        self.parameter_values.update({n: float(v) for n, v in values.items()})

    def reset(self, inputs=None, keep_time: bool = False, keep_inputs: bool = True) -> None:
        """Back to the FMU's initial state at the held inputs (the FMU's starts unless
        ``keep_inputs``), with ``inputs`` by name over them."""
        if not keep_inputs:
            self.u = self.model.u0.copy()
        for name, v in (inputs or {}).items():
            self.set_input(name, v)
        self.fmu.initialise(self.parameter_values, self._in, self.u, at=self.t)
        if not keep_time:
            self.t, self.steps = 0.0, 0

    # The inputs by name, clamped to their ranges, as the simulator holds a model's.
    take_inputs = Simulator.take_inputs
    set_input = Simulator.set_input

    def step(self) -> None:
        """One increment of the FMU: the held inputs set, ``fmi2DoStep`` over ``dt``
        (its own clock runs on from its reset, whatever jumps the node's makes)."""
        self.fmu.set(self._in, self.u, at=self.t)
        self.fmu.step(self.dt, at=self.t)
        self.stats[0] += 1
        self.steps += 1
        self.t = self.steps * self.dt

    def outputs(self) -> np.ndarray:
        """Every signal now: the FMU's outputs, then the pump's joints and pressures the
        readout takes (from the measured signals it has, else 0)."""
        m = self.model
        n = len(m.outputs)
        if self._out:
            self.fmu.set(self._in, self.u, at=self.t)
            self.y[:n] = self.fmu.get(self._out, at=self.t)
        for j, name in enumerate(m.signals[n:], n):
            src = PUMP_SIGNALS[name.split('.', 1)[1]]
            self.y[j] = self.y[m.outputs.index(src)] if src in m.outputs else 0.0
        return self.y

    def close(self) -> None:
        """The FMU ended and its unpacked files removed (again: nothing)."""
        self.fmu.close()
