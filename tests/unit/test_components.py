"""Every circuit component type against a closed form computed here from its equations.

The truths come from the formulas of each component's module docstring (and textbook
statics: a force balance, continuity), written out below with their own helpers (``k``,
``sroot``); nothing of the component code and no value it printed is reused. One test-bench
circuit holds an independent sub-network per component, between pressure sources and tanks,
so one structure is compiled; inputs and parameters are varied with ``sets``/inputs.
"""

import copy
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
T0 = 0.01                      # s: the step of the dynamic tests
G_SEAT = 1.0e-15               # m^3/(s Pa): the bench's seat leakages (0.6 mL/min at 100 bar)
G_SPOOL = 2.0e-13              # m^3/(s Pa): the bench's spool leakages (0.12 L/min at 100 bar)


def k(A, C_d=0.65):
    """Orifice coefficient C_d A sqrt(2/rho)."""
    return C_d * A * math.sqrt(2.0 / RHO)


def sroot(dp, dp_cr):
    """dp / (dp^2 + dp_cr^2)^(1/4) (docs/reference.md I3)."""
    return dp / (dp * dp + dp_cr * dp_cr) ** 0.25


def close(name, got, want, rel, abs_=0.0):
    assert abs(got - want) <= rel * abs(want) + abs_, f'{name}: {got!r} vs truth {want!r}'


def src(node, p):
    return {'type': 'pressure_source', 'ports': {'node': node}, 'pressure': p}


def vol(node, V):
    return {'type': 'volume', 'ports': {'node': node}, 'V': V}


def orf(a, b, A):
    return {'type': 'orifice', 'ports': {'a': a, 'b': b}, 'A': A}


def dvalve(a, b, A, cmd, tau=0.0, **kw):
    return {'type': 'directional_valve', 'ports': {'in': a, 'out': b}, 'A_max': A,
            'command': cmd, 'tau': tau, 'G_leak': G_SPOOL, **kw}


def relief(node, tau):
    return {'type': 'relief', 'ports': {'in': node, 'out': 'tank'}, 'p_crack': 1.5e7,
            'p_full': 1.7e7, 'q_full': 1.0e-3, 'tau': tau, 'G_leak': G_SEAT}


# The regulating spools' regulation range, hysteresis and flow-force droop on the bench.
BAND, HYST, R_FF = 1.0e5, 3.0e4, 1.0e8
SPOOL = {'p_band': BAND, 'p_h': HYST, 'r_ff': R_FF, 'G_leak': G_SPOOL}


