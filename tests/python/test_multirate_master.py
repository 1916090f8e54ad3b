"""Our master against an independent multi-rate master written here over fmpy's FMU2Slave, on
the same .ssp: the Keck pier-vibration system (pier -> mirror, edge sensors, global controller,
optics) written by `m1cs system` without --uniform, so the controller steps every 50 base steps
and the others every base step (the rates come from the .ssp's `org.m1cs.master` annotation).
Both run 0.2 s; every recorded column agrees to 1e-12 relative on every row, in Jacobi and in
Gauss-Seidel order. The same comparison on the system written with --uniform (every rate 1)
checks the reference master itself on single-rate timing.

The reference master's rules (base step h, t_k = t0 + k h; component c steps every N_c base
steps: at base step k when k % N_c == 0, over N_c h cut so it ends at the stop time):
- set-up: instantiate, setupExperiment(t0, stop), parameter bindings, enterInitializationMode;
  every connected input set from its source's output (getReal in initialisation mode), in the
  topological order of the outputs' direct dependencies (ModelStructure/Outputs), so an input
  is set after the inputs its source's output depends on; exitInitializationMode; the outputs
  then read are stamped t0;
- the outputs read after doStep(t, H) are stamped t + H;
- Jacobi: a component stepping at t_k gets each source's newest outputs stamped <= t_k;
- Gauss-Seidel: the due components step in the .ssp's component order, each on the newest
  outputs stamped <= t_k + h among those computed so far (so a slower component's outputs of
  doStep(t, N h) reach the others in the base step that ends at t + N h, not earlier);
- row k (time t_k) shows each recorded output's newest value stamped <= t_k.
Stamps are kept as base-step counts (exact integers), not as floating-point times.

Not vacuous: every compared column is nonzero and varies in time; the controller's commands
are nonzero, and disabling it changes the columns from the arrival of its first command on;
and the previous hand-over rule of our master (a slower component's outputs stamped one base
step after its step starts) moves the columns by far more than the tolerance.

Format notes: the writer binds parameters inline (ssv:ParameterValues inside the
ssd:ParameterBinding); a `source` .ssv file inside the archive is read as well. Connections are
per scalar (`u_cmd[1]` ...). fmpy's read_model_description keeps `dependencies` None when the
attribute is absent (depends on every input) and [] when it is empty (no direct dependency):
the two are told apart here.
"""
import csv
import json
import posixpath
import subprocess
import xml.etree.ElementTree as ET
import zipfile
from urllib.parse import unquote, urlparse

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from conftest import FMU_DIR, ROOT

M1CS = ROOT / "target" / "release" / "m1cs"
STEP = 1e-3
DURATION = 0.2
REL = 1e-12
ABS = 1e-21

NS = {
    "ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
    "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
    "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
}
ANNOTATION = "org.m1cs.master"


# ---------------------------------------------------------------------------------------------
# Reading the .ssp


def _local(tag):
    return tag.rsplit("}", 1)[-1]


def _ssv_parameters(set_element):
    """(name, type, text value) of every ssv:Parameter under an ssv:ParameterSet."""
    out = []
    for p in set_element.iter(f"{{{NS['ssv']}}}Parameter"):
        typed = [c for c in p if _local(c.tag) in ("Real", "Integer", "Boolean", "String",
                                                    "Enumeration")]
        assert len(typed) == 1, f"parameter {p.get('name')}: one typed value expected"
        out.append((p.get("name"), _local(typed[0].tag), typed[0].get("value")))
    return out


def _archive_member(ssd_dir, source):
    """Member name of a relative URI reference inside the archive."""
    u = urlparse(source)
    assert not u.scheme and not u.netloc, f"only archive-relative sources here: {source}"
    return posixpath.normpath(posixpath.join(ssd_dir, unquote(u.path)))


