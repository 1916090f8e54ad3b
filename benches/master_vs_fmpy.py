#!/usr/bin/env python3
"""Our master against fmpy's own ways of running the same system, side by side in one run.

The system: the Keck pier-vibration closed loop written by `m1cs system --layout keck
--scenario vibration --uniform` (pier vibration -> mirror -> edge sensors -> global controller,
and the optics metrics), every component at the base step, as fmpy requires. Three masters run
it for the same stop time at the same communication step:

  ours       `m1cs run --ssp SYSTEM.ssp --order jacobi --decimation 1 --json`: the whole
             command's wall time (process start, FMU loading, run, CSV, plots, summary) and the
             run's `wall_seconds` from its JSON (instantiation, initialisation, step loop).
  fmpy.ssp   `fmpy.ssp.simulate_ssp(SYSTEM.ssp, stop_time, step_size)`: fmpy's Jacobi loop in
             Python, one fmi2SetReal/fmi2GetReal per scalar connector and step, every variable
             recorded; timed around the call (it extracts and instantiates the FMUs inside). As
             shipped (fmpy 0.3.32) it wires every unconnected input to the start of the previous
             connected one (FMPy issue #690), so it is also run with only the SSD's connections
             (same FMI calls, right answer).
  container  fmpy's container FMU (`fmpy.container_fmu`, a Rust runtime): the five FMUs of the
             .ssp in one FMI 2.0 co-simulation FMU built here from the SSD (one container
             connection per array, e.g. the 168 sensor readings in one get/set pair; the SSD's
             parameter bindings as container parameters; the optics outputs exposed), run by
             `fmpy.simulate_fmu(container, stop_time, step_size, output=[...])`, with
             parallelDoStep False and True (the latter in a child process, since fmpy 0.3.32's
             runtime aborts there); timed around the call (extraction included).

Agreement is checked before any timing (optics outputs, max |difference| over each column's
largest magnitude, at most --rtol):
  - fmpy.ssp starts every connection at 0 and records the state after the step from t at t:
    our run with `--zero-start`, fmpy.ssp's row k against our row k + 1;
  - the container copies every connection in exitInitializationMode, before the components
    leave initialisation (so the first step sees the FMUs' initial outputs, as our master does
    without --zero-start), then in each fixed step calls every doStep and only afterwards copies
    the connections (Jacobi, whatever parallelDoStep), and fmpy.simulate_fmu records the state
    after the step from t at t + h: our default-start Jacobi run, row for row.

Timing: each method on the full run and on a one-step run (its set-up), best of --repeat; the
difference over the remaining steps is the step loop's cost. Our Gauss-Seidel order (the default
of `m1cs run`; other numbers) is timed for scale. Measured on an idle 2-core machine (0.5 s, 500
steps): ours 0.21 s whole command / 0.17 s wall_seconds (~0.15 ms per step), the container 0.22 s
(~0.16 ms per step, 1.0x), fmpy.ssp 2.3 s (~4.2 ms per step, 13x the whole command, 32x per step).

Usage: .venv/bin/python benches/master_vs_fmpy.py [--stop 0.5] [--step 1e-3] [--repeat 3]
Build first: cargo build --release -p m1cs && cargo xtask package keck
"""

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
M1CS = ROOT / "target" / "release" / "m1cs"
FMU_DIR = Path(os.environ.get("M1CS_FMU_DIR", ROOT / "target" / "fmu"))
OPTICS = ["optics.rms_surface", "optics.focus_mode", "optics.rms_surface_without_focus",
          "optics.pssn"]
SSD_NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
          "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues"}


# ---------------------------------------------------------------------------------------------
# The system and our master


def write_ssp(path, stop, step, fmu_dir=FMU_DIR):
    """`m1cs system --layout keck --scenario vibration --uniform` into `path`."""
    subprocess.run([str(M1CS), "system", "--layout", "keck", "--scenario", "vibration",
                    "--uniform", "--step", repr(step), "--duration", repr(stop),
                    "--fmu-dir", str(fmu_dir), "-o", str(path)], check=True,
                   stdout=subprocess.DEVNULL)
    return path


