"""Scenario files and sensor models."""

import numpy as np
import pytest

from hydropump_sim.params import ParamError
from hydropump_sim.scenario import load_scenario, ScenarioError
from hydropump_sim.sensors import (
    apply_profile,
    load_profile,
    profile_from_dict,
    SensorProfile,
    SensorSpec,
)

from ..conftest import ROOT


def _write(tmp_path, text):
    f = tmp_path / 'sc.yaml'
    f.write_text(text)
    return f


def test_scenario_signals(tmp_path):
    sc = load_scenario(_write(tmp_path, f"""
duration: 2.0
params: {ROOT / 'config' / 'pump.yaml'}
overrides: {{spool.F_coul_c: 0.5}}
inputs:
  current: {{steps: [[0.0, 0.46], [0.5, 0.54]], sine: {{amplitude: 0.01, frequency: 2.0,
            start: 1.0}}}}
  aperture: {{ramp: [[0.0, 0.5], [1.0, 0.7]]}}
  load_pressure: 1.0e+7
"""))
    cur, ap, pu = sc.inputs['current'], sc.inputs['aperture'], sc.inputs['load_pressure']
    assert cur(0.49) == 0.46 and cur(0.5) == 0.54
    assert cur(1.125) == pytest.approx(0.54 + 0.01 * np.sin(2 * np.pi * 2 * 0.125))
    assert ap(0.5) == pytest.approx(0.6)
    assert pu(np.array([0.0, 3.0])).tolist() == [1.0e7, 1.0e7]
    assert sc.params.spool.F_coul_c == 0.5


def test_bad_scenario_lists_every_problem(tmp_path):
    with pytest.raises(ScenarioError) as exc:
        load_scenario(_write(tmp_path, """
duration: -1
model: coarse
inputs:
  current: {steps: [[0.5, 0.4], [0.1, 0.5]]}
  pressure: 1.0e+7
  aperture: {sine: {amplitude: 0.1}}
overrides: {spool.mc: 1.0}
"""))
    text = '\n'.join(exc.value.lines)
    assert 'duration = -1' in text
    assert "model = 'coarse'" in text
    assert 'inputs.current.steps: times must increase' in text
    assert 'inputs.pressure: unknown input (did you mean inputs.load_pressure?)' in text
    assert 'inputs.aperture.sine: expected amplitude and frequency' in text
    assert 'did you mean spool.m_c' in text


def test_fractional_delay_noise_and_quantisation():
    t = np.arange(0.0, 0.3, 1e-3)
    x = np.where(t >= 0.1, 1.0, 0.0)
    out = apply_profile(SensorProfile({'line_flow': SensorSpec(delay=0.0554)}), t,
                        {'line_flow': x})['line_flow']
    # The step at 100 ms arrives over the samples at 155 and 156 ms, split 0.6 / 1.0.
    k = int(np.flatnonzero(out > 0)[0])
    assert t[k] == pytest.approx(0.155) and out[k] == pytest.approx(0.6)
    assert out[k + 1] == 1.0
    noisy = apply_profile(SensorProfile({'line_flow': SensorSpec(noise_std=0.01, quantum=0.005)},
                                        seed=3), t, {'line_flow': np.zeros_like(t)})['line_flow']
    assert 0.007 < noisy.std() < 0.013
    assert np.allclose(noisy / 0.005, np.round(noisy / 0.005))
    again = apply_profile(SensorProfile({'line_flow': SensorSpec(noise_std=0.01)}, seed=3), t,
                          {'line_flow': np.zeros_like(t)})['line_flow']
    assert np.array_equal(np.round(again / 0.005) * 0.005, noisy)  # seeded: reproducible


def test_first_order_filter():
    t = np.arange(0.0, 0.2, 1e-3)
    out = apply_profile(SensorProfile({'line_flow': SensorSpec(filter_tau=0.02)}), t,
                        {'line_flow': np.where(t >= 0.05, 1.0, 0.0)})['line_flow']
    assert out[np.searchsorted(t, 0.07)] == pytest.approx(1 - np.exp(-1.0), abs=0.03)


def test_bench_profile():
    prof = load_profile(ROOT / 'config' / 'bench.yaml')
    assert prof.spec('line_flow').delay == 0.055
    assert prof.plant_overrides['input.dither_amp'] > 0.0
    with pytest.raises(ParamError, match='sensors.line_flow.delay'):
        profile_from_dict({'sensors': {'line_flow': {'delay': -1.0}}})
    with pytest.raises(ParamError, match='unknown sensor parameter .did you mean'):
        profile_from_dict({'sensors': {'flow': {'delay': 0.1}}})