def read_ssp(path):
    """The system of an .ssp: components (name, FMU member, parameters, every), connections,
    start and stop time, base step and the file's order."""
    with zipfile.ZipFile(path) as z:
        ssd_name = "SystemStructure.ssd"
        root = ET.fromstring(z.read(ssd_name))
        ssd_dir = posixpath.dirname(ssd_name)
        system = root.find("ssd:System", NS)
        assert system is not None
        elements = system.find("ssd:Elements", NS)
        assert elements.find("ssd:System", NS) is None, "nested systems are not handled here"
        components = []
        for c in elements.findall("ssd:Component", NS):
            assert c.get("type", "application/x-fmu-sharedlibrary") == \
                "application/x-fmu-sharedlibrary"
            params = []
            for b in c.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS):
                assert not b.get("prefix"), "prefixed parameter bindings are not handled here"
                if b.get("source"):
                    doc = ET.fromstring(z.read(_archive_member(ssd_dir, b.get("source"))))
                    params += _ssv_parameters(doc)
                for values in b.findall("ssd:ParameterValues", NS):
                    params += _ssv_parameters(values)
            components.append({"name": c.get("name"),
                               "member": _archive_member(ssd_dir, c.get("source")),
                               "parameters": params, "every": 1})
        connections = []
        for c in system.findall("ssd:Connections/ssd:Connection", NS):
            assert c.get("startElement") and c.get("endElement"), "system connectors unused here"
            connections.append((c.get("startElement"), c.get("startConnector"),
                                c.get("endElement"), c.get("endConnector")))
        experiment = root.find("ssd:DefaultExperiment", NS)
        t0 = float(experiment.get("startTime", "0"))
        stop = float(experiment.get("stopTime"))
        step, order = None, "jacobi"
        by_name = {c["name"]: c for c in components}
        for a in root.iter(f"{{{NS['ssc']}}}Annotation"):
            if a.get("type") != ANNOTATION:
                continue
            master = a.find("Master")
            step = float(master.get("step"))
            order = master.get("order", "jacobi")
            for r in master.findall("Rate"):
                by_name[r.get("component")]["every"] = int(r.get("every"))
        assert step is not None, "the .ssp has no master annotation"
        return {"components": components, "connections": connections, "t0": t0,
                "stop": stop, "step": step, "order": order}


# ---------------------------------------------------------------------------------------------
# The reference master


class Component:
    def __init__(self, spec, fmu_file, unzip_dir):
        self.name = spec["name"]
        self.every = spec["every"]
        self.md = read_model_description(str(fmu_file))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.dir = extract(str(fmu_file), unzipdir=str(unzip_dir))
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.dir,
                             modelIdentifier=self.md.coSimulation.modelIdentifier,
                             instanceName=self.name)
        outs = [v for v in self.md.modelVariables if v.causality == "output"]
        assert all(v.type == "Real" for v in outs), f"{self.name}: non-Real outputs"
        self.out_names = [v.name for v in outs]
        self.out_vrs = [v.valueReference for v in outs]
        self.out_pos = {n: i for i, n in enumerate(self.out_names)}
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
        # Direct dependencies of each output on inputs: None in the file means all of them.
        self.depends = {}
        for u in self.md.outputs:
            deps = self.inputs if u.dependencies is None else \
                [d.name for d in u.dependencies if d.causality == "input"]
            self.depends[u.variable.name] = deps
        # (stamp in base steps, output values), newest last
        self.history = []
        # Connected inputs: (input value reference, source component, source output position)
        self.wires = []

    def set_parameter(self, name, kind, text):
        v = self.vars[name]
        vr = [v.valueReference]
        if kind == "Real":
            assert v.type == "Real", name
            self.fmu.setReal(vr, [float(text)])
        elif kind in ("Integer", "Enumeration"):
            self.fmu.setInteger(vr, [int(text)])
        elif kind == "Boolean":
            assert text in ("true", "false", "1", "0"), (name, text)
            self.fmu.setBoolean(vr, [text in ("true", "1")])
        else:
            self.fmu.setString(vr, [text])

    def newest(self, limit):
        """The newest outputs stamped <= limit (base steps)."""
        for stamp, values in reversed(self.history):
            if stamp <= limit:
                return values
        raise AssertionError(f"{self.name}: no outputs stamped <= {limit}")

    def read_outputs(self, stamp):
        self.history.append((stamp, np.array(self.fmu.getReal(self.out_vrs))))

    def set_inputs(self, limit):
        if self.wires:
            vrs = [w[0] for w in self.wires]
            values = [float(src.newest(limit)[pos]) for _, src, pos in self.wires]
            self.fmu.setReal(vrs, values)


