"""The 4/3 load-sensing valve, the counterbalance valve and the pilot-operated check valve
against closed forms computed here.

The truths are the orifice law (``C_d A sqrt(2/rho)`` with the laminar regularisation
``dp / (dp^2 + dp_cr^2)^(1/4)``), the openings of each module's docstring written out with
this module's own helpers, textbook statics (a cylinder's force balance, continuity), the
analytic step of a second-order system and the exponential decay of a volume through a
laminar leak; nothing of the component code is reused. One rig holds an independent
sub-network per case, between pressure sources and a tank, so one structure is compiled.
"""

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from hydropump_sim.circuit import CircuitError, load_circuit
from hydropump_sim.simulate import simulate
from hydropump_sim.steady import equilibrium

from .conftest import write_circuit

RHO, BETA = 870.0, 1.6e9
FLUID = dict(rho=RHO, beta=BETA, nu=3.2e-5, alpha_air=0.0, p_atm=1.013e5, P_T=0.0)
G_SPOOL = 1.7e-13        # m^3/(s Pa): the spool edges' leakage set in the rig
G_SEAT = 2.5e-16         # m^3/(s Pa): the seats' leakage set in the rig
T0 = 0.01                # s: the time of the steps
TOL = 1.0e-12            # the steady states' scaled residual

# The 4/3 valve between held pressures (v) and driving a cylinder (w, wc).
VALVE = dict(A_max=1.0e-5, A_BT=1.5e-5, C_d=0.65, overlap_P=0.1, overlap_T=0.05, omega=60.0,
             zeta=0.7, G_leak=G_SPOOL, dp_cr=5.0e4, A_ls=1.0e-6, ls_open=0.05)
# The cylinders' piston seals are taken leak-free (G_int 0): the valves' flows and leakages
# are what is measured.
CYL = dict(A_a=3.14e-3, A_b=1.5e-3, m=200.0, stroke=1.0, x0=0.5, V_a=1.0e-3, V_b=5.0e-4,
           c=1.0e4, G_int=0.0)
# The counterbalance between held pressures (cb) and holding a hanging load (hc, hcb, hv).
CB = dict(A=2.0e-5, p_set=1.25e7, ratio=5.0, p_band=1.0e6, p_h=5.0e5, tau=0.01, dp_ff=7.0e6,
          p_check=3.5e4, p_check_full=1.5e5, C_d=0.65, G_leak=G_SEAT, dp_cr=1.0e4)
HANG = dict(A_a=3.14e-3, m=500.0, stroke=1.0, x0=0.5, V_a=1.0e-3, c=1.0e4, G_int=0.0)
F_HANG = 3.0e4           # N: the hanging load, 95.5 bar on the cap side (p_set = 1.3 x)
PC = dict(A=1.0e-5, ratio=3.5, p_crack=1.0e5, p_band=2.0e5, C_d=0.65, G_leak=G_SEAT,
          dp_cr=1.0e4)
V_HOLD = 1.0e-3          # m^3: the volume the pilot-operated check holds
P_HOLD = 1.0e7           # Pa: its pressure at the start


def src(node, p):
    return {'type': 'pressure_source', 'ports': {'node': node}, 'pressure': p}


def vol(node, V):
    return {'type': 'volume', 'ports': {'node': node}, 'V': V}


