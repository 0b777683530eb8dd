"""A circuit behind the paper plant's interface: what the simulator node and its
:class:`~hydropump_sim.runner.Runner` step, whatever circuit they run.

:class:`CircuitPlant` answers as :class:`~hydropump_sim.Simulator` does (``reset``,
``set_inputs``, ``step``, ``outputs`` in the plant's ``OUTPUTS`` layout, ``u`` as
``[i_s, P_u, xi_u, f_p]``) from the circuit's pump and loads, so the node publishes the
suite's topics for any circuit:

- the pump's signals are its pump component's; ``Q_load`` is the load orifice's flow (eq. 9)
  or the loads' total; ``P_u`` is the load orifice's held pressure or, in a load-sensing
  circuit, the load-sensing pressure (what the margin is taken against); ``Q_relief`` is
  every relief valve's;
- :attr:`CircuitPlant.topics` lists what a circuit adds (``ls_pressure``,
  ``loads/<name>/pressure``, ``.../flow``, ``.../position`` or ``.../speed``) and
  :attr:`CircuitPlant.commands` the inputs it takes (``loads/<name>/command``);
- :meth:`CircuitPlant.joints` gives the valve spools and the actuators for ``joint_states``.

``config/circuits/paper.yaml`` is the paper's plant: through this the node's topics carry
what they always carried.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _core as c
from .circuit import Circuit, CircuitError
from .circuit_sim import CircuitSimulator, CircuitTrimError, DEFAULT_CONFIG, equilibrium
from .model import OUTPUTS
from .simulate import IntegratorConfig

# The plant's outputs that a pump component gives by the same name.
_PUMP = {'I_s': 'current', 'x_c': 'x_c', 'v_c': 'v_c', 'x_a': 'x_a', 'v_a': 'v_a',
         'P_a': 'P_a', 'P_l': 'P_l', 'Q_p': 'Q_p', 'Q_a': 'Q_a', 'q_l': 'q_l'}


@dataclass(frozen=True)
class Topic:
    """A topic a circuit adds: the circuit signal it carries, and its kind (``pressure``:
    FluidPressure, absolute; anything else: Float64), with the measured signal whose sensor
    model it takes (``like``, or none)."""

    topic: str
    signal: str
    kind: str
    like: str | None


def circuit_topics(circuit: Circuit) -> tuple[list[Topic], list[tuple[str, str]]]:
    """The topics a circuit adds and the command topics it takes ``(topic, input)``."""
    topics: list[Topic] = []
    m = circuit.measured()
    if 'ls_pressure' in m:
        topics.append(Topic('ls_pressure', m['ls_pressure'], 'pressure', 'line_pressure'))
    commands = []
    measured = set(m.values())
    for name, sig in circuit.loads().items():
        if set(sig.values()) <= measured:
            continue  # the paper's load: load_flow and load_pressure carry it
        for key, kind, like in (('pressure', 'pressure', 'line_pressure'),
                                ('flow', 'flow', 'line_flow'), ('position', 'position', None),
                                ('velocity', 'velocity', None), ('speed', 'speed', None)):
            if key in sig:
                topics.append(Topic(f'loads/{name}/{key}', sig[key], kind, like))
        if 'command' in sig:
            commands.append((f'loads/{name}/command', sig['command']))
    return topics, commands


class CircuitPlant:
    """The :class:`~hydropump_sim.Simulator` interface over a circuit (see the module).

    Parameters
    ----------
    circuit : Circuit
        With a pump component (``pump`` or ``ls_pump``).
    dt : float
        Increment [s].
    """

    def __init__(self, circuit: Circuit, dt: float = 1.0e-3,
                 config: IntegratorConfig = DEFAULT_CONFIG):
        pump = circuit.pump()
        if pump is None:
            raise CircuitError([f'{circuit.name}: the simulator node runs a circuit with a '
                                'pump (type pump or ls_pump)'])
        self.circuit = circuit
        self.params = pump.comp.params.plant
        self._pump = pump.comp.name
        idx = circuit.input_index
        self._i_cur = idx(f'{self._pump}.current') if circuit.electric_pump() else None
        self._i_fp = idx(f'{self._pump}.shaft_speed')
        load = next((pt for pt in circuit.role('load') if pt.comp.PLANT_INPUTS), None)
        self._i_pu = idx(f'{load.comp.name}.load_pressure') if load else None
        self._i_xi = idx(f'{load.comp.name}.aperture') if load else None
        sig = circuit.signal_index
        pump_out = [(OUTPUTS.index(o), sig(f'{self._pump}.{s}')) for o, s in _PUMP.items()
                    if f'{self._pump}.{s}' in circuit.signals]
        self._o_pump = np.array([o for o, _ in pump_out], dtype=np.int64)
        self._y_pump = np.array([k for _, k in pump_out], dtype=np.int64)
        m = circuit.measured()
        self._y_ls = sig(m['ls_pressure']) if 'ls_pressure' in m else None
        self._y_load = np.array([sig(m['load_flow'])] if 'load_flow' in m else
                                [sig(v['flow']) for v in circuit.loads().values()
                                 if 'flow' in v], dtype=np.int64)
        self._y_relief = np.array([sig(f'{pt.comp.name}.flow')
                                   for pt in circuit.role('pressure_limit')], dtype=np.int64)
        self.topics, self.commands = circuit_topics(circuit)
        self._y_topics = [sig(t.signal) for t in self.topics]
        self._joints = [(j, sig(p) if p else None, sig(v) if v else None)
                        for j, p, v in circuit.joints()]
        self._sim = CircuitSimulator(circuit, dt, config)
        self._y = self._sim.outputs()

    # ---- what the Runner reads and sets ----------------------------------------------------

    @property
    def dt(self) -> float:
        return self._sim.dt

    @property
    def stats(self) -> np.ndarray:
        return self._sim.stats

    @property
    def steps(self) -> int:
        return self._sim.steps

    @steps.setter
    def steps(self, value: int) -> None:
        self._sim.steps = value

    @property
    def t(self) -> float:
        return self._sim.t

    @t.setter
    def t(self, value: float) -> None:
        self._sim.t = value

    @property
    def x(self) -> np.ndarray:
        return self._sim.x

    @property
    def u(self) -> np.ndarray:
        """``[i_s, P_u, xi_u, f_p]`` as the plant alone holds them (see the module)."""
        u = self._sim.u
        cur = u[self._i_cur] if self._i_cur is not None else self.params.I_nominal
        if self._i_pu is not None:
            p_u, xi = u[self._i_pu], u[self._i_xi]
        else:
            p_u = self._y[self._y_ls] if self._y_ls is not None else 0.0
            xi = np.nan
        return np.array([cur - self.params.I_nominal, p_u, xi, u[self._i_fp]])

    def set_inputs(self, current: float | None = None, load_pressure: float | None = None,
                   aperture: float | None = None, shaft_speed: float | None = None,
                   **named: float) -> None:
        """Hold new inputs from the next increment: the plant's by their names (those the
        circuit lacks are ignored: a load-sensing circuit holds no load pressure), any
        circuit input by its own (``boom.command``)."""
        sim = self._sim
        if current is not None and self._i_cur is not None:
            lo, hi = self.params.I_limits
            sim.u[self._i_cur] = min(max(current, lo), hi)
        if load_pressure is not None and self._i_pu is not None:
            sim.u[self._i_pu] = load_pressure
        if aperture is not None and self._i_xi is not None:
            sim.u[self._i_xi] = aperture
        if shaft_speed is not None:
            sim.u[self._i_fp] = shaft_speed
        for name, value in named.items():
            sim.set_input(name, value)

    def take_inputs(self, other: CircuitPlant) -> None:
        """Hold what ``other`` (the circuit this one replaces) holds, input by input where
        the names agree."""
        mine, theirs = self.circuit.inputs, other.circuit.inputs
        for k, name in enumerate(mine):
            if name in theirs:
                self._sim.u[k] = other._sim.u[theirs.index(name)]

    def reset(self, current: float | None = None, keep_time: bool = False,
              keep_inputs: bool = False) -> None:
        """The steady state at ``current`` and the circuit's inputs, or with ``keep_inputs``
        every input held now; time restarts at 0 unless ``keep_time``."""
        sim = self._sim
        u = sim.u.copy() if keep_inputs else self.circuit.u0.copy()
        if current is not None and self._i_cur is not None:
            u[self._i_cur] = current
        self.reset_note = None
        try:  # from where the plant is: a reset near its operating point is quick
            eq = equilibrium(self.circuit, u, x0=sim.x)
        except CircuitTrimError:
            # No rest at these inputs (a pump whose flow compensated loads take exactly
            # leaves the pressure free) starts from the nearest state found, and says so.
            eq = equilibrium(self.circuit, u, strict=False)
            if eq.residual > 1.0e-5:
                self.reset_note = (f'no steady state at the held inputs (scaled residual '
                                   f'{eq.residual:.2e})')
        sim.u[:] = eq.u
        sim.x = eq.x.copy()
        if not keep_time:
            sim.t = 0.0
            sim.steps = 0
        sim._h = sim.dt
        self._y = sim.outputs()

    def step(self) -> None:
        self._sim.step()

    def outputs(self) -> np.ndarray:
        """The plant's outputs (``OUTPUTS`` layout); the circuit's own stay for
        :meth:`extra` and :meth:`joints` until the next call."""
        y = self._sim.outputs()
        self._y = y
        out = np.zeros(c.N_Y)
        out[self._o_pump] = y[self._y_pump]
        out[c.Y_QLOAD] = y[self._y_load].sum()
        out[c.Y_QRELIEF] = y[self._y_relief].sum()
        return out

    # ---- what a circuit adds -------------------------------------------------------------

    def extra(self) -> dict[str, float]:
        """The values of :attr:`topics` at the last :meth:`outputs` (true, SI, gauge)."""
        y = self._y
        return {t.topic: float(y[k]) for t, k in zip(self.topics, self._y_topics)}

    def joints(self) -> tuple[list[str], list[float], list[float]]:
        """Names, positions and velocities of the circuit's joints (valve spools as
        openings, cylinders, motors as speeds) at the last :meth:`outputs`."""
        y = self._y
        return ([j[0] for j in self._joints],
                [float(y[j[1]]) if j[1] is not None else 0.0 for j in self._joints],
                [float(y[j[2]]) if j[2] is not None else 0.0 for j in self._joints])


def recorded_topics(circuit_file: str, commands: bool = True) -> list[str]:
    """The recorder's topics for a circuit: the suite's, then what the circuit adds and
    (unless not ``commands``: a run that sets them as parameters) its load commands (the
    structure only: nothing is compiled)."""
    from .circuit import load_circuit
    from .measure import SIGNALS
    circuit = load_circuit(circuit_file, compile=False)
    topics, cmds = circuit_topics(circuit)
    suite = ['solenoid_current_cmd', *dict.fromkeys(i.topic for i in SIGNALS.values()),
             'controller/state']
    return suite + [t.topic for t in topics] + [c[0] for c in cmds if commands]
