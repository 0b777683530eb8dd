"""The components of a real machine against closed forms computed here, the bad inputs a
machine's file can hold, and the excavator holding its boom.

Truths (from the components' module docstrings and textbook statics, written out with the
test's own helpers; no value the code printed is reused):

- cylinder (cylinder.py): each chamber's volume is its dead volume plus what the piston
  swept, ``V_a + A_a x`` and ``V_b + A_b (L - x)``; at a steady velocity the force balance
  with Stribeck friction ``c v + (F_c + (F_s - F_c) exp(-(v/v_s)^2)) tanh(v/v_eps)``; at
  rest on its end stop the ports pass exactly the internal leakage ``G_int (P_a - P_b)``;
  inside an end cushion the cushion's throttle force ``A rho/2 (A v / (0.7 A_c))^2``;
- motor (motor.py): its angle grows at its speed;
- the pump's pressure cut-off (pump.py): at rest it holds the pressure where eq. 8's flow
  at the current less the cut-off's override ``g (P - p_set)`` equals what the outlet takes,
  with ``g`` the full current range over the band;
- reducing valve: its outlet at ``dp_set`` above its reference, within half its regulation
  range, hysteresis and droop;
- the excavator's boom held by its counterbalance valve, its 4/3 valve closed, sinks only
  by its piston seal's leakage: ``G_int P_cap / A_a``, under 1 mm/min (60 s simulated).
"""

import math

import numpy as np
import pytest
from scipy.optimize import brentq
import yaml

from hydropump_sim.circuit import CircuitError, load_circuit
from hydropump_sim.params import load_params
from hydropump_sim.simulate import simulate
from hydropump_sim.steady import equilibrium

from ..conftest import PUMP_YAML, ROOT
from .conftest import write_circuit

RHO, BETA = 870.0, 1.6e9
FLUID = dict(rho=RHO, beta=BETA, nu=3.2e-5, alpha_air=0.0, p_atm=1.013e5, P_T=0.0)
CYL = dict(A_a=3.14e-3, A_b=1.91e-3, m=300.0, stroke=1.0, V_a=5.0e-4, V_b=4.0e-4, c=2.0e3,
           F_coul=800.0, F_stat=1500.0, v_s=0.02, v_eps=1.0e-3, G_int=2.0e-13)


def k(A, C_d=0.65):
    return C_d * A * math.sqrt(2.0 / RHO)


def sroot(dp, dp_cr):
    return dp / (dp * dp + dp_cr * dp_cr) ** 0.25


def src(node, p):
    return {'type': 'pressure_source', 'ports': {'node': node}, 'pressure': p}


RIG = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    # A cylinder driven through two orifices from held pressures.
    'ca_s': src('ca_src', 1.2e7), 'ca_o': {'type': 'orifice', 'ports': {'a': 'ca_src', 'b': 'ca'},
                                           'A': 2.0e-6},
    'cb_s': src('cb_src', 0.0), 'cb_o': {'type': 'orifice', 'ports': {'a': 'cb', 'b': 'cb_src'},
                                         'A': 4.0e-6},
    'cyl': {'type': 'cylinder', 'ports': {'a': 'ca', 'b': 'cb'}, 'x0': 0.3, 'force': 2.0e4,
            **CYL},
    # The same cylinder straight on held pressures, parked on its end stop.
    'cs_a': src('cs_a', 9.0e6), 'cs_b': src('cs_b', 1.0e6),
    'cyl_stop': {'type': 'cylinder', 'ports': {'a': 'cs_a', 'b': 'cs_b'}, 'x0': 1.0,
                 'force': 1.0e4, **CYL},
    # In its cushion: the last 50 mm, throttled through 1e-5 m^2.
    'cu_a': src('cu_a', 8.0e6), 'cu_b': src('cu_b', 0.0),
    'cyl_cush': {'type': 'cylinder', 'ports': {'a': 'cu_a', 'b': 'cu_b'}, 'x0': 0.97,
                 'force': 1.0e4, 'l_cush': 0.05, 'A_cush': 1.0e-5, **CYL},
    # A motor on held pressures.
    'm_a': src('m_a', 5.0e6), 'm_b': src('m_b', 0.0),
    'mot': {'type': 'motor', 'ports': {'a': 'm_a', 'b': 'm_b'}, 'D': 3.0e-6, 'J': 0.02,
            'c': 0.01, 'V_a': 1.0e-4, 'torque': 5.0},
    # A reducing valve feeding a bleed.
    'r_s': src('r_src', 2.0e7), 'r_v': {'type': 'reducing_valve',
                                        'ports': {'in': 'r_src', 'out': 'r_out', 'ref': 'tank'},
                                        'A_max': 2.0e-6, 'dp_set': 4.0e6},
    'r_vol': {'type': 'volume', 'ports': {'node': 'r_out'}, 'V': 1.0e-5},
    'r_use': {'type': 'orifice', 'ports': {'a': 'r_out', 'b': 'tank'}, 'A': 1.0e-7},
}


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    return load_circuit(write_circuit(tmp_path_factory.mktemp('machine'), 'rig', FLUID, RIG))