RIG = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    'vP': src('nvP', 2.0e7), 'vT': src('nvT', 2.0e5), 'vA': src('nvA', 8.0e6),
    'vB': src('nvB', 3.0e6), 'vls': vol('nvls', 1.0e-6),
    'v': {'type': 'valve_4_3', 'ports': {'P': 'nvP', 'T': 'nvT', 'A': 'nvA', 'B': 'nvB',
                                         'ls': 'nvls'}, **VALVE},
    'wP': src('nwP', 2.0e7),
    'w': {'type': 'valve_4_3', 'ports': {'P': 'nwP', 'T': 'tank', 'A': 'nwA', 'B': 'nwB'},
          **VALVE},
    'wc': {'type': 'cylinder', 'ports': {'a': 'nwA', 'b': 'nwB'}, 'force': 2.0e4, **CYL},
    'cbL': src('ncbL', 1.0e7), 'cbV': src('ncbV', 0.0), 'cbP': src('ncbP', 0.0),
    'cb': {'type': 'counterbalance', 'ports': {'load': 'ncbL', 'valve': 'ncbV',
                                               'pilot': 'ncbP'}, **CB},
    # a hanging load: cylinder, counterbalance, a 3-way valve section (B plugged) in neutral
    'hc': {'type': 'cylinder', 'ports': {'a': 'nhl'}, 'force': F_HANG, **HANG},
    'hcb': {'type': 'counterbalance', 'ports': {'load': 'nhl', 'valve': 'nhv',
                                                'pilot': 'nhp'}, **CB},
    'hp': src('nhp', 0.0), 'hvol': vol('nhv', 1.0e-5),
    'hv': {'type': 'valve_4_3', 'ports': {'P': 'tank', 'T': 'tank', 'A': 'nhv'},
           **{**VALVE, 'A_max': 2.0e-5, 'A_BT': 0.0}},
    'pcI': src('npcI', 0.0), 'pcO': src('npcO', 1.0e7), 'pcP': src('npcP', 0.0),
    'pc': {'type': 'pilot_check', 'ports': {'in': 'npcI', 'out': 'npcO', 'pilot': 'npcP'},
           **PC},
    # a volume held by a pilot-operated check, its pilot at tank
    'hk': {'type': 'pilot_check', 'ports': {'in': 'tank', 'out': 'nhk', 'pilot': 'tank'},
           **PC},
    'hkv': vol('nhk', V_HOLD),
}


# ---- the test's own laws -----------------------------------------------------------------

def k(A, C_d=0.65):
    """Orifice coefficient C_d A sqrt(2/rho)."""
    return C_d * A * math.sqrt(2.0 / RHO)


def sroot(dp, dp_cr):
    """dp / (dp^2 + dp_cr^2)^(1/4), odd in dp."""
    return dp / (dp * dp + dp_cr * dp_cr) ** 0.25


def clip(v, lo=0.0, hi=1.0):
    return min(max(v, lo), hi)


def lap(x, overlap):
    """Opening of an edge opening toward positive x past an overlap (fraction of stroke)."""
    return clip((x - overlap) / (1.0 - overlap))


def edge(A, s, dp, G, dp_cr=5.0e4):
    return k(A) * s * sroot(dp, dp_cr) + G * dp


def valve_flows(x, PP, PT, PA, PB, oP=0.1, oT=0.05, A_pa=1.0e-5, A_bt=1.5e-5, A_pb=1.0e-5,
                A_at=1.0e-5):
    """(flow_P, flow_A, flow_B, flow_T) of the 4/3 valve at spool x, steady LS node."""
    q_pa = edge(A_pa, lap(x, oP), PP - PA, G_SPOOL)
    q_bt = edge(A_bt, lap(x, oT), PB - PT, G_SPOOL)
    q_pb = edge(A_pb, lap(-x, oP), PP - PB, G_SPOOL)
    q_at = edge(A_at, lap(-x, oT), PA - PT, G_SPOOL)
    return q_pa + q_pb, q_pa - q_at, q_pb - q_bt, q_at + q_bt


def close(name, got, want, rel, abs_=0.0):
    assert abs(got - want) <= rel * abs(want) + abs_, f'{name}: {got!r} vs truth {want!r}'


def cb_opening(PL, PV, Pp, side=0.0):
    """Counterbalance opening: (PL + ratio Pp - p_set) / (p_band f) shifted by side * h/2
    (side -1 rising, +1 falling, 0 without hysteresis), f = 1 + max(dp, 0)/dp_ff."""
    band = CB['p_band'] * (1.0 + max(PL - PV, 0.0) / CB['dp_ff'])
    return clip((PL + CB['ratio'] * Pp - CB['p_set'] + side * 0.5 * CB['p_h']) / band)


def cb_flow(PL, PV, s):
    """Counterbalance flow load -> valve at main opening s, with the check valve -> load."""
    dp = PL - PV
    c = clip((-dp - CB['p_check']) / (CB['p_check_full'] - CB['p_check']))
    q_check = k(CB['A']) * c * sroot(-dp, CB['dp_cr']) if c > 0.0 else 0.0
    return k(CB['A']) * s * sroot(dp, CB['dp_cr']) + G_SEAT * dp - q_check


# ---- the rig -----------------------------------------------------------------------------

