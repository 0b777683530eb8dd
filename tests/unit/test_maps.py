"""The plant's eq. 19 over the operating range and against the dither (noise-free fine
model), checked against the closed forms of eqs. 14-15 at each operating point."""

import numpy as np

from hydropump_ctrl.demo.maps import (
    dither_sensitivity,
    operating_map,
    spool_resonance,
    STEP,
)
from hydropump_sim.paper import eq14_time_constant
from hydropump_sim.trim import equilibrium


def test_the_operating_map_follows_eqs_14_and_15(params):
    loads, disps = [8.0e6, 1.6e7], [0.3, 0.7]
    m = operating_map(params, loads, disps)
    lo, hi = params.current_range
    for i, pu in enumerate(loads):
        for j, d in enumerate(disps):
            current = lo + (d + STEP / 2) * (hi - lo)
            eq = equilibrium(params, current, load_pressure=pu)
            # Growing flow: S_a (1 + K_c/K_a) / (mu_a sqrt(P_a)), eq. 14 with K_c kept.
            assert abs(m['tau_up'][i, j] / eq14_time_constant(params, eq, 'pos', True) - 1) \
                < 0.03
            # Falling flow is faster: the pilot valve drains the actuator to the line side.
            assert m['tau_down'][i, j] < 0.8 * m['tau_up'][i, j]
            # The static gain of eq. 19 is 100 % per unit current by design (D1).
            assert abs(m['G0'][i, j] - 100.0) < 0.5


def test_the_dither_shortens_the_growing_flow_time_constant(params):
    s = dither_sensitivity(params, [0.0, 0.004, 0.012], [150.0])
    tau = s['tau_up'][:, 0]
    assert np.all(np.diff(tau) < 0)          # more dither, faster growing flow
    assert abs(tau[0] - eq14_time_constant(params, equilibrium(params), 'pos', True)) < 0.005
    assert 140.0 < spool_resonance(params) < 170.0   # the dither sits near the resonance
