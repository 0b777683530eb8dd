"""A second, separately written fine model of the pump: the "truth" of the calibration
coverage tests.

It is written from the paper's equations (1)-(9) and the project's reading of them
(variational spool and plate equations around x_c = 0, x_a = 0 with the preload pressures
P_a_bar, P_l_bar; V_a = V_a0 - S_a x_a; pilot edge x_c > 0 drains the actuator to tank,
x_c < 0 feeds it from the line; the absolute current is I_s = I_min + I_max + i_s), and it
shares no code with the simulator. It takes the parameters as a flat dict of dotted names
(as in config/pump.yaml) and integrates the 6th-order model (7th with the solenoid lag) with
scipy's LSODA, one call per run of constant inputs, from an equilibrium found by root finding.

Deliberate structural differences from the simulator, of the size a real pump differs from
its model by, so that a calibration that only reproduces the simulator's own equations is
not enough to pass:
  * orifice laws (pilot edges, load orifice) are linear below the transition pressure dp_cr
    and a pure power law above it, matched in value there (Hopsan/Amesim style), instead of
    the smooth dp/(dp^2 + dp_cr^2)^(1/4) form;
  * Coulomb friction is smoothed with (2/pi) arctan(v/v_eps) instead of tanh(v/v_eps);
  * optional ``stamp_offset``: every output is read at t + stamp_offset relative to the
    recorded current, as on a bench whose current stamps lag or lead the sensors.
Dither, entrained air and the pressure floor are not modelled (inactive in the parameter
sets this plant is used with).
"""
import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root

_EPS_T = 1e-9   # a sampler at t_k still sees the input held before t_k


def _root(dp, dp_cr, inv_gamma=0.5):
    """Signed |dp|^(1/gamma), linear (laminar) below dp_cr, continuous at dp_cr."""
    a = abs(dp)
    if a >= dp_cr:
        return math.copysign(a ** inv_gamma, dp)
    return dp * dp_cr ** (inv_gamma - 1.0)


def _coulomb(F, v, v_eps):
    return F * (2.0 / math.pi) * math.atan(v / v_eps) if F else 0.0


def _stop(x, v, lim, k, c):
    """Penalty end stop at +-lim: spring and damper act only while the stop is penetrated."""
    if x > lim:
        return -k * (x - lim) - c * v
    if x < -lim:
        return -k * (x + lim) - c * v
    return 0.0


