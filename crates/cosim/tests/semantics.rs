//! The master's semantics on a probe FMU (tests/fixtures/probe.c, plain C compiled with the
//! system C compiler at test time): the FMI timing of outputs in multi-rate systems, row by row
//! against closed forms; initialisation through direct-feedthrough chains and algebraic loops;
//! Integer, Boolean and String connections; a component that ends the simulation itself. The
//! first tests check the probe alone, through the importer, so that a failure further down is
//! the master's.
//!
//! The rules the master tests follow (times in base steps `h`, `t_k = k h`):
//! - outputs after `doStep(t, H)` carry the time `t + H`; the initial outputs the start time;
//! - Jacobi: a component stepping at base step `k` receives each source's latest outputs with
//!   time `<= t_k`;
//! - Gauss-Seidel (components step in the order added): the latest outputs with time
//!   `<= t_k + h` among those already computed (by components earlier in the order in this base
//!   step, or at earlier base steps);
//! - a recorded row at `t_k` shows each output's latest value with time `<= t_k`.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::Command;

use cosim::description::{Causality, Initial, Start, VarType};
use cosim::system::{Order, Results, System, Value, run};
use cosim::{CosimError, Fmu, Instance};

mod common;
use common::{FIXTURES, cc, zip_fmu};

/// The base step of the master tests (s).
const H: f64 = 0.01;

/// The probe's value references, per type (as in probe.c and probe.xml).
mod vr {
    pub const U: u32 = 0;
    pub const T_END: u32 = 1;
    pub const U_HELD: u32 = 2;
    pub const FT: u32 = 3;
    pub const GAIN: u32 = 4;
    pub const OFFSET: u32 = 5;
    pub const TERMINATE_AT: u32 = 6;
    pub const NI: u32 = 0;
    pub const COUNT: u32 = 1;
    pub const NI_FT: u32 = 2;
    pub const S_LEN: u32 = 3;
    pub const BI: u32 = 0;
    pub const ODD: u32 = 1;
    pub const B_HELD: u32 = 2;
    pub const SI: u32 = 0;
    pub const S_HELD: u32 = 1;
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("m1cs-cosim-semantics", name)
}

/// Compiles probe.c to a shared library in `dir`.
fn compile_probe(dir: &Path) -> PathBuf {
    common::compile_fixture(dir, "probe.c", &[])
}

fn probe_xml() -> String {
    std::fs::read_to_string(Path::new(FIXTURES).join("probe.xml")).unwrap()
}

/// The probe's model description without the unit of t_end. The timing tests connect t_end
/// (declared in s) into u (declared in m), which the master's unit check rightly refuses
/// (`units_are_still_checked` below); a missing unit at either end passes it.
fn probe_xml_without_t_end_unit() -> String {
    let xml = probe_xml();
    let t_end = "<Real start=\"0\" unit=\"s\"/>";
    assert_eq!(xml.matches(t_end).count(), 1, "the fixture changed");
    xml.replace(t_end, "<Real start=\"0\"/>")
}

/// A probe .fmu with model description `xml`, in a scratch directory of its own.
fn probe_fmu(name: &str, xml: &str) -> PathBuf {
    let dir = scratch(name);
    let so = compile_probe(&dir);
    let path = dir.join("probe.fmu");
    zip_fmu(
        &path,
        &[
            ("modelDescription.xml", xml.as_bytes().to_vec()),
            ("binaries/linux64/probe.so", std::fs::read(so).unwrap()),
        ],
    );
    path
}

/// The probe as the master tests use it (t_end without a unit).
fn probe(name: &str) -> PathBuf {
    probe_fmu(name, &probe_xml_without_t_end_unit())
}

// -------------------------------------------------------------------------------------------
// The probe alone, through the importer.
// -------------------------------------------------------------------------------------------

/// Every output of a probe instance, read through the four getters.
#[derive(Debug, Clone, PartialEq)]
struct Look {
    t_end: f64,
    u_held: f64,
    ft: f64,
    count: i32,
    ni_ft: i32,
    s_len: i32,
    odd: bool,
    b_held: bool,
    s_held: String,
}

fn look(p: &mut Instance) -> Look {
    let mut r = [0.0; 3];
    p.get_real(&[vr::T_END, vr::U_HELD, vr::FT], &mut r)
        .unwrap();
    let mut i = [0; 3];
    p.get_integer(&[vr::COUNT, vr::NI_FT, vr::S_LEN], &mut i)
        .unwrap();
    let mut b = [false; 2];
    p.get_boolean(&[vr::ODD, vr::B_HELD], &mut b).unwrap();
    let s = p.get_string(&[vr::S_HELD]).unwrap();
    Look {
        t_end: r[0],
        u_held: r[1],
        ft: r[2],
        count: i[0],
        ni_ft: i[1],
        s_len: i[2],
        odd: b[0],
        b_held: b[1],
        s_held: s[0].clone(),
    }
}