def test_a_number_yaml_reads_as_text_gets_the_yaml_hint(tmp_path):
    with pytest.raises(ScenarioError) as exc:
        load_scenario(_write(tmp_path, """
duration: 1.0
inputs:
  load_pressure: 1.2e7
"""))
    (line,) = exc.value.lines
    assert "inputs.load_pressure = '1.2e7'" in line and 'signed exponent' in line


def test_a_sine_the_input_sampling_cannot_carry_is_refused(tmp_path):
    """A 1 MHz sine held every millisecond is sampled at its zeros (sin(2 pi 1e6 k 1e-3) =
    0): refused with the sampling rate; one below half that rate is accepted."""
    for freq, ok in ((1.0e6, False), (500.0, False), (100.0, True)):
        path = _write(tmp_path, f"""
duration: 1.0
inputs:
  load_pressure: {{offset: 1.0e+7, sine: {{amplitude: 1.0e+6, frequency: {freq!r}}}}}
""")
        if ok:
            assert load_scenario(path).inputs['load_pressure'].sine[1] == freq
            continue
        with pytest.raises(ScenarioError) as exc:
            load_scenario(path)
        (line,) = exc.value.lines
        assert line.startswith(f'inputs.load_pressure.sine.frequency = {freq:g} Hz') and \
            '500 Hz' in line


def test_the_shipped_scenario_runs_as_its_comments_say(tmp_path):
    """config/scenarios/load_change.yaml through ``hydropump simulate``: at rest before each
    change, the flow is the displacement asked times V_p f_p, and the orifice's drop follows
    eq. 9, (q / xi)^2: the aperture from 0.5 to 0.6 takes it to (5/6)^2 of itself, the
    load pressure's 30 bar fall leaves it as it was."""
    from hydropump_ctrl.cli import main
    from hydropump_sim import load_params
    out = tmp_path / 'load_change.csv'
    assert main(['simulate', str(ROOT / 'config' / 'scenarios' / 'load_change.yaml'),
                 '--out', str(out)]) == 0
    d = np.genfromtxt(out, delimiter=',', names=True)
    cols = d.dtype.names
    t, q, p_l, p_u = (d[c] for c in (cols[0], cols[10], cols[7], cols[13]))
    q_max = load_params(ROOT / 'config' / 'pump.yaml').Q_max

    def at(time):
        return int(np.searchsorted(t, time))
    assert q[at(0.45)] == pytest.approx(0.4 * q_max, rel=1e-3)
    assert q[at(1.45)] == pytest.approx(0.6 * q_max, rel=1e-3)
    drop = [p_l[at(s)] - p_u[at(s)] for s in (1.45, 2.45, 2.95)]
    assert p_u[at(2.95)] == pytest.approx(p_u[at(2.45)] - 3.0e6)
    assert drop[1] / drop[0] == pytest.approx((0.5 / 0.6) ** 2, rel=1e-3)
    assert drop[2] == pytest.approx(drop[1], rel=1e-3)
    assert (tmp_path / 'load_change.png').stat().st_size > 10_000


def test_the_shipped_circuit_scenario_is_what_its_comments_say():
    """config/scenarios/fig1_boom.yaml takes Fig. 1's inputs by name, as the simulator node
    reads it with that circuit: the boom's valve open only from 1 s to 3 s, its force
    stepping at 2 s, the motor's valve ramping linearly over 1.5..2.5 s, the steering held."""
    from hydropump_sim.circuit import load_circuit
    circuit = load_circuit(str(ROOT / 'config' / 'circuits' / 'fig1.yaml'), compile=False)
    sc = load_scenario(ROOT / 'config' / 'scenarios' / 'fig1_boom.yaml',
                       ['current', 'aperture', 'load_pressure', 'shaft_speed',
                        *circuit.all_inputs()])
    u = sc.inputs
    assert sc.duration == 4.0
    assert [u['boom.command'](t) for t in (0.5, 1.5, 2.9, 3.5)] == [0.0, 0.8, 0.8, 0.0]
    assert [u['boom.force'](t) for t in (1.9, 2.1)] == [4.0e4, 6.0e4]
    assert u['motor.command'](2.0) == pytest.approx(0.3)
    assert u['motor.command'](1.0) == 0.0 and u['motor.command'](3.0) == pytest.approx(0.6)
    assert u['steering.command'](3.7) == 0.3
