"""Effects real pumps show and the paper leaves out: each switchable, each checked."""

import numpy as np
import pytest

from hydropump_sim import equilibrium, simulate
from hydropump_sim.metrics import step_figures
from hydropump_sim.scaling import current_for_displacement


def _staircase_levels(params, levels, hold):
    currents = current_for_displacement(params, levels)

    def cur(t):
        k = np.minimum((np.asarray(t) // hold).astype(int), len(currents) - 1)
        return currents[k]
    return cur


def _hysteresis_gap(params):
    """Steady q_l at 50 % reached from below and from above, in % of V_p f_p."""
    levels = [0.3, 0.5, 0.7, 0.5]
    hold = 1.5
    r = simulate(params, hold * len(levels), _staircase_levels(params, levels, hold),
                 dt_out=1e-3)
    q = lambda k: r.q_l[int(round((k + 1) * hold / 1e-3)) - 1]  # noqa: E731
    return (q(1) - q(3)) / params.Q_max * 100.0


def test_coulomb_friction_gives_hysteresis(params):
    friction = params.replace({'spool.F_coul_c': 0.5, 'plate.F_coul_a': 20.0})
    gap_on = _hysteresis_gap(friction)
    gap_off = _hysteresis_gap(params)
    # From below the flow stays short of its target, from above it stays beyond it.
    assert gap_on < -0.2
    assert abs(gap_off) < 1e-4


def test_relief_valve_caps_line_pressure(params):
    """Load closed at full displacement: the relief valve holds P_l near p_crack..p_full."""
    I_full = float(current_for_displacement(params, 1.0))
    kw = dict(current=I_full, aperture=lambda t: np.where(t < 0.05, 0.5, 0.0))
    r = simulate(params, 1.0, **kw)
    rl = params.relief
    assert r.P_l.max() <= rl.p_full * 1.02
    assert rl.p_crack < r.P_l[-1] < rl.p_full
    assert r.Q_relief[-1] == pytest.approx(r.Q_p[-1], rel=1e-3)
    # Without the valve the same case goes far beyond it: the check above can fail.
    free = simulate(params.replace({'relief.enabled': False}), 0.15, **kw)
    assert free.P_l.max() > 1.5 * rl.p_full


@pytest.mark.parametrize('current', [0.9, 0.1])
def test_end_stops_hold(params, current):
    """Commands beyond the stroke leave spool and plate at their stops (I13, I1)."""
    r = simulate(params, 0.6, lambda t: np.where(t < 0.01, 0.5, current))
    pen_c = np.max(np.abs(r.x_c)) - params.spool.x_c_max
    pen_a = np.max(np.abs(r.x_a)) - params.x_a_stop
    # Penalty stops are compliant: the 4.5 g spool hitting 1e6 N/m overshoots by about
    # sqrt(m_c/k) v = 0.2 mm, and at zero displacement the full line pressure on S_a
    # (7 kN) holds the plate 0.7 mm into its 1e7 N/m stop. Both stay within 10 % of the stroke
    # and at rest within the static compliance F/k.
    assert pen_c < 0.1 * params.spool.x_c_max
    assert pen_a < 0.1 * params.x_a_stop
    F_max = (r.P_l.max() - r.P_a.min() + params.actuator.P_a_bar) * params.actuator.S_a
    assert abs(r.x_a[-1]) - params.x_a_stop < F_max / params.plate.k_stop_a
    assert abs(r.x_c[-1]) <= params.spool.x_c_max * 1.01
    disp = r.Q_p / params.Q_max
    assert np.all((disp >= 0.0) & (disp <= 1.0))
    # The equilibrium solver finds the same resting point.
    eq = equilibrium(params, current)
    assert eq.x_a == pytest.approx(r.x_a[-1], abs=1e-6)


def test_without_end_stops_the_plate_overtravels(params):
    free = params.replace({'plate.k_stop_a': 0.0, 'pump.disp_clip': False})
    r = simulate(free, 0.6, lambda t: np.where(t < 0.01, 0.5, 0.85))
    assert np.max(r.x_a) > 1.2 * params.x_a_stop


def test_pressure_floor_and_entrained_air(params):
    """A fast destroke draws the actuator down; pressures never pass absolute zero, and
    entrained air (alpha 0.005) leaves the 63 % time at about 100.39 ms."""
    hard = params.replace({'spool.x_c_max': 0.01, 'actuator.P_a_bar': 3.0e5,
                           'line.P_l_bar': 3.0e6, 'line.P_u': 2.0e6})
    r = simulate(hard, 0.3, lambda t: np.where(t < 0.01, 0.3, 0.7))
    p_abs_min = min(r.P_a.min(), r.P_l.min()) + params.fluid.p_atm
    assert p_abs_min >= -1.0
    I0, I1 = current_for_displacement(params, [0.4, 0.6])
    air = params.replace({'fluid.alpha_air': 0.005})
    ra = simulate(air, 1.2, lambda t: np.where(t < 0.01, I0, I1), dt_out=1e-4)
    t63 = step_figures(ra.t, ra.q_l, 0.01, final=equilibrium(air, I1).q_l).t63
    assert t63 == pytest.approx(100.39e-3, abs=0.1e-3)


def test_leakage_needs_pilot_inflow(params):
    """With actuator leakage the equilibrium sits slightly at x_c < 0 (the pilot feeds it)."""
    leaky = params.replace({'actuator.G_leak_a': 1.0e-12})
    eq = equilibrium(leaky)
    assert eq.x_c < 0.0
    assert eq.Q_a == pytest.approx(0.0, abs=1e-12)
    r = simulate(leaky, 0.3)
    assert np.max(np.abs(r.q_l - eq.q_l)) < 1e-9


def test_dither_gives_flow_ripple(params):
    """20 mA at 150 Hz: about 1.15 % of V_p f_p of flow ripple (peak to peak)."""
    r = simulate(params.replace({'input.dither_amp': 0.02}), 0.6, 0.5, dt_out=1e-4)
    q = r.q_l[r.t > 0.3]
    ripple = (q.max() - q.min()) / params.Q_max * 100.0
    assert ripple == pytest.approx(1.15, abs=0.1)
    spec = np.abs(np.fft.rfft(r.I_s[r.t > 0.3] - 0.5))
    f = np.fft.rfftfreq(q.size, 1e-4)
    assert f[np.argmax(spec)] == pytest.approx(150.0, abs=4.0)


def test_solenoid_current_dynamics(params):
    """A first-order current lag adds a 7th state and slows the step by about tau_s."""
    lag = params.replace({'input.tau_s': 0.005})
    I0, I1 = current_for_displacement(params, [0.4, 0.6])
    cur = lambda t: np.where(t < 0.01, I0, I1)  # noqa: E731
    r = simulate(lag, 0.2, cur, dt_out=1e-4)
    assert r.x.shape[1] == 7
    k = np.searchsorted(r.t, 0.015)
    assert r.I_s[k] == pytest.approx(I0 + (I1 - I0) * (1 - np.exp(-1.0)), abs=0.002)
    base = simulate(params, 1.2, cur, dt_out=1e-4)
    slow = simulate(lag, 1.2, cur, dt_out=1e-4)
    final = equilibrium(params, I1).q_l
    d = (step_figures(slow.t, slow.q_l, 0.01, final=final).t63
         - step_figures(base.t, base.q_l, 0.01, final=final).t63)
    assert 0.003 < d < 0.007


def test_regularised_root_allows_reverse_flow(params):
    """Below the crack pressure drop the orifice is laminar and flow may reverse (I3)."""
    from hydropump_sim.components.laws import groot, sroot
    assert sroot(-4.0e6, 1e5) == pytest.approx(-np.sqrt(4.0e6), rel=1e-3)
    assert sroot(10.0, 1e5) == pytest.approx(10.0 / np.sqrt(1e5), rel=1e-6)
    assert sroot(-1.0, 0.0) == 0.0
    assert groot(4.0e6, 1e5, 1.0) == pytest.approx(4.0e6)