/// The model description says what probe.c does: types, causalities, value references, units,
/// initial, start values, and the outputs' dependencies (ft on u, ni_ft on ni, none else).
#[test]
fn probe_description_matches_the_c_code() {
    let path = probe_fmu("description", &probe_xml());
    let fmu = Fmu::open(&path).unwrap();
    let md = &fmu.description;
    assert_eq!(md.co_simulation.model_identifier, "probe");
    assert_eq!(md.guid, "{probe-0001}");
    use Causality::{Input, Output, Parameter};
    use VarType::{Boolean, Integer, Real, String as Str};
    let (exact, calc) = (Some(Initial::Exact), Some(Initial::Calculated));
    let table = [
        ("u", Real, Input, vr::U, Some("m"), None),
        ("t_end", Real, Output, vr::T_END, Some("s"), exact),
        ("u_held", Real, Output, vr::U_HELD, Some("m"), exact),
        ("ft", Real, Output, vr::FT, Some("m"), calc),
        ("gain", Real, Parameter, vr::GAIN, None, None),
        ("offset", Real, Parameter, vr::OFFSET, Some("m"), None),
        (
            "terminate_at",
            Real,
            Parameter,
            vr::TERMINATE_AT,
            Some("s"),
            None,
        ),
        ("ni", Integer, Input, vr::NI, None, None),
        ("count", Integer, Output, vr::COUNT, None, exact),
        ("ni_ft", Integer, Output, vr::NI_FT, None, calc),
        ("s_len", Integer, Output, vr::S_LEN, None, exact),
        ("bi", Boolean, Input, vr::BI, None, None),
        ("odd", Boolean, Output, vr::ODD, None, exact),
        ("b_held", Boolean, Output, vr::B_HELD, None, exact),
        ("si", Str, Input, vr::SI, None, None),
        ("s_held", Str, Output, vr::S_HELD, None, exact),
    ];
    assert_eq!(md.variables.len(), table.len());
    for (name, ty, causality, vref, unit, initial) in table {
        let v = md.variable_by_name(name).unwrap();
        assert_eq!(
            (
                v.var_type,
                v.causality,
                v.value_reference,
                v.unit.as_deref(),
                v.initial
            ),
            (ty, causality, vref, unit, initial),
            "{name}"
        );
    }
    let start = |n: &str| md.variable_by_name(n).unwrap().start.clone();
    assert_eq!(start("u"), Some(Start::Real(0.0)));
    assert_eq!(start("gain"), Some(Start::Real(1.0)));
    assert_eq!(start("offset"), Some(Start::Real(0.0)));
    assert_eq!(start("terminate_at"), Some(Start::Real(-1.0)));
    assert_eq!(start("ni"), Some(Start::Integer(0)));
    assert_eq!(start("bi"), Some(Start::Boolean(false)));
    assert_eq!(start("si"), Some(Start::String("none".into())));
    assert_eq!(start("s_held"), Some(Start::String("none".into())));
    assert_eq!(start("s_len"), Some(Start::Integer(4)));
    let idx = |n: &str| md.index_of(n).unwrap();
    let deps = |n: &str| {
        md.outputs
            .iter()
            .find(|u| u.variable == idx(n))
            .and_then(|u| u.dependencies.clone())
    };
    assert_eq!(md.outputs.len(), 9);
    for n in [
        "t_end", "u_held", "count", "s_len", "odd", "b_held", "s_held",
    ] {
        assert_eq!(deps(n), Some(vec![]), "{n}");
    }
    assert_eq!(deps("ft"), Some(vec![idx("u")]));
    assert_eq!(deps("ni_ft"), Some(vec![idx("ni")]));
    let initial: Vec<(usize, Option<Vec<usize>>)> = md
        .initial_unknowns
        .iter()
        .map(|u| (u.variable, u.dependencies.clone()))
        .collect();
    assert_eq!(
        initial,
        vec![
            (idx("ft"), Some(vec![idx("u"), idx("gain"), idx("offset")])),
            (idx("ni_ft"), Some(vec![idx("ni")])),
        ]
    );
}

