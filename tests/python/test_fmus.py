"""Every packaged FMU passes fmpy's validation and simulates in fmpy."""
import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from conftest import all_fmus

FMUS = all_fmus()
IDS = [f"{layout}/{p.stem}" for layout, p in FMUS]


@pytest.mark.parametrize("layout,path", FMUS, ids=IDS)
def test_validates_without_problems(layout, path):
    problems = validate_fmu(str(path))
    assert problems == [], "\n".join(problems)


@pytest.mark.parametrize("layout,path", FMUS, ids=IDS)
def test_simulates_its_default_experiment_briefly(layout, path):
    """Every FMU runs 50 communication steps of its default step size on its defaults, and every
    Real output stays finite."""
    md = read_model_description(str(path))
    outputs = [v.name for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
    assert outputs, "no Real output"
    step = float(md.defaultExperiment.stepSize)
    r = simulate_fmu(
        str(path),
        stop_time=50 * step,
        step_size=step,
        output_interval=step,
        output=outputs,
    )
    assert len(r) == 51
    for name in outputs:
        assert np.all(np.isfinite(r[name])), name


SEGMENTS = [(layout, p) for layout, p in FMUS if p.stem.startswith("segments")]
SEGMENT_IDS = [f"{layout}/{p.stem}" for layout, p in SEGMENTS]


@pytest.mark.parametrize("layout,path", SEGMENTS, ids=SEGMENT_IDS)
def test_simulates_a_command_step(layout, path):
    md = read_model_description(str(path))
    n = {v.name: v for v in md.modelVariables}["n_segments"]
    na = 3 * int(n.start)
    assert sum(v.name.startswith("z[") for v in md.modelVariables) == na
    # A 1 um piston step on the last segment: its three actuators follow, the others stay put.
    step = {f"u_cmd[{i}]": 1e-6 for i in (na - 2, na - 1, na)}
    # The undamped hard actuator rings on its 31 Hz stack mode (damping ratio 0.01, a 0.5 s
    # decay): it settles to 20 nm in 3 s, the others well within 0.3 s.
    stop = 3.0 if path.stem == "segments_piezo" else 0.3
    r = simulate_fmu(
        str(path),
        stop_time=stop,
        output_interval=1e-3,
        start_values=step,
        output=["z[1]", f"z[{na}]", f"f_cell[{na}]"],
    )
    assert len(r) == round(stop / 1e-3) + 1
    assert np.all(r["z[1]"] == 0.0)
    assert abs(r[f"z[{na}]"][-1] - 1e-6) < 2e-8, r[f"z[{na}]"][-1]
    # No load: the actuator's force on the cell goes back to zero once the segment is at rest.
    assert abs(r[f"f_cell[{na}]"][-1]) < 0.5