CYL = dict(A_a=3.14e-3, A_b=1.5e-3, m=200.0, stroke=1.0, x0=0.2, V_a=1.0e-3, c=1.0e4)
MOT = dict(D=3.18e-6, J=0.05, V_a=3.0e-4, c=0.05, G_leak=2.0e-13)
BENCH = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    'orf_a': src('n1a', 1.0e7), 'orf_b': src('n1b', 0.0), 'orf': orf('n1a', 'n1b', 1.0e-5),
    'chk_a': src('n2a', 1.0e6), 'chk_b': src('n2b', 0.0),
    'chk': {'type': 'check_valve', 'ports': {'in': 'n2a', 'out': 'n2b'}, 'A': 1.0e-5,
            'p_crack': 1.0e5, 'p_full': 3.0e5, 'dp_cr': 1.0e4, 'G_leak': G_SEAT},
    'rel_p': src('n3', 1.0e7), 'rel': relief('n3', 0.0),
    'lag_p': src('n3l', 1.0e7), 'rel_lag': relief('n3l', 0.05),
    'vol_a': src('n4a', 1.5e7), 'vol_b': src('n4b', 2.0e6), 'vol': vol('n4', 2.0e-5),
    'vol_in': orf('n4a', 'n4', 4.0e-6), 'vol_out': orf('n4', 'n4b', 3.0e-6),
    'dv_a': src('n5a', 1.0e7), 'dv_b': src('n5b', 0.0), 'dv': dvalve('n5a', 'n5b', 1.0e-5, 0.7),
    'dvl_a': src('n5c', 1.0e7), 'dvl_b': src('n5d', 0.0),
    'dvl': dvalve('n5c', 'n5d', 1.0e-5, 0.0, tau=0.03),
    'dv2_a': src('n5e', 1.0e7), 'dv2_b': src('n5f', 0.0),
    'dv2': dvalve('n5e', 'n5f', 1.0e-5, 0.7, check=False),
    # a pre-compensated section: compensator, mid volume, metering valve, load
    'pre_s': src('n6s', 2.0e7), 'pre_l': src('n6l', 1.0e7), 'pre_mid': vol('n6m', 1.0e-5),
    'pre': {'type': 'pre_compensator', 'ports': {'in': 'n6s', 'out': 'n6m', 'sense': 'n6l'},
            'A_max': 5.0e-5, 'dp_set': 1.0e6, **SPOOL},
    'pre_v': dvalve('n6m', 'n6l', 1.5e-5, 0.6),
    # a post-compensated section: metering valve, mid volume, compensator on P_ls, load
    'post_s': src('n7s', 2.0e7), 'post_l': src('n7l', 1.0e7), 'post_ls': src('n7ls', 1.2e7),
    'post_mid': vol('n7m', 1.0e-5), 'post_v': dvalve('n7s', 'n7m', 1.5e-5, 0.6),
    'post': {'type': 'post_compensator', 'ports': {'in': 'n7m', 'out': 'n7l', 'ls': 'n7ls'},
             'A_max': 5.0e-5, 'dp_set': 1.0e6, **SPOOL},
    # a priority valve on a flow-limited supply (a feed orifice): cf -> metering valve ->
    # load source (its sensed pressure), ef -> an orifice consumer -> a load source
    'pri_s': src('n8f', 2.0e7), 'pri_feed': orf('n8f', 'n8s', 2.0e-5),
    'pri_sv': vol('n8s', 1.0e-4), 'pri_cv': vol('n8c', 1.0e-5), 'pri_ev': vol('n8e', 1.0e-5),
    'pri': {'type': 'priority_valve', 'ports': {'in': 'n8s', 'cf': 'n8c', 'ef': 'n8e',
                                                'ls': 'n8l'},
            'A_cf': 2.0e-5, 'A_ef': 2.0e-5, 'dp_set': 1.0e6, **SPOOL},
    'pri_v': dvalve('n8c', 'n8l', 8.0e-6, 0.5), 'pri_l': src('n8l', 6.0e6),
    'pri_eo': orf('n8e', 'n8x', 1.0e-5), 'pri_x': src('n8x', 5.0e6),
    'sh_1': src('n9a', 5.0e6), 'sh_2': src('n9b', 1.2e7), 'sh_3': src('n9c', 8.0e6),
    'sh': {'type': 'shuttle_network', 'ports': {'in': ['n9a', 'n9b', 'n9c'], 'out': 'n9',
                                                'tank': 'tank'}, 'V': 5.0e-5,
           'A': 3.0e-6, 'A_bleed': 2.0e-8},
    'cyl_s': src('n10s', 1.5e7), 'cyl_o': orf('n10s', 'n10', 5.0e-6),
    'cyl': {'type': 'cylinder', 'ports': {'a': 'n10', 'b': 'tank'}, 'force': 3.0e4, **CYL},
    'mot_s': src('n11s', 1.5e7), 'mot_o': orf('n11s', 'n11', 5.0e-6),
    'mot': {'type': 'motor', 'ports': {'a': 'n11', 'b': 'tank'}, 'torque': 30.0, **MOT},
    'ts_s': src('n12', 3.0e6), 'ts_o': orf('n12', 'n12t', 2.0e-6),
    'ts_t': {'type': 'tank', 'ports': {'node': 'n12t'}, 'pressure': 2.0e5},
    'ol_s': src('n13', 1.0e7),
    'ol': {'type': 'orifice_load', 'ports': {'in': 'n13'}, 'mu': 3.0e-7, 'load_pressure': 4.0e6,
           'aperture': 0.7, 'gamma': 2.0, 'dp_cr': 1.0e4},
}


