//! The importer and the master on FMUs the tests build themselves (a tiny FMU written in plain C,
//! compiled with the system C compiler) and on this project's packaged FMUs.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};

use cosim::description::{Causality, Start, VarType};
use cosim::{CosimError, Fmu, ModelDescription};

mod common;
use common::{FIXTURES, zip_fmu};

fn scratch(name: &str) -> PathBuf {
    common::scratch("m1cs-cosim-test", name)
}

/// Compiles tiny.c to a shared library in `dir`.
fn compile_tiny(dir: &Path, defines: &[&str]) -> PathBuf {
    common::compile_fixture(dir, "tiny.c", defines)
}

fn tiny_fmu(name: &str, xml: &str, defines: &[&str], with_binary: bool) -> PathBuf {
    let dir = scratch(name);
    let mut entries = vec![("modelDescription.xml", xml.as_bytes().to_vec())];
    if with_binary {
        let so = compile_tiny(&dir, defines);
        entries.push(("binaries/linux64/tiny.so", std::fs::read(so).unwrap()));
    }
    let path = dir.join("tiny.fmu");
    zip_fmu(&path, &entries);
    path
}

fn tiny_xml() -> String {
    std::fs::read_to_string(Path::new(FIXTURES).join("tiny.xml")).unwrap()
}

#[test]
fn tiny_c_fmu_runs_and_integrates_exactly() {
    let path = tiny_fmu("runs", &tiny_xml(), &[], true);
    let fmu = Fmu::open(&path).unwrap();
    let md = &fmu.description;
    assert_eq!(md.co_simulation.model_identifier, "tiny");
    assert_eq!(md.default_experiment.step_size, Some(0.1));
    let u = md.variable_by_name("u").unwrap();
    assert_eq!((u.causality, u.var_type), (Causality::Input, VarType::Real));
    assert_eq!(
        md.variable_by_name("k").unwrap().start,
        Some(Start::Real(1.0))
    );
    assert_eq!(md.outputs.len(), 2);
    assert_eq!(md.outputs[0].dependencies, Some(vec![]));

    let mut a = fmu.instantiate("a", false).unwrap();
    let mut b = fmu.instantiate("b", false).unwrap();
    for inst in [&mut a, &mut b] {
        inst.setup_experiment(None, 0.0, Some(1.0)).unwrap();
        inst.enter_initialization_mode().unwrap();
        inst.exit_initialization_mode().unwrap();
    }
    a.set_real(&[2], &[3.0]).unwrap();
    a.set_real(&[0], &[0.5]).unwrap();
    b.set_real(&[0], &[-1.0]).unwrap();
    let h = 0.1;
    for k in 0..10 {
        a.do_step(k as f64 * h, h).unwrap();
        b.do_step(k as f64 * h, h).unwrap();
    }
    let mut y = [0.0];
    a.get_real(&[1], &mut y).unwrap();
    assert!((y[0] - 3.0 * 0.5 * 1.0).abs() < 1e-12, "{}", y[0]);
    b.get_real(&[1], &mut y).unwrap();
    assert!(
        (y[0] + 1.0).abs() < 1e-12,
        "instances are independent: {}",
        y[0]
    );
    let mut steps = [0];
    a.get_integer(&[0], &mut steps).unwrap();
    assert_eq!(steps[0], 10);
    a.terminate().unwrap();
    // The library stays loaded while instances live, even once the Fmu is dropped.
    drop(fmu);
    b.do_step(1.0, h).unwrap();
    b.get_real(&[1], &mut y).unwrap();
    assert!((y[0] + 1.1).abs() < 1e-12);
}

#[test]
fn fmu_errors_come_back_with_the_logged_message() {
    let path = tiny_fmu("status", &tiny_xml(), &[], true);
    let fmu = Fmu::open(&path).unwrap();
    let mut a = fmu.instantiate("a", false).unwrap();
    a.setup_experiment(None, 0.0, None).unwrap();
    a.enter_initialization_mode().unwrap();
    a.exit_initialization_mode().unwrap();
    // The variadic logger formats "%s (%g)" with its arguments.
    let e = a.set_real(&[2], &[-2.0]).unwrap_err().to_string();
    assert!(
        e.contains("fmi2SetReal") && e.contains("k must be >= 0, got (-2)"),
        "{e}"
    );
    let e = a.do_step(0.5, -1.0).unwrap_err().to_string();
    assert!(
        e.contains("t = 0.5") && e.contains("step size must be positive"),
        "{e}"
    );
    let e = a.get_real(&[1, 2], &mut [0.0]).unwrap_err().to_string();
    assert!(e.contains("2 value references and 1 values"), "{e}");
}

#[test]
fn guid_mismatch_is_reported_with_the_fmu_message() {
    let path = tiny_fmu("guid", &tiny_xml(), &[], true);
    let fmu = Fmu::open(&path).unwrap();
    match fmu.instantiate_with_guid("g", "{not-it}") {
        Err(CosimError::Instantiate { log, guid, .. }) => {
            assert_eq!(guid, "{not-it}");
            assert!(
                log.contains("wrong GUID {not-it}, expected {tiny-0001}"),
                "{log}"
            );
        }
        Err(e) => panic!("wrong error {e}"),
        Ok(_) => panic!("instantiated with a wrong GUID"),
    }
}

#[test]
fn missing_binary_and_missing_symbol_are_named() {
    let path = tiny_fmu("nobin", &tiny_xml(), &[], false);
    match Fmu::open(&path) {
        Err(CosimError::MissingBinary { expected, .. }) => {
            assert_eq!(expected, "binaries/linux64/tiny.so");
        }
        other => panic!("expected MissingBinary, got {other:?}"),
    }
    let path = tiny_fmu("nosym", &tiny_xml(), &["OMIT_DO_STEP"], true);
    match Fmu::open(&path) {
        Err(CosimError::MissingSymbol { symbol, .. }) => assert_eq!(symbol, "fmi2DoStep"),
        other => panic!("expected MissingSymbol, got {other:?}"),
    }
}

/// Archives opened together come back in the order asked, and the first failure in that
/// order is the one reported, whichever thread met it first.
#[test]
fn archives_opened_together_keep_their_order_and_the_first_error() {
    let good = tiny_fmu("all-good", &tiny_xml(), &[], true);
    let other = tiny_fmu(
        "all-other",
        &tiny_xml().replace("modelName=\"tiny\"", "modelName=\"tiny two\""),
        &[],
        true,
    );
    let opened = Fmu::open_all(&[&good, &other, &good]).unwrap();
    let names: Vec<&str> = opened
        .iter()
        .map(|f| f.description.model_name.as_str())
        .collect();
    assert_eq!(names, ["tiny", "tiny two", "tiny"]);
    let nobin = tiny_fmu("all-nobin", &tiny_xml(), &[], false);
    let missing = Path::new("/nonexistent/all.fmu");
    for _ in 0..4 {
        match Fmu::open_all(&[good.as_path(), nobin.as_path(), missing]) {
            Err(CosimError::MissingBinary { fmu, .. }) => assert_eq!(fmu, nobin),
            other => panic!("expected the missing binary first, got {other:?}"),
        }
    }
}

