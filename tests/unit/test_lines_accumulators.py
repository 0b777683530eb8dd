"""The hose (lumped pi segments) and the bladder accumulator against closed forms.

Truths are textbook formulas written out here: Joukowsky's ``dp = rho c v0`` and the period
``4 L / c`` of water hammer, Hagen-Poiseuille's ``128 mu L / (pi d^4)``, Blasius' friction
factor, the orifice law and the polytropic gas law in absolute pressure. Two test-bench
structures, each compiled once: a pressure source feeding a hose that an orifice (the valve)
closes to tank, and two accumulators (isothermal and adiabatic) charged from pressure
sources through small orifices.

Each bench has a relief valve set above anything its runs reach, which never opens (its flow
is checked): the ceiling every real circuit has. A hose's water hammer rises above its
supply, and an accumulator charged earlier holds its pressure after its supply falls; the
invariants of every run (no pressure above what a source can make, checked against the held
inputs of each instant) need that ceiling to cover them.
"""

import math

import numpy as np
import pytest

from hydropump_sim.circuit import CircuitError, load_circuit
from hydropump_sim.simulate import simulate
from hydropump_sim.steady import equilibrium

from .conftest import write_circuit

RHO, BETA, NU, P_ATM = 870.0, 1.6e9, 1.5e-5, 1.013e5
FLUID = dict(rho=RHO, beta=BETA, nu=NU, alpha_air=0.0, p_atm=P_ATM, P_T=0.0)

# ---- the hose bench ---------------------------------------------------------------------

L_H, D_H = 10.0, 0.02          # m: the hose
BETA_H = 1.0e9                 # Pa: the hose's default effective bulk modulus (oil and wall)
P_S = 5.0e6                    # Pa: the supply
A_V = 4.5e-6                   # m^2: the valve (an orifice): about 1 m/s in the hose
T_CLOSE = 0.005                # s: the valve starts to close
HOSE = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    'supply': {'type': 'pressure_source', 'ports': {'node': 'hs'}, 'pressure': P_S},
    'hose': {'type': 'hose', 'ports': {'a': 'hs', 'b': 'hv'}, 'L': L_H, 'd': D_H},
    'valve': {'type': 'orifice', 'ports': {'a': 'hv', 'b': 'tank'}, 'A': A_V, 'C_d': 0.65,
              'dp_cr': 1.0e5},
    'ceiling': {'type': 'relief', 'ports': {'in': 'hv', 'out': 'tank'}, 'p_crack': 9.0e6,
                'p_full': 1.0e7, 'q_full': 1.0e-3},
}

# ---- the accumulator bench --------------------------------------------------------------

P0, V0 = 5.0e6, 1.0e-3         # precharge [Pa gauge], gas volume at precharge [m^3]
EXPONENTS = {'iso': 1.0, 'adi': 1.4}


def acc_branch(tag, n):
    """A pressure source charging an accumulator through a small orifice."""
    return {
        f'{tag}_s': {'type': 'pressure_source', 'ports': {'node': f'{tag}_a'},
                     'pressure': 4.0e6},
        f'{tag}_o': {'type': 'orifice', 'ports': {'a': f'{tag}_a', 'b': f'{tag}_m'},
                     'A': 1.0e-5},
        f'{tag}_v': {'type': 'volume', 'ports': {'node': f'{tag}_m'}, 'V': 1.0e-6},
        tag: {'type': 'accumulator', 'ports': {'port': f'{tag}_m'}, 'p0': P0, 'V0': V0,
              'n': n},
    }


ACC = {k: v for tag, n in EXPONENTS.items() for k, v in acc_branch(tag, n).items()}
ACC['tank'] = {'type': 'tank', 'ports': {'node': 'tank'}}
ACC['ceiling'] = {'type': 'relief', 'ports': {'in': 'iso_m', 'out': 'tank'}, 'p_crack': 1.8e7,
                  'p_full': 1.9e7, 'q_full': 1.0e-3}