@pytest.fixture(scope='module')
def bench(tmp_path_factory):
    return load_circuit(write_circuit(tmp_path_factory.mktemp('bench'), 'bench', FLUID, BENCH))


@pytest.fixture(scope='module')
def base(bench):
    return equilibrium(bench)


def steady(bench, base, inputs):
    """The steady state at these inputs, searched from the base one."""
    return equilibrium(bench, inputs, x0=base.x)


@pytest.fixture(scope='module')
def steps(bench, base):
    """A run from the base state with two steps at T0: the lagged relief's inlet from
    100 to 200 bar (target opening 0 -> 1), the lagged valve's command 0 -> 0.8."""
    def step(lo, hi):
        return lambda t: np.where(np.asarray(t) >= T0 - 1e-9, hi, lo)
    return simulate(bench, 0.25, {'lag_p.pressure': step(1.0e7, 2.0e7),
                                          'dvl.command': step(0.0, 0.8)}, x0=base.x)


def lag_error(res, signal, tau, final):
    """Worst deviation of a signal from final*(1 - exp(-(t - T0)/tau)), relative to final."""
    t = res.t
    want = np.where(t >= T0, final * (1.0 - np.exp(-(t - T0) / tau)), 0.0)
    at_tau = res[signal][np.argmin(abs(t - (T0 + tau)))] / (final * (1.0 - math.exp(-1.0)))
    return float(np.max(abs(res[signal] - want))) / final, abs(at_tau - 1.0)


def test_orifice(bench, base):
    """Truth: orifice.py, Q = C_d A xi sqrt(2/rho) dp/(dp^2 + dp_cr^2)^(1/4) (1e-9), its
    turbulent limit C_d A xi sqrt(2 dp/rho) at dp >> dp_cr (0.5 %), odd in dp."""
    for dp, xi in [(1.0e7, 1.0), (2.0e6, 0.4), (3.0e4, 1.0), (1.0e5, 0.25)]:
        fwd = steady(bench, base, {'orf_a.pressure': dp, 'orf.aperture': xi})['orf.flow']
        rev = steady(bench, base, {'orf_a.pressure': 0.0, 'orf_b.pressure': dp,
                                   'orf.aperture': xi})['orf.flow']
        close('orifice', fwd, k(1.0e-5) * xi * sroot(dp, 1.0e5), 1e-9)
        close('orifice', rev, -fwd, 1e-12)
        if dp >= 2.0e6:
            close('orifice turbulent', fwd, k(1.0e-5) * xi * math.sqrt(dp), 5e-3)


def test_check_valve(bench, base):
    """Truth: check_valve.py, s = clip((dp - p_crack)/(p_full - p_crack), 0, 1),
    Q = C_d A s sqrt(2/rho) sroot(dp) + G_leak dp; backwards or below p_crack only the
    seat's leakage."""
    for p_in, p_out in [(0.0, 1.0e6), (0.0, 1.0e4), (5.0e4, 0.0), (1.0e5, 0.0)]:
        eq = steady(bench, base, {'chk_a.pressure': p_in, 'chk_b.pressure': p_out})
        assert eq['chk.opening'] == 0.0
        close('check_valve seat', eq['chk.flow'], G_SEAT * (p_in - p_out), 1e-9)
    for dp in [1.5e5, 2.0e5, 2.5e5, 3.0e5, 5.0e5, 1.0e6, 1.0e7]:
        eq = steady(bench, base, {'chk_a.pressure': dp + 1.0e6, 'chk_b.pressure': 1.0e6})
        s = min((dp - 1.0e5) / 2.0e5, 1.0)
        close('check_valve', eq['chk.opening'], s, 1e-12)
        close('check_valve', eq['chk.flow'], k(1.0e-5) * s * sroot(dp, 1.0e4) + G_SEAT * dp,
              1e-9)


