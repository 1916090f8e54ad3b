"""The mirror FMU's `solver_threads` through fmpy: its helper thread (the coupled solver's work
split in two) gives the outputs of one thread bit for bit, and a bad value is refused at
initialisation with a message naming the variable."""
import numpy as np
import pytest

from conftest import fmu_path
from slave import Slave


def run(threads, steps=30):
    s = Slave(fmu_path("keck", "mirror_voicecoil"), name=f"threads{threads}")
    try:
        # 100 of Keck's 109 modes: the channels' maps and the free part split by kind, the
        # shapes' pass back by rows (the coupled solve stays in double precision below 150).
        s.set(solver_threads=threads, n_modes=100)
        s.start()
        na = s.size("f_wind")
        s.set(f_wind=np.linspace(-5.0, 5.0, na), u_cmd=np.full(na, 1e-8))
        for _ in range(steps):
            s.step(1e-3)
        return np.concatenate([s.get("z"), s.get("z_cell"), s.get("f_cell")])
    finally:
        s.close()


def test_two_solver_threads_give_the_outputs_of_one_bit_for_bit():
    one, two, auto = run(1), run(2), run(0)
    assert np.count_nonzero(one) > 0.9 * one.size
    assert one.tobytes() == two.tobytes()
    assert one.tobytes() == auto.tobytes()


def test_a_bad_solver_threads_value_is_refused_at_initialisation():
    s = Slave(fmu_path("keck", "mirror_voicecoil"), name="bad")
    try:
        s.set(solver_threads=3)
        with pytest.raises(Exception):
            s.start()
        assert "solver_threads" in s.log_text(), s.log_text()
    finally:
        s.fmu.freeInstance()
