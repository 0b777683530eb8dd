"""Proportional 4/3 directional valve of a load-sensing block: one section's spool between
the pressure port ``P``, the tank port ``T`` and the work ports ``A`` and ``B`` (``B`` may
be plugged: a 3-way use with a single-acting actuator), with the section's load-sensing
passage to ``ls``.

Spool: the command ``xi`` (-1..1, a fraction of the stroke; + opens P->A and B->T, - opens
P->B and A->T) drives a second-order spool (its proportional solenoid or pilot stage and
its position loop), of natural frequency ``omega`` and damping ``zeta``:

    d2x/dt2 = omega^2 (xi - x) - 2 zeta omega dx/dt,      s = clip(x, -1, 1)

(``omega = 0``: the spool follows the command at once, no states.)

Metering edges: each edge opens on the side of the stroke its sign gives (``sigma = +1``
for P-A and B-T, ``-1`` for P-B and A-T) past its overlap ``o`` (``overlap_P`` for the P
edges, ``overlap_T`` for the T edges, as a fraction of the stroke):

    a(sigma s, o) = clip((sigma s - o) / (1 - o), 0, 1)

A positive overlap is a closed centre (a dead band ``|s| < o`` where only leakage passes);
zero is a zero lap; a negative one an underlap, an open centre: at ``s = 0`` every edge is
open by ``-o / (1 - o)``, and an edge closes only once the spool is ``-o`` past the centre
on its closing side. Each edge passes flow both ways with its leakage (laws.edge):

    Q_PA = k_PA a(s, o_P) sroot(P_P - P_A) + G_leak (P_P - P_A)
    Q_BT = k_BT a(s, o_T) sroot(P_B - P_T) + G_leak (P_B - P_T)
    Q_PB = k_PB a(-s, o_P) sroot(P_P - P_B) + G_leak (P_P - P_B)
    Q_AT = k_AT a(-s, o_T) sroot(P_A - P_T) + G_leak (P_A - P_T)

with ``k_ij = C_d A_ij sqrt(2/rho)``. Load-sensing passage (area ``A_ls``, coefficient
``k_ls``): the node ``ls`` is connected to A on the + side, to B on the - side and drained
to T near the centre, switching linearly over the first ``ls_open`` of the stroke:

    g_A = clip(s / ls_open, 0, 1),   g_B = clip(-s / ls_open, 0, 1),   g_T = 1 - g_A - g_B
    Q_A->ls = k_ls g_A sroot(P_A - P_ls), Q_B->ls = k_ls g_B sroot(P_B - P_ls),
    Q_ls->T = k_ls g_T sroot(P_ls - P_T)

so an idle section senses tank and a working one its work port (the ``sensed`` signal,
``g_A P_A + g_B P_B + g_T P_T``). With B plugged, its share drains to T. ``sense_A`` and
``sense_B`` take the passage's sides elsewhere than the work ports (the load behind a post
compensator, as flow-sharing sections sense it). The signals ``flow_A`` and ``flow_B`` are
the valve's net flows into the work ports through its edges, ``flow_T`` into T with the
passage's drain; ``loss`` is the sum of ``dp q`` over the four edges and the passage.

Defaults and their sources:

- ``omega`` 60 rad/s, ``zeta`` 0.7: a proportional load-sensing section's spool (a long,
  heavy spool moved by a solenoid or an electro-hydraulic pilot stage under a position
  loop) is slower than a servo valve's, about 10 Hz, and its position loop is tuned for a
  small overshoot: 60 rad/s at 0.7 puts a step's peak at 73 ms with a 4.6 % overshoot.
  Hopsan's 4/3 valve default is 100 rad/s critically damped (1.0), a faster, generic spool
  that cannot overshoot;
- ``overlap_P = overlap_T`` 0.1: a closed centre with a dead band of 10 % of the stroke,
  so that the neutral holds a load with the spool's leakage only and the load-sensing
  passage is switched (``ls_open`` 0.05, half of it) before metering starts, the sequence
  of Hopsan's load-sensing 4/3 valve (its Compgen version: a 0.3 mm overlap of a 10 mm
  stroke, the LS land fully open at 1 mm) with a wider band typical of a mobile valve's
  neutral;
- ``A_ls`` 3e-6 m^2 (a 2 mm drilling: the load-sensing bleed's drop across it stays
  below 0.1 bar) and ``dp_cr`` 0.5 bar, as directional_valve;
  ``C_d`` 0.65 (Hopsan's 0.67, a sharp edge's 0.6-0.7); ``G_leak`` laws.G_LEAK_SPOOL
  (0.1 L/min at 100 bar per edge, a proportional valve's catalogue leakage order).
"""