def test_relief(bench, base, steps):
    """Truth: relief.py, static: the seat's leakage up to p_crack, then q_full s*
    sqrt(dp/p_full) besides, with s* linear from p_crack to p_full (1e-9); lagged: opening
    1 - exp(-t/tau) (63 % at tau within 2 %)."""
    for p in [1.0e7, 1.5e7, 1.55e7, 1.6e7, 1.7e7, 2.0e7, 3.0e7]:
        s = min(max((p - 1.5e7) / 2.0e6, 0.0), 1.0)
        q = steady(bench, base, {'rel_p.pressure': p})['rel.flow']
        close('relief static', q, 1.0e-3 * s * math.sqrt(p / 1.7e7) + G_SEAT * p, 1e-9)
    curve, at_tau = lag_error(steps, 'rel_lag.opening', 0.05, 1.0)
    assert at_tau < 0.02 and curve < 0.01


def test_volume_continuity(bench, base):
    """Truth: volume.py, dP/dt = beta/V * (sum of inflows), the inflows from the orifice law,
    at arbitrary node pressures (no air, far above the cavitation floor)."""
    n = bench.node_state('n4')
    for P in [9.0e6, 1.8e7, 2.5e6]:
        x = base.x.copy()
        x[n] = P
        dx, _ = bench.rhs(0.3, x, base.u)
        inflow = k(4.0e-6) * sroot(1.5e7 - P, 1.0e5) - k(3.0e-6) * sroot(P - 2.0e6, 1.0e5)
        close('volume', dx[n], BETA / 2.0e-5 * inflow, 1e-9)


def test_directional_valve(bench, base, steps):
    """Truth: directional_valve.py, Q = C_d A_max xi sqrt(2/rho) sroot(dp) + G_leak dp
    forward (1e-9), C_d A_max xi sqrt(2 dp/rho) at dp >> dp_cr (0.5 %), backwards only a
    seat's leakage with the load-holding check (under 1e-15 dp: 0.6 mL/min at 100 bar) and
    the same law both ways without it, the closed spool its leakage; the lagged spool
    follows a step as 1 - exp(-t/tau) (2 % at tau, 1 % on the curve)."""
    for dp, cmd in [(1.0e7, 0.7), (2.0e6, 0.3), (5.0e6, 1.0)]:
        q = steady(bench, base, {'dv_a.pressure': dp, 'dv.command': cmd})['dv.flow']
        close('directional_valve', q, k(1.0e-5) * cmd * sroot(dp, 5.0e4) + G_SPOOL * dp, 1e-9)
        close('directional_valve turbulent', q, k(1.0e-5) * cmd * math.sqrt(dp), 5e-3)
        back = steady(bench, base, {'dv_a.pressure': 0.0, 'dv_b.pressure': dp,
                                    'dv.command': cmd})
        assert -1.0e-15 * dp <= back['dv.flow'] < 0.0
        both = steady(bench, base, {'dv2_a.pressure': 0.0, 'dv2_b.pressure': dp,
                                    'dv2.command': cmd})
        close('directional_valve both ways', both['dv2.flow'], -q, 1e-9)
    shut = steady(bench, base, {'dv2_a.pressure': 1.0e7, 'dv2.command': 0.0})
    close('directional_valve closed', shut['dv2.flow'], G_SPOOL * 1.0e7, 1e-9)
    curve, at_tau = lag_error(steps, 'dvl.opening', 0.03, 0.8)
    assert at_tau < 0.02 and curve < 0.01


def test_pre_compensator(bench, base):
    """Truth: pre_compensator.py, the force balance on the spool: the metering drop is
    dp_set less the flow-force droop r_ff Q, less (s - 1/2) p_band (the spring's travel),
    within half the hysteresis; the metering edge passes the orifice law at that drop
    (1e-6): within 2 % of C_d A_valve xi sqrt(2 dp_set/rho) whatever the load."""
    for load, cmd in [(5.0e6, 0.6), (1.0e7, 0.6), (1.5e7, 0.6), (1.0e7, 1.0)]:
        eq = steady(bench, base, {'pre_l.pressure': load, 'pre_v.command': cmd})
        q, s, held = eq['pre_v.flow'], eq['pre.opening'], eq['pre.dp']
        assert 0.0 < s < 1.0
        assert abs(held - (1.0e6 - R_FF * q - (s - 0.5) * BAND)) <= HYST / 2 + 1.0
        close('pre_compensator edge', q, k(1.5e-5) * cmd * sroot(held, 5.0e4) + G_SPOOL * held,
              1e-6)
        close('pre_compensator', q, k(1.5e-5) * cmd * math.sqrt(1.0e6), 2e-2)


