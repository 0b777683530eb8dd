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


# The same pump as an FMI 3.0 co-simulation FMU written in C against the standard's headers
# (those FMPy ships), built with the system's C compiler: neither PythonFMU nor the suite in
# it. Its lag is integrated exactly over each step (q += (target - q)(1 - exp(-h/tau))), so a
# run has a closed form to check against; past ``fail_after`` [s] (0: never) a step fails,
# saying why through the FMU's logger.
PUMP3_C = textwrap.dedent(r"""
    #include <math.h>
    #include <stdlib.h>
    #include "fmi3PlatformTypes.h"
    #include "fmi3FunctionTypes.h"

    enum { TIME, CURRENT, FLOW, PRESSURE, TAU, GAIN, FAIL_AFTER, N };
    typedef struct { double v[N]; double q; fmi3LogMessageCallback log;
                     fmi3InstanceEnvironment env; } Pump;

    static void start(Pump *p) {
        p->v[CURRENT] = 0.5; p->v[TAU] = 0.02; p->v[GAIN] = 1.0e-3; p->v[FAIL_AFTER] = 0.0;
        p->v[TIME] = 0.0; p->q = 0.0;
    }
    static void publish(Pump *p) {
        p->v[FLOW] = p->q;
        p->v[PRESSURE] = 2.0e6 + 8.0e9 * p->q;
    }
    static double target(Pump *p) { return p->v[GAIN] * (p->v[CURRENT] - 0.3); }

    const char *fmi3GetVersion(void) { return "3.0"; }

    fmi3Instance fmi3InstantiateCoSimulation(
            fmi3String name, fmi3String token, fmi3String resources, fmi3Boolean visible,
            fmi3Boolean loggingOn, fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
            const fmi3ValueReference required[], size_t nRequired,
            fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
            fmi3IntermediateUpdateCallback update) {
        Pump *p = calloc(1, sizeof(Pump));
        if (!p) return NULL;
        p->log = log; p->env = env;
        start(p);
        return p;
    }
    void fmi3FreeInstance(fmi3Instance c) { free(c); }
    fmi3Status fmi3EnterInitializationMode(fmi3Instance c, fmi3Boolean tolDefined,
            fmi3Float64 tol, fmi3Float64 startTime, fmi3Boolean stopDefined,
            fmi3Float64 stopTime) {
        ((Pump *)c)->v[TIME] = startTime;
        return fmi3OK;
    }
    fmi3Status fmi3ExitInitializationMode(fmi3Instance c) {
        Pump *p = c;
        p->q = target(p);
        publish(p);
        return fmi3OK;
    }
    fmi3Status fmi3EnterStepMode(fmi3Instance c) { return fmi3OK; }
    fmi3Status fmi3Terminate(fmi3Instance c) { return fmi3OK; }
    fmi3Status fmi3Reset(fmi3Instance c) { start(c); return fmi3OK; }
    fmi3Status fmi3SetDebugLogging(fmi3Instance c, fmi3Boolean on, size_t n,
                                   const fmi3String categories[]) { return fmi3OK; }
    fmi3Status fmi3SetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                              const fmi3Float64 values[], size_t nValues) {
        Pump *p = c;
        for (size_t i = 0; i < nvr; i++) {
            if (vr[i] != CURRENT && vr[i] != TAU && vr[i] != GAIN && vr[i] != FAIL_AFTER)
                return fmi3Error;
            p->v[vr[i]] = values[i];
        }
        return fmi3OK;
    }
    fmi3Status fmi3GetFloat64(fmi3Instance c, const fmi3ValueReference vr[], size_t nvr,
                              fmi3Float64 values[], size_t nValues) {
        Pump *p = c;
        for (size_t i = 0; i < nvr; i++) {
            if (vr[i] >= N) return fmi3Error;
            values[i] = p->v[vr[i]];
        }
        return fmi3OK;
    }
    fmi3Status fmi3DoStep(fmi3Instance c, fmi3Float64 t, fmi3Float64 h,
                          fmi3Boolean noSetPrior, fmi3Boolean *eventNeeded,
                          fmi3Boolean *terminate, fmi3Boolean *earlyReturn,
                          fmi3Float64 *lastTime) {
        Pump *p = c;
        *eventNeeded = fmi3False; *terminate = fmi3False; *earlyReturn = fmi3False;
        *lastTime = t;
        if (p->v[FAIL_AFTER] > 0.0 && t >= p->v[FAIL_AFTER]) {
            if (p->log) p->log(p->env, fmi3Error, "logStatusError",
                               "the pump model diverged (made to, for the test)");
            return fmi3Error;
        }
        p->q += (target(p) - p->q) * (1.0 - exp(-h / p->v[TAU]));
        p->v[TIME] = t + h;
        *lastTime = t + h;
        publish(p);
        return fmi3OK;
    }
    """)

