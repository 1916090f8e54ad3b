"""The global_controller FMU driven by fmpy: the command steps only at the loop's 50 ms instants
whatever the communication step, it does not feed y through, the low-order command u_lo passes
straight to u_cmd without touching the integrator, the loop closed through the edge_sensors FMU
on a perfect plant removes a disturbance, the calculated loop gains follow
g = 1 - exp(-2 pi f / rate), and bad parameters are refused with the variable named."""
import math

import numpy as np
import pytest
from fmpy import read_model_description
from fmpy.fmi1 import FMICallException

from conftest import fmu_path
from slave import Slave


def readings(layout, seg=4, p=1e-6):
    """Edge-sensor readings of a piston p on one segment, from the edge_sensors FMU."""
    s = Slave(fmu_path(layout, "edge_sensors"))
    s.start()
    z = np.zeros(s.size("z"))
    z[3 * seg:3 * seg + 3] = p
    s.set(z=z)
    s.step(1e-3)  # sampled at the end of the step
    y = s.get("y")
    s.close()
    return y


def run(h, t_end, y, **params):
    """Controller alone with constant readings y: u_cmd after every step."""
    c = Slave(fmu_path("keck", "global_controller"))
    c.set(**params)
    c.start()
    c.set(y=y)
    times, us = [0.0], [c.get("u_cmd")]
    n = round(t_end / h)
    for _ in range(n):
        c.step(h)
        times.append(c.t)
        us.append(c.get("u_cmd"))
    c.close()
    return np.array(times), np.array(us)


def test_u_cmd_has_no_direct_dependency_on_y():
    """u_cmd[i] depends directly on u_lo[i] only (the pass-through), never on y."""
    md = read_model_description(str(fmu_path("keck", "global_controller")))
    outputs = md.outputs
    assert outputs and all(o.variable.name.startswith("u_cmd[") for o in outputs)
    for o in outputs:
        i = o.variable.name[len("u_cmd["):-1]
        assert [d.name for d in o.dependencies] == [f"u_lo[{i}]"], o.variable.name
        assert o.variable.variability == "discrete"


def test_u_lo_passes_to_u_cmd_at_once_and_leaves_the_integrator_alone():
    y = readings("keck")
    path = fmu_path("keck", "global_controller")
    with_lo, without = Slave(path, name="with"), Slave(path, name="without")
    for c in (with_lo, without):
        c.start()
        c.set(y=y)
    na = with_lo.size("u_lo")
    lo = 1e-6 * np.cos(0.3 * np.arange(na))
    h = 10e-3
    for _ in range(7):
        with_lo.step(h)
        without.step(h)
    u = without.get("u_cmd")
    assert np.any(u != 0.0)
    assert np.array_equal(with_lo.get("u_cmd"), u)
    # Set between two samples: u_cmd follows at once, before any step.
    with_lo.set(u_lo=lo)
    assert np.array_equal(with_lo.get("u_cmd"), u + lo)
    for _ in range(13):
        with_lo.step(h)
        without.step(h)
        # The integrator goes on as without u_lo (same samples, same command), u_lo on top.
        assert np.array_equal(with_lo.get("u_cmd"), without.get("u_cmd") + lo)
    assert not np.array_equal(without.get("u_cmd"), u), "the integrator moved on"
    with_lo.set(u_lo=np.zeros(na))
    assert np.array_equal(with_lo.get("u_cmd"), without.get("u_cmd"))
    with_lo.close()
    without.close()


def test_command_steps_only_at_the_50_ms_instants():
    y = readings("keck")
    t, u = run(1e-3, 0.3, y)
    changed = np.any(np.diff(u, axis=0) != 0.0, axis=1)
    assert np.allclose(t[1:][changed], [0.05, 0.10, 0.15, 0.20, 0.25, 0.30], atol=1e-9)
    assert np.all(u[0] == 0.0)
    # With y held constant the integrator ramps: equal increments at each sample.
    k = [round(x / 1e-3) for x in (0.05, 0.10, 0.15)]
    d1, d2 = u[k[1]] - u[k[0]], u[k[2]] - u[k[1]]
    assert np.allclose(d1, d2, rtol=1e-12, atol=1e-18)
    assert np.allclose(u[k[0]], d1, rtol=1e-12, atol=1e-18)


