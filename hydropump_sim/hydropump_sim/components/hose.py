"""A hydraulic line or hose between ports ``a`` and ``b`` with the inertia, the friction and
the compliance of its oil column, as ``n`` lumped pi segments, so that a fast valve closure
shows water hammer (the Joukowsky rise ``rho c v0`` and the period ``4 L / c``).

Segment ``k`` (length ``l = L / n``, bore area ``A = pi d^2 / 4``) carries the flow ``q_k``
from node ``k - 1`` to node ``k`` (node 0 is port ``a``, node ``n`` is port ``b``)::

    rho l / A  dq_k/dt = P_{k-1} - P_k - dp_f(q_k)                 (momentum, the inertia)
    dP_j/dt = beta_eff / (A l) (q_j - q_{j+1})    j = 1 .. n-1     (laws.continuity)

The interior nodes hold the volume ``A l`` each; the two end half-volumes ``A l / 2`` go to
the port nodes (:meth:`Hose.volumes`) as the oil volume of the same capacitance,
``A l / 2 * beta / beta_eff`` (the node's continuity uses the circuit fluid's ``beta``), so
the ladder is uniform: pi segments.

Friction, quasi-steady, with ``mu = rho nu`` of the circuit's fluid and the Reynolds number
``Re = |q| d / (A nu)``:

- laminar (Hagen-Poiseuille) below ``Re = 2300``: ``dp_f = 128 mu l / (pi d^4) q``;
- turbulent smooth pipe (Blasius) above ``Re = 4000``:
  ``dp_f = f (l / d) rho / 2 v |v|``, ``f = 0.3164 Re^-0.25`` (Darcy; the Fanning
  ``0.079 Re^-0.25`` of Hopsan's hose times 4), ``v = q / A``;
- between 2300 and 4000 (the transition range) a smoothstep blend of the two drops, so the
  drop and its slope are continuous in ``q`` and the drop grows monotonically with the flow.

Signals: ``flow_a`` (into the hose at ``a``), ``flow_b`` (out of the hose at ``b``),
``velocity`` (mean velocity at ``a``, ``q_1 / A``) and ``loss``, the friction power
``sum dp_f(q_k) q_k`` (>= 0).

Defaults:

- ``n = 5``: a chain of ``n`` pi segments (inductance ``rho l / A``, capacitance
  ``A l / beta_eff``) held at one end (a pressure source) and closed at the other (the
  valve) has its modes at ``2 (c / l) sin(k pi / (4 n))``, ``k = 1, 3, 5, ...``, against
  ``k pi c / (2 L)`` for the continuous line. Its fundamental period is therefore
  ``x / sin(x)`` times ``4 L / c`` with ``x = pi / (4 n)``: 0.41 % long at ``n = 5``
  (1.2 % at 3, 0.64 % at 4). With both ends held or both closed (the half-wave, ``2 L / c``)
  ``x = pi / (2 n)``: 1.7 % at 5, 2.6 % at 4. The error depends on ``n`` only, not on
  ``L``, ``d`` or ``c``, and laminar friction (decay rate ``16 nu / d^2``, about 2/s for
  VG46 oil in a 20 mm bore, against ``pi c / (2 L)`` = 168/s for 10 m at ``c`` = 1070
  m/s) shifts it by far less, so ``n = 5`` keeps the fundamental of either end condition
  within 2 % for any hose, with ``2 n - 1 = 9`` states. More segments resolve the steep
  front of the wave (with few, the higher modes ring about the Joukowsky plateau); fewer
  are cheaper.
- ``beta_eff = 1e9`` Pa: Hopsan's hydraulic hose default. Oil and wall are in series:
  ``1 / beta_eff = 1 / beta_oil + 1 / beta_wall``, with ``beta_wall = E s / d`` for a thin
  wall of thickness ``s``. A steel tube (``E = 210`` GPa, ``d / s`` about 10) has
  ``beta_wall`` about 20 GPa and softens 1.5 GPa oil by some 7 %; a hose's elastomer wall,
  held only by its braid, swells far more per bar, and its effective modulus falls well
  below the oil's (Hopsan's 1e9 Pa against oil of 1.5 GPa and more). ``beta_eff = 0``
  takes the circuit fluid's ``beta``: a rigid steel pipe. ``beta_eff`` should not exceed
  the oil's own modulus (a wall only softens it).

The hose makes no pressure of its own at rest (no :meth:`~.base.Component.pressure_cap`),
but its water hammer rises above every source by ``rho c v`` (and with few segments their
ringing overshoots that plateau, up to about twice it after an abrupt closure): a circuit
with a fast valve on a long line needs a relief above that, as a real one does.
"""

from dataclasses import dataclass
import math

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec, StateSpec
from .laws import continuity

#: Reynolds numbers of the laminar-turbulent transition range (fully laminar below the
#: first, Blasius above the second).
RE_LAMINAR = 2300.0
RE_TURBULENT = 4000.0
#: Blasius' Darcy friction factor ``f = BLASIUS Re^-0.25`` (smooth pipe, Re 4e3 .. 1e5).
BLASIUS = 0.3164


