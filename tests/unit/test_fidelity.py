"""The ``fidelity`` of a model: the fine one, or section IV's simplified one with its error
bound, and the bandwidths it refuses.

The truth: the simplified circuit is judged against the fine circuit integrated by another
method (Radau, rtol 1e-6) and averaged here over the control period, not by the code that
states the bound; the controller's bandwidth is its eigenvalues' closed form."""

import math

import numpy as np
import pytest

from hydropump_ctrl.cli import main
from hydropump_ctrl.experiments.circuit_loop import hydromechanical
from hydropump_sim import invariants, reduction
from hydropump_sim.circuit import load_circuit
from hydropump_sim.errors import InputError
from hydropump_sim.plant_model import PumpModel
from hydropump_sim.reduction import EPSILON_STATIC, same_start, with_fidelity
from hydropump_sim.simulate import simulate
from hydropump_sim.steady import equilibrium

from ..conftest import ROOT

THREE = ROOT / 'config' / 'circuits' / 'three_loads.yaml'


@pytest.fixture(scope='module')
def three_loads():
    """three_loads under the hydromechanical load-sensing pump (no controller: section IV's
    bandwidth, 20 Hz)."""
    return hydromechanical(load_circuit(THREE), 2.0e6)


def averaged(y: np.ndarray, width: int) -> np.ndarray:
    """A moving average over ``width`` samples (what a controller averaging over T sees)."""
    kernel = np.ones(width) / width
    return np.convolve(np.pad(y, (width // 2, width - 1 - width // 2), mode='edge'), kernel,
                       mode='valid')


def test_simplified_circuit_is_within_its_stated_bound_of_an_independent_fine_run(three_loads):
    simple, fid = with_fidelity(three_loads, 'simplified')
    assert fid.name == 'simplified' and fid.bandwidth == pytest.approx(20.0)
    # The compensators' spools (10 ms) lie beyond 20 Hz; the directional valves (24 ms) not.
    assert {'load1.comp', 'load2.comp', 'load3.comp'} <= set(fid.components)
    assert not any(c.endswith('valve') for c in fid.components)
    assert 0.0 < fid.bound < 0.25 and 'error bound' in fid.text()
    eq = equilibrium(three_loads)
    ins = reduction.test_inputs(three_loads, 1.0)
    ref = simulate(three_loads, 1.0, ins, x0=eq.x, method='radau', rtol=1e-6)
    run = simulate(simple, 1.0, ins, x0=same_start(three_loads, eq.x, simple))
    broken = invariants.check(simple, run.t, run.y, run.u)   # the simplified physics too
    assert not broken, invariants.report(broken)
    width = int(round(1.0 / fid.bandwidth / float(ref.t[1] - ref.t[0])))
    for name, stated in fid.error.items():
        a, b = averaged(ref[name], width), averaged(run[name], width)
        span = max(float(np.ptp(a)), 1e-3 * float(np.max(np.abs(a))))
        # Within the bound stated, to the fine model's integration error (rtol 1e-6).
        assert np.max(np.abs(a - b)) / span <= stated + 2e-3, name
    # The pressures the pump's compensator and a controller look at: within 2 %. (The
    # flows a static compensator passes at once differ more while they start.)
    assert fid.error['pump.P_l'] < 0.02 and fid.error['ls.pressure'] < 0.02


def test_fine_is_the_model_itself_and_an_unknown_fidelity_is_refused(three_loads):
    model, fid = with_fidelity(three_loads, 'fine')
    assert model is three_loads and fid.bound == 0.0 and fid.text() == 'fine'
    with pytest.raises(InputError, match="fidelity = 'coarse': use fine or simplified"):
        with_fidelity(three_loads, 'coarse')


def test_the_paper_pump_simplified_is_eq_10(params):
    model, fid = with_fidelity(PumpModel(params), 'simplified')
    # Its spool and plate (about 2 ms) lie beyond 20 Hz: eq. 10 keeping K_c.
    assert fid.components == ('pump',) and model.model == 'simplified_Kc'
    assert fid.bound < 0.05


def test_the_controllers_bandwidth_is_its_fastest_loop_eigenvalue(cfg):
    e = cfg.emc
    assert cfg.bandwidth('flow') == pytest.approx(
        1 / (2 * math.pi * min(e.tau_control, e.tau_reference)))
    assert cfg.bandwidth('margin') == pytest.approx(1 / (2 * math.pi * e.tau_margin_flow))
    assert cfg.bandwidth() == max(cfg.bandwidth('flow'), cfg.bandwidth('margin'))


def test_a_bandwidth_that_drops_a_mode_the_controller_needs_is_refused(three_loads):
    controller = 16.0      # Hz: it acts on every mode slower than 12.5 ms
    # At 3 Hz the directional valves' 24 ms lag would be made static: refused, named.
    with pytest.raises(InputError) as err:
        with_fidelity(three_loads, 'simplified', 3.0, controller)
    text = str(err.value)
    assert 'valve' in text and 'the controller acts on' in text
    lowest = float(text.split('give at least ')[1].split(' Hz')[0])
    assert lowest == pytest.approx(EPSILON_STATIC / 0.0238, rel=0.05)
    # At or above the controller's own, nothing it needs goes.
    _, fid = with_fidelity(three_loads, 'simplified', 0.0, controller)
    assert fid.bandwidth == controller
    with pytest.raises(InputError, match='expected a frequency in Hz'):
        with_fidelity(three_loads, 'simplified', float('nan'))


def test_the_circuit_command_runs_either_fidelity(capsys):
    import json
    assert main(['circuit', str(THREE), '--control', 'hydromechanical', '--duration', '0.3',
                 '--fidelity', 'simplified', '--json']) == 0
    out = json.loads(capsys.readouterr().out)
    fid = out['fidelity']
    assert fid['name'] == 'simplified' and 'load1.comp' in fid['static']
    assert 0.0 < fid['error_bound'] < 0.25
    assert main(['circuit', str(THREE), '--bandwidth', '5']) == 2
    assert capsys.readouterr().err.strip() == \
        'error: --bandwidth goes with --fidelity simplified'
