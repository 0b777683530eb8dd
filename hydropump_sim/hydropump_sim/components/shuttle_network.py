"""Shuttle-valve network of load sensing: the highest of its input pressures reaches the
load-sensing line ``out`` (its volume ``V``, bled to ``tank``). Each input feeds the line
through its own seat, which opens only toward the line, as the balls of a shuttle cascade
do:

    Q_i = k_s sroot(P_in,i - P_ls)  for P_in,i > P_ls, else 0
    Q_bleed = k_b sroot(P_ls - P_tank)

``P_ls`` is then the highest input pressure, less the drop the bleed flow makes across its
seat; inputs below it are shut off; two equal inputs share the bleed flow (a ball in
balance), and when the highest input falls the line follows through the bleed. It falls to
tank pressure when every input is drained (every section idle). The bleed's default, a
0.3 mm orifice (0.2 L/min at 20 bar, 0.4 L/min at 100 bar), is the order of a load-sensing
line's bleed, which lets the line fall when a load does and damps it.
"""

from dataclasses import dataclass

from ..jitcache import jit
from ..schema import spec
from .base import Component, PortSpec, SignalSpec
from .laws import sroot
from .orifice import coefficient


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    out, tank, n = int(p[0]), int(p[1]), int(p[2])
    k, k_b, dp_cr = p[3 + n], p[4 + n], p[5 + n]
    total = 0.0
    loss = 0.0
    best = 0
    for i in range(n):
        j = int(p[3 + i])
        if P[j] > P[int(p[3 + best])]:
            best = i
        dp = P[j] - P[out]
        if dp > 0.0:
            q = k * sroot(dp, dp_cr)
            Q[j] -= q
            Q[out] += q
            total += q
            loss += q * dp
    q_b = 0.0
    if tank >= 0 and k_b > 0.0:
        q_b = k_b * sroot(P[out] - P[tank], dp_cr)
        Q[out] -= q_b
        Q[tank] += q_b
        loss += q_b * (P[out] - P[tank])
    y[0] = P[out]
    y[1] = best
    y[2] = total
    y[3] = q_b
    y[4] = loss


@dataclass(frozen=True)
class ShuttleParams:
    V: float = spec('m^3', 'volume of the load-sensing line', 1.0e-9, 1.0e-2)
    A: float = spec('m^2', 'flow area of a shuttle passage', 1.0e-10, 1.0e-3, default=3.0e-6)
    A_bleed: float = spec('m^2', 'area of the bleed orifice to tank; 0 = none', 0.0, 1.0e-4,
                          default=7.0e-8)
    C_d: float = spec('-', 'discharge coefficient', 0.1, 1.0, default=0.65)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=1.0e4)


class ShuttleNetwork(Component):
    kind = 'shuttle_network'
    LOSS_GROUP = 'signal'
    doc = 'shuttle valves: the highest load pressure to the load-sensing line, with a bleed'
    Params = ShuttleParams
    PORTS = (PortSpec('out', 'load-sensing line (P_LS)'),
             PortSpec('tank', 'bleed outlet (may be left out only with A_bleed: 0)',
                      optional=True),
             PortSpec('in', 'the sensed load nodes', many=True))
    SIGNALS = (SignalSpec('pressure', 'Pa', 'load-sensing pressure P_LS'),
               SignalSpec('selected', '-', 'index of the highest input'),
               SignalSpec('flow', 'm^3/s', 'flow from the inputs into the line'),
               SignalSpec('bleed', 'm^3/s', 'bleed flow to tank'),
               SignalSpec('loss', 'W', 'power dissipated in the seats and the bleed'))
    kernel = kernel
    ROLES = frozenset({'ls_sensor'})
    MEASURES = {'ls_pressure': 'pressure'}

    def port_problems(self):
        if 'tank' in self.ports or self.params.A_bleed == 0.0:
            return []
        # Without it the bleed drains nowhere: the line would hold the highest pressure it
        # ever saw, not follow a falling load.
        return [f'{self.name}: A_bleed = {self.params.A_bleed:g} m^2 bleeds the load-sensing '
                'line to tank, but port tank is not connected: connect it, or set A_bleed: 0 '
                '(no bleed: the line then holds the highest pressure it saw)']

    def pack(self):
        r = self.params
        rho = self.fluid.rho
        return [coefficient(r.C_d, r.A, rho), coefficient(r.C_d, r.A_bleed, rho), r.dp_cr]

    def volumes(self):
        return {'out': self.params.V}
