"""Parameter sweep of the closed global loop on the default plant, wind speed x control
bandwidth, with fmpy on Dask.

The plant is the default one of `m1cs run`: the mirror FMU (`mirror_voicecoil`, or
`mirror_piezo`, with `shunt_enabled` for the piezo-damped variant), the segments and the
telescope structure solved together at every servo sample, on the structure's default preset
(tmt, the FMU parameter `structure`'s default) with `--structure-modes` structure modes. The
system is the one `m1cs system` wires with its default `--cell coupled` (see `standard_system`
in src/commands/cosim.rs):

    wind.f_wind -> mirror.f_wind       mirror.z -> sensors.z -> controller.y
    controller.u_cmd -> mirror.u_cmd   mirror.z -> optics.z

with wind at 100 Hz, the global controller at 20 Hz, optics at 1 kHz and the mirror and edge
sensors at every base step (1 ms by default; the mirror FMU takes any multiple of its 0.2 ms
servo period). `--cell rigid` sweeps the segments FMU alone instead (`segments_voicecoil` or
`segments_piezo`, the cell does not move), as `m1cs run --cell rigid`. The system is stepped
here by an explicit Python loop over fmpy FMU2Slave instances with the master algorithm of
`m1cs run` (crates/cosim/src/system/step.rs), on its FMI 2.0 timing. With base step h, a
component stepping every N base steps is due at base step k (t_k = k h) when k % N == 0 and
steps over N h (its last step cut to end at the stop time); the outputs it gives after
fmi2DoStep(t, H) are those at t + H, and its initial outputs those at the start time (they feed
the first step). A due component reads, per input, the source's latest outputs with a time up to
t_k in Jacobi order, and up to t_k + h among those already computed in Gauss-Seidel order (the
default, as `m1cs run`'s: components in the order above, each after its predecessors at this
base step). So the wind's outputs from its step at t_k reach the mirror at base step k + 9
(Gauss-Seidel) or k + 10 (Jacobi), the controller's at k + 49 or k + 50, while the mirror's reach
the sensors and the optics at the same base step (Gauss-Seidel) or the next (Jacobi). The
optics' outputs are recorded at the ends of its steps, each row showing every output's latest
value with a time up to the row's. Values move in bulk: one fmi2SetReal, one fmi2DoStep and one
fmi2GetReal per component and step, on numpy arrays of value references and values allocated
once per run. The optics'
outputs equal those of `m1cs run --layout LAYOUT --cell CELL --structure-modes N [--structure
NAME] --step STEP --order ORDER --bandwidth B --bandwidth-radial34 B34 --bandwidth-radial2 B2`
bit for bit.

A sweep's bandwidth B is the global loop's on the modes of radial degrees >= 5; radial degrees
3-4 and 2 get the seed paper's baseline ratios of it (B34 = B x 1 / 1.5, B2 = B x 0.75 / 1.5, the
ratios of m1::control::controller's default bandwidths, as `m1cs wind` sweeps), focus-mode its own
`--focus-bandwidth`. The default wind speeds, 0.5, 1 and 2 m/s, bracket the seed paper's
Figure 12 case (1 m/s, `m1cs run`'s default).

Following fmpy's parameter-variation example, every Dask worker extracts each FMU once (into its
own local directory, by a worker plugin), instantiates it once, and runs each sweep point on that
instance after fmi2Reset. Every point reports, over the second half of the run: the rms surface
(the time rms of the optics' `rms_surface`, i.e. the square root of its time-averaged square), the
time rms of the focus-mode amplitude (in m along the unit-norm focus-mode vector of the actuator
space, as the optics FMU reports it; printed in nm) and of the rms surface without focus-mode,
and the mean PSSN, as `m1cs run` summarises its runs.

Usage (after `cargo xtask package keck`):

    python examples/dask_sweep.py --speeds 0.5,1,2 --bandwidths 0.5,1,2 --duration 2 --workers 2

writes OUT/sweep.csv and OUT/sweep.json (one row per point) and prints the table. `--workers 0`
runs the points in this process, without Dask (for debugging).
"""
import argparse
import csv
import ctypes
import itertools
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]

