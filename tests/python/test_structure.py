"""The structure FMU: an imported 2-mode model against its closed-form response, the static
correction, a pier tone through the built-in model, and errors at initialisation."""
import pathlib
import sys

import numpy as np
import pytest
from fmpy import simulate_fmu

from conftest import fmu_path, start_values

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "examples"))
from write_structure_npz import write_modal_npz  # noqa: E402

NA = 108  # keck: 36 segments x 3 actuators
FREQ = np.array([9.0, 23.0])
ZETA = np.array([0.05, 0.08])
K_PIER = 2.0e9


def two_mode_model():
    """A 2-mode model with a known residual flexibility (seeded)."""
    rng = np.random.default_rng(1234)
    phi = rng.normal(size=(NA, 2)) * 1e-3
    phi_pier = np.array([2e-4, -1e-4])
    w2 = (2 * np.pi * FREQ) ** 2
    modal_flex = phi @ np.diag(1 / w2) @ phi.T
    residual = np.diag(np.full(NA, 3e-10))  # the truncated modes' static compliance
    static_pier = np.full(NA, 1.0)
    return phi, phi_pier, modal_flex + residual, static_pier


def write_model(tmp_path, **extra):
    phi, phi_pier, flex, static_pier = two_mode_model()
    path = tmp_path / "two_modes.npz"
    write_modal_npz(path, FREQ, phi, phi_pier, K_PIER, damping_ratios=ZETA,
                    flexibility=flex, static_pier=static_pier, **extra)
    return path


def step_response(w, zeta, t):
    """Unit-force step response of q'' + 2 zeta w q' + w^2 q = 1 from rest (zeta < 1)."""
    s = zeta * w
    wd = w * np.sqrt(1 - zeta**2)
    return (1 - np.exp(-s * t) * (np.cos(wd * t) + s / wd * np.sin(wd * t))) / w**2


@pytest.mark.parametrize("compressed", [True, False], ids=["deflated", "stored"])
def test_force_step_matches_the_closed_form_response(tmp_path, compressed):
    path = write_model(tmp_path, compressed=compressed)
    phi, _, flex, _ = two_mode_model()
    fmu = fmu_path("keck", "structure")
    force, j = 500.0, 4  # on actuator index 4 (z_cell[5])
    h, stop = 1e-3, 4.0
    r = simulate_fmu(str(fmu), stop_time=stop, output_interval=h,
                     start_values={"modal_file": str(path), "n_modes": 2, f"f_cell[{j + 1}]": force},
                     output=["z_cell[1]", f"z_cell[{j + 1}]", "first_mode_frequency",
                             "n_modes_retained"])
    t = r["time"]
    w = 2 * np.pi * FREQ
    f = np.zeros(NA)
    f[j] = force
    u = phi.T @ f
    q = np.stack([u[m] * step_response(w[m], ZETA[m], t) for m in range(2)], axis=1)
    residual = (flex - phi @ np.diag(1 / w**2) @ phi.T) @ f
    for k in (0, j):
        expected = q @ phi[k] + residual[k]
        expected[0] = 0.0  # at rest before the first step (no direct feedthrough)
        got = r[f"z_cell[{k + 1}]"]
        err = np.max(np.abs(got - expected)) / np.max(np.abs(expected))
        assert err < 1e-9, f"z_cell[{k + 1}]: max relative error {err:.2e}"
    # Converges to the static deflection G f (the damped transient has died out).
    static = flex @ f
    assert abs(r[f"z_cell[{j + 1}]"][-1] / static[j] - 1) < 1e-3
    assert r["first_mode_frequency"][-1] == pytest.approx(9.0)
    assert r["n_modes_retained"][-1] == 2


def pier_input(f_tone, amp, h, stop):
    """A pier tone as fmpy input (every input column given, the forces zero)."""
    t = np.arange(0.0, stop + h / 2, h)
    names = ["time", "pier_z"] + [f"f_cell[{k + 1}]" for k in range(NA)]
    sig = np.zeros(t.size, dtype=[(n, np.float64) for n in names])
    sig["time"] = t
    sig["pier_z"] = amp * np.sin(2 * np.pi * f_tone * t)
    return sig


def tone_amplitude(t, x, f):
    """Least-squares amplitude of the f-Hz component, and the rms of what is left."""
    a = np.stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)], axis=1)
    c, *_ = np.linalg.lstsq(a, x, rcond=None)
    return np.hypot(c[0], c[1]), np.sqrt(np.mean((x - a @ c) ** 2))