def run_ours(ssp, out, zero_start, order="jacobi"):
    """`m1cs run --ssp` (Jacobi order unless told), every step recorded: (command wall s, run
    JSON, CSV columns by name)."""
    cmd = [str(M1CS), "run", "--ssp", str(ssp), "--order", order, "--decimation", "1",
           "--out", str(out), "--json"] + (["--zero-start"] if zero_start else [])
    t0 = time.perf_counter()
    r = subprocess.run(cmd, check=True, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    run = json.loads(r.stdout)["runs"][0]
    with open(Path(out) / "system.csv") as f:
        rows = list(csv.reader(f))
    data = np.array(rows[1:], dtype=float)
    return wall, run, {name: data[:, k] for k, name in enumerate(rows[0])}


# ---------------------------------------------------------------------------------------------
# fmpy's container FMU, built from the SSD


def _base(connector):
    """`z[17]` -> `z`."""
    return connector.split("[", 1)[0]


def read_ssd(ssp, unzipdir):
    """Extracts the .ssp into `unzipdir`: (components as (name, FMU path), connections as
    (startElement, startConnector, endElement, endConnector) in file order, parameter bindings as
    (component, name, SSV type, value literal))."""
    with zipfile.ZipFile(ssp) as z:
        z.extractall(unzipdir)
    root = ET.parse(Path(unzipdir) / "SystemStructure.ssd").getroot()
    system = root.find("ssd:System", SSD_NS)
    components, bindings = [], []
    for c in system.find("ssd:Elements", SSD_NS).findall("ssd:Component", SSD_NS):
        components.append((c.get("name"), Path(unzipdir) / c.get("source")))
        for p in c.iterfind(".//ssv:Parameter", SSD_NS):
            value = p[0]  # ssv:Real / ssv:Integer / ssv:Boolean / ssv:String
            kind = value.tag.split("}", 1)[1]
            bindings.append((c.get("name"), p.get("name"), kind, value.get("value")))
    connections = [(c.get("startElement"), c.get("startConnector"), c.get("endElement"),
                    c.get("endConnector"))
                   for c in system.find("ssd:Connections", SSD_NS).findall("ssd:Connection",
                                                                              SSD_NS)]
    return components, connections, bindings


def build_container(ssp, workdir, step, parallel, outputs=OPTICS, bind_parameters=True):
    """fmpy's container FMU of the system in `ssp`: returns its path.

    Each run of SSD connections between the same pair of components and the same two arrays
    (e.g. the 168 `sensors.y[i] -> controller.y[i]`) becomes one container connection with the
    lists of connectors, moved by one fmi2GetReal and one fmi2SetReal. `outputs` (component.var)
    become container outputs; the SSD's parameter bindings become container parameters whose
    start values the runtime sets right after instantiating the components.
    """
    from fmpy import read_model_description
    from fmpy.container_fmu.cli import create_container_fmu
    from fmpy.container_fmu.config import Component, Configuration, Connection
    from fmpy.model_description import (CoSimulation, DefaultExperiment, ModelDescription,
                                        ModelVariable, Unknown)

    workdir = Path(workdir)
    components, connections, bindings = read_ssd(ssp, workdir / "ssp")
    comp, variables = {}, {}
    for name, path in components:
        md = read_model_description(str(path))
        if md.fmiVersion != "2.0" or md.coSimulation is None:
            raise ValueError(f"{name}: the container is built for FMI 2.0 co-simulation here")
        comp[name] = Component(name=name, filename=path, modelDescription=md)
        variables[name] = {v.name: v for v in md.modelVariables}
    stems = [p.stem for _, p in components]
    if len(set(stems)) != len(stems):  # the runtime extracts each FMU to resources/<stem>
        raise ValueError(f"two components share an FMU file name: {stems}")

    groups = []  # [key, [start vars], [end vars]]
    for se, sc, ee, ec in connections:
        sv, ev = variables[se][sc], variables[ee][ec]
        if sv.type != "Real" or ev.type != "Real":
            raise ValueError(f"{se}.{sc} -> {ee}.{ec}: only Real connections are built here")
        key = (se, _base(sc), ee, _base(ec))
        if groups and groups[-1][0] == key:
            groups[-1][1].append(sv)
            groups[-1][2].append(ev)
        else:
            groups.append([key, [sv], [ev]])
    # fmpy 0.3.32's write_configuration copies a connection's type from its first start
    # connector ("Real" for FMI 2.0), but the runtime only knows the FMI 3.0 names ("Float64")
    # and refuses to instantiate ("unknown variant `Real`"): give it connectors typed Float64
    # (only their type, value reference and shape are read).
    def as_float64(v):
        return ModelVariable(name=v.name, valueReference=v.valueReference, type="Float64",
                             causality=v.causality, variability=v.variability)

    container_connections = [Connection(comp[k[0]], [as_float64(v) for v in s], comp[k[2]],
                                        [as_float64(v) for v in e]) for k, s, e in groups]

    mappings = {}  # container variable -> [(component, component variable)], in VR order
    ssv_type = {"Real": "Real", "Integer": "Integer", "Boolean": "Boolean", "String": "String"}
    if bind_parameters:
        for c, p, kind, value in bindings:
            target = variables[c][p]
            if ssv_type.get(kind) != target.type or target.type == "String":
                raise ValueError(f"binding {c}.{p} ({kind}) on a {target.type} variable")
            v = ModelVariable(name=f"{c}.{p}", type=target.type, causality="parameter",
                              variability=target.variability, initial="exact", start=value)
            mappings[v] = [(comp[c], target)]
    outs = []
    for o in outputs:
        c, p = o.split(".", 1)
        v = ModelVariable(name=o, type="Real", causality="output",
                          variability=variables[c][p].variability, initial="calculated")
        mappings[v] = [(comp[c], variables[c][p])]
        outs.append(v)

    # The runtime serves VR 0 as the time and VR i (i >= 1) as the i-th entry of
    # variableMappings; create_container_fmu numbers modelVariables 0, 1, 2, ...: so the time
    # comes first and the mapped variables follow in the mappings' order.
    model_variables = [ModelVariable(name="time", type="Real", causality="independent",
                                     variability="continuous")] + list(mappings)
    md = ModelDescription(
        fmiVersion="2.0",
        modelName="keck_vibration_container",
        instantiationToken="{" + str(uuid.uuid4()) + "}",
        coSimulation=CoSimulation(modelIdentifier="container_fmu", fixedInternalStepSize=step,
                                  canHandleVariableCommunicationStepSize=True),
        defaultExperiment=DefaultExperiment(startTime="0", stepSize=repr(step)),
        modelVariables=model_variables,
    )
    md.outputs = [Unknown(variable=v) for v in outs]
    md.initialUnknowns = [Unknown(variable=v) for v in outs]
    config = Configuration(parallelDoStep=parallel, modelDescription=md,
                           components=[comp[n] for n, _ in components],
                           connections=container_connections, variableMappings=mappings)
    unzipdir = workdir / ("container_par" if parallel else "container_seq")
    unzipdir.mkdir(parents=True, exist_ok=True)
    fmu = workdir / (unzipdir.name + ".fmu")
    create_container_fmu(config, unzipdir, fmu)
    return fmu


def run_container(fmu, stop, step, outputs=OPTICS):
    """fmpy.simulate_fmu on the container, a communication point (and a row) every `step`:
    (wall s, result array). For co-simulation fmpy ignores step_size: it steps at
    output_interval, by default the fixedInternalStepSize doubled until at most 1000 intervals
    remain (2 ms for a 2 s run), hence the explicit output_interval."""
    from fmpy import simulate_fmu
    t0 = time.perf_counter()
    res = simulate_fmu(str(fmu), stop_time=stop, step_size=step, output_interval=step,
                       output=list(outputs))
    return time.perf_counter() - t0, res


def run_container_isolated(fmu, stop, step, workdir):
    """run_container in a child process, because a runtime that panics (fmpy 0.3.32's
    container_fmu.so with parallelDoStep: `todo!()` in Container::doStep, a panic that cannot
    unwind through fmi2DoStep) aborts the whole interpreter. Returns (wall s or None, result or
    None, the child's error output when it failed)."""
    npz = Path(workdir) / (Path(fmu).stem + "_result.npz")
    r = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child-container",
                        str(fmu), "--child-out", str(npz), "--stop", repr(stop), "--step",
                        repr(step)], capture_output=True, text=True)
    if r.returncode != 0:
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        panic = [ln for ln in lines if "panicked" in ln or "not yet implemented" in ln]
        why = " / ".join(panic[:2] or lines[-2:])
        return None, None, f"child exited with {r.returncode}: {why}"
    with np.load(npz) as z:
        res = {k: z[k] for k in z.files}
    return float(r.stdout.strip().splitlines()[-1]), res, ""


