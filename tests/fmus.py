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


def c_fmu(where: Path, name: str, source: str, description: str, fmi: int) -> Path:
    """A C FMU (``source`` against the FMI ``fmi`` headers FMPy ships) compiled and packed
    with its model description as ``<where>/<name>.fmu``, for Linux x86-64. A host loads
    every function of the standard: those ``source`` does not define are added, refusing
    (status error). The test is skipped where no C compiler is installed."""
    import re
    import subprocess
    import zipfile

    import fmpy
    import pytest
    cc = shutil.which('cc') or shutil.which('gcc')
    if cc is None:
        pytest.skip('no C compiler (cc) to build the test FMU')
    headers = Path(fmpy.__file__).parent / 'c-code'
    types = (headers / f'fmi{fmi}FunctionTypes.h').read_text()
    every = set(re.findall(rf'\bfmi{fmi}(\w+)TYPE\b', types))
    have = set(re.findall(rf'\bfmi{fmi}(\w+)\(', source))
    stubs = ''.join(f'int fmi{fmi}{f}(void) {{ return 3; }}\n' for f in sorted(every - have))
    src = where / f'{name}.c'
    src.write_text(source + stubs)
    lib = where / f'{name}.so'
    subprocess.run([cc, '-shared', '-fPIC', '-O2', '-o', str(lib), str(src), '-I', str(headers),
                    '-lm'], check=True, capture_output=True)
    out = where / f'{name}.fmu'
    with zipfile.ZipFile(out, 'w') as z:
        z.writestr('modelDescription.xml', description.replace('NAME', name))
        z.write(lib, f'binaries/{"x86_64-linux" if fmi == 3 else "linux64"}/{name}.so')
    return out


def c_pump3(where: Path, name: str = 'lag_pump3') -> Path:
    """:data:`PUMP3_C` as an FMI 3.0 co-simulation FMU."""
    return c_fmu(where, name, PUMP3_C, PUMP3_DESCRIPTION, 3)


# What the FMI 2.0 model-exchange FMUs in C below share: the headers, and the calls that
# only accept (their state's nominal is 1e-4 m^3/s, a flow's scale).
ME_SCAFFOLD = textwrap.dedent(r"""
    #include <math.h>
    #include <stdlib.h>
    #include "fmi2TypesPlatform.h"
    #include "fmi2FunctionTypes.h"
    const char *fmi2GetTypesPlatform(void) { return "default"; }
    const char *fmi2GetVersion(void) { return "2.0"; }
    void fmi2FreeInstance(fmi2Component c) { free(c); }
    fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n,
                                   const fmi2String categories[]) { return fmi2OK; }
    fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
    fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
    fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
        x[0] = 1.0e-4;
        return fmi2OK;
    }
    fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
    fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
    fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetPrior,
            fmi2Boolean *enterEventMode, fmi2Boolean *terminate) {
        *enterEventMode = fmi2False; *terminate = fmi2False;
        return fmi2OK;
    }
    """)