@pytest.fixture(scope='module')
def hose_path(tmp_path_factory):
    return write_circuit(tmp_path_factory.mktemp('hose'), 'hose_bench', FLUID, HOSE)


@pytest.fixture(scope='module')
def hose_bench(hose_path):
    return load_circuit(hose_path)


@pytest.fixture(scope='module')
def acc_path(tmp_path_factory):
    return write_circuit(tmp_path_factory.mktemp('acc'), 'acc_bench', FLUID, ACC)


@pytest.fixture(scope='module')
def acc_bench(acc_path):
    return load_circuit(acc_path)


# ---- closed forms -----------------------------------------------------------------------

AREA = math.pi * D_H ** 2 / 4.0


def wave_speed(beta):
    return math.sqrt(beta / RHO)


def orifice_flow(A, dp, dp_cr=1.0e5, C_d=0.65):
    """C_d A sqrt(2/rho) dp / (dp^2 + dp_cr^2)^(1/4) (docs/reference.md I3)."""
    return C_d * A * math.sqrt(2.0 / RHO) * dp / (dp * dp + dp_cr * dp_cr) ** 0.25


def hagen_poiseuille(nu, L=L_H, d=D_H):
    """Laminar resistance 128 mu L / (pi d^4) [Pa s/m^3]."""
    return 128.0 * RHO * nu * L / (math.pi * d ** 4)


def blasius_drop(q, nu, L=L_H, d=D_H):
    """Turbulent smooth-pipe drop: f (L/d) rho v^2 / 2, f = 0.3164 Re^-0.25."""
    v = q / AREA
    re = v * d / nu
    return 0.3164 * re ** -0.25 * L / d * RHO * v * v / 2.0


def gas_law(v_oil, n):
    """Gas pressure [Pa gauge]: (p + p_atm) (V0 - V)^n = (p0 + p_atm) V0^n."""
    return (P0 + P_ATM) * (V0 / (V0 - v_oil)) ** n - P_ATM


def charged_volume(p, n):
    """The oil volume at which the gas balances a port pressure p (0 below the precharge)."""
    if p <= P0:
        return 0.0
    return V0 * (1.0 - ((P0 + P_ATM) / (p + P_ATM)) ** (1.0 / n))


def crossings(t, y, band):
    """Times where ``y`` crosses zero (linear interpolation), each counted once ``y`` has
    gone beyond ``band`` on the other side (a Schmitt trigger: the ripple of the higher
    modes near zero is not a crossing)."""
    out, side = [], 0
    for i in range(1, y.size):
        new = -1 if y[i] < -band else 1 if y[i] > band else 0
        if new == 0 or new == side:
            continue
        if side != 0:
            j = i - 1
            while np.sign(y[j]) == np.sign(y[i]):
                j -= 1
            out.append(t[j] - y[j] * (t[j + 1] - t[j]) / (y[j + 1] - y[j]))
        side = new
    return np.array(out)


def rel(got, want):
    return abs(got - want) / abs(want)


# ---- hose -------------------------------------------------------------------------------

@pytest.fixture(scope='module')
def hose_steady(hose_bench):
    return equilibrium(hose_bench)


def test_hose_steady_flow_is_the_valve_law(hose_steady):
    """In steady flow the hose passes what the valve's orifice law passes at its drop."""
    q = hose_steady['hose.flow_b']
    assert rel(hose_steady['hose.flow_a'], q) < 1e-9
    assert rel(q, orifice_flow(A_V, hose_steady['node:hv'])) < 1e-3
    assert rel(hose_steady['hose.velocity'], q / AREA) < 1e-9


