"""The measurement map: model outputs -> the named signals a bench measures.

One map serves the simulator node and the offline closed-loop harness, so that both see the
plant through the same signals (SI units, gauge pressures; a node converts pressures to
absolute at its edge):

- :data:`SIGNALS` is the one table of the measured signals (model output, unit, label, kind,
  topic and message type); :data:`SIGNAL_OUTPUTS` names which output of
  :data:`hydropump_sim.model.OUTPUTS` each is (``load_pressure`` is the input ``P_u``);
- :class:`Readout` reads them from any model by name (the model says which of its signals
  each is), with the generalised forces of ``joint_states`` (solenoid force of eq. 1,
  actuator force ``P_a S_a`` of eq. 6), the physical limit at which it is (end stops,
  relief, pressure floor), and the topics and joints a circuit adds
  (:func:`model_topics`, :func:`recorded_topics`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FLOAT64 = 'std_msgs/msg/Float64'
FLUID_PRESSURE = 'sensor_msgs/msg/FluidPressure'
JOINT_STATE = 'sensor_msgs/msg/JointState'


@dataclass(frozen=True)
class SignalInfo:
    """A measured signal: the model output it is, its SI unit, its label in the paper's
    symbols, what kind of quantity it is, and how the simulator node publishes it (topic,
    message type, ``joint_states`` entry). ``held`` signals are piecewise constant between
    samples (the applied current); ``bench`` says whether a test bench measures it (the
    spool and plate positions are the simulator's exact states, which no bench has).
    ``display`` is how reports show it (scale from SI, unit); ``plausible`` the range a
    controller takes a sample from (SI, pressures absolute, as the topics carry them),
    ``None`` where it takes none; ``feedback`` whether a flow controller can close its loop
    on it (the pump's own flow, eq. 14, or the line's, eq. 15: not the load's)."""

    output: str | None       # None: the input P_u
    unit: str
    label: str
    kind: str                # current | flow | pressure | position
    topic: str
    msgtype: str = FLOAT64
    entry: str | None = None
    held: bool = False
    bench: bool = True
    display: tuple[float, str] = (1.0, '')
    plausible: tuple[float, float] | None = None
    feedback: bool = False


# Display units and plausible ranges by kind (a flow in L/min, within 100 L/s either way; a
# pressure in bar, absolute from 0 to 1000 bar; a current in A, 0 to 10 A).
_FLOW = {'display': (6.0e4, 'L/min'), 'plausible': (-0.1, 0.1)}
_PRESSURE = {'display': (1e-5, 'bar'), 'plausible': (0.0, 1.0e8)}
_POSITION = {'display': (1e3, 'mm')}


# The one table of the measured signals; every other list of them is derived from it.
SIGNALS = {
    'solenoid_current': SignalInfo('I_s', 'A', 'solenoid current I_s', 'current',
                                   'solenoid_current', held=True, display=(1.0, 'A'),
                                   plausible=(0.0, 10.0)),
    'pump_flow': SignalInfo('Q_p', 'm^3/s', 'pump flow Q_p', 'flow', 'pump_flow',
                            feedback=True, **_FLOW),
    'line_flow': SignalInfo('q_l', 'm^3/s', 'line flow q_l', 'flow', 'line_flow',
                            feedback=True, **_FLOW),
    'load_flow': SignalInfo('Q_load', 'm^3/s', 'load flow Q_load', 'flow', 'load_flow',
                            **_FLOW),
    'actuator_pressure': SignalInfo('P_a', 'Pa', 'actuator pressure P_a', 'pressure',
                                    'actuator_pressure', FLUID_PRESSURE, **_PRESSURE),
    'line_pressure': SignalInfo('P_l', 'Pa', 'line pressure P_l', 'pressure',
                                'line_pressure', FLUID_PRESSURE, **_PRESSURE),
    'load_pressure': SignalInfo(None, 'Pa', 'load pressure P_u', 'pressure', 'load_pressure',
                                FLUID_PRESSURE, **_PRESSURE),
    'spool_position': SignalInfo('x_c', 'm', 'spool position x_c', 'position', 'joint_states',
                                 JOINT_STATE, 'spool', bench=False, **_POSITION),
    'actuator_position': SignalInfo('x_a', 'm', 'actuator position x_a', 'position',
                                    'joint_states', JOINT_STATE, 'swash_plate_actuator',
                                    bench=False, **_POSITION),
}
# A load-sensing circuit's highest load pressure (Pa, absolute on its topic): not a signal
# of the pump's bench, but what a controller in margin mode takes as the load pressure.
LS_PRESSURE_SIGNAL = 'ls_pressure'
# Measured signal -> model output (``None``: the input P_u).
SIGNAL_OUTPUTS = {name: info.output for name, info in SIGNALS.items()}
PRESSURE_SIGNALS = tuple(n for n, i in SIGNALS.items() if i.kind == 'pressure')
FLOW_SIGNALS = tuple(n for n, i in SIGNALS.items() if i.kind == 'flow')
# The flows a flow controller can take as its feedback (controller.flow_signal).
FEEDBACK_FLOW_SIGNALS = tuple(n for n, i in SIGNALS.items() if i.feedback)
# The load orifice's own flow (eq. 9): at rest every flow equals it, and it is the one that
# leaves the pump's leakages and the line's compression out.
LOAD_FLOW_SIGNAL = 'load_flow'
# The line's flow q_l, eqs. 14-16's output and the controller's default feedback.
LINE_FLOW_SIGNAL = 'line_flow'
# The inputs a recording gives a model of the pump, and the outputs it is compared on.
CURRENT_SIGNAL = 'solenoid_current'
LOAD_PRESSURE_SIGNAL = 'load_pressure'
OUTPUT_SIGNALS = tuple(n for n in SIGNALS if n not in (CURRENT_SIGNAL, LOAD_PRESSURE_SIGNAL))
BENCH_OUTPUT_SIGNALS = tuple(n for n in OUTPUT_SIGNALS if SIGNALS[n].bench)
# joint_states: joint names and the outputs of their positions and velocities.
JOINTS = (('spool', 'x_c', 'v_c'), ('swash_plate_actuator', 'x_a', 'v_a'))



@dataclass(frozen=True)
class Topic:
    """A topic a model adds beside the suite's: the signal it carries, its kind
    (``pressure``: FluidPressure, absolute; anything else: Float64), and the measured signal
    whose sensor model it takes (``like``, or none)."""

    topic: str
    signal: str
    kind: str
    like: str | None


def model_topics(model) -> tuple[list[Topic], list[tuple[str, str]]]:
    """The topics a model adds (``ls_pressure``, ``loads/<name>/pressure``, ``flow``,
    ``position``, ``velocity``, ``speed``, ``angle``, ``pressure_b``; the energy account's
    ``energy/*``, kind ``energy``: cumulative, see :mod:`.energy`) and the command topics it
    takes ``(topic, input)``: ``loads/<name>/command``. A load whose signals are all measured
    signals of the suite (the paper's load) adds none."""
    topics: list[Topic] = []
    m = model.measured()
    if LS_PRESSURE_SIGNAL in m:
        topics.append(Topic(LS_PRESSURE_SIGNAL, m[LS_PRESSURE_SIGNAL], 'pressure',
                            'line_pressure'))
    commands = []
    measured = set(m.values())
    for name, sig in model.loads().items():
        if set(v for k, v in sig.items() if k != 'command') <= measured:
            continue
        for key, kind, like in (('pressure', 'pressure', 'line_pressure'),
                                ('pressure_b', 'pressure', 'line_pressure'),
                                ('flow', 'flow', 'line_flow'), ('position', 'position', None),
                                ('velocity', 'velocity', None), ('speed', 'speed', None),
                                ('angle', 'angle', None)):
            if key in sig:
                topics.append(Topic(f'loads/{name}/{key}', sig[key], kind, like))
        if 'command' in sig:
            commands.append((f'loads/{name}/command', sig['command']))
    from .energy import topics as energy_topics
    topics += [Topic(topic, signal, 'energy', None) for topic, signal in energy_topics(model)]
    topics += model.own_topics()
    return topics, commands


def suite_topics() -> list[str]:
    """The topics every simulator publishes, with the current command and the controller's
    state (a recorder's default list)."""
    return ['solenoid_current_cmd', *dict.fromkeys(i.topic for i in SIGNALS.values()),
            'controller/state']


def recorded_topics(circuit_file: str, commands: bool = True) -> list[str]:
    """The recorder's topics for a circuit: the suite's, then what the circuit adds and
    (unless not ``commands``: a run that sets them as parameters) its load commands (the
    structure only: nothing is compiled)."""
    from .circuit import load_circuit
    circuit = load_circuit(circuit_file, compile=False)
    topics, cmds = model_topics(circuit)
    return suite_topics() + [t.topic for t in topics] + [c[0] for c in cmds if commands]


class Readout:
    """What a simulator publishes of a model, read by name (the indices found once): the
    measured signals (:data:`SIGNALS`), the joints of the pump's spool and plate with their
    efforts, the limits it is at, and what the model adds (its topics and joints).

    A model without the paper's load (a load-sensing circuit) gives as ``load_pressure`` its
    load-sensing pressure (what the margin is taken against) and as ``load_flow`` the sum
    of its loads' flows.
    """

    def __init__(self, model):
        self.model = model
        self.params = model.plant_params()
        m = model.measured()
        ix = model.signal_index
        self._signals = {sig: ix(m[sig]) for sig in SIGNALS if sig in m}
        if 'load_pressure' not in self._signals and 'ls_pressure' in m:
            self._signals['load_pressure'] = ix(m['ls_pressure'])
        self._load_flows = None
        if 'load_flow' not in self._signals and model.loads():
            self._load_flows = np.array([ix(v['flow']) for v in model.loads().values()
                                         if 'flow' in v], dtype=np.int64)
        pump = model.pump_name()
        self._pump = {k: ix(f'{pump}.{k}') for k in ('x_c', 'v_c', 'x_a', 'v_a', 'P_a', 'P_l')}
        self._current = ix(f'{pump}.current') if model.electric_pump() else None
        self._relieved = np.array([ix(n) for n in model.relieved()], dtype=np.int64)
        self.topics, self.commands = model_topics(model)
        self._topics = [(t.topic, ix(t.signal)) for t in self.topics if t.kind != 'energy']
        self._joints = [(j, ix(p) if p else None, ix(v) if v else None)
                        for j, p, v in model.joints()]

    @property
    def names(self) -> list[str]:
        """The measured signals :meth:`signals` gives (a user's FMU may lack some)."""
        return list(self._signals) + (['load_flow'] if self._load_flows is not None else [])

    def signals(self, y: np.ndarray) -> dict[str, float]:
        """Every measured signal at one step, without sensor models (SI, gauge)."""
        out = {sig: float(y[k]) for sig, k in self._signals.items()}
        if self._load_flows is not None:
            out['load_flow'] = float(y[self._load_flows].sum())
        return out

    def current(self, y: np.ndarray) -> float | None:
        """The solenoid current of the step [A] (``None``: a pump without one)."""
        return float(y[self._current]) if self._current is not None else None

    def velocities(self, y: np.ndarray) -> tuple[float, float]:
        """Spool and plate velocities ``(v_c, v_a)`` [m/s]."""
        return float(y[self._pump['v_c']]), float(y[self._pump['v_a']])

    def efforts(self, y: np.ndarray) -> tuple[float, float]:
        """Solenoid force ``phi_s i_s`` (eq. 1) [N] and actuator force ``P_a S_a`` (eq. 6)
        [N]."""
        p = self.params
        i_s = (y[self._current] - p.I_nominal) if self._current is not None else 0.0
        return float(p.spool.phi_s * i_s), float(y[self._pump['P_a']] * p.actuator.S_a)

    def flags(self, y: np.ndarray) -> dict[str, bool]:
        """Which physical limit the step is at: end stops, an open relief, the pressure
        floor."""
        p, k = self.params, self._pump
        return {
            'spool_at_stop': bool(abs(y[k['x_c']]) >= p.spool.x_c_max),
            'plate_at_stop': bool(abs(y[k['x_a']]) >= p.x_a_stop),
            'relief_open': bool(np.any(y[self._relieved] > 1.0e-7)),
            'pressure_floor_active': bool(min(y[k['P_a']], y[k['P_l']]) + p.fluid.p_atm
                                          < p.fluid.dp_floor),
        }

    def relieved(self, y: np.ndarray) -> float:
        """The flow of every relief valve [m^3/s]."""
        return float(y[self._relieved].sum())

    def extra(self, y: np.ndarray) -> dict[str, float]:
        """The values of :attr:`topics` (true, SI, gauge) but the energies, which a
        :class:`~hydropump_sim.energy.Meter` integrates."""
        return {topic: float(y[k]) for topic, k in self._topics}

    def joints(self, y: np.ndarray) -> tuple[list[str], list[float], list[float]]:
        """Names, positions and velocities of the model's own joints."""
        js = self._joints
        return ([j[0] for j in js], [float(y[j[1]]) if j[1] is not None else 0.0 for j in js],
                [float(y[j[2]]) if j[2] is not None else 0.0 for j in js])
