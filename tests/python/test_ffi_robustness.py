"""Calls in the wrong order, NULL pointers, bad values and unknown references through the raw C
API (ctypes): every call answers with an error status and a logged message, and the Python
process survives."""
import ctypes as C
import math

import pytest
from fmpy import extract, read_model_description

from conftest import fmu_path

OK, WARNING, DISCARD, ERROR, FATAL = range(5)


class Callbacks(C.Structure):
    # The logger is variadic in C; with the "%s" format the FMU passes the message as the one
    # variadic argument, which the x86-64 calling convention delivers like a fixed argument.
    LOGGER = C.CFUNCTYPE(None, C.c_void_p, C.c_char_p, C.c_int, C.c_char_p, C.c_char_p, C.c_char_p)
    _fields_ = [
        ("logger", LOGGER),
        ("allocateMemory", C.c_void_p),
        ("freeMemory", C.c_void_p),
        ("stepFinished", C.c_void_p),
        ("componentEnvironment", C.c_void_p),
    ]


class Fmu:
    def __init__(self, path):
        self.md = read_model_description(str(path))
        self.dir = extract(str(path))
        self.lib = C.CDLL(f"{self.dir}/binaries/linux64/{self.md.coSimulation.modelIdentifier}.so")
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.messages = []

        def log(env, name, status, category, fmt, msg):
            assert category, "the log category is never NULL"
            self.messages.append((status, category.decode(), (msg or b"").decode()))

        self._log = Callbacks.LOGGER(log)
        self.callbacks = Callbacks(self._log, None, None, None, None)
        L = self.lib
        L.fmi2Instantiate.restype = C.c_void_p
        L.fmi2Instantiate.argtypes = [C.c_char_p, C.c_int, C.c_char_p, C.c_char_p, C.c_void_p, C.c_int, C.c_int]
        for f in ["fmi2EnterInitializationMode", "fmi2ExitInitializationMode", "fmi2Terminate", "fmi2Reset"]:
            getattr(L, f).argtypes = [C.c_void_p]
        L.fmi2FreeInstance.argtypes = [C.c_void_p]
        L.fmi2FreeInstance.restype = None
        L.fmi2SetupExperiment.argtypes = [C.c_void_p, C.c_int, C.c_double, C.c_double, C.c_int, C.c_double]
        L.fmi2DoStep.argtypes = [C.c_void_p, C.c_double, C.c_double, C.c_int]
        for t, ct in [("Real", C.c_double), ("Integer", C.c_int), ("Boolean", C.c_int), ("String", C.c_char_p)]:
            getattr(L, f"fmi2Set{t}").argtypes = [C.c_void_p, C.c_void_p, C.c_size_t, C.c_void_p]
            getattr(L, f"fmi2Get{t}").argtypes = [C.c_void_p, C.c_void_p, C.c_size_t, C.c_void_p]
        L.fmi2SetDebugLogging.argtypes = [C.c_void_p, C.c_int, C.c_size_t, C.c_void_p]
        L.fmi2GetFMUstate.argtypes = [C.c_void_p, C.c_void_p]
        L.fmi2SetFMUstate.argtypes = [C.c_void_p, C.c_void_p]
        L.fmi2GetDirectionalDerivative.argtypes = [C.c_void_p] + [C.c_void_p, C.c_size_t] * 2 + [C.c_void_p] * 2
        L.fmi2CancelStep.argtypes = [C.c_void_p]

    def instantiate(self, guid=None, callbacks=True, name=b"inst", fmu_type=1):
        guid = self.md.guid.encode() if guid is None else guid
        cb = C.byref(self.callbacks) if callbacks is True else callbacks
        uri = f"file://{self.dir}/resources".encode()
        return self.lib.fmi2Instantiate(name, fmu_type, guid, uri, cb, 0, 0)

    def set_real(self, c, names, values):
        vrs = (C.c_uint * len(names))(*[self.vr[n] if isinstance(n, str) else n for n in names])
        vals = (C.c_double * len(values))(*values)
        return self.lib.fmi2SetReal(c, vrs, len(names), vals)

    def get_real(self, c, names):
        vrs = (C.c_uint * len(names))(*[self.vr[n] for n in names])
        vals = (C.c_double * len(names))()
        status = self.lib.fmi2GetReal(c, vrs, len(names), vals)
        return status, list(vals)

    def last(self):
        return self.messages[-1][2] if self.messages else ""