def test_hose_laminar_drop_is_hagen_poiseuille(hose_steady):
    """A laminar steady flow (Re about 1300) drops R q, R = 128 mu L / (pi d^4), and
    dissipates R q^2: within 1 %."""
    q = hose_steady['hose.flow_a']
    assert q * D_H / (AREA * NU) < 2300.0
    dp = hose_steady['node:hs'] - hose_steady['node:hv']
    R = hagen_poiseuille(NU)
    print(f'Hagen-Poiseuille: dp {dp:.6g} Pa, R q {R * q:.6g} Pa, error {rel(dp, R * q):.2e}')
    assert rel(dp, R * q) < 0.01, (dp, R * q)
    assert rel(hose_steady['hose.loss'], R * q * q) < 0.01


def test_hose_turbulent_drop_is_blasius(hose_path):
    """A thin oil (nu = 1e-6 m^2/s, Re about 2e4) drops Blasius' f (L/d) rho v^2/2 within
    1 %; in the transition range (Re about 3000) the drop lies between the laminar and the
    turbulent laws."""
    for nu, law in ((1.0e-6, 'blasius'), (6.7e-6, 'transition')):
        eq = equilibrium(load_circuit(hose_path, {'fluid.nu': nu}))
        q = eq['hose.flow_a']
        re = q * D_H / (AREA * nu)
        dp = eq['node:hs'] - eq['node:hv']
        print(f'{law}: Re {re:.4g}, dp {dp:.6g} Pa, Hagen-Poiseuille '
              f'{hagen_poiseuille(nu) * q:.6g} Pa, Blasius {blasius_drop(q, nu):.6g} Pa')
        if law == 'blasius':
            assert re > 4000.0
            assert rel(dp, blasius_drop(q, nu)) < 0.01, (dp, blasius_drop(q, nu))
        else:
            assert 2300.0 < re < 4000.0
            lo, hi = sorted((hagen_poiseuille(nu) * q, blasius_drop(q, nu)))
            assert lo < dp < hi, (lo, dp, hi)


@pytest.fixture(scope='module')
def hammer(hose_bench, hose_steady):
    """The valve closes from its steady flow: its aperture falls 1 -> 0 along a smoothstep
    over ``0.2 * 4L/c`` (a fast closure, well within the reflection time 2L/c), then the
    line rings for 14 periods."""
    period = 4.0 * L_H / wave_speed(BETA_H)
    t_c = 0.2 * period

    def aperture(t):
        z = np.clip((np.asarray(t) - T_CLOSE) / t_c, 0.0, 1.0)
        return 1.0 - z * z * (3.0 - 2.0 * z)

    res = simulate(hose_bench, T_CLOSE + 14.0 * period, {'valve.aperture': aperture},
                           x0=hose_steady.x, dt_out=2.0e-5)
    return res, t_c


def test_water_hammer_joukowsky(hose_steady, hammer):
    """The pressure rise at the valve is Joukowsky's rho c v0 within 2 %, c = sqrt(beta_eff /
    rho) (the hose's 1e9 Pa, not the fluid's 1.6e9), v0 the steady mean velocity before the
    closure.

    Measured as the plateau: the mean of the valve's pressure, less its steady value before
    the closure, from the end of the closure to the return of the reflected wave (2L/c after
    the closure began), where the continuous line holds exactly rho c v0. The mean takes out
    the ringing of the lumped segments' higher modes about the plateau."""
    res, t_c = hammer
    c = wave_speed(BETA_H)
    v0 = hose_steady['hose.flow_b'] / AREA
    joukowsky = RHO * c * v0
    t = res.t
    window = (t >= T_CLOSE + t_c) & (t <= T_CLOSE + 2.0 * L_H / c)
    rise = float(np.mean(res.node('hv')[window])) - hose_steady['node:hv']
    print(f'Joukowsky: rise {rise:.6g} Pa, rho c v0 {joukowsky:.6g} Pa, '
          f'error {rel(rise, joukowsky):.2%}')
    assert rel(rise, joukowsky) < 0.02
    assert res['hose.loss'].min() >= 0.0
    assert res['ceiling.opening'].max() == 0.0     # the relief never opened