/// Every variable behaves as documented in probe.c, driven through `Instance`: start values
/// (t_end is the start time), feedthrough in initialisation mode, held inputs and counts after
/// each step, errors for unknown references, outputs set, long strings, steps that do not
/// start where the last ended or end past the stop time, and the discarded step at
/// terminate_at.
#[test]
fn probe_variables_behave_as_documented() {
    let path = probe_fmu("direct", &probe_xml());
    let fmu = Fmu::open(&path).unwrap();
    let mut p = fmu.instantiate("p", false).unwrap();
    let mut other = fmu.instantiate("other", false).unwrap();
    p.setup_experiment(None, 0.5, Some(2.0)).unwrap();
    let start = Look {
        t_end: 0.5,
        u_held: 0.0,
        ft: 0.0,
        count: 0,
        ni_ft: 1,
        s_len: 4,
        odd: false,
        b_held: false,
        s_held: "none".into(),
    };
    assert_eq!(look(&mut p), start, "before initialisation");
    // Initialisation mode: inputs and parameters set, the feedthrough outputs follow at once,
    // the held values and the count do not.
    p.enter_initialization_mode().unwrap();
    p.set_real(&[vr::GAIN, vr::OFFSET], &[2.0, 1.0]).unwrap();
    p.set_real(&[vr::U], &[3.0]).unwrap();
    p.set_integer(&[vr::NI], &[4]).unwrap();
    p.set_boolean(&[vr::BI], &[true]).unwrap();
    p.set_string(&[vr::SI], &["abc"]).unwrap();
    let init = Look {
        ft: 7.0,
        ni_ft: 5,
        ..start.clone()
    };
    assert_eq!(look(&mut p), init, "in initialisation mode");
    let mut x = [0.0; 4];
    p.get_real(&[vr::U, vr::GAIN, vr::OFFSET, vr::TERMINATE_AT], &mut x)
        .unwrap();
    assert_eq!(x, [3.0, 2.0, 1.0, -1.0]);
    let mut n = [0];
    p.get_integer(&[vr::NI], &mut n).unwrap();
    assert_eq!(n, [4]);
    let mut b = [false];
    p.get_boolean(&[vr::BI], &mut b).unwrap();
    assert_eq!(b, [true]);
    assert_eq!(p.get_string(&[vr::SI]).unwrap(), ["abc"]);
    p.exit_initialization_mode().unwrap();
    assert_eq!(look(&mut p), init, "after initialisation");
    // First step: the held values are the inputs at its start.
    p.do_step(0.5, 0.25).unwrap();
    let first = Look {
        t_end: 0.75,
        u_held: 3.0,
        ft: 7.0,
        count: 1 + 4,
        ni_ft: 5,
        s_len: 3,
        odd: true,
        b_held: true,
        s_held: "abc".into(),
    };
    assert_eq!(look(&mut p), first, "after the first step");
    // New inputs: feedthrough at once, held values at the next step.
    p.set_real(&[vr::U], &[-1.0]).unwrap();
    p.set_integer(&[vr::NI], &[10]).unwrap();
    p.set_boolean(&[vr::BI], &[false]).unwrap();
    p.set_string(&[vr::SI], &["hello world"]).unwrap();
    assert_eq!(
        look(&mut p),
        Look {
            ft: -1.0,
            ni_ft: 11,
            ..first.clone()
        },
        "new inputs before the second step"
    );
    p.do_step(0.75, 0.5).unwrap();
    let second = Look {
        t_end: 1.25,
        u_held: -1.0,
        ft: -1.0,
        count: 2 + 10,
        ni_ft: 11,
        s_len: 11,
        odd: false,
        b_held: false,
        s_held: "hello world".into(),
    };
    assert_eq!(look(&mut p), second, "after the second step");
    // Unknown value references and outputs set are errors with the FMU's message.
    let errors = [
        (
            p.get_real(&[99], &mut [0.0]),
            "unknown Real value reference 99",
        ),
        (p.set_real(&[99], &[0.0]), "unknown Real value reference 99"),
        (
            p.get_integer(&[99], &mut [0]),
            "unknown Integer value reference 99",
        ),
        (
            p.set_integer(&[99], &[0]),
            "unknown Integer value reference 99",
        ),
        (
            p.get_boolean(&[99], &mut [false]),
            "unknown Boolean value reference 99",
        ),
        (
            p.set_boolean(&[99], &[false]),
            "unknown Boolean value reference 99",
        ),
        (
            p.get_string(&[99]).map(|_| ()),
            "unknown String value reference 99",
        ),
        (
            p.set_string(&[99], &["x"]),
            "unknown String value reference 99",
        ),
        (
            p.set_real(&[vr::T_END], &[0.0]),
            "Real value reference 1 is an output",
        ),
        (
            p.set_real(&[vr::FT], &[0.0]),
            "Real value reference 3 is an output",
        ),
        (
            p.set_integer(&[vr::COUNT], &[0]),
            "Integer value reference 1 is an output",
        ),
        (
            p.set_boolean(&[vr::ODD], &[true]),
            "Boolean value reference 1 is an output",
        ),
        (
            p.set_string(&[vr::S_HELD], &["x"]),
            "String value reference 1 is an output",
        ),
        (
            p.set_string(&[vr::SI], &["x".repeat(64).as_str()]),
            "si holds at most 63 characters, got 64",
        ),
    ];
    for (result, expected) in errors {
        let e = result.unwrap_err().to_string();
        assert!(e.contains(expected), "{e:?} lacks {expected:?}");
    }
    // A 63-character string fits.
    p.set_string(&[vr::SI], &["y".repeat(63).as_str()]).unwrap();
    p.set_string(&[vr::SI], &["hello world"]).unwrap();
    assert_eq!(look(&mut p), second, "the refused calls changed nothing");
    // Steps start where the last ended and end by the stop time (2.0).
    let e = p.do_step(1.0, 0.25).unwrap_err().to_string();
    assert!(
        e.contains("doStep from t = 1 but the last step ended at t = 1.25"),
        "{e}"
    );
    let e = p.do_step(1.25, 1.0).unwrap_err().to_string();
    assert!(e.contains("ends past the stop time 2"), "{e}");
    let e = p.do_step(1.25, 0.0).unwrap_err().to_string();
    assert!(e.contains("step size must be positive"), "{e}");
    p.do_step(1.25, 0.75).unwrap();
    assert_eq!(look(&mut p).t_end, 2.0);
    // Instances are independent.
    other.setup_experiment(None, 0.0, None).unwrap();
    assert_eq!(
        look(&mut other),
        Look {
            t_end: 0.0,
            ..start.clone()
        }
    );
    // fmi2Reset: back to the start values (the start time too).
    p.reset().unwrap();
    assert_eq!(
        look(&mut p),
        Look {
            t_end: 0.0,
            ..start.clone()
        }
    );
    // terminate_at: the step from 0.03 is discarded (with the FMU's message) and changes
    // nothing; any step after it is an error.
    let mut q = fmu.instantiate("q", false).unwrap();
    q.setup_experiment(None, 0.0, None).unwrap();
    q.enter_initialization_mode().unwrap();
    q.set_real(&[vr::TERMINATE_AT], &[0.03]).unwrap();
    q.exit_initialization_mode().unwrap();
    let mut t = 0.0;
    for _ in 0..3 {
        q.do_step(t, 0.01).unwrap();
        t += 0.01;
    }
    match q.do_step(t, 0.01) {
        Err(CosimError::Discarded {
            component,
            function,
            log,
            ..
        }) => {
            assert_eq!((component.as_str(), function), ("q", "fmi2DoStep"));
            assert!(
                log.contains("reached terminate_at = 0.03: the simulation ends at t = 0.03"),
                "{log}"
            );
        }
        other => panic!("expected the step from 0.03 discarded, got {other:?}"),
    }
    let after = look(&mut q);
    assert!(
        (after.t_end - 0.03).abs() < 1e-15 && after.count == 3,
        "{after:?}"
    );
    let e = q.do_step(t, 0.01).unwrap_err().to_string();
    assert!(e.contains("after the FMU ended the simulation"), "{e}");
    // The GUID is checked.
    match fmu.instantiate_with_guid("g", "{not-it}") {
        Err(CosimError::Instantiate { log, .. }) => assert!(
            log.contains("wrong GUID {not-it}, expected {probe-0001}"),
            "{log}"
        ),
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("instantiated with a wrong GUID"),
    }
}