def test_pier_tone_through_the_imported_model(tmp_path):
    path = write_model(tmp_path)
    phi, phi_pier, _, static_pier = two_mode_model()
    fmu = fmu_path("keck", "structure")
    f_tone, amp, h, stop = 29.6, 1e-6, 2e-4, 2.0
    sig = pier_input(f_tone, amp, h, stop)
    r = simulate_fmu(str(fmu), stop_time=stop, output_interval=h, input=sig,
                     start_values={"modal_file": str(path)}, output=["z_cell[1]"])
    t, z = r["time"], r["z_cell[1]"]
    keep = t > 1.0  # transients (damping 5 % and 8 %) have decayed
    got, rest = tone_amplitude(t[keep], z[keep], f_tone)
    w = 2 * np.pi * FREQ
    om = 2 * np.pi * f_tone
    modal = K_PIER * phi_pier * phi[0]
    h_dyn = np.sum(modal / (w**2 - om**2 + 2j * ZETA * w * om))
    h_res = static_pier[0] - np.sum(modal / w**2)
    expected = abs(h_dyn + h_res) * amp
    assert rest < 0.02 * got, "the response is a tone at the pier frequency"
    # The held inputs and the one-step lag of the residual shift the phase a little.
    assert got == pytest.approx(expected, rel=0.02)


def test_pier_tone_through_the_built_in_model():
    fmu = fmu_path("keck", "structure")
    f_tone, amp, h, stop = 3.0, 1e-6, 1e-3, 2.0
    sig = pier_input(f_tone, amp, h, stop)
    # Damping 0.2 lets the start-up transient of the modes die out within the record.
    r = simulate_fmu(str(fmu), stop_time=stop, output_interval=h, input=sig,
                     start_values={"damping_ratio": 0.2},
                     output=["z_cell[1]", "z_cell[100]", "first_mode_frequency"])
    f1 = r["first_mode_frequency"][-1]
    assert 5.0 < f1 < 20.0
    keep = r["time"] > 0.5
    for name in ("z_cell[1]", "z_cell[100]"):
        got, rest = tone_amplitude(r["time"][keep], r[name][keep], f_tone)
        # A third of the first mode's frequency: the cell follows the pier, amplified a little
        # by the modes above (each by 1 / (1 - (f/f_j)^2) <= 1.12 here, shapes > 1 at the rim).
        assert 1.0 < got / amp < 1.5, got / amp
        assert rest < 0.05 * got


def test_force_step_on_the_built_in_model_settles():
    fmu = fmu_path("keck", "structure")
    force = 1000.0
    # Strong damping settles quickly; the static deflection is downward-positive for +z force.
    r = simulate_fmu(str(fmu), stop_time=1.0, output_interval=1e-3,
                     start_values={"f_cell[1]": force, "damping_ratio": 0.7, "n_modes": 10},
                     output=["z_cell[1]"])
    z = r["z_cell[1]"]
    assert z[0] == 0.0
    assert z[-1] > 0.0
    assert abs(z[-1] - z[-100]) < 1e-6 * abs(z[-1])


def test_bad_modal_file_fails_at_initialisation(tmp_path):
    fmu = fmu_path("keck", "structure")
    with pytest.raises(Exception):
        simulate_fmu(str(fmu), stop_time=0.01, output_interval=1e-3,
                     start_values={"modal_file": str(tmp_path / "missing.npz")})
    # A file for another layout (na = 1476, TMT) is refused too.
    phi = np.ones((1476, 1)) * 1e-3
    wrong = tmp_path / "tmt.npz"
    write_modal_npz(wrong, [10.0], phi, [1e-4], 1e9)
    with pytest.raises(Exception):
        simulate_fmu(str(fmu), stop_time=0.01, output_interval=1e-3,
                     start_values={"modal_file": str(wrong)})


def test_bad_parameters_are_refused():
    fmu = fmu_path("keck", "structure")
    for bad in ({"damping_ratio": -0.1}, {"n_modes": 0}, {"cell_frequency": 0.0}):
        with pytest.raises(Exception):
            simulate_fmu(str(fmu), stop_time=0.01, output_interval=1e-3, start_values=bad)


def test_documented_defaults():
    s = start_values(fmu_path("tmt", "structure"))
    assert s["damping_ratio"] == 0.02
    assert s["modal_file"] == ""
    assert s["n_modes"] == 60
    assert s["f_cell[1476]"] == 0.0