def test_samples_at_its_own_instants_whatever_the_communication_step():
    y = readings("keck")
    ta, ua = run(1e-3, 0.3, y)
    tb, ub = run(0.3e-3, 0.3, y)
    tc, uc = run(50e-3, 0.3, y)
    for t_common in (0.15, 0.3):
        ia = np.argmin(abs(ta - t_common))
        ib = np.argmin(abs(tb - t_common))
        ic = np.argmin(abs(tc - t_common))
        assert abs(tb[ib] - t_common) < 1e-9
        assert np.array_equal(ua[ia], ub[ib])
        assert np.array_equal(ua[ia], uc[ic])


def test_disabled_loop_holds_the_command():
    t, u = run(10e-3, 0.2, readings("keck"), enabled=False)
    assert np.all(u == 0.0)


def test_closed_loop_through_the_edge_sensors_removes_a_disturbance():
    """Perfect plant z = u_cmd + d, readings from the edge_sensors FMU, 1 ms Jacobi steps."""
    sensors = Slave(fmu_path("keck", "edge_sensors"))
    ctrl = Slave(fmu_path("keck", "global_controller"))
    na = sensors.size("z")
    d = np.zeros(na)
    d[3 * 7:3 * 7 + 3] = [1e-6, -0.5e-6, 0.2e-6]  # piston and tilt of one segment
    sensors.set(z=d)  # u_cmd starts at 0: the initial sample reads d
    sensors.start()
    ctrl.start()
    y0 = np.sqrt(np.mean(sensors.get("y") ** 2))
    assert y0 > 1e-7
    h = 1e-3
    rms = []
    for _ in range(2000):
        y = sensors.get("y")
        ctrl.set(y=y)
        sensors.step(h)
        ctrl.step(h)
        u = ctrl.get("u_cmd")
        sensors.set(z=u + d)
        rms.append(np.sqrt(np.mean(sensors.get("y") ** 2)))
    sensors.close()
    ctrl.close()
    # 2 s = 40 samples: the 1.5 Hz and 1 Hz modes (radial degrees >= 5 and 3-4) are gone
    # ((1 - 0.27)^40 ~ 3e-6); what is left is the slow focus-mode and astigmatism content,
    # which reads weakly.
    assert rms[-1] < 0.02 * y0, (rms[-1], y0)
    # Monotone decay sample after sample (the loop is a set of first-order integrators).
    at_samples = [rms[k] for k in range(49, 2000, 50)]
    assert all(b <= a * (1 + 1e-9) for a, b in zip(at_samples, at_samples[1:]))


def test_calculated_loop_gains():
    c = Slave(fmu_path("keck", "global_controller"))
    c.set(rate=40.0, bandwidth=2.0, bandwidth_radial34=1.5, bandwidth_radial2=1.0,
          bandwidth_focus=0.5, focus_gain=0.25)
    c.start()
    g = lambda f: 1 - math.exp(-2 * math.pi * f / 40.0)  # noqa: E731
    assert c.get("loop_gain") == pytest.approx(g(2.0), rel=1e-14)
    assert c.get("loop_gain_radial34") == pytest.approx(g(1.5), rel=1e-14)
    assert c.get("loop_gain_radial2") == pytest.approx(g(1.0), rel=1e-14)
    assert c.get("loop_gain_focus") == pytest.approx(0.25 * g(0.5), rel=1e-14)
    c.close()


