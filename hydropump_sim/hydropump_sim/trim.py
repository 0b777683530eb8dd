"""Equilibrium (trim) solver for any operating point."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize

from . import _core as c
from .model import nominal_inputs, OUTPUTS, pack
from .params import Params


class TrimError(ValueError):
    """No equilibrium exists or none was found at the requested operating point."""


@dataclass(frozen=True)
class Equilibrium:
    """A steady state: state vector, held inputs and outputs (SI, gauge pressures)."""

    x: np.ndarray
    u: np.ndarray
    outputs: dict
    model: str
    residual: float

    def __getattr__(self, name):
        # Attribute access to outputs: eq.P_a, eq.q_l, ...
        try:
            return self.__dict__['outputs'][name]
        except KeyError:
            raise AttributeError(name) from None


def operating_inputs(params: Params, current: float | None = None, *, load_pressure=None,
                     aperture=None, shaft_speed=None) -> np.ndarray:
    """Input vector ``[i_s, P_u, xi_u, f_p]`` from absolute values; ``None`` = file value."""
    u = nominal_inputs(params)
    if current is not None:
        u[c.U_IS] = current - params.I_nominal
    if load_pressure is not None:
        u[c.U_PU] = load_pressure
    if aperture is not None:
        u[c.U_XI] = aperture
    if shaft_speed is not None:
        u[c.U_FP] = shaft_speed
    return u


def _line_pressure(p: np.ndarray, Q_p: float, u: np.ndarray) -> float:
    """Line pressure that balances pump flow against load and relief flows (eq. 9)."""
    def surplus(P_l):
        Q_load = p[c.P_MUU] * u[c.U_XI] * c.groot(P_l - u[c.U_PU], p[c.P_DPCRU], p[c.P_GAMMA])
        return Q_p - Q_load - c.relief_flow(P_l, p)

    lo, hi = u[c.U_PU] - 1.0e7, 1.0e9
    if surplus(hi) > 0.0:
        raise TrimError('no equilibrium: the pump flow has nowhere to go (load aperture closed '
                        'and relief valve disabled)')
    if surplus(lo) < 0.0:
        lo = -float(p[c.P_PATM])
    return optimize.brentq(surplus, lo, hi, xtol=1e-9, rtol=1e-14, maxiter=500)


def seed_state(params: Params, u: np.ndarray, model: str = 'fine') -> np.ndarray:
    """Closed-form equilibrium with ``x_c = 0`` (exact without leakage and end stops)."""
    p = pack(params, model)
    sp = params.spool
    x_a = float(np.clip(sp.phi_s * u[c.U_IS] / sp.K_a, -params.x_a_stop, params.x_a_stop))
    Q_p = c.pump_flow(x_a, u[c.U_FP], p)
    P_l = _line_pressure(p, Q_p, u)
    if model != 'fine':
        return np.array([x_a, P_l])
    x_c = (sp.phi_s * u[c.U_IS] - sp.K_a * x_a) / (sp.K_a + sp.K_c)
    # Eq. 6 at rest gives the actuator pressure that holds the plate (eq. 12, first line).
    P_a = params.actuator.P_a_bar - (params.plate.K_b * x_a + sp.K_a * (x_a + x_c)
                                     + (P_l - params.line.P_l_bar) * params.plate.S_d
                                     ) / params.actuator.S_a
    x = [x_c, 0.0, x_a, 0.0, P_a, P_l]
    if params.input.tau_s > 0.0:
        x.append(u[c.U_IS])
    return np.array(x)


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

    Returns
    -------
    Equilibrium

    Raises
    ------
    TrimError
        If no equilibrium exists (e.g. closed load with no relief) or none is found.
    """
    u = operating_inputs(params, current, load_pressure=load_pressure, aperture=aperture,
                         shaft_speed=shaft_speed)
    p = pack(params, model)
    p[c.P_DITHA] = 0.0  # the mean current defines the equilibrium
    x0 = seed_state(params, u, model)
    scale = c.state_scale(p, x0.shape[0])
    dx = np.empty_like(x0)
    ybuf = np.empty(c.N_Y)

    def resid(z):
        c.evaluate(0.0, z * scale, u, p, dx, ybuf)
        return dx * 1.0e-3 / scale

    r0 = float(np.max(np.abs(resid(x0 / scale))))
    x = x0
    if r0 > tol:
        sol = optimize.root(resid, x0 / scale, method='hybr', options={'xtol': 1e-13})
        x = sol.x * scale
    r = float(np.max(np.abs(resid(x / scale))))
    if not np.isfinite(r) or r > max(tol, 1e-7):
        raise TrimError(f'no equilibrium found at I_s = {u[0] + params.I_nominal:.4g} A, '
                        f'P_u = {u[1]:.4g} Pa, xi_u = {u[2]:.4g}, f_p = {u[3]:.4g} Hz '
                        f'(scaled residual {r:.2e})')
    y = np.empty(c.N_Y)
    c.evaluate(0.0, x, u, p, dx, y)
    return Equilibrium(x=x, u=u, outputs=dict(zip(OUTPUTS, y.tolist())), model=model,
                       residual=r)