@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    return load_circuit(write_circuit(tmp_path_factory.mktemp('valves'), 'valves', FLUID, RIG))


@pytest.fixture(scope='module')
def base(rig):
    return equilibrium(rig)


def steady(circuit, base, inputs, x0=None):
    """The steady state at these inputs, searched from the base one (or x0), polished to
    a scaled residual of 1e-12."""
    return equilibrium(circuit, inputs, x0=base.x if x0 is None else x0, tol=TOL)


# ---- valve_4_3 -----------------------------------------------------------------------------

def test_valve_4_3_steady_flows(rig, base):
    """Truth: the orifice law of each edge (4/3 valve docstring) between held pressures:
    + meter-in P->A against a load at A and meter-out B->T, - the mirror with the load at
    B, and a reverse flow A->P when the load exceeds the supply (1e-9)."""
    cases = [(0.6, 2.0e7, 2.0e5, 8.0e6, 3.0e6), (1.0, 2.0e7, 2.0e5, 1.2e7, 4.0e6),
             (-0.6, 2.0e7, 2.0e5, 3.0e6, 8.0e6), (-0.3, 1.5e7, 0.0, 9.0e6, 1.1e7),
             (0.5, 6.0e6, 2.0e5, 9.0e6, 1.0e6)]
    for x, PP, PT, PA, PB in cases:
        eq = steady(rig, base, {'v.command': x, 'vP.pressure': PP, 'vT.pressure': PT,
                                'vA.pressure': PA, 'vB.pressure': PB})
        want = valve_flows(x, PP, PT, PA, PB)
        assert eq['v.spool'] == pytest.approx(x, abs=1e-9)
        for name, w in zip(('flow_P', 'flow_A', 'flow_B', 'flow_T'), want):
            close(f'valve_4_3 {name} at {x}', eq[f'v.{name}'], w, 1e-9, 1e-15)
        close('valve_4_3 source A', eq['vA.flow'], want[1], 1e-9, 1e-15)
        loss = sum(q * dp for q, dp in zip(
            [edge(1.0e-5, lap(x, 0.1), PP - PA, G_SPOOL),
             edge(1.5e-5, lap(x, 0.05), PB - PT, G_SPOOL),
             edge(1.0e-5, lap(-x, 0.1), PP - PB, G_SPOOL),
             edge(1.0e-5, lap(-x, 0.05), PA - PT, G_SPOOL)],
            [PP - PA, PB - PT, PP - PB, PA - PT]))
        close('valve_4_3 loss', eq['v.loss'], loss, 1e-6)
    assert eq['v.flow_A'] < 0.0            # the last case: the load drives oil back to P


def test_valve_4_3_cylinder(rig, base):
    """Truth: a double-acting cylinder driven through the valve, meter-in and meter-out in
    series: A_a v and A_b v through the two open edges (and the leakage of the two closed
    ones), P_A A_a - P_B A_b = F + c v; v, P_A, P_B solved by brentq (1e-6)."""
    A_a, A_b, c = CYL['A_a'], CYL['A_b'], CYL['c']

    def solve(x, F, PS=2.0e7):
        def pressure(flow_into, q, lo=-1.0e10, hi=1.0e10):
            return brentq(lambda P: flow_into(P) - q, lo, hi, xtol=1e-6)

        def force_excess(v):
            PA = pressure(lambda P: valve_flows(x, PS, 0.0, P, 0.0)[1], A_a * v)
            PB = pressure(lambda P: valve_flows(x, PS, 0.0, 0.0, P)[2], -A_b * v)
            return PA * A_a - PB * A_b - F - c * v, PA, PB

        v = brentq(lambda v: force_excess(v)[0], -0.5, 0.5, xtol=1e-14)
        return v, *force_excess(v)[1:]

    for x, F in [(0.6, 2.0e4), (1.0, 4.0e4), (-0.6, -1.0e4), (-0.8, 1.0e4)]:
        v, PA, PB = solve(x, F)
        eq = steady(rig, base, {'w.command': x, 'wc.force': F})
        close(f'valve_4_3 cylinder v at {x}', eq['wc.velocity'], v, 1e-6)
        close(f'valve_4_3 cylinder P_A at {x}', eq['node:nwA'], PA, 1e-6)
        close(f'valve_4_3 cylinder P_B at {x}', eq['node:nwB'], PB, 1e-6)
        close(f'valve_4_3 cylinder flow_A at {x}', eq['w.flow_A'], A_a * v, 1e-6)
        assert eq['w.loss'] > 0.0


