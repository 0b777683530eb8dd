"""The shipped circuits against what is known of them from outside the compiler:

- ``paper.yaml`` computes what the paper's plant alone computes (``simulate``), a separate
  code path with the same equations, to 1e-6 of every signal;
- Fig. 1's steady states against the closed forms of load sensing: a pre-compensated
  section's flow ``C_d A xi sqrt(2 dp_c/rho)`` whatever its load, the priority load's flow
  held while the others change, flow sharing's ratios and pre-compensation's starving order
  when the pump saturates, the margin held against the highest load;
- continuity: over a 10 s duty cycle, the volume pumped less every volume that left equals
  the volume the nodes' compressibility stored, ``sum V_i dP_i / beta`` (an invariant of the
  equations, so to the stepper's rounding).
"""

import math

import numpy as np
import pytest

from hydropump_sim import load_params, simulate
from hydropump_sim.circuit import CircuitError, load_circuit
from hydropump_sim.model import OUTPUTS
from hydropump_sim.simulate import IntegratorConfig
from hydropump_sim.steady import equilibrium

from ..conftest import PUMP_YAML, ROOT

CIRCUITS = ROOT / 'config' / 'circuits'
# The paper plant's outputs and the paper circuit's signals that are the same quantity.
PAPER_SIGNALS = {'I_s': 'pump.current', 'x_c': 'pump.x_c', 'v_c': 'pump.v_c', 'x_a': 'pump.x_a',
                 'v_a': 'pump.v_a', 'P_a': 'pump.P_a', 'P_l': 'pump.P_l', 'Q_p': 'pump.Q_p',
                 'Q_a': 'pump.Q_a', 'q_l': 'pump.q_l', 'Q_load': 'load.flow',
                 'Q_relief': 'relief.flow', 'P_u': 'load.load_pressure'}
STEPPED = IntegratorConfig(dense=False)


def step(t0, a, b):
    return lambda t: np.where(np.asarray(t) < t0, a, b)


@pytest.fixture(scope='module')
def fig1():
    return load_circuit(CIRCUITS / 'fig1.yaml')


@pytest.mark.parametrize('overrides', [{}, {'input.dither_amp': 0.004, 'input.dither_freq': 400.0,
                                            'relief.p_crack': 1.55e7, 'relief.p_full': 1.65e7}])
def test_the_paper_circuit_computes_what_the_plant_alone_computes(overrides):
    """Current steps and a sine, an aperture and a load-pressure step (the relief valve
    opens in the second case); the same start, the same stepping."""
    params = load_params(PUMP_YAML).replace(overrides) if overrides else load_params(PUMP_YAML)
    circuit = load_circuit(CIRCUITS / 'paper.yaml', plant=params)
    assert len(circuit.states) == 6 and circuit.states[-1] == 'node:line'

    def current(t):
        t = np.asarray(t)
        return np.where(t < 0.3, 0.46, 0.58) + 0.02 * np.sin(2 * np.pi * 3.0 * t)
    inputs = dict(current=current, aperture=step(1.0, 0.5, 0.35),
                  load_pressure=step(1.4, 1.2e7, 1.35e7))
    ref = simulate(params, 2.0, config=STEPPED, **inputs)
    res = simulate(circuit, 2.0, {'pump.current': current,
                                          'load.aperture': inputs['aperture'],
                                          'load.load_pressure': inputs['load_pressure']},
                           x0=ref.x[0], config=STEPPED)
    for out, sig in PAPER_SIGNALS.items():
        a, b = getattr(ref, out), res[sig]
        scale = max(np.max(np.abs(a)), 1e-12)
        assert np.max(np.abs(a - b)) <= 1e-6 * scale, (out, np.max(np.abs(a - b)) / scale)
    if overrides:
        assert ref.Q_relief.max() > 1e-5  # the relief valve took part
    # The circuit's own steady state is the plant's.
    from hydropump_sim import equilibrium as plant_equilibrium
    eq_p = plant_equilibrium(params, 0.55)
    eq_c = equilibrium(circuit, {'pump.current': 0.55})
    for out in OUTPUTS:
        assert eq_c[PAPER_SIGNALS[out]] == pytest.approx(getattr(eq_p, out),
                                                         rel=1e-6, abs=1e-9), out


def _k(A, rho, C_d=0.65):
    return C_d * A * math.sqrt(2.0 / rho)


def _opening(command, overlap=0.1):
    """A 4/3 valve edge's opening past its overlap (valve_4_3.py), as a fraction."""
    return min(max((command - overlap) / (1.0 - overlap), 0.0), 1.0)


