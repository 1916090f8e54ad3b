"""The edge_sensors FMU driven by fmpy: single-segment pistons read only on their own edges with
opposite signs across an edge, a global piston reads (almost) nothing, in-plane motion changes
the gap, readings are sampled and held with seeded noise independent of the communication step
and no direct feedthrough, a gap law scales the readings as the gaps open, the temperature
drives the drift, and bad parameters are refused with the variable named."""
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


def test_a_gap_law_scales_the_readings_as_the_gaps_open():
    """height_gain_per_gap = gamma (leff_per_gap 0): with a constant uniform radial slide of
    every segment (w) the gaps open, and each reading is (1 + gamma dg) times that of the same
    sensors without the law, dg = gap - g0 the gap change at the sensor; the gap readings are
    those without the law."""
    path = fmu_path("keck", "edge_sensors")
    gamma = -210.0

    def run(**params):
        s = Slave(path)
        s.set(**params)
        s.start()
        g0 = s.get("gap")  # the initial sample reads z = w = 0: the nominal gap
        na = s.size("z")
        z = P * np.sin(1.7 * np.arange(na))
        w = np.zeros(na)
        w[0::3] = 2e-5  # every segment slides 20 um radially outward
        y = read(s, z=z, w=w)
        gap = s.get("gap")
        s.close()
        return g0, y, gap

    g0, y0, gap0 = run()
    _, y, gap = run(height_gain_per_gap=gamma)
    assert np.array_equal(gap, gap0)
    dg = gap - g0
    # Every gap opens or stays (the pistons couple into the gap on the curved mirror at the
    # 1e-2 level only).
    assert np.all(dg > -0.01 * np.max(dg)) and np.mean(dg) > 1e-6, "the gaps open"
    scale = np.max(np.abs(y0))
    assert scale > 0.5 * P
    assert np.allclose(y, (1 + gamma * dg) * y0, rtol=0, atol=1e-12 * scale)
    # The law is visible: readings shrink by 1e-3 and more where the gaps open most.
    opened = dg > 0.5 * np.max(dg)
    ratio = y[opened] / y0[opened]
    assert np.all(ratio < 1 - 1e-3), ratio
    # Off by default: an explicit 0 is the default.
    _, y_off, _ = run(height_gain_per_gap=0.0, leff_per_gap=0.0)
    assert np.array_equal(y_off, y0)


def test_the_temperature_drives_the_drift():
    """drift_per_degc = c: each reading moves by c_n T with |c_n| <= c; the gap does not."""
    path = fmu_path("keck", "edge_sensors")
    out = {}
    for t in (0.0, 3.0):
        s = Slave(path)
        s.set(drift_per_degc=1e-9)
        s.start()
        s.set(temperature=t)
        s.step(1e-3)
        out[t] = (s.get("y"), s.get("gap"))
        s.close()
    assert np.all(out[0.0][0] == 0.0)
    dy = out[3.0][0] - out[0.0][0]
    assert np.all(np.abs(dy) <= 3e-9 * (1 + 1e-12)) and np.max(np.abs(dy)) > 2e-9
    assert np.array_equal(out[3.0][1], out[0.0][1])


@pytest.mark.parametrize("name,value", [
    ("noise_rms", -1e-9),
    ("gain_error_rms", -0.01),
    ("install_tilt_rms", -1e-3),
    ("install_segment_position_rms", -1e-4),
    ("install_sensor_gap_rms", -1e-5),
    ("drift_per_week", -1e-9),
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
