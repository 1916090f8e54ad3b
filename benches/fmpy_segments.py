#!/usr/bin/env python3
"""Wall time of a packaged segments FMU through the FMI 2.0 C API, driven by fmpy.

Loads target/fmu/<layout>/segments_<model>.fmu (the real shared library) with fmpy's FMU2Slave
and times one second of simulated time at a fixed communication step (default 1 ms, i.e. 1000
fmi2DoStep calls), single-threaded, in these cases:

  fmpy_api   per step: one bulk FMU2Slave.setReal of all three input arrays (u_cmd, z_cell,
             f_wind: 3 x na values), doStep, one bulk FMU2Slave.getReal of both outputs (z,
             f_cell: 2 x na values). fmpy converts the values to and from ctypes arrays in
             Python on every call.
  ctypes     the same three C calls (through FMU2Slave.fmi2SetReal/fmi2DoStep/fmi2GetReal, so
             with fmpy's status checks) on ctypes arrays allocated once and filled/read through
             NumPy views: the cost of the FMU plus a minimal Python master.
  ctypes_split   as ctypes, but one fmi2SetReal per input array (3 calls of na values).
  dostep     FMU2Slave.doStep alone, inputs held (the FMU's own stepping cost).
  simulate   fmpy.simulate_fmu for the same second with its own loop (instantiate, initialise,
             1000 steps recording every output, terminate, free; model description parsed once).
  simulate_norec   the same with output=[] (nothing recorded).

The inputs change every step (small sinusoids, a different amplitude per actuator), as in the
criterion benchmark fmus/segments/benches/step.rs. Each case is repeated (--repeat) and the best
and median wall times are reported with their ratio to real time (wall s per simulated s).

Usage: .venv/bin/python benches/fmpy_segments.py [--layout tmt] [--model voicecoil|piezo]
       [--step 1e-3] [--repeat 7] [--fmu PATH]
Build the FMUs first: cargo xtask package keck tmt
"""

import argparse
import math
import os
import pathlib
import platform
import re
import shutil
import statistics
import sys
import time

# One core: keep NumPy's BLAS from starting worker threads (none of its routines are used here).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

import fmpy  # noqa: E402
from fmpy import extract, read_model_description, simulate_fmu  # noqa: E402
from fmpy.fmi2 import FMU2Slave, fmi2Real, fmi2True, fmi2ValueReference  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent
INPUTS = ("u_cmd", "z_cell", "f_wind")
OUTPUTS = ("z", "f_cell")
# Amplitude scale and frequency (Hz) of each input: 0.1 um command at 10 Hz, 10 nm cell motion
# at 3 Hz, 1 N wind at 1 Hz.
SCALE = (1e-7, 1e-8, 1.0)
FREQ = (10.0, 3.0, 1.0)


def array_vrs(md, name):
    """Value references of the array variable `name`, in element order."""
    pat = re.compile(re.escape(name) + r"\[(\d+)\]$")
    found = []
    for v in md.modelVariables:
        m = pat.match(v.name)
        if m:
            found.append((int(m.group(1)), v.valueReference))
    if not found:
        sys.exit(f"no variable {name}[...] in the model description")
    found.sort()
    return [vr for _, vr in found]