@jit
def friction(q, r_lam, k_turb, re_per_q):
    """Friction drop [Pa] of a segment at flow ``q`` [m^3/s]: ``r_lam q`` (Hagen-Poiseuille)
    below Re 2300, ``k_turb Re^-0.25 q |q|`` (Blasius) above 4000, a smoothstep blend of the
    two drops between."""
    dp = r_lam * q
    re = abs(q) * re_per_q
    if re > RE_LAMINAR:
        z = min((re - RE_LAMINAR) / (RE_TURBULENT - RE_LAMINAR), 1.0)
        w = z * z * (3.0 - 2.0 * z)
        dp += w * (k_turb * re ** -0.25 * q * abs(q) - dp)
    return dp


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    a, b = int(p[0]), int(p[1])
    n = int(p[2])
    inertia, r_lam, k_turb, re_per_q = p[3], p[4], p[5], p[6]
    volume, beta, alpha, p_atm, floor, dp_floor, area = (p[7], p[8], p[9], p[10], p[11],
                                                         p[12], p[13])
    loss = 0.0
    stored = 0.0
    p_up = P[a]
    for k in range(n):
        # segment k runs from node k to node k + 1 (node n is port b)
        p_dn = P[b] if k == n - 1 else x[n + k]
        dp_f = friction(x[k], r_lam, k_turb, re_per_q)
        dx[k] = (p_up - p_dn - dp_f) / inertia
        loss += dp_f * x[k]
        stored += inertia * x[k] * dx[k]
        p_up = p_dn
    for j in range(1, n):
        i = n + j - 1
        dx[i] = continuity(x[i], x[j - 1] - x[j], volume, beta, alpha, p_atm, floor, dp_floor)
        stored += x[i] * (x[j - 1] - x[j])
    Q[a] -= x[0]
    Q[b] += x[n - 1]
    y[0] = x[0]
    y[1] = x[n - 1]
    y[2] = x[0] / area
    y[3] = loss
    y[4] = stored


@dataclass(frozen=True)
class HoseParams:
    L: float = spec('m', 'length of the line', 1.0e-2, 1.0e3)
    d: float = spec('m', 'inner (bore) diameter', 1.0e-3, 0.5)
    n: int = spec('-', 'number of lumped pi segments (5 keeps the fundamental period within '
                  '2 % for any end condition; see the module)', 1, 100, default=5)
    beta_eff: float = spec('Pa', 'effective bulk modulus of oil and wall; 0 = the circuit '
                           "fluid's beta (a rigid steel pipe). Default: Hopsan's hose default",
                           0.0, 3.0e9, default=1.0e9)


class Hose(Component):
    kind = 'hose'
    LOSS_GROUP = 'lines'
    doc = 'hydraulic line or hose: n lumped pi segments with inertia, friction, compliance'
    Params = HoseParams
    PORTS = (PortSpec('a', 'end a'), PortSpec('b', 'end b'))
    SIGNALS = (SignalSpec('flow_a', 'm^3/s', 'flow into the hose at a'),
               SignalSpec('flow_b', 'm^3/s', 'flow out of the hose at b'),
               SignalSpec('velocity', 'm/s', 'mean fluid velocity at a (+ from a to b)'),
               SignalSpec('loss', 'W', 'friction power'),
               SignalSpec('stored', 'W', "rate of the oil's kinetic energy and of the power "
                          'into its inner volumes'))
    kernel = kernel

    @property
    def area(self) -> float:
        return math.pi * self.params.d ** 2 / 4.0

    @property
    def beta(self) -> float:
        """The effective bulk modulus [Pa] the hose's oil column has."""
        return self.params.beta_eff if self.params.beta_eff > 0.0 else self.fluid.beta

    def states(self):
        """The flow of each segment (typical magnitude: 1 m/s through the bore), then the
        pressure of each interior node."""
        n = self.params.n
        return (tuple(StateSpec(f'q{k}', 'm^3/s', self.area) for k in range(1, n + 1))
                + tuple(StateSpec(f'p{j}', 'Pa', 1.0e6) for j in range(1, n)))

    def pack(self):
        r, fl = self.params, self.fluid
        area = self.area
        seg = r.L / r.n
        mu = fl.rho * fl.nu
        return [float(r.n), fl.rho * seg / area,
                128.0 * mu * seg / (math.pi * r.d ** 4),
                BLASIUS * seg / r.d * fl.rho / (2.0 * area * area),
                r.d / (area * fl.nu),
                area * seg, self.beta, fl.alpha_air, fl.p_atm,
                1.0 if fl.pressure_floor else 0.0, fl.dp_floor, area]

    def volumes(self):
        """The end half-segments, as the oil volume of the same capacitance at the port
        node (whose continuity uses the fluid's ``beta``)."""
        r = self.params
        half = self.area * r.L / (2.0 * r.n) * self.fluid.beta / self.beta
        return {'a': half, 'b': half}

    def initial_state(self, P, u):
        r = self.params
        frac = np.arange(1, r.n) / r.n
        return np.concatenate([np.zeros(r.n), P['a'] + (P['b'] - P['a']) * frac])