def stribeck(v):
    c = CYL
    return c['c'] * v + (c['F_coul'] + (c['F_stat'] - c['F_coul'])
                         * math.exp(-(v / c['v_s']) ** 2)) * math.tanh(v / c['v_eps'])


def test_cylinder_chambers_friction_and_leakage(rig):
    eq = equilibrium(rig)
    v = eq['cyl.velocity']
    assert v > 0.0
    # The force balance with Stribeck friction at the steady velocity (1e-6).
    P_a, P_b = eq['node:ca'], eq['node:cb']
    force = P_a * CYL['A_a'] - P_b * CYL['A_b'] - 2.0e4
    assert force == pytest.approx(stribeck(v), rel=1e-6)
    # The feed and the drain pass the swept flows and the piston's leakage (1e-6).
    leak = CYL['G_int'] * (P_a - P_b)
    assert eq['ca_o.flow'] == pytest.approx(CYL['A_a'] * v + leak, rel=1e-6)
    assert eq['cb_o.flow'] == pytest.approx(CYL['A_b'] * v + leak, rel=1e-6)
    # Parked on its end stop: nothing but the seal's leakage between the ports.
    assert eq['cyl_stop.velocity'] == pytest.approx(0.0, abs=1e-9)
    assert eq['cs_a.flow'] == pytest.approx(-CYL['G_int'] * 8.0e6, rel=1e-6)
    # The chambers follow the piston over a run.
    r = simulate(rig, 0.5, x0=eq.x)
    x = r['cyl.position']
    assert x[-1] - x[0] == pytest.approx(0.5 * v, rel=1e-3)
    np.testing.assert_allclose(r['node:ca.volume'], CYL['V_a'] + CYL['A_a'] * x, rtol=1e-12)
    np.testing.assert_allclose(r['node:cb.volume'],
                               CYL['V_b'] + CYL['A_b'] * (CYL['stroke'] - x), rtol=1e-12)


def test_end_cushion_throttles_the_last_of_the_stroke(rig):
    """Inside its cushion (20 mm in, past the ramp's 50 mm: 40 %), the piston's steady
    velocity balances the cushion throttle's force on the rod side's area."""
    eq = equilibrium(rig)
    v = eq['cyl_cush.velocity']
    kc = 0.5 * RHO / (0.7 * 1.0e-5) ** 2

    def excess(u):
        cush = kc * CYL['A_b'] ** 3 * u * u * (0.02 / 0.05)
        return 8.0e6 * CYL['A_a'] - 1.0e4 - stribeck(u) - cush
    truth = brentq(excess, 1e-6, 5.0)
    assert v == pytest.approx(truth, rel=1e-6)
    assert v < 0.2 * (8.0e6 * CYL['A_a'] - 1.0e4) / CYL['c']  # the cushion brakes it


def test_motor_angle_grows_at_its_speed(rig):
    eq = equilibrium(rig)
    w = (5.0e6 * 3.0e-6 - 5.0) / 0.01      # D dp = T + c w, no Coulomb friction
    assert eq['mot.speed'] == pytest.approx(w, rel=1e-6)
    r = simulate(rig, 0.2, x0=eq.x)
    assert r['mot.angle'][-1] - r['mot.angle'][0] == pytest.approx(0.2 * w, rel=1e-6)


def test_reducing_valve_holds_its_outlet(rig):
    eq = equilibrium(rig)
    q = eq['r_use.flow']
    # The setting less the droop, within half the regulation range and the hysteresis.
    dev = 0.5 * 1.0e5 + 0.5 * 3.0e4
    assert 4.0e6 - 1.0e8 * q - dev <= eq['node:r_out'] <= 4.0e6 + dev
    assert q == pytest.approx(k(1.0e-7) * sroot(eq['node:r_out'], 1.0e5), rel=1e-9)