/// A C driver for the status functions (`Instance` does not call them here): it includes
/// probe.c, steps an instance with terminate_at = 0.03 and prints what
/// fmi2GetBooleanStatus(fmi2Terminated) and fmi2GetRealStatus(fmi2LastSuccessfulTime) say.
const STATUS_DRIVER: &str = r#"
#include "probe.c"
#include <stdio.h>

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status s, fmi2String cat, fmi2String msg, ...) {
    va_list ap;
    va_start(ap, msg);
    printf("log %d %s: ", (int)s, cat);
    vprintf(msg, ap);
    printf("\n");
    va_end(ap);
}

static void status(fmi2Component c, const char *when) {
    fmi2Boolean term = -1;
    fmi2Real last = -1.0;
    int sb = fmi2GetBooleanStatus(c, fmi2Terminated, &term);
    int sr = fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &last);
    printf("%s: terminated %d (status %d), last successful %.12g (status %d)\n", when, term, sb, last, sr);
}

int main(void) {
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2Component c = fmi2Instantiate("drv", fmi2CoSimulation, GUID, "file:///tmp/", &cb, 0, 0);
    if (!c) return 2;
    fmi2ValueReference vr = VR_TERMINATE_AT;
    fmi2Real at = 0.03;
    if (fmi2SetupExperiment(c, 0, 0.0, 0.0, 0, 0.0) != fmi2OK) return 3;
    if (fmi2EnterInitializationMode(c) != fmi2OK) return 4;
    if (fmi2SetReal(c, &vr, 1, &at) != fmi2OK) return 5;
    if (fmi2ExitInitializationMode(c) != fmi2OK) return 6;
    status(c, "before");
    double t = 0.0;
    for (int k = 0; k < 5; k++) {
        int s = fmi2DoStep(c, t, 0.01, fmi2True);
        printf("step from %.12g: status %d\n", t, s);
        if (s == fmi2OK) t += 0.01;
        char when[32];
        snprintf(when, sizeof when, "after step %d", k);
        status(c, when);
    }
    fmi2Boolean b;
    printf("other kind: status %d\n", fmi2GetBooleanStatus(c, fmi2DoStepStatus, &b));
    fmi2FreeInstance(c);
    return 0;
}
"#;

/// Before terminate_at the FMU does not ask to end (fmi2False, fmi2OK); the step from 0.03 is
/// discarded, and from then fmi2Terminated is fmi2True and fmi2LastSuccessfulTime 0.03; a
/// later step is an error (fmi2Error = 3) and changes neither.
#[test]
fn probe_status_functions_report_the_termination() {
    let dir = scratch("status");
    let src = dir.join("driver.c");
    std::fs::write(&src, STATUS_DRIVER).unwrap();
    let exe = dir.join("driver");
    let include = format!("-I{FIXTURES}");
    cc(&[
        "-O1".as_ref(),
        include.as_ref(),
        "-o".as_ref(),
        exe.as_os_str(),
        src.as_os_str(),
    ]);
    let out = Command::new(&exe).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "driver failed ({}): {text}",
        out.status
    );
    let (logs, lines): (Vec<&str>, Vec<&str>) = text.lines().partition(|l| l.starts_with("log "));
    let ok = |t: &str| format!("terminated 0 (status 0), last successful {t} (status 0)");
    let ended = "terminated 1 (status 0), last successful 0.03 (status 0)";
    assert_eq!(
        lines,
        [
            format!("before: {}", ok("0")),
            "step from 0: status 0".into(),
            format!("after step 0: {}", ok("0.01")),
            "step from 0.01: status 0".into(),
            format!("after step 1: {}", ok("0.02")),
            "step from 0.02: status 0".into(),
            format!("after step 2: {}", ok("0.03")),
            "step from 0.03: status 2".into(),
            format!("after step 3: {ended}"),
            "step from 0.03: status 3".into(),
            format!("after step 4: {ended}"),
            "other kind: status 3".into(),
        ]
    );
    assert_eq!(logs.len(), 3, "{logs:?}");
    assert!(
        logs[0].starts_with("log 2 logStatusDiscard: reached terminate_at = 0.03"),
        "{logs:?}"
    );
    assert!(
        logs[1].contains("after the FMU ended the simulation"),
        "{logs:?}"
    );
    assert!(
        logs[2].contains("status kind 0 is not supported"),
        "{logs:?}"
    );
}

// -------------------------------------------------------------------------------------------
// The master: helpers.
// -------------------------------------------------------------------------------------------

fn strings(v: &[&str]) -> Vec<String> {
    v.iter().map(|s| (*s).to_string()).collect()
}

/// Runs `sys` recording `record` every base step; a failed run fails the test with its error.
fn run_ok(sys: &System, record: &[&str], what: &str) -> Results {
    match run(sys, &strings(record), 1, &mut |_, _| {}) {
        Ok(r) => r,
        Err(f) => panic!("{what}: the run failed: {f}"),
    }
}

/// Runs `sys`, expecting it to fail: the error's text.
fn run_err(sys: &System, record: &[&str], what: &str) -> String {
    match run(sys, &strings(record), 1, &mut |_, _| {}) {
        Ok(r) => panic!(
            "{what}: the run succeeded ({} rows) but should have failed",
            r.n_rows()
        ),
        Err(f) => f.to_string(),
    }
}

/// Whether `msg` names `name` as a word of its own (names like "A" are in other words too).
fn names(msg: &str, name: &str) -> bool {
    msg.split(|c: char| !(c.is_alphanumeric() || c == '_'))
        .any(|w| w == name)
}

/// Collects every difference from the expected values, to report them all at once.
#[derive(Default)]
struct Check {
    wrong: Vec<String>,
}

