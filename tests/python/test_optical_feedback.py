"""The optical_feedback FMU through fmpy: validation passes; y_ref passes y_ref_in through
while focus-mode is off, and u_lo answers the surface after a step, not before."""
import numpy as np
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from conftest import fmu_path


def test_validates_without_problems():
    problems = validate_fmu(str(fmu_path("keck", "optical_feedback")))
    assert problems == [], "\n".join(problems)


def test_y_ref_in_passes_through_and_u_lo_follows_the_steps():
    path = fmu_path("keck", "optical_feedback")
    md = read_model_description(str(path))
    names = {v.name for v in md.modelVariables}
    na = sum(n.startswith("z[") for n in names)
    ns = sum(n.startswith("y_ref_in[") for n in names)
    start = {f"z[{i}]": 1e-8 * np.sin(0.37 * i) + 2e-9 * i for i in range(1, na + 1)}
    start.update({f"y_ref_in[{n}]": 1e-9 * n for n in range(1, ns + 1)})
    start.update({"focus": False, "noise_rms": 0.0, "bandwidth": 0.05})
    out = [f"y_ref[{n}]" for n in range(1, ns + 1)] + [f"u_lo[{i}]" for i in range(1, na + 1)]
    r = simulate_fmu(str(path), stop_time=3.0, step_size=1.0, output_interval=1.0,
                     start_values=start, output=out)
    y = np.stack([r[f"y_ref[{n}]"] for n in range(1, ns + 1)], axis=1)
    u = np.stack([r[f"u_lo[{i}]"] for i in range(1, na + 1)], axis=1)
    assert np.all(y == 1e-9 * np.arange(1, ns + 1))
    assert np.all(u[0] == 0.0)
    assert np.all(np.abs(u[1:]).max(axis=1) > 0.0)
    # Open loop on a fixed surface: the command grows by the same amount every step.
    assert np.allclose(u[3] - u[2], u[1] - u[0], rtol=1e-9, atol=1e-24)