class _Plant:
    """The right-hand side, the algebraic outputs and the rest state for one parameter set."""

    def __init__(self, p):
        def g(k, d=None):
            return float(p[k]) if d is None else float(p.get(k, d))
        self.beta, self.P_T = g('fluid.beta'), g('fluid.P_T', 0.0)
        self.Qmax, self.xa_max = g('pump.V_p') * g('pump.f_p'), g('pump.x_a_max')
        # 'paper' flow map: eq. 8 literally, physical stroke +-x_a_max/2 (0..100 % displacement);
        # 'consistent': full stroke +-x_a_max with half the slope. Same pump either way.
        self.consistent = str(p.get('pump.flow_map', 'paper')) == 'consistent'
        self.xa_lim = self.xa_max if self.consistent else self.xa_max / 2
        self.clip = bool(p.get('pump.disp_clip', True))
        for k in ('m_c', 'K_c', 'K_a', 'phi_s', 'I_max', 'I_min', 'x_c_max', 'c_c',
                  'k_stop_c', 'c_stop_c'):
            setattr(self, k, g('spool.' + k))
        self.F_c, self.ve_c = g('spool.F_coul_c', 0.0), g('spool.v_eps_c', 1e-4)
        for k in ('S_a', 'V_a0', 'V_a_min', 'P_a_bar', 'mu_a', 'dp_cr_a'):
            setattr(self, k, g('actuator.' + k))
        self.G_leak = g('actuator.G_leak_a', 0.0)
        for k in ('m_a', 'K_b', 'S_d', 'c_a', 'k_stop_a', 'c_stop_a'):
            setattr(self, k, g('plate.' + k))
        self.F_a, self.ve_a = g('plate.F_coul_a', 0.0), g('plate.v_eps_a', 1e-4)
        for k in ('V_l', 'P_l_bar', 'P_u', 'xi_u', 'gamma_u', 'mu_u', 'dp_cr_u'):
            setattr(self, k, g('line.' + k))
        self.relief = bool(p.get('relief.enabled', False))
        if self.relief:
            self.p_crack, self.p_full, self.q_full = (
                g('relief.' + k) for k in ('p_crack', 'p_full', 'q_full'))
        self.tau_s = g('input.tau_s', 0.0)
        self.I_nom = self.I_min + self.I_max        # eq. 2: i_s = I_s - I_min - I_max

    # algebraic parts
    def pump_flow(self, x_a):
        frac = 0.5 + (x_a / (2 * self.xa_max) if self.consistent else x_a / self.xa_max)
        if self.clip:
            frac = min(max(frac, 0.0), 1.0)
        return self.Qmax * frac

    def pilot_flow(self, x_c, P_a, P_l):
        """Eq. 4, positive out of the actuator: to tank for x_c > 0, from the line for x_c < 0."""
        if x_c > 0:
            return self.mu_a * x_c * _root(P_a - self.P_T, self.dp_cr_a)
        if x_c < 0:
            return self.mu_a * x_c * _root(P_l - P_a, self.dp_cr_a)
        return 0.0

    def load_flow(self, P_l, P_u):
        return self.mu_u * self.xi_u * _root(P_l - P_u, self.dp_cr_u, 1.0 / self.gamma_u)

    def relief_flow(self, P_l):
        if not self.relief or P_l <= self.p_crack:
            return 0.0
        opening = min((P_l - self.p_crack) / (self.p_full - self.p_crack), 1.0)
        return self.q_full * opening * math.sqrt(P_l / self.p_full)

    def forces(self, x_c, v_c, x_a, v_a, P_a, P_l, I_s):
        """Net forces on spool (eq. 1) and plate (eq. 6), preloads hidden in the variations."""
        F_c = (-self.c_c * v_c - _coulomb(self.F_c, v_c, self.ve_c)
               - (self.K_c + self.K_a) * x_c - self.K_a * x_a + self.phi_s * (I_s - self.I_nom)
               + _stop(x_c, v_c, self.x_c_max, self.k_stop_c, self.c_stop_c))
        F_a = (-self.c_a * v_a - _coulomb(self.F_a, v_a, self.ve_a)
               - self.K_b * x_a - self.K_a * (x_a + x_c)
               - (P_a - self.P_a_bar) * self.S_a - (P_l - self.P_l_bar) * self.S_d
               + _stop(x_a, v_a, self.xa_lim, self.k_stop_a, self.c_stop_a))
        return F_c, F_a

    def flows(self, x_c, v_a, x_a, P_a, P_l, P_u):
        """Net inflows of the actuator chamber (eq. 3, plus leakage) and of the line (eq. 9)."""
        Q_a = self.pilot_flow(x_c, P_a, P_l)
        q_act = -Q_a + self.S_a * v_a - self.G_leak * (P_a - self.P_T)
        q_line = (self.pump_flow(x_a) + (Q_a if x_c < 0 else 0.0)
                  - self.load_flow(P_l, P_u) - self.relief_flow(P_l))
        return q_act, q_line

    def rhs_for(self, I_cmd, P_u):
        b, lag = self.beta, self.tau_s > 0

        def f(t, y):
            x_c, v_c, x_a, v_a, P_a, P_l = y[0], y[1], y[2], y[3], y[4], y[5]
            I_s = y[6] if lag else I_cmd
            F_c, F_a = self.forces(x_c, v_c, x_a, v_a, P_a, P_l, I_s)
            q_act, q_line = self.flows(x_c, v_a, x_a, P_a, P_l, P_u)
            V_a = max(self.V_a0 - self.S_a * x_a, self.V_a_min)
            d = [v_c, F_c / self.m_c, v_a, F_a / self.m_a, b / V_a * q_act, b / self.V_l * q_line]
            if lag:
                d.append((I_cmd - I_s) / self.tau_s)
            return d
        return f

    def rest(self, I_s, P_u):
        """Equilibrium (all rates zero) for constant current I_s and load pressure P_u."""
        sc = np.array([self.x_c_max, self.xa_max, 1e6, 1e7])     # unknowns scaled to ~1

        def res(z):
            x_c, x_a, P_a, P_l = z * sc
            F_c, F_a = self.forces(x_c, 0.0, x_a, 0.0, P_a, P_l, I_s)
            q_act, q_line = self.flows(x_c, 0.0, x_a, P_a, P_l, P_u)
            return [F_c / (self.K_a * self.x_c_max), F_a / (self.K_a * self.x_c_max),
                    q_act / self.Qmax, q_line / self.Qmax]
        # start: spool centred, eq. 10/11 stroke, load law for P_l, eq. 12 (with p_l S_d) for P_a
        x_a = min(max(self.phi_s * (I_s - self.I_nom) / self.K_a, -self.xa_lim), self.xa_lim)
        dpl = (self.pump_flow(x_a) / (self.mu_u * self.xi_u)) ** self.gamma_u
        P_l = P_u + dpl
        P_a = self.P_a_bar - ((self.K_b + self.K_a) * x_a
                              + (P_l - self.P_l_bar) * self.S_d) / self.S_a
        # second start for currents beyond the stroke: the stop holds the plate, the spool stays
        # open to tank and the chamber drains to P_T (the x_c = 0 root there needs P_a < 0)
        x_c = min(max((self.phi_s * (I_s - self.I_nom) - self.K_a * x_a) / (self.K_a + self.K_c),
                      -self.x_c_max), self.x_c_max)
        for z0 in (np.array([0.0, x_a, P_a, P_l]) / sc, np.array([x_c, x_a, self.P_T, P_l]) / sc):
            sol = root(res, z0, method='hybr', options={'xtol': 1e-13})
            if np.max(np.abs(res(sol.x))) < 1e-10 and sol.x[2] * sc[2] >= self.P_T - 1e3:
                break
        else:
            raise RuntimeError(f'no rest state for I_s={I_s}, P_u={P_u}: {sol.message}')
        x_c, x_a, P_a, P_l = sol.x * sc
        y = [x_c, 0.0, x_a, 0.0, P_a, P_l]
        return np.array(y + [I_s] if self.tau_s > 0 else y)