# Mirror-cell models (as `m1cs run --cell`): the instance name of the plant, which is also the
# prefix of its FMU's file name (FMU_DIR/LAYOUT/PREFIX_VARIANT.fmu).
CELLS = {
    "coupled": "mirror",  # the mirror FMU: segments and structure in one solve (the default)
    "rigid": "segments",  # the segments FMU alone: the cell does not move
}
DEFAULT_CELL = "coupled"
DEFAULT_STRUCTURE_MODES = 60  # `m1cs run --structure-modes`'s default
ORDERS = ("jacobi", "gauss-seidel")
# m1::control::controller's default bandwidths (Hz), the seed paper's baseline tuning: radial degrees
# >= 5, radial degrees 3-4, radial degree 2 (astigmatism) and focus-mode.
DEFAULT_BANDWIDTH = 1.5
DEFAULT_BANDWIDTH_RADIAL34 = 1.0
DEFAULT_BANDWIDTH_RADIAL2 = 0.75
DEFAULT_BANDWIDTH_FOCUS = 0.1
METRICS = ["rms_surface", "focus_mode", "rms_surface_without_focus", "pssn"]
# Actuator variant: (suffix of the plant's FMU, parameters of the plant).
ACTUATORS = {
    "voicecoil": ("voicecoil", {}),
    "piezo": ("piezo", {}),
    "piezo-damped": ("piezo", {"shunt_enabled": True}),
}
# Columns of the output table.
COLUMNS = ["wind_speed", "bandwidth", "bandwidth_radial34", "bandwidth_radial2", "rms_surface_m",
           "focus_mode_m", "rms_surface_without_focus_m", "pssn", "wall_s", "worker"]


def components(cell=DEFAULT_CELL):
    """Components in stepping order: (instance name, FMU file without .fmu or None for the
    plant's, rate in Hz or None for every base step), as `standard_system` orders them."""
    if cell not in CELLS:
        raise ValueError(f"cell {cell!r}: expected one of {tuple(CELLS)}")
    return [
        ("wind", "wind", 100.0),
        (CELLS[cell], None, None),
        ("sensors", "edge_sensors", None),
        ("controller", "global_controller", 20.0),
        ("optics", "optics", 1000.0),
    ]


def connections(cell=DEFAULT_CELL):
    """(from component, output signal, to component, input signal): whole arrays by base
    name."""
    plant = components(cell)[1][0]
    return [
        ("wind", "f_wind", plant, "f_wind"),
        ("controller", "u_cmd", plant, "u_cmd"),
        (plant, "z", "sensors", "z"),
        ("sensors", "y", "controller", "y"),
        (plant, "z", "optics", "z"),
    ]


def fmu_files(fmu_dir, layout, actuator="voicecoil", cell=DEFAULT_CELL):
    """The FMU file of each component, checked to exist."""
    comps = components(cell)
    plant = f"{CELLS[cell]}_{ACTUATORS[actuator][0]}"
    files = {name: pathlib.Path(fmu_dir) / layout / f"{fmu or plant}.fmu"
             for name, fmu, _ in comps}
    missing = [str(p) for p in files.values() if not p.is_file()]
    if missing:
        raise FileNotFoundError(
            f"missing FMU(s): {', '.join(missing)}; run `cargo xtask package {layout}` first "
            f"(or pass --fmu-dir)")
    return {k: str(v) for k, v in files.items()}


def structure_parameter(name):
    """The value of the mirror FMU's `structure` parameter for `--structure NAME`: a preset's
    name as given, a `.npz` path made absolute (as `m1cs run` does, so the FMU finds it)."""
    name = name.strip()
    if name.lower().endswith(".npz"):
        path = pathlib.Path(name)
        if not path.is_file():
            raise FileNotFoundError(f"--structure {name}: no such file")
        return str(path.resolve())
    return name