#[test]
fn malformed_and_rule_breaking_descriptions_are_named() {
    let file = Path::new("x/modelDescription.xml");
    let cases: Vec<(String, &str)> = vec![
        ("<fmiModelDescription fmiVersion=\"2.0\"".into(), "malformed"),
        (tiny_xml().replace("fmiVersion=\"2.0\"", "fmiVersion=\"3.0\""), "only FMI 2.0"),
        (
            tiny_xml().replace(
                "<CoSimulation modelIdentifier=\"tiny\" canHandleVariableCommunicationStepSize=\"true\"/>",
                "",
            ),
            "not a Co-Simulation FMU",
        ),
        (
            tiny_xml().replace("<Real start=\"0\" unit=\"m\"/></ScalarVariable>\n    <ScalarVariable name=\"y\"", "<Real unit=\"m\"/></ScalarVariable>\n    <ScalarVariable name=\"y\""),
            "\"u\": an input needs a start value",
        ),
        (tiny_xml().replace("causality=\"parameter\"", "causality=\"knob\""), "unknown causality \"knob\""),
        (tiny_xml().replace("<Real start=\"1\"/>", "<Real start=\"one\"/>"), "\"k\": start \"one\" is not a number"),
        (tiny_xml().replace("<Unknown index=\"4\" dependencies=\"\"/>", ""), "ModelStructure/Outputs lists 1"),
        (tiny_xml().replace("name=\"steps\"", "name=\"u\""), "\"u\" is used twice"),
    ];
    for (xml, expected) in cases {
        match ModelDescription::parse(&xml, file) {
            Err(CosimError::Xml { file: f, reason }) => {
                assert_eq!(f, file);
                assert!(reason.contains(expected), "{reason:?} lacks {expected:?}");
            }
            other => panic!("expected an XML error with {expected:?}, got {other:?}"),
        }
    }
    // Through Fmu::open the archive path is named.
    let path = tiny_fmu("badxml", "<oops", &[], false);
    let e = Fmu::open(&path).unwrap_err().to_string();
    assert!(e.contains("tiny.fmu") && e.contains("malformed"), "{e}");
    let e = Fmu::open(Path::new("/nonexistent/x.fmu"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/x.fmu"), "{e}");
}

fn packaged(layout: &str, name: &str) -> PathBuf {
    let dir = std::env::var_os("M1CS_FMU_DIR").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/fmu"),
        PathBuf::from,
    );
    let p = dir.join(layout).join(format!("{name}.fmu"));
    assert!(
        p.is_file(),
        "{} is missing: run `cargo xtask package` first",
        p.display()
    );
    p
}

/// This project's segments FMU through the importer: array signals by structured name, a
/// command step followed by the actuator, as in the fmpy tests.
#[test]
fn packaged_segments_fmu_imports_and_steps() {
    let fmu = Fmu::open(packaged("keck", "segments_voicecoil")).unwrap();
    let md = &fmu.description;
    let u = md.signal("u_cmd").unwrap();
    let z = md.signal("z").unwrap();
    assert_eq!((u.len(), z.len()), (108, 108));
    let u_vr: Vec<u32> = u.iter().map(|v| v.value_reference).collect();
    let z_vr: Vec<u32> = z.iter().map(|v| v.value_reference).collect();
    assert!(md.signal("nosuch").is_none());
    let mut inst = fmu.instantiate("segments", false).unwrap();
    inst.setup_experiment(None, 0.0, None).unwrap();
    inst.enter_initialization_mode().unwrap();
    inst.exit_initialization_mode().unwrap();
    let mut cmd = vec![0.0; 108];
    cmd[105..].fill(1e-6);
    let mut zs = vec![0.0; 108];
    for k in 0..300 {
        inst.set_real(&u_vr, &cmd).unwrap();
        inst.do_step(k as f64 * 1e-3, 1e-3).unwrap();
    }
    inst.get_real(&z_vr, &mut zs).unwrap();
    assert_eq!(zs[0], 0.0);
    assert!((zs[107] - 1e-6).abs() < 2e-8, "{}", zs[107]);
    // A bad value is refused with the FMU's message naming the variable.
    let kp = md.variable_by_name("servo_kp").unwrap().value_reference;
    let e = fmu
        .instantiate("bad", false)
        .and_then(|mut b| b.set_real(&[kp], &[f64::NAN]))
        .unwrap_err()
        .to_string();
    assert!(e.contains("servo_kp"), "{e}");
}

// -------------------------------------------------------------------------------------------
// The master on systems of tiny FMUs: exact sums for Jacobi and Gauss-Seidel, multi-rate, and
// the connection checks.
// -------------------------------------------------------------------------------------------

use cosim::system::{Order, System, Value, run};

/// a integrates its constant input u = 2 (y_a = 2 t); b integrates y_a. With n steps of h:
/// Jacobi feeds b the value of y_a before a's step, y_b = h^2 2 n (n - 1) / 2; Gauss-Seidel
/// feeds the value after it, y_b = h^2 2 n (n + 1) / 2.
#[test]
fn chained_integrators_give_the_exact_sums() {
    let path = tiny_fmu("chain", &tiny_xml(), &[], true);
    let (h, n) = (0.01, 50usize);
    for (order, expected) in [
        (Order::Jacobi, h * h * 2.0 * (n * (n - 1)) as f64 / 2.0),
        (Order::GaussSeidel, h * h * 2.0 * (n * (n + 1)) as f64 / 2.0),
    ] {
        let sys = System::new(n as f64 * h, h)
            .component("a", &path)
            .parameter("a", "u", Value::Real(2.0))
            .component("b", &path)
            .connect("a.y", "b.u")
            .order(order);
        let r = run(&sys, &["a.y".into(), "b.y".into()], 1, &mut |_, _| {}).unwrap();
        assert_eq!(r.columns, ["time", "a.y", "b.y"]);
        assert_eq!(r.n_rows(), n + 1);
        let last = r.last_row().unwrap();
        assert!((last[0] - n as f64 * h).abs() < 1e-12);
        assert!(
            (last[1] - 2.0 * n as f64 * h).abs() < 1e-12,
            "{order:?}: {}",
            last[1]
        );
        assert!(
            (last[2] - expected).abs() < 1e-12,
            "{order:?}: {} vs {expected}",
            last[2]
        );
    }
}

/// In Gauss-Seidel order the outputs of a component that steps every base step and is not
/// recorded (a) wait in its ports until a reader's turn: a slower reader before it in the order
/// (c, every 3 steps: a's outputs after its previous step) and a reader after it (b, every
/// step: a's outputs of this step) get the values of the sequential order, the exact sums.
#[test]
fn unrecorded_outputs_reach_readers_before_and_after_them() {
    let path = tiny_fmu("lazy", &tiny_xml(), &[], true);
    let (h, n, m) = (0.01, 30usize, 3usize);
    let sys = System::new(n as f64 * h, h)
        .component("c", &path)
        .every(m)
        .component("a", &path)
        .parameter("a", "u", Value::Real(1.0))
        .component("b", &path)
        .connect("a.y", "c.u")
        .connect("a.y", "b.u")
        .order(Order::GaussSeidel);
    for lookahead in [false, true] {
        let sys = if lookahead {
            sys.clone()
        } else {
            sys.clone().scheduler(cosim::SchedulerParams {
                lookahead_min_seconds: f64::INFINITY,
                ..cosim::SchedulerParams::default()
            })
        };
        let r = run(&sys, &["c.y".into(), "b.y".into()], 1, &mut |_, _| {}).unwrap();
        for (k, row) in r.rows().enumerate() {
            // c's step j (from 3 j h) reads y_a = 3 j h and shows at its end, 3 (j + 1) h;
            // b's step from k h reads y_a = (k + 1) h.
            let done = k / m;
            let c = (m as f64 * h).powi(2) * (done * done.saturating_sub(1)) as f64 / 2.0;
            let b = h * h * (k * (k + 1)) as f64 / 2.0;
            assert!((row[1] - c).abs() < 1e-12, "row {k}: c.y {} vs {c}", row[1]);
            assert!((row[2] - b).abs() < 1e-12, "row {k}: b.y {} vs {b}", row[2]);
        }
    }
}

/// An input set straight from the master's buffer is set again only when its source's outputs
/// have changed: b reads a, which steps every third base step. An FMU that keeps its inputs (as
/// FMI 2.0 requires) integrates the same values either way; one that forgets them after each step
/// (built with -DFORGET_INPUTS) then misses a's value at two steps of three, unless the system
/// sets unchanged inputs at every step ([`System::set_unchanged_inputs`]), with which it gets the
/// same values as the first, in both orders.
#[test]
fn unchanged_inputs_are_not_set_again_unless_asked() {
    let keeps = tiny_fmu("keeps", &tiny_xml(), &[], true);
    let forgets = tiny_fmu("forgets", &tiny_xml(), &["FORGET_INPUTS"], true);
    let (h, n) = (0.01, 30usize);
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let last = |b: &Path, every_step: bool| {
            let mut sys = System::new(n as f64 * h, h)
                .component("a", &keeps)
                .every(3)
                .parameter("a", "u", Value::Real(1.0))
                .component("b", b)
                .connect("a.y", "b.u")
                .order(order);
            sys.set_unchanged_inputs = every_step;
            let r = run(&sys, &["b.y".into()], 1, &mut |_, _| {}).unwrap();
            r.last_row().unwrap()[1]
        };
        let exact = last(&keeps, false);
        assert!(exact > 0.0, "{order:?}");
        assert_eq!(last(&keeps, true).to_bits(), exact.to_bits(), "{order:?}");
        assert_eq!(last(&forgets, true).to_bits(), exact.to_bits(), "{order:?}");
        let missed = last(&forgets, false);
        assert!(missed < 0.5 * exact, "{order:?}: {missed} against {exact}");
    }
}

