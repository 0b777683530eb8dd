"""The energy account (hydropump_sim/energy.py): where the pump's power goes.

Truths:

- conservation: at every instant the power supplied equals what the loads take, what is
  stored and what is dissipated; each component's terms come from its own equations, so a
  flow no term carries, or a loss taken on the wrong pressure, breaks it. Checked over whole
  runs of every kind of component (the test asserts that every kind registered ran);
- an accumulator's gas takes the polytropic work ``(p2 V2 - p1 V1)/(n - 1)`` in absolute
  pressures (less what the atmosphere does, ``p_atm dV``), from its end states alone;
- a cylinder's load takes ``F dx``, its force times its stroke;
- the checker's own test: a circuit whose account does not close is named, with the time.
"""

import math

import numpy as np
import pytest

from hydropump_sim import energy, invariants
from hydropump_sim.circuit import load_circuit
from hydropump_sim.components import registry
from hydropump_sim.simulate import simulate
from hydropump_sim.steady import equilibrium

from ..conftest import ROOT
from .conftest import write_circuit

CIRCUITS = ROOT / 'config' / 'circuits'
FLUID = dict(rho=870.0, beta=1.6e9, nu=3.2e-5, alpha_air=0.0, p_atm=1.013e5, P_T=0.0)


def src(node, p):
    return {'type': 'pressure_source', 'ports': {'node': node}, 'pressure': p}


# What the shipped circuits do not hold: a meter-in valve, a pilot-operated check, a cylinder
# lifting a force, an accumulator charged, all from held pressures.
RIG = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    'supply': src('p', 1.2e7),
    'dv': {'type': 'directional_valve', 'ports': {'in': 'p', 'out': 'a'}, 'A_max': 2.0e-6,
           'command': 0.5},
    'poc': {'type': 'pilot_check', 'ports': {'in': 'a', 'out': 'cap', 'pilot': 'p'},
            'A': 1.0e-5},
    'cyl': {'type': 'cylinder', 'ports': {'a': 'cap', 'b': 'rod'}, 'A_a': 2.0e-3,
            'A_b': 1.0e-3, 'm': 50.0, 'stroke': 1.0, 'V_a': 1.0e-4, 'V_b': 1.0e-4, 'x0': 0.2,
            'force': 1.0e4},
    'rod_out': {'type': 'orifice', 'ports': {'a': 'rod', 'b': 'tank'}, 'A': 5.0e-6},
    'a_vol': {'type': 'volume', 'ports': {'node': 'a'}, 'V': 1.0e-5},
    'acc_in': {'type': 'orifice', 'ports': {'a': 'p', 'b': 'acc'}, 'A': 1.0e-6},
    'acc_vol': {'type': 'volume', 'ports': {'node': 'acc'}, 'V': 1.0e-6},
    'acc': {'type': 'accumulator', 'ports': {'port': 'acc'}, 'V0': 1.0e-3, 'p0': 2.0e6,
            'n': 1.4, 'V_oil0': 1.0e-5},
    'relief': {'type': 'relief', 'ports': {'in': 'p', 'out': 'tank'}, 'p_crack': 2.0e7,
               'p_full': 2.1e7, 'q_full': 1.0e-3},
}


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    return load_circuit(write_circuit(tmp_path_factory.mktemp('energy'), 'rig', FLUID, RIG))


def _runs(rig):
    """A run of every kind of component: the shipped circuits with their loads moving."""
    fig1 = load_circuit(CIRCUITS / 'fig1.yaml')
    excavator = load_circuit(CIRCUITS / 'excavator.yaml')
    idle = {'pump.current': excavator.plant_params().current_range[0]}
    yield simulate(fig1, 0.4, inputs={'boom.command': 0.6, 'motor.command': 0.5})
    post = fig1.with_values({'boom.compensator': 'post', 'motor.compensator': 'post',
                             'pump.type': 'ls_pump', 'pump.ls.margin': 2.5e6})
    yield simulate(post, 0.4, inputs={'boom.command': 0.6, 'motor.command': 0.5})
    yield simulate(load_circuit(CIRCUITS / 'paper.yaml'), 0.3)
    yield simulate(load_circuit(CIRCUITS / 'three_loads.yaml'), 0.3)
    yield simulate(excavator, 0.4, inputs={**idle, 'boom.command': -0.5,
                                           'swing.command': lambda t: 0.8 * (t > 0.1)})
    yield simulate(rig, 0.5, dt_out=1.0e-4)