class FmuSet:
    """Each FMU extracted once and instantiated once; `slave` hands out the instance, reset when
    it has run before (fmpy's parameter-variation pattern). One per process."""

    def __init__(self, files, workdir=None):
        self.files = dict(files)
        self.workdir = tempfile.mkdtemp(prefix="m1cs_sweep_", dir=workdir)
        self._slaves = {}
        self.runs = 0  # points run on these instances so far

    def slave(self, name):
        """(FMU2Slave, {variable name: ScalarVariable}) for the component `name`, ready for
        fmi2SetupExperiment."""
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave

        if name in self._slaves:
            s, variables = self._slaves[name]
            s.reset()
            return s, variables
        unzipdir = extract(self.files[name], unzipdir=os.path.join(self.workdir, name))
        md = read_model_description(unzipdir)
        s = FMU2Slave(guid=md.guid, unzipDirectory=unzipdir,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
        s.instantiate()
        variables = {v.name: v for v in md.modelVariables}
        self._slaves[name] = (s, variables)
        return s, variables

    def close(self):
        for s, _ in self._slaves.values():
            s.freeInstance()  # allowed in any state; every run ends in fmi2Terminate
        self._slaves.clear()
        shutil.rmtree(self.workdir, ignore_errors=True)


def _signal(variables, name):
    """Value references of a scalar or of an array signal by its base name (`z` -> z[1..n])."""
    if name in variables:
        return np.array([variables[name].valueReference], dtype=np.uint32)
    vrs, k = [], 1
    while f"{name}[{k}]" in variables:
        vrs.append(variables[f"{name}[{k}]"].valueReference)
        k += 1
    if not vrs:
        raise KeyError(f"no variable {name!r}")
    return np.array(vrs, dtype=np.uint32)


def _set_parameter(s, variables, name, value):
    v = variables[name]
    vr = [v.valueReference]
    if v.type == "Real":
        s.setReal(vr, [float(value)])
    elif v.type in ("Integer", "Enumeration"):
        s.setInteger(vr, [int(value)])
    elif v.type == "Boolean":
        s.setBoolean(vr, [bool(value)])
    else:
        s.setString(vr, [str(value)])


def _ptr(a, ctype):
    return a.ctypes.data_as(ctypes.POINTER(ctype))


def group_bandwidths(bandwidth):
    """(radial degrees 3-4, radial degree 2) bandwidths for the bandwidth `bandwidth` of radial
    degrees >= 5: the baseline's ratios, computed as `m1cs wind` does."""
    return (bandwidth * DEFAULT_BANDWIDTH_RADIAL34 / DEFAULT_BANDWIDTH,
            bandwidth * DEFAULT_BANDWIDTH_RADIAL2 / DEFAULT_BANDWIDTH)


def simulate_point(fmus, wind_speed, bandwidth, duration, step,
                   focus_bandwidth=DEFAULT_BANDWIDTH_FOCUS, seed=1, actuator="voicecoil",
                   order="gauss-seidel", series=False, bandwidth_radial34=None,
                   bandwidth_radial2=None, cell=DEFAULT_CELL,
                   structure_modes=DEFAULT_STRUCTURE_MODES, structure=None):
    """Runs the closed loop for one (wind speed, bandwidth) on the instances of `fmus` (an
    FmuSet of `fmu_files` for the same actuator and cell) and returns the row of metrics (SI
    units); with `series`, the row also holds row["series"]: "time" and the optics outputs
    at the ends of its steps, the times of those outputs (arrays, by name). `bandwidth` acts
    on radial degrees >= 5; `bandwidth_radial34` and `bandwidth_radial2` default to the
    baseline's ratios of it (`group_bandwidths`). On the coupled cell, the mirror FMU gets
    `n_modes` = `structure_modes` and, when `structure` is given, the String parameter
    `structure` (else the FMU's default preset, tmt)."""
    if not (duration > 0 and step > 0 and duration >= step):
        raise ValueError(f"duration {duration} and step {step} must be positive, "
                         f"the duration at least one step")
    r34, r2 = group_bandwidths(bandwidth)
    bandwidth_radial34 = r34 if bandwidth_radial34 is None else bandwidth_radial34
    bandwidth_radial2 = r2 if bandwidth_radial2 is None else bandwidth_radial2
    if not (wind_speed > 0 and bandwidth > 0 and focus_bandwidth > 0
            and bandwidth_radial34 > 0 and bandwidth_radial2 > 0):
        raise ValueError("wind speed and bandwidths must be positive")
    if order not in ORDERS:
        raise ValueError(f"order {order!r}: expected one of {ORDERS}")
    comps_def, conns = components(cell), connections(cell)
    plant = CELLS[cell]
    if set(fmus.files) != {name for name, _, _ in comps_def}:
        raise ValueError(f"the FMUs {sorted(fmus.files)} are not those of the {cell} cell: "
                         f"pass fmu_files(..., cell={cell!r})")
    plant_parameters = {}
    if cell == "coupled":
        if not (isinstance(structure_modes, int) and structure_modes > 0):
            raise ValueError(f"structure_modes {structure_modes!r}: expected a positive integer")
        plant_parameters["n_modes"] = structure_modes
        if structure is not None:
            plant_parameters["structure"] = structure_parameter(structure)
    elif structure is not None:
        raise ValueError(f"structure {structure!r}: the {cell} cell has no structure")
    plant_parameters.update(ACTUATORS[actuator][1])
    wall0 = time.perf_counter()
    reuse = fmus.runs
    fmus.runs += 1
    parameters = {
        "wind": {"wind_speed": wind_speed, "seed": seed},
        plant: plant_parameters,
        "sensors": {"seed": seed},
        "controller": {"enabled": True, "bandwidth": bandwidth,
                       "bandwidth_radial34": bandwidth_radial34,
                       "bandwidth_radial2": bandwidth_radial2,
                       "bandwidth_focus": focus_bandwidth},
        "optics": {},
    }
    slaves, variables = {}, {}
    for name, _, _ in comps_def:
        s, var = fmus.slave(name)
        s.setupExperiment(startTime=0.0, stopTime=duration)
        for p, value in parameters[name].items():
            _set_parameter(s, var, p, value)
        s.enterInitializationMode()
        slaves[name], variables[name] = s, var
    for name, _, _ in comps_def:
        slaves[name].exitInitializationMode()

    # Output slots: every connected or recorded output, concatenated in one array.
    out_vrs = {name: [] for name, _, _ in comps_def}
    slot = {}

    def output_slot(comp, signal):
        if (comp, signal) not in slot:
            vrs = _signal(variables[comp], signal)
            slot[(comp, signal)] = (sum(len(a) for a in out_vrs[comp]), len(vrs))
            out_vrs[comp].append(vrs)
        return slot[(comp, signal)]

    in_vrs = {name: [] for name, _, _ in comps_def}
    in_src = {name: [] for name, _, _ in comps_def}
    for a, out, b, inp in conns:
        local, n = output_slot(a, out)
        vrs = _signal(variables[b], inp)
        if len(vrs) != n:
            raise ValueError(f"{a}.{out} has {n} values, {b}.{inp} {len(vrs)}")
        in_vrs[b].append(vrs)
        in_src[b].append((a, local, n))
    metric_slots = [output_slot("optics", m)[0] for m in METRICS]
    offset, total = {}, 0
    for name, _, _ in comps_def:
        offset[name] = total
        total += sum(len(a) for a in out_vrs[name])
    outputs = np.zeros(total)

    class Running:
        pass

    comps = []
    for name, _, rate in comps_def:
        r = Running()
        r.name, r.fmu = name, slaves[name]
        r.every = 1 if rate is None else max(1, int(round((1.0 / rate) / step)))
        r.in_vrs = np.concatenate(in_vrs[name]) if in_vrs[name] else np.zeros(0, np.uint32)
        r.in_src = (np.concatenate([np.arange(offset[a] + loc, offset[a] + loc + n)
                                    for a, loc, n in in_src[name]])
                    if in_src[name] else np.zeros(0, np.intp))
        r.in_buf = np.zeros(len(r.in_vrs))
        r.out_vrs = (np.concatenate(out_vrs[name]) if out_vrs[name]
                     else np.zeros(0, np.uint32))
        # Its outputs as read after its latest step (`out_buf`), and as the others see them
        # (`out_view`, its part of `outputs`): copied over when their time comes.
        r.out_buf = np.zeros(len(r.out_vrs))
        r.out_view = outputs[offset[name]:offset[name] + len(r.out_vrs)]
        r.ready_at = None  # base step at which `out_buf` becomes visible (None: it is)
        # ctypes pointers made once: the arrays live as long as this run.
        r.p_in_vrs, r.p_in_buf = _ptr(r.in_vrs, ctypes.c_uint), _ptr(r.in_buf, ctypes.c_double)
        r.p_out_vrs = _ptr(r.out_vrs, ctypes.c_uint)
        r.p_out = _ptr(r.out_buf, ctypes.c_double)
        r.n_in, r.n_out = len(r.in_vrs), len(r.out_vrs)
        comps.append(r)
        # The initial outputs (time: the start) feed the first step, visible at once (as
        # `m1cs run` without --zero-start).
        if r.n_out:
            r.fmu.fmi2GetReal(r.fmu.component, r.p_out_vrs, r.n_out, r.p_out)
            r.out_view[:] = r.out_buf

    def publish_due(limit):
        """Makes visible the pending outputs whose time is base step `limit` or earlier."""
        for r in comps:
            if r.ready_at is not None and r.ready_at <= limit:
                r.out_view[:] = r.out_buf
                r.ready_at = None

    # FMI 2.0 timing, as `m1cs run`: the outputs read after fmi2DoStep(t_k, n h) are those at
    # t_{k+n}, pending until base step k + n (`ready_at`; n = every, cut to end at the stop
    # time). A component due at base step k reads the visible outputs: in Jacobi order those
    # with times up to t_k (what becomes due at t_k + h is published once every due component
    # has stepped); in Gauss-Seidel order those with times up to t_k + h computed so far
    # (published at the start of the base step, and right after a step that ends at t_k + h).
    # A step over N base steps from t_k is thus first seen at base step k + N - 1 in
    # Gauss-Seidel order, k + N in Jacobi order.
    n_steps = int(round(duration / step))
    optics = comps[-1]
    # Recorded at the times of the optics' outputs, the ends of its steps: a row at t_k holds
    # the visible outputs, each the latest with a time up to t_k.
    rec_steps = [k for k in range(1, n_steps + 1) if k % optics.every == 0 or k == n_steps]
    n_rec = len(rec_steps)
    record = np.empty((n_rec, len(METRICS)))
    rec_index = np.array([offset["optics"] + s for s in metric_slots])
    jacobi = order == "jacobi"
    i = 0
    for k in range(n_steps):
        t, left = k * step, n_steps - k  # base steps left before the stop time
        if not jacobi:
            publish_due(k + 1)  # slower components' outputs for t_k + h
        for r in comps:
            if k % r.every:
                continue
            c, f = r.fmu.component, r.fmu
            if r.n_in:
                np.take(outputs, r.in_src, out=r.in_buf)
                f.fmi2SetReal(c, r.p_in_vrs, r.n_in, r.p_in_buf)
            n = min(r.every, left)
            f.fmi2DoStep(c, t, n * step, 1)
            if r.n_out:
                f.fmi2GetReal(c, r.p_out_vrs, r.n_out, r.p_out)
            r.ready_at = k + n
            if not jacobi:
                publish_due(k + 1)  # its outputs, if they are for t_k + h
        publish_due(k + 1)  # Jacobi: the outputs for t_k + h, once every due one has stepped
        if i < n_rec and rec_steps[i] == k + 1:
            record[i] = outputs[rec_index]
            i += 1
    for r in comps:
        r.fmu.terminate()

    settled = record[n_rec // 2:]
    rms = np.sqrt(np.mean(settled[:, :3] ** 2, axis=0))
    row = {
        "wind_speed": float(wind_speed),
        "bandwidth": float(bandwidth),
        "bandwidth_radial34": float(bandwidth_radial34),
        "bandwidth_radial2": float(bandwidth_radial2),
        "rms_surface_m": float(rms[0]),
        "focus_mode_m": float(rms[1]),
        "rms_surface_without_focus_m": float(rms[2]),
        "pssn": float(np.mean(settled[:, 3])),
        "wall_s": time.perf_counter() - wall0,
        "earlier_runs": reuse,  # points run before on the same instances (0: fresh)
    }
    if series:
        row["series"] = {"time": np.array(rec_steps) * step}
        row["series"].update({m: record[:, j].copy() for j, m in enumerate(METRICS)})
    return row


PLUGIN_NAME = "m1cs-fmus"


def _plugin_class():
    from distributed import WorkerPlugin

    class FmuPlugin(WorkerPlugin):
        """Extracts and instantiates the FMUs once per worker (in the worker's local
        directory); the sweep tasks reuse them."""
        name = PLUGIN_NAME

        def __init__(self, files):
            self.files = files
            self.fmus = None

        def setup(self, worker):
            self.fmus = FmuSet(self.files, workdir=worker.local_directory)

        def teardown(self, worker):
            if self.fmus is not None:
                self.fmus.close()

    return FmuPlugin


def _worker_point(point, **kwargs):
    from distributed import get_worker

    worker = get_worker()
    row = simulate_point(worker.plugins[PLUGIN_NAME].fmus, point[0], point[1], **kwargs)
    row["worker"] = worker.name
    return row


def run_sweep(files, points, workers, **kwargs):
    """Rows of `simulate_point` for every (wind speed, bandwidth) in `points`, in order: on a
    Dask LocalCluster of `workers` single-threaded processes, or in this process when
    `workers` is 0."""
    if workers == 0:
        fmus = FmuSet(files)
        try:
            return [dict(simulate_point(fmus, v, bw, **kwargs), worker="local")
                    for v, bw in points]
        finally:
            fmus.close()
    stem = pathlib.Path(__file__).stem
    if __name__ not in ("__main__", stem):
        raise ImportError(f"the Dask workers import this file as `{stem}`: run it as a "
                          f"script or import it under that name, not as `{__name__}`")
    import logging

    from distributed import Client, LocalCluster

    # The workers preload this file (importable there under its file name): run as a script,
    # its functions travel by value; imported (e.g. by path from a test, as `dask_sweep`), they
    # travel by reference and the workers find them.
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.ERROR,
                      preload=[str(pathlib.Path(__file__).resolve())]) as cluster, \
            Client(cluster) as client:
        client.register_plugin(_plugin_class()(files))
        futures = client.map(_worker_point, points, pure=False, **kwargs)
        return client.gather(futures)


def _floats(text):
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
    if not values or any(not (v > 0) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: expected positive numbers, comma-separated")
    return values


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--layout", default="keck", help="mirror layout (keck, tmt, elt)")
    p.add_argument("--fmu-dir", default=str(ROOT / "target" / "fmu"),
                   help="where `cargo xtask package` wrote the FMUs (FMU_DIR/LAYOUT/*.fmu)")
    p.add_argument("--speeds", type=_floats, default=[0.5, 1.0, 2.0],
                   help="wind speeds (m/s), comma-separated (1 m/s: the seed paper's Figure 12 "
                        "case, `m1cs run`'s default)")
    p.add_argument("--bandwidths", type=_floats, default=[0.5, 1.0, 2.0],
                   help="global-loop bandwidths on radial degrees >= 5 (Hz), comma-separated; "
                        "radial degrees 3-4 get 1/1.5 of each, radial degree 2 0.75/1.5 (the "
                        "baseline's ratios, as `m1cs wind`)")
    p.add_argument("--focus-bandwidth", type=float, default=DEFAULT_BANDWIDTH_FOCUS,
                   help="focus-mode bandwidth (Hz)")
    p.add_argument("--actuator", choices=sorted(ACTUATORS), default="voicecoil",
                   help="actuator variant: the plant FMU is mirror_voicecoil or mirror_piezo "
                        "(piezo-damped: with shunt_enabled), segments_* with --cell rigid")
    p.add_argument("--cell", choices=tuple(CELLS), default=DEFAULT_CELL,
                   help="mirror-cell model, as `m1cs run --cell`: coupled (the default plant, "
                        "the mirror FMU: segments and structure solved together) or rigid (the "
                        "segments FMU alone, the cell does not move)")
    p.add_argument("--structure-modes", type=int, default=DEFAULT_STRUCTURE_MODES,
                   help="structure modes retained by the mirror FMU (its n_modes; the rest "
                        "enter as a static correction), as `m1cs run --structure-modes`")
    p.add_argument("--structure", default=argparse.SUPPRESS, metavar="NAME",
                   help="structure under the segments, the mirror FMU's String parameter "
                        "`structure`: a preset of the built-in cell (tmt, soft-cell) or the path "
                        "of a .npz modal model; set only when given (default: the FMU's own "
                        "default, the tmt preset)")
    p.add_argument("--duration", type=float, default=2.0, help="simulated time per point (s)")
    p.add_argument("--step", type=float, default=1e-3,
                   help="base communication step (s): a multiple of the 0.2 ms servo period "
                        "of the mirror and segments FMUs")
    p.add_argument("--seed", type=int, default=1, help="seed of the wind screens and sensors")
    p.add_argument("--order", choices=ORDERS, default="gauss-seidel",
                   help="stepping order, as `m1cs run --order`")
    p.add_argument("--workers", type=int, default=min(4, os.cpu_count() or 1),
                   help="Dask worker processes (0: run in this process without Dask)")
    p.add_argument("--out", default="results/dask_sweep",
                   help="folder for sweep.csv and sweep.json")
    a = p.parse_args(argv)
    a.structure = getattr(a, "structure", None)
    if a.workers < 0:
        p.error("--workers must be 0 or more")
    if not (a.duration > 0 and a.step > 0 and a.duration >= a.step):
        p.error("--duration and --step must be positive, the duration at least one step")
    if a.structure_modes <= 0:
        p.error("--structure-modes must be positive")
    if a.structure is not None and a.cell != "coupled":
        p.error(f"--structure acts on the coupled cell's mirror FMU, not on --cell {a.cell}")
    return a


def print_table(rows, file=sys.stdout):
    print(f"{'wind (m/s)':>10} {'BW (Hz)':>8} {'rms surf (nm)':>14} {'focus amp (nm)':>14} "
          f"{'w/o focus (nm)':>15} {'PSSN':>9} {'wall (s)':>9}  worker", file=file)
    for r in rows:
        print(f"{r['wind_speed']:>10.3g} {r['bandwidth']:>8.3g} {r['rms_surface_m'] * 1e9:>14.4f} "
              f"{r['focus_mode_m'] * 1e9:>14.4f} {r['rms_surface_without_focus_m'] * 1e9:>15.4f} "
              f"{r['pssn']:>9.6f} {r['wall_s']:>9.2f}  {r.get('worker', '')}", file=file)


def main(argv=None):
    """Runs the sweep; returns the rows (one per point, speeds outer, bandwidths inner)."""
    a = parse_args(argv)
    files = fmu_files(a.fmu_dir, a.layout, a.actuator, a.cell)
    structure = None if a.structure is None else structure_parameter(a.structure)
    points = list(itertools.product(a.speeds, a.bandwidths))
    t0 = time.perf_counter()
    rows = run_sweep(files, points, a.workers, duration=a.duration, step=a.step,
                     focus_bandwidth=a.focus_bandwidth, seed=a.seed, actuator=a.actuator,
                     order=a.order, cell=a.cell, structure_modes=a.structure_modes,
                     structure=structure)
    wall = time.perf_counter() - t0
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "sweep.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow({k: repr(r[k]) if isinstance(r[k], float) else r[k] for k in COLUMNS})
    summary = {"layout": a.layout, "actuator": a.actuator, "cell": a.cell,
               "structure": a.structure, "structure_modes": a.structure_modes,
               "duration_s": a.duration, "step_s": a.step, "order": a.order,
               "focus_bandwidth_hz": a.focus_bandwidth, "seed": a.seed, "workers": a.workers,
               "wall_s": wall, "rows": rows}
    (out / "sweep.json").write_text(json.dumps(summary, indent=1))
    plant = (f"coupled cell (mirror FMU, structure {a.structure or 'tmt'}, "
             f"{a.structure_modes} modes)" if a.cell == "coupled" else "rigid cell")
    print(f"{a.layout}, {a.actuator}, {plant}, closed loop, {a.duration} s per point "
          f"(statistics over the second half), {len(rows)} points on "
          f"{a.workers or 'no'} Dask worker(s) in {wall:.1f} s:")
    print_table(rows)
    print(f"wrote {out / 'sweep.csv'} and {out / 'sweep.json'}")
    return rows


if __name__ == "__main__":
    try:
        main()
    except FileNotFoundError as e:
        sys.exit(f"error: {e}")
