"""The pump with the classic hydromechanical load-sensing compensator instead of the
solenoid and the feedback spring: a spool of area ``A_ls`` between the line pressure and
the load-sensing pressure plus a spring set to the margin meters the actuator, so the plate
moves until ``P_l - P_LS`` equals the margin (an integral action: no feedback of the plate
position).

The equations are the pump's (:func:`~.pump.pump_equations`, eqs. 3-8) with the spool of
eq. 1 driven by the pressure balance instead of the solenoid,

    m_c dv_c/dt = A_ls (margin - (P_l - P_LS)) - K_ls x_c - c_c v_c (+ end stops),

and no feedback spring (``K_a = 0`` in eqs. 1 and 6). Ports ``out`` (the line) and ``ls``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..jitcache import jit
from ..params import Params, params_from_dict
from ..schema import build, spec
from . import pump
from .base import Component, InputSpec, PortSpec, SignalSpec


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    out, ls = int(p[0]), int(p[1])
    margin = p[2]
    q = p[3:3 + pump.N_P]
    over, n = pump.cutoff(x, dx, P[out], p[3 + pump.N_P:])
    error = margin - (P[out] - P[ls]) - over
    q_l = pump.pump_equations(t, x[:n], dx[:n], n - 1, P[out], error, u[0], q, y)
    Q[out] += q_l
    y[pump.Y_SUPPLY] = P[out] * q_l
    y[pump.Y_IS] = P[out] - P[ls]


@dataclass(frozen=True)
class LsSpool:
    margin: float = spec('Pa', 'margin P_l - P_LS the compensator holds', 1.0e5, 1.0e7)
    A_ls: float = spec('m^2', 'compensator spool area', 1.0e-7, 1.0e-3, default=2.0e-5)
    K_ls: float = spec('N/m', 'compensator spool spring stiffness', 10.0, 1.0e7, default=3.0e3)


@dataclass(frozen=True)
class LsPumpSetup:
    plant: Params
    spool: LsSpool
    cutoff: pump.Cutoff = pump.Cutoff()


class LsPump(Component):
    kind = 'ls_pump'
    doc = 'the pump with a hydromechanical load-sensing compensator (no solenoid)'
    PORTS = (PortSpec('out', 'pump outlet: the line'),
             PortSpec('ls', 'load-sensing pressure', sense=True))
    INPUTS = (InputSpec('shaft_speed', 'Hz', 'shaft frequency', 1.0, 100.0, 'f_p'),)
    SIGNALS = (SignalSpec('margin', 'Pa', 'P_l - P_LS'),) + pump.Pump.SIGNALS[1:]
    kernel = kernel
    ROLES = frozenset({'pump'})
    MEASURES = {k: v for k, v in pump.Pump.MEASURES.items() if k != 'solenoid_current'}
    PLANT_INPUTS = True
    PLANT_PARAMS = True
    P_OFFSET = 3  # the ports out and ls, the margin

    @classmethod
    def build_params(cls, values: Mapping[str, Any], source: str | None = None):
        values, cut = pump.split_cutoff(values, source)
        plant = {k: v for k, v in values.items() if not k.startswith('ls.')}
        own = {k[3:]: v for k, v in values.items() if k.startswith('ls.')}
        return LsPumpSetup(params_from_dict(plant, source), build(LsSpool, own, source), cut)

    @classmethod
    def param_specs(cls):
        from ..params import iter_specs
        from ..schema import specs_of
        return {**{s.name: s for s in iter_specs()},
                **{f'ls.{s.name}': s for s in specs_of(LsSpool)},
                **{f'cutoff.{s.name}': s for s in specs_of(pump.Cutoff)}}

    def states(self):
        plant = self.params.plant.replace({'input.tau_s': 0.0})
        return pump.Pump(self.name, pump.PumpSetup(plant, 'fine', self.params.cutoff),
                         {}).states()

    def pack(self):
        sp = self.params.spool
        q = pump.pack(self.params.plant)
        q[pump.P_KA] = 0.0
        q[pump.P_PHI] = sp.A_ls
        q[pump.P_KC] = sp.K_ls
        q[pump.P_DITHA] = 0.0
        q[pump.P_TAUS] = 0.0
        cut = self.params.cutoff
        return [sp.margin] + list(q) + [cut.p_set, 2.0 * sp.margin / cut.band, cut.lead]

    def pressure_cap(self, u):
        cut = self.params.cutoff
        return cut.p_set + cut.band if cut.p_set > 0.0 else None

    def input_default(self, spec):
        return self.params.plant.pump.f_p

    def initial_state(self, P, u):
        """At rest at mid stroke, the actuator holding the plate (eq. 6 with ``K_a = 0``)."""
        plant = self.params.plant
        P_l = P['out']
        P_a = plant.actuator.P_a_bar - (P_l - plant.line.P_l_bar) * plant.plate.S_d \
            / plant.actuator.S_a
        P_a = min(max(P_a, plant.fluid.P_T), max(P_l, plant.fluid.P_T))
        return np.array([0.0, 0.0, 0.0, 0.0, P_a]
                        + [P_l] * len(pump.cutoff_state(self.params.cutoff)))