@pytest.fixture
def fmu():
    return Fmu(fmu_path("keck", "segments_voicecoil"))


def test_null_instance_pointers_are_refused(fmu):
    L = fmu.lib
    assert L.fmi2DoStep(None, 0.0, 1e-3, 1) == ERROR
    assert L.fmi2EnterInitializationMode(None) == ERROR
    assert L.fmi2SetReal(None, None, 0, None) == ERROR
    L.fmi2FreeInstance(None)  # no crash


def test_instantiate_checks_guid_type_and_name(fmu):
    assert fmu.instantiate(guid=b"{not-the-guid}") is None
    assert "GUID" in fmu.last() and "segments_voicecoil" in fmu.last()
    assert fmu.instantiate(fmu_type=0) is None
    assert "co-simulation" in fmu.last()
    assert fmu.instantiate(name=None) is None
    assert "instanceName" in fmu.last()


def test_null_callbacks_and_null_logger_are_handled(fmu):
    c = fmu.instantiate(callbacks=None)
    assert c
    empty = Callbacks()
    c2 = fmu.lib.fmi2Instantiate(b"x", 1, fmu.md.guid.encode(), None, C.byref(empty), 0, 0)
    assert c2
    # Errors with no logger to report to still return a status.
    assert fmu.lib.fmi2DoStep(c2, 0.0, 1e-3, 1) == ERROR
    fmu.lib.fmi2FreeInstance(c)
    fmu.lib.fmi2FreeInstance(c2)


def test_wrong_call_order_is_an_error(fmu):
    L = fmu.lib
    c = fmu.instantiate()
    assert L.fmi2DoStep(c, 0.0, 1e-3, 1) == ERROR
    assert "illegal call sequence" in fmu.last()
    assert L.fmi2ExitInitializationMode(c) == ERROR
    assert "illegal call sequence" in fmu.last()
    assert fmu.get_real(c, ["z[1]"])[0] == ERROR
    assert L.fmi2Terminate(c) == ERROR
    assert L.fmi2SetupExperiment(c, 0, 0.0, 0.0, 1, 1.0) == OK
    assert L.fmi2EnterInitializationMode(c) == OK
    assert L.fmi2EnterInitializationMode(c) == ERROR
    assert L.fmi2ExitInitializationMode(c) == OK
    assert L.fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0) == ERROR
    # The instance still works after all the refused calls.
    assert L.fmi2DoStep(c, 0.0, 1e-3, 1) == OK
    L.fmi2FreeInstance(c)


@pytest.mark.parametrize(
    "name,value,words",
    [
        ("segment_mass", math.nan, ["segment_mass", "finite"]),
        ("segment_mass", -220.0, ["segment_mass", "> 0"]),
        ("spring_stiffness", -1.0, ["spring_stiffness", ">= 0"]),
        ("servo_rate", 0.0, ["servo_rate", "> 0"]),
        ("u_cmd[4]", math.inf, ["u_cmd[4]", "finite"]),
    ],
)
def test_bad_values_are_refused_and_leave_the_instance_unchanged(fmu, name, value, words):
    L = fmu.lib
    c = fmu.instantiate()
    before = fmu.messages[:]
    # A batch with one bad value is refused as a whole.
    assert fmu.set_real(c, ["actuator_mass", name], [3.0, value]) == ERROR
    assert len(fmu.messages) == len(before) + 1
    for w in words:
        assert w in fmu.last(), fmu.last()
    assert L.fmi2EnterInitializationMode(c) == OK
    status, vals = fmu.get_real(c, ["actuator_mass", "segment_mass"])
    assert status == OK and vals == [2.0, 220.0]
    L.fmi2FreeInstance(c)


