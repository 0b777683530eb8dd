"""A user's FMU as a load inside a circuit (``type: fmu``, hydropump_ctrl.fmi.loads), without
ROS: an orifice written here with PythonFMU (none of the suite's code) at the paper pump's
line, stepped beside the circuit, against the same circuit with the suite's own orifice
load of the same law (eq. 9) in its place; the FMU's flow is its closed form at every step,
the power it takes is P Q; bad files and mappings are one line each."""

import math
from pathlib import Path

import numpy as np
import pytest

from hydropump_ctrl.fmi.export import FmuError
from hydropump_ctrl.fmi.loads import CoupledSimulator
from hydropump_sim import invariants
from hydropump_sim.circuit import load_circuit
from hydropump_sim.errors import InputError
from hydropump_sim.simulate import simulate, Simulator

from .. import fmus

pytest.importorskip('fmpy')
pytest.importorskip('pythonfmu')

RHO, CDA, P_U = 850.0, 4.0e-6, 1.0e4
ROOT = Path(__file__).resolve().parents[2]


def circuit_text(load: str) -> str:
    return f"""name: fmu_load
plant: {ROOT / 'config' / 'pump.yaml'}
components:
  pump: {{type: pump, ports: {{out: line}}}}
  load: {load}
  relief: {{type: relief, ports: {{in: line, out: tank}}, p_crack: plant.relief.p_crack,
           p_full: plant.relief.p_full, q_full: plant.relief.q_full}}
  line: {{type: volume, ports: {{node: line}}, V: plant.line.V_l}}
  tank: {{type: tank, ports: {{node: tank}}}}
"""


@pytest.fixture(scope='module')
def folder(tmp_path_factory):
    """The orifice FMU (Cd_A 4e-6 m^2, to P_U above tank) and two circuits: the FMU load,
    named relative to the circuit's folder, and the suite's orifice load of the same law."""
    where = tmp_path_factory.mktemp('fmu_load')
    # A name of its own: tests/fmus.py's orifice, with other values, is built elsewhere.
    fmus.build(where, 'orifice_4e6',
               fmus.ORIFICE.replace('self.Cd_A = 2.0e-6', f'self.Cd_A = {CDA!r}')
               .replace('max(self.pressure, 0.0)', f'max(self.pressure - {P_U!r}, 0.0)'))
    (where / 'fmu.yaml').write_text(circuit_text(
        '{type: fmu, ports: {in: line}, file: orifice_4e6.fmu}'))
    mu = CDA * math.sqrt(2.0 / RHO)
    (where / 'suite.yaml').write_text(circuit_text(
        f'{{type: orifice_load, ports: {{in: line}}, mu: {mu!r}, load_pressure: {P_U!r}, '
        'aperture: 1.0, gamma: 2.0}'))
    return where


def _run(sim, n=1500, current=None, signals=('node:line', 'load.flow', 'load.work')):
    """``signals`` at the start and after each of ``n`` steps (a current step to
    ``current`` at the first one, if given); every physical invariant holds over the whole
    run (hydropump_sim.invariants: no pressure above a source, none below the cavitation
    floor, the energy balanced, every value finite)."""
    c = sim.model
    k = [c.signal_index(s) for s in signals]
    t, y, u = [sim.t], [sim.outputs().copy()], [sim.u.copy()]
    if current is not None:
        sim.set_input('pump.current', current)
    for _ in range(n):
        u.append(sim.u.copy())         # held over the step that ends at the row
        sim.step()
        t.append(sim.t)
        y.append(sim.outputs().copy())
    y = np.array(y)
    broken = invariants.check(c, np.array(t), y, np.array(u))
    assert not broken, invariants.report(broken)
    return y[:, k]