def ls_passage(x, PA, PB, PT, ls_open=0.05):
    """Flow [m^3/s] from the work port through the LS node to T at spool x (the node at rest:
    k_ls g_S sroot(P_S - P_ls) = k_ls g_T sroot(P_ls - P_T), by brentq), on the A side
    positive, on the B side negative."""
    g_a, g_b = clip(x / ls_open), clip(-x / ls_open)
    g_t = 1.0 - g_a - g_b
    if g_t <= 0.0 or g_a + g_b <= 0.0:
        return 0.0
    g_s, PS = (g_a, PA) if g_a > 0.0 else (g_b, PB)
    Pl = brentq(lambda P: g_s * sroot(PS - P, 5.0e4) - g_t * sroot(P - PT, 5.0e4), PT, PS,
                xtol=1e-9)
    q = k(1.0e-6) * g_t * sroot(Pl - PT, 5.0e4)
    return q if g_a > 0.0 else -q


def test_valve_4_3_centre(rig, base):
    """Truth: closed centre (overlaps 0.1 / 0.05), inside the dead band only leakage
    G_leak dp through each edge (flow_A, flow_B: the edges'), and in the first ls_open of
    the stroke the LS passage's flow from the work port through the LS node to T, in
    flow_T (1e-9); open centre (overlaps -0.1),
    every edge open by 0.1/1.1 at 0 and the orifice law through them (1e-9), far more than
    leakage."""
    P = dict(PP=2.0e7, PT=2.0e5, PA=8.0e6, PB=3.0e6)
    held = {'vP.pressure': P['PP'], 'vT.pressure': P['PT'], 'vA.pressure': P['PA'],
            'vB.pressure': P['PB']}
    G = G_SPOOL
    for x in [0.0, 0.04, -0.04]:
        eq = steady(rig, base, {'v.command': x, **held})
        q_ls = ls_passage(x, P['PA'], P['PB'], P['PT'])
        close(f'closed centre flow_P at {x}', eq['v.flow_P'],
              G * (P['PP'] - P['PA']) + G * (P['PP'] - P['PB']), 1e-9)
        close(f'closed centre flow_A at {x}', eq['v.flow_A'],
              G * (P['PP'] - P['PA']) - G * (P['PA'] - P['PT']), 1e-9)
        close(f'closed centre flow_B at {x}', eq['v.flow_B'],
              G * (P['PP'] - P['PB']) - G * (P['PB'] - P['PT']), 1e-9)
        close(f'closed centre flow_T at {x}', eq['v.flow_T'],
              G * (P['PA'] - P['PT']) + G * (P['PB'] - P['PT']) + abs(q_ls), 1e-9)
    open_c = rig.with_values({'v.overlap_P': -0.1, 'v.overlap_T': -0.1})
    for x in [0.0, 0.05, -0.05, 0.3]:
        eq = steady(open_c, base, {'v.command': x, **held})
        want = valve_flows(x, *P.values(), oP=-0.1, oT=-0.1)
        for name, w in zip(('flow_P', 'flow_A', 'flow_B', 'flow_T'), want):
            close(f'open centre {name} at {x}', eq[f'v.{name}'], w, 1e-9, 1e-15)
        if x == 0.0:
            s0 = 0.1 / 1.1
            close('open centre P', eq['v.flow_P'],
                  k(1.0e-5) * s0 * (sroot(P['PP'] - P['PA'], 5.0e4)
                                    + sroot(P['PP'] - P['PB'], 5.0e4))
                  + G * (2 * P['PP'] - P['PA'] - P['PB']), 1e-9)
            assert eq['v.flow_P'] > 20.0 * G * (2 * P['PP'] - P['PA'] - P['PB'])
            assert eq['v.flow_T'] > 20.0 * G * (P['PA'] + P['PB'] - 2 * P['PT'])