def test_unknown_references_outputs_and_structural_parameters(fmu):
    L = fmu.lib
    c = fmu.instantiate()
    assert fmu.set_real(c, [999999], [1.0]) == ERROR
    assert "unknown Real value reference 999999" in fmu.last()
    # A Real reference used as an Integer.
    assert L.fmi2SetInteger(c, (C.c_uint * 1)(fmu.vr["segment_mass"]), 1, (C.c_int * 1)(3)) == ERROR
    assert "Integer" in fmu.last()
    # Sizes and layout are fixed by packaging.
    assert L.fmi2SetInteger(c, (C.c_uint * 1)(fmu.vr["n_segments"]), 1, (C.c_int * 1)(492)) == ERROR
    assert "n_segments" in fmu.last() and "packaged value 36" in fmu.last()
    assert L.fmi2SetString(c, (C.c_uint * 1)(fmu.vr["layout"]), 1, (C.c_char_p * 1)(b"tmt")) == ERROR
    assert "layout" in fmu.last() and "keck" in fmu.last()
    assert fmu.set_real(c, ["z[1]"], [1.0]) == ERROR
    assert "cannot be set" in fmu.last()
    # NULL arrays: fine when empty, an error otherwise.
    assert L.fmi2SetReal(c, None, 0, None) == OK
    assert L.fmi2SetReal(c, None, 2, None) == ERROR
    assert "NULL" in fmu.last()
    assert L.fmi2EnterInitializationMode(c) == OK
    assert L.fmi2GetReal(c, (C.c_uint * 1)(0), 1, None) == ERROR
    assert L.fmi2SetDebugLogging(c, 1, 1, C.byref(C.c_char_p(b"noSuchCategory"))) == ERROR
    assert "noSuchCategory" in fmu.last()
    assert L.fmi2GetFMUstate(c, None) == ERROR
    assert L.fmi2GetDirectionalDerivative(c, None, 0, None, 0, None, None) == ERROR
    assert "not supported" in fmu.last()
    assert L.fmi2ExitInitializationMode(c) == OK
    # Fixed parameters can't change after initialisation.
    assert fmu.set_real(c, ["segment_mass"], [100.0]) == ERROR
    assert "cannot be set in state stepComplete" in fmu.last()
    L.fmi2FreeInstance(c)


def test_do_step_checks_time_and_step(fmu):
    L = fmu.lib
    c = fmu.instantiate()
    for f in ["fmi2EnterInitializationMode", "fmi2ExitInitializationMode"]:
        assert getattr(L, f)(c) == OK
    assert L.fmi2DoStep(c, 0.5, 1e-3, 1) == ERROR
    assert "currentCommunicationPoint" in fmu.last()
    # Steps between servo samples are fine (the servo keeps its own instants).
    assert L.fmi2DoStep(c, 0.0, 1.1e-4, 1) == OK
    assert L.fmi2DoStep(c, 1.1e-4, 0.9e-4, 1) == OK
    assert L.fmi2DoStep(c, 0.0, -1e-3, 1) == ERROR
    assert L.fmi2DoStep(c, 0.0, math.nan, 1) == ERROR
    assert L.fmi2CancelStep(c) == ERROR
    assert L.fmi2DoStep(c, 2e-4, 1e-3, 1) == OK
    assert L.fmi2DoStep(c, 1.2e-3, 1e-3, 1) == OK
    L.fmi2FreeInstance(c)


def test_parameters_that_destabilise_the_servo_are_refused_at_initialisation(fmu):
    L = fmu.lib
    c = fmu.instantiate()
    assert fmu.set_real(c, ["servo_kp"], [1e9]) == OK
    assert L.fmi2EnterInitializationMode(c) == OK
    assert L.fmi2ExitInitializationMode(c) == ERROR
    assert "unstable" in fmu.last()
    # Still in initialisation mode: fix the parameter and carry on.
    assert fmu.set_real(c, ["servo_kp"], [1.5e6]) == OK
    assert L.fmi2ExitInitializationMode(c) == OK
    L.fmi2FreeInstance(c)