from dataclasses import dataclass

import numpy as np

from ..jitcache import jit
from ..schema import spec
from .base import Component, InputSpec, JointSpec, PortSpec, SignalSpec, StateSpec
from .laws import clip01, edge, G_LEAK_SPOOL
from .orifice import coefficient


@jit
def opening(s, overlap):
    """Opening 0..1 of an edge that opens toward positive ``s`` past ``overlap``."""
    return clip01((s - overlap) / (1.0 - overlap))


def openings(s, overlap: float) -> np.ndarray:
    """:func:`opening` of each of the spool positions or commands ``s`` (an array)."""
    return np.vectorize(opening, otypes=[float])(s, overlap)


@jit
def kernel(t, x, dx, u, p, y, P, Q, V):
    ip, it, ia, ib, il = int(p[0]), int(p[1]), int(p[2]), int(p[3]), int(p[4])
    isa, isb = int(p[5]), int(p[6])
    k_pa, k_bt, k_pb, k_at = p[7], p[8], p[9], p[10]
    o_p, o_t, g, dp_cr, omega, zeta, k_ls, ls_open = (p[11], p[12], p[13], p[14], p[15],
                                                      p[16], p[17], p[18])
    if isa < 0:
        isa = ia
    cmd = min(max(u[0], -1.0), 1.0)
    if omega > 0.0:
        dx[0] = x[1]
        dx[1] = omega * omega * (cmd - x[0]) - 2.0 * zeta * omega * x[1]
        s = min(max(x[0], -1.0), 1.0)
    else:
        s = cmd
    pp, pt, pa = P[ip], P[it], P[ia]
    q_pa = edge(k_pa, opening(s, o_p), pp - pa, dp_cr, g)
    q_at = edge(k_at, opening(-s, o_t), pa - pt, dp_cr, g)
    loss = q_pa * (pp - pa) + q_at * (pa - pt)
    q_pb = 0.0
    q_bt = 0.0
    pb = pt
    g_a = clip01(s / ls_open)
    g_b = 0.0
    if ib >= 0:
        pb = P[ib]
        q_pb = edge(k_pb, opening(-s, o_p), pp - pb, dp_cr, g)
        q_bt = edge(k_bt, opening(s, o_t), pb - pt, dp_cr, g)
        loss += q_pb * (pp - pb) + q_bt * (pb - pt)
        g_b = clip01(-s / ls_open)
    if isb < 0:
        isb = ib if ib >= 0 else it
    g_t = 1.0 - g_a - g_b
    q_als = 0.0
    q_bls = 0.0
    q_lst = 0.0
    if il >= 0:
        pl, psa, psb = P[il], P[isa], P[isb]
        q_als = edge(k_ls, g_a, psa - pl, dp_cr, 0.0)
        q_bls = edge(k_ls, g_b, psb - pl, dp_cr, 0.0)
        q_lst = edge(k_ls, g_t, pl - pt, dp_cr, 0.0)
        Q[il] += q_als + q_bls - q_lst
        Q[isa] -= q_als
        Q[isb] -= q_bls
        loss += q_als * (psa - pl) + q_bls * (psb - pl) + q_lst * (pl - pt)
    flow_p = q_pa + q_pb
    flow_a = q_pa - q_at
    flow_b = q_pb - q_bt
    flow_t = q_at + q_bt + q_lst
    Q[ip] -= flow_p
    Q[ia] += flow_a
    if ib >= 0:
        Q[ib] += flow_b
    Q[it] += flow_t
    y[0] = s
    y[1] = flow_a
    y[2] = flow_b
    y[3] = flow_p
    y[4] = flow_t
    y[5] = loss
    y[6] = g_a * psa + g_b * psb + g_t * pt