# The same pump again as an FMI 2.0 model-exchange FMU in C (the equations only: the host
# integrates them), with a time event: at ``t_switch`` [s] (0: never) its gain doubles, an
# instant that falls between communication points; and a state event: with ``q_max``
# [m^3/s] (0: none) the plate meets its end stop where the flow reaches q_max (an event
# indicator q_max - q crosses zero), and stays there until the target falls below it. It
# asks for completed integrator steps (FMI 2.0's default) and declares its state's nominal
# (1e-4 m^3/s); past ``fail_after`` [s] (0: never) its derivatives fail, saying why.
PUMP_ME_C = ME_SCAFFOLD + textwrap.dedent(r"""

    enum { CURRENT, FLOW, PRESSURE, Q, DQ, TAU, GAIN, T_SWITCH, FAIL_AFTER, Q_MAX, N };
    typedef struct { double v[N]; double t; int switched, at_stop; fmi2CallbackFunctions cb;
                     const char *name; } Pump;

    static void start(Pump *p) {
        p->v[CURRENT] = 0.5; p->v[TAU] = 0.02; p->v[GAIN] = 1.0e-3; p->v[T_SWITCH] = 0.0;
        p->v[FAIL_AFTER] = 0.0; p->v[Q_MAX] = 0.0; p->v[Q] = 0.0; p->t = 0.0;
        p->switched = 0; p->at_stop = 0;
    }
    static double target(Pump *p) {
        return (p->switched ? 2.0 : 1.0) * p->v[GAIN] * (p->v[CURRENT] - 0.3);
    }
    static void stop(Pump *p) {     /* the end stop met or left, at an event */
        double qm = p->v[Q_MAX];
        if (p->at_stop && target(p) < qm) p->at_stop = 0;
        if (!p->at_stop && qm > 0.0 && p->v[Q] >= qm - 1e-12) {
            p->at_stop = 1;
            p->v[Q] = qm;
        }
    }
    static void update(Pump *p) {
        p->v[DQ] = (target(p) - p->v[Q]) / p->v[TAU];
        if (p->at_stop && p->v[DQ] > 0.0) p->v[DQ] = 0.0;
        p->v[FLOW] = p->v[Q];
        p->v[PRESSURE] = 2.0e6 + 8.0e9 * p->v[Q];
    }

    fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
            fmi2String resources, const fmi2CallbackFunctions *functions,
            fmi2Boolean visible, fmi2Boolean loggingOn) {
        if (type != fmi2ModelExchange) return NULL;
        Pump *p = calloc(1, sizeof(Pump));
        if (!p) return NULL;
        p->cb = *functions; p->name = "pump";
        start(p);
        return p;
    }
    fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol,
            fmi2Real tStart, fmi2Boolean stopDefined, fmi2Real tStop) {
        ((Pump *)c)->t = tStart;
        return fmi2OK;
    }
    fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
        Pump *p = c;
        p->v[Q] = target(p);
        if (p->v[Q_MAX] > 0.0 && p->v[Q] > p->v[Q_MAX]) p->v[Q] = p->v[Q_MAX];
        stop(p);
        update(p);
        return fmi2OK;
    }
    fmi2Status fmi2Reset(fmi2Component c) { start(c); return fmi2OK; }
    fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                           const fmi2Real value[]) {
        Pump *p = c;
        for (size_t i = 0; i < nvr; i++) {
            if (vr[i] != CURRENT && vr[i] < TAU) return fmi2Error;
            if (vr[i] >= N) return fmi2Error;
            p->v[vr[i]] = value[i];
        }
        update(p);
        return fmi2OK;
    }
    fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                           fmi2Real value[]) {
        Pump *p = c;
        update(p);
        for (size_t i = 0; i < nvr; i++) {
            if (vr[i] >= N) return fmi2Error;
            value[i] = p->v[vr[i]];
        }
        return fmi2OK;
    }
    fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Pump *)c)->t = t; return fmi2OK; }
    fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
        Pump *p = c;
        p->v[Q] = x[0];
        update(p);
        return fmi2OK;
    }
    fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
        x[0] = ((Pump *)c)->v[Q];
        return fmi2OK;
    }
    fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
        Pump *p = c;
        if (p->v[FAIL_AFTER] > 0.0 && p->t >= p->v[FAIL_AFTER]) {
            p->cb.logger(p->cb.componentEnvironment, p->name, fmi2Error, "logStatusError",
                         "the pump model diverged (made to, for the test)");
            return fmi2Error;
        }
        update(p);
        dx[0] = p->v[DQ];
        return fmi2OK;
    }
    fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) {
        Pump *p = c;
        double qm = p->v[Q_MAX];
        z[0] = qm <= 0.0 ? 1.0 : p->at_stop ? qm - target(p) : qm - p->v[Q];
        return fmi2OK;
    }
    fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
        Pump *p = c;
        double ts = p->v[T_SWITCH];
        double q = p->v[Q];
        if (!p->switched && ts > 0.0 && p->t >= ts) p->switched = 1;   /* no tolerance */
        stop(p);
        update(p);
        info->newDiscreteStatesNeeded = fmi2False;
        info->terminateSimulation = fmi2False;
        info->nominalsOfContinuousStatesChanged = fmi2False;
        info->valuesOfContinuousStatesChanged = q != p->v[Q] ? fmi2True : fmi2False;
        info->nextEventTimeDefined = (!p->switched && ts > 0.0) ? fmi2True : fmi2False;
        info->nextEventTime = ts;
        return fmi2OK;
    }
    """)

