"""Hydraulic motor: displacement ``D`` per radian between ports ``a`` and ``b``, an inertia
and a load torque (an input), viscous and Coulomb friction, laminar leakage:

    J dw/dt = D (P_a - P_b) - T - c w - T_c tanh(w / w_eps),    dphi/dt = w
    Q = D w + G_leak (P_a - P_b)   (from a to b)

Chamber and hose volumes are lumped into the port nodes (``V_a``, ``V_b``). The shaft angle
``phi`` is an integrating state (a swing's heading), published as the joint's position.
With both ports blocked a motor under a load torque creeps at its leakage over its
displacement: a swing holds with its brake valves and its parking brake, not its valve.
"""

from dataclasses import dataclass
import math

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, JointSpec, PortSpec, SignalSpec, StateSpec


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    D, J, c, T_c, w_eps, G = p[2], p[3], p[4], p[5], p[6], p[7]
    w = x[0]
    P_b = P[b] if b >= 0 else 0.0
    dp = P[a] - P_b
    T_f = c * w + T_c * math.tanh(w / w_eps)
    dx[0] = (D * dp - u[0] - T_f) / J
    dx[1] = w
    q = D * w + G * dp
    Q[a] -= q
    if b >= 0:
        Q[b] += q
    y[0] = w
    y[1] = P[a]
    y[2] = q
    y[3] = u[0]
    y[4] = x[1]
    y[5] = P_b
    y[6] = T_f * w + G * dp * dp
    y[7] = u[0] * w
    y[8] = w * (D * dp - u[0] - T_f)


@dataclass(frozen=True)
class MotorParams:
    D: float = spec('m^3/rad', 'displacement per radian', 1.0e-9, 1.0e-2)
    J: float = spec('kg m^2', 'inertia of motor and load', 1.0e-6, 1.0e4)
    V_a: float = spec('m^3', 'inlet volume (chamber and hose)', 1.0e-8, 1.0)
    V_b: float = spec('m^3', 'outlet volume', 0.0, 1.0, default=0.0)
    c: float = spec('N m s/rad', 'viscous friction', 0.0, 1.0e5, default=0.01)
    T_coul: float = spec('N m', 'Coulomb friction', 0.0, 1.0e5, default=0.0)
    w_eps: float = spec('rad/s', 'tanh smoothing speed of the Coulomb term', 1.0e-4, 10.0,
                        default=0.1)
    G_leak: float = spec('m^3/(s Pa)', 'laminar leakage a -> b', 0.0, 1.0e-9, default=0.0)
    torque: float = spec('N m', 'load torque (an input)', -1.0e6, 1.0e6, default=0.0)


class Motor(Component):
    kind = 'motor'
    LOSS_GROUP = 'actuators'
    doc = 'hydraulic motor: displacement, inertia, friction, leakage, a load torque'
    Params = MotorParams
    PORTS = (PortSpec('a', 'inlet'), PortSpec('b', 'outlet', optional=True))
    INPUTS = (InputSpec('torque', 'N m', 'load torque', -1.0e6, 1.0e6, 'torque'),)
    SIGNALS = (SignalSpec('speed', 'rad/s', 'shaft speed'),
               SignalSpec('pressure', 'Pa', 'inlet pressure'),
               SignalSpec('flow', 'm^3/s', 'flow through the motor'),
               SignalSpec('torque', 'N m', 'load torque'),
               SignalSpec('angle', 'rad', 'shaft angle'),
               SignalSpec('pressure_b', 'Pa', 'outlet pressure'),
               SignalSpec('loss', 'W', 'power dissipated: friction and leakage'),
               SignalSpec('work', 'W', 'power delivered to the load, torque times speed'),
               SignalSpec('stored', 'W', 'rate of kinetic energy'))
    kernel = kernel
    PASSAGE = False
    ROLES = frozenset({'actuator'})
    JOINTS = (JointSpec('', 'angle', 'speed'),)

    def pressure_cap(self, u):
        """The load torque over the displacement."""
        return abs(u['torque']) / self.params.D

    def states(self):
        return (StateSpec('speed', 'rad/s', 100.0),
                StateSpec('angle', 'rad', 2.0 * math.pi, integrating=True))

    def pack(self):
        r = self.params
        return [r.D, r.J, r.c, r.T_coul, r.w_eps, r.G_leak]

    def volumes(self):
        r = self.params
        return {'a': r.V_a, 'b': r.V_b} if r.V_b > 0.0 else {'a': r.V_a}

    def pressure_guess(self, u):
        return {'a': max(u['torque'], 0.0) / self.params.D}

    def initial_state(self, P, u):
        return np.array([0.0, 0.0])