def test_every_kind_of_component_balances_its_energy_at_every_instant(rig):
    seen = set()
    for r in _runs(rig):
        c = r.model
        seen |= {type(pt.comp).kind for pt in c.parts}
        bal = r['power:balance']
        bound = energy.balance_bound(r.y, c.signal_index)
        assert np.all(np.abs(bal) <= bound), (c.name, float(np.max(np.abs(bal) / bound)))
        # The terms are not all zero: something was supplied and dissipated.
        a = energy.account(r)
        assert a.supply > 0.0 and a.loss > 0.0, c.name
        assert a.relative < 1.0e-9, (c.name, a)
        assert sum(a.groups.values()) == pytest.approx(a.loss, rel=1e-12)
        assert all(v >= -1e-9 for v in a.groups.values()), a.groups
    # A composite's parts ran; an FMU load steps beside the circuit, not in simulate()
    # (tests/unit/test_fmi_loads.py balances it).
    kinds = {k for k, cls in registry().items() if 'external' not in cls.ROLES} - {'section'}
    assert kinds <= seen, sorted(kinds - seen)


def test_accumulator_gas_takes_the_polytropic_work(rig):
    # From the rig at rest with the accumulator nearly empty.
    x0 = equilibrium(rig).x.copy()
    x0[rig.states.index('acc.V_oil')] = 1.0e-5
    comp = next(pt.comp for pt in rig.parts if pt.comp.name == 'acc')
    x0[rig.states.index('node:acc')] = comp.gas_pressure(1.0e-5)
    r = simulate(rig, 0.5, x0=x0, dt_out=1.0e-4)
    p = comp.params
    p_atm = FLUID['p_atm']
    v1, v2 = r['acc.volume'][0], r['acc.volume'][-1]
    assert v2 > 2.0 * v1   # it charged

    def p_abs(v_oil):
        return (p.p0 + p_atm) * (p.V0 / (p.V0 - v_oil)) ** p.n
    gas = ((p_abs(v2) * (p.V0 - v2) - p_abs(v1) * (p.V0 - v1)) / (p.n - 1.0)
           - p_atm * (v2 - v1))
    stored = float(np.trapezoid(r['acc.stored'], r.t))
    # 0.1 %: the trapezoidal rule over the charge's first 0.1 ms, where the inlet's flow
    # jumps.
    assert stored == pytest.approx(gas, rel=1e-3)


def test_a_cylinder_load_takes_its_force_times_its_stroke(rig):
    r = simulate(rig, 0.5, dt_out=1.0e-4)
    x = r['cyl.position']
    assert x[-1] - x[0] > 0.01   # it moved
    work = float(np.trapezoid(r['cyl.work'], r.t))
    assert work == pytest.approx(1.0e4 * (x[-1] - x[0]), rel=1e-5)


def test_the_checker_names_energy_made_from_nothing(rig):
    r = simulate(rig, 0.1)
    y = r.y.copy()
    k = rig.signal_index('power:balance')
    y[60, k] += 1.0e3   # a kilowatt from nowhere at t = 60 ms
    found = [v for v in invariants.check(rig, r.t, y, r.u)
             if v.invariant == 'energy not balanced']
    assert len(found) == 1
    assert found[0].t == pytest.approx(r.t[60])
    assert math.isclose(found[0].value, r['power:balance'][60] + 1.0e3, rel_tol=1e-9)
    assert 'energy not balanced' in invariants.report(found)