@dataclass(frozen=True)
class Valve43Params:
    A_max: float = spec('m^2', 'metering area of an edge fully open (the default of the four '
                        'A_PA, A_BT, A_PB, A_AT)', 1.0e-9, 1.0e-2)
    A_PA: float = spec('m^2', 'area of the P-A edge fully open; 0 = A_max', 0.0, 1.0e-2,
                       default=0.0)
    A_BT: float = spec('m^2', 'area of the B-T edge fully open; 0 = A_max', 0.0, 1.0e-2,
                       default=0.0)
    A_PB: float = spec('m^2', 'area of the P-B edge fully open; 0 = A_max', 0.0, 1.0e-2,
                       default=0.0)
    A_AT: float = spec('m^2', 'area of the A-T edge fully open; 0 = A_max', 0.0, 1.0e-2,
                       default=0.0)
    C_d: float = spec('-', 'discharge coefficient (Hopsan 0.67)', 0.1, 1.0, default=0.65)
    overlap_P: float = spec('-', 'overlap of the P edges as a fraction of the stroke (+ closed '
                            'centre, 0 zero lap, - open centre)', -0.5, 0.9, default=0.1)
    overlap_T: float = spec('-', 'overlap of the T edges as a fraction of the stroke (+ closed '
                            'centre, 0 zero lap, - open centre)', -0.5, 0.9, default=0.1)
    omega: float = spec('rad/s', 'spool natural frequency (Hopsan 100); 0 = follows the '
                        'command at once', 0.0, 1.0e4, default=60.0)
    zeta: float = spec('-', 'spool damping ratio (Hopsan 1.0)', 0.05, 5.0, default=0.7)
    G_leak: float = spec('m^3/(s Pa)', 'leakage of each edge (laws.G_LEAK_SPOOL: 0.1 L/min at '
                         '100 bar)', 0.0, 1.0e-9, default=G_LEAK_SPOOL)
    dp_cr: float = spec('Pa', 'laminar/turbulent transition', 0.0, 1.0e6, default=5.0e4)
    A_ls: float = spec('m^2', 'area of the load-sensing passage (ls port): a 2 mm drilling',
                       1.0e-10, 1.0e-4, default=3.0e-6)
    ls_open: float = spec('-', 'spool travel (fraction of the stroke) over which the '
                          'load-sensing passage switches from T to the work port', 1.0e-3, 1.0,
                          default=0.05)
    command: float = spec('-', 'spool command -1..1 (an input)', -1.0, 1.0, default=0.0)


class Valve43(Component):
    kind = 'valve_4_3'
    LOSS_GROUP = 'metering'
    doc = 'proportional 4/3 valve of a load-sensing block: P, T, A, B edges, LS passage'
    Params = Valve43Params
    PORTS = (PortSpec('P', 'pressure port'), PortSpec('T', 'tank port'),
             PortSpec('A', 'work port A'),
             PortSpec('B', 'work port B (unconnected: plugged, a 3-way use)', optional=True),
             PortSpec('ls', 'load-sensing signal of the section', optional=True),
             PortSpec('sense_A', 'where the load-sensing passage takes the A side (default: '
                      'A; the load behind a post compensator)', optional=True),
             PortSpec('sense_B', 'where it takes the B side (default: B)', optional=True))
    INPUTS = (InputSpec('command', '-', 'spool command -1..1 (+ P->A, B->T)', -1.0, 1.0,
                        'command'),)
    SIGNALS = (SignalSpec('spool', '-', 'spool position, fraction of the stroke -1..1'),
               SignalSpec('flow_A', 'm^3/s', 'net flow from the valve into A through its edges'),
               SignalSpec('flow_B', 'm^3/s', 'net flow from the valve into B through its edges'),
               SignalSpec('flow_P', 'm^3/s', 'flow from P into the valve'),
               SignalSpec('flow_T', 'm^3/s', 'flow from the valve into T (LS drain too)'),
               SignalSpec('loss', 'W', 'power dissipated in the edges and the LS passage'),
               SignalSpec('sensed', 'Pa', 'pressure the LS passage connects to'))
    kernel = kernel
    JOINTS = (JointSpec('', 'spool', None),)

    def static_values(self):
        """Its spool dynamics off: the spool follows the command at once."""
        return {'omega': 0.0}

    def states(self):
        if self.params.omega <= 0.0:
            return ()
        return (StateSpec('spool', '-', 1.0),
                StateSpec('spool_rate', '1/s', self.params.omega))

    def pack(self):
        r = self.params
        rho = self.fluid.rho
        areas = [a if a > 0.0 else r.A_max for a in (r.A_PA, r.A_BT, r.A_PB, r.A_AT)]
        return ([coefficient(r.C_d, a, rho) for a in areas]
                + [r.overlap_P, r.overlap_T, r.G_leak, r.dp_cr, r.omega, r.zeta,
                   coefficient(r.C_d, r.A_ls, rho), r.ls_open])

    def initial_state(self, P, u):
        if self.params.omega <= 0.0:
            return np.array([])
        return np.array([min(max(float(u['command']), -1.0), 1.0), 0.0])
