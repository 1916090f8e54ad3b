"""The edge_sensors FMU driven by fmpy: single-segment pistons read only on their own edges with
opposite signs across an edge, a global piston reads (almost) nothing, in-plane motion changes
the gap, readings are sampled and held with seeded noise independent of the communication step
and no direct feedthrough, and bad parameters are refused with the variable named."""
import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException

from conftest import fmu_path
from slave import Slave

P = 1e-6  # piston amplitude (m)


@pytest.fixture
def keck():
    s = Slave(fmu_path("keck", "edge_sensors"))
    s.start()
    yield s
    s.close()


def read(s, **inputs):
    """Sets the inputs and reads the sample taken at the end of the next 1 ms step (default
    sample rate 1 kHz; the inputs are held over the step)."""
    s.set(**inputs)
    s.step(1e-3)
    return s.get("y")


def pistons(s):
    """Readings of a piston P on each segment."""
    na = s.size("z")
    out = []
    for seg in range(na // 3):
        z = np.zeros(na)
        z[3 * seg:3 * seg + 3] = P
        out.append(read(s, z=z))
    return np.array(out)


def test_outputs_do_not_feed_the_inputs_through():
    md = read_model_description(str(fmu_path("tmt", "edge_sensors")))
    assert len(md.outputs) == 2 * 2772
    for o in md.outputs:
        assert o.dependencies == [], o.variable.name
        assert o.variable.variability == "discrete"
    s = Slave(fmu_path("keck", "edge_sensors"))
    s.start()
    s.set(z=np.full(s.size("z"), 1e-6), w=np.full(s.size("w"), 1e-6))
    assert np.all(s.get("y") == 0.0), "a reading changed without a sample"
    s.close()


def test_a_single_segment_piston_reads_only_on_its_edges_opposite_across_them(keck):
    ns, na = keck.size("y"), keck.size("z")
    assert (ns, na) == (168, 108)
    y = pistons(keck)
    support = np.abs(y) > 1e-3 * P
    # Exactly zero off the segment's edges (a sparse A), close to +-P on them.
    assert np.all(y[~support] == 0.0)
    assert np.all(np.abs(np.abs(y[support]) / P - 1.0) < 0.05)
    # Every sensor sees exactly two segments; every segment has 3..6 neighbours, 2 sensors each.
    assert np.all(support.sum(axis=0) == 2)
    counts = support.sum(axis=1)
    assert np.all((counts >= 6) & (counts <= 12) & (counts % 2 == 0)), counts
    for n in range(ns):
        a, b = np.flatnonzero(support[:, n])
        # Opposite signs across the edge: the two segments' pistons read -+ each other.
        assert y[a, n] * y[b, n] < 0
        assert abs(y[a, n] + y[b, n]) < 1e-3 * P
    # The two sensors of an edge (2 e, 2 e + 1) compare the same segments with the same sign.
    assert np.array_equal(support[:, 0::2], support[:, 1::2])
    assert np.all(np.sign(y[:, 0::2]) == np.sign(y[:, 1::2]))
    # Superposition: all segments pistoned together (global piston) read almost nothing (on the
    # curved mirror each segment moves along its own normal: a 1e-4 residual, not zero).
    y_all = read(keck, z=np.full(na, P))
    assert np.max(np.abs(y_all)) < 1e-3 * P
    assert np.allclose(y_all, y.sum(axis=0), rtol=0, atol=1e-12 * P)


def test_in_plane_motion_changes_the_gap_of_the_segment_edges(keck):
    ns, na = keck.size("y"), keck.size("z")
    g0 = keck.get("gap")
    assert np.all(g0 == g0[0]) and 1e-3 < g0[0] < 1e-2, g0[0]
    assert np.all(keck.get("y") == 0.0)
    w = np.zeros(na)
    w[3 * 10] = 1e-5  # radial slide of segment 11
    y = read(keck, w=w)
    dg = keck.get("gap") - g0
    moved = np.abs(dg) > 1e-3 * 1e-5
    assert 6 <= moved.sum() <= 12
    assert np.all(dg[~moved] == 0.0)
    assert np.max(np.abs(dg)) < 1.5e-5
    # A radial slide along the sphere leaves the heights almost unchanged.
    assert np.max(np.abs(y)) < 0.1 * 1e-5


def test_readings_are_sampled_and_held_with_seeded_noise():
    path = str(fmu_path("keck", "edge_sensors"))
    params = {"noise_rms": 5e-9, "sample_rate": 100.0, "seed": 3}
    out = ["y[1]", "y[2]", "y[100]"]

    def run(h, **extra):
        return simulate_fmu(path, stop_time=0.2, step_size=h, output_interval=h,
                            start_values={**params, **extra}, output=out)

    r = run(1e-3)
    t, y = r["time"], r["y[1]"]
    changes = t[1:][np.diff(y) != 0.0]
    expected = np.arange(1, 21) * 0.01
    assert np.allclose(changes, expected, atol=1e-9), changes
    # Noise independent of the communication step (drawn per sample, seeded per sample).
    r5 = run(5e-3)
    for name in out:
        a = r[name][::10]
        b = r5[name][::2]
        assert np.array_equal(a, b), name
    # Reproducible, and another seed differs.
    assert np.array_equal(run(1e-3)["y[100]"], r["y[100]"])
    assert not np.array_equal(run(1e-3, seed=4)["y[100]"], r["y[100]"])


def test_noise_rms_over_sensors_and_samples():
    s = Slave(fmu_path("keck", "edge_sensors"))
    s.set(noise_rms=5e-9, gap_noise_rms=1e-8, sample_rate=1000.0)
    s.start()
    ys, gs = [], []
    for _ in range(60):
        s.step(1e-3)
        ys.append(s.get("y"))
        gs.append(s.get("gap"))
    s.close()
    ys, gs = np.array(ys), np.array(gs)
    assert abs(np.std(ys) / 5e-9 - 1) < 0.05  # 10080 draws: 4 sigma is 2.8 %
    assert abs(np.std(gs) / 1e-8 - 1) < 0.05
    assert abs(np.mean(ys)) < 4 * 5e-9 / np.sqrt(ys.size)


def test_installation_errors_are_reported():
    path = fmu_path("keck", "edge_sensors")
    s = Slave(path)
    s.set(install_position_rms=1e-3, install_tilt_rms=1e-3, seed=5)
    s.start()
    change = s.get("install_a_change")
    s.close()
    assert 1e-4 < change < 1e-2, change
    ideal = Slave(path)
    ideal.start()
    assert ideal.get("install_a_change") == 0.0
    ideal.close()


@pytest.mark.parametrize("name,value", [
    ("noise_rms", -1e-9),
    ("gain_error_rms", -0.01),
    ("install_tilt_rms", -1e-3),
    ("sample_rate", 0.0),
    ("leff", -0.1),
    ("seed", -1),
])
def test_bad_parameters_are_refused_naming_the_variable(name, value):
    s = Slave(fmu_path("keck", "edge_sensors"))
    with pytest.raises(FMICallException):
        s.set(**{name: value})
    assert name in s.log_text(), s.log_text()
    s.close()
