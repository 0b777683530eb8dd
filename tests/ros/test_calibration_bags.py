"""Calibration on bags the project's own nodes made: the simulator (lock-step, a perturbed
params file, the bench sensor chain, a load-pressure scenario) recorded by the recorder as
`ros2 run` starts it; `hydropump calibrate` must find the perturbed values."""

import numpy as np
import yaml

from hydropump_ctrl.ident import read_recordings, Recording
from hydropump_ctrl.ident.calibrate import calibrate, params_with
from hydropump_sim.params import load_params
from hydropump_sim.schema import dump_ros_yaml

from ..conftest import ROOT
from .test_recorder import run_lock_step

FREE = ('actuator.mu_a', 'line.mu_u')


def test_calibration_recovers_a_perturbed_plant_from_recorded_bags(nodes, test_node, tmp_path):
    base = load_params(ROOT / 'config' / 'pump.yaml')
    truth = params_with(base, FREE, [base.flat()[n] * f for n, f in zip(FREE, (1.2, 0.85))])
    plant = tmp_path / 'truth.yaml'
    plant.write_text(dump_ros_yaml(truth.flat()))
    # The bench's sensors, without its dither (which only slows the fit down).
    bench = yaml.safe_load((ROOT / 'config' / 'bench.yaml').read_text())
    bench['/**']['ros__parameters'].pop('input')
    profile = tmp_path / 'sensors.yaml'
    profile.write_text(yaml.safe_dump(bench))
    scenario = tmp_path / 'load.yaml'
    scenario.write_text('duration: 10.0\ninputs:\n'
                        '  load_pressure: {steps: [[0.0, 1.2e+7], [1.6, 0.9e+7]]}\n')
    lo, hi = truth.current_range
    levels = [lo + f * (hi - lo) for f in (0.4, 0.55, 0.45, 0.6, 0.5)]

    def staircase(t):
        return levels[min(int(t / 0.5), len(levels) - 1)]

    bag = tmp_path / 'bag'
    nodes.extra = {'simulator': ['-p', f'params_file:={plant}', '-p', f'sensor_profile:={profile}',
                        '-p', f'scenario_file:={scenario}']}
    _, _, driver = run_lock_step(nodes, test_node, bag, until=2.5, schedule=staircase)
    driver.destroy()   # the stand-in controller must not answer later tests' simulators
    (rec,) = read_recordings([bag])
    assert 'solenoid_current_cmd' in rec and 'load_pressure' in rec
    # The applied current holds from its stamp, as the command does (the topic contract).
    ok = np.isfinite(rec['solenoid_current_cmd'])
    np.testing.assert_allclose(rec['solenoid_current'][ok], rec['solenoid_current_cmd'][ok],
                               atol=1e-3)
    without_cmd = Recording(rec.t, {k: v for k, v in rec.signals.items()
                                    if k != 'solenoid_current_cmd'}, name='current only')
    for r in (rec, without_cmd):
        cal = calibrate([r], base, FREE)
        for p in cal.estimates:
            assert p.well_determined and abs(p.value / truth.flat()[p.name] - 1) < 0.02, \
                (r.name, p.name, p.value, truth.flat()[p.name])
        # The bench's 55 ms, and no timing mismatch at the load steps: the line pressure is
        # fitted to its noise.
        assert abs(cal.delays['all']['line_flow'] - 0.055) < 2e-4, cal.delays
        assert all(m['ratio'] < 1.5 for per in cal.misfit.values() for m in per.values()), \
            cal.misfit