/// b steps every 4 base steps with a step of 4 h, on the value of y_a at its step start.
#[test]
fn multirate_components_step_at_their_own_multiple() {
    let path = tiny_fmu("multirate", &tiny_xml(), &[], true);
    let (h, n, m) = (0.01, 40usize, 4usize);
    let sys = System::new(n as f64 * h, h)
        .component("a", &path)
        .parameter("a", "u", Value::Real(1.0))
        .component("b", &path)
        .every(m)
        .connect("a.y", "b.u");
    // Integer outputs are recorded as numbers: b has taken one step per recorded row.
    let r = run(&sys, &["b.y".into(), "b.steps".into()], 4, &mut |_, _| {}).unwrap();
    assert_eq!(r.n_rows(), n / 4 + 1);
    for (k, row) in r.rows().enumerate() {
        assert_eq!(row[2], k as f64, "b.steps at row {k}");
    }
    // y_b = sum over b's steps j of (m h) * y_a(j m h) = (m h)^2 * sum j.
    let steps = n / m;
    let expected = (m as f64 * h).powi(2) * (steps * (steps - 1)) as f64 / 2.0;
    let got = r.last_row().unwrap()[1];
    assert!((got - expected).abs() < 1e-12, "{got} vs {expected}");
    // A stop time that is not a multiple of b's step: b's last step (from 40 h) is cut to the
    // 2 h left, never past the stop time. b integrates y_a as it was at its step start
    // (Jacobi) or just after a's step (Gauss-Seidel, a comes first).
    let n = 42usize;
    let sys = System::new(n as f64 * h, h)
        .component("a", &path)
        .parameter("a", "u", Value::Real(1.0))
        .component("b", &path)
        .every(m)
        .connect("a.y", "b.u");
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let r = run(
            &sys.clone().order(order),
            &["b.y".into()],
            1,
            &mut |_, _| {},
        )
        .unwrap();
        let lag = usize::from(order == Order::GaussSeidel);
        let full: f64 = (0..10)
            .map(|j| (m as f64 * h) * (j * m + lag) as f64 * h)
            .sum();
        let expected = full + 2.0 * h * (10 * m + lag) as f64 * h;
        let got = r.last_row().unwrap()[1];
        assert!(
            (got - expected).abs() < 1e-12,
            "{order:?}: {got} vs {expected}"
        );
        assert!((r.last_row().unwrap()[0] - n as f64 * h).abs() < 1e-12);
    }
}

/// A component that fails mid-run (fmi2Error from doStep) stops the run with its name, the
/// function and the time, and the rows recorded until then come back; a NaN output is
/// reported the same way instead of propagating. The timing adds up.
#[test]
fn failures_stop_the_run_and_keep_the_results() {
    let path = tiny_fmu("failing", &tiny_xml(), &[], true);
    let h = 0.01;
    let sys = System::new(1.0, h)
        .component("a", &path)
        .parameter("a", "u", Value::Real(1.0))
        .parameter("a", "fail_at", Value::Real(0.25))
        .component("b", &path)
        .connect("a.y", "b.u");
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let f = run(
            &sys.clone().order(order),
            &["a.y".into()],
            1,
            &mut |_, _| {},
        )
        .unwrap_err();
        let msg = f.to_string();
        assert!(
            msg.contains("a: fmi2DoStep returned fmi2Error at t = 0.25 s"),
            "{msg}"
        );
        assert!(msg.contains("told to fail"), "{msg}");
        let partial = f.partial.expect("partial results");
        // Steps from 0 to 0.24 completed: rows at 0, 0.01, ..., 0.25.
        assert_eq!(partial.n_rows(), 26, "{order:?}");
        let last = partial.last_row().unwrap();
        assert!((last[0] - 0.25).abs() < 1e-12 && (last[1] - 0.25).abs() < 1e-12);
    }
    let sys = System::new(1.0, h)
        .component("a", &path)
        .parameter("a", "k", Value::Real(f64::NAN));
    let f = run(&sys, &["a.y".into()], 1, &mut |_, _| {}).unwrap_err();
    let msg = f.to_string();
    assert!(
        msg.contains("a: output y is NaN after the step to t = 0.01"),
        "{msg}"
    );
    assert_eq!(f.partial.expect("partial").n_rows(), 1);
    // Timing: the loop contains the FMU calls.
    let sys = System::new(0.5, h).component("a", &path);
    let r = run(&sys, &[], 1, &mut |_, _| {}).unwrap();
    let t = &r.timing;
    assert_eq!(t.components.len(), 1);
    assert!(
        t.fmu_seconds > 0.0 && t.fmu_seconds <= t.loop_seconds,
        "{t:?}"
    );
    assert!((0.0..=1.0).contains(&t.master_share()));
}

#[test]
fn bad_connections_are_named() {
    let path = tiny_fmu("badconn", &tiny_xml(), &[], true);
    let base = || {
        System::new(0.1, 0.01)
            .component("a", &path)
            .component("b", &path)
    };
    let cases = [
        (
            base().connect("a.nosuch", "b.u"),
            "no variable named nosuch",
        ),
        (base().connect("a.u", "b.u"), "u is not an output"),
        (base().connect("a.y", "b.y"), "y is not an input"),
        (
            base().connect("a.steps", "b.u"),
            "a.steps is Integer and b.u is Real; a connection joins two variables of one type",
        ),
        (
            base().connect("a.y", "b.u").connect("b.y", "b.u"),
            "already connected",
        ),
        (base().connect("a.y", "c.u"), "no component named c"),
        (
            base().parameter("a", "k", Value::Boolean(true)),
            "a.k: k is Real, the value is Boolean",
        ),
        (
            base().parameter("a", "kk", Value::Real(1.0)),
            "no variable named kk",
        ),
        (base().every(0), "steps every 0 base steps"),
    ];
    for (sys, expected) in cases {
        match cosim::Simulation::new(&sys, &[]) {
            Err(e) => assert!(e.to_string().contains(expected), "{e} lacks {expected:?}"),
            Ok(_) => panic!("accepted a system that should fail with {expected:?}"),
        }
    }
    // An FMU error during the run names the component and the time.
    let sys = base().parameter("a", "k", Value::Real(-1.0));
    let e = run(&sys, &[], 1, &mut |_, _| {}).unwrap_err().to_string();
    assert!(
        e.contains("a: fmi2SetReal") && e.contains("k must be >= 0"),
        "{e}"
    );
}