def _only_ssd_connections(get_connections):
    """fmpy.ssp.ssd.get_connections without its stale-variable bug: for each input connector it
    searches the SSD's connections and appends (connectors[start_p], input) after the loop even
    when none matched, so an unconnected input is wired to the start of the previous connected
    input (FMPy issue #690). Here: every unconnected sensors.w[i] <- mirror.z[108],
    mirror.f_wind[i] <- controller.u_cmd[108], controller.y_ref[i] <- sensors.y[168] (877 pairs for
    493 connections). The wrapper keeps only the pairs that are connections of the SSD."""

    def fixed(system, connectors=None):
        pairs = get_connections(system, connectors)
        real = set()
        for c in system.connections:
            a, b = f"{c.startElement}.{c.startConnector}", f"{c.endElement}.{c.endConnector}"
            real.update({(a, b), (b, a)})
        return [(a, b) for a, b in pairs if (a.path, b.path) in real]

    return fixed


def run_fmpy_ssp(ssp, stop, step, fixed=False):
    """fmpy.ssp.simulate_ssp, as shipped or (fixed=True) with only the SSD's connections (the
    same FMI calls either way: it sets every input connector before every doStep)."""
    import fmpy.ssp.simulation as sim
    stock = sim.get_connections
    if fixed:
        sim.get_connections = _only_ssd_connections(stock)
    try:
        t0 = time.perf_counter()
        res = sim.simulate_ssp(str(ssp), stop_time=stop, step_size=step)
        return time.perf_counter() - t0, res
    finally:
        sim.get_connections = stock