class Bench:
    def __init__(self, fmu_path, step):
        self.fmu_path = fmu_path
        self.md = read_model_description(fmu_path)
        self.unzipdir = extract(fmu_path)
        self.step = step
        self.n_steps = round(1.0 / step)
        self.in_vrs = [vr for name in INPUTS for vr in array_vrs(self.md, name)]
        self.out_vrs = [vr for name in OUTPUTS for vr in array_vrs(self.md, name)]
        self.na = len(self.in_vrs) // 3
        idx = np.arange(self.na)
        self.amp = [s * (1.0 + (idx % 7) / 7.0) for s in SCALE]
        t0 = time.perf_counter()
        self.fmu = FMU2Slave(
            guid=self.md.guid,
            unzipDirectory=self.unzipdir,
            modelIdentifier=self.md.coSimulation.modelIdentifier,
            instanceName="bench",
        )
        self.fmu.instantiate()
        self.load_s = time.perf_counter() - t0
        self.init_s = []

    def close(self):
        self.fmu.terminate()
        self.fmu.freeInstance()
        shutil.rmtree(self.unzipdir, ignore_errors=True)

    def restart(self):
        """Back to t = 0 at rest, initialised (not timed in the step loops)."""
        f = self.fmu
        t0 = time.perf_counter()
        f.reset()
        f.setupExperiment(startTime=0.0)
        f.enterInitializationMode()
        f.exitInitializationMode()
        self.init_s.append(time.perf_counter() - t0)

    def inputs_into(self, t, out):
        """This step's inputs, written into `out` (length 3 na)."""
        na = self.na
        for k in range(3):
            np.multiply(self.amp[k], math.sin(2.0 * math.pi * FREQ[k] * t), out=out[k * na:(k + 1) * na])

    def run_fmpy_api(self):
        f, h, vin, vout = self.fmu, self.step, self.in_vrs, self.out_vrs
        buf = np.zeros(len(vin))
        self.restart()
        t = 0.0
        t0 = time.perf_counter()
        for _ in range(self.n_steps):
            self.inputs_into(t, buf)
            f.setReal(vin, buf.tolist())
            f.doStep(t, h)
            t += h
            y = f.getReal(vout)
        wall = time.perf_counter() - t0
        return wall, np.asarray(y)

    def run_ctypes(self):
        f, h = self.fmu, self.step
        n_in, n_out = len(self.in_vrs), len(self.out_vrs)
        vr_in = (fmi2ValueReference * n_in)(*self.in_vrs)
        vr_out = (fmi2ValueReference * n_out)(*self.out_vrs)
        val_in = (fmi2Real * n_in)()
        val_out = (fmi2Real * n_out)()
        buf = np.frombuffer(val_in, dtype=np.float64)
        y = np.frombuffer(val_out, dtype=np.float64)
        master_y = np.empty(n_out)
        c = f.component
        set_real, do_step, get_real = f.fmi2SetReal, f.fmi2DoStep, f.fmi2GetReal
        self.restart()
        t = 0.0
        t0 = time.perf_counter()
        for _ in range(self.n_steps):
            self.inputs_into(t, buf)
            set_real(c, vr_in, n_in, val_in)
            do_step(c, t, h, fmi2True)
            t += h
            get_real(c, vr_out, n_out, val_out)
            np.copyto(master_y, y)
        wall = time.perf_counter() - t0
        return wall, master_y

    def run_ctypes_split(self):
        """As run_ctypes, but one fmi2SetReal per input array (three calls per step)."""
        f, h = self.fmu, self.step
        na, n_in, n_out = self.na, len(self.in_vrs), len(self.out_vrs)
        vr_in = (fmi2ValueReference * n_in)(*self.in_vrs)
        vr_out = (fmi2ValueReference * n_out)(*self.out_vrs)
        val_in = (fmi2Real * n_in)()
        val_out = (fmi2Real * n_out)()
        parts = [
            ((fmi2ValueReference * na).from_buffer(vr_in, 4 * k * na), (fmi2Real * na).from_buffer(val_in, 8 * k * na))
            for k in range(3)
        ]
        buf = np.frombuffer(val_in, dtype=np.float64)
        y = np.frombuffer(val_out, dtype=np.float64)
        master_y = np.empty(n_out)
        c = f.component
        set_real, do_step, get_real = f.fmi2SetReal, f.fmi2DoStep, f.fmi2GetReal
        self.restart()
        t = 0.0
        t0 = time.perf_counter()
        for _ in range(self.n_steps):
            self.inputs_into(t, buf)
            for vrs, vals in parts:
                set_real(c, vrs, na, vals)
            do_step(c, t, h, fmi2True)
            t += h
            get_real(c, vr_out, n_out, val_out)
            np.copyto(master_y, y)
        wall = time.perf_counter() - t0
        return wall, master_y

    def run_dostep(self):
        f, h = self.fmu, self.step
        self.restart()
        t = 0.0
        t0 = time.perf_counter()
        for _ in range(self.n_steps):
            f.doStep(t, h)
            t += h
        return time.perf_counter() - t0, None

    def run_simulate(self, record=True):
        t0 = time.perf_counter()
        res = simulate_fmu(
            self.unzipdir,
            model_description=self.md,
            fmi_type="CoSimulation",
            start_time=0.0,
            stop_time=1.0,
            output_interval=self.step,
            output=None if record else [],
        )
        wall = time.perf_counter() - t0
        if len(res) != self.n_steps + 1:
            sys.exit(f"simulate_fmu returned {len(res)} rows, expected {self.n_steps + 1}")
        return wall, None


