"""The paper plant's steady state at an operating point, by the paper's arguments: the one
steady-state search of :mod:`hydropump_sim.steady` on its model
(:class:`~hydropump_sim.plant_model.PumpModel`), answering by the paper's names.
"""

from __future__ import annotations

from .params import Params
from .plant_model import operating_inputs, PumpModel, SIGNAL_NAMES
from .steady import equilibrium as steady_state
from .steady import TrimError
from .system import SteadyState

__all__ = ['Equilibrium', 'equilibrium', 'operating_inputs', 'TrimError']


class Equilibrium(SteadyState):
    """A steady state of the paper's plant: ``x``, the held inputs ``u`` (``[I_s, P_u,
    xi_u, f_p]``), the signals, by name (``eq['pump.q_l']``) and by the paper's output names
    (``eq.P_a``, ``eq.q_l``; SI, gauge pressures)."""

    def __getattr__(self, name):
        if name in SIGNAL_NAMES:
            return self[SIGNAL_NAMES[name]]
        raise AttributeError(name)

    @property
    def outputs(self) -> dict[str, float]:
        """Every output by the paper's name."""
        return {o: self[s] for o, s in SIGNAL_NAMES.items()}


def equilibrium(params: Params, current: float | None = None, *, load_pressure=None,
                aperture=None, shaft_speed=None, model: str = 'fine',
                tol: float = 1e-10) -> Equilibrium:
    """Steady state at an operating point.

    Parameters
    ----------
    params : Params
    current : float, optional
        Absolute solenoid current ``I_s`` [A]; default ``I_min + I_max`` (50 %).
    load_pressure, aperture, shaft_speed : float, optional
        ``P_u`` [Pa gauge], ``xi_u`` [-], ``f_p`` [Hz]; default the parameter file's values.
    model : {'fine', 'simplified', 'simplified_Kc'}
    tol : float
        Accepted scaled residual (derivatives times a 1 ms horizon over the state scales).

    Raises
    ------
    TrimError
        If no equilibrium exists (e.g. closed load with no relief) or none is found.
    """
    u = operating_inputs(params, current, load_pressure=load_pressure, aperture=aperture,
                         shaft_speed=shaft_speed)
    eq = steady_state(PumpModel(params, model), u, tol=tol, horizon=10.0, time_budget=10.0)
    return Equilibrium(eq.model, eq.x, eq.u, eq.y, eq.residual)