def test_default_bandwidths_are_the_baseline_tuning():
    """The seed paper's baseline: 1.5 Hz on radial degrees >= 5, 1 Hz on 3-4, 0.75 Hz on 2,
    0.1 Hz on focus-mode, at 20 Hz."""
    md = read_model_description(str(fmu_path("keck", "global_controller")))
    start = {v.name: float(v.start) for v in md.modelVariables
             if v.name in ("rate", "bandwidth", "bandwidth_radial34", "bandwidth_radial2",
                           "bandwidth_focus")}
    assert start == {"rate": 20.0, "bandwidth": 1.5, "bandwidth_radial34": 1.0,
                     "bandwidth_radial2": 0.75, "bandwidth_focus": 0.1}
    c = Slave(fmu_path("keck", "global_controller"))
    c.start()
    g = lambda f: 1 - math.exp(-2 * math.pi * f / 20.0)  # noqa: E731
    for name, f in [("loop_gain", 1.5), ("loop_gain_radial34", 1.0),
                    ("loop_gain_radial2", 0.75), ("loop_gain_focus", 0.1)]:
        assert c.get(name) == pytest.approx(g(f), rel=1e-14), name
    c.close()


@pytest.mark.parametrize("name,value", [
    ("rate", 0.0),
    ("bandwidth", -1.0),
    ("focus_gain", 1.5),
    ("leff", -0.1),
])
def test_bad_parameters_are_refused_naming_the_variable(name, value):
    c = Slave(fmu_path("keck", "global_controller"))
    with pytest.raises(FMICallException):
        c.set(**{name: value})
    assert name in c.log_text(), c.log_text()
    c.close()


@pytest.mark.parametrize("name", ["bandwidth", "bandwidth_radial34", "bandwidth_radial2",
                                  "bandwidth_focus"])
def test_bandwidth_at_or_above_nyquist_is_refused_at_initialisation(name):
    c = Slave(fmu_path("keck", "global_controller"))
    c.set(**{name: 10.0})  # rate 20 Hz: Nyquist 10 Hz
    with pytest.raises(FMICallException):
        c.start()
    assert name in c.log_text(), c.log_text()
    # The instance stays in initialisation mode: a corrected value initialises.
    c.set(**{name: 0.5})
    c.start()
    c.close()


@pytest.mark.parametrize("name,extras", [
    ("global_controller", False),
    ("global_controller", True),
    ("edge_sensors", False),
    ("edge_sensors", True),
])
def test_restored_and_deserialised_states_continue_identically(name, extras):
    """The reconstructor and sensor matrices are not serialised: a deserialised state rebuilds
    them from its parameters and continues exactly; with extras, the controller has a low-order
    command and the sensors the installed-sensor errors (gap law, segment and sensor-gap
    installation, drift at a temperature change)."""
    s = Slave(fmu_path("keck", name))
    if name == "edge_sensors":
        s.set(noise_rms=5e-9, sample_rate=100.0)
        if extras:
            s.set(height_gain_per_gap=-210.0, leff_per_gap=6.0,
                  install_segment_position_rms=1e-4, install_segment_clocking_rms=1e-4,
                  install_sensor_gap_rms=1e-5, drift_per_degc=1e-9, drift_per_week=1e-9)
    s.start()
    out = "u_cmd" if name == "global_controller" else "y"
    if name == "global_controller":
        s.set(y=readings("keck"))
        if extras:
            s.set(u_lo=1e-7 * np.sin(np.arange(s.size("u_lo"))))
    else:
        s.set(z=np.linspace(-1e-6, 1e-6, s.size("z")))
        if extras:
            s.set(temperature=2.5)
    for _ in range(40):
        s.step(1e-3)
    state = s.fmu.getFMUstate()
    blob = s.fmu.serializeFMUstate(state)
    t_saved = s.t
    first = []
    for _ in range(80):
        s.step(1e-3)
        first.append(s.get(out))
    for restore in ("memory", "bytes"):
        if restore == "memory":
            s.fmu.setFMUstate(state)
        else:
            s.fmu.setFMUstate(s.fmu.deSerializeFMUstate(blob))
        s.t = t_saved
        again = []
        for _ in range(80):
            s.step(1e-3)
            again.append(s.get(out))
        assert np.array_equal(np.array(first), np.array(again)), restore
    assert not np.array_equal(first[0], first[-1])
    s.fmu.freeFMUstate(state)
    s.close()