def reference_master(ssp, order, columns, workdir, overrides=None, early_hand_over=False):
    """Runs `ssp` by the rules of the module docstring; returns the times, per column
    ("component.output") the recorded values at every base step (row 0 = t0), and the
    controller's u_cmd as seen at every base step (rows of the same stamps).

    `overrides`: {component: {parameter: (type, text)}} set after the file's bindings.
    `early_hand_over`: the previous rule of our master, for the sensitivity test only: a slower
    component's outputs of doStep(t_k, N h) are stamped t_k + h instead of t_k + N h."""
    spec = read_ssp(ssp)
    workdir.mkdir(parents=True, exist_ok=True)
    comps = []
    with zipfile.ZipFile(ssp) as z:
        for i, s in enumerate(spec["components"]):
            fmu_file = workdir / f"{i}_{posixpath.basename(s['member'])}"
            fmu_file.write_bytes(z.read(s["member"]))
            comps.append(Component(s, fmu_file, workdir / f"{i}_unzipped"))
    by_name = {c.name: c for c in comps}
    h, t0, stop = spec["step"], spec["t0"], spec["stop"]
    n_steps = int(round((stop - t0) / h))
    assert abs(t0 + n_steps * h - stop) <= 1e-9 * h, "stop time is not a whole number of steps"

    wires = []  # (destination, input name, source, output name)
    for src, out, dst, inp in spec["connections"]:
        s, d = by_name[src], by_name[dst]
        assert inp in d.vars and d.vars[inp].causality == "input", (dst, inp)
        assert out in s.out_pos, (src, out)
        wires.append((d, inp, s, out))
        d.wires.append((d.vars[inp].valueReference, s, s.out_pos[out]))
    assert len({(w[0].name, w[1]) for w in wires}) == len(wires), "an input fed twice"

    try:
        for c in comps:
            c.fmu.instantiate()
            c.fmu.setupExperiment(startTime=t0, stopTime=stop)
        for s, c in zip(spec["components"], comps):
            for name, kind, text in s["parameters"]:
                c.set_parameter(name, kind, text)
            for name, (kind, text) in (overrides or {}).get(c.name, {}).items():
                c.set_parameter(name, kind, text)
            c.fmu.enterInitializationMode()

        # Initial values through the direct-feedthrough dependencies, in topological order:
        # an input is set once every connected input its source's output depends on is set.
        connected = {(d.name, inp) for d, inp, _, _ in wires}
        done, pending = set(), list(wires)

        def propagate(w):
            d, inp, s, out = w
            value = s.fmu.getReal([s.vars[out].valueReference])[0]
            d.fmu.setReal([d.vars[inp].valueReference], [value])
            done.add((d.name, inp))

        progress = True
        while pending and progress:
            progress = False
            for w in list(pending):
                _, _, s, out = w
                needed = [(s.name, i) for i in s.depends[out] if (s.name, i) in connected]
                if all(n in done for n in needed):
                    propagate(w)
                    pending.remove(w)
                    progress = True
        for w in pending:  # an algebraic loop: whatever its sources give now
            propagate(w)

        for c in comps:
            c.fmu.exitInitializationMode()
        for c in comps:
            c.read_outputs(0)

        # Gauss-Seidel sees what ends by the end of this base step, Jacobi what ends by its start.
        lookahead = {"jacobi": 0, "gauss-seidel": 1}[order]
        for k in range(n_steps):
            t = t0 + k * h
            for c in comps:
                if k % c.every:
                    continue
                end = min(k + c.every, n_steps)
                size = c.every * h if end == k + c.every else stop - t
                c.set_inputs(k + lookahead)
                c.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=size)
                c.read_outputs(k + 1 if early_hand_over else end)

        times = np.array([t0 + k * h for k in range(n_steps + 1)])
        record = {}
        for col in columns:
            cname, out = col.split(".", 1)
            c = by_name[cname]
            pos = c.out_pos[out]
            record[col] = np.array([c.newest(k)[pos] for k in range(n_steps + 1)])
        ctrl = by_name["controller"]
        u_pos = [i for i, n in enumerate(ctrl.out_names) if n.startswith("u_cmd[")]
        u_cmd = np.array([ctrl.newest(k)[u_pos] for k in range(n_steps + 1)])
        return times, record, u_cmd
    finally:
        for c in comps:
            try:
                c.fmu.terminate()
            finally:
                c.fmu.freeInstance()


# ---------------------------------------------------------------------------------------------
# Our master


def write_system(path, uniform):
    args = [str(M1CS), "system", "--layout", "keck", "--scenario", "vibration",
            "--step", str(STEP), "--duration", str(DURATION), "--fmu-dir", str(FMU_DIR),
            "-o", str(path)] + (["--uniform"] if uniform else [])
    subprocess.run(args, check=True, capture_output=True)


def run_ours(ssp, order, out):
    r = subprocess.run([str(M1CS), "run", "--ssp", str(ssp), "--order", order,
                        "--decimation", "1", "--out", str(out), "--json"],
                       check=True, capture_output=True, text=True)
    json.loads(r.stdout)
    with open(out / "system.csv") as f:
        rows = list(csv.reader(f))
    header, data = rows[0], np.array(rows[1:], dtype=float)
    assert header[0] == "time"
    return data[:, 0], {name: data[:, i] for i, name in enumerate(header) if i > 0}