# ---------------------------------------------------------------------------------------------
# Agreement


def compare(ours, theirs, columns, offset, step):
    """Largest |difference| / max|ours| per column, with `theirs` row k against our row
    k + offset (times checked); also the number of rows compared."""
    n = min(len(theirs["time"]), len(ours["time"]) - offset)
    dt = np.max(np.abs(theirs["time"][:n] + offset * step - ours["time"][offset:offset + n]))
    # A row out of place would be a whole step off; fmpy adds the step to its time at every
    # step, which drifts by about 1e-12 s over 10,000 steps.
    if dt > 1e-6 * step:
        raise AssertionError(f"time columns disagree by {dt} s with a row offset of {offset}")
    errs = {}
    for name in columns:
        a, b = np.asarray(theirs[name][:n], float), ours[name][offset:offset + n]
        scale = np.max(np.abs(b))
        if not scale > 0.0:
            raise AssertionError(f"{name} stays zero: the comparison would be vacuous")
        errs[name] = float(np.max(np.abs(a - b)) / scale)
    return errs, n


def check_container(ssp, workdir, stop, step, rtol=1e-9, parallel=(False, True), log=print):
    """Builds and runs the container (each parallelDoStep setting; the parallel one in a child
    process) against our default-start Jacobi run; raises AssertionError on disagreement.
    Returns {parallel: container path, or None when that runtime cannot run it}."""
    _, _, ours = run_ours(ssp, Path(workdir) / "ours_default_start", zero_start=False)
    out = {}
    for par in parallel:
        fmu = build_container(ssp, workdir, step, par)
        if par:
            _, res, err = run_container_isolated(fmu, stop, step, workdir)
            if res is None:
                log(f"  container (parallelDoStep=True): cannot run: {err}")
                out[par] = None
                continue
        else:
            _, res = run_container(fmu, stop, step)
        if len(res["time"]) != len(ours["time"]):
            raise AssertionError(f"container: {len(res['time'])} rows, ours {len(ours['time'])}")
        errs, n = compare(ours, res, OPTICS, 0, step)
        log(f"  container (parallelDoStep={par}) vs ours (Jacobi, initial outputs), row k vs "
            f"row k, {n} rows: max rel. diff " + ", ".join(f"{k.split('.')[1]} {e:.1e}"
                                                            for k, e in errs.items()))
        bad = {k: e for k, e in errs.items() if e > rtol}
        if bad:
            raise AssertionError(f"container (parallelDoStep={par}) disagrees: {bad}")
        out[par] = fmu
    return out


