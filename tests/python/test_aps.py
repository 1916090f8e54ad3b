"""The aps FMU through fmpy: the desired readings are held between runs and change at each run
instant, first_run + k interval; runs counts them."""
import numpy as np
from fmpy import read_model_description, simulate_fmu

from conftest import fmu_path


def test_y_ref_is_held_between_runs():
    path = fmu_path("keck", "aps")
    md = read_model_description(str(path))
    y_ref = [v.name for v in md.modelVariables if v.name.startswith("y_ref[")]
    assert len(y_ref) == 168
    # A segment error on segment 3, held; a run every 10 s from the start.
    start = {"interval": 10.0, "first_run": 0.0, "z[7]": 3e-8, "z[8]": -1e-8, "z[9]": 2e-8}
    r = simulate_fmu(str(path), stop_time=35.0, step_size=1.0, output_interval=1.0,
                     start_values=start, output=y_ref + ["runs"])
    t = r["time"]
    y = np.stack([r[n] for n in y_ref], axis=1)
    assert np.array_equal(r["runs"], 1 + np.floor(t / 10.0 + 1e-9).astype(int))
    assert np.any(y[0] != 0.0), "a run at the start time"
    changed = np.any(y[1:] != y[:-1], axis=1)
    ran = np.diff(r["runs"]) > 0
    # Unchanged between runs; every run moves the readings (its measurement errors differ).
    assert np.array_equal(changed, ran)
    assert list(t[1:][ran]) == [10.0, 20.0, 30.0]
