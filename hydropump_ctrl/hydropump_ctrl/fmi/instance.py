"""One instance of a user's FMU (FMI 2.0 or 3.0), stepped through FMPy: what the FMU plant
(:mod:`.plant`), the FMU loads of a circuit (:mod:`.loads`) and the FMU calibration share.

A co-simulation FMU steps itself. A model-exchange FMU (only the equations: what Amesim
exports) is integrated here between communication points by CVode (BDF, the SUNDIALS FMPy
ships), relative tolerance :data:`RTOL` and each state's nominal times it as its absolute
one; its time, state and step events are handled at the instant they occur, and a change of
its inputs at a communication point restarts the integration there (the inputs are held
over each step, as a co-simulation master holds them).

Variables are set and read by name (real ones: FMI 2.0 ``Real``, FMI 3.0 ``Float64``);
parameters are set before each initialisation (both versions set them in the instantiated
state); the FMU's messages are kept, so that a failing call says what the FMU said. Nothing
here imports ROS.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
import os
import shutil
import threading

from hydropump_sim.errors import HydropumpError
from hydropump_sim.simulate import IntegrationError

from .export import FmuError
from .reading import FmuInfo

#: CVode's relative tolerance for a model-exchange FMU.
RTOL = 1.0e-6
#: FMPy loads a library from its folder, changing the process's working folder meanwhile:
#: one load at a time (a fleet loads its pumps' FMUs on threads at once).
_LOADING = threading.Lock()


class FmuInstance:
    """The FMU of ``info`` unpacked, loaded and instantiated as ``name``; :meth:`close`
    frees it and removes its files (:class:`FmuError` in one line if its binary does not
    load or instantiate, with the FMU's own message)."""

    def __init__(self, info: FmuInfo, name: str = 'simulator'):
        import fmpy
        self.info = info
        self.messages: list[str] = []
        self._logged_n = 0             # messages logged in all (self.messages keeps the last)
        self.time = 0.0                # the FMU's own clock, from its last initialisation
        self._fmu, self._instantiated, self._started = None, False, False
        self._solver = None            # a model-exchange FMU's integrator, once initialised
        #: The FMI version's prefix of the calls named in errors.
        self.fmi = 'fmi3' if info.fmi_version.startswith('3') else 'fmi2'
        self._where = fmpy.extract(str(info.path))
        md = info.description
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        try:
            # FMPy loads the library from its folder and does not come back when loading
            # fails: the process's folder is put back here whatever happens.
            with _LOADING:
                cwd = os.getcwd()
                try:
                    self._fmu = (self._load3 if self.fmi == 'fmi3' else self._load2)(name)
                finally:
                    os.chdir(cwd)
            self._instantiated = True
        except HydropumpError:
            self.close()
            raise
        except Exception as exc:   # FMPy's own: a binary that does not load or instantiate
            self.close()
            said = '; '.join(m for m in self.messages if m) or str(exc)
            raise FmuError([f'{info.path}: cannot load or instantiate it: {said}']) from None

    def _load2(self, name: str):
        import fmpy
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
            FMU2Model,
            FMU2Slave,
        )
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(self._logged)
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(fmpy.calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(fmpy.free)
        try:
            from ctypes import byref

            from fmpy.logging import addLoggerProxy
            addLoggerProxy(byref(callbacks))
        except Exception:   # messages then arrive unformatted: still worth keeping
            pass
        self._callbacks = callbacks
        kind = FMU2Model if self.info.model_exchange else FMU2Slave
        fmu = kind(guid=self.info.description.guid, unzipDirectory=self._where,
                   modelIdentifier=self.info.model_identifier, instanceName=name)
        self._fmu = fmu          # freed by close() if instantiating fails
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        return fmu

    def _load3(self, name: str):
        from fmpy.fmi3 import FMU3Model, FMU3Slave
        kind = FMU3Model if self.info.model_exchange else FMU3Slave
        fmu = kind(guid=self.info.description.guid, unzipDirectory=self._where,
                   modelIdentifier=self.info.model_identifier, instanceName=name)
        self._fmu = fmu
        # FMI 3.0's logger has no instance name and formats its message itself.
        fmu.instantiate(loggingOn=True,
                        logMessage=lambda env, status, category, message:
                        self._logged(env, None, status, category, message))
        return fmu

    def _logged(self, env, instance, status, category, message):
        text = message.decode(errors='replace') if isinstance(message, bytes) else str(message)
        self.messages = (self.messages + [text])[-20:]
        self._logged_n += 1

    def said_since(self, n: int, otherwise: str) -> str:
        """The FMU's messages logged after it had logged ``n`` (what it said during a
        call), else ``otherwise``."""
        new = self.messages[-min(self._logged_n - n, len(self.messages)):] \
            if self._logged_n > n else []
        return '; '.join(m for m in new if m) or otherwise

    def _live(self):
        if self._fmu is None:
            raise IntegrationError('the FMU is closed')
        return self._fmu

    def call(self, what: str, fn, *args, at: float | None = None, **kwargs):
        """``fn(*args, **kwargs)`` of the FMU; :class:`IntegrationError` with the FMU's own
        messages during the call, else the error's (and the simulation time ``at``, default
        its own) if it fails."""
        n = self._logged_n
        try:
            return fn(*args, **kwargs)
        except Exception as exc:
            said = self.said_since(n, str(exc))
            t = self.time if at is None else at
            raise IntegrationError(f'the FMU failed in {what} at t = {t:.6g} s of '
                                   f'simulation time: {said}') from None

    def refs(self, names: Sequence[str]) -> list[int]:
        return [self.vr[n] for n in names]

    def initialise(self, parameters: Mapping[str, float], inputs: Sequence[int],
                   values: Sequence[float], at: float | None = None) -> None:
        """Back to the FMU's start (``fmi2Reset`` once it has run), ``parameters`` by name
        set, then initialised at the inputs of references ``inputs``."""
        f, v = self._live(), self.fmi
        if self._started:
            self.call(f'{v}Reset', f.reset, at=at)
        if parameters:
            self.set(self.refs(list(parameters)), [float(x) for x in parameters.values()],
                     at=at)
        if v == 'fmi2':
            self.call('fmi2SetupExperiment', f.setupExperiment, startTime=0.0, at=at)
            self.call('fmi2EnterInitializationMode', f.enterInitializationMode, at=at)
        else:   # FMI 3.0 takes the start with the initialisation; no stop time: runs are open
            self.call('fmi3EnterInitializationMode', f.enterInitializationMode,
                      startTime=0.0, at=at)
        self.set(inputs, values, at=at)
        self.call(f'{v}ExitInitializationMode', f.exitInitializationMode, at=at)
        self._started = True
        self.time = 0.0
        if self.info.model_exchange:
            if self._solver is None:        # one integrator for the instance's life
                self._solver = _Integrator(self, at)
            else:
                self._solver.restart(at)

    def set(self, refs: Sequence[int], values: Sequence[float], at: float | None = None
            ) -> None:
        if len(refs):
            f = self._live()
            if self.fmi == 'fmi2':
                self.call('fmi2SetReal', f.setReal, list(refs), list(values), at=at)
            else:
                self.call('fmi3SetFloat64', f.setFloat64, list(refs), list(values), at=at)

    def get(self, refs: Sequence[int], at: float | None = None) -> list[float]:
        if not len(refs):
            return []
        f = self._live()
        if self.fmi == 'fmi2':
            return self.call('fmi2GetReal', f.getReal, list(refs), at=at)
        return self.call('fmi3GetFloat64', f.getFloat64, list(refs), at=at)

    def step(self, dt: float, at: float | None = None) -> None:
        """``fmi2DoStep`` (``fmi3DoStep``) over ``dt`` from the FMU's own clock; a
        model-exchange FMU integrated over it."""
        if self.info.model_exchange:
            if self._solver is None or not self._started:
                raise IntegrationError('the FMU is not initialised')
            self.time = self._solver.advance(self.time + dt, at)
            return
        n = self._logged_n
        done = self.call(f'{self.fmi}DoStep', self._live().doStep,
                         currentCommunicationPoint=self.time, communicationStepSize=dt, at=at)
        if self.fmi == 'fmi3' and done[1]:     # terminateSimulation: the FMU asks to end
            t = self.time if at is None else at
            said = self.said_since(n, 'no message')
            raise IntegrationError(f'the FMU ended the simulation in fmi3DoStep at '
                                   f't = {t:.6g} s of simulation time: {said}')
        self.time += dt

    def close(self) -> None:
        """The FMU ended and its unpacked files removed (again: nothing)."""
        self._solver = None          # CVode's memory, before the library it calls goes
        f, self._fmu = self._fmu, None
        if f is not None:
            try:
                if self._instantiated:
                    if self._started:
                        f.terminate()
                    f.freeInstance()
                else:
                    f.freeLibrary()
            except Exception:    # an FMU that failed may refuse to end: its files still go
                pass
        if self._where:
            shutil.rmtree(self._where, ignore_errors=True)
            self._where = None


class _Integrator:
    """CVode over a model-exchange FMU's continuous states, from its initialisation on (see
    the module): :meth:`advance` to a communication point, events handled on the way; one
    for the instance's life (:meth:`restart` after each initialisation)."""

    def __init__(self, inst: FmuInstance, at: float | None):
        from ctypes import c_double, c_int, c_void_p

        from fmpy.sundials import CVodeSolver
        from fmpy.sundials.cvode import sundials_cvode
        from fmpy.sundials.sundials_context import (
            SUNContext,
            SUNContext_PushErrHandler,
            sundials_core,
        )
        self.inst, f, md = inst, inst._fmu, inst.info.description
        self.v3 = inst.fmi == 'fmi3'
        self.needs_completed = bool(md.modelExchange.needsCompletedIntegratorStep)
        self.input_refs = [inst.vr[n] for n in inst.info.of('input')
                           if inst.info.variables[n].real]
        self._enter(at)

        class Held:               # the inputs are held over a step: nothing to apply
            def apply(self, *args, **kwargs):
                pass

        class Solver(CVodeSolver):
            # FMPy's callbacks let a failing FMU call pass (ctypes prints it, CVode goes on
            # with what the arrays held): here it ends the integration, unrecoverable.
            def f(self, *args):
                try:
                    return super().f(*args)
                except Exception:
                    return -1

            def g(self, *args):
                try:
                    return super().g(*args)
                except Exception:
                    return -1

        self.stop_at = sundials_cvode.CVodeSetStopTime
        self.stop_at.argtypes, self.stop_at.restype = [c_void_p, c_double], c_int
        self.solver = inst.call(
            'CVodeInit', Solver, at=at, nx=md.numberOfContinuousStates,
            nz=md.numberOfEventIndicators, get_x=f.getContinuousStates,
            set_x=f.setContinuousStates,
            get_dx=f.getContinuousStateDerivatives if self.v3 else f.getDerivatives,
            get_z=f.getEventIndicators, get_nominals=f.getNominalsOfContinuousStates,
            set_time=f.setTime, input=Held(), startTime=0.0, relativeTolerance=RTOL,
            maxNumSteps=100_000)
        # SUNDIALS prints its errors to stderr besides FMPy's handler: only FMPy's (which
        # puts them in the error raised) is kept.
        clear = sundials_core.SUNContext_ClearErrHandlers
        clear.argtypes, clear.restype = [SUNContext], c_int
        clear(self.solver.sunctx)
        SUNContext_PushErrHandler(self.solver.sunctx, self.solver.ehfun_, None)

    def _enter(self, at) -> None:
        """From the FMU's event mode after its initialisation into continuous time."""
        inst, f = self.inst, self.inst._fmu
        self.next_event = self._discrete(at)
        inst.call(f'{inst.fmi}EnterContinuousTimeMode', f.enterContinuousTimeMode, at=at)
        self.inputs = self._inputs()

    def restart(self, at: float | None) -> None:
        """After another initialisation of the FMU: CVode from its new states at 0 (its
        memory kept: SUNDIALS' vectors and matrices are not freed by FMPy)."""
        self._enter(at)
        self.solver.reset(0.0)

    def _inputs(self) -> list[float]:
        return self.inst.get(self.input_refs)

    def _discrete(self, at) -> float | None:
        """The FMU's discrete states updated until it needs no more; the time of its next
        time event (None: none). :class:`IntegrationError` if it asks to end."""
        inst, f = self.inst, self.inst._fmu
        update = f.updateDiscreteStates if self.v3 else f.newDiscreteStates
        name = f'{inst.fmi}UpdateDiscreteStates' if self.v3 else 'fmi2NewDiscreteStates'
        for _ in range(1000):
            n = inst._logged_n
            needed, terminate, _, _, defined, when = inst.call(name, update, at=at)
            if terminate:
                t = inst.time if at is None else at
                raise IntegrationError(f'the FMU ended the simulation at t = {t:.6g} s of '
                                       f'simulation time: {inst.said_since(n, "no message")}')
            if not needed:
                return when if defined else None
        raise IntegrationError('the FMU did not settle its discrete states in 1000 '
                               'iterations of an event')

    def _event(self, t: float, at) -> None:
        """An event at ``t``: the FMU's time set there, its discrete states updated, CVode
        restarted from there."""
        inst, f = self.inst, self.inst._fmu
        inst.call(f'{inst.fmi}SetTime', f.setTime, t, at=at)
        inst.call(f'{inst.fmi}EnterEventMode', f.enterEventMode, at=at)
        self.next_event = self._discrete(at)
        inst.call(f'{inst.fmi}EnterContinuousTimeMode', f.enterContinuousTimeMode, at=at)
        self.solver.reset(t)

    def advance(self, t_end: float, at: float | None) -> float:
        """Integrated from the FMU's clock to ``t_end``; a change of its inputs since the
        last communication point is an event at the start. Returns the time reached (a
        time event due at ``t_end`` or a hair before is taken at its own instant)."""
        inst, f = self.inst, self.inst._fmu
        t = inst.time
        inputs = self._inputs()
        if inputs != self.inputs:
            self.inputs = inputs
            self._event(t, at)

        def close(a: float, b: float) -> bool:      # too close for CVode to step between
            return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)
        for _ in range(1_000_000):
            # A time event due now (the clock's sums drift by ulps from where the FMU puts
            # its events): taken at its own instant, so that the FMU sees its time reached.
            if self.next_event is not None and (self.next_event <= t
                                                or close(t, self.next_event)):
                t = max(t, self.next_event)
                self._event(t, at)
                continue
            if close(t, t_end) or t > t_end:
                return t_end if close(t, t_end) else t
            target = t_end
            if self.next_event is not None and t < self.next_event < t_end:
                target = self.next_event
            # CVode stops at the target, never past it: the FMU is not asked for a time
            # beyond the communication point (or the event) it is integrated to.
            self.stop_at(self.solver.cvode_mem, target)
            _, roots, t = inst.call('CVode', self.solver.step, t, target, at=at)
            state_event = bool(roots.any())
            inst.call(f'{inst.fmi}SetTime', f.setTime, t, at=at)
            step_event = False
            if self.needs_completed:
                step_event, terminate = inst.call(
                    f'{inst.fmi}CompletedIntegratorStep', f.completedIntegratorStep, at=at)
                if terminate:
                    raise IntegrationError('the FMU ended the simulation at its completed '
                                           f'integrator step, t = {t:.6g} s')
            if state_event or step_event:
                self._event(t, at)
        raise IntegrationError(f"the FMU's events did not let time advance past t = {t:.6g} s")