def test_an_fmu_load_runs_as_the_suites_orifice_of_the_same_law(folder):
    coupled = CoupledSimulator(load_circuit(folder / 'fmu.yaml'), 1.0e-3)
    try:
        assert coupled.reset_note is None
        assert coupled.model.operator_inputs() == []        # the FMU's flow is no operator's
        got = _run(coupled, current=0.62)
    finally:
        coupled.close()
    ref = _run(Simulator(load_circuit(folder / 'suite.yaml'), 1.0e-3), current=0.62)
    p, q, w = got.T
    # The start is the steady state of both together: the suite's, within its solver's
    # tolerance (the line pressure is steep in the flow where the pump's flow is flat in it).
    assert p[0] == pytest.approx(ref[0, 0], rel=1e-4)
    assert q[0] == pytest.approx(ref[0, 1], rel=1e-6)
    # Every step the flow is the FMU's closed form at the pressure the step started from
    # (explicit coupling), and the power it takes P Q.
    np.testing.assert_allclose(q[1:], CDA * np.sqrt(2.0 * (p[:-1] - P_U) / RHO), rtol=1e-12)
    np.testing.assert_allclose(w, p * q, rtol=1e-12)
    # The current step moves the line by bars, and the coupled run follows the suite's
    # within what a step's lag makes of it; it settles (1.5 s) where the suite's settles.
    assert np.ptp(ref[:, 0]) > 5.0e5
    assert np.max(np.abs(p - ref[:, 0])) < 0.02 * np.ptp(ref[:, 0])
    assert p[-1] == pytest.approx(ref[-1, 0], rel=1e-6)
    assert q[-1] == pytest.approx(ref[-1, 1], rel=1e-6)


def test_bad_fmu_loads_are_one_line_each(folder):
    (folder / 'missing.yaml').write_text(circuit_text(
        '{type: fmu, ports: {in: line}, file: none.fmu}'))
    with pytest.raises(FmuError) as err:
        CoupledSimulator(load_circuit(folder / 'missing.yaml'))
    assert err.value.lines == [f'load: {folder / "none.fmu"}: no such file']
    (folder / 'unmapped.yaml').write_text(circuit_text(
        '{type: fmu, ports: {in: line}, file: orifice_4e6.fmu, pressure_input: p_in}'))
    with pytest.raises(FmuError) as err:
        CoupledSimulator(load_circuit(folder / 'unmapped.yaml'))
    (line,) = err.value.lines
    assert line.startswith(f'load: {folder / "orifice_4e6.fmu"}: ') and 'p_in' in line, line
    # The plant library steps no FMU: simulate() and a plain stepper say where it runs,
    # and an exported FMU would not carry it.
    with pytest.raises(InputError, match='simulate: load step beside the circuit'):
        simulate(load_circuit(folder / 'fmu.yaml'), 0.1)
    with pytest.raises(InputError, match='Simulator: load step beside the circuit'):
        Simulator(load_circuit(folder / 'fmu.yaml'))
    from hydropump_ctrl.fmi.export import export_fmu
    with pytest.raises(FmuError) as err:
        export_fmu(folder / 'out.fmu', folder / 'fmu.yaml')
    assert err.value.lines == [f'{folder / "fmu.yaml"}: load: FMUs of their own: an FMU '
                               'of this suite does not carry them (export the circuit '
                               'without them)']
    assert not (folder / 'out.fmu').exists()


def test_an_fmu_loads_own_parameters_come_from_the_circuit_file(folder):
    """``parameters: {Cd_A: ...}`` in the circuit file (or ``--set load.parameters.Cd_A=``)
    is set in the FMU before each initialisation: its flow is the closed form with that
    area, not the one it was built with; a name it lacks or a value that is no finite number is one
    line."""
    (folder / 'half.yaml').write_text(circuit_text(
        '{type: fmu, ports: {in: line}, file: orifice_4e6.fmu, parameters: {Cd_A: 2.0e-6}}'))
    for circuit in (load_circuit(folder / 'half.yaml'),
                    load_circuit(folder / 'fmu.yaml', {'load.parameters.Cd_A': 2.0e-6})):
        coupled = CoupledSimulator(circuit, 1.0e-3)
        try:
            assert coupled.loads.parameters() == {'load': {'Cd_A': 2.0e-6}}
            p, q, _ = _run(coupled, n=50).T
        finally:
            coupled.close()
        np.testing.assert_allclose(q[1:], 2.0e-6 * np.sqrt(2.0 * (p[:-1] - P_U) / RHO),
                                   rtol=1e-12)
    for given, line in [
            ('{Cd_a: 2.0e-6}', f'load.parameters.Cd_a: {folder / "orifice_4e6.fmu"} has no '
                               'real parameter of that name (did you mean Cd_A?)'),
            ('{Cd_A: big}', "load.parameters.Cd_A = 'big': not a finite number"),
            ('{Cd_A: .inf}', 'load.parameters.Cd_A = inf: not a finite number'),
            ('{Cd_A: 3e-6}', 'write a dot and a signed exponent, e.g. 1.5e+9)')]:
        (folder / 'bad.yaml').write_text(circuit_text(
            f'{{type: fmu, ports: {{in: line}}, file: orifice_4e6.fmu, parameters: {given}}}'))
        with pytest.raises(Exception) as err:
            CoupledSimulator(load_circuit(folder / 'bad.yaml'))
        assert any(ln.endswith(line) for ln in err.value.lines), err.value.lines