def check_fmpy_ssp(ssp, workdir, stop, step, rtol=1e-9, log=print):
    """fmpy.ssp against our --zero-start Jacobi run: as shipped (reported: it rewires the
    unconnected inputs) and with only the SSD's connections (required to agree)."""
    _, _, ours = run_ours(ssp, Path(workdir) / "ours_zero_start", zero_start=True)
    out = {}
    for fixed in (False, True):
        _, res = run_fmpy_ssp(ssp, stop, step, fixed=fixed)
        errs, n = compare(ours, res, OPTICS, 1, step)
        label = "fmpy.ssp, only the SSD's connections" if fixed else "fmpy.ssp as shipped"
        log(f"  {label} vs ours (Jacobi, --zero-start), its row k vs our row k+1, {n} rows: max "
            "rel. diff " + ", ".join(f"{k.split('.')[1]} {e:.1e}" for k, e in errs.items()))
        bad = {k: e for k, e in errs.items() if e > rtol}
        if bad and not fixed:
            a, b = res["optics.rms_surface"][:n], ours["optics.rms_surface"][1:n + 1]
            k = int(np.argmax(np.abs(a - b) > rtol * np.max(np.abs(b))))
            log(f"    (differs from t = {ours['time'][k + 1]:.3f} s, when the controller's first "
                "sample reaches the optics: fmpy.ssp wires the unconnected inputs to other outputs,"
                " FMPy issue #690)")
        elif bad:
            raise AssertionError(f"fmpy.ssp (only the SSD's connections) disagrees: {bad}")
        out[fixed] = errs
    return out


