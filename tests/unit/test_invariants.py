"""The invariant checker catches what it claims to, and the compiler refuses a pump that
nothing limits.

The bench: a pressure source feeding a node through an orifice, a relief valve at 200 bar
on it, and a volume trapped behind a closed valve with no leakage. A run that starts with
the trapped volume at 400 bar breaks "no pressure above every source" there, from its first
sample (the truth: 400 bar against the relief's 200 bar full-flow pressure plus one
regulation range); one that starts it at -2 bar (below absolute zero) breaks the floor; a
run at rest breaks nothing. Strict (as the suite runs) the same run raises with the node's
name; ``hydropump circuit --check`` says it in one line and exits 1.
"""

import subprocess
import sys

import pytest
import yaml

from hydropump_sim.circuit import CircuitError, load_circuit
from hydropump_sim.invariants import check, InvariantError
from hydropump_sim.simulate import simulate
from hydropump_sim.steady import equilibrium

from ..conftest import ROOT
from .conftest import write_circuit

FLUID = dict(rho=870.0, beta=1.6e9, nu=3.2e-5, alpha_air=0.0, p_atm=1.013e5, P_T=0.0)
BENCH = {
    'tank': {'type': 'tank', 'ports': {'node': 'tank'}},
    'src': {'type': 'pressure_source', 'ports': {'node': 'feed'}, 'pressure': 1.0e7},
    'orf': {'type': 'orifice', 'ports': {'a': 'feed', 'b': 'line'}, 'A': 1.0e-6},
    'line_v': {'type': 'volume', 'ports': {'node': 'line'}, 'V': 1.0e-4},
    'relief': {'type': 'relief', 'ports': {'in': 'line', 'out': 'tank'}, 'p_crack': 1.8e7,
               'p_full': 2.0e7, 'q_full': 1.0e-3},
    'shut': {'type': 'directional_valve', 'ports': {'in': 'line', 'out': 'trapped'},
             'A_max': 1.0e-5, 'command': 0.0, 'tau': 0.0, 'G_leak': 0.0, 'check': False},
    'trapped_v': {'type': 'volume', 'ports': {'node': 'trapped'}, 'V': 1.0e-5},
}


@pytest.fixture(scope='module')
def bench(tmp_path_factory):
    return load_circuit(write_circuit(tmp_path_factory.mktemp('inv'), 'inv', FLUID, BENCH))


def start(bench, trapped: float):
    x = equilibrium(bench).x.copy()
    x[bench.node_state('trapped')] = trapped
    return x


def test_a_trapped_volume_above_every_source_is_caught(bench, monkeypatch):
    monkeypatch.delenv('HYDROPUMP_STRICT_INVARIANTS')
    res = simulate(bench, 0.05, x0=start(bench, 4.0e7))
    assert res['node:trapped'].min() > 3.99e7  # it holds: sealed, with no leakage
    bad = [v for v in res.violations if v.where == 'node trapped']
    assert len(bad) == 1 and bad[0].invariant == 'a pressure above every source'
    assert bad[0].t == 0.0 and bad[0].value == pytest.approx(4.0e7)
    # The cap is the relief's: full flow at 200 bar plus one regulation range.
    assert bad[0].bound == pytest.approx(2.0 * 2.0e7 - 1.8e7)
    assert 'node trapped at t = 0 s: 400 bar (bound 220 bar)' in str(bad[0])
    assert all(v.where == 'node trapped' for v in res.violations)


def test_a_pressure_below_absolute_zero_is_caught(bench, monkeypatch):
    monkeypatch.delenv('HYDROPUMP_STRICT_INVARIANTS')
    res = simulate(bench, 0.01, x0=start(bench, -2.0e5))
    assert [(v.invariant, v.where) for v in res.violations] == [
        ('a pressure below the cavitation floor', 'node trapped')]


def test_a_run_at_rest_breaks_nothing_and_strict_runs_raise(bench):
    rest = simulate(bench, 0.05)
    assert rest.violations == []
    with pytest.raises(InvariantError) as err:   # the suite runs strict
        simulate(bench, 0.05, x0=start(bench, 4.0e7))
    assert 'node trapped' in err.value.lines[0]


def test_the_checker_catches_a_component_making_energy(bench):
    res = simulate(bench, 0.01)
    y = res.y.copy()
    y[3, bench.signal_index('orf.loss')] = -5.0   # a forged sample: an orifice giving power
    found = check(bench, res.t, y, res.u)
    assert [(v.invariant, v.where, v.t) for v in found] == [
        ('a component making energy', 'orf', res.t[3])]


def test_the_command_line_check(tmp_path):
    path = write_circuit(tmp_path, 'inv', FLUID, BENCH)
    ok = subprocess.run([sys.executable, '-m', 'hydropump_ctrl.cli', 'circuit', str(path),
                         '--duration', '0.05', '--control', 'open', '--check'],
                        capture_output=True, text=True, timeout=600)
    assert ok.returncode == 0, ok.stderr
    assert 'invariants: every one held over the whole run' in ok.stdout


def test_a_pump_that_nothing_limits_is_refused(tmp_path):
    text = (ROOT / 'config' / 'circuits' / 'paper.yaml').read_text()
    doc = yaml.safe_load(text)
    del doc['components']['relief']
    doc['plant'] = str(ROOT / 'config' / 'pump.yaml')
    path = tmp_path / 'open.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CircuitError) as err:
        load_circuit(path, compile=False)
    assert err.value.lines == ['pump: nothing limits the pressure this pump can make: add a '
                               'relief valve (type relief) at its outlet or give it a '
                               'pressure cut-off (cutoff.p_set)']
    # A cut-off is a limit: the pump's own, its setting and its band.
    cut = load_circuit(path, {'pump.cutoff.p_set': 2.5e7, 'pump.cutoff.band': 5.0e5},
                       compile=False)
    assert cut.pump().comp.pressure_cap({'current': 0.5, 'shaft_speed': 25.0}) == 2.55e7
