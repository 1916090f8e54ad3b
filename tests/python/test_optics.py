"""The optics FMU: rms surface against an independent least-squares computation from the
packaged layout (resources/layout.json), PSSN properties, sampling at the FMU's own instants,
and parameter checks."""
import json
import zipfile

import numpy as np
import pytest
from fmpy import simulate_fmu

from conftest import fmu_path, start_values

OUT = ["rms_surface", "focus_mode", "rms_surface_without_focus", "pssn"]


def layout(path):
    with zipfile.ZipFile(path) as z:
        return json.loads(z.read("resources/layout.json"))


def expected_rms(lay, ptt):
    """Area-weighted rms over the regular hexagons of the state ptt[i] = (p, tx, ty) after the
    least-squares global plane: a weighted linear least-squares problem written from the
    hexagon moments (area A, second moment I per axis), solved with numpy."""
    a = lay["circumradius"]
    area = 1.5 * np.sqrt(3) * a * a
    moment = 5 * np.sqrt(3) / 16 * a**4
    c = np.array([[s["x"], s["y"]] for s in lay["segments"]])
    n = len(c)
    # Every segment contributes 3 weighted "observations": piston (weight A), x and y slopes
    # (weight I); the global plane P + Tx x + Ty y has piston P + Tx cx + Ty cy, slopes Tx, Ty.
    rows = np.zeros((3 * n, 3))
    rows[0::3] = np.column_stack([np.ones(n), c[:, 0], c[:, 1]])
    rows[1::3, 1] = 1.0
    rows[2::3, 2] = 1.0
    w = np.sqrt(np.tile([area, moment, moment], n))
    y = np.asarray(ptt, dtype=float).reshape(-1)
    beta, *_ = np.linalg.lstsq(rows * w[:, None], y * w, rcond=None)
    r = (y - rows @ beta) * w
    return float(np.sqrt(r @ r / (n * area)))


def run(path, start=None, stop=0.3, h=1e-3, inp=None):
    return simulate_fmu(str(path), stop_time=stop, output_interval=h, start_values=start or {},
                        input=inp, output=OUT)


@pytest.mark.parametrize("lay", ["keck", "tmt"])
def test_zero_input_is_perfect(lay):
    r = run(fmu_path(lay, "optics"), stop=0.25)
    assert np.all(r["rms_surface"] == 0.0)
    assert np.all(r["rms_surface_without_focus"] == 0.0)
    assert np.all(r["focus_mode"] == 0.0)
    assert np.all(np.abs(r["pssn"] - 1.0) < 1e-12)


@pytest.mark.parametrize("lay", ["keck", "tmt"])
def test_segment_piston_rms_and_quadratic_pssn(lay):
    path = fmu_path(lay, "optics")
    geo = layout(path)
    n = len(geo["segments"])
    seg = n // 3
    deficits = []
    for p in (10e-9, 20e-9):
        start = {f"z[{3 * seg + k + 1}]": p for k in range(3)}
        r = run(path, start, stop=0.1, h=0.05)
        ptt = np.zeros((n, 3))
        ptt[seg, 0] = p
        want = expected_rms(geo, ptt)
        got = r["rms_surface"][-1]
        assert abs(got / want - 1) < 1e-9, (got, want)
        # About p sqrt(N - 1) / N: the global piston removed, the global tip/tilt a little less.
        assert 0.9 < got / (p * np.sqrt(n - 1) / n) < 1.0
        assert r["pssn"][-1] < 1.0
        deficits.append(1.0 - r["pssn"][-1])
    ratio = deficits[1] / deficits[0]
    assert 3.8 < ratio < 4.05, f"1 - PSSN not quadratic: ratio {ratio:.3f} for twice the piston"


def test_disabled_pssn_reads_zero_and_metrics_still_sampled():
    path = fmu_path("keck", "optics")
    r = run(path, {"pssn_rate": 0.0, "z[1]": 5e-9}, stop=0.05)
    assert np.all(r["pssn"] == 0.0)
    assert np.all(r["rms_surface"] > 0.0)


@pytest.mark.parametrize("h", [1e-3, 3e-3, 0.0125])
def test_outputs_change_only_at_the_fmu_instants(h):
    """Input ramp on one actuator; metrics at 100 Hz, PSSN at 10 Hz. Every output at a
    communication point T is the metric of the input held over the step that contains the last
    instant t_k <= T (zero-order hold: z at the communication point before t_k), whatever h."""
    path = fmu_path("keck", "optics")
    stop, slope = 0.3, 1e-7  # m/s: 30 nm at the end
    rate_m, rate_p = 100.0, 10.0
    inp = np.array([(0.0, 0.0), (stop, slope * stop)], dtype=[("time", float), ("z[2]", float)])
    r = run(path, {"metrics_rate": rate_m, "pssn_rate": rate_p}, stop=stop, h=h, inp=inp)
    t = r["time"]
    # rms is proportional to |z[2]|: its value per metre of the single actuator.
    unit = r["rms_surface"][-1] / (slope * held_time(t, len(t) - 1, rate_m))
    for rate, name in [(rate_m, "rms_surface"), (rate_p, "pssn")]:
        y = r[name]
        changes = t[1:][np.diff(y) != 0]
        for tc in changes:
            # The first communication point at or after an instant.
            k = np.floor(tc * rate + 1e-9)
            assert tc - k / rate < h - 1e-12, f"{name} changed at {tc} (h {h})"
        # A change at every instant (the ramp moves), at most one per step.
        assert len(changes) >= min(int(stop * rate), len(t) - 1) - 1, (name, changes)
    for i in range(len(t)):
        want = unit * slope * held_time(t, i, rate_m)
        assert abs(r["rms_surface"][i] - want) <= 1e-9 * unit * slope * stop, (t[i], h)