/// The tiny FMU's model description with output y's unit element replaced by `real` (the
/// `<Real .../>` of y) and `types` inserted as its TypeDefinitions.
fn tiny_xml_y(real: &str, types: &str) -> String {
    let y = "<ScalarVariable name=\"y\" valueReference=\"1\" causality=\"output\" \
             variability=\"continuous\" initial=\"exact\"><Real start=\"0\" unit=\"m\"/>";
    let xml = tiny_xml();
    assert!(xml.contains(y), "the fixture changed");
    xml.replace(y, &y.replace("<Real start=\"0\" unit=\"m\"/>", real))
        .replace(
            "</UnitDefinitions>",
            &format!("</UnitDefinitions>\n  {types}"),
        )
}

/// Connected variables that both declare a unit must declare the same one: a.y in s into b.u in
/// m is refused, naming both ends and both units; the same unit, or a missing unit at either
/// end, passes. A unit comes from the `unit` attribute or, without one, from the variable's
/// declared type.
#[test]
fn connections_with_different_units_are_refused() {
    let metres = tiny_fmu("units_m", &tiny_xml(), &[], true);
    let seconds = tiny_fmu(
        "units_s",
        &tiny_xml_y("<Real start=\"0\" unit=\"s\"/>", ""),
        &[],
        true,
    );
    let none = tiny_fmu(
        "units_none",
        &tiny_xml_y("<Real start=\"0\"/>", ""),
        &[],
        true,
    );
    let types = "<TypeDefinitions><SimpleType name=\"Time\"><Real unit=\"s\"/></SimpleType>\
                 <SimpleType name=\"Length\"><Real unit=\"m\"/></SimpleType>\
                 <SimpleType name=\"Plain\"><Real/></SimpleType></TypeDefinitions>";
    let declared = |name: &str, ty: &str| {
        tiny_fmu(
            name,
            &tiny_xml_y(&format!("<Real start=\"0\" declaredType=\"{ty}\"/>"), types),
            &[],
            true,
        )
    };
    let (time, length, plain) = (
        declared("units_time", "Time"),
        declared("units_length", "Length"),
        declared("units_plain", "Plain"),
    );
    // The declared type's unit is the variable's.
    let md = Fmu::open(&time).unwrap().description;
    let y = md.variable_by_name("y").unwrap();
    assert_eq!(
        (y.unit.as_deref(), y.declared_type.as_deref()),
        (Some("s"), Some("Time"))
    );
    assert_eq!(
        Fmu::open(&plain)
            .unwrap()
            .description
            .variable_by_name("y")
            .unwrap()
            .unit,
        None
    );
    let system = |from: &Path| {
        System::new(0.1, 0.01)
            .component("a", from)
            .component("b", &metres)
            .connect("a.y", "b.u")
    };
    for from in [&seconds, &time] {
        match cosim::Simulation::new(&system(from), &[]) {
            Err(CosimError::Mismatch { what, reason }) => {
                assert_eq!(what, "a.y -> b.u");
                assert_eq!(reason, "units differ: a.y is in \"s\" but b.u is in \"m\"");
            }
            Err(e) => panic!("wrong error {e}"),
            Ok(_) => panic!("connected a.y in s to b.u in m"),
        }
    }
    let e = run(&system(&seconds), &[], 1, &mut |_, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("a.y") && e.contains("\"s\"") && e.contains("b.u") && e.contains("\"m\""),
        "{e}"
    );
    for from in [&metres, &none, &length, &plain] {
        let r = run(&system(from), &["b.y".into()], 1, &mut |_, _| {});
        assert!(r.is_ok(), "{}: {:?}", from.display(), r.err());
    }
}

/// fmi2Discard from doStep fails the run as fmi2Error does (the rows until then come back),
/// as its own error: the component, the function, the time and that the FMU discarded the step.
#[test]
fn a_discarded_step_fails_the_run_as_a_discard() {
    let path = tiny_fmu("discard", &tiny_xml(), &[], true);
    let sys = System::new(1.0, 0.01)
        .component("a", &path)
        .parameter("a", "u", Value::Real(1.0))
        .parameter("a", "discard_at", Value::Real(0.25))
        .component("b", &path)
        .connect("a.y", "b.u");
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let f = run(
            &sys.clone().order(order),
            &["a.y".into()],
            1,
            &mut |_, _| {},
        )
        .unwrap_err();
        let msg = f.to_string();
        assert!(
            msg.contains(
                "a: fmi2DoStep returned fmi2Discard at t = 0.25 s: the FMU discarded the step"
            ) && msg.contains("told to discard"),
            "{order:?}: {msg}"
        );
        match &f.error {
            CosimError::Discarded {
                component,
                function,
                ..
            } => assert_eq!((component.as_str(), *function), ("a", "fmi2DoStep")),
            other => panic!("{order:?}: expected Discarded, got {other:?}"),
        }
        assert_eq!(
            f.partial.expect("partial results").n_rows(),
            26,
            "{order:?}"
        );
    }
}