def test_post_compensator(bench, base):
    """Truth: post_compensator.py, the force balance on the spool: the valve outlet held at
    P_ls + dp_set + r_ff Q + (s - 1/2) p_band within half the hysteresis:
    Q = C_d A xi sqrt(2 (P_supply - P_ls - dp_set)/rho) within 1.5 %."""
    for p_ls, load in [(1.2e7, 1.2e7), (1.2e7, 8.0e6), (6.0e6, 4.0e6), (1.5e7, 1.0e7)]:
        eq = steady(bench, base, {'post_ls.pressure': p_ls, 'post_l.pressure': load})
        q, s = eq['post_v.flow'], eq['post.opening']
        want = p_ls + 1.0e6 + R_FF * q + (s - 0.5) * BAND
        assert abs(eq['node:n7m'] - want) <= HYST / 2 + 1.0
        close('post_compensator', q, k(1.5e-5) * 0.6 * math.sqrt(2.0e7 - p_ls - 1.0e6), 1.5e-2)


def test_priority_valve(bench, base):
    """Truth: priority_valve.py, the force balance on the spool: P_cf - P_ls held at
    dp_set - r_ff Q_cf + (y - 1/2) p_band within half the hysteresis, the priority load's
    flow within the band of C_d A_valve xi sqrt(2 dp_set/rho) whatever the ef load; as the supply
    falls short, ef gets nothing (its edge's leakage) before cf loses flow."""
    q_set = k(8.0e-6) * 0.5 * math.sqrt(1.0e6)
    for p_ef in [5.0e6, 1.0e7]:
        eq = steady(bench, base, {'pri_x.pressure': p_ef})
        q, y = eq['pri.cf_flow'], eq['pri.position']
        assert abs(eq['pri.dp'] - (1.0e6 - R_FF * q + (y - 0.5) * BAND)) <= HYST / 2 + 1.0
        # Within the band: sqrt(1 +- (p_band/2 + p_h/2)/dp_set) of the set flow, 3.2 %.
        close('priority_valve', q, q_set, math.sqrt(1.0 + (BAND + HYST) / 2.0 / 1.0e6) - 1.0)
        assert eq['pri.ef_flow'] > 0.5 * q_set      # really sharing
    x, seen = base.x, []
    for ap in [0.5, 0.2, 0.1, 0.07, 0.06, 0.055, 0.05, 0.04, 0.02]:
        eq = equilibrium(bench, {'pri_feed.aperture': ap}, x0=x)
        x = eq.x
        seen.append((eq['pri.cf_flow'] / q_set, eq['pri.ef_flow'] / q_set))
    # While ef still flows, cf keeps at least what the spool's travel to closing ef
    # leaves of the held drop (-p_band/2, the droop and half the hysteresis); ef's closed
    # edge only leaks (2e-13 x 200 bar = 4e-6 m^3/s).
    low = math.sqrt((1.0e6 - R_FF * q_set - BAND / 2 - HYST / 2) / 1.0e6)
    for cf, ef in seen:
        if ef > 0.05:
            assert low - 1e-3 <= cf <= 1.02, seen
        if cf < low - 1e-3:
            assert ef < 0.05, seen
    assert seen[0][1] > 1.0 and seen[-1][0] < 0.5, seen   # both regimes were reached