impl Check {
    /// Column `col` of `r` against `expected(row)`, to 1e-12 in every row.
    fn column(&mut self, what: &str, r: &Results, col: &str, expected: impl Fn(usize) -> f64) {
        let Some(got) = r.column(col) else {
            self.wrong
                .push(format!("{what}: no column {col} in {:?}", r.columns));
            return;
        };
        let time = r.column("time").unwrap_or_default();
        let bad: Vec<String> = got
            .iter()
            .enumerate()
            .filter(|&(j, g)| (g - expected(j)).abs() > 1e-12 || g.is_nan())
            .map(|(j, g)| {
                format!(
                    "row {j} (t = {:.4}): {g:.6} instead of {:.6}",
                    time.get(j).copied().unwrap_or(f64::NAN),
                    expected(j)
                )
            })
            .collect();
        if !bad.is_empty() {
            self.wrong.push(format!(
                "{what}: {col} wrong in {} of {} rows, first: {}",
                bad.len(),
                got.len(),
                bad[..bad.len().min(4)].join("; ")
            ));
        }
    }

    /// `k_total + 1` rows at 0, h, ..., k_total h (the last is the stop time).
    fn times(&mut self, what: &str, r: &Results, k_total: usize) {
        if r.n_rows() != k_total + 1 {
            self.wrong.push(format!(
                "{what}: {} rows instead of {}",
                r.n_rows(),
                k_total + 1
            ));
        }
        self.column(what, r, "time", |j| j as f64 * H);
    }

    fn assert_none(self) {
        assert!(
            self.wrong.is_empty(),
            "{} differences:\n{}",
            self.wrong.len(),
            self.wrong.join("\n")
        );
    }
}

// The rules of the module docs for one connection, source output t_end (whose value is its
// time stamp) into reader input u (u_held shows what the reader received at its latest step's
// start). Times are in base steps; a component stepping every `n` base steps over `k_total`
// steps from base step s = 0, n, 2n, ... to min(s + n, k_total).

/// The steps (start, end) of a component stepping every `every` base steps until `k_total`.
fn steps_of(every: usize, k_total: usize) -> Vec<(usize, usize)> {
    (0..k_total)
        .step_by(every)
        .map(|s| (s, (s + every).min(k_total)))
        .collect()
}

/// The time stamp of the outputs the row at t_j shows: the end of the latest step ended by
/// then (0: the initial outputs).
fn shown(every: usize, k_total: usize, j: usize) -> usize {
    steps_of(every, k_total)
        .iter()
        .map(|s| s.1)
        .filter(|&e| e <= j)
        .max()
        .unwrap_or(0)
}

/// The time stamp of the source's outputs a reader stepping at base step k receives: Jacobi,
/// the latest with stamp <= k; Gauss-Seidel, the latest with stamp <= k + 1 among those
/// already computed (steps of earlier base steps, or of this one if the source comes first).
fn received(order: Order, src_every: usize, src_first: bool, k_total: usize, k: usize) -> usize {
    steps_of(src_every, k_total)
        .iter()
        .filter(|&&(s, e)| match order {
            Order::Jacobi => e <= k,
            Order::GaussSeidel => (s < k || (s == k && src_first)) && e <= k + 1,
        })
        .map(|s| s.1)
        .max()
        .unwrap_or(0)
}

/// What the reader's u_held shows in the row at t_j: what it received at the start of its
/// latest step ended by then (0, u's start value, before any).
fn held(
    order: Order,
    reader_every: usize,
    src_every: usize,
    src_first: bool,
    k_total: usize,
    j: usize,
) -> usize {
    steps_of(reader_every, k_total)
        .iter()
        .rfind(|s| s.1 <= j)
        .map_or(0, |&(r, _)| {
            received(order, src_every, src_first, k_total, r)
        })
}

/// The two orders, and the two orders the components can be added in.
const CONFIGS: [(Order, bool); 4] = [
    (Order::Jacobi, true),
    (Order::Jacobi, false),
    (Order::GaussSeidel, true),
    (Order::GaussSeidel, false),
];

/// A (every 5) and B (every base step), A.t_end -> B.u or (`reverse`) B.t_end -> A.u, from 0
/// to `stop` = `k_total` h, in every order and component order: every row of A.t_end, B.t_end,
/// the reader's u_held and the time against the rules, into `check`.
fn check_two_rates(check: &mut Check, name: &str, stop: f64, k_total: usize, reverse: bool) {
    let path = probe(name);
    for (order, a_first) in CONFIGS {
        let mut sys = System::new(stop, H);
        for first in [a_first, !a_first] {
            sys = if first {
                sys.component("A", &path).every(5)
            } else {
                sys.component("B", &path)
            };
        }
        let (conn, reader) = if reverse {
            (("B.t_end", "A.u"), "A.u_held")
        } else {
            (("A.t_end", "B.u"), "B.u_held")
        };
        let sys = sys.connect(conn.0, conn.1).order(order);
        let what = format!(
            "{order:?}, {} added first, {} -> {}, stop {stop}",
            if a_first { "A" } else { "B" },
            conn.0,
            conn.1
        );
        let r = run_ok(&sys, &["A.t_end", "B.t_end", reader], &what);
        check.times(&what, &r, k_total);
        check.column(&what, &r, "A.t_end", |j| shown(5, k_total, j) as f64 * H);
        check.column(&what, &r, "B.t_end", |j| shown(1, k_total, j) as f64 * H);
        let expected = |j: usize| {
            let stamp = if reverse {
                held(order, 5, 1, !a_first, k_total, j)
            } else {
                held(order, 1, 5, a_first, k_total, j)
            };
            stamp as f64 * H
        };
        check.column(&what, &r, reader, expected);
    }
}

// -------------------------------------------------------------------------------------------
// a) FMI timing, multi-rate.
// -------------------------------------------------------------------------------------------