/// A system written as .ssp (the FMU inside, parameters inline, step and rates in the master
/// annotation) reads back to the same system and runs to the same results; a .ssd next to its
/// FMUs reads too.
#[test]
fn ssp_round_trip_runs_the_same() {
    use cosim::ssp;
    let path = tiny_fmu("ssp", &tiny_xml(), &[], true);
    let sys = System::new(0.2, 0.01)
        .component("a", &path)
        .parameter("a", "u", Value::Real(2.0))
        .parameter("a", "k", Value::Real(0.5))
        .component("b", &path)
        .every(2)
        .connect("a.y", "b.u")
        .order(Order::GaussSeidel);
    let dir = path.parent().unwrap();
    let file = dir.join("chain.ssp");
    ssp::write_ssp(&sys, "chain", &file).unwrap();
    let back = ssp::read(&file).unwrap();
    assert!(back.has_step);
    let s2 = &back.system;
    assert_eq!(s2.components.len(), 2);
    assert_eq!(
        (s2.step, s2.stop_time, s2.order),
        (0.01, 0.2, Order::GaussSeidel)
    );
    assert_eq!(s2.components[1].every, 2);
    assert_eq!(
        s2.components[0].parameters,
        vec![
            ("u".to_string(), Value::Real(2.0)),
            ("k".to_string(), Value::Real(0.5))
        ]
    );
    assert_eq!(s2.connections.len(), 1);
    let rec = ["b.y".to_string()];
    let r1 = run(&sys, &rec, 1, &mut |_, _| {}).unwrap();
    let r2 = run(s2, &rec, 1, &mut |_, _| {}).unwrap();
    assert_eq!(r1.values(), r2.values());
    // The .ssd alone, with its FMU at the relative source path.
    let ssd_dir = dir.join("ssd");
    std::fs::create_dir_all(ssd_dir.join("resources")).unwrap();
    std::fs::copy(&path, ssd_dir.join("resources/tiny.fmu")).unwrap();
    let text = ssp::ssd_text(
        &sys,
        "chain",
        &["resources/tiny.fmu".into(), "resources/tiny.fmu".into()],
    )
    .unwrap();
    std::fs::write(ssd_dir.join("chain.ssd"), &text).unwrap();
    let back = ssp::read(&ssd_dir.join("chain.ssd")).unwrap();
    let r3 = run(&back.system, &rec, 1, &mut |_, _| {}).unwrap();
    assert_eq!(r1.values(), r3.values());
    // Sources are URI references (SSP 1.0): a percent-encoded relative path and an absolute
    // file: URI give the same system.
    std::fs::create_dir_all(ssd_dir.join("my dir")).unwrap();
    std::fs::copy(&path, ssd_dir.join("my dir/tiny.fmu")).unwrap();
    let abs = ssd_dir.join("my dir/tiny.fmu").canonicalize().unwrap();
    let uri = format!("file://{}", abs.display().to_string().replace(' ', "%20"));
    let text = ssp::ssd_text(&sys, "chain", &["my%20dir/tiny.fmu".into(), uri]).unwrap();
    std::fs::write(ssd_dir.join("uri.ssd"), &text).unwrap();
    let back = ssp::read(&ssd_dir.join("uri.ssd")).unwrap();
    assert_eq!(back.system.components[1].fmu, abs);
    let r4 = run(&back.system, &rec, 1, &mut |_, _| {}).unwrap();
    assert_eq!(r1.values(), r4.values());
    // Schema-level checks, each named: stop before start, an unknown order, two components
    // of one name, no component.
    let start = text.find("startTime=\"").unwrap();
    let stop_at = text.find("stopTime=\"").unwrap();
    let end = stop_at + text[stop_at..].find('>').unwrap();
    let bad_cases = [
        (
            format!(
                "{}startTime=\"1\" stopTime=\"0.5\"{}",
                &text[..start],
                &text[end..]
            ),
            "stopTime 0.5 is before startTime 1",
        ),
        (
            text.replacen("order=\"", "order=\"random\" x=\"", 1),
            "order \"random\"",
        ),
        (
            text.replace("name=\"b\"", "name=\"a\""),
            "two components are named a",
        ),
    ];
    for (bad, why) in bad_cases {
        std::fs::write(ssd_dir.join("bad.ssd"), &bad).unwrap();
        let e = ssp::read(&ssd_dir.join("bad.ssd")).unwrap_err().to_string();
        assert!(e.contains(why) && e.contains("bad.ssd"), "{why}: {e}");
    }
    let empty = System::new(0.2, 0.01);
    let text = ssp::ssd_text(&empty, "empty", &[]).unwrap();
    std::fs::write(ssd_dir.join("empty.ssd"), &text).unwrap();
    let e = ssp::read(&ssd_dir.join("empty.ssd"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("no component"), "{e}");
    // A missing FMU is named.
    std::fs::remove_file(ssd_dir.join("resources/tiny.fmu")).unwrap();
    let e = ssp::read(&ssd_dir.join("chain.ssd"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("resources/tiny.fmu not found"), "{e}");
}

/// Counts the allocations of each thread of this test binary (the master's; the C test FMU
/// uses malloc), per thread so that tests running alongside do not count.
struct Counting;

thread_local! {
    static ALLOCATIONS: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

fn count() {
    ALLOCATIONS.with(|c| c.set(c.get() + 1));
}

// SAFETY: forwards to the system allocator unchanged, only counting the calls.
unsafe impl std::alloc::GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { std::alloc::System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { std::alloc::System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, size: usize) -> *mut u8 {
        count();
        // SAFETY: same contract as the caller's.
        unsafe { std::alloc::System.realloc(ptr, layout, size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

/// The step loop allocates nothing, recording included (every step, both orders, multi-rate):
/// the count of this thread's allocations is the same after the second step and after the
/// last (the components are too light for Jacobi's threads, so the loop runs on this one).
/// Only the look-ahead's timed trials allocate (a switch starts or ends its thread, a trial's
/// outcome is kept), every `lookahead_trial_every` base steps: none here.
#[test]
fn the_step_loop_does_not_allocate() {
    let path = tiny_fmu("no_alloc", &tiny_xml(), &[], true);
    let sys = System::new(0.5, 0.001)
        .scheduler(cosim::SchedulerParams {
            lookahead_trial_every: 0,
            ..cosim::SchedulerParams::default()
        })
        .component("a", &path)
        .parameter("a", "u", Value::Real(1.0))
        .component("b", &path)
        .every(4)
        .connect("a.y", "b.u")
        .component("c", &path)
        .connect("b.y", "c.u");
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let mut seen: Vec<usize> = Vec::with_capacity(1000);
        let mut progress = |_: f64, _: f64| {
            if seen.len() < seen.capacity() {
                seen.push(ALLOCATIONS.with(std::cell::Cell::get));
            }
        };
        let r = run(
            &sys.clone().order(order),
            &["a.y".into(), "b.y".into(), "c.y".into()],
            1,
            &mut progress,
        )
        .unwrap();
        assert_eq!(r.n_rows(), 501);
        assert_eq!(seen.len(), 500);
        assert_eq!(seen[1], seen[499], "{order:?}: the loop allocated");
    }
}

/// Opening an unchanged archive that is still open shares its unpacked files and library; once
/// every handle is gone it is unpacked afresh; a changed archive is never shared.
#[test]
fn an_open_fmu_is_shared_until_closed() {
    let path = tiny_fmu("shared", &tiny_xml(), &[], true);
    let a = Fmu::open(&path).unwrap();
    let b = Fmu::open(&path).unwrap();
    assert_eq!(a.unpacked_dir(), b.unpacked_dir());
    let dir = a.unpacked_dir().to_path_buf();
    drop((a, b));
    assert!(!dir.exists(), "unpacked files removed with the last handle");
    let c = Fmu::open(&path).unwrap();
    assert_ne!(c.unpacked_dir(), dir.as_path());
    // The same path rewritten (a longer model description: other size and time) is new.
    let other = tiny_fmu("shared", &format!("{}<!-- v2 -->", tiny_xml()), &[], true);
    assert_eq!(other, path);
    let d = Fmu::open(&path).unwrap();
    assert_ne!(d.unpacked_dir(), c.unpacked_dir());
}

/// Gauss-Seidel's look-ahead (every eligible component handed to the second thread: threshold
/// 0) gives bit for bit the values of the sequential order: a feeds b (every 3 steps) and c, b
/// feeds d (every 2). b is read by neither of the next turns, so it steps on the look-ahead
/// thread while c steps, and d waits for it. The step loop allocates nothing on this thread
/// with the look-ahead on, and a deferred component's failure is reported with its name,
/// function and time at the next wait.
#[test]
fn gauss_seidel_lookahead_changes_no_value() {
    let path = tiny_fmu("lookahead", &tiny_xml(), &[], true);
    // b from its own copy: only the sole instance of an FMU goes ahead.
    let own = path.with_file_name("tiny_b.fmu");
    std::fs::copy(&path, &own).unwrap();
    let sys = |fail_b: f64| {
        System::new(0.3, 0.001)
            .component("a", &path)
            .parameter("a", "u", Value::Real(1.5))
            .component("b", &own)
            .every(3)
            .parameter("b", "k", Value::Real(0.7))
            .parameter("b", "fail_at", Value::Real(fail_b))
            .component("c", &path)
            .component("d", &path)
            .every(2)
            .connect("a.y", "b.u")
            .connect("a.y", "c.u")
            .connect("b.y", "d.u")
            .order(Order::GaussSeidel)
    };
    let record = ["c.y".to_string(), "d.y".to_string()];
    let rows = |lookahead: Option<f64>| {
        let mut sim = cosim::Simulation::new(&sys(-1.0), &record).unwrap();
        sim.set_lookahead(lookahead).unwrap();
        let mut out = Vec::with_capacity(2 * 400);
        let mut row = [0.0; 2];
        let mut allocs = (0, 0);
        let mut k = 0;
        while !sim.finished() {
            sim.step().unwrap();
            sim.recorded_values(&mut row);
            out.extend_from_slice(&row);
            k += 1;
            // After the first waits (the channel's per-thread context is made once).
            if k == 30 {
                allocs.0 = ALLOCATIONS.with(std::cell::Cell::get);
            }
        }
        allocs.1 = ALLOCATIONS.with(std::cell::Cell::get);
        sim.settle().unwrap();
        (out, sim.lookahead_steps(), allocs)
    };
    // Sharing its FMU with another component, b stays on the master's thread.
    let mut shared = cosim::Simulation::new(
        &sys(-1.0).component("e", &own).connect("a.y", "e.u"),
        &record,
    )
    .unwrap();
    shared.set_lookahead(Some(0.0)).unwrap();
    while !shared.finished() {
        shared.step().unwrap();
    }
    assert_eq!(shared.lookahead_steps(), 0);
    let (plain, none, _) = rows(None);
    let (ahead, steps, allocs) = rows(Some(0.0));
    assert_eq!(none, 0);
    // b steps 100 times; all but none go ahead.
    assert!(steps >= 90, "{steps} steps went ahead");
    assert_eq!(plain.len(), 600);
    assert_eq!(plain, ahead, "the look-ahead changed a value");
    assert!(plain.iter().any(|&x| x != 0.0));
    assert_eq!(allocs.0, allocs.1, "the loop allocated");
    // A failure on the look-ahead thread.
    let mut sim = cosim::Simulation::new(&sys(0.15), &record).unwrap();
    sim.set_lookahead(Some(0.0)).unwrap();
    let e = loop {
        if let Err(e) = sim.step() {
            break e;
        }
        assert!(!sim.finished(), "b's failure was not reported");
    };
    let msg = e.to_string();
    assert!(
        msg.contains("b: fmi2DoStep returned fmi2Error at t = 0.15"),
        "{msg}"
    );
}

/// A slower component's step handed to the look-ahead thread is waited for by its readers only
/// once its outputs are due: a (every 5 base steps, 0.5 s per step) is read by b (every step);
/// c (every step, not reading a) comes after a, so a goes to the thread at base step 5 (at 0
/// its step time is not known yet). b's turns at base steps 6 to 8 read a's previous outputs
/// (a's step gives its own at base step 10) and go on: a's step is still under way after them
/// (before, each waited for it); b's turn at base step 9, whose step ends when a's outputs are
/// due, waits for it. The values are the sequential run's.
#[test]
fn a_slower_source_on_the_lookahead_thread_is_waited_for_when_its_outputs_are_due() {
    let path = tiny_fmu("slow_source", &tiny_xml(), &[], true);
    let own_a = path.with_file_name("tiny_slow_a.fmu");
    std::fs::copy(&path, &own_a).unwrap();
    let sys = System::new(0.011, 0.001)
        .component("b", &path)
        .component("a", &own_a)
        .every(5)
        .parameter("a", "u", Value::Real(1.5))
        .parameter("a", "busy", Value::Real(0.5))
        .component("c", &path)
        .parameter("c", "u", Value::Real(-0.25))
        .connect("a.y", "b.u")
        .order(Order::GaussSeidel);
    // a's outputs are not recorded (a recorded component stays on the master's thread unless
    // the rows can wait for it, `run`'s choice); b shows them.
    let record = ["b.y".to_string(), "c.y".to_string()];
    let rows = |lookahead: Option<f64>| {
        let mut sim = cosim::Simulation::new(&sys, &record).unwrap();
        sim.set_lookahead(lookahead).unwrap();
        let (mut out, mut row) = (Vec::new(), [0.0; 2]);
        let mut under_way = Vec::new();
        while !sim.finished() {
            sim.step().unwrap();
            sim.recorded_values(&mut row);
            out.extend_from_slice(&row);
            under_way.push(sim.in_flight_since());
        }
        sim.settle().unwrap();
        (out, under_way, sim.lookahead_steps())
    };
    let (plain, _, none) = rows(None);
    let (ahead, under_way, steps) = rows(Some(0.0));
    assert_eq!(none, 0);
    assert_eq!(
        steps, 2,
        "a's steps at base steps 5 and 10 go to the thread"
    );
    assert_eq!(under_way[5..9], [Some(5); 4], "{under_way:?}");
    assert_ne!(under_way[9], Some(5), "{under_way:?}");
    assert_eq!(plain, ahead, "the look-ahead changed a value");
    assert!(plain.iter().any(|&x| x != 0.0));
}

/// The memo follows the look-ahead thread: a (every 3 base steps) feeds b (every 3, the only
/// instance of its FMU, handed to the thread with its inputs kept there as the memo) and e
/// (every step, a sink kept there), so that e's steps between a's take a.y from the memo. The
/// thread stopped and started again mid-run has no memo: e's inputs then come with its step
/// (a kept step asking the new thread for a memo it does not have fails the run). Whether b
/// goes there at a turn depends on the timing (not while e's last step is under way there; a
/// busy step of a before it leaves the thread the time), so the run goes on until the memo has
/// been used, restarts the thread between two of a's
/// steps, and goes on until it is used again; c (recorded, reading b) gets the values of the
/// same steps without the thread.
#[test]
fn the_memo_follows_the_lookahead_thread() {
    let path = tiny_fmu("memo", &tiny_xml(), &[], true);
    let (own_b, own_e) = (
        path.with_file_name("tiny_memo_b.fmu"),
        path.with_file_name("tiny_memo_e.fmu"),
    );
    std::fs::copy(&path, &own_b).unwrap();
    std::fs::copy(&path, &own_e).unwrap();
    // Long enough never to end here.
    let sys = System::new(1000.0, 0.001)
        .component("a", &path)
        .every(3)
        .parameter("a", "u", Value::Real(1.5))
        // 0.1 ms of the master's time at a's steps: e's last step is done there by b's turn,
        // unless the thread gets no core meanwhile (other tests).
        .parameter("a", "busy", Value::Real(1e-4))
        .component("b", &own_b)
        .every(3)
        .component("e", &own_e)
        .component("c", &path)
        .every(3)
        .connect("a.y", "b.u")
        .connect("a.y", "e.u")
        .connect("b.y", "c.u")
        .order(Order::GaussSeidel);
    let record = ["c.y".to_string()];
    const MOST: usize = 30_000;
    let mut sim = cosim::Simulation::new(&sys, &record).unwrap();
    sim.set_lookahead(Some(0.0)).unwrap();
    let (mut ahead, mut row) = (Vec::new(), [0.0]);
    let mut step = |sim: &mut cosim::Simulation, out: &mut Vec<f64>| {
        sim.step().unwrap();
        sim.recorded_values(&mut row);
        out.push(row[0]);
    };
    // Until the memo is used, then to a step between two of a's.
    while sim.lookahead_memo_steps() == 0 || ahead.len() % 3 != 1 {
        assert!(ahead.len() < MOST, "the memo was never used");
        step(&mut sim, &mut ahead);
    }
    let before = sim.lookahead_memo_steps();
    sim.set_lookahead(None).unwrap();
    sim.set_lookahead(Some(0.0)).unwrap();
    while sim.lookahead_memo_steps() == before || ahead.len() % 3 != 0 {
        assert!(
            ahead.len() < 2 * MOST,
            "the memo was not used after the restart"
        );
        step(&mut sim, &mut ahead);
    }
    sim.settle().unwrap();
    let mut plain_sim = cosim::Simulation::new(&sys, &record).unwrap();
    plain_sim.set_lookahead(None).unwrap();
    let mut plain = Vec::new();
    while plain.len() < ahead.len() {
        step(&mut plain_sim, &mut plain);
    }
    assert_eq!(plain, ahead, "the look-ahead changed a value");
    assert!(plain.iter().any(|&x| x != 0.0));
}

/// Recorded components on the look-ahead thread (threshold 0): `run` gives the rows of the
/// sequential order bit for bit, in both orders, at every decimation. In Gauss-Seidel order b
/// (the only instance of its FMU, recorded, read only by d every third step) steps there while
/// the next components step, and so does e (recorded, read by nobody) when it steps every 4
/// base steps; stepping every base step, e is a sink, kept there in both orders, its steps
/// queued one after the other. The rows sampled meanwhile show
/// their previous outputs until the master patches them (b's integer step count is recorded
/// too). A slow sink (0.3 ms per step against the others' microseconds) fills the queue, and
/// the master waits for room; b then stays on the master's thread, not to wait behind it. A recorded component failing there ends the run as in the
/// sequential order, with the same error and the same rows kept.
#[test]
fn recorded_components_on_the_lookahead_thread_change_no_row() {
    use cosim::SchedulerParams;
    let path = tiny_fmu("lookahead_rows", &tiny_xml(), &[], true);
    let (own_b, own_e) = (
        path.with_file_name("tiny_b.fmu"),
        path.with_file_name("tiny_e.fmu"),
    );
    std::fs::copy(&path, &own_b).unwrap();
    std::fs::copy(&path, &own_e).unwrap();
    struct Case {
        order: Order,
        lookahead: bool,
        fail_e: f64,
        every_e: usize,
        busy_e: f64,
        stop: f64,
    }
    let sys = |c: &Case| {
        let mut s = System::new(c.stop, 0.001)
            .component("a", &path)
            .parameter("a", "u", Value::Real(1.5))
            .component("b", &own_b)
            .parameter("b", "k", Value::Real(0.7))
            .component("e", &own_e)
            .every(c.every_e)
            .parameter("e", "k", Value::Real(0.3))
            .parameter("e", "fail_at", Value::Real(c.fail_e))
            .parameter("e", "busy", Value::Real(c.busy_e))
            .component("d", &path)
            .every(3)
            .component("c", &path)
            .connect("a.y", "b.u")
            .connect("a.y", "c.u")
            .connect("a.y", "e.u")
            .connect("b.y", "d.u")
            .order(c.order)
            .scheduler(SchedulerParams {
                lookahead_min_seconds: 0.0,
                // Every eligible step there (the counts below): no timed trial.
                lookahead_trial_every: 0,
                ..SchedulerParams::default()
            });
        s.no_lookahead = !c.lookahead;
        s
    };
    let record = [
        "b.y".to_string(),
        "b.steps".to_string(),
        "e.y".to_string(),
        "d.y".to_string(),
    ];
    let cases = [
        (1, 1, 0.0, 0.2),
        (1, 3, 0.0, 0.2),
        (4, 1, 0.0, 0.2),
        (4, 3, 0.0, 0.2),
        (1, 1, 3e-4, 0.4),
    ];
    for order in [Order::GaussSeidel, Order::Jacobi] {
        for &(every_e, decimation, busy_e, stop) in &cases {
            let what =
                format!("{order:?}, e every {every_e}, decimation {decimation}, busy {busy_e}");
            let case = |lookahead| Case {
                order,
                lookahead,
                fail_e: -1.0,
                every_e,
                busy_e,
                stop,
            };
            let seq = run(&sys(&case(false)), &record, decimation, &mut |_, _| {}).unwrap();
            let la = run(&sys(&case(true)), &record, decimation, &mut |_, _| {}).unwrap();
            assert_eq!(seq.timing.lookahead_steps, 0, "{what}");
            let steps = (stop / 0.001).round() as u64;
            // Gauss-Seidel with e every 4 steps: b and e step there at most of their turns (b
            // not when d is next: 4 in 5 turns), so both are in flight at once. Jacobi: e
            // alone, kept from its second step on when it steps every base step.
            let (went, expected) = match (order, every_e) {
                // e kept from its second step on; b goes too when e's steps there are done
                // at its turn, which depends on timing (never for the slow sink).
                (Order::GaussSeidel, 1) => (la.timing.lookahead_steps, steps - 1),
                // e not a sink: b and e both handed over and back.
                (Order::GaussSeidel, _) => (
                    la.timing.lookahead_steps * 4,
                    (steps + steps / every_e as u64) * 3,
                ),
                (Order::Jacobi, 1) => (la.timing.lookahead_steps, steps - 1),
                (Order::Jacobi, _) => (la.timing.lookahead_steps * 1000, 0),
            };
            assert!(
                went >= expected && (order == Order::GaussSeidel || went <= expected),
                "{what}: {} steps went there",
                la.timing.lookahead_steps
            );
            // Gauss-Seidel with e kept: e reads a.y as b does, so at e's steps after b went
            // there in the same base step its input may be b's, kept there (the memo; how
            // often depends on the timing: `the_memo_follows_the_lookahead_thread`); when b
            // stayed on the master's thread (d next, or e's steps still under way), a.y has
            // changed since b's last one went there, and e's input comes as it is. Never in
            // Jacobi order, where nothing but e goes there.
            if order == Order::Jacobi {
                assert_eq!(la.timing.lookahead_memo_steps, 0, "{what}");
            }
            assert_eq!(seq.n_rows(), steps as usize / decimation + 1, "{what}");
            assert!(seq.values().iter().all(|x| x.is_finite()));
            assert!(seq.column("e.y").unwrap().iter().any(|&x| x != 0.0));
            assert_eq!(
                la.values(),
                seq.values(),
                "{what}: the look-ahead changed a row"
            );
        }
        // e fails at t = 0.05 on the look-ahead thread: the same error and the same rows kept.
        let failed = |lookahead| {
            let case = Case {
                order,
                lookahead,
                fail_e: 0.05,
                every_e: 1,
                busy_e: 0.0,
                stop: 0.2,
            };
            let f = run(&sys(&case), &record, 1, &mut |_, _| {}).unwrap_err();
            (
                f.error.to_string(),
                f.partial.expect("rows before the failure"),
            )
        };
        let (seq_msg, seq_rows) = failed(false);
        let (la_msg, la_rows) = failed(true);
        assert!(
            seq_msg.contains("e: fmi2DoStep returned fmi2Error at t = 0.05"),
            "{order:?}: {seq_msg}"
        );
        assert_eq!(la_msg, seq_msg, "{order:?}");
        assert_eq!(la_rows.values(), seq_rows.values(), "{order:?}");
        assert_eq!(seq_rows.n_rows(), 51, "{order:?}");
    }
}

/// Jacobi with one heavy component (a waits 0.4 ms per step, b and c 0.04 ms): a steps on this
/// thread while b and c step in turn on a worker, and every value is that of the same system
/// stepped on one thread (no waits). Gauss-Seidel through `run` with a component slow enough
/// for the default look-ahead threshold (b, 0.1 ms, read only by d every other step) gives the
/// values of the same system without waits too, the last deferred step included.
#[test]
fn threads_change_no_value() {
    let path = tiny_fmu("threads", &tiny_xml(), &[], true);
    let own = path.with_file_name("tiny_b.fmu");
    std::fs::copy(&path, &own).unwrap();
    let sys = |busy: [f64; 3], order: Order| {
        System::new(0.06, 0.001)
            .component("a", &path)
            .parameter("a", "u", Value::Real(1.0))
            .parameter("a", "busy", Value::Real(busy[0]))
            .component("b", &own)
            .parameter("b", "busy", Value::Real(busy[1]))
            .component("c", &path)
            .parameter("c", "busy", Value::Real(busy[2]))
            .component("d", &path)
            .every(2)
            .connect("a.y", "b.u")
            .connect("a.y", "c.u")
            .connect("b.y", "d.u")
            .order(order)
    };
    let record = ["a.y".to_string(), "c.y".to_string(), "d.y".to_string()];
    let values = |s: &System| -> (Vec<f64>, u64) {
        let mut sim = cosim::Simulation::new(s, &record).unwrap();
        let mut out = Vec::new();
        let mut row = [0.0; 3];
        while !sim.finished() {
            sim.step().unwrap();
            sim.recorded_values(&mut row);
            out.extend_from_slice(&row);
        }
        (out, sim.parallel_steps())
    };
    let (plain, none) = values(&sys([0.0; 3], Order::Jacobi));
    let (split, steps) = values(&sys([4e-4, 4e-5, 4e-5], Order::Jacobi));
    // Only the first step of the light system (nothing measured yet) goes parallel.
    assert!(none <= 1, "{none}");
    assert!(steps >= 50, "{steps} of 60 steps split");
    assert_eq!(plain, split);
    assert!(plain.iter().all(|x| x.is_finite()) && plain[plain.len() - 1] > 0.0);
    let rec = ["a.y".to_string(), "d.y".to_string()];
    let last = |busy| {
        let r = run(&sys(busy, Order::GaussSeidel), &rec, 1, &mut |_, _| {}).unwrap();
        assert_eq!(r.timing.components.len(), 4);
        r.last_row().unwrap().to_vec()
    };
    assert_eq!(last([0.0; 3]), last([0.0, 1e-4, 0.0]));
}

/// The look-ahead's timed trials change no value: with short trials (every 60 base steps,
/// blocks of 10 timed steps) the look-ahead thread is switched off and on during the run (a
/// busy component handed there, and a recorded sink kept there, which comes back at each
/// switch off), its steps counted across the switches, and the rows are those of the run
/// without the thread, bit for bit, in both orders; each trial is reported with its timings;
/// `set_lookahead` ends the trials.
#[test]
fn lookahead_trials_change_no_value() {
    use cosim::SchedulerParams;
    let path = tiny_fmu("trials", &tiny_xml(), &[], true);
    let own = path.with_file_name("tiny_trials_b.fmu");
    std::fs::copy(&path, &own).unwrap();
    let own_e = path.with_file_name("tiny_trials_e.fmu");
    std::fs::copy(&path, &own_e).unwrap();
    let sys = |order: Order, lookahead: bool| {
        let mut s = System::new(0.4, 0.001)
            .component("a", &path)
            .parameter("a", "u", Value::Real(1.0))
            .component("b", &own)
            .parameter("b", "k", Value::Real(0.5))
            .parameter("b", "busy", Value::Real(2e-5))
            .component("c", &path)
            .component("d", &path)
            .every(2)
            .component("e", &own_e)
            .parameter("e", "k", Value::Real(0.3))
            .connect("a.y", "b.u")
            .connect("a.y", "c.u")
            .connect("a.y", "e.u")
            .connect("b.y", "d.u")
            .order(order)
            .scheduler(SchedulerParams {
                lookahead_min_seconds: 0.0,
                lookahead_trial_every: 60,
                lookahead_trial_block: 10,
                ..SchedulerParams::default()
            });
        s.no_lookahead = !lookahead;
        s
    };
    let record = [
        "a.y".to_string(),
        "c.y".to_string(),
        "d.y".to_string(),
        "e.y".to_string(),
    ];
    for order in [Order::GaussSeidel, Order::Jacobi] {
        let plain = run(&sys(order, false), &record, 1, &mut |_, _| {}).unwrap();
        let tried = run(&sys(order, true), &record, 1, &mut |_, _| {}).unwrap();
        assert!(plain.timing.lookahead_trials.is_empty());
        let trials = &tried.timing.lookahead_trials;
        // 400 base steps: trials from base step 11, every 60 (the last may not end).
        assert!(trials.len() >= 5, "{order:?}: {trials:?}");
        for (n, t) in trials.iter().enumerate() {
            assert_eq!(t.step, 11 + 60 * n as u64, "{order:?}");
            assert!(t.with_seconds > 0.0 && t.with_seconds.is_finite(), "{t:?}");
            assert_eq!(
                t.kept,
                t.without_seconds.is_nan() || t.without_seconds >= t.with_seconds,
                "{t:?}"
            );
        }
        assert_eq!(
            plain.values(),
            tried.values(),
            "{order:?}: a trial changed a value"
        );
        assert!(plain.values().iter().any(|&x| x != 0.0));
        // e (kept there in both orders) and, in Gauss-Seidel order, b went there in each
        // trial's first block: each trial timed the run without the thread.
        assert!(trials.iter().all(|t| t.without_seconds > 0.0), "{trials:?}");
        if order == Order::GaussSeidel {
            assert!(
                tried.timing.lookahead_steps > 100,
                "{}",
                tried.timing.lookahead_steps
            );
        }
    }
    // An explicit choice ends the trials.
    let mut sim = cosim::Simulation::new(&sys(Order::GaussSeidel, true), &record).unwrap();
    sim.set_lookahead(Some(0.0)).unwrap();
    while !sim.finished() {
        sim.step().unwrap();
    }
    assert!(sim.lookahead_trials().is_empty());
}

/// The scheduler's thresholds come from the system ([`SchedulerParams`], today's values by
/// default) and change no value: every measured Jacobi step forced onto the threads (threshold
/// 0) or none (infinite thresholds), every eligible Gauss-Seidel step handed to the look-ahead thread
/// or none, give the values of the defaults.
#[test]
fn scheduler_params_change_no_value() {
    use cosim::SchedulerParams;
    let d = SchedulerParams::default();
    assert_eq!(
        (
            d.parallel_min_seconds,
            d.split_min_seconds,
            d.wake_seconds,
            d.lookahead_min_seconds,
            d.mean_weight,
            d.lookahead_trial_every,
            d.lookahead_trial_block,
        ),
        (2e-4, 5e-5, 1.5e-4, 5e-6, 0.05, 8000, 100)
    );
    assert_eq!(System::default().scheduler, d);
    let path = tiny_fmu("scheduler", &tiny_xml(), &[], true);
    let own = path.with_file_name("tiny_b.fmu");
    std::fs::copy(&path, &own).unwrap();
    let sys = |order: Order| {
        System::new(0.05, 0.001)
            .component("a", &path)
            .parameter("a", "u", Value::Real(1.0))
            .component("b", &own)
            .parameter("b", "k", Value::Real(0.5))
            .component("c", &path)
            .component("d", &path)
            .every(2)
            .connect("a.y", "b.u")
            .connect("a.y", "c.u")
            .connect("b.y", "d.u")
            .order(order)
    };
    // b (the only instance of its FMU, not recorded) is read by d only: it may go ahead.
    let record = ["a.y".to_string(), "c.y".to_string(), "d.y".to_string()];
    let values = |s: &System| -> (Vec<f64>, u64, u64) {
        let mut sim = cosim::Simulation::new(s, &record).unwrap();
        assert_eq!(sim.scheduler(), &s.scheduler);
        let mut out = Vec::new();
        let mut row = [0.0; 3];
        while !sim.finished() {
            sim.step().unwrap();
            sim.recorded_values(&mut row);
            out.extend_from_slice(&row);
        }
        sim.settle().unwrap();
        (out, sim.parallel_steps(), sim.lookahead_steps())
    };
    let always = SchedulerParams {
        parallel_min_seconds: 0.0,
        lookahead_min_seconds: 0.0,
        ..SchedulerParams::default()
    };
    let never = SchedulerParams {
        parallel_min_seconds: f64::INFINITY,
        split_min_seconds: f64::INFINITY,
        lookahead_min_seconds: f64::INFINITY,
        ..SchedulerParams::default()
    };
    for order in [Order::Jacobi, Order::GaussSeidel] {
        let (plain, ..) = values(&sys(order));
        let (threaded, parallel, ahead) = values(&sys(order).scheduler(always));
        let (single, parallel_none, ahead_none) = values(&sys(order).scheduler(never));
        assert_eq!(plain, threaded, "{order:?}");
        assert_eq!(plain, single, "{order:?}");
        assert!(plain.iter().any(|&x| x != 0.0));
        assert_eq!((parallel_none, ahead_none), (0, 0), "{order:?}");
        match order {
            // Every step but the first, before any step time is measured.
            Order::Jacobi => assert_eq!((parallel, ahead), (49, 0)),
            Order::GaussSeidel => assert!(parallel == 0 && ahead > 0, "{ahead}"),
        }
    }
}