PUMP_ME_DESCRIPTION = textwrap.dedent("""\
    <?xml version="1.0" encoding="UTF-8"?>
    <fmiModelDescription fmiVersion="2.0" modelName="LagPumpME"
        guid="{5d1c7a52-0a7e-4d8e-9a51-2f0e3b6c7e11}" numberOfEventIndicators="1"
        description="A first-order pump in C (FMI 2.0 model exchange)">
      <ModelExchange modelIdentifier="NAME"/>
      <UnitDefinitions>
        <Unit name="s"><BaseUnit s="1"/></Unit>
        <Unit name="A"><BaseUnit A="1"/></Unit>
        <Unit name="m3/s"><BaseUnit m="3" s="-1"/></Unit>
        <Unit name="Pa"><BaseUnit kg="1" m="-1" s="-2"/></Unit>
      </UnitDefinitions>
      <ModelVariables>
        <ScalarVariable name="current" valueReference="0" causality="input"
            variability="continuous"><Real start="0.5" unit="A"/></ScalarVariable>
        <ScalarVariable name="line_flow" valueReference="1" causality="output"
            variability="continuous"><Real unit="m3/s"/></ScalarVariable>
        <ScalarVariable name="line_pressure" valueReference="2" causality="output"
            variability="continuous"><Real unit="Pa"/></ScalarVariable>
        <ScalarVariable name="q" valueReference="3" causality="local"
            variability="continuous" initial="calculated"><Real unit="m3/s"/></ScalarVariable>
        <ScalarVariable name="der(q)" valueReference="4" causality="local"
            variability="continuous" initial="calculated"><Real derivative="4"/>
        </ScalarVariable>
        <ScalarVariable name="tau" valueReference="5" causality="parameter"
            variability="fixed" initial="exact"><Real start="0.02" unit="s"/></ScalarVariable>
        <ScalarVariable name="gain" valueReference="6" causality="parameter"
            variability="fixed" initial="exact"><Real start="0.001"/></ScalarVariable>
        <ScalarVariable name="t_switch" valueReference="7" causality="parameter"
            variability="fixed" initial="exact"><Real start="0" unit="s"/></ScalarVariable>
        <ScalarVariable name="fail_after" valueReference="8" causality="parameter"
            variability="fixed" initial="exact"><Real start="0" unit="s"/></ScalarVariable>
        <ScalarVariable name="q_max" valueReference="9" causality="parameter"
            variability="fixed" initial="exact"><Real start="0" unit="m3/s"/></ScalarVariable>
      </ModelVariables>
      <ModelStructure>
        <Outputs><Unknown index="2"/><Unknown index="3"/></Outputs>
        <Derivatives><Unknown index="5"/></Derivatives>
        <InitialUnknowns>
          <Unknown index="2"/><Unknown index="3"/><Unknown index="4"/><Unknown index="5"/>
        </InitialUnknowns>
      </ModelStructure>
    </fmiModelDescription>
    """)


def c_pump_me(where: Path, name: str = 'lag_pump_me') -> Path:
    """:data:`PUMP_ME_C` as an FMI 2.0 model-exchange FMU."""
    return c_fmu(where, name, PUMP_ME_C, PUMP_ME_DESCRIPTION, 2)