def _held(dp_set, q=0.0, p_band=1.0e5, p_h=3.0e4, r_ff=1.0e8):
    """The range of the drop a compensating spool holds at flow ``q``: its setting less the
    flow-force droop ``r_ff q``, within half its regulation range and half its hysteresis
    (pre_compensator.py), as a flow ratio ``sqrt(dp/dp_set)``."""
    dev = 0.5 * p_band + 0.5 * p_h
    return (math.sqrt((dp_set - r_ff * q - dev) / dp_set),
            math.sqrt((dp_set + dev) / dp_set))


def test_pre_compensated_flow_is_the_closed_form_whatever_the_load(fig1):
    """Boom at half command, relief-limited supply (the pump well above the demand): the
    metered flow is C_d A_max a(xi) sqrt(2 dp/rho) with dp the compensator's setting within
    its regulation range, for a light and a heavy load; the double-acting cylinder's force
    balance holds with its meter-out back pressure."""
    rho = fig1.fluid.rho
    want = _k(2.2e-5, rho) * _opening(0.5) * math.sqrt(1.0e6)
    lo, hi = _held(1.0e6, want)
    flows = []
    for force in (2.0e4, 6.0e4, 9.0e4):
        eq = equilibrium(fig1, {'pump.current': 0.7, 'boom.command': 0.5,
                                'boom.force': force})
        # The cylinder's force balance: load, viscous friction, the rod side's pressure.
        assert eq['boom.pressure'] * 5.03e-3 - eq['boom.pressure_b'] * 2.57e-3 == \
            pytest.approx(force + 2.0e4 * eq['boom.velocity'], rel=1e-3)
        assert lo * want <= eq['boom.flow'] <= hi * want, force
        assert eq['relief.flow'] > 1e-5  # the supply is not what limits the flow
        flows.append(eq['boom.flow'])
    assert np.ptp(flows) < (hi - lo) * want  # whatever the load


def test_the_priority_load_keeps_its_flow_while_the_others_vary(fig1):
    """Steering at half command behind the priority valve: its flow is its metering
    edge's at the priority spring, C_d A a(xi) sqrt(2 dp_pr/rho) within the spool's
    regulation range, as the loads on demand start and stop."""
    want = _k(8.9e-6, fig1.fluid.rho) * _opening(0.5) * math.sqrt(7.0e5)
    lo, hi = _held(7.0e5, want)
    for boom, motor in ((0.0, 0.0), (0.8, 0.0), (0.8, 0.6), (0.2, 1.0)):
        eq = equilibrium(fig1, {'pump.current': 0.9, 'boom.command': boom,
                                'motor.command': motor})
        assert lo * want <= eq['steering.flow'] <= hi * want, (boom, motor)


def _saturated(circuit):
    """Boom and motor fully open with the steering: more than the pump's 67.5 L/min, the
    pump at full displacement, the relief valve shut (its seat's leakage only)."""
    eq = equilibrium(circuit, {'pump.current': 0.9, 'boom.command': 1.0,
                               'motor.command': 1.0})
    q_max = circuit.pump().comp.params.plant.Q_max
    assert eq['pump.Q_p'] == pytest.approx(q_max, rel=1e-3)
    assert eq['relief.flow'] < 1e-7
    return eq


def test_flow_sharing_keeps_the_demand_ratio_when_the_pump_saturates(fig1):
    """Post-compensated: every metering edge sees the same drop, so the loads share the
    flow in the ratio of their openings (2.2e-5 : 1.8e-5 m^2), whatever their pressures,
    within what the compensators' regulation ranges leave of that drop."""
    post = fig1.with_values({'boom.compensator': 'post', 'motor.compensator': 'post'})
    eq = _saturated(post)
    drop = eq['node:demand'] - eq['node:ls'] - 1.0e6
    spread = (0.5e5 + 0.5 * 3.0e4) / drop   # the spools' band, as a share of the drop
    assert eq['boom.flow'] / eq['motor.flow'] == pytest.approx(2.2e-5 / 1.8e-5,
                                                               rel=max(spread, 0.01))
    # Both slowed: each gets less than it does alone.
    alone = equilibrium(post, {'pump.current': 0.9, 'boom.command': 1.0})
    assert eq['boom.flow'] < 0.9 * alone['boom.flow']


def test_pre_compensation_starves_the_highest_load_first(fig1):
    """Pre-compensated: the lighter boom (119 bar) keeps its compensated flow; the motor
    (126 bar) takes what is left."""
    rho = fig1.fluid.rho
    eq = _saturated(fig1)
    boom_full = _k(2.2e-5, rho) * math.sqrt(1.0e6)
    motor_full = _k(1.8e-5, rho) * math.sqrt(1.0e6)
    lo, hi = _held(1.0e6, boom_full)
    assert eq['boom.pressure'] < eq['motor.pressure']
    assert lo * boom_full <= eq['boom.flow'] <= hi * boom_full
    assert eq['motor.flow'] < 0.9 * motor_full
    # The highest load swapped (a light motor, a heavy boom): the boom now starves.
    heavy = equilibrium(fig1, {'pump.current': 0.9, 'boom.command': 1.0,
                               'motor.command': 1.0, 'boom.force': 7.0e4,
                               'motor.torque': 20.0})
    lo, hi = _held(1.0e6, motor_full)
    assert lo * motor_full <= heavy['motor.flow'] <= hi * motor_full
    assert heavy['boom.flow'] < 0.9 * boom_full