def test_water_hammer_period(hammer):
    """The valve's pressure oscillates with the period 4L/c within 2 %.

    Measured from the zero crossings of the oscillation about its mean: with the valve shut
    and no flow left the whole line settles at the supply pressure, so the oscillation is the
    valve's pressure less the supply's. A crossing counts once the pressure has gone beyond
    half of the Joukowsky rise on the other side (a Schmitt trigger, so that the higher
    modes' ripple near zero is not counted); crossings come every half period, and the period
    is twice the mean spacing from the first to the last (14 periods after the closure)."""
    res, t_c = hammer
    c = wave_speed(BETA_H)
    period = 4.0 * L_H / c
    y = res.node('hv') - P_S
    band = 0.5 * RHO * c * 1.0        # half the rise at v0 of about 1 m/s
    tc = crossings(res.t, y, band)
    assert tc.size >= 20
    measured = 2.0 * (tc[-1] - tc[0]) / (tc.size - 1)
    print(f'period: {measured:.6g} s ({tc.size} crossings), 4L/c {period:.6g} s, '
          f'error {rel(measured, period):.2%}')
    assert rel(measured, period) < 0.02


def test_hose_length_must_be_positive(hose_path):
    with pytest.raises(CircuitError) as err:
        load_circuit(hose_path, {'hose.L': 0.0}, compile=False)
    lines = [ln for ln in err.value.lines if 'hose.L' in ln]
    assert len(lines) == 1 and 'outside the accepted range' in lines[0]


# ---- accumulator ------------------------------------------------------------------------

@pytest.mark.parametrize('pressure', [6.0e6, 9.0e6, 1.2e7, 1.5e7])
def test_accumulator_held_pressures(acc_bench, pressure):
    """Held at a supply pressure above the precharge, each accumulator takes the oil volume
    at which its gas balances that pressure: V = V0 (1 - ((p0 + p_atm) / (p + p_atm))^(1/n)),
    within 1 %, its gas at the supply's pressure."""
    eq = equilibrium(acc_bench, {f'{tag}_s.pressure': pressure for tag in EXPONENTS})
    for tag, n in EXPONENTS.items():
        want = charged_volume(pressure, n)
        print(f'{tag} at {pressure:.3g} Pa: volume {eq[f"{tag}.volume"]:.6g} m^3, law '
              f'{want:.6g} m^3, error {rel(eq[f"{tag}.volume"], want):.2e}')
        assert rel(eq[f'{tag}.volume'], want) < 0.01, (tag, eq[f'{tag}.volume'], want)
        assert rel(eq[f'{tag}.pressure'], pressure) < 0.01
        assert abs(eq[f'{tag}.flow']) < 1e-6 * V0      # the steady state's own tolerance


@pytest.fixture(scope='module')
def charge(acc_bench):
    """From empty (supply 40 bar, below the 50 bar precharge) the supply ramps to 150 bar
    over 4 s and holds 2 s."""
    start = equilibrium(acc_bench)

    def ramp(t):
        return 4.0e6 + 1.1e7 * np.clip(np.asarray(t) / 4.0, 0.0, 1.0)

    return simulate(acc_bench, 6.0, {f'{tag}_s.pressure': ramp for tag in EXPONENTS},
                            x0=start.x, dt_out=1.0e-2)