def test_shuttle_network(bench, base):
    """Truth: shuttle_network.py, P_ls solves k_s sroot(P_max - P_ls) = k_b sroot(P_ls):
    within 0.5 bar of the highest input, the others' seats shut (no flow from them)."""
    for p, best in [((5.0e6, 1.2e7, 8.0e6), 1), ((5.0e6, 1.2e7, 1.5e7), 2)]:
        eq = steady(bench, base, {f'sh_{i + 1}.pressure': v for i, v in enumerate(p)})
        hi = max(p)
        def seat_minus_bleed(P, hi=hi):
            return k(3.0e-6) * sroot(hi - P, 1.0e4) - k(2.0e-8) * sroot(P, 1.0e4)
        truth = brentq(seat_minus_bleed, 0.5 * hi, hi, xtol=1e-6)
        assert abs(eq['sh.pressure'] - hi) < 5.0e4 and eq['sh.selected'] == best
        close('shuttle_network', eq['sh.pressure'], truth, 1e-9)
        close('shuttle_network', eq[f'sh_{best + 1}.flow'], -k(2.0e-8) * sroot(truth, 1.0e4), 1e-6)
        for i, v in enumerate(p):
            if i != best:
                assert v < eq['sh.pressure'] and eq[f'sh_{i + 1}.flow'] == 0.0


def test_a_shuttle_network_bleeding_to_no_tank_is_refused(tmp_path):
    """Its tank port is optional only without a bleed: a bleed with nowhere to drain would
    leave the load-sensing line at the highest pressure it ever saw (a loaded machine gone
    idle at full LS pressure). One line names the port and the two ways out."""
    net = {k: copy.deepcopy(BENCH[k]) for k in ('sh_1', 'sh_2', 'sh_3', 'sh')}
    del net['sh']['ports']['tank']
    with pytest.raises(CircuitError) as exc:
        load_circuit(write_circuit(tmp_path, 'no_tank', FLUID, net))
    (line,) = [ln for ln in exc.value.lines if 'sh:' in ln]
    assert 'port tank is not connected' in line and 'A_bleed: 0' in line, exc.value.lines
    net['sh']['A_bleed'] = 0.0
    load_circuit(write_circuit(tmp_path, 'no_bleed', FLUID, net))


def test_cylinder(bench, base, steps):
    """Truth: statics of cylinder.py, P_a A_a = F + c v, the feed orifice passing A_a v
    (solved by brentq, 0.5 %); the position grows at that velocity in a run."""
    def velocity(F, P_s=1.5e7):
        return brentq(lambda v: k(5.0e-6) * sroot(P_s - (F + CYL['c'] * v) / CYL['A_a'], 1.0e5)
                      - CYL['A_a'] * v, 0.0, 1.0, xtol=1e-14)
    for F in [3.0e4, 1.0e4]:
        eq = steady(bench, base, {'cyl.force': F})
        v = velocity(F)
        close('cylinder', eq['cyl.velocity'], v, 5e-3)
        close('cylinder', eq['cyl_o.flow'], CYL['A_a'] * v, 5e-3)
    pos = steps['cyl.position']
    close('cylinder position', (pos[-1] - pos[0]) / steps.t[-1], velocity(3.0e4), 5e-3)


def test_motor(bench, base):
    """Truth: statics of motor.py, D (P_a - P_b) = T + c w, the feed orifice passing
    D w + G_leak (P_a - P_b) (solved by brentq, 0.5 %)."""
    D, c, G = MOT['D'], MOT['c'], MOT['G_leak']
    for T in [30.0, 10.0]:
        def excess(w, T=T):
            P_a = (T + c * w) / D
            return k(5.0e-6) * sroot(1.5e7 - P_a, 1.0e5) - D * w - G * P_a
        w = brentq(excess, 0.0, 1.0e4, xtol=1e-12)
        eq = steady(bench, base, {'mot.torque': T})
        close('motor', eq['mot.speed'], w, 5e-3)
        close('motor', eq['node:n11'], (T + c * w) / D, 5e-3)


