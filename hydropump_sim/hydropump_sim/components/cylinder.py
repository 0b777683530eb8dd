"""Hydraulic cylinder: a mass pushed by the cap-side pressure on ``A_a`` against the
rod-side pressure on ``A_b``, an external force (an input), viscous and Coulomb friction
and end stops at 0 and the stroke:

    m dv/dt = P_a A_a - P_b A_b - F - c v - F_c tanh(v / v_eps) + F_stop,    dx/dt = v
    Q_a = A_a v (taken from port a),   Q_b = A_b v (delivered into port b)

The chambers' compressibility is lumped into the port nodes as the constant volumes ``V_a``
and ``V_b`` (chamber at mid-stroke plus hose): the load's oil spring at mid-stroke, and a
continuity whose volumes do not move, so that the stored volume is ``sum V_i P_i / beta``.
The position is an integrating state: a steady state moves at a constant velocity, wherever
the piston is.
"""

from dataclasses import dataclass
import math

import numpy as np

from ..jitcache import jit
from ..schema import fmt, spec
from .base import Component, InputSpec, JointSpec, PortSpec, SignalSpec, StateSpec
from .laws import stop_force


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    A_a, A_b, m, c, F_c, v_eps, L, k_stop, c_stop = (p[2], p[3], p[4], p[5], p[6], p[7],
                                                     p[8], p[9], p[10])
    pos = x[0]
    v = x[1]
    P_b = P[b] if b >= 0 else 0.0
    F = (P[a] * A_a - P_b * A_b - u[0] - c * v - F_c * math.tanh(v / v_eps)
         + stop_force(pos - 0.5 * L, v, 0.5 * L, k_stop, c_stop))
    dx[0] = v
    dx[1] = F / m
    Q[a] -= A_a * v
    if b >= 0:
        Q[b] += A_b * v
    y[0] = pos
    y[1] = v
    y[2] = P[a]
    y[3] = A_a * v
    y[4] = u[0]


@dataclass(frozen=True)
class CylinderParams:
    A_a: float = spec('m^2', 'cap-side (piston) area', 1.0e-6, 1.0)
    m: float = spec('kg', 'moving mass (piston, rod, load)', 1.0e-3, 1.0e6)
    stroke: float = spec('m', 'stroke', 1.0e-3, 20.0)
    V_a: float = spec('m^3', 'cap-side volume (chamber at mid-stroke and hose)', 1.0e-8, 1.0)
    A_b: float = spec('m^2', 'rod-side (annulus) area', 0.0, 1.0, default=0.0)
    V_b: float = spec('m^3', 'rod-side volume (mid-stroke and hose)', 0.0, 1.0, default=0.0)
    c: float = spec('N s/m', 'viscous friction', 0.0, 1.0e8, default=1.0e3)
    F_coul: float = spec('N', 'Coulomb friction', 0.0, 1.0e6, default=0.0)
    v_eps: float = spec('m/s', 'tanh smoothing velocity of the Coulomb term', 1.0e-6, 1.0,
                        default=1.0e-3)
    x0: float = spec('m', 'initial position (0 = retracted)', 0.0, 20.0, default=0.0)
    k_stop: float = spec('N/m', 'end-stop stiffness', 0.0, 1.0e12, default=1.0e8)
    c_stop: float = spec('N s/m', 'end-stop damping', 0.0, 1.0e9, default=1.0e5)
    force: float = spec('N', 'external force against extension (an input)', -1.0e7, 1.0e7,
                        default=0.0)

    def cross_checks(self):
        out = []
        if self.x0 > self.stroke:
            out.append(f'x0 = {fmt(self.x0)} m is beyond the stroke {fmt(self.stroke)} m')
        if self.A_b > self.A_a:
            out.append(f'A_b = {fmt(self.A_b)} m^2 exceeds A_a = {fmt(self.A_a)} m^2')
        return out


class Cylinder(Component):
    kind = 'cylinder'
    doc = 'cylinder: mass, friction, end stops, an external force'
    Params = CylinderParams
    PORTS = (PortSpec('a', 'cap side'), PortSpec('b', 'rod side', optional=True))
    INPUTS = (InputSpec('force', 'N', 'external force against extension', -1.0e7, 1.0e7,
                        'force'),)
    SIGNALS = (SignalSpec('position', 'm', 'piston position'),
               SignalSpec('velocity', 'm/s', 'piston velocity (+ extends)'),
               SignalSpec('pressure', 'Pa', 'cap-side pressure'),
               SignalSpec('flow', 'm^3/s', 'flow taken by the cap side, A_a v'),
               SignalSpec('force', 'N', 'external force'))
    kernel = kernel
    PASSAGE = False
    ROLES = frozenset({'actuator'})
    JOINTS = (JointSpec('', 'position', 'velocity'),)

    def pressure_cap(self, u):
        """The load's force over the area it pushes on."""
        r = self.params
        f = u['force']
        return f / r.A_a if f >= 0.0 or r.A_b <= 0.0 else -f / r.A_b

    def states(self):
        r = self.params
        return (StateSpec('position', 'm', r.stroke, integrating=True),
                StateSpec('velocity', 'm/s', 0.1))

    def pack(self):
        r = self.params
        return [r.A_a, r.A_b, r.m, r.c, r.F_coul, r.v_eps, r.stroke, r.k_stop, r.c_stop]

    def volumes(self):
        r = self.params
        return {'a': r.V_a, 'b': r.V_b} if r.V_b > 0.0 else {'a': r.V_a}

    def pressure_guess(self, u):
        return {'a': max(u['force'], 0.0) / self.params.A_a}

    def initial_state(self, P, u):
        return np.array([self.params.x0, 0.0])
