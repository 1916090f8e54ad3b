"""The deformation FMU through fmpy: the thermal field of +5 K opens every gap by about
alpha x 5 K x pitch, a table of FEA results is interpolated bilinearly relative to its baseline,
and an input outside the table ends the simulation with an error."""
import numpy as np
import pytest
from fmpy import simulate_fmu

from conftest import fmu_path

NA = 108  # Keck: 36 segments x 3
PITCH = np.sqrt(3) * 0.9 + 0.003  # Keck: circumradius 0.9 m, gap 3 mm
ALPHA = 10e-6  # default thermal_expansion (1/K)


def inputs(zenith, temperature, stop):
    """Constant inputs as fmpy's structured array."""
    dtype = [("time", np.float64), ("zenith_angle", np.float64), ("temperature", np.float64)]
    return np.array([(0.0, zenith, temperature), (stop, zenith, temperature)], dtype=dtype)


def run(zenith, temperature, start_values=None, stop=120.0, **kwargs):
    names = [f"w[{i}]" for i in range(1, NA + 1)] + [f"z_cell[{i}]" for i in range(1, NA + 1)]
    r = simulate_fmu(str(fmu_path("keck", "deformation")), stop_time=stop, step_size=60.0,
                     output_interval=60.0, input=inputs(zenith, temperature, stop),
                     start_values=start_values or {}, output=names, **kwargs)
    w = np.stack([r[f"w[{i}]"] for i in range(1, NA + 1)], axis=1)
    z = np.stack([r[f"z_cell[{i}]"] for i in range(1, NA + 1)], axis=1)
    return w, z


def test_five_kelvin_opens_every_gap_by_alpha_dt_pitch():
    w, z = run(30.0, 5.0)
    assert np.all(w == w[0]) and np.all(z == z[0]), "algebraic functions of constant inputs"
    radial, azimuthal, clocking = w[0, 0::3], w[0, 1::3], w[0, 2::3]
    # An isotropic strain alpha dT about the vertex: each segment slides radially by alpha dT
    # times its centre distance (to the surface slope and sag, 2 % at Keck's rim), with no
    # azimuthal motion or clocking.
    assert np.max(np.abs(azimuthal)) < 1e-6 * np.max(radial)
    assert np.all(clocking == 0.0)
    # Centre distances on Keck's three hex rings: 1, sqrt 3, 2, sqrt 7 and 3 pitches.
    rho = radial / (ALPHA * 5.0) / PITCH
    rings = np.array([1.0, np.sqrt(3.0), 2.0, np.sqrt(7.0), 3.0])
    nearest = rings[np.argmin(np.abs(rho[:, None] - rings[None, :]), axis=1)]
    assert np.allclose(rho, nearest, rtol=0.03), rho
    # Segments 1 and 7 are the corners of rings 1 and 2 on +x, one pitch apart: their gap
    # opens by alpha dT pitch.
    assert radial[6] - radial[0] == pytest.approx(ALPHA * 5.0 * PITCH, rel=0.03)


def table(tmp_path):
    """An .npz of FEA results linear in zenith angle and temperature (bilinear interpolation
    is then exact), and the function it samples."""
    zen = np.array([0.0, 60.0])
    temp = np.array([-5.0, 5.0])
    k = np.arange(1, NA + 1)

    def f(z, t, scale):
        return scale * (z + 10.0 * t) * k

    w = np.array([[f(a, b, 1e-7) for b in temp] for a in zen])
    z_cell = np.array([[f(a, b, -2e-8) for b in temp] for a in zen])
    path = tmp_path / "fea.npz"
    np.savez(path, zenith_deg=zen, temperature_c=temp, w=w, z_cell=z_cell)
    return path, f


def test_a_table_is_interpolated_relative_to_its_baseline(tmp_path):
    path, f = table(tmp_path)
    w, z = run(45.0, 2.0, start_values={"fea_file": str(path)})
    # Baseline: zenith 30 deg, no temperature change (the defaults).
    assert np.allclose(w[-1], f(45.0, 2.0, 1e-7) - f(30.0, 0.0, 1e-7), rtol=1e-12, atol=0)
    assert np.allclose(z[-1], f(45.0, 2.0, -2e-8) - f(30.0, 0.0, -2e-8), rtol=1e-12, atol=0)


def test_an_input_outside_the_table_is_an_error(tmp_path):
    path, _ = table(tmp_path)
    messages = []
    with pytest.raises(Exception):
        run(70.0, 0.0, start_values={"fea_file": str(path)}, debug_logging=True,
            logger=lambda *args: messages.append(str(args)))
    assert any("outside the table" in m for m in messages), messages