def test_tank_and_pressure_source(bench, base):
    """Truth: tank.py and pressure_source.py, the node at the set value exactly, the signal
    flow = the net inflow (the orifice law between them)."""
    for circuit, p_tank, p_src in [(bench, 2.0e5, 3.0e6),
                                   (bench.with_values({'ts_t.pressure': 5.0e5}), 5.0e5, 4.0e6)]:
        eq = equilibrium(circuit, {'ts_s.pressure': p_src}, x0=base.x)
        assert eq['node:n12t'] == p_tank and eq['ts_t.pressure'] == p_tank
        assert eq['node:n12'] == p_src and eq['ts_s.pressure'] == p_src
        q = k(2.0e-6) * sroot(p_src - p_tank, 1.0e5)
        close('tank', eq['ts_t.flow'], q, 1e-9)
        close('pressure_source', eq['ts_s.flow'], -q, 1e-9)


def test_orifice_load(bench, base):
    """Truth: eq. 9 (orifice_load.py), Q = mu xi (P - P_u)^(1/gamma) at dp >> dp_cr (1e-4),
    with I3's regularisation mu xi dp (dp^2 + dp_cr^2)^((1/gamma - 1)/2) (1e-9); gamma 2, 1."""
    laminar = bench.with_values({'ol.gamma': 1.0, 'ol.mu': 1.0e-10})
    for circuit, mu, gamma in [(bench, 3.0e-7, 2.0), (laminar, 1.0e-10, 1.0)]:
        for P, P_u, xi in [(1.0e7, 4.0e6, 0.7), (2.0e7, 1.0e6, 0.2), (1.0e7, 9.0e6, 1.0)]:
            eq = equilibrium(circuit, {'ol_s.pressure': P, 'ol.load_pressure': P_u,
                                       'ol.aperture': xi}, x0=base.x)
            dp, e = P - P_u, 1.0 / gamma
            close(f'orifice_load gamma {gamma:g}', eq['ol.flow'],
                  mu * xi * dp * (dp * dp + 1.0e8) ** (0.5 * (e - 1.0)), 1e-9)
            close(f'orifice_load gamma {gamma:g} power law', eq['ol.flow'], mu * xi * dp ** e,
                  1e-4)


# ---- the compiler's errors ------------------------------------------------------------------

ORF = orf('sn', 'tn', 1.0e-5)
MINI = {'s': src('sn', 1.0e6), 'o': ORF, 't': {'type': 'tank', 'ports': {'node': 'tn'}}}
MOTOR = {'type': 'motor', 'ports': {'a': 'ma', 'b': 'mb'}, 'D': 1.0e-6, 'J': 0.01, 'V_a': 1.0e-4}


@pytest.mark.parametrize('change, names', [
    ({'o': {**ORF, 'type': 'orifise'}}, ['o:', 'orifise']),                 # unknown type
    ({'o': {**ORF, 'Area': 1.0e-5}}, ['o.Area']),                           # unknown parameter
    ({'o': {**ORF, 'ports': {'a': 'sn'}}}, ['o:', 'port b']),               # port left open
    ({'o': {**ORF, 'ports': {'a': 'sn', 'b': 'tn', 'c': 'xn'}}}, ['o:', "'c'"]),  # no such port
    ({'t2': MINI['t']}, ['node tn', ' t ', 't2']),                          # two tanks
    ({'o': orf('sn', 'mid', 1.0e-5), 'o2': orf('mid', 'tn', 1.0e-5)},       # no volume
     ['node mid', 'o.b', 'o2.a']),
    ({'m': MOTOR, 'vb': vol('mb', 1.0e-4)}, ['node mb', 'm.b', 'return path']),  # an island
    # a motor fed from a source whose outlet goes into a dead-end volume
    ({'o': orf('sn', 'ma', 1.0e-5), 'm': MOTOR, 'vb': vol('mb', 1.0e-4)},
     ['node mb', 'm.b', 'return path']),
])
def test_circuit_errors(tmp_path, change, names):
    """Each bad input: a CircuitError whose lines are single lines, one naming the
    component, the port or the node."""
    comps = copy.deepcopy({**MINI, **change})
    with pytest.raises(CircuitError) as info:
        load_circuit(write_circuit(tmp_path, 'bad', FLUID, comps))
    lines = info.value.lines
    assert lines and all('\n' not in ln for ln in lines)
    assert any(all(n in ln for n in names) for ln in lines), lines