PUMP3_DESCRIPTION = textwrap.dedent("""\
    <?xml version="1.0" encoding="UTF-8"?>
    <fmiModelDescription fmiVersion="3.0" modelName="LagPump3"
        instantiationToken="{8c4e810f-3df3-4a00-8276-176fa3c9f003}"
        description="A first-order pump in C (FMI 3.0 co-simulation)">
      <CoSimulation modelIdentifier="NAME" canHandleVariableCommunicationStepSize="true"/>
      <UnitDefinitions>
        <Unit name="s"><BaseUnit s="1"/></Unit>
        <Unit name="A"><BaseUnit A="1"/></Unit>
        <Unit name="m3/s"><BaseUnit m="3" s="-1"/></Unit>
        <Unit name="Pa"><BaseUnit kg="1" m="-1" s="-2"/></Unit>
      </UnitDefinitions>
      <ModelVariables>
        <Float64 name="time" valueReference="0" causality="independent"
            variability="continuous" unit="s"/>
        <Float64 name="current" valueReference="1" causality="input" variability="continuous"
            start="0.5" unit="A"/>
        <Float64 name="line_flow" valueReference="2" causality="output"
            variability="continuous" unit="m3/s"/>
        <Float64 name="line_pressure" valueReference="3" causality="output"
            variability="continuous" unit="Pa"/>
        <Float64 name="tau" valueReference="4" causality="parameter" variability="fixed"
            start="0.02" min="0.001" max="1" unit="s"/>
        <Float64 name="gain" valueReference="5" causality="parameter" variability="fixed"
            start="0.001" min="1e-05" max="0.1"/>
        <Float64 name="fail_after" valueReference="6" causality="parameter" variability="fixed"
            start="0" unit="s"/>
      </ModelVariables>
      <ModelStructure>
        <Output valueReference="2"/>
        <Output valueReference="3"/>
        <InitialUnknown valueReference="2"/>
        <InitialUnknown valueReference="3"/>
      </ModelStructure>
    </fmiModelDescription>
    """)


def c_pump3(where: Path, name: str = 'lag_pump3') -> Path:
    """:data:`PUMP3_C` compiled and packed as ``<where>/<name>.fmu`` (FMI 3.0, Linux x86-64);
    the test is skipped where no C compiler is installed."""
    import subprocess
    import zipfile

    import fmpy
    import pytest
    cc = shutil.which('cc') or shutil.which('gcc')
    if cc is None:
        pytest.skip('no C compiler (cc) to build the FMI 3.0 test FMU')
    import re
    headers = Path(fmpy.__file__).parent / 'c-code'
    # A host loads every function of the standard: those the pump does not need refuse.
    every = set(re.findall(r'\bfmi3(\w+)TYPE\b', (headers / 'fmi3FunctionTypes.h').read_text()))
    have = set(re.findall(r'\bfmi3(\w+)\(', PUMP3_C))
    stubs = ''.join(f'int fmi3{f}(void) {{ return 3; }}\n' for f in sorted(every - have))
    src = where / f'{name}.c'
    src.write_text(PUMP3_C + stubs)
    lib = where / f'{name}.so'
    subprocess.run([cc, '-shared', '-fPIC', '-O2', '-o', str(lib), str(src),
                    '-I', str(headers), '-lm'],
                   check=True, capture_output=True)
    out = where / f'{name}.fmu'
    with zipfile.ZipFile(out, 'w') as z:
        z.writestr('modelDescription.xml', PUMP3_DESCRIPTION.replace('NAME', name))
        z.write(lib, f'binaries/x86_64-linux/{name}.so')
    return out


def pump3_closed_form(currents, dt: float = 1.0e-3, tau: float = 0.02, gain: float = 1.0e-3):
    """:data:`PUMP3_C`'s flow from its equation alone: q_0 at the first current's target,
    then ``currents[k]`` held over step ``k`` through the exact lag."""
    import numpy as np
    a = 1.0 - np.exp(-dt / tau)
    q = [gain * (currents[0] - 0.3)]
    for i in currents:
        q.append(q[-1] + (gain * (i - 0.3) - q[-1]) * a)
    return np.array(q)


def run3(path, inputs, n: int, dt: float = 1.0e-3):
    """An FMI 3.0 FMU stepped ``n`` times by ``dt`` through FMPy's FMI 3.0 interface as a
    master orders it: inputs of t_k set, a step to t_k+1, the inputs of t_k+1 set before its
    outputs are read (``inputs``: name -> n + 1 values). Returns the output names and their
    values at t_0..t_n."""
    import fmpy
    from fmpy.fmi3 import FMU3Slave
    import numpy as np
    md = fmpy.read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outs = [v.name for v in md.modelVariables if v.causality == 'output']
    where = fmpy.extract(str(path))
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=where,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName='three')
    try:
        fmu.instantiate()
        fmu.enterInitializationMode(startTime=0.0)
        for name, u in inputs.items():
            fmu.setFloat64([vr[name]], [float(u[0])])
        fmu.exitInitializationMode()
        rows = [fmu.getFloat64([vr[o] for o in outs])]
        for k in range(n):
            for name, u in inputs.items():
                fmu.setFloat64([vr[name]], [float(u[k])])
            fmu.doStep(currentCommunicationPoint=k * dt, communicationStepSize=dt)
            for name, u in inputs.items():
                fmu.setFloat64([vr[name]], [float(u[k + 1])])
            rows.append(fmu.getFloat64([vr[o] for o in outs]))
        fmu.terminate()
        fmu.freeInstance()           # FMPy frees the library with it
    finally:
        shutil.rmtree(where, ignore_errors=True)
    return outs, np.array(rows)


if __name__ == '__main__':
    # python -m tests.fmus run3 FMU INPUTS.npz OUT.npz N: run3 in a process of its own.
    import numpy as np
    _, fmu, given, out, steps = sys.argv[1:]
    names, values = run3(fmu, dict(np.load(given)), int(steps))
    np.savez(out, names=np.array(names), values=values)
    print('written', flush=True)