def summary(name, walls, n_calls):
    best, med = min(walls), statistics.median(walls)
    return (
        f"{name:<16} best {best * 1e3:9.2f} ms  median {med * 1e3:9.2f} ms  "
        f"per call {med / n_calls * 1e6:8.1f} us  x real time {med:7.4f} (best {best:.4f})"
    )


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--layout", default="tmt", help="mirror layout of the packaged FMU (keck, tmt, elt)")
    ap.add_argument("--model", default="voicecoil", choices=["voicecoil", "piezo"])
    ap.add_argument("--step", type=float, default=1e-3, help="communication step (s), default 1e-3")
    ap.add_argument("--repeat", type=int, default=7, help="repetitions of each case (default 7)")
    ap.add_argument("--fmu", help="path of the .fmu (default target/fmu/<layout>/segments_<model>.fmu)")
    ap.add_argument(
        "--cases",
        default="fmpy_api,ctypes,ctypes_split,dostep,simulate,simulate_norec",
        help="comma-separated cases to run",
    )
    args = ap.parse_args()

    fmu_dir = pathlib.Path(os.environ.get("M1CS_FMU_DIR", ROOT / "target" / "fmu"))
    path = pathlib.Path(args.fmu) if args.fmu else fmu_dir / args.layout / f"segments_{args.model}.fmu"
    if not path.exists():
        sys.exit(f"{path} not found; build it with: cargo xtask package {args.layout}")

    b = Bench(str(path), args.step)
    print(f"fmu:      {path} ({b.md.coSimulation.modelIdentifier}, {b.na} actuators)")
    print(
        f"python:   {platform.python_version()}  fmpy {fmpy.__version__}  numpy {np.__version__}  "
        f"host {platform.machine()}, {os.cpu_count()} CPUs"
    )
    print(
        f"case:     1 s simulated, step {args.step:g} s = {b.n_steps} calls; per step "
        f"setReal of {len(b.in_vrs)} values, getReal of {len(b.out_vrs)} values; "
        f"{args.repeat} repetitions"
    )
    print(f"load:     FMU2Slave + instantiate {b.load_s * 1e3:.1f} ms")

    runners = {
        "fmpy_api": b.run_fmpy_api,
        "ctypes": b.run_ctypes,
        "ctypes_split": b.run_ctypes_split,
        "dostep": b.run_dostep,
        "simulate": lambda: b.run_simulate(True),
        "simulate_norec": lambda: b.run_simulate(False),
    }
    results = {}
    finals = {}
    for name in args.cases.split(","):
        run = runners[name]
        run()  # warm-up
        walls = []
        for _ in range(args.repeat):
            wall, y = run()
            walls.append(wall)
            if y is not None:
                finals[name] = y
        results[name] = walls
        print(summary(name, walls, b.n_steps), flush=True)
    if b.init_s:
        print(f"init:     reset + setup + enter/exit initialisation, median {statistics.median(b.init_s) * 1e3:.2f} ms")

    # The two exchange loops saw the same inputs: their final outputs must agree exactly.
    for name, y in finals.items():
        if not np.all(np.isfinite(y)):
            sys.exit(f"{name}: non-finite outputs")
    names = [n for n in ("fmpy_api", "ctypes", "ctypes_split") if n in finals]
    for other in names[1:]:
        d = float(np.max(np.abs(finals[names[0]] - finals[other])))
        print(f"check:    final outputs of {names[0]} and {other} differ by at most {d:g}")
        if d != 0.0:
            sys.exit("the exchange loops disagree")
    b.close()


if __name__ == "__main__":
    main()
