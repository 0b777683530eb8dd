"""The measurement map: model outputs -> the named signals a bench measures.

One map serves the simulator node and the offline closed-loop harness, so that both see the
plant through the same signals (SI units, gauge pressures; a node converts pressures to
absolute at its edge):

- :data:`SIGNALS` is the one table of the measured signals (model output, unit, label, kind,
  topic and message type); :data:`SIGNAL_OUTPUTS` names which output of
  :data:`hydropump_sim.model.OUTPUTS` each is (``load_pressure`` is the input ``P_u``);
- :func:`true_signals` evaluates them at one step;
- :func:`efforts` gives the generalised forces of ``joint_states`` (solenoid force of eq. 1,
  actuator force ``P_a S_a`` of eq. 6);
- :func:`limit_flags` says which physical limit is active (end stops, relief, pressure floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import Params

FLOAT64 = 'std_msgs/msg/Float64'
FLUID_PRESSURE = 'sensor_msgs/msg/FluidPressure'
JOINT_STATE = 'sensor_msgs/msg/JointState'


@dataclass(frozen=True)
class SignalInfo:
    """A measured signal: the model output it is, its SI unit, its label in the paper's
    symbols, what kind of quantity it is, and how the simulator node publishes it (topic,
    message type, ``joint_states`` entry). ``held`` signals are piecewise constant between
    samples (the applied current); ``bench`` says whether a test bench measures it (the
    spool and plate positions are the simulator's exact states, which no bench has)."""

    output: str | None       # None: the input P_u
    unit: str
    label: str
    kind: str                # current | flow | pressure | position
    topic: str
    msgtype: str = FLOAT64
    entry: str | None = None
    held: bool = False
    bench: bool = True


# The one table of the measured signals; every other list of them is derived from it.
SIGNALS = {
    'solenoid_current': SignalInfo('I_s', 'A', 'solenoid current I_s', 'current',
                                   'solenoid_current', held=True),
    'pump_flow': SignalInfo('Q_p', 'm^3/s', 'pump flow Q_p', 'flow', 'pump_flow'),
    'line_flow': SignalInfo('q_l', 'm^3/s', 'line flow q_l', 'flow', 'line_flow'),
    'load_flow': SignalInfo('Q_load', 'm^3/s', 'load flow Q_load', 'flow', 'load_flow'),
    'actuator_pressure': SignalInfo('P_a', 'Pa', 'actuator pressure P_a', 'pressure',
                                    'actuator_pressure', FLUID_PRESSURE),
    'line_pressure': SignalInfo('P_l', 'Pa', 'line pressure P_l', 'pressure',
                                'line_pressure', FLUID_PRESSURE),
    'load_pressure': SignalInfo(None, 'Pa', 'load pressure P_u', 'pressure', 'load_pressure',
                                FLUID_PRESSURE),
    'spool_position': SignalInfo('x_c', 'm', 'spool position x_c', 'position', 'joint_states',
                                 JOINT_STATE, 'spool', bench=False),
    'actuator_position': SignalInfo('x_a', 'm', 'actuator position x_a', 'position',
                                    'joint_states', JOINT_STATE, 'swash_plate_actuator',
                                    bench=False),
}
# Measured signal -> model output (``None``: the input P_u).
SIGNAL_OUTPUTS = {name: info.output for name, info in SIGNALS.items()}
PRESSURE_SIGNALS = tuple(n for n, i in SIGNALS.items() if i.kind == 'pressure')
FLOW_SIGNALS = tuple(n for n, i in SIGNALS.items() if i.kind == 'flow')
# The inputs a recording gives a model of the pump, and the outputs it is compared on.
CURRENT_SIGNAL = 'solenoid_current'
LOAD_PRESSURE_SIGNAL = 'load_pressure'
OUTPUT_SIGNALS = tuple(n for n in SIGNALS if n not in (CURRENT_SIGNAL, LOAD_PRESSURE_SIGNAL))
BENCH_OUTPUT_SIGNALS = tuple(n for n in OUTPUT_SIGNALS if SIGNALS[n].bench)
# joint_states: joint names and the outputs of their positions and velocities.
JOINTS = (('spool', 'x_c', 'v_c'), ('swash_plate_actuator', 'x_a', 'v_a'))

# Output name -> index, and the index of P_u in the inputs: filled on first use, so that the
# table above costs a node that only reads signal names no compiled model (the controller and
# the recorder start in half a second).
_Y: dict[str, int] = {}


def _index() -> dict[str, int]:
    if not _Y:
        from .model import INPUTS, OUTPUTS
        _Y.update({name: i for i, name in enumerate(OUTPUTS)}, _P_u=INPUTS.index('P_u'))
    return _Y


def true_signals(y: np.ndarray, u: np.ndarray) -> dict[str, float]:
    """Every measured signal at one step, without sensor models (SI, gauge).

    Parameters
    ----------
    y : ndarray, shape (len(OUTPUTS),)
        Outputs of the step (:meth:`hydropump_sim.Simulator.outputs`).
    u : ndarray, shape (4,)
        Held inputs ``[i_s, P_u, xi_u, f_p]``.
    """
    ix = _Y or _index()
    return {sig: float(u[ix['_P_u']]) if out is None else float(y[ix[out]])
            for sig, out in SIGNAL_OUTPUTS.items()}


def velocities(y: np.ndarray) -> tuple[float, float]:
    """Spool and plate velocities ``(v_c, v_a)`` [m/s]."""
    ix = _Y or _index()
    return float(y[ix['v_c']]), float(y[ix['v_a']])


def efforts(params: Params, y: np.ndarray) -> tuple[float, float]:
    """Solenoid force ``phi_s i_s`` (eq. 1) [N] and actuator force ``P_a S_a`` (eq. 6) [N]."""
    ix = _Y or _index()
    return (float(params.spool.phi_s * (y[ix['I_s']] - params.I_nominal)),
            float(y[ix['P_a']] * params.actuator.S_a))


def limit_flags(params: Params, y: np.ndarray) -> dict[str, bool]:
    """Which physical limit the step is at: end stops, open relief, the pressure floor."""
    ix = _Y or _index()
    return {
        'spool_at_stop': bool(abs(y[ix['x_c']]) >= params.spool.x_c_max),
        'plate_at_stop': bool(abs(y[ix['x_a']]) >= params.x_a_stop),
        'relief_open': bool(y[ix['Q_relief']] > 0.0),
        'pressure_floor_active': bool(min(y[ix['P_a']], y[ix['P_l']]) + params.fluid.p_atm
                                      < params.fluid.dp_floor),
    }