def test_valve_4_3_load_sensing(rig, base):
    """Truth: the LS node (a volume fed by the passage only) at rest: P_A on the + side past
    ls_open, P_B on the - side, P_T at the centre, half-way between P_A and P_T at
    ls_open/2 (the passage split evenly between them; sroot is odd) (1 Pa)."""
    for x, truth in [(0.6, 'A'), (0.06, 'A'), (-0.6, 'B'), (-0.2, 'B'), (0.0, 'T'),
                     (0.025, 'AT')]:
        eq = steady(rig, base, {'v.command': x})
        P = {'A': eq['node:nvA'], 'B': eq['node:nvB'], 'T': eq['node:nvT']}
        want = 0.5 * (P['A'] + P['T']) if truth == 'AT' else P[truth]
        assert abs(eq['node:nvls'] - want) < 1.0, (x, eq['node:nvls'], want)
        assert abs(eq['v.sensed'] - want) < 1.0e-6, (x, eq['v.sensed'], want)


def test_valve_4_3_spool_step(rig, base):
    """Truth: the analytic step of x'' = omega^2 (xi - x) - 2 zeta omega x': overshoot
    exp(-pi zeta / sqrt(1 - zeta^2)) and peak time pi / (omega sqrt(1 - zeta^2)) (2 %), the
    whole curve (0.5 % of the step)."""
    step = 0.5
    res = simulate(rig, 0.3, {'v.command': lambda t: np.where(
        np.asarray(t) >= T0 - 1e-9, step, 0.0)}, x0=base.x, dt_out=1.0e-4, dt_max=1.0e-4)
    w, z = VALVE['omega'], VALVE['zeta']
    wd = w * math.sqrt(1.0 - z * z)
    tau = np.maximum(res.t - T0, 0.0)
    curve = step * (1.0 - np.exp(-z * w * tau) * (np.cos(wd * tau)
                                                 + z / math.sqrt(1.0 - z * z)
                                                 * np.sin(wd * tau)))
    x = res['v.spool']
    i = int(np.argmax(x))
    overshoot = (x[i] - step) / step
    close('spool overshoot', overshoot, math.exp(-math.pi * z / math.sqrt(1.0 - z * z)), 0.02)
    close('spool peak time', res.t[i] - T0, math.pi / wd, 0.02)
    assert float(np.max(np.abs(x - curve))) < 0.005 * step


# ---- counterbalance -----------------------------------------------------------------------

@pytest.fixture(scope='module')
def minute(rig, base):
    """A minute at rest from the steady state, the pilot-operated check's volume at 100 bar:
    the hanging load and the held volume drain through their seats."""
    x0 = base.x.copy()
    x0[rig.node_state('nhk')] = P_HOLD
    return simulate(rig, 60.0, x0=x0, dt_out=1.0, dt_max=1.0)


def test_counterbalance_holds_load(minute):
    """Truth: continuity at the cap side, the load drifts at G_leak P_load / A_a with
    P_load = F / A_a (the seat's leakage, the valve side drained by the spool's): over 60 s
    below 1 mm/min and within 5 %."""
    res = minute
    P_load = F_HANG / HANG['A_a']
    drift = res['hc.position'][-1] - res['hc.position'][0]          # m in a minute
    want = -G_SEAT * P_load / HANG['A_a'] * 60.0
    assert abs(drift) < 1.0e-3
    close('counterbalance drift', drift, want, 0.05)
    assert float(np.max(res['hcb.opening'])) < 1.0e-9
    close('counterbalance load pressure', res.node('nhl')[-1], P_load, 1e-3)