# A load as a user might bring it as model exchange, in C: an orifice whose flow lags its
# law, q' = (Cd_A sqrt(2 max(p, 0) / 850) - q) / tau, p its input (the node's pressure,
# gauge), q its output; it starts settled at its law.
LAG_ORIFICE_ME_C = ME_SCAFFOLD + textwrap.dedent(r"""

    enum { PRESSURE, FLOW, Q, DQ, CD_A, TAU, N };
    typedef struct { double v[N]; } Orifice;

    static void start(Orifice *o) {
        o->v[PRESSURE] = 1.0e7; o->v[CD_A] = 2.0e-6; o->v[TAU] = 0.01; o->v[Q] = 0.0;
    }
    static double law(Orifice *o) {
        double p = o->v[PRESSURE] > 0.0 ? o->v[PRESSURE] : 0.0;
        return o->v[CD_A] * sqrt(2.0 * p / 850.0);
    }
    static void update(Orifice *o) {
        o->v[DQ] = (law(o) - o->v[Q]) / o->v[TAU];
        o->v[FLOW] = o->v[Q];
    }

    fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid,
            fmi2String resources, const fmi2CallbackFunctions *functions,
            fmi2Boolean visible, fmi2Boolean loggingOn) {
        if (type != fmi2ModelExchange) return NULL;
        Orifice *o = calloc(1, sizeof(Orifice));
        if (o) start(o);
        return o;
    }
    fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol,
            fmi2Real tStart, fmi2Boolean stopDefined, fmi2Real tStop) { return fmi2OK; }
    fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
        Orifice *o = c;
        o->v[Q] = law(o);
        update(o);
        return fmi2OK;
    }
    fmi2Status fmi2Reset(fmi2Component c) { start(c); return fmi2OK; }
    fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                           const fmi2Real value[]) {
        Orifice *o = c;
        for (size_t i = 0; i < nvr; i++) {
            if (vr[i] != PRESSURE && vr[i] != CD_A && vr[i] != TAU) return fmi2Error;
            o->v[vr[i]] = value[i];
        }
        update(o);
        return fmi2OK;
    }
    fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                           fmi2Real value[]) {
        Orifice *o = c;
        update(o);
        for (size_t i = 0; i < nvr; i++) {
            if (vr[i] >= N) return fmi2Error;
            value[i] = o->v[vr[i]];
        }
        return fmi2OK;
    }
    fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { return fmi2OK; }
    fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
        ((Orifice *)c)->v[Q] = x[0];
        update(c);
        return fmi2OK;
    }
    fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
        x[0] = ((Orifice *)c)->v[Q];
        return fmi2OK;
    }
    fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
        update(c);
        dx[0] = ((Orifice *)c)->v[DQ];
        return fmi2OK;
    }
    fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) {
        return fmi2OK;
    }
    fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *info) {
        info->newDiscreteStatesNeeded = fmi2False;
        info->terminateSimulation = fmi2False;
        info->nominalsOfContinuousStatesChanged = fmi2False;
        info->valuesOfContinuousStatesChanged = fmi2False;
        info->nextEventTimeDefined = fmi2False;
        info->nextEventTime = 0.0;
        return fmi2OK;
    }
    """)

LAG_ORIFICE_ME_DESCRIPTION = textwrap.dedent("""\
    <?xml version="1.0" encoding="UTF-8"?>
    <fmiModelDescription fmiVersion="2.0" modelName="LagOrifice"
        guid="{0b8f6c3e-6a1d-4f0e-8a55-6f2d1c9e7a21}" numberOfEventIndicators="0">
      <ModelExchange modelIdentifier="NAME"/>
      <ModelVariables>
        <ScalarVariable name="pressure" valueReference="0" causality="input"
            variability="continuous"><Real start="1e7"/></ScalarVariable>
        <ScalarVariable name="flow" valueReference="1" causality="output"
            variability="continuous"><Real/></ScalarVariable>
        <ScalarVariable name="q" valueReference="2" causality="local"
            variability="continuous" initial="calculated"><Real/></ScalarVariable>
        <ScalarVariable name="der(q)" valueReference="3" causality="local"
            variability="continuous" initial="calculated"><Real derivative="3"/>
        </ScalarVariable>
        <ScalarVariable name="Cd_A" valueReference="4" causality="parameter"
            variability="fixed" initial="exact"><Real start="2e-6"/></ScalarVariable>
        <ScalarVariable name="tau" valueReference="5" causality="parameter"
            variability="fixed" initial="exact"><Real start="0.01"/></ScalarVariable>
      </ModelVariables>
      <ModelStructure>
        <Outputs><Unknown index="2"/></Outputs>
        <Derivatives><Unknown index="4"/></Derivatives>
        <InitialUnknowns><Unknown index="2"/><Unknown index="3"/><Unknown index="4"/>
        </InitialUnknowns>
      </ModelStructure>
    </fmiModelDescription>
    """)