def held_time(t, i, rate):
    """Time of the input value that the output at t[i] holds: the communication point that
    starts the step containing the last instant k / rate <= t[i] (the start time for k = 0)."""
    k = np.floor(t[i] * rate + 1e-9)
    if k == 0:
        return 0.0
    tk = k / rate
    return float(t[t < tk - 1e-12].max())


@pytest.mark.parametrize("name,value", [
    ("pssn_rate", -1.0),
    ("metrics_rate", 0.0),
    ("r0", 0.0),
    ("wavelength", 1.0),
    ("pssn_samples", 4),
    ("L0", -30.0),
])
def test_bad_parameters_are_rejected(name, value):
    path = fmu_path("keck", "optics")
    messages = []

    def logger(env, instance, status, category, message):
        messages.append(message.decode() if isinstance(message, bytes) else str(message))

    with pytest.raises(Exception):
        simulate_fmu(str(path), stop_time=0.01, start_values={name: value}, logger=logger)
    assert any(name in m for m in messages), messages


def test_bad_combination_is_rejected_at_initialisation():
    path = fmu_path("keck", "optics")
    a = layout(path)["circumradius"]
    messages = []

    def logger(env, instance, status, category, message):
        messages.append(message.decode() if isinstance(message, bytes) else str(message))

    with pytest.raises(Exception):
        simulate_fmu(str(path), stop_time=0.01, start_values={"actuator_radius": 1.5 * a},
                     logger=logger)
    assert any("actuator_radius" in m for m in messages), messages


def test_start_values_are_documented_defaults():
    v = start_values(fmu_path("tmt", "optics"))
    assert v["pssn_rate"] == 10.0 and v["metrics_rate"] == 1000.0
    assert v["wavelength"] == 500e-9 and v["r0"] == 0.2 and v["L0"] == 30.0
    assert v["pssn_samples"] == 256
    assert abs(v["actuator_radius"] - 0.36) < 1e-12


def test_fmu_state_and_serialisation_reproduce_the_outputs():
    """The precomputed evaluators are not serialised: a deserialised state rebuilds them."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    path = fmu_path("keck", "optics")
    md = read_model_description(str(path))
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                  modelIdentifier="optics", instanceName="s")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.setReal([vr["pssn_rate"], vr["metrics_rate"]], [50.0, 200.0])
    s.exitInitializationMode()
    outs = [vr[n] for n in OUT]
    h = 1e-3

    def run_from(k0, n):
        y = []
        for k in range(k0, k0 + n):
            s.setReal([vr["z[4]"], vr["z[8]"]], [1e-9 * k, -2e-9 * np.sin(k)])
            s.doStep(currentCommunicationPoint=k * h, communicationStepSize=h)
            y.append(s.getReal(outs))
        return np.array(y)

    run_from(0, 13)
    state = s.getFMUState()
    first = run_from(13, 40)
    assert len(np.unique(first[:, 3])) > 1  # PSSN was sampled in the window
    s.setFMUState(state)
    assert np.array_equal(run_from(13, 40), first)
    restored = s.deserializeFMUState(s.serializeFMUState(state))
    s.setFMUState(restored)
    assert np.array_equal(run_from(13, 40), first)
    s.freeFMUState(state)
    s.freeFMUState(restored)
    s.terminate()
    s.freeInstance()


@pytest.mark.parametrize("lay", ["keck", "tmt"])
def test_focus_mode_is_a_surface_figure(lay):
    """focus_mode is the rms surface of the focus-mode component (rms^2 = rms without
    focus-mode^2 + focus_mode^2), signed as its actuator-space coefficient, which is reported
    as focus_mode_coefficient = focus_mode / focus_rms_per_unit."""
    path = fmu_path(lay, "optics")
    n = len(layout(path)["segments"])
    rng = np.random.default_rng(14)
    z = rng.normal(0.0, 20e-9, 3 * n)
    start = {f"z[{k + 1}]": float(v) for k, v in enumerate(z)}
    start["pssn_rate"] = 0.0
    r = simulate_fmu(str(path), stop_time=0.002, output_interval=1e-3, start_values=start,
                     output=OUT + ["focus_mode_coefficient", "focus_rms_per_unit"])
    rms, wo, fm = r["rms_surface"][-1], r["rms_surface_without_focus"][-1], r["focus_mode"][-1]
    coef, unit = r["focus_mode_coefficient"][-1], r["focus_rms_per_unit"][-1]
    assert fm != 0.0
    assert abs(rms**2 - wo**2 - fm**2) <= 1e-10 * rms**2
    assert abs(fm - coef * unit) <= 1e-12 * abs(fm)
    # The coefficient is an actuator-space amplitude: much larger than the surface it makes.
    assert unit < 0.5, unit