def test_counterbalance_opening_load(rig, base):
    """Truth: at zero pilot the poppet opens at p_set + p_h/2 rising and closes at
    p_set - p_h/2 falling (hysteresis), s = (P_load - p_set -+ p_h/2) / (p_band f) between,
    the flow the orifice law at that opening (1e-6); the opening pressure found by
    bisection on the steady flow against p_set +- p_h/2 (2 %); without hysteresis
    (p_h = 0) against p_set."""
    i = rig.states.index('cb.opening')
    shut, full = base.x.copy(), base.x.copy()
    shut[i], full[i] = 0.0, 1.0
    for side, x0 in [(-1.0, shut), (1.0, full)]:
        for PL in [1.2e7, 1.28e7, 1.3e7, 1.35e7, 1.5e7, 2.0e7]:
            eq = steady(rig, base, {'cbL.pressure': PL}, x0=x0)
            s = cb_opening(PL, 0.0, 0.0, side)
            close(f'counterbalance opening at {PL:g} ({side:+g})', eq['cb.opening'], s, 1e-6,
                  1e-9)
            close(f'counterbalance flow at {PL:g} ({side:+g})', eq['cb.flow'],
                  cb_flow(PL, 0.0, s), 1e-6)

    def crack(circuit, x0):
        def excess(PL):
            eq = steady(circuit, None, {'cbL.pressure': PL}, x0)
            return eq['cb.flow'] / (G_SEAT * PL) - 2.0   # twice the seat's leakage
        return brentq(excess, 1.0e7, 1.6e7, xtol=1.0e2)

    flat = rig.with_values({'cb.p_h': 0.0})
    for circuit, x0, want in [(rig, shut, CB['p_set'] + 0.5 * CB['p_h']),
                              (rig, full, CB['p_set'] - 0.5 * CB['p_h']),
                              (flat, shut, CB['p_set'])]:
        close('counterbalance opening pressure', crack(circuit, x0), want, 0.02)


def test_counterbalance_opening_pilot(rig, base):
    """Truth: at a load below p_set the pilot opens it when P_load + ratio P_pilot reaches
    p_set + p_h/2 (rising): the opening and flow vs the pilot pressure (1e-6), the pilot
    pressure at opening by bisection within 2 % of (p_set + p_h/2 - P_load) / ratio."""
    i = rig.states.index('cb.opening')
    shut = base.x.copy()
    shut[i] = 0.0
    PL = 8.0e6
    for Pp in [5.0e5, 1.0e6, 1.1e6, 1.2e6, 1.5e6, 3.0e6]:
        eq = steady(rig, base, {'cbL.pressure': PL, 'cbP.pressure': Pp}, x0=shut)
        s = cb_opening(PL, 0.0, Pp, -1.0)
        close(f'counterbalance opening at pilot {Pp:g}', eq['cb.opening'], s, 1e-6, 1e-9)
        close(f'counterbalance flow at pilot {Pp:g}', eq['cb.flow'], cb_flow(PL, 0.0, s),
              1e-6)

    def excess(Pp):
        eq = steady(rig, None, {'cbL.pressure': PL, 'cbP.pressure': Pp}, shut)
        return eq['cb.flow'] / (G_SEAT * PL) - 2.0
    got = brentq(excess, 0.0, 3.0e6, xtol=1.0e1)
    close('counterbalance pilot opening pressure', got,
          (CB['p_set'] + 0.5 * CB['p_h'] - PL) / CB['ratio'], 0.02)


def test_counterbalance_free_flow(rig, base):
    """Truth: the integral check, valve -> load, c = (dp - p_check)/(p_check_full -
    p_check) clipped, the orifice law at c plus the closed poppet's seat leakage (1e-9);
    below p_check only the leakage."""
    PL = 5.0e6
    for dp in [2.0e4, 3.5e4, 5.0e4, 1.0e5, 1.5e5, 5.0e5, 2.0e6]:
        eq = steady(rig, base, {'cbL.pressure': PL, 'cbV.pressure': PL + dp})
        close(f'counterbalance check at {dp:g}', eq['cb.flow'], cb_flow(PL, PL + dp, 0.0),
              1e-9)
        assert eq['cb.opening'] == 0.0 and eq['cb.loss'] >= 0.0
    assert eq['cb.flow'] < -1.0e3 * G_SEAT * dp