def test_a_model_exchange_fmu_load_follows_its_own_law_at_every_step(folder):
    """A load written in C as FMI 2.0 model exchange (an orifice whose flow lags its law,
    tau 10 ms), integrated by the suite beside the circuit: every step its flow is the exact
    lag toward its law at the pressure the step started from (held over the step), to
    CVode's tolerance, and every invariant holds over the run."""
    fmus.c_fmu(folder, 'lag_orifice', fmus.LAG_ORIFICE_ME_C, fmus.LAG_ORIFICE_ME_DESCRIPTION, 2)
    (folder / 'me.yaml').write_text(circuit_text(
        '{type: fmu, ports: {in: line}, file: lag_orifice.fmu}'))
    coupled = CoupledSimulator(load_circuit(folder / 'me.yaml'), 1.0e-3)
    try:
        assert coupled.loads.instances[0][1].info.model_exchange
        p, q, _ = _run(coupled, n=600, current=0.62).T
    finally:
        coupled.close()
    law = 2.0e-6 * np.sqrt(2.0 * np.maximum(p[:-1], 0.0) / RHO)
    exact = law + (q[:-1] - law) * math.exp(-1.0e-3 / 0.01)
    # Within CVode's tolerance (relative 1e-6), where the law itself (no lag) is far off.
    tol = 1e-6 * q.max()
    np.testing.assert_allclose(q[1:], exact, rtol=0, atol=tol)
    assert np.max(np.abs(q[1:] - law)) > 100 * tol
    assert q[0] == pytest.approx(2.0e-6 * math.sqrt(2.0 * p[0] / RHO), rel=1e-9)


# A line volume a user might bring: its pressure from the net flow into it, p' = beta/V q (q
# held over the step: exact), from its start p0 (not the suite's code: PythonFMU's only).
VOLUME = """
from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class Volume(Fmi2Slave):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.flow = 0.0
        self.pressure = 0.0
        self.p0 = 1.0e7
        self.beta_over_V = 2.0e12
        for name, causality, variability in (
                ('flow', Fmi2Causality.input, Fmi2Variability.continuous),
                ('pressure', Fmi2Causality.output, Fmi2Variability.continuous),
                ('p0', Fmi2Causality.parameter, Fmi2Variability.fixed),
                ('beta_over_V', Fmi2Causality.parameter, Fmi2Variability.fixed)):
            self.register_variable(Real(name, causality=causality, variability=variability))

    def exit_initialization_mode(self):
        self.pressure = self.p0

    def do_step(self, current_time, step_size):
        self.pressure += step_size * self.beta_over_V * self.flow
        return True
"""


def test_an_fmu_that_sets_a_nodes_pressure_integrates_its_flow_and_settles_as_the_suite(
        folder):
    """``type: fmu_pressure``: the line volume is the FMU's (the flow into it in, the
    pressure out). Every step its pressure moves by dt beta/V times the flow the circuit
    published into it a step before; it settles where the same circuit with the suite's own
    volume settles (a steady state does not depend on the volume)."""
    fmus.build(folder, 'line_volume', VOLUME)
    (folder / 'volume.yaml').write_text(circuit_text(
        f'{{type: orifice_load, ports: {{in: line}}, mu: {CDA * math.sqrt(2.0 / RHO)!r}, '
        f'load_pressure: {P_U!r}, aperture: 1.0, gamma: 2.0}}').replace(
        '  line: {type: volume, ports: {node: line}, V: plant.line.V_l}',
        '  line: {type: fmu_pressure, ports: {node: line}, file: line_volume.fmu}'))
    sim = CoupledSimulator(load_circuit(folder / 'volume.yaml'), 1.0e-3)
    try:
        p, q = _run(sim, signals=('line.pressure', 'line.flow')).T
    finally:
        sim.close()
    assert p[0] == 1.0e7                                    # the FMU's own start
    np.testing.assert_allclose(np.diff(p), 1.0e-3 * 2.0e12 * q[:-1], rtol=1e-9, atol=1e-3)
    ref = Simulator(load_circuit(folder / 'suite.yaml'), 1.0e-3)
    assert abs(p[-1] - p[0]) > 1.0e5 and abs(q[-1]) < 1e-9
    assert p[-1] == pytest.approx(ref.outputs()[ref.model.signal_index('node:line')], rel=1e-6)