@pytest.fixture(scope="module")
def systems(tmp_path_factory):
    if not M1CS.exists():
        pytest.fail(f"{M1CS} is missing: run `cargo build --release` first")
    d = tmp_path_factory.mktemp("multirate")
    out = {}
    for rates, uniform in (("multirate", False), ("uniform", True)):
        out[rates] = d / f"keck_vibration_{rates}.ssp"
        write_system(out[rates], uniform)
    return out


def max_rel_diff(a, b):
    """max|a-b| over the allowed error 1e-12 max|a| + 1e-21 (<= 1 passes)."""
    return np.max(np.abs(a - b)) / (REL * np.max(np.abs(a)) + ABS)


def test_the_ssp_is_multi_rate(systems):
    spec = read_ssp(systems["multirate"])
    every = {c["name"]: c["every"] for c in spec["components"]}
    assert every == {"pier": 1, "mirror": 1, "sensors": 1, "controller": 50, "optics": 1}
    assert spec["step"] == STEP and spec["t0"] == 0.0 and spec["stop"] == DURATION
    assert {c["every"] for c in read_ssp(systems["uniform"])["components"]} == {1}


@pytest.mark.parametrize("rates", ["multirate", "uniform"])
@pytest.mark.parametrize("order", ["jacobi", "gauss-seidel"])
def test_master_agrees_with_the_reference_master(systems, rates, order, tmp_path):
    ssp = systems[rates]
    t_ours, ours = run_ours(ssp, order, tmp_path / "ours")
    columns = list(ours)
    assert {"optics.rms_surface", "optics.focus_mode",
            "optics.rms_surface_without_focus"} <= set(columns)
    t_ref, ref, u = reference_master(ssp, order, columns, tmp_path / "reference")

    n_steps = int(round(DURATION / STEP))
    assert len(t_ours) == len(t_ref) == n_steps + 1
    assert np.max(np.abs(t_ours - t_ref)) <= 1e-15
    report = {}
    for col in columns:
        a, b = ref[col], ours[col]
        # Not vacuous: nonzero, and moving with the pier tone.
        assert np.max(np.abs(a)) > 0.0, f"{col} stays zero"
        assert np.ptp(a[1:]) > 1e-6 * np.max(np.abs(a)), f"{col} does not vary in time"
        report[col] = (max_rel_diff(a, b), np.max(np.abs(a - b)), np.max(np.abs(a)))
    bad = {c: r for c, r in report.items() if not r[0] <= 1.0}
    if bad:
        first = {c: int(np.argmax(np.abs(ref[c] - ours[c]) > REL * np.max(np.abs(ref[c])) + ABS))
                 for c in bad}
        pytest.fail(f"{rates}/{order}: (max|a-b| / allowed, max|a-b|, max|a|) {bad}; "
                    f"first row out of tolerance {first}")

    # The controller takes part: its commands are nonzero within the run (the 0.05 s sample
    # reaches the mirror at 0.1 s).
    assert np.max(np.abs(u)) > 0.0, "the controller never commands anything"


def test_the_controller_changes_the_mirror(systems, tmp_path):
    """The compared columns depend on the controller's commands (so on when the multi-rate
    hand-over delivers them): with the controller disabled they differ after 0.1 s, far beyond
    the tolerance, and agree exactly before its first nonzero command arrives."""
    ssp = systems["multirate"]
    cols = ["optics.rms_surface", "optics.focus_mode", "optics.rms_surface_without_focus"]
    _, on, u = reference_master(ssp, "jacobi", cols, tmp_path / "on")
    _, off, u_off = reference_master(ssp, "jacobi", cols, tmp_path / "off",
                                     overrides={"controller": {"enabled": ("Boolean", "false")}})
    first = int(np.argmax(np.any(u != 0.0, axis=1)))
    assert np.any(u[first] != 0.0) and first > 0
    assert np.max(np.abs(u_off)) == 0.0
    for c in cols:
        assert np.array_equal(on[c][:first + 1], off[c][:first + 1]), c
        assert max_rel_diff(on[c], off[c]) > 1e3, c


@pytest.mark.parametrize("order", ["jacobi", "gauss-seidel"])
def test_the_hand_over_time_is_observable(systems, order, tmp_path):
    """Handing the controller's outputs over one base step after its step starts (instead of
    when its step ends) moves every compared column by far more than the tolerance: the
    comparison above tells the two rules apart."""
    ssp = systems["multirate"]
    cols = ["optics.rms_surface", "optics.focus_mode", "optics.rms_surface_without_focus"]
    _, rule, _ = reference_master(ssp, order, cols, tmp_path / "rule")
    _, early, _ = reference_master(ssp, order, cols, tmp_path / "early", early_hand_over=True)
    for c in cols:
        assert max_rel_diff(rule[c], early[c]) > 1e3, c
