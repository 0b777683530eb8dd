"""FMUs this suite did not write, for the FMI tests: small models written here with PythonFMU's
own classes (none of the suite's code), built into FMUs in a test's folder."""

from contextlib import contextmanager
from pathlib import Path
import shutil
import sys
import textwrap

# A load a user might bring: an orifice, flow from the pressure across it (not the suite's
# code: PythonFMU's own classes only).
ORIFICE = textwrap.dedent("""
    from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


    class Orifice(Fmi2Slave):
        description = 'A sharp-edged orifice to tank'

        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.pressure = 1.0e7
            self.flow = 0.0
            self.Cd_A = 2.0e-6
            self.register_variable(Real('pressure', causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous))
            self.register_variable(Real('flow', causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous))
            self.register_variable(Real('Cd_A', causality=Fmi2Causality.parameter,
                                        variability=Fmi2Variability.fixed))

        def _flow(self):
            self.flow = self.Cd_A * (2.0 * max(self.pressure, 0.0) / 850.0) ** 0.5

        def exit_initialization_mode(self):
            self._flow()

        def do_step(self, current_time, step_size):
            self._flow()
            return True
    """)


# A pump as a user might model it elsewhere: the flow follows the current through a first
# lag of gain ``gain`` [m^3/s/A] above 0.3 A and time constant ``tau`` [s] (``substeps``
# explicit Euler steps per step, ten by default), the line pressure rises with the flow over
# the load's resistance; its outputs carry a seeded Gaussian noise of ``noise`` times their
# own scale (0: none); it fails on purpose past ``fail_after`` [s] (0: never), saying why.
PUMP = textwrap.dedent("""
    import random

    from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
    from pythonfmu.enums import Fmi2Status


    class LagPump(Fmi2Slave):
        def __init__(self, **kwargs):
            super().__init__(**kwargs)
            self.current = 0.5
            self.line_flow = 0.0
            self.line_pressure = 0.0
            self.tau = 0.02
            self.gain = 1.0e-3
            self.noise = 0.0
            self.fail_after = 0.0
            self.substeps = 10.0
            self.q = 0.0
            self.rng = random.Random(1)
            for name, causality, variability in (
                    ('current', Fmi2Causality.input, Fmi2Variability.continuous),
                    ('line_flow', Fmi2Causality.output, Fmi2Variability.continuous),
                    ('line_pressure', Fmi2Causality.output, Fmi2Variability.continuous),
                    ('tau', Fmi2Causality.parameter, Fmi2Variability.fixed),
                    ('gain', Fmi2Causality.parameter, Fmi2Variability.fixed),
                    ('noise', Fmi2Causality.parameter, Fmi2Variability.fixed),
                    ('fail_after', Fmi2Causality.parameter, Fmi2Variability.fixed),
                    ('substeps', Fmi2Causality.parameter, Fmi2Variability.fixed)):
                self.register_variable(Real(name, causality=causality,
                                            variability=variability))

        def _target(self):
            return self.gain * (self.current - 0.3)

        def _publish(self):
            n = self.noise
            self.line_flow = self.q + n * 1.0e-4 * self.rng.gauss(0.0, 1.0)
            self.line_pressure = 2.0e6 + 8.0e9 * self.q + n * 1.0e5 * self.rng.gauss(0.0, 1.0)

        def exit_initialization_mode(self):
            self.q = self._target()
            self.rng = random.Random(1)
            self._publish()

        def do_step(self, current_time, step_size):
            if self.fail_after and current_time >= self.fail_after:
                self.log('the pump model diverged (made to, for the test)', Fmi2Status.error)
                return False
            n = max(1, int(self.substeps))
            h = step_size / n
            for _ in range(n):
                self.q += h * (self._target() - self.q) / self.tau
            self._publish()
            return True
    """)


def build(where: Path, name: str, source: str) -> Path:
    """``source`` (a PythonFMU slave) built as ``<where>/<name>.fmu``.

    PythonFMU imports an FMU's model script by its file name, into the one interpreter of
    the process: two FMUs of one name in a process get the first one's module. The
    builder's import is dropped again here; each test FMU takes a name of its own."""
    from pythonfmu.builder import FmuBuilder
    script = where / f'{name}.py'
    script.write_text(source)
    sys.path.insert(0, str(where))
    sys.modules.pop(name, None)
    try:
        return FmuBuilder.build_FMU(script, dest=where / f'{name}.fmu')
    finally:
        sys.path.remove(str(where))
        sys.modules.pop(name, None)


def lag_pump(where: Path, name: str = 'lag_pump', fail_after: float = 0.0) -> Path:
    """The first-order pump, failing past ``fail_after`` [s] (0: never)."""
    return build(where, name, PUMP.replace('self.fail_after = 0.0',
                                           f'self.fail_after = {fail_after!r}'))


@contextmanager
def opened(path, name: str = 'test'):
    """The FMU at ``path`` unpacked and instantiated by FMPy alone, as a master does, with
    its value references by name: ``(fmu, vr)``; freed and its files removed after."""
    import fmpy
    from fmpy.fmi2 import FMU2Slave
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    where = fmpy.extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=where,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    try:
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        yield fmu, vr
    finally:
        fmu.freeInstance()
        shutil.rmtree(where, ignore_errors=True)


def alone(path, currents, dt: float = 1.0e-3, output: str = 'line_flow'):
    """A pump FMU run by FMPy alone: ``currents[k]`` held over step ``k`` (the first also
    at the start); ``output`` at the start, then after each step."""
    import numpy as np
    with opened(path, 'alone') as (fmu, vr):
        fmu.enterInitializationMode()
        fmu.setReal([vr['current']], [float(currents[0])])
        fmu.exitInitializationMode()
        out = [fmu.getReal([vr[output]])[0]]
        for k, i in enumerate(currents):
            fmu.setReal([vr['current']], [float(i)])
            fmu.doStep(currentCommunicationPoint=k * dt, communicationStepSize=dt)
            out.append(fmu.getReal([vr[output]])[0])
        fmu.terminate()
    return np.array(out)
