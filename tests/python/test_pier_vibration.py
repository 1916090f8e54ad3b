"""The pier_vibration FMU through fmpy: the tone recovered, samples independent of the
communication step, seeds, and bad parameters refused."""
import numpy as np
import pytest
from fmpy import simulate_fmu

from conftest import fmu_path


def run(step, stop_time=1.0, start_values=None, output=("pier_z",)):
    return simulate_fmu(str(fmu_path("keck", "pier_vibration")), stop_time=stop_time,
                        step_size=step, output_interval=step,
                        start_values=start_values or {}, output=list(output))


def test_default_tone_is_recovered_by_least_squares():
    r = run(1e-3, stop_time=2.0, start_values={"noise_rms": 0.0, "tone_1_phase": 0.4})
    t, z = r["time"], r["pier_z"]
    m = np.stack([np.sin(2 * np.pi * 29.6 * t), np.cos(2 * np.pi * 29.6 * t)], axis=1)
    (a, b), *_ = np.linalg.lstsq(m, z, rcond=None)
    assert np.hypot(a, b) == pytest.approx(1e-8, rel=1e-9)
    assert np.arctan2(b, a) == pytest.approx(0.4, abs=1e-9)


def test_samples_do_not_depend_on_the_communication_step():
    values = {"tone_2_amplitude": 3e-9, "tone_2_frequency": 7.3, "noise_rms": 2e-9}
    a = run(1e-3, start_values=values)
    b = run(2.5e-4, start_values=values)
    assert np.allclose(a["time"], b["time"][::4], rtol=0, atol=1e-12)
    assert np.allclose(a["pier_z"], b["pier_z"][::4], rtol=0, atol=1e-18)
    assert np.std(a["pier_z"]) > 5e-9


def test_noise_rms_and_seed():
    values = {"tone_1_amplitude": 0.0, "noise_rms": 1e-9, "noise_period": 10.0}
    r = run(1e-3, stop_time=10.0, start_values=values, output=("pier_z", "pier_z_rms"))
    z = r["pier_z"][:-1]
    assert np.sqrt(np.mean(z**2)) == pytest.approx(1e-9, rel=0.02)
    assert r["pier_z_rms"][-1] == pytest.approx(1e-9, rel=1e-9)
    again = run(1e-3, stop_time=1.0, start_values=values)
    other = run(1e-3, stop_time=1.0, start_values={**values, "noise_seed": 2})
    assert np.array_equal(again["pier_z"], r["pier_z"][:1001])
    assert np.max(np.abs(other["pier_z"] - again["pier_z"])) > 5e-10


@pytest.mark.parametrize("values,words", [
    ({"noise_high_frequency": 0.5}, "noise_high_frequency"),
    ({"noise_rms": -1e-9}, "noise_rms"),
    ({"tone_1_frequency": -29.6}, "tone_1_frequency"),
    ({"noise_period": 1e9}, "noise_period"),
])
def test_bad_parameters_are_a_simulation_error(values, words):
    messages = []
    with pytest.raises(Exception):
        simulate_fmu(str(fmu_path("keck", "pier_vibration")), stop_time=0.01, step_size=1e-3,
                     output_interval=1e-3, start_values=values, output=["pier_z"],
                     debug_logging=True, logger=lambda *args: messages.append(str(args)))
    assert any(words in m for m in messages), messages