class PaperRun:
    """One integrated run: inputs held per sample, piecewise dense solution."""

    def __init__(self, plant, current, load_pressure, dt, stamp_offset, t0s, sols, y0, y_end):
        self.plant, self.dt, self.stamp_offset = plant, dt, stamp_offset
        self.current, self.load_pressure = current, load_pressure
        self.n = len(current)
        self._t0s, self._sols, self._y0, self._y_end = t0s, sols, y0, y_end

    def _states(self, t):
        """State (columns) at times t; rest before 0, end state after the end."""
        t = np.asarray(t, float)
        Y = np.empty((len(self._y0), t.size))
        Y[:] = self._y0[:, None]
        T_end = self.n * self.dt
        Y[:, t >= T_end] = self._y_end[:, None]
        inside = (t > 0) & (t < T_end)
        seg = np.searchsorted(self._t0s, t, side='right') - 1
        for s in np.unique(seg[inside]):
            m = inside & (seg == s)
            Y[:, m] = self._sols[s](t[m])
        return Y

    def signal(self, name, times):
        """The true ``name`` at ``times`` [s]: 'line_flow' is the net pump-plus-pilot flow
        into the line (eqs. 14-15's output), 'load_flow' the load orifice's, 'load_pressure'
        the held input (on the current's clock: the stamp offset moves the outputs only)."""
        times = np.atleast_1d(np.asarray(times, float))
        if name == 'load_pressure':
            k = np.clip(np.floor((times - _EPS_T) / self.dt).astype(int), 0, self.n - 1)
            return self.load_pressure[k].copy()
        te = times + self.stamp_offset
        k = np.clip(np.floor((te - _EPS_T) / self.dt).astype(int), 0, self.n - 1)
        P_u = self.load_pressure[k]          # input the sampler sees (before 0: the first, = rest)
        Y = self._states(te)
        pl = self.plant
        if name == 'line_pressure':
            return Y[5]
        if name == 'actuator_pressure':
            return Y[4]
        if name == 'pump_flow':
            return np.array([pl.pump_flow(x) for x in Y[2]])
        if name == 'line_flow':
            return np.array([pl.pump_flow(x_a) + (pl.pilot_flow(x_c, P_a, P_l) if x_c < 0
                                                   else 0.0)
                             for x_c, x_a, P_a, P_l in zip(Y[0], Y[2], Y[4], Y[5])])
        if name == 'load_flow':
            return np.array([pl.load_flow(P, u) for P, u in zip(Y[5], P_u)])
        raise KeyError(name)


def run(params, current, load_pressure=None, dt=1e-3, stamp_offset=0.0, rtol=1e-8):
    """Integrate the plant for absolute currents ``current`` [A] and gauge load pressures
    ``load_pressure`` [Pa] (None: line.P_u), each held over [k dt, (k+1) dt), from rest."""
    pl = _Plant(params)
    current = np.asarray(current, float)
    n = current.size
    load = (np.full(n, pl.P_u) if load_pressure is None
            else np.broadcast_to(np.asarray(load_pressure, float), (n,)).copy())
    y = pl.rest(current[0], load[0])
    y0 = y.copy()
    # absolute tolerances: rtol times the natural scale of each state
    scale = [pl.x_c_max, pl.x_c_max / 1e-3, pl.xa_max, pl.xa_max / 1e-2, pl.P_l_bar, pl.P_l_bar]
    atol = rtol * np.array(scale + ([pl.I_max] if pl.tau_s > 0 else []))
    # One solve_ivp call per run of identical inputs; the last step size seeds the next call so
    # the solver does not restart from a tiny step at every sample. LSODA (stiff BDF core in
    # Fortran) is ~5x faster here than scipy's pure-Python BDF at the same accuracy.
    change = np.flatnonzero((np.diff(current) != 0) | (np.diff(load) != 0)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [n]])
    t0s, sols, h = [], [], None
    for a, b in zip(starts, ends):
        t0, t1 = a * dt, b * dt
        sol = solve_ivp(pl.rhs_for(current[a], load[a]), (t0, t1), y, method='LSODA',
                        rtol=rtol, atol=atol, dense_output=True,
                        first_step=None if h is None else min(h, t1 - t0))
        if not sol.success:
            raise RuntimeError(f'integration failed at t={t0}: {sol.message}')
        steps = np.diff(sol.t)
        h = steps[-2] if steps.size > 1 else steps[-1]   # the last step is cut at the boundary
        y = sol.y[:, -1]
        t0s.append(t0)
        sols.append(sol.sol)
    return PaperRun(pl, current, load, dt, stamp_offset, np.array(t0s), sols, y0, y.copy())
