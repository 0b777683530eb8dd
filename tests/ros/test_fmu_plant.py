"""A user's FMU as the simulator's plant (``fmu_file:=``), through the installed simulator
over DDS: the FMU is not the suite's (a first-order pump written here with PythonFMU), and
what the node publishes is compared with FMPy running the same FMU alone on the same
currents. Bad FMUs stop the node at start-up with one line; a step the FMU fails stops the
stepping with the FMU's own message."""


import numpy as np
import pytest

from .. import fmus
from .rosutil import call, LockStepDriver, spin_until, StepCollector

pytestmark = pytest.mark.ros
pytest.importorskip('pythonfmu')
fmpy = pytest.importorskip('fmpy')

@pytest.fixture(scope='module')
def lag_pump(tmp_path_factory):
    return fmus.lag_pump(tmp_path_factory.mktemp('lag_pump'))


def schedule(t):
    return 0.5 if t < 0.05 - 1e-9 else 0.6


def _alone(path, n, dt=1.0e-3, period=0.005):
    """The FMU run by FMPy alone: the current of each control instant held for its period;
    the line flow at the start, then after each step."""
    return fmus.alone(path, [schedule(np.floor(k * dt / period + 1e-9) * period)
                             for k in range(n)], dt)


def test_the_simulator_publishes_what_the_fmu_computes(nodes, test_node, lag_pump):
    sim = nodes.start('simulator', '-p', f'fmu_file:={lag_pump}', '-p', 'lock_step:=true',
                      '-p', 'real_time_factor:=0.0')
    got = StepCollector(test_node, ['line_flow', 'fmu/line_flow'])
    driver = LockStepDriver(test_node, schedule)
    spin_until(test_node, lambda: test_node.count_publishers('/clock') > 0 or not sim.alive(),
               30.0, 'the simulator')
    assert sim.alive(), sim.log()
    driver.kick()
    spin_until(test_node, lambda: got.series('line_flow')[0].size >= 200 or not sim.alive(),
               60.0, '200 steps of line_flow')
    t, flow = got.series('line_flow')
    k = np.round(t / 1.0e-3).astype(int)
    alone = _alone(lag_pump, int(k.max()))
    np.testing.assert_allclose(flow, alone[k], rtol=1e-12, atol=0.0)
    assert np.ptp(flow) > 1e-5                    # the step on the current shows
    # Every output also on fmu/<name>, the same values.
    t2, flow2 = got.series('fmu/line_flow')
    assert flow2.size and np.allclose(flow2, alone[np.round(t2 / 1e-3).astype(int)])
    # Its parameters as read-only parameters of the node.
    from rcl_interfaces.srv import GetParameters
    client = test_node.create_client(GetParameters, '/simulator/get_parameters')
    answer = call(test_node, client, GetParameters.Request(names=['fmu_parameters.tau']))
    assert answer.values[0].double_value == pytest.approx(0.02)


@pytest.mark.parametrize('make, line', [
    (lambda d: (d / 'x.fmu', (d / 'x.fmu').write_text('hello'))[0], 'not an FMU: not a zip'),
    (lambda d: d / 'none.fmu', 'none.fmu: no such file'),
])
def test_a_bad_fmu_stops_the_node_at_start_in_one_line(nodes, tmp_path, make, line):
    path = make(tmp_path)
    sim = nodes.start('simulator', '-p', f'fmu_file:={path}')
    sim.proc.wait(timeout=60)
    assert sim.proc.returncode not in (0, None)
    log = sim.log()
    assert line in log and 'Traceback' not in log, log


def test_a_failing_fmu_stops_stepping_with_its_own_message(nodes, test_node, tmp_path):
    path = fmus.lag_pump(tmp_path, 'failing', fail_after=0.02)
    sim = nodes.start('simulator', '-p', f'fmu_file:={path}',
                      '-p', 'real_time_factor:=0.0')
    spin_until(test_node, lambda: 'the pump model diverged' in sim.log() or not sim.alive(),
               60.0, "the FMU's message in the log")
    log = sim.log()
    assert 'the FMU failed in fmi2DoStep at t = 0.02 s' in log, log
    assert 'the pump model diverged (made to, for the test)' in log