@pytest.mark.parametrize('algorithm, settle', [('emc', 5.0), ('pi', 8.0)])
def test_margin_control_holds_the_margin_over_the_highest_load(fig1, algorithm, settle):
    """Closed loop (designed for this circuit, ideal sensors), every load fed: after the
    loads settle, P_l - max P_i is the margin within 0.5 bar (the PI climbs out of the
    starvation of the loads' start more slowly; the motor rings at its oil spring for a
    few seconds)."""
    from hydropump_ctrl.experiments.circuit_loop import run_circuit
    # Steering held at 0.3: its cylinder stays inside its stroke for the whole run.
    run = run_circuit(fig1, settle + 0.5, {'boom.command': step(0.2, 0.0, 0.7),
                                           'motor.command': step(0.8, 0.0, 0.5),
                                           'steering.command': 0.3},
                      algorithm=algorithm, margin=2.0e6)
    end = run.t > settle
    highest = np.maximum.reduce([run[f'{n}.pressure'] for n in ('steering', 'boom', 'motor')])
    margin = run['pump.P_l'] - highest
    assert np.max(np.abs(margin[end] - 2.0e6)) < 0.5e5, (margin[end].min(), margin[end].max())


def test_continuity_balances_over_a_duty_cycle():
    """10 s: the pump stepped, loads switched on and off. The volume delivered, less what
    returned to tank and what the cylinders' chambers swept, is what the nodes stored,
    ``sum integral V_i(t) dP_i / beta`` (the chambers' volumes follow the pistons): the
    meters are exact to the stepper's rounding, the stored volume is integrated from the
    samples (trapezoids on 0.5 ms), so the balance holds to 1e-3 of the stored volume."""
    c = load_circuit(CIRCUITS / 'fig1.yaml', meters=('pump.q_l', 'tank.flow'))
    inputs = {'pump.current': step(5.0, 0.45, 0.6),
              'steering.command': lambda t: np.where(np.asarray(t) % 5.0 < 3.0, 0.5, 0.0),
              'boom.command': lambda t: np.where((np.asarray(t) > 1) & (np.asarray(t) < 6),
                                                 0.8, 0.0),
              'motor.command': step(3.0, 0.0, 0.6)}
    r = simulate(c, 10.0, inputs, dt_out=5.0e-4)
    floor = c.fluid.dp_floor - c.fluid.p_atm
    assert min(r.node(n).min() for n in c.volume) > floor  # no node cavitated

    def delta(state):
        k = c.states.index(state)
        return r.x[-1, k] - r.x[0, k]
    swept = sum((pt.comp.params.A_a - pt.comp.params.A_b) * delta(f'{pt.comp.name}.position')
                for pt in c.role('actuator') if hasattr(pt.comp.params, 'A_a'))
    left = delta('meter:pump.q_l') - delta('meter:tank.flow') - swept
    stored = sum(np.trapezoid(r[f'node:{n}.volume'], r.node(n)) / c.fluid.beta
                 for n in c.volume)
    assert delta('meter:pump.q_l') > 1e2 * abs(stored)  # the balance is a small difference
    assert left == pytest.approx(stored, rel=1e-3)


@pytest.mark.parametrize('sets, words', [
    ({'boom.compensator': 'mid'}, ['boom.compensator', 'pre, post, none']),
    ({'boom.valve.A_mx': 1.0e-5}, ['boom.valve.A_mx', 'did you mean A_max']),
    ({'boom.command': 3.0}, ['boom.valve.command', '[-1, 1]']),
    ({'relief.p_full': 1.0e7}, ['relief', 'p_full', 'p_crack']),
    ({'bom.command': 0.5}, ['bom', 'did you mean boom']),
    # YAML 1.1 (what --set and params files are read as) takes 6e4 for text: the fix said.
    ({'boom.force': '6e4'}, ['boom.cylinder.force', 'YAML read it as text', '1.5e+9']),
])
def test_a_bad_set_value_is_one_line_naming_it(sets, words):
    with pytest.raises(CircuitError) as info:
        load_circuit(CIRCUITS / 'fig1.yaml', sets, compile=False)
    assert len(info.value.lines) == 1 and all(w in info.value.lines[0] for w in words), \
        info.value.lines
