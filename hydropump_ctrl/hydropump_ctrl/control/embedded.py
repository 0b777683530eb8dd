"""The embedded model of Embedded Model Control: the pump and the line in discrete time.

Canuto's EMC builds the controller around a discrete-time model of the plant that is simple
enough to run in the controller, completed by disturbance states that collect what the model
leaves out. Here the controllable dynamics are the paper's simplified model reduced to the
current-to-flow path of eq. 19, with the structure the simplified model adds around it:

- eq. 10: the spool position is the error between the commanded and the actual stroke. In flow
  units ``e = v + d - Q`` (``v`` the eq. 11 static map of the command, ``d`` the disturbance).
  The spool stroke limit ``x_c_max`` bounds it: ``|e| <= E = b_p x_c_max``.
- eqs. 14/15: ``dQ/dt = e / tau`` for growing flow, ``e / tau_down`` for falling flow.
- eq. 17: for falling flow the pilot valve takes ``S_a dx_a/dt`` from the line, so the line
  flow leads the pump flow: ``q_l = Q + tau_z dQ/dt``.
- eq. 8: the displacement stops, ``0 <= Q <= Q_max``.
- eqs. 9/13: the line pressure over the load orifice, ``C_l dP/dt = q_l - k (P_l - P_u)^(1/gamma)``
  with ``k = mu_u xi_u`` the load conductance.

All functions are pure and take SI values (flows in m^3/s, pressures in Pa). Each discrete step
holds its inputs over the step (zero-order hold), and the solutions are exact for held inputs,
so the model is valid for any update period.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

from .schema import Model

#: The smallest share of their demand starving compensated loads are taken to get: a margin
#: near zero must not blow a demand estimate up.
FED_MIN = 0.2


def fed_share(dp: float, dp_c: float) -> float:
    """The share of their demand compensated loads take at margin ``dp`` [Pa]: all of it
    at or above the compensators' setting ``dp_c``, an orifice's ``sqrt(dp / dp_c)`` below
    (at least :data:`FED_MIN`); 1 without compensators (``dp_c = 0``)."""
    if dp_c <= 0.0 or dp >= dp_c:
        return 1.0
    return max(math.sqrt(max(dp, 0.0) / dp_c), FED_MIN)


@dataclass(frozen=True)
class PumpModel:
    """Current-to-flow dynamics of the embedded model (see the module docstring).

    Attributes are the ``model`` group of the configuration; ``E`` is ``flow_error_max``.
    """

    gain: float
    I_nominal: float
    Q_bar: float
    Q_max: float
    tau: float
    tau_down: float
    tau_z: float
    E: float

    @classmethod
    def from_config(cls, m: Model) -> PumpModel:
        return cls(m.gain, m.I_nominal, m.Q_bar, m.Q_max, m.tau, m.tau_down, m.tau_z,
                   m.flow_error_max)

    def flow_command(self, current: float) -> float:
        """Eq. 11: the flow-equivalent command ``v`` [m^3/s] of an absolute current [A]."""
        return self.Q_bar + self.gain * (current - self.I_nominal)

    def current(self, v: float) -> float:
        """Inverse of :meth:`flow_command`: absolute current [A] of a flow command [m^3/s]."""
        return self.I_nominal + (v - self.Q_bar) / self.gain

    def branch_tau(self, error: float) -> float:
        """Time constant of the branch that the spool error selects (eq. 14 or eq. 15)."""
        return self.tau if error >= 0.0 else self.tau_down

    def step(self, Q: float, target: float, dt: float) -> tuple[float, bool]:
        """Advance the pump flow by ``dt`` with ``target = v + d`` held.

        Returns ``(Q_next, sensitive)``; ``sensitive`` is False when the step does not depend
        on the target (spool at its stroke limit for the whole step, or plate at an end stop):
        a disturbance is then unobservable and its estimate must not integrate.
        """
        e = target - Q
        tau = self.tau if e >= 0.0 else self.tau_down
        E = self.E
        ae = abs(e)
        sensitive = True
        if ae > E:
            # Spool at x_c_max: the stroke moves at its largest rate until |e| = E (eq. 10).
            t_sat = (ae - E) * tau / E
            if t_sat >= dt:
                Q_next = Q + math.copysign(E * dt / tau, e)
                sensitive = False
            else:
                Q_next = target - math.copysign(E * math.exp(-(dt - t_sat) / tau), e)
        else:
            Q_next = target - e * math.exp(-dt / tau)
        # Beyond a displacement stop the target has no effect (eq. 8).
        if Q_next >= self.Q_max:
            return self.Q_max, False
        if Q_next <= 0.0:
            return 0.0, False
        return Q_next, sensitive

    def line_flow(self, Q: float, target: float) -> float:
        """Net flow into the line, eq. 17: ``q_l = Q + tau_z dQ/dt`` while the flow falls."""
        e = target - Q
        if e >= 0.0 or Q <= 0.0:
            return Q
        return Q + self.tau_z * max(e, -self.E) / self.tau_down

    def inverse(self, Q: float, Q_next: float, dt: float) -> float:
        """Target that moves the flow from ``Q`` to ``Q_next`` in ``dt`` (linear region)."""
        a = math.exp(-dt / (self.tau if Q_next >= Q else self.tau_down))
        return (Q_next - a * Q) / (1.0 - a)

    def steady_flow(self, current: float) -> float:
        """Steady-state pump flow of a held current (eq. 11 inside the end stops) [m^3/s]."""
        return min(max(self.flow_command(current), 0.0), self.Q_max)


def trajectory_step(Q_r: float, r: float, k_r: float, limit: float, tau: float,
                    dt: float) -> tuple[float, float]:
    """One step of the reference generator: the nominal eq. 19 model under its own law.

    The law ``v_r = Q_r + k_r (r - Q_r)`` is bounded to ``|v_r - Q_r| <= limit`` so that the
    trajectory stays feasible for the spool stroke limit; the same (growing-flow) dynamics
    serve both directions, so falling steps are as smooth as rising ones.

    Returns ``(Q_r_next, v_r)`` in m^3/s.
    """
    v_r = Q_r + k_r * (r - Q_r)
    v_r = min(max(v_r, Q_r - limit), Q_r + limit)
    return v_r - (v_r - Q_r) * math.exp(-dt / tau), v_r


@dataclass(frozen=True)
class LineModel:
    """Line pressure over the load orifice, eqs. 9 and 13, as a margin ``dp = P_l - P_u``.

    ``C_l`` is the line capacitance ``V_l/beta`` [m^3/Pa] and ``gamma_u`` the load law
    exponent; the load conductance ``k`` [m^3/(s Pa^(1/gamma_u))] is a disturbance state of
    the embedded model (it moves with the load aperture ``xi_u``).
    """

    C_l: float
    gamma_u: float

    @classmethod
    def from_config(cls, m: Model) -> LineModel:
        return cls(m.C_l, m.gamma_u)

    def steady_margin(self, q: float, k: float) -> float:
        """Margin [Pa] at which the load passes the flow ``q`` (eq. 9 at rest)."""
        return (max(q, 0.0) / k) ** self.gamma_u

    def flow(self, dp: float, k: float) -> float:
        """Load flow [m^3/s] at the margin ``dp`` [Pa]."""
        return k * max(dp, 0.0) ** (1.0 / self.gamma_u)

    def tau(self, dp: float, q: float) -> float:
        """Line time constant ``gamma_u C_l dp / q`` [s] of the linearised eq. 9."""
        return self.gamma_u * self.C_l * dp / max(q, 1.0e-9)

    def alpha(self, dp: float, q: float, dt: float) -> float:
        """Discrete pole ``exp(-dt/tau)`` of the line over one step."""
        return math.exp(-dt / max(self.tau(dp, q), 1.0e-9))

    def step(self, dp: float, q: float, k: float, dt: float) -> float:
        """Advance the margin by ``dt`` with the line inflow ``q`` held.

        An exponential integrator of the linearised line: exact at rest and stable for any
        ``dt``, as the line pole (2 to 20 ms over the aperture range) may be faster than the
        update period.
        """
        dp_ss = self.steady_margin(q, k)
        return dp_ss + (dp - dp_ss) * self.alpha(dp, q, dt)