def test_the_pump_cut_off_holds_its_pressure(tmp_path):
    """The paper's pump at full current into a small orifice: the cut-off destrokes it
    where eq. 8 (x_a = phi_s i_s / K_a at rest, x_c = 0) at the current less the override
    gives what the orifice takes."""
    params = load_params(PUMP_YAML)
    doc = {'name': 'cut', 'plant': str(PUMP_YAML), 'components': {
        'pump': {'type': 'pump', 'ports': {'out': 'line'}, 'current': 0.85,
                 'cutoff': {'p_set': 1.5e7, 'band': 2.0e6}},
        'line_volume': {'type': 'volume', 'ports': {'node': 'line'}, 'V': 5.0e-4},
        'use': {'type': 'orifice', 'ports': {'a': 'line', 'b': 'tank'}, 'A': 4.0e-6,
                'dp_cr': 0.0},
        'relief': {'type': 'relief', 'ports': {'in': 'line', 'out': 'tank'},
                   'p_crack': 2.5e7, 'p_full': 2.6e7, 'q_full': 1.35e-3},
        'tank': {'type': 'tank', 'ports': {'node': 'tank'}}}}
    path = tmp_path / 'cut.yaml'
    path.write_text(yaml.safe_dump(doc))
    eq = equilibrium(load_circuit(path))
    sp, pu = params.spool, params.pump
    g = 2.0 * sp.I_max / 2.0e6

    def excess(P):
        i_s = 0.85 - params.I_nominal - g * (P - 1.5e7)
        x_a = sp.phi_s * i_s / sp.K_a
        Q_p = pu.V_p * pu.f_p * min(max(0.5 + x_a / pu.x_a_max, 0.0), 1.0)
        return Q_p - 0.65 * 4.0e-6 * math.sqrt(2.0 * P / params.fluid.rho)
    truth = brentq(excess, 1.5e7, 1.7e7)
    assert 1.5e7 < eq['pump.P_l'] < 1.7e7                # within the cut-off's band
    assert eq['pump.P_l'] == pytest.approx(truth, rel=2e-3)
    assert eq['relief.flow'] < 1e-7                       # the relief takes nothing


# ---- bad input ----------------------------------------------------------------------------

MINI = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    's': src('sn', 1.0e7),
    'relief': {'type': 'relief', 'ports': {'in': 'sn', 'out': 'tank'}, 'p_crack': 2.0e7,
               'p_full': 2.1e7, 'q_full': 1.0e-3},
}


@pytest.mark.parametrize('extra, words', [
    ({'v': {'type': 'valve_4_3', 'ports': {'P': 'sn', 'A': 'na'}, 'A_max': 1e-5},
      'na_v': {'type': 'volume', 'ports': {'node': 'na'}, 'V': 1e-4}},
     ['v: port T is not connected']),
    ({'cyl': {'type': 'cylinder', 'ports': {'a': 'sn'}, 'A_a': 1e-3, 'm': 10.0, 'stroke': 0.5,
              'V_a': 0.0}}, ['cyl.V_a = 0']),
    ({'cyl': {'type': 'cylinder', 'ports': {'a': 'sn'}, 'A_a': 1e-3, 'm': 10.0, 'stroke': 0.5,
              'V_a': -1e-4}}, ['cyl.V_a = -0.0001']),
    ({'acc': {'type': 'accumulator', 'ports': {'port': 'sn'}, 'V0': 1e-3, 'p0': 2.5e7}},
     ['acc: precharged at 250 bar', 'never take oil']),
    ({'cb': {'type': 'counterbalance', 'ports': {'load': 'sn', 'valve': 'nv', 'pilot': 'tank'},
             'A': 1e-4, 'p_set': 2e7, 'ratio': 0.0},
      'nv_v': {'type': 'volume', 'ports': {'node': 'nv'}, 'V': 1e-4}}, ['cb.ratio = 0']),
    ({'h': {'type': 'hose', 'ports': {'a': 'sn', 'b': 'tank'}, 'L': 0.0, 'd': 0.02}},
     ['h.L = 0']),
])
def test_a_bad_machine_is_one_line_naming_the_component(tmp_path, extra, words):
    path = write_circuit(tmp_path, 'bad', FLUID, {**MINI, **extra})
    with pytest.raises(CircuitError) as err:
        load_circuit(path, compile=False)
    lines = err.value.lines
    assert all('\n' not in ln for ln in lines)
    assert any(all(w in ln for w in words) for ln in lines), lines


# ---- the excavator holding its boom ---------------------------------------------------------

def test_the_excavator_holds_its_boom_on_its_counterbalance_valve():
    c = load_circuit(ROOT / 'config' / 'circuits' / 'excavator.yaml')
    # Parked: the pump at its least current (no displacement), every spool centred.
    idle = {'pump.current': c.plant_params().current_range[0]}
    r = simulate(c, 60.0, inputs=idle, dt_out=0.01)
    boom = next(pt.comp.params for pt in c.role('actuator') if pt.comp.name == 'boom.cylinder')
    drift = (r['boom.position'][-1] - r['boom.position'][0]) / 60.0 * 60.0e3   # mm/min
    assert r['boom.brake_a.opening'].max() == 0.0          # held by the valve, shut
    assert -1.0 < drift < 0.0, drift
    # What the piston seal lets by from the loaded cap side (the rod side is vented).
    want = boom.G_int * r['boom.pressure'].mean() / boom.A_a * 60.0e3
    assert -drift == pytest.approx(want, rel=0.05)
