"""Equilibrium (trim) solver for any operating point."""

from __future__ import annotations

from dataclasses import dataclass
import time

import numpy as np
from scipy import optimize

from . import _core as c
from .errors import HydropumpError
from .model import nominal_inputs, OUTPUTS, pack
from .params import Params


class TrimError(HydropumpError, ValueError):
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

    if Q_p <= 0.0:
        return float(u[c.U_PU])  # no flow: the line rests at the load pressure
    lo, hi = max(u[c.U_PU] - 1.0e7, -float(p[c.P_PATM])), 1.0e9
    if surplus(hi) > 0.0:
        raise TrimError('no equilibrium: the pump flow has nowhere to go (load aperture closed '
                        'and relief valve disabled)')
    if surplus(lo) < 0.0:
        return lo
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

    def worst(x):
        return float(np.max(np.abs(resid(x / scale))))

    def polish(x):
        if worst(x) <= tol:
            return x
        sol = optimize.root(resid, x / scale, method='hybr', options={'xtol': 1e-13})
        return sol.x * scale

    def good(x, accept):
        return _physical(params, x, u, p, model) and worst(x) <= accept

    x = polish(x0) if _physical(params, x0, u, p, model) else x0
    if not good(x, max(tol, 1e-7)) and model == 'fine':
        xs = _standby_seed(params, u, p)
        if xs is not None:
            xs = polish(xs)
            x = xs if good(xs, max(tol, 1e-7)) else x
    if not good(x, max(tol, 1e-7)):
        # No closed-form steady state here (a spool or plate on its stop, or too little line
        # pressure to destroke the pump): let the dynamics find it, then polish. Some such
        # points are degenerate (a dead-headed pump at zero displacement rests at any line
        # pressure below the relief valve), so a settled state is accepted more loosely.
        x, stopped = _march(params, x0, u, p, model)
        xp = polish(x)
        x = xp if good(xp, max(tol, 1e-7)) else x
        if not good(x, 1e-5):
            why = _unphysical(params, x, u, p) or (
                f'the state does not settle (scaled residual {worst(x):.2e} above 1e-05)')
            raise TrimError(f'no equilibrium found at I_s = {u[0] + params.I_nominal:.4g} A, '
                            f'P_u = {u[1]:.4g} Pa, xi_u = {u[2]:.4g}, f_p = {u[3]:.4g} Hz: '
                            f'{why}' + (f'; {stopped}' if stopped else ''))
    r = worst(x)
    y = np.empty(c.N_Y)
    c.evaluate(0.0, x, u, p, dx, y)
    return Equilibrium(x=x, u=u, outputs=dict(zip(OUTPUTS, y.tolist())), model=model,
                       residual=r)


def _physical(params: Params, x: np.ndarray, u: np.ndarray, p: np.ndarray, model: str) -> bool:
    """A steady state the pump can hold (see :func:`_unphysical`)."""
    return _unphysical(params, x, u, p) is None


