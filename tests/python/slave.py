"""A thin driver of one FMI 2.0 co-simulation instance over fmpy's FMU2Slave: array variables by
base name, and the FMU's log messages captured (the FMU logs with the format "%s" and the
message as the variadic argument, which a six-argument ctypes callback receives)."""
import ctypes as C

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave, defaultCallbacks, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE

LOGGER = C.CFUNCTYPE(None, C.c_void_p, C.c_char_p, C.c_int, C.c_char_p, C.c_char_p, C.c_char_p)


class Slave:
    def __init__(self, path, start_time=0.0, name="inst"):
        self.md = read_model_description(str(path))
        self.dir = extract(str(path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.messages = []

        def log(env, instance, status, category, fmt, msg):
            self.messages.append((status, (msg or b"").decode(errors="replace")))

        self._log = LOGGER(log)
        cb = fmi2CallbackFunctions()
        cb.logger = C.cast(self._log, fmi2CallbackLoggerTYPE)
        cb.allocateMemory = defaultCallbacks.allocateMemory
        cb.freeMemory = defaultCallbacks.freeMemory
        self._cb = cb
        self.fmu = FMU2Slave(
            guid=self.md.guid,
            unzipDirectory=self.dir,
            modelIdentifier=self.md.coSimulation.modelIdentifier,
            instanceName=name,
        )
        self.fmu.instantiate(callbacks=cb)
        self.fmu.setupExperiment(startTime=start_time)
        self.fmu.enterInitializationMode()
        self.t = start_time
        self.started = False

    def log_text(self):
        return "\n".join(m for _, m in self.messages)

    def _array(self, name):
        first = self.vars.get(f"{name}[1]")
        if first is None:
            return None
        n = 0
        while f"{name}[{n + 1}]" in self.vars:
            n += 1
        return [first.valueReference + i for i in range(n)]

    def size(self, name):
        return len(self._array(name))

    def set(self, **values):
        """Scalars by name, arrays (numpy or lists) by base name."""
        for name, x in values.items():
            vrs = self._array(name)
            if vrs is not None:
                self.fmu.setReal(vrs, [float(v) for v in np.asarray(x, dtype=float)])
                continue
            v = self.vars[name]
            if v.type == "Real":
                self.fmu.setReal([v.valueReference], [float(x)])
            elif v.type == "Integer":
                self.fmu.setInteger([v.valueReference], [int(x)])
            elif v.type == "Boolean":
                self.fmu.setBoolean([v.valueReference], [bool(x)])
            else:
                raise KeyError(name)

    def get(self, name):
        vrs = self._array(name)
        if vrs is not None:
            return np.array(self.fmu.getReal(vrs))
        v = self.vars[name]
        if v.type == "Real":
            return self.fmu.getReal([v.valueReference])[0]
        if v.type == "Integer":
            return self.fmu.getInteger([v.valueReference])[0]
        return self.fmu.getBoolean([v.valueReference])[0]

    def start(self):
        self.fmu.exitInitializationMode()
        self.started = True

    def step(self, h):
        self.fmu.doStep(currentCommunicationPoint=self.t, communicationStepSize=h)
        self.t += h

    def close(self):
        try:
            if self.started:
                self.fmu.terminate()
        finally:
            self.fmu.freeInstance()