def test_counterbalance_lowering(rig, base):
    """Truth: lowering the hanging load with pilot pressure and the valve's A->T edge open:
    the cap side's A_a v through the counterbalance (fully open) and the A->T edge in
    series (with the leakage of the closed P-A edge), P_load = (F + c v) / A_a; v by
    brentq (1e-6)."""
    x, Pp = -0.5, 3.0e6
    A_a, c = HANG['A_a'], HANG['c']

    def mid(v):
        PL = (F_HANG + c * v) / A_a
        return PL, brentq(lambda Pm: cb_flow(PL, Pm, cb_opening(PL, Pm, Pp, -1.0)) + A_a * v,
                          -1.0e6, PL, xtol=1e-6)

    def excess(v):
        _, Pm = mid(v)
        return (-A_a * v - edge(2.0e-5, lap(-x, 0.05), Pm, G_SPOOL)
                - G_SPOOL * Pm)

    v = brentq(excess, -0.5, -1.0e-9, xtol=1e-14)
    PL, Pm = mid(v)
    eq = steady(rig, base, {'hv.command': x, 'hp.pressure': Pp})
    close('counterbalance lowering velocity', eq['hc.velocity'], v, 1e-6)
    close('counterbalance lowering middle pressure', eq['node:nhv'], Pm, 1e-6)
    assert eq['hcb.opening'] == pytest.approx(1.0, abs=1e-9)
    q = cb_flow(PL, Pm, 1.0)
    close('counterbalance lowering flow', eq['hcb.flow'], q, 1e-6)
    close('counterbalance lowering loss', eq['hcb.loss'], q * (PL - Pm), 1e-6)


def test_counterbalance_ratio_must_be_positive(rig):
    """A pilot ratio of 0: one line naming the parameter and saying what it is."""
    with pytest.raises(CircuitError) as info:
        rig.with_values({'cb.ratio': 0.0})
    lines = [ln for ln in info.value.lines if 'ratio' in ln]
    assert len(lines) == 1 and 'cb.ratio' in lines[0] and 'pilot ratio' in lines[0], lines
    assert '\n' not in lines[0]


# ---- pilot_check ---------------------------------------------------------------------------

def pc_flow(PI, PO, Pp):
    dp = PI - PO
    s = clip((dp + PC['ratio'] * Pp - PC['p_crack']) / PC['p_band'])
    return s, k(PC['A']) * s * sroot(dp, PC['dp_cr']) + G_SEAT * dp


def test_pilot_check_both_ways(rig, base):
    """Truth: free flow in -> out above p_crack over p_band, reverse flow once
    ratio P_pilot > P_out - P_in + p_crack, the orifice law at the opening (1e-9); with the
    pilot short of that only the seat's leakage."""
    fwd = [(1.0e6 + dp, 1.0e6, 0.0) for dp in [5.0e4, 1.0e5, 1.5e5, 2.0e5, 3.0e5, 2.0e6]]
    rev = [(0.0, 1.0e7, Pp) for Pp in [2.0e6, 2.9e6, 2.9e6 + 1.0e5 / 3.5, 3.0e6, 4.0e6]]
    rev += [(2.0e6, 1.2e7, 2.0e6), (2.0e6, 1.2e7, 3.5e6)]
    for PI, PO, Pp in fwd + rev:
        eq = steady(rig, base, {'pcI.pressure': PI, 'pcO.pressure': PO, 'pcP.pressure': Pp})
        s, q = pc_flow(PI, PO, Pp)
        close(f'pilot_check opening {PI:g} {PO:g} {Pp:g}', eq['pc.opening'], s, 1e-9, 1e-12)
        close(f'pilot_check flow {PI:g} {PO:g} {Pp:g}', eq['pc.flow'], q, 1e-9)
        close(f'pilot_check loss {PI:g} {PO:g} {Pp:g}', eq['pc.loss'], q * (PI - PO), 1e-9)
    eq = steady(rig, base, {'pcI.pressure': 0.0, 'pcO.pressure': 1.0e7, 'pcP.pressure': 4.0e6})
    assert eq['pc.flow'] < -1.0e4 * G_SEAT * 1.0e7           # really open backwards
    eq = steady(rig, base, {'pcI.pressure': 0.0, 'pcO.pressure': 1.0e7, 'pcP.pressure': 0.0})
    assert eq['pc.opening'] == 0.0
    close('pilot_check held', eq['pc.flow'], -G_SEAT * 1.0e7, 1e-12)


def test_pilot_check_holds_pressure(minute):
    """Truth: a volume at 100 bar behind the closed valve, pilot at zero, drains only
    through the seat: P(t) = P0 exp(-beta G_leak t / V) (1 % of the drop in 60 s)."""
    res = minute
    want = P_HOLD * np.exp(-BETA * G_SEAT * res.t / V_HOLD)
    got = res.node('nhk')
    assert float(np.max(res['hk.opening'])) == 0.0
    assert got[-1] > 0.97 * P_HOLD
    assert float(np.max(np.abs(got - want))) < 0.01 * (P_HOLD - want[-1])
