"""A gas-charged bladder accumulator on one port ``port``: a nitrogen bladder precharged to
``p0`` (gauge) at its full volume ``V0``, compressed by the oil volume ``V_oil`` it has
taken through an inlet restriction, with the anti-extrusion poppet that closes the port as
the empty bladder reaches it.

The gas law is polytropic in ABSOLUTE pressure::

    (p_gas + p_atm) V_gas^n = (p0 + p_atm) V0^n,      V_gas = V0 - V_oil

The inlet (the port's bore and the poppet seat) is a turbulent orifice with the laminar
regularisation of :func:`~.laws.signed_root` near zero drop, both ways::

    q = C_d A_in sqrt(2/rho) signed_root(P_port - p_gas, dp_cr)          (q into it)
    q *= clip(V_oil / (travel V0), 0, 1)   when q < 0 (oil leaving)
    dV_oil/dt = q

An empty bladder (``V_oil = 0``) holds the gas at ``p0``: below the precharge no oil enters
(the port's pressure is below the gas's), and none leaves, for the poppet closes over the
last ``travel V0`` of oil: the outflow falls with the oil volume to zero, so ``V_oil``
never goes below zero. Nothing is sealed behind the poppet (no oil is left there), so it
needs no leakage conductance. ``loss`` is the power ``(P_port - p_gas) q`` (>= 0) the inlet
dissipates.

Defaults:

- ``n = 1.2``: Hopsan's bladder accumulator default (``kappa``). The exponent lies between
  the isothermal 1.0 (slow cycles: the gas keeps the shell's temperature) and the adiabatic
  1.4 of nitrogen (cycles much shorter than the bladder's thermal time constant, of the order
  of seconds to a minute); a machine's working cycles, of seconds, sit between the two.
- ``A_in = 1e-4`` m^2 (an 11 mm bore, a 1 L accumulator's port): 59 L/min at 1 bar, the
  flow Hopsan's bladder accumulator's default inlet conductance ``Kca = 1e-8 m^3/(s Pa)``
  passes there. A turbulent law rather than Hopsan's laminar one: the inlet is a short
  port and a poppet seat, where the drop goes with the square of the flow.
- ``C_d = 0.65``: as the circuit's orifices (a sharp-edged orifice; Hopsan's ``C_q`` 0.67).
- ``dp_cr = 1e4`` Pa: as the check valve's seat; at a 1 bar drop the regularisation changes
  the flow by 0.25 %, and it keeps the flow's slope finite at zero drop.
- ``travel = 0.005``: the poppet closes over the last 0.5 % of the gas volume (5 cm^3 of a
  1 L accumulator: a poppet of some 25 mm pushed over a few mm by the bladder).
- ``V_oil0 = 0``: the accumulator starts empty, at its precharge.
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import fmt, spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .laws import clip01, signed_root
from .orifice import coefficient

#: The least gas volume, as a fraction of ``V0``, the gas law is evaluated at (a guard
#: against a state pushed through the bladder's bottom by a step: a pressure ratio of
#: 1000^n, far beyond any accumulator's).
V_GAS_MIN = 1.0e-3


@jit
def gas_pressure(v_oil, p0, V0, n, p_atm):
    """Gas pressure [Pa gauge] at oil volume ``v_oil``: polytropic in absolute pressure."""
    v_gas = max(V0 - v_oil, V_GAS_MIN * V0)
    return (p0 + p_atm) * (V0 / v_gas) ** n - p_atm


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a = int(p[0])
    p0, V0, n, p_atm, k, dp_cr, v_close = p[1], p[2], p[3], p[4], p[5], p[6], p[7]
    v_oil = x[0]
    p_gas = gas_pressure(v_oil, p0, V0, n, p_atm)
    dp = P[a] - p_gas
    q = k * signed_root(dp, dp_cr)
    if q < 0.0:
        q *= clip01(v_oil / v_close)
    dx[0] = q
    Q[a] -= q
    y[0] = p_gas
    y[1] = v_oil
    y[2] = q
    y[3] = dp * q
    y[4] = p_gas * q


@dataclass(frozen=True)
class AccumulatorParams:
    p0: float = spec('Pa', 'gas precharge pressure (gauge) at the full gas volume V0', 0.0,
                     1.0e8)
    V0: float = spec('m^3', 'gas volume at the precharge (the nominal size)', 1.0e-6, 1.0)
    n: float = spec('-', 'polytropic exponent: 1.0 isothermal .. 1.4 adiabatic (default: '
                    "Hopsan's bladder accumulator's)", 1.0, 1.4, default=1.2)
    A_in: float = spec('m^2', 'inlet (port and poppet seat) flow area', 1.0e-8, 1.0e-2,
                       default=1.0e-4)
    C_d: float = spec('-', 'discharge coefficient of the inlet', 0.1, 1.0, default=0.65)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition of the inlet', 0.0, 1.0e6,
                        default=1.0e4)
    travel: float = spec('-', 'fraction of V0 over which the poppet closes as the bladder '
                         'empties', 1.0e-4, 0.1, default=0.005)
    V_oil0: float = spec('m^3', 'initial oil volume (the start of the steady-state search)',
                         0.0, 1.0, default=0.0)

    def cross_checks(self):
        if self.V_oil0 >= self.V0:
            return [f'V_oil0 = {fmt(self.V_oil0)} m^3 must be below the gas volume V0 = '
                    f'{fmt(self.V0)} m^3']
        return []


class Accumulator(Component):
    kind = 'accumulator'
    LOSS_GROUP = 'lines'
    doc = 'gas-charged bladder accumulator: polytropic gas, inlet restriction, poppet'
    Params = AccumulatorParams
    PORTS = (PortSpec('port', 'oil port'),)
    SIGNALS = (SignalSpec('pressure', 'Pa', 'gas pressure (gauge)'),
               SignalSpec('volume', 'm^3', 'oil volume in the accumulator'),
               SignalSpec('flow', 'm^3/s', 'flow into the accumulator'),
               SignalSpec('loss', 'W', 'power dissipated in the inlet'),
               SignalSpec('stored', 'W', 'power into the gas, p_gas q'))
    kernel = kernel

    def precharge(self) -> float:
        """The gas precharge ``p0`` [Pa gauge]."""
        return self.params.p0

    def cap_checks(self, cap: float) -> list[str]:
        p0 = self.params.p0
        if p0 >= cap:
            return [f'{self.name}: precharged at {p0 / 1e5:.4g} bar, at or above the highest '
                    f'pressure the circuit makes ({cap / 1e5:.4g} bar: its reliefs and '
                    'cut-offs): it would never take oil']
        return []

    def gas_pressure(self, v_oil: float) -> float:
        """Gas pressure [Pa gauge] at an oil volume [m^3]."""
        r = self.params
        return float(gas_pressure(v_oil, r.p0, r.V0, r.n, self.fluid.p_atm))

    def pressure_cap(self, u):
        """A charged accumulator (``V_oil0 > 0``) can push its node up to its starting gas
        pressure; an empty one delivers nothing (and later holds no more than what charged
        it)."""
        r = self.params
        return self.gas_pressure(r.V_oil0) if r.V_oil0 > 0.0 else None

    def states(self):
        return (StateSpec('V_oil', 'm^3', self.params.V0),)

    def pack(self):
        r = self.params
        return [r.p0, r.V0, r.n, self.fluid.p_atm, coefficient(r.C_d, r.A_in, self.fluid.rho),
                r.dp_cr, r.travel * r.V0]

    def initial_state(self, P, u):
        return np.array([self.params.V_oil0])
