"""Our master against fmpy.ssp on the same .ssp: the Keck pier-vibration system (pier ->
mirror, edge sensors, global controller, optics) written by `m1cs system`, run by fmpy.ssp's
fixed-step Jacobi loop and by `m1cs run --ssp` in Jacobi order, agree to 1e-9 relative over
0.1 s: long enough for the 20 Hz controller's first command (sampled at 0.05 s) to reach the
mirror and the optics, so the whole loop is compared.

fmpy.ssp (0.3.32, and FMPy's current source) wires every *unconnected* input to the output that
feeds the previous connected input (a stale variable in `fmpy.ssp.ssd.get_connections`, FMPy
issue #690): here sensors.w, mirror.f_wind and controller.y_ref would all be driven by wrong
signals from t = 0.052 s on. The test keeps only the SSD's connections (same FMI calls).

Its other conventions, accounted for here:
- every connection starts at 0 (not at the FMUs' initial outputs): our master runs with
  `--zero-start`;
- it steps every component at one step size: the system is written with `--uniform`;
- it records after stepping from t, labelled t: its row k is our row k + 1 (labelled t + h);
- it ignores parameter bindings: the vibration system binds only values equal to the defaults.
"""
import csv
import json
import subprocess

import numpy as np
import pytest
import fmpy.ssp.simulation as fmpy_ssp

from conftest import FMU_DIR, ROOT

M1CS = ROOT / "target" / "release" / "m1cs"
STEP = 1e-3
DURATION = 0.1


def simulate_ssp_connected_only(path, stop_time, step_size):
    """fmpy.ssp.simulate_ssp with get_connections reduced to the SSD's own connections."""
    stock = fmpy_ssp.get_connections

    def only_ssd(system, connectors=None):
        pairs = stock(system, connectors)
        real = set()
        for c in system.connections:
            a, b = f"{c.startElement}.{c.startConnector}", f"{c.endElement}.{c.endConnector}"
            real.update({(a, b), (b, a)})
        return [(a, b) for a, b in pairs if (a.path, b.path) in real]

    fmpy_ssp.get_connections = only_ssd
    try:
        return fmpy_ssp.simulate_ssp(str(path), stop_time=stop_time, step_size=step_size)
    finally:
        fmpy_ssp.get_connections = stock
COLUMNS = ["optics.rms_surface", "optics.focus_mode", "optics.rms_surface_without_focus"]


def test_master_agrees_with_fmpy_ssp(tmp_path):
    if not M1CS.exists():
        pytest.fail(f"{M1CS} is missing: run `cargo build --release` first")
    ssp = tmp_path / "keck_vibration.ssp"
    subprocess.run([str(M1CS), "system", "--layout", "keck", "--scenario", "vibration",
                    "--uniform", "--step", str(STEP), "--duration", str(DURATION),
                    "--fmu-dir", str(FMU_DIR), "-o", str(ssp)], check=True)
    out = tmp_path / "results"
    r = subprocess.run([str(M1CS), "run", "--ssp", str(ssp), "--order", "jacobi", "--zero-start",
                        "--decimation", "1", "--out", str(out), "--json"],
                       check=True, capture_output=True, text=True)
    json.loads(r.stdout)
    with open(out / "system.csv") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    ours = {name: data[:, k] for k, name in enumerate(header)}

    theirs = simulate_ssp_connected_only(ssp, stop_time=DURATION, step_size=STEP)
    n = min(len(theirs), len(data) - 1)
    assert n >= int(round(DURATION / STEP)) - 1
    # fmpy's row k (time t_k, values after the step from t_k) is our row k + 1 (time t_k + h).
    assert np.allclose(theirs["time"][:n] + STEP, ours["time"][1:n + 1], rtol=0, atol=1e-12)
    for name in COLUMNS:
        a, b = theirs[name][:n], ours[name][1:n + 1]
        scale = max(np.max(np.abs(a)), 1e-30)
        assert np.max(np.abs(a)) > 0.0, f"{name} stays zero: the comparison would be vacuous"
        assert np.max(np.abs(a - b)) <= 1e-9 * scale, (name, np.max(np.abs(a - b)), scale)
    # The comparison extends past the controller's first command (sampled at 0.05 s, at the
    # mirror from 0.051 s, in the optics from 0.052 s), so the closed loop itself is compared.
    assert ours["time"][n] > 0.06
