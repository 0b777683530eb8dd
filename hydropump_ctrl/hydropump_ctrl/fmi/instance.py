"""One instance of a user's FMI 2.0 co-simulation FMU, stepped through FMPy: what the FMU
plant (:mod:`.plant`) and the FMU loads of a circuit (:mod:`.loads`) share.

Variables are set and read by name (Real ones: FMI 2.0 counts value references per type);
parameters are set before each initialisation (FMI 2.0 sets them in the instantiated state);
the FMU's messages are kept, so that a failing call says what the FMU said. Nothing here
imports ROS.
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
        from fmpy.fmi2 import (
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
            FMU2Slave,
        )
        self.info = info
        self.messages: list[str] = []
        self.time = 0.0                # the FMU's own clock, from its last initialisation
        self._fmu, self._instantiated, self._started = None, False, False
        self._where = fmpy.extract(str(info.path))
        md = info.description
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        try:
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
            # FMPy loads the library from its folder and does not come back when loading
            # fails: the process's folder is put back here whatever happens.
            cwd = os.getcwd()
            try:
                self._fmu = FMU2Slave(guid=md.guid, unzipDirectory=self._where,
                                      modelIdentifier=info.model_identifier,
                                      instanceName=name)
            finally:
                os.chdir(cwd)
            self._fmu.instantiate(callbacks=callbacks, loggingOn=True)
            self._instantiated = True
        except HydropumpError:
            self.close()
            raise
        except Exception as exc:   # FMPy's own: a binary that does not load or instantiate
            self.close()
            said = '; '.join(m for m in self.messages if m) or str(exc)
            raise FmuError([f'{info.path}: cannot load or instantiate it: {said}']) from None

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
        f = self._live()
        if self._started:
            self.call('fmi2Reset', f.reset, at=at)
        if parameters:
            self.call('fmi2SetReal', f.setReal, self.refs(list(parameters)),
                      [float(v) for v in parameters.values()], at=at)
        self.call('fmi2SetupExperiment', f.setupExperiment, startTime=0.0, at=at)
        self.call('fmi2EnterInitializationMode', f.enterInitializationMode, at=at)
        if inputs:
            self.call('fmi2SetReal', f.setReal, list(inputs), list(values), at=at)
        self.call('fmi2ExitInitializationMode', f.exitInitializationMode, at=at)
        self._started = True
        self.time = 0.0

    def set(self, refs: Sequence[int], values: Sequence[float], at: float | None = None
            ) -> None:
        if refs:
            self.call('fmi2SetReal', self._live().setReal, list(refs), list(values), at=at)

    def get(self, refs: Sequence[int], at: float | None = None) -> list[float]:
        return self.call('fmi2GetReal', self._live().getReal, list(refs), at=at) \
            if refs else []

    def step(self, dt: float, at: float | None = None) -> None:
        """``fmi2DoStep`` over ``dt`` from the FMU's own clock."""
        self.call('fmi2DoStep', self._live().doStep, currentCommunicationPoint=self.time,
                  communicationStepSize=dt, at=at)
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