def _unphysical(params: Params, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> str | None:
    """Why ``x`` is not a steady state the pump can hold, or ``None``: pressures above
    absolute zero, the actuator between tank and line pressure (D5; otherwise the pilot
    feedback reverses), parts near their stroke."""
    if not np.all(np.isfinite(x)):
        return 'the state is not finite'
    y = np.empty(c.N_Y)
    c.evaluate(0.0, x, u, p, np.empty_like(x), y)
    P_a, P_l, x_a, x_c = y[c.Y_PA], y[c.Y_PL], y[c.Y_XA], y[c.Y_XC]
    slack = 1.0e4  # Pa: the regularised orifice lets P_a sit a little outside P_T..P_l
    if P_l + params.fluid.p_atm < 0.0:
        return f'the line pressure P_l = {P_l:.4g} Pa is below absolute zero'
    if not params.fluid.P_T - slack <= P_a <= P_l + slack:
        return (f'the actuator pressure P_a = {P_a:.4g} Pa is outside [P_T, P_l] = '
                f'[{params.fluid.P_T:.4g}, {P_l:.4g}] Pa (D5: the pilot feedback reverses)')
    if abs(x_a) > 1.5 * params.x_a_stop:
        return f'the plate is at x_a = {x_a:.4g} m, beyond its stroke {params.x_a_stop:.4g} m'
    if abs(x_c) > 1.5 * params.spool.x_c_max:
        return (f'the spool is at x_c = {x_c:.4g} m, beyond its stroke '
                f'{params.spool.x_c_max:.4g} m')
    return None


def _standby_seed(params: Params, u: np.ndarray, p: np.ndarray) -> np.ndarray | None:
    """Steady state with the pilot valve open to the line (``P_a = P_l``): the line pressure
    is too low to hold the demanded displacement, so the pump settles where the line pressure
    on the actuator balances the bias spring (a pump's standby pressure)."""
    sp, S_a, S_d = params.spool, params.actuator.S_a, params.plate.S_d

    def state(x_a):
        x_c = (sp.phi_s * u[c.U_IS] - sp.K_a * x_a) / (sp.K_a + sp.K_c)
        x_c = min(max(x_c, -sp.x_c_max), sp.x_c_max)
        P_l = ((params.actuator.P_a_bar * S_a + params.line.P_l_bar * S_d
                - params.plate.K_b * x_a - sp.K_a * (x_a + x_c)) / (S_a + S_d))
        return x_c, P_l

    def surplus(x_a):
        x_c, P_l = state(x_a)
        Q_load = p[c.P_MUU] * u[c.U_XI] * c.groot(P_l - u[c.U_PU], p[c.P_DPCRU], p[c.P_GAMMA])
        return c.pump_flow(x_a, u[c.U_FP], p) - Q_load - c.relief_flow(P_l, p)

    lo, hi = -params.x_a_stop, params.x_a_stop
    if surplus(lo) * surplus(hi) > 0.0:
        return None
    x_a = optimize.brentq(surplus, lo, hi, xtol=1e-15)
    x_c, P_l = state(x_a)
    x = [x_c, 0.0, x_a, 0.0, P_l, P_l]
    if params.input.tau_s > 0.0:
        x.append(u[c.U_IS])
    return np.array(x)


def _march(params: Params, x0: np.ndarray, u: np.ndarray, p: np.ndarray, model: str,
           horizon: float = 10.0, max_steps: int = 1_000_000, time_budget: float = 10.0
           ) -> tuple[np.ndarray, str]:
    """Integrate with held inputs from a physically clipped seed until the state settles,
    within ``horizon`` of simulated time, ``max_steps`` solver steps and ``time_budget`` s of
    wall time. Returns the state and why the march stopped early (``''`` if it did not)."""
    x = x0.copy()
    if model == 'fine':
        x[5] = max(x[5], params.fluid.P_T)
        x[4] = min(max(x[4], params.fluid.P_T), x[5])
    dt, chunk = 1.0e-3, 200
    U = np.tile(u, (chunk, 1))
    Y = np.empty((chunk + 1, c.N_Y))
    X = np.empty((chunk + 1, x.size))
    stats = np.zeros(2, dtype=np.int64)
    scale = c.state_scale(p, x.size)
    dx = np.empty_like(x)
    t0 = time.perf_counter()
    for k in range(int(horizon / (dt * chunk))):
        status, _ = c.run(x[None], k * dt * chunk, dt, U, p[None], 1e-6, 1e-12, 20000, 1, Y[None],
                          X[None], stats, max_steps)
        if status == c.FAIL_BUDGET:
            return x, (f'the integration toward it took more than {max_steps:.3g} solver steps '
                       'in {:.3g} s (the parameters make the model very stiff)'.format(
                           (k + 1) * dt * chunk))
        if status != c.OK:
            return x, 'the integration toward it failed'
        x = X[-1].copy()
        c.evaluate(0.0, x, u, p, dx, Y[0])
        if np.max(np.abs(dx) * 1.0e-3 / scale) < 1e-9:
            break
        if time.perf_counter() - t0 > time_budget:
            return x, f'the integration toward it ran out of its {time_budget:g} s time budget'
    return x, ''
