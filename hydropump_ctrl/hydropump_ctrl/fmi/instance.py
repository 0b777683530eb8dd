"""One instance of a user's co-simulation FMU (FMI 2.0 or 3.0), stepped through FMPy: what the
FMU plant (:mod:`.plant`) and the FMU loads of a circuit (:mod:`.loads`) share.

Variables are set and read by name (real ones: FMI 2.0 ``Real``, FMI 3.0 ``Float64``);
parameters are set before each initialisation (both versions set them in the instantiated
state); the FMU's messages are kept, so that a failing call says what the FMU said. Nothing
here imports ROS.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import os
import shutil

from hydropump_sim.errors import HydropumpError
from hydropump_sim.simulate import IntegrationError

from .export import FmuError
from .reading import FmuInfo


class FmuInstance:
    """The FMU of ``info`` unpacked, loaded and instantiated as ``name``; :meth:`close`
    frees it and removes its files (:class:`FmuError` in one line if its binary does not
    load or instantiate, with the FMU's own message)."""

    def __init__(self, info: FmuInfo, name: str = 'simulator'):
        import fmpy
        self.info = info
        self.messages: list[str] = []
        self.time = 0.0                # the FMU's own clock, from its last initialisation
        self._fmu, self._instantiated, self._started = None, False, False
        #: The FMI version's prefix of the calls named in errors.
        self.fmi = 'fmi3' if info.fmi_version.startswith('3') else 'fmi2'
        self._where = fmpy.extract(str(info.path))
        md = info.description
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        try:
            # FMPy loads the library from its folder and does not come back when loading
            # fails: the process's folder is put back here whatever happens.
            cwd = os.getcwd()
            try:
                self._fmu = (self._slave3 if self.fmi == 'fmi3' else self._slave2)(name)
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

    def _slave2(self, name: str):
        import fmpy
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
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
        fmu = FMU2Slave(guid=self.info.description.guid, unzipDirectory=self._where,
                        modelIdentifier=self.info.model_identifier, instanceName=name)
        self._fmu = fmu          # freed by close() if instantiating fails
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
        return fmu

    def _slave3(self, name: str):
        from fmpy.fmi3 import FMU3Slave
        fmu = FMU3Slave(guid=self.info.description.guid, unzipDirectory=self._where,
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

    def _live(self):
        if self._fmu is None:
            raise IntegrationError('the FMU is closed')
        return self._fmu

    def call(self, what: str, fn, *args, at: float | None = None, **kwargs):
        """``fn(*args, **kwargs)`` of the FMU; :class:`IntegrationError` with the FMU's own
        messages (and the simulation time ``at``, default its own) if it fails."""
        try:
            return fn(*args, **kwargs)
        except Exception as exc:
            said = '; '.join(m for m in self.messages if m) or str(exc)
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
        """``fmi2DoStep`` (``fmi3DoStep``) over ``dt`` from the FMU's own clock."""
        done = self.call(f'{self.fmi}DoStep', self._live().doStep,
                         currentCommunicationPoint=self.time, communicationStepSize=dt, at=at)
        if self.fmi == 'fmi3' and done[1]:     # terminateSimulation: the FMU asks to end
            t = self.time if at is None else at
            said = '; '.join(m for m in self.messages if m) or 'no message'
            raise IntegrationError(f'the FMU ended the simulation in fmi3DoStep at '
                                   f't = {t:.6g} s of simulation time: {said}')
        self.time += dt

    def close(self) -> None:
        """The FMU ended and its unpacked files removed (again: nothing)."""
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