/// The rules above in closed form for A (every 5) -> B (every 1), stop 20 h: the row at t_j
/// shows A.t_end = 5h floor(j/5); B.u_held (j >= 1) = 5h floor((j-1)/5) in Jacobi (what A
/// showed at B's step start t_{j-1}), 5h floor(j/5) in Gauss-Seidel whichever of A and B comes
/// first: A's step from 5m h, computed at base step 5m, carries 5(m+1) h, which B may use from
/// its step at 5m + 4 on (stamp <= t_k + h), when A has long been computed. (A brief said
/// "Gauss-Seidel with B before A: same as Jacobi"; the rules say otherwise at k = 5m + 4, and
/// these tests follow the rules.) Reverse, B (every 1) -> A (every 5): A.u_held in the row at
/// t_j, j >= 5, is what A received at its latest completed step's start 5m, m = floor(j/5) - 1:
/// 5m h in Jacobi and in Gauss-Seidel with A first, (5m + 1) h in Gauss-Seidel with B first.
#[test]
fn the_rules_in_closed_form() {
    use Order::{GaussSeidel, Jacobi};
    let k = 20;
    for j in 0..=k {
        assert_eq!(shown(5, k, j), 5 * (j / 5), "{j}");
        let prev = j.saturating_sub(1);
        let jacobi = if j == 0 { 0 } else { 5 * (prev / 5) };
        assert_eq!(held(Jacobi, 1, 5, true, k, j), jacobi, "{j}");
        assert_eq!(held(Jacobi, 1, 5, false, k, j), jacobi, "{j}");
        assert_eq!(held(GaussSeidel, 1, 5, true, k, j), 5 * (j / 5), "{j}");
        assert_eq!(held(GaussSeidel, 1, 5, false, k, j), 5 * (j / 5), "{j}");
        let m = (j / 5).saturating_sub(1);
        let slow = if j < 5 { 0 } else { 5 * m };
        assert_eq!(held(Jacobi, 5, 1, true, k, j), slow, "{j}");
        assert_eq!(held(GaussSeidel, 5, 1, false, k, j), slow, "{j}");
        let b_first = if j < 5 { 0 } else { 5 * m + 1 };
        assert_eq!(held(GaussSeidel, 5, 1, true, k, j), b_first, "{j}");
    }
}

/// A (every 5) -> B (every 1), h = 0.01, stop 0.2: outputs carry their step's end time.
#[test]
fn multirate_slow_source_outputs_carry_their_step_end_time() {
    let mut check = Check::default();
    check_two_rates(&mut check, "slow_source", 0.2, 20, false);
    check.assert_none();
}

/// B (every 1) -> A (every 5), h = 0.01, stop 0.2.
#[test]
fn multirate_slow_reader_receives_what_was_visible_at_its_step() {
    let mut check = Check::default();
    check_two_rates(&mut check, "slow_reader", 0.2, 20, true);
    check.assert_none();
}

/// Stop 0.23, not a multiple of A's period: A's step from 0.2 is cut to end at 0.23 (the probe
/// refuses a step past the stop time), and the last row is at 0.23, both directions.
#[test]
fn multirate_last_slow_step_is_cut_at_the_stop_time() {
    let mut check = Check::default();
    check_two_rates(&mut check, "cut_source", 0.23, 23, false);
    check_two_rates(&mut check, "cut_reader", 0.23, 23, true);
    check.assert_none();
}

// -------------------------------------------------------------------------------------------
// b) Initialisation and algebraic loops.
// -------------------------------------------------------------------------------------------

/// A.ft -> B.u, B.ft -> C.u; A: gain 2, offset 1, u = 0 gives A.ft = 1; B: gain 3 gives
/// B.ft = 3; C: offset 0.5 gives C.ft = 3.5. Propagated in initialisation mode, the row at 0
/// shows 1, 3, 3.5 (and so does every row); the first step holds B.u = 1 and C.u = 3. The same
/// with the components added and connected in the opposite order.
#[test]
fn initialisation_propagates_through_feedthrough_chains() {
    let path = probe("init");
    let chain = |reversed: bool| {
        let mut sys = System::new(0.05, H);
        let added = if reversed {
            ["C", "B", "A"]
        } else {
            ["A", "B", "C"]
        };
        for n in added {
            sys = sys.component(n, &path);
        }
        let sys = sys
            .parameter("A", "gain", Value::Real(2.0))
            .parameter("A", "offset", Value::Real(1.0))
            .parameter("B", "gain", Value::Real(3.0))
            .parameter("C", "offset", Value::Real(0.5));
        if reversed {
            sys.connect("B.ft", "C.u").connect("A.ft", "B.u")
        } else {
            sys.connect("A.ft", "B.u").connect("B.ft", "C.u")
        }
    };
    let mut check = Check::default();
    for order in [Order::Jacobi, Order::GaussSeidel] {
        for reversed in [false, true] {
            let what = format!(
                "{order:?}, {}",
                if reversed { "C, B, A" } else { "A, B, C" }
            );
            let r = run_ok(
                &chain(reversed).order(order),
                &["A.ft", "B.ft", "C.ft", "B.u_held", "C.u_held"],
                &what,
            );
            check.times(&what, &r, 5);
            check.column(&what, &r, "A.ft", |_| 1.0);
            check.column(&what, &r, "B.ft", |_| 3.0);
            check.column(&what, &r, "C.ft", |_| 3.5);
            check.column(&what, &r, "B.u_held", |j| if j == 0 { 0.0 } else { 1.0 });
            check.column(&what, &r, "C.u_held", |j| if j == 0 { 0.0 } else { 3.0 });
        }
    }
    check.assert_none();
}