@pytest.mark.parametrize('tag', list(EXPONENTS))
def test_accumulator_polytropic_charge(charge, tag):
    """Along a slow charge the gas pressure is the polytropic law (absolute pressure) at the
    oil volume reached, within 1 %, isothermal (n = 1.0) and adiabatic (n = 1.4); the volume
    reached at the end of the hold is the one the supply's pressure balances; the volume is
    the integral of the flow; the inlet dissipates no negative power."""
    n = EXPONENTS[tag]
    vol, pres = charge[f'{tag}.volume'], charge[f'{tag}.pressure']
    charged = vol > 1.0e-3 * V0
    assert charged.sum() > 300
    law = gas_law(vol[charged], n)
    worst = float(np.max(np.abs(pres[charged] - law) / law))
    print(f'{tag}: worst gas-law error {worst:.2e}')
    assert worst < 0.01
    print(f'{tag}: end volume {vol[-1]:.6g} m^3, law {charged_volume(1.5e7, n):.6g} m^3, '
          f'gas {pres[-1]:.6g} Pa')
    assert rel(vol[-1], charged_volume(1.5e7, n)) < 0.01
    assert rel(pres[-1], 1.5e7) < 0.01
    flow = charge[f'{tag}.flow']
    integral = float(np.sum(0.5 * (flow[1:] + flow[:-1]) * np.diff(charge.t)))
    assert rel(integral, vol[-1] - vol[0]) < 0.01
    assert charge[f'{tag}.loss'].min() >= 0.0
    assert charge['ceiling.opening'].max() == 0.0


def test_accumulator_nothing_below_precharge(acc_bench):
    """Below the precharge no oil enters an empty accumulator (the supply swings between 20
    and 48 bar for 1 s); a charged one (held at 120 bar) gives all its oil back when the
    supply falls to 30 bar, and no more: the volume comes to zero without going below it,
    the gas to its precharge, the flow to zero."""
    def swing(t):
        return 3.4e6 + 1.4e6 * np.sin(2.0 * np.pi * 3.0 * np.asarray(t))

    empty = equilibrium(acc_bench, {f'{tag}_s.pressure': 3.4e6 for tag in EXPONENTS})
    for tag in EXPONENTS:
        assert abs(empty[f'{tag}.volume']) < 1e-9 * V0
        assert abs(empty[f'{tag}.flow']) < 1e-12

    res = simulate(acc_bench, 1.0, {f'{tag}_s.pressure': swing for tag in EXPONENTS},
                           x0=empty.x, dt_out=1.0e-3)
    for tag in EXPONENTS:
        assert np.max(np.abs(res[f'{tag}.volume'])) < 1e-9 * V0
        assert np.max(np.abs(res[f'{tag}.flow'])) < 1e-9 * V0

    full = equilibrium(acc_bench, {f'{tag}_s.pressure': 1.2e7 for tag in EXPONENTS})
    res = simulate(acc_bench, 3.0, {f'{tag}_s.pressure': 3.0e6 for tag in EXPONENTS},
                           x0=full.x, dt_out=1.0e-3)
    for tag, n in EXPONENTS.items():
        v_full = full[f'{tag}.volume']
        assert rel(v_full, charged_volume(1.2e7, n)) < 0.01
        vol, flow = res[f'{tag}.volume'], res[f'{tag}.flow']
        assert vol.min() > -1e-6 * V0            # the stepper's tolerance on V0
        assert abs(vol[-1]) < 1e-6 * V0
        assert abs(flow[-1]) < 1e-9 * V0
        assert rel(res[f'{tag}.pressure'][-1], P0) < 1e-3
        delivered = -float(np.sum(0.5 * (flow[1:] + flow[:-1]) * np.diff(res.t)))
        print(f'{tag}: charged {v_full:.6g} m^3, gave back {delivered:.6g} m^3, least volume '
              f'{vol.min():.3g} m^3, final gas {res[f"{tag}.pressure"][-1]:.6g} Pa')
        assert rel(delivered, v_full) < 0.01


def test_accumulator_precharge_and_checks(acc_bench, acc_path):
    comps = {pt.comp.name: pt.comp for pt in acc_bench.parts}
    assert comps['iso'].precharge() == P0
    assert comps['iso'].pressure_cap({}) is None      # empty: it delivers nothing
    with pytest.raises(CircuitError) as err:
        load_circuit(acc_path, {'adi.V_oil0': 2.0e-3}, compile=False)
    assert any('V_oil0' in ln and 'V0' in ln for ln in err.value.lines)
