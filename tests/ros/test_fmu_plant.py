"""A user's FMU as the simulator's plant (``fmu_file:=``), through the installed simulator
over DDS: the FMU is not the suite's (a first-order pump written here with PythonFMU, FMI
2.0; in C, FMI 3.0 co-simulation and FMI 2.0 model exchange), and what the node publishes
is compared with FMPy running the same FMU alone on the same currents (the C ones: with
their closed form). Bad FMUs stop the node at
start-up with one line; a step the FMU fails stops the stepping with the FMU's own
message."""


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
    """The FMU run by FMPy alone (the C ones: their closed form): the current of each
    control instant held for its period; the line flow at the start, then after each
    step."""
    currents = [schedule(np.floor(k * dt / period + 1e-9) * period) for k in range(n)]
    if 'lag_pump3' in path.name or 'lag_pump_me' in path.name:
        return fmus.lag_closed_form(currents, dt)
    return fmus.alone(path, currents, dt)


# PythonFMU's FMI 2.0 pump, the C FMI 3.0 one (both step themselves: equal to 1e-12) and
# the C model-exchange one (integrated by the node with CVode: to 1e-4 of the range).
@pytest.mark.parametrize('fmu, tol', [('lag_pump', 1e-12), ('pump3', 1e-12), ('pump_me', 1e-4)])
def test_the_simulator_publishes_what_the_fmu_computes(nodes, test_node, fmu, tol, request):
    lag_pump = request.getfixturevalue(fmu)
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
    if tol < 1e-9:
        np.testing.assert_allclose(flow, alone[k], rtol=tol, atol=0.0)
    else:
        assert np.max(np.abs(flow - alone[k])) < tol * np.ptp(alone)
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


def test_an_fmu_load_in_a_circuit_draws_its_own_flow_at_every_step(nodes, test_node, tmp_path):
    """``type: fmu`` in a circuit behind the installed simulator: the orifice FMU of
    tests/fmus.py (built with Cd_A 2e-6 m^2 to tank, given 3e-6 by the circuit file) at the
    paper pump's line; every published load flow is the orifice's closed form with the
    circuit's area at the load pressure the node published a step before (explicit
    co-simulation), from a steady start; the area is the node's read-only parameter."""
    from sensor_msgs.msg import FluidPressure

    from hydropump_sim.params import default_params_path, load_params
    fmus.build(tmp_path, 'orifice', fmus.ORIFICE)
    circuit = tmp_path / 'fmu_load.yaml'
    circuit.write_text(f"""name: fmu_load
plant: {default_params_path()}
components:
  pump: {{type: pump, ports: {{out: line}}}}
  load: {{type: fmu, ports: {{in: line}}, file: orifice.fmu, parameters: {{Cd_A: 3.0e-6}}}}
  relief: {{type: relief, ports: {{in: line, out: tank}}, p_crack: plant.relief.p_crack,
           p_full: plant.relief.p_full, q_full: plant.relief.q_full}}
  line: {{type: volume, ports: {{node: line}}, V: plant.line.V_l}}
  tank: {{type: tank, ports: {{node: tank}}}}
""")
    p_atm = load_params(default_params_path()).fluid.p_atm
    pressure = {}
    test_node.create_subscription(FluidPressure, 'loads/load/pressure', lambda m: pressure.update(
        {round((m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec) / 1e-3):
         m.fluid_pressure - p_atm}), 1000)
    sim = nodes.start('simulator', '-p', f'circuit_file:={circuit}', '-p', 'lock_step:=true',
                      '-p', 'real_time_factor:=0.0')
    got = StepCollector(test_node, ['loads/load/flow'])
    driver = LockStepDriver(test_node, lambda t: 0.5 if t < 0.05 - 1e-9 else 0.35)
    spin_until(test_node, lambda: test_node.count_publishers('/clock') > 0 or not sim.alive(),
               60.0, 'the simulator')
    assert sim.alive(), sim.log()
    driver.kick()
    spin_until(test_node, lambda: got.series('loads/load/flow')[0].size >= 150
               or not sim.alive(), 60.0, '150 steps of loads/load/flow')
    t, flow = got.series('loads/load/flow')
    k = np.round(t / 1.0e-3).astype(int)
    both = [(q, pressure[j - 1]) for j, q in zip(k, flow) if j - 1 in pressure]
    assert len(both) > 100
    q, p = np.array(both).T
    np.testing.assert_allclose(q, 3.0e-6 * np.sqrt(2.0 * np.maximum(p, 0.0) / 850.0),
                               rtol=1e-9)
    from rcl_interfaces.srv import GetParameters
    client = test_node.create_client(GetParameters, '/simulator/get_parameters')
    answer = call(test_node, client, GetParameters.Request(names=['fmu_loads.load.Cd_A']))
    assert answer.values[0].double_value == pytest.approx(3.0e-6)
    # A steady start (the first steps hold, to 1e-4: the start's agreement docs/fmi.md
    # states), then the current's step moves the line.
    assert np.ptp(p[:40]) < 1e-4 * p[0] and np.ptp(p) > 1.0e5
