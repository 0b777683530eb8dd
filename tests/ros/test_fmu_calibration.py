"""Calibrating a user's FMU from bags recorded through the nodes, as a user does it: the
installed simulator runs the first-order pump FMU of tests/fmus.py (not the suite's code)
with perturbed parameters, measurement noise and a finer integration (200 Euler steps a
step: nearly the exact lag) given as ``fmu_parameters``, the controller and the recorder
beside it; ``hydropump record --attach`` records a plan; ``hydropump calibrate --fmu`` fits
the FMU at its own starts (no noise, its own ten Euler steps) to the bags: the data are not
the fitted model's; the params file it writes starts a simulator with the calibrated
values."""

from pathlib import Path

import pytest
import yaml

from .. import fmus
from .rosutil import call, spin_until
from .test_record import hydropump

pytestmark = pytest.mark.ros
pytest.importorskip('pythonfmu')
pytest.importorskip('fmpy')

# The pump the bags come from: 20 % and 25 % off the FMU's starts (gain 1e-3 m^3/s/A, tau
# 20 ms), its outputs noisy (NOISE x 1e-4 m^3/s and 1e5 Pa: 2e-6 m^3/s, 2 kPa), which the
# fitted FMU leaves out.
TRUTH = {'gain': 1.2e-3, 'tau': 0.025}
NOISE = 0.02
PLAN = [
    {'name': 'up', 'duration': 1.2,
     'current': {'staircase': {'levels': [0.4, 0.6, 0.8, 0.5], 'dwell': 0.3}}},
    {'name': 'down', 'duration': 1.2,
     'current': {'staircase': {'levels': [0.7, 0.45, 0.65, 0.35], 'dwell': 0.3}}},
]


def _parameters(test_node, names):
    from rcl_interfaces.srv import GetParameters
    client = test_node.create_client(GetParameters, '/simulator/get_parameters')
    try:
        answer = call(test_node, client, GetParameters.Request(names=names))
        return [v.double_value for v in answer.values]
    finally:
        test_node.destroy_client(client)


def test_an_fmu_is_calibrated_from_bags_recorded_through_the_nodes(nodes, test_node,
                                                                   tmp_path):
    path = fmus.lag_pump(tmp_path)
    # (An integer is a number too: fail_after:=0.)
    truth = [f'fmu_parameters.{n}:={v!r}' for n, v in
             {**TRUTH, 'noise': NOISE, 'substeps': 200.0, 'fail_after': 0}.items()]
    sim = nodes.start('simulator', '-p', f'fmu_file:={path}', '-p', 'lock_step:=true',
                      '-p', 'start_paused:=true', *[a for t in truth for a in ('-p', t)])
    nodes.start('controller', '-p', 'autostart:=true')
    # The recorder records what this plant publishes (the FMU has two measured outputs).
    nodes.start('recorder', '-p', 'autostart:=false', '-p',
                'topics:=[solenoid_current_cmd, line_flow, line_pressure]')
    spin_until(test_node, lambda: any(n == '/simulator/reset' for n, _ in
                                      test_node.get_service_names_and_types())
               or not sim.alive(), 60, 'the simulator')
    assert sim.alive(), sim.log()
    # The values given are the node's read-only parameters.
    assert _parameters(test_node, ['fmu_parameters.gain', 'fmu_parameters.tau']) == \
        [TRUTH['gain'], TRUTH['tau']]
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump(PLAN))
    bags = tmp_path / 'bags'
    rc, out, err = hydropump('record', str(plan), '--attach', '--out', str(bags),
                             timeout=120)
    assert rc == 0, out + err
    report = tmp_path / 'report'
    rc, out, err = hydropump('calibrate', '--fmu', str(path), *(str(bags / e['name'])
                             for e in PLAN), '--free', 'gain', 'tau', '--report',
                             str(report), '--no-plots', timeout=120)
    assert rc == 0, out + err
    result = yaml.safe_load((report / 'result.json').read_text())
    for name, value in TRUTH.items():
        got = result['parameters'][name]
        assert got['value'] == pytest.approx(value, rel=0.02), (name, got)
        assert got['initial'] == {'gain': 1.0e-3, 'tau': 0.02}[name]
    # Fitted down to the noise the FMU made, on both signals of both bags.
    made = {'line_flow': NOISE * 1.0e-4, 'line_pressure': NOISE * 1.0e5}
    for per in result['misfit'].values():
        assert set(per) == set(made)
        for s, m in per.items():
            assert m['rms'] == pytest.approx(made[s], rel=0.2), result['misfit']
    # Its params file starts a simulator on the calibrated FMU.
    calibrated = report / 'calibrated.yaml'
    node = yaml.safe_load(calibrated.read_text())['/**']['ros__parameters']
    assert Path(node['fmu_file']) == path.resolve()
    sim.stop()
    sim = nodes.start('simulator', '--params-file', str(calibrated))
    spin_until(test_node, lambda: any(n == '/simulator/reset' for n, _ in
                                      test_node.get_service_names_and_types())
               or not sim.alive(), 60, 'the calibrated simulator')
    assert sim.alive(), sim.log()
    got = _parameters(test_node, ['fmu_parameters.gain', 'fmu_parameters.tau'])
    assert got == pytest.approx([result['parameters'][n]['value'] for n in ('gain', 'tau')],
                                rel=1e-9)
