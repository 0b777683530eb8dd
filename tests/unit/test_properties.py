"""Property-based checks over parameter ranges and input profiles: no NaN, and no pressure or
position outside its physical bounds."""

from hypothesis import given, HealthCheck, settings
from hypothesis import strategies as st
import numpy as np

from hydropump_sim import held, simulate

SCALES = {
    'spool.m_c': (0.5, 3.0), 'plate.m_a': (0.3, 3.0), 'plate.K_b': (0.5, 2.0),
    'fluid.beta': (0.6, 1.3), 'line.V_l': (0.2, 4.0), 'actuator.V_a0': (1.0, 3.0),
    'spool.c_c': (0.3, 3.0), 'plate.c_a': (0.3, 3.0), 'actuator.mu_a': (0.3, 3.0),
    'actuator.dp_cr_a': (0.05, 5.0), 'line.dp_cr_u': (0.05, 5.0), 'line.mu_u': (0.5, 2.0),
}


def _steps(values, duration):
    return held(np.linspace(0.0, duration, len(values), endpoint=False), values)


@st.composite
def cases(draw):
    scales = {k: draw(st.floats(*rng)) for k, rng in SCALES.items()}
    extra = {
        'spool.F_coul_c': draw(st.sampled_from([0.0, 0.3, 1.0])),
        'plate.F_coul_a': draw(st.sampled_from([0.0, 10.0, 50.0])),
        'fluid.alpha_air': draw(st.sampled_from([0.0, 0.005, 0.02])),
        'input.dither_amp': draw(st.sampled_from([0.0, 0.02])),
        'input.tau_s': draw(st.sampled_from([0.0, 0.002])),
        'actuator.G_leak_a': draw(st.sampled_from([0.0, 2e-12])),
        'line.gamma_u': draw(st.sampled_from([1.0, 1.5, 2.0])),
    }
    n = draw(st.integers(1, 6))
    current = draw(st.lists(st.floats(0.1, 0.9), min_size=n, max_size=n))
    aperture = draw(st.lists(st.floats(0.0, 1.0), min_size=1, max_size=4))
    load = draw(st.lists(st.floats(1.0e5, 2.2e7), min_size=1, max_size=3))
    return scales, extra, current, aperture, load


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(cases())
def test_no_nan_and_physical_bounds(params, case):
    scales, extra, current, aperture, load = case
    values = {k: getattr(getattr(params, k.split('.')[0]), k.split('.')[1]) * s
              for k, s in scales.items()}
    values.update(extra)
    values['actuator.h_a'] = params.actuator.h_a * scales['actuator.mu_a']  # eq. 4 pair
    if extra['line.gamma_u'] != 2.0:
        # Keep the nominal load flow: mu_u carries the unit Pa^-(1/gamma_u) (I10).
        dp = params.line.P_l_bar - params.line.P_u
        values['line.mu_u'] = (params.Q_max / 2) / (params.line.xi_u
                                                    * dp ** (1 / extra['line.gamma_u']))
    p = params.replace(values)
    duration = 0.6
    r = simulate(p, duration, _steps(current, duration), aperture=_steps(aperture, duration),
                 load_pressure=_steps(load, duration), dt_out=1e-3)
    assert np.all(np.isfinite(r.y)) and np.all(np.isfinite(r.x))
    p_atm = p.fluid.p_atm
    # Pressures never below absolute zero (the floor, or the air model).
    assert r.P_a.min() + p_atm >= -1.0
    assert r.P_l.min() + p_atm >= -1.0
    # The relief valve bounds the line pressure (its flow at p_full exceeds the pump's).
    assert r.P_l.max() <= 1.05 * max(p.relief.p_full, max(load))
    # Positions within the stops plus the penalty compliance F/k.
    F_a = ((r.P_l.max() + p_atm + p.actuator.P_a_bar) * p.actuator.S_a
           + p.line.P_l_bar * p.plate.S_d + (p.plate.K_b + p.spool.K_a) * p.x_a_stop
           + p.spool.K_a * p.spool.x_c_max)
    assert np.max(np.abs(r.x_a)) <= p.x_a_stop + F_a / p.plate.k_stop_a
    assert np.max(np.abs(r.x_c)) <= 1.15 * p.spool.x_c_max
    disp = r.Q_p / (p.pump.V_p * r.f_p)
    assert disp.min() >= 0.0 and disp.max() <= 1.0
    assert r.n_clamped == 0