def lag_closed_form(currents, dt: float = 1.0e-3, tau: float = 0.02, gain: float = 1.0e-3,
                    t_switch: float = 0.0, q_max: float = 0.0):
    """The C pumps' flow from their equation alone: q_0 at the first current's target,
    then ``currents[k]`` held over step ``k`` through the exact lag, the gain doubled from
    ``t_switch`` on (0: never), mid-step where it falls there; with ``q_max`` (0: none) the
    flow held at q_max from the instant it reaches it until the target falls below."""
    import numpy as np
    g = lambda t: gain * (2.0 if 0.0 < t_switch <= t + 1e-12 else 1.0)  # noqa: E731

    def lag(x, target, s):      # over s seconds, the end stop met on the way
        if q_max > 0.0 and x >= q_max and target >= q_max:
            return q_max
        x = target + (x - target) * np.exp(-s / tau)
        return min(x, q_max) if q_max > 0.0 and target > q_max else x

    first = g(0.0) * (currents[0] - 0.3)
    q = [min(first, q_max) if q_max > 0.0 else first]
    for k, i in enumerate(currents):
        t0, t1, x = k * dt, (k + 1) * dt, q[-1]
        if t0 < t_switch < t1:
            x, t0 = lag(x, g(t0) * (i - 0.3), t_switch - t0), t_switch
        q.append(lag(x, g(t0) * (i - 0.3), t1 - t0))
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


def lag_recording(levels, p_atm, seed, n=1200, dwell=0.3, settled_at=None, gain=1.2e-3,
                  tau=0.025, dt=1.0e-3):
    """The lag's exact response to a staircase of ``levels`` held ``dwell`` each: the flow
    q' = (gain (I - 0.3) - q) / tau from rest at the first level (or at ``settled_at`` [A]),
    sampled every dt, with noise of 2e-6 m^3/s on it and 1e4 Pa on the pressure 2 MPa +
    8e9 q (absolute)."""
    import numpy as np

    from hydropump_ctrl.ident.recording import Recording
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    cur = np.asarray(levels)[np.minimum((t / dwell).astype(int), len(levels) - 1)]
    q = np.empty(n)
    q[0] = gain * ((cur[0] if settled_at is None else settled_at) - 0.3)
    for k in range(n - 1):
        target = gain * (cur[k] - 0.3)
        q[k + 1] = target + (q[k] - target) * np.exp(-dt / tau)
    return Recording(t, {'solenoid_current_cmd': cur,
                         'line_flow': q + 2e-6 * rng.standard_normal(n),
                         'line_pressure': 2e6 + 8e9 * q + 1e4 * rng.standard_normal(n) + p_atm},
                     name=f'staircase{seed}',
                     roles={'current': 'solenoid_current_cmd', 'flow': 'line_flow'})


if __name__ == '__main__':
    # python -m tests.fmus run3 FMU INPUTS.npz OUT.npz N: run3 in a process of its own.
    import numpy as np
    _, fmu, given, out, steps = sys.argv[1:]
    names, values = run3(fmu, dict(np.load(given)), int(steps))
    np.savez(out, names=np.array(names), values=values)
    print('written', flush=True)
