"""Hydraulic cylinder, double-acting (or single-acting with ``A_b = 0`` or its port ``b``
left open to the atmosphere): a mass pushed by the cap-side pressure on ``A_a`` against the
rod-side pressure on ``A_b``, an external force (an input), friction, end cushions and end
stops at 0 and the stroke ``L``:

    m dv/dt = P_a A_a - P_b A_b - F - F_f(v) - F_cush(x, v) + F_stop,     dx/dt = v
    F_f     = c v + (F_coul + (F_stat - F_coul) exp(-(v/v_s)^2)) tanh(v / v_eps)   (Stribeck)
    Q_a = A_a v + G_int (P_a - P_b)  (taken from port a),
    Q_b = A_b v + G_int (P_a - P_b)  (delivered into port b)

Each chamber is part of its port's node: its volume is the dead volume (chamber end, ports
and hose) plus the swept one, ``V_dead_a + A_a x`` and ``V_dead_b + A_b (L - x)``, so the
load's oil spring stiffens toward the ends, as a real cylinder's does.

An end cushion of length ``l_cush`` throttles the outflow of the chamber that a piston
closing on its end is emptying, through the cushion's throttle of area ``A_cush``: modelled
as the force its pressure makes, ``F_cush = A rho/2 (A v / (C_d A_cush))^2`` ramped in over
the cushion's length (the cushion chamber's pressure itself is not in the port's). Its
work and the friction's are the cylinder's ``loss``.

Defaults: a piston seal's internal leakage (0.01 L/min at 100 bar; Hopsan's cylinder takes
1e-11, a worn seal); Stribeck friction of a few hundred newtons, as for a 63-100 mm bore
cylinder (breakaway above sliding); end stops as stiff as the stepper takes.
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
def cushion(pen, l_c, A, v, k_c):
    """Force of an end cushion at penetration ``pen`` into it (0 outside), against ``v``."""
    if l_c <= 0.0 or pen <= 0.0:
        return 0.0
    ramp = min(pen / l_c, 1.0)
    return k_c * A * A * A * v * abs(v) * ramp


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    A_a, A_b, m, c, F_c, v_eps, L, k_stop, c_stop = (p[2], p[3], p[4], p[5], p[6], p[7],
                                                     p[8], p[9], p[10])
    F_s, v_s, G, l_c, k_c = p[11], p[12], p[13], p[14], p[15]
    pos = x[0]
    v = x[1]
    P_b = P[b] if b >= 0 else 0.0
    F_f = c * v + (F_c + (F_s - F_c) * math.exp(-(v / v_s) ** 2)) * math.tanh(v / v_eps)
    # The cushion of the end the piston is closing on, on the area it is emptying.
    F_cu = 0.0
    if v > 0.0:
        F_cu = cushion(pos - (L - l_c), l_c, A_b if A_b > 0.0 else A_a, v, k_c)
    elif v < 0.0:
        F_cu = cushion(l_c - pos, l_c, A_a, v, k_c)
    F_stop = stop_force(pos - 0.5 * L, v, 0.5 * L, k_stop, c_stop)
    F = P[a] * A_a - P_b * A_b - u[0] - F_f - F_cu + F_stop
    dx[0] = v
    dx[1] = F / m
    q_i = G * (P[a] - P_b)
    xs = min(max(pos, 0.0), L)
    Q[a] -= A_a * v + q_i
    V[a] += A_a * xs
    if b >= 0:
        Q[b] += A_b * v + q_i
        V[b] += A_b * (L - xs)
    y[0] = pos
    y[1] = v
    y[2] = P[a]
    y[3] = A_a * v
    y[4] = u[0]
    y[5] = P_b
    y[6] = (F_f + F_cu) * v + q_i * (P[a] - P_b)
    y[7] = u[0] * v
    # Kinetic energy, and what the end stops take (their springs and dampers).
    y[8] = v * F - F_stop * v


@dataclass(frozen=True)
class CylinderParams:
    A_a: float = spec('m^2', 'cap-side (piston) area', 1.0e-6, 1.0)
    m: float = spec('kg', 'moving mass (piston, rod, load)', 1.0e-3, 1.0e6)
    stroke: float = spec('m', 'stroke', 1.0e-3, 20.0)
    V_a: float = spec('m^3', 'cap-side dead volume (chamber at x = 0, ports and hose)', 1.0e-8,
                      1.0)
    A_b: float = spec('m^2', 'rod-side (annulus) area; 0 = single-acting', 0.0, 1.0, default=0.0)
    V_b: float = spec('m^3', 'rod-side dead volume (chamber at full stroke, ports and hose)',
                      0.0, 1.0, default=0.0)
    c: float = spec('N s/m', 'viscous friction', 0.0, 1.0e8, default=1.0e3)
    F_coul: float = spec('N', 'Coulomb (sliding) friction', 0.0, 1.0e6, default=0.0)
    F_stat: float = spec('N', 'breakaway (static) friction, at least F_coul; 0 = F_coul', 0.0,
                         1.0e6, default=0.0)
    v_s: float = spec('m/s', 'Stribeck velocity: breakaway falls to sliding over it', 1.0e-4,
                      1.0, default=0.01)
    v_eps: float = spec('m/s', 'tanh smoothing velocity of the friction at rest', 1.0e-6, 1.0,
                        default=1.0e-3)
    G_int: float = spec('m^3/(s Pa)', "internal leakage across the piston (a seal's: 0.01 "
                        'L/min at 100 bar)', 0.0, 1.0e-9, default=1.7e-14)
    l_cush: float = spec('m', 'length of each end cushion; 0 = none', 0.0, 1.0, default=0.0)
    A_cush: float = spec('m^2', "area of a cushion's throttle", 1.0e-9, 1.0e-2, default=5.0e-6)
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
        if self.F_stat and self.F_stat < self.F_coul:
            out.append(f'F_stat = {fmt(self.F_stat)} N is below F_coul = {fmt(self.F_coul)} '
                       'N: breakaway is at least the sliding friction')
        if 2.0 * self.l_cush > self.stroke:
            out.append(f'l_cush = {fmt(self.l_cush)} m: two cushions longer than the stroke')
        return out


class Cylinder(Component):
    kind = 'cylinder'
    LOSS_GROUP = 'actuators'
    doc = 'cylinder: two chambers, Stribeck friction, leakage, cushions, end stops, a force'
    Params = CylinderParams
    PORTS = (PortSpec('a', 'cap side'),
             PortSpec('b', 'rod side (open to the atmosphere if not connected)', optional=True))
    INPUTS = (InputSpec('force', 'N', 'external force against extension', -1.0e7, 1.0e7,
                        'force'),)
    SIGNALS = (SignalSpec('position', 'm', 'piston position'),
               SignalSpec('velocity', 'm/s', 'piston velocity (+ extends)'),
               SignalSpec('pressure', 'Pa', 'cap-side pressure'),
               SignalSpec('flow', 'm^3/s', 'flow swept by the cap side, A_a v'),
               SignalSpec('force', 'N', 'external force'),
               SignalSpec('pressure_b', 'Pa', 'rod-side pressure'),
               SignalSpec('loss', 'W', 'power dissipated: friction, cushions, leakage'),
               SignalSpec('work', 'W', 'power delivered to the load, force times velocity'),
               SignalSpec('stored', 'W', "rate of kinetic energy, and the end stops' work"))
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
        return (StateSpec('position', 'm', r.stroke, integrating=True,
                          stops=(0.0, r.stroke)),
                StateSpec('velocity', 'm/s', 0.1))

    def pack(self):
        r = self.params
        F_stat = max(r.F_stat, r.F_coul)
        k_c = 0.5 * self.fluid.rho / (0.7 * r.A_cush) ** 2
        return [r.A_a, r.A_b, r.m, r.c, r.F_coul, r.v_eps, r.stroke, r.k_stop, r.c_stop,
                F_stat, r.v_s, r.G_int, r.l_cush, k_c]

    def volumes(self):
        r = self.params
        return {'a': r.V_a, 'b': r.V_b} if r.V_b > 0.0 else {'a': r.V_a}

    def pressure_guess(self, u):
        r = self.params
        out = {'a': max(u['force'], 0.0) / r.A_a}
        if r.A_b > 0.0:
            out['b'] = max(-u['force'], 0.0) / r.A_b
        return out

    def initial_state(self, P, u):
        return np.array([self.params.x0, 0.0])
