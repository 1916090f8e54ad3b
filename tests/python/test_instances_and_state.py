"""Independent instances in one process, and FMU states (get/set, serialise/deserialise)
reproducing a trajectory exactly."""
import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from conftest import fmu_path


def slave(path, name):
    md = read_model_description(str(path))
    d = extract(str(path))
    s = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier=md.coSimulation.modelIdentifier,
                  instanceName=name)
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    return s, vr


def run(s, vr, t0, n, h=1e-3):
    out = []
    for k in range(n):
        s.doStep(currentCommunicationPoint=t0 + k * h, communicationStepSize=h)
        out.append(s.getReal([vr["z[1]"], vr["z[2]"], vr["f_cell[1]"]]))
    return np.array(out)


@pytest.mark.parametrize("name", ["segments_voicecoil", "segments_piezo"])
def test_two_instances_are_independent(name):
    path = fmu_path("keck", name)
    a, vr = slave(path, "a")
    b, _ = slave(path, "b")
    a.setReal([vr["u_cmd[1]"]], [1e-6])
    ya = run(a, vr, 0.0, 30)
    yb = run(b, vr, 0.0, 30)
    assert np.all(yb == 0.0) and np.max(np.abs(ya)) > 1e-7
    b.reset()
    b.setupExperiment(startTime=0.0)
    b.enterInitializationMode()
    b.exitInitializationMode()
    b.setReal([vr["u_cmd[1]"]], [1e-6])
    assert np.array_equal(run(b, vr, 0.0, 30), ya)
    for s in (a, b):
        s.terminate()
        s.freeInstance()


@pytest.mark.parametrize("name", ["segments_voicecoil", "segments_piezo"])
def test_fmu_state_reproduces_the_trajectory(name):
    s, vr = slave(fmu_path("keck", name), "s")
    s.setReal([vr["u_cmd[1]"], vr["f_wind[2]"]], [1e-6, 20.0])
    run(s, vr, 0.0, 10)
    state = s.getFMUState()
    first = run(s, vr, 0.01, 25)
    s.setFMUState(state)
    again = run(s, vr, 0.01, 25)
    assert np.array_equal(first, again)
    blob = s.serializeFMUState(state)
    assert len(blob) > 0
    restored = s.deserializeFMUState(blob)
    s.setFMUState(restored)
    assert np.array_equal(run(s, vr, 0.01, 25), first)
    # A corrupted blob is refused, not trusted.
    with pytest.raises(Exception):
        s.deserializeFMUState(bytes(blob[:20]))
    s.freeFMUState(state)
    s.freeFMUState(restored)
    s.terminate()
    s.freeInstance()
