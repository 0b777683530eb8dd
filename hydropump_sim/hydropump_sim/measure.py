"""The measurement map: model outputs -> the named signals a bench measures.

One map serves the simulator node and the offline closed-loop harness, so that both see the
plant through the same signals (SI units, gauge pressures; a node converts pressures to
absolute at its edge):

- :data:`SIGNAL_OUTPUTS` names which output of :data:`hydropump_sim.model.OUTPUTS` each
  measured signal is (``load_pressure`` is the input ``P_u``);
- :func:`true_signals` evaluates them at one step;
- :func:`efforts` gives the generalised forces of ``joint_states`` (solenoid force of eq. 1,
  actuator force ``P_a S_a`` of eq. 6);
- :func:`limit_flags` says which physical limit is active (end stops, relief, pressure floor).
"""

from __future__ import annotations

import numpy as np

from . import _core as c
from .model import OUTPUTS
from .params import Params

# Measured signal -> model output (``None``: the input P_u).
SIGNAL_OUTPUTS = {
    'solenoid_current': 'I_s',
    'pump_flow': 'Q_p',
    'line_flow': 'q_l',
    'load_flow': 'Q_load',
    'actuator_pressure': 'P_a',
    'line_pressure': 'P_l',
    'load_pressure': None,
    'spool_position': 'x_c',
    'actuator_position': 'x_a',
}
PRESSURE_SIGNALS = ('actuator_pressure', 'line_pressure', 'load_pressure')
FLOW_SIGNALS = ('pump_flow', 'line_flow', 'load_flow')
# joint_states: joint names and the outputs of their positions and velocities.
JOINTS = (('spool', 'x_c', 'v_c'), ('swash_plate_actuator', 'x_a', 'v_a'))

_Y = {name: i for i, name in enumerate(OUTPUTS)}


def true_signals(y: np.ndarray, u: np.ndarray) -> dict[str, float]:
    """Every measured signal at one step, without sensor models (SI, gauge).

    Parameters
    ----------
    y : ndarray, shape (len(OUTPUTS),)
        Outputs of the step (:meth:`hydropump_sim.Simulator.outputs`).
    u : ndarray, shape (4,)
        Held inputs ``[i_s, P_u, xi_u, f_p]``.
    """
    return {sig: float(u[c.U_PU]) if out is None else float(y[_Y[out]])
            for sig, out in SIGNAL_OUTPUTS.items()}


def velocities(y: np.ndarray) -> tuple[float, float]:
    """Spool and plate velocities ``(v_c, v_a)`` [m/s]."""
    return float(y[_Y['v_c']]), float(y[_Y['v_a']])


def efforts(params: Params, y: np.ndarray) -> tuple[float, float]:
    """Solenoid force ``phi_s i_s`` (eq. 1) [N] and actuator force ``P_a S_a`` (eq. 6) [N]."""
    return (float(params.spool.phi_s * (y[_Y['I_s']] - params.I_nominal)),
            float(y[_Y['P_a']] * params.actuator.S_a))


def limit_flags(params: Params, y: np.ndarray) -> dict[str, bool]:
    """Which physical limit the step is at: end stops, open relief, the pressure floor."""
    return {
        'spool_at_stop': bool(abs(y[_Y['x_c']]) >= params.spool.x_c_max),
        'plate_at_stop': bool(abs(y[_Y['x_a']]) >= params.x_a_stop),
        'relief_open': bool(y[_Y['Q_relief']] > 0.0),
        'pressure_floor_active': bool(min(y[_Y['P_a']], y[_Y['P_l']]) + params.fluid.p_atm
                                      < params.fluid.dp_floor),
    }