/// Feedthrough outputs in a cycle are an algebraic loop: the run fails naming it and every
/// component in it, in both orders (A.ft -> B.u -> B.ft -> A.u; three components; one component
/// into itself).
#[test]
fn algebraic_loops_are_refused_naming_the_components() {
    let path = probe("loop");
    let abc = || {
        System::new(0.05, H)
            .component("A", &path)
            .component("B", &path)
            .component("C", &path)
    };
    let cases = [
        (
            abc().connect("A.ft", "B.u").connect("B.ft", "A.u"),
            vec!["A", "B"],
        ),
        (
            abc()
                .connect("A.ft", "B.u")
                .connect("B.ft", "C.u")
                .connect("C.ft", "A.u"),
            vec!["A", "B", "C"],
        ),
        (abc().connect("C.ft", "C.u"), vec!["C"]),
    ];
    for order in [Order::Jacobi, Order::GaussSeidel] {
        for (sys, members) in &cases {
            let what = format!("{order:?}, loop through {members:?}");
            let e = run_err(&sys.clone().order(order), &[], &what);
            assert!(e.contains("algebraic loop"), "{what}: {e}");
            for m in members {
                assert!(names(&e, m), "{what}: {e} does not name {m}");
            }
        }
    }
}

/// A cycle through an output without feedthrough is no algebraic loop: A.t_end -> B.u,
/// B.ft -> A.u runs, and B holds A's step end times as the rules say.
#[test]
fn a_cycle_through_a_non_feedthrough_output_runs() {
    let path = probe("no_loop");
    let sys = System::new(0.05, H)
        .component("A", &path)
        .component("B", &path)
        .connect("A.t_end", "B.u")
        .connect("B.ft", "A.u");
    let mut check = Check::default();
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let what = format!("{order:?}");
        let r = run_ok(&sys.clone().order(order), &["B.u_held"], &what);
        check.times(&what, &r, 5);
        check.column(&what, &r, "B.u_held", |j| {
            held(order, 1, 1, true, 5, j) as f64 * H
        });
    }
    check.assert_none();
}

/// An algebraic loop of Integer feedthrough outputs (A.ni_ft -> B.ni, B.ni_ft -> A.ni) is one
/// too.
#[test]
fn integer_feedthrough_cycles_are_algebraic_loops_too() {
    let path = probe("int_loop");
    let sys = System::new(0.05, H)
        .component("A", &path)
        .component("B", &path)
        .connect("A.ni_ft", "B.ni")
        .connect("B.ni_ft", "A.ni");
    let e = run_err(&sys, &[], "Integer loop");
    assert!(
        e.contains("algebraic loop") && names(&e, "A") && names(&e, "B"),
        "{e}"
    );
}

// -------------------------------------------------------------------------------------------
// c) Integer, Boolean and String connections.
// -------------------------------------------------------------------------------------------

/// A.count -> B.ni, A.odd -> B.bi, A.s_held -> B.si (A's si is "hello"), h = 0.01, stop 0.1.
/// A's outputs after n steps: count n (its ni stays 0), odd = n odd, s_held "hello" (n >= 1).
/// B's step at base step k receives them after n_k steps: n_k = k in Jacobi (stamp <= t_k),
/// k + 1 in Gauss-Seidel (A first, just stepped). The row at t_j (j >= 1, after B's step j-1)
/// shows B.count = j + n_{j-1}, B.b_held = n_{j-1} odd, B.s_len = 5 once n_{j-1} >= 1 (4,
/// "none", before); row 0 the start values. Integer and Boolean columns come back as numbers
/// (a Boolean as 0 or 1).
#[test]
fn integer_boolean_and_string_connections_carry_their_values() {
    let path = probe("types");
    let sys = System::new(0.1, H)
        .component("A", &path)
        .parameter("A", "si", Value::String("hello".into()))
        .component("B", &path)
        .connect("A.count", "B.ni")
        .connect("A.odd", "B.bi")
        .connect("A.s_held", "B.si");
    let mut check = Check::default();
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let what = format!("{order:?}");
        let r = run_ok(
            &sys.clone().order(order),
            &["A.count", "A.odd", "B.count", "B.b_held", "B.s_len"],
            &what,
        );
        let n = |k: usize| match order {
            Order::Jacobi => k,
            Order::GaussSeidel => k + 1,
        };
        let bool01 = |b: bool| if b { 1.0 } else { 0.0 };
        check.times(&what, &r, 10);
        check.column(&what, &r, "A.count", |j| j as f64);
        check.column(&what, &r, "A.odd", |j| bool01(j % 2 == 1));
        check.column(&what, &r, "B.count", |j| {
            if j == 0 { 0.0 } else { (j + n(j - 1)) as f64 }
        });
        check.column(&what, &r, "B.b_held", |j| {
            bool01(j > 0 && n(j - 1) % 2 == 1)
        });
        check.column(&what, &r, "B.s_len", |j| {
            if j > 0 && n(j - 1) >= 1 { 5.0 } else { 4.0 }
        });
    }
    check.assert_none();
}

/// A String output into a String input runs (both orders); recording a String is refused
/// naming it.
#[test]
fn string_connections_run_and_strings_are_not_recorded() {
    let path = probe("strings");
    let sys = System::new(0.05, H)
        .component("A", &path)
        .parameter("A", "si", Value::String("hello".into()))
        .component("B", &path)
        .connect("A.s_held", "B.si");
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let r = run_ok(&sys.clone().order(order), &[], &format!("{order:?}"));
        assert_eq!(r.n_rows(), 6);
    }
    let e = run_err(&sys, &["B.s_held"], "recording a String");
    assert!(e.contains("B.s_held"), "{e}");
    // A pattern leaves the String outputs out instead of failing.
    let r = run_ok(&sys, &["B.*"], "a pattern over B's outputs");
    assert!(r.columns.iter().any(|c| c == "B.t_end"), "{:?}", r.columns);
    assert!(
        !r.columns.iter().any(|c| c == "B.s_held"),
        "{:?}",
        r.columns
    );
    // The run advances on the base-step grid: a stop time between two points is refused.
    let off_grid = System::new(0.055, H).component("A", &path);
    let e = run_err(&off_grid, &[], "a stop time off the grid");
    assert!(e.contains("whole number of steps"), "{e}");
}

