"""Linear analysis: eq. 16 against eqs. 14/15, eq. 11 DC gain, section IV's check."""

import control
import numpy as np
import pytest

from hydropump_sim.linear import bode_data, linearize
from hydropump_sim.paper import paper_linear, singular_perturbation_check, transfer_matrix


@pytest.mark.parametrize('branch', ['pos', 'neg'])
def test_eq16_equals_eqs_14_15(params, branch):
    """The transfer matrix of eq. 16-18 is the transfer matrix of the state space 14/15."""
    G = transfer_matrix(params, branch=branch)
    ss = paper_linear(params, branch=branch).ss()
    w = np.logspace(-1, 4, 60)
    for i in range(2):
        for j in range(2):
            a = np.asarray(control.frequency_response(G[i, j], w).complex).ravel()
            b = np.asarray(control.frequency_response(ss[i, j], w).complex).ravel()
            assert np.allclose(a, b, rtol=1e-9, atol=1e-20)  # (2,2) is zero in both


def test_dc_gain_is_eq_11(params):
    """G21(0) = V_p f_p / I_max on both branches: the static pump characteristic."""
    for branch in ('pos', 'neg'):
        G = transfer_matrix(params, branch=branch)
        assert np.real(G(0)[1, 0]) == pytest.approx(params.Q_max / params.spool.I_max, rel=1e-12)
        # and p_u passes to p_l with unit DC gain (the load restriction holds the margin).
        assert np.real(G(0)[0, 1]) == pytest.approx(1.0, rel=1e-12)


def test_falling_flow_has_the_zero(params):
    """Eq. 17: the falling branch has a zero at -b_p/S_a; the growing branch has none."""
    zeros_neg = control.zeros(transfer_matrix(params, branch='neg')[1, 0])
    assert zeros_neg.size == 1
    assert -1 / zeros_neg[0].real == pytest.approx(params.actuator.S_a / params.b_p, rel=1e-9)
    assert control.zeros(transfer_matrix(params, branch='pos')[1, 0]).size == 0


def test_fine_and_simplified_agree_inside_the_bandwidth(params):
    """Below 1/T the fine model's current-to-flow response is the simplified one's (the
    premise of section IV); far above it they part."""
    w = np.array([1.0, 5.0, 20.0])
    fine = linearize(params, branch='pos').ss(inputs=['i_s'], outputs=['q_l'])
    simp = linearize(params, branch='pos', model='simplified_Kc').ss(inputs=['i_s'],
                                                                      outputs=['q_l'])
    mf, pf = bode_data(fine, w)
    ms, ps = bode_data(simp, w)
    assert np.allclose(mf, ms, rtol=0.02)
    assert np.allclose(pf, ps, atol=3.0)
    mf2, _ = bode_data(fine, np.array([2 * np.pi * 1500]))
    ms2, _ = bode_data(simp, np.array([2 * np.pi * 1500]))
    assert abs(np.log10(mf2[0] / ms2[0])) > 0.5


def test_singular_perturbation_check(params):
    """T = 50 ms: only the displacement mode lies inside the bandwidth on the growing side;
    spool (153 Hz) and plate/oil (1.5 kHz) modes and the line pole lie outside."""
    modes = singular_perturbation_check(params, T=0.05, branch='pos')
    slow = [m for m in modes if not m.neglected]
    assert len(slow) == 1 and slow[0].mode.dominant[0] == 'x_a'
    assert slow[0].epsilon == pytest.approx(99.17e-3 / 0.05, rel=1e-3)
    fast = [m for m in modes if m.neglected]
    assert all(m.epsilon < 0.1 for m in fast)
    # A slower controller (T = 1 ms) would have to keep the line and spool modes too.
    assert sum(not m.neglected for m in singular_perturbation_check(params, T=1e-3)) == 4