# ---------------------------------------------------------------------------------------------


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stop", type=float, default=0.5, help="stop time (s)")
    ap.add_argument("--step", type=float, default=1e-3, help="communication step (s)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each, best kept")
    ap.add_argument("--rtol", type=float, default=1e-9, help="agreement required")
    ap.add_argument("--keep", action="store_true", help="keep the work folder")
    ap.add_argument("--child-container", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child_container:  # run_container_isolated's child: the wall time on stdout
        wall, res = run_container(a.child_container, a.stop, a.step)
        np.savez(a.child_out, **{k: res[k] for k in res.dtype.names})
        print(repr(wall))
        return
    for p in (M1CS, FMU_DIR / "keck" / "mirror_voicecoil.fmu"):
        if not p.exists():
            sys.exit(f"{p} is missing: cargo build --release -p m1cs && cargo xtask package keck")

    tmp = Path(tempfile.mkdtemp(prefix="master-vs-fmpy-"))
    try:
        ssp = write_ssp(tmp / "keck_vibration.ssp", a.stop, a.step)
        steps = round(a.stop / a.step)
        print(f"Keck pier-vibration system, {a.stop} s at {a.step} s ({steps} steps); agreement:")
        check_fmpy_ssp(ssp, tmp, a.stop, a.step, a.rtol)
        containers = check_container(ssp, tmp, a.stop, a.step, a.rtol)

        # Timing: every method on the full run and on a one-step run (its set-up: extraction,
        # instantiation, initialisation, and for ours process start and the output files), best
        # of --repeat each; the difference over the remaining steps is the step loop's cost.
        one = write_ssp(tmp / "one_step.ssp", a.step, a.step)

        def round_(system, stop):
            t = {}
            for key, zero, order in (("ours", False, "jacobi"), ("ours0", True, "jacobi"),
                                     ("gs", False, "gauss-seidel")):
                w, run, _ = run_ours(system, tmp / ("t_" + key), zero_start=zero, order=order)
                t[key + "_cmd"], t[key + "_run"] = w, run["wall_seconds"]
            t["ssp"] = run_fmpy_ssp(system, stop, a.step)[0]
            t["ssp_fixed"] = run_fmpy_ssp(system, stop, a.step, fixed=True)[0]
            t["cont_seq"] = run_container(containers[False], stop, a.step)[0]
            if containers.get(True) is not None:
                t["cont_par"] = run_container_isolated(containers[True], stop, a.step, tmp)[0]
            return t

        full = [round_(ssp, a.stop) for _ in range(a.repeat)]
        setup = [round_(one, a.step) for _ in range(a.repeat)]
        b = {k: min(r[k] for r in full) for k in full[0]}
        s1 = {k: min(r[k] for r in setup) for k in setup[0]}
        rows = (("ours (Jacobi), whole `m1cs run`", "ours_cmd"),
                ("ours (Jacobi), run wall_seconds", "ours_run"),
                ("ours (Jacobi, --zero-start), whole", "ours0_cmd"),
                ("ours (Jacobi, --zero-start), run", "ours0_run"),
                ("fmpy.ssp as shipped", "ssp"),
                ("fmpy.ssp, SSD connections only", "ssp_fixed"),
                ("container, parallelDoStep=False", "cont_seq"),
                ("container, parallelDoStep=True", "cont_par"),
                ("ours (Gauss-Seidel)*, whole", "gs_cmd"),
                ("ours (Gauss-Seidel)*, run", "gs_run"))
        print(f"Wall times, best of {a.repeat} (set-up: the same on a one-step run; loop: the "
              f"difference over {steps - 1} steps):")
        print(f"  {'':38s} {'total s':>8s} {'set-up s':>9s} {'loop ms/step':>13s}")
        for label, k in rows:
            if k not in b:
                print(f"  {label:38s} {'cannot run, see above':>32s}")
                continue
            per = (b[k] - s1[k]) / max(steps - 1, 1) * 1e3
            loop = f"{per:13.3f}" if per > 0 else f"{'(in noise)':>13s}"
            print(f"  {label:38s} {b[k]:8.3f} {s1[k]:9.3f} {loop}")
        print("  * other numbers (one delay less per connection): our default order, for scale")
        print("Ratios, theirs / ours (fmpy.ssp against our --zero-start run, the container against"
              " our default-start run):")
        print(f"  {'':32s} {'/ whole command':>16s} {'/ wall_seconds':>15s} {'loop / loop':>12s}")
        for label, k, ref in (("fmpy.ssp as shipped", "ssp", "ours0"),
                              ("fmpy.ssp, SSD connections only", "ssp_fixed", "ours0"),
                              ("container, parallelDoStep=False", "cont_seq", "ours"),
                              ("container, parallelDoStep=True", "cont_par", "ours")):
            if k in b:
                theirs, ours = b[k] - s1[k], b[ref + "_run"] - s1[ref + "_run"]
                loop = f"{theirs / ours:11.2f}x" if theirs > 0 and ours > 0 else "   (in noise)"
                print(f"  {label:32s} {b[k] / b[ref + '_cmd']:15.1f}x"
                      f" {b[k] / b[ref + '_run']:14.1f}x {loop}")
    finally:
        if a.keep:
            print(f"work folder kept: {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