/// A connection between variables of different types is refused naming both ends.
#[test]
fn connections_between_types_are_refused_naming_both_ends() {
    let path = probe("mistyped");
    for (from, to) in [
        ("A.count", "B.u"),
        ("A.t_end", "B.ni"),
        ("A.odd", "B.ni"),
        ("A.count", "B.bi"),
        ("A.s_held", "B.u"),
        ("A.ft", "B.si"),
    ] {
        let sys = System::new(0.05, H)
            .component("A", &path)
            .component("B", &path)
            .connect(from, to);
        let e = run_err(&sys, &[], &format!("{from} -> {to}"));
        assert!(e.contains(from) && e.contains(to), "{e}");
    }
}

/// With the probe as declared (t_end in s, u in m), t_end into u is refused for its units: the
/// reason the other tests use a probe without t_end's unit.
#[test]
fn units_are_still_checked() {
    let path = probe_fmu("units", &probe_xml());
    let sys = System::new(0.05, H)
        .component("A", &path)
        .component("B", &path)
        .connect("A.t_end", "B.u");
    let e = run_err(&sys, &[], "A.t_end (s) -> B.u (m)");
    assert!(
        e.contains("units differ") && e.contains("A.t_end") && e.contains("B.u"),
        "{e}"
    );
    let ok = System::new(0.05, H)
        .component("A", &path)
        .component("B", &path)
        .connect("A.ft", "B.u");
    run_ok(&ok, &[], "A.ft (m) -> B.u (m)");
}

// -------------------------------------------------------------------------------------------
// d) A component ending the simulation.
// -------------------------------------------------------------------------------------------

/// The system of the termination tests: A (terminate_at, if given) -> B, h = 0.01, stop 1.
fn ending(path: &Path, terminate_at: Option<f64>) -> System {
    let sys = System::new(1.0, H).component("A", path);
    let sys = match terminate_at {
        Some(t) => sys.parameter("A", "terminate_at", Value::Real(t)),
        None => sys,
    };
    sys.component("B", path).connect("A.t_end", "B.u")
}

/// A's step from 0.1 is discarded and A asks to end the simulation: the run ends there
/// successfully, its last row at 0.1, every row before complete.
#[test]
fn a_component_ending_the_simulation_ends_the_run() {
    let path = probe("ended");
    let mut check = Check::default();
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let what = format!("{order:?}");
        let r = run_ok(
            &ending(&path, Some(0.1)).order(order),
            &["A.t_end", "B.u_held"],
            &what,
        );
        check.times(&what, &r, 10);
        check.column(&what, &r, "A.t_end", |j| j as f64 * H);
        check.column(&what, &r, "B.u_held", |j| {
            held(order, 1, 1, true, 10, j) as f64 * H
        });
    }
    check.assert_none();
}

/// `Results::ended` names the component that ended the run and its last successful time
/// (0.1); without terminate_at the run goes to the stop time and `ended` is None.
#[test]
fn results_say_who_ended_the_run_and_when() {
    use cosim::system::Ended;
    let path = probe("ended_by");
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let r = run_ok(
            &ending(&path, Some(0.1)).order(order),
            &["A.t_end"],
            &format!("{order:?}"),
        );
        match &r.ended {
            Some(Ended { component, time }) => {
                assert_eq!(component, "A", "{order:?}");
                assert!((time - 0.1).abs() < 1e-12, "{order:?}: {time}");
            }
            None => panic!("{order:?}: Results::ended is None"),
        }
        assert!((r.last_row().unwrap()[0] - 0.1).abs() < 1e-12);
        let r = run_ok(&ending(&path, None).order(order), &["A.t_end"], "no end");
        assert!(r.ended.is_none(), "{order:?}: ended without terminate_at");
        assert_eq!(r.n_rows(), 101);
    }
}

/// A component that ends the run while its step is on Gauss-Seidel's look-ahead thread: the
/// run ends exactly as in the sequential order (the same rows, the same `ended`), though the
/// master went on with the others meanwhile; and the same when it ends in the very last step.
/// A (its own FMU file, not recorded, read by nobody) may go to the look-ahead thread; B is
/// recorded.
#[test]
fn an_end_on_the_lookahead_thread_is_the_sequential_end() {
    use cosim::system::SchedulerParams;
    let (a, b) = (probe("lookahead_a"), probe("lookahead_b"));
    for terminate_at in [0.1, 0.99] {
        let sys = System::new(1.0, H)
            .component("A", &a)
            .parameter("A", "terminate_at", Value::Real(terminate_at))
            .component("B", &b)
            .order(Order::GaussSeidel)
            .scheduler(SchedulerParams {
                lookahead_min_seconds: 0.0,
                ..SchedulerParams::default()
            });
        let mut sequential = sys.clone();
        sequential.no_lookahead = true;
        let what = format!("terminate_at {terminate_at}");
        let seq = run_ok(&sequential, &["B.t_end"], &what);
        let mut sim = cosim::Simulation::new(&sys, &["B.t_end".into()]).unwrap();
        sim.step().unwrap();
        sim.step().unwrap();
        assert!(
            sim.lookahead_steps() > 0,
            "{what}: A never went to the look-ahead thread"
        );
        drop(sim);
        let la = run_ok(&sys, &["B.t_end"], &what);
        assert_eq!(la.values(), seq.values(), "{what}: the rows differ");
        assert_eq!(la.ended, seq.ended, "{what}");
        let ended = la.ended.as_ref().expect("ended");
        assert_eq!(ended.component, "A");
        assert!(
            (ended.time - terminate_at).abs() < 1e-9,
            "{what}: {}",
            ended.time
        );
        assert!((la.last_row().unwrap()[0] - terminate_at).abs() < 1e-9);
    }
}
