//! fmi2Set*: a batch is checked as a whole before anything is written, and what may be set
//! depends on causality, variability and the state (fixed parameters only before
//! fmi2ExitInitializationMode; inputs and tunable parameters also between steps).
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use fmu::fmi_sys::fmi2::fmi2Status;
use fmu::{Instance, VariableTable};

/// Every settable Real, Integer, Boolean and String, read back.
#[derive(Debug, PartialEq)]
struct Settable {
    reals: Vec<f64>,
    integers: Vec<i32>,
    booleans: Vec<bool>,
    strings: Vec<String>,
}

fn read_settable(fmu: &mut Fmu, t: &VariableTable) -> Settable {
    let mut reals = Vec::new();
    for name in ["tau", "gain", "y0", "bias", "panic_at", "u"] {
        reals.extend(fmu.get_reals_of(t, name));
    }
    Settable {
        reals,
        integers: fmu
            .get_integer(&[vr(t, "n", 0), vr(t, "substeps", 0)])
            .unwrap(),
        booleans: fmu.get_boolean(&[vr(t, "enabled", 0)]).unwrap(),
        strings: fmu
            .get_string(&[vr(t, "layout", 0), vr(t, "label", 0)])
            .unwrap(),
    }
}

fn start_values() -> Settable {
    Settable {
        reals: vec![0.5, 2.0, 0.1, 0.0, 0.0, 0.25, 0.25, 0.25],
        integers: vec![3, 4],
        booleans: vec![true],
        strings: vec!["small".into(), LABEL_START.into()],
    }
}

/// Batches with one bad entry (anywhere in the batch) fail as a whole, before and during
/// initialisation mode; the message names the offending scalar.
#[test]
fn failed_batch_changes_nothing() {
    let d = describe("small");
    let t = &d.table;
    let v = |name: &str, i: usize| vr(t, name, i);
    let real_batches: Vec<(Vec<u32>, Vec<f64>, &str)> = vec![
        (
            vec![v("tau", 0), v("gain", 0), v("u", 0), v("u", 1)],
            vec![2.0, 3.0, f64::NAN, 1.0],
            "u[1]",
        ),
        (
            vec![v("gain", 0), v("u", 0), v("tau", 0)],
            vec![3.0, 0.7, -1.0],
            "tau",
        ),
        (vec![v("gain", 0), v("tau", 0)], vec![3.0, 0.0], "tau"),
        (
            vec![v("gain", 0), v("panic_at", 0)],
            vec![3.0, -0.5],
            "panic_at",
        ),
        (
            vec![v("u", 0), v("u", 1), v("u", 2)],
            vec![1.0, 2000.0, 3.0],
            "u[2]",
        ),
        (
            vec![v("u", 0), v("u", 1), v("u", 2)],
            vec![1.0, 2.0, f64::INFINITY],
            "u[3]",
        ),
        (
            vec![v("gain", 0), v("bias", 0), v("y", 0)],
            vec![3.0, 1.0, 1.0],
            "y[1]",
        ),
        (vec![v("bias", 0), v("corner", 0)], vec![1.0, 1.0], "corner"),
        (vec![v("gain", 0), 9999], vec![3.0, 1.0], "9999"),
        (
            vec![v("gain", 0), v("n", 0)],
            vec![3.0, 3.0],
            "Real value reference",
        ),
    ];
    for in_init in [false, true] {
        let mut fmu = open("small");
        if in_init {
            assert_eq!(fmu.enter_init(), OK);
        }
        for (vrs, vals, culprit) in &real_batches {
            fmu.log.take();
            assert_eq!(
                fmu.set_real(vrs, vals),
                ERROR,
                "{vrs:?} = {vals:?} (in init: {in_init})"
            );
            assert!(fmu.logged(&["fmi2SetReal", culprit]), "{}", fmu.log.dump());
        }
        fmu.log.take();
        assert_eq!(
            fmu.set_integer(&[v("substeps", 0), v("n", 0)], &[8, 4]),
            ERROR
        );
        assert!(fmu.logged(&["n", "packaged value 3"]), "{}", fmu.log.dump());
        assert_eq!(
            fmu.set_integer(&[v("n", 0), v("substeps", 0)], &[3, 0]),
            ERROR
        );
        assert!(fmu.logged(&["substeps", "> 0"]), "{}", fmu.log.dump());
        assert_eq!(
            fmu.set_integer(&[v("substeps", 0), v("steps", 0)], &[8, 1]),
            ERROR,
            "steps is an output"
        );
        assert_eq!(
            fmu.set_boolean(&[v("enabled", 0), 9999], &[false, true]),
            ERROR
        );
        assert_eq!(
            fmu.set_boolean(&[v("enabled", 0), v("tau", 0)], &[false, true]),
            ERROR
        );
        assert_eq!(
            fmu.set_string(&[v("label", 0), v("layout", 0)], &["new", "big"]),
            ERROR
        );
        assert!(
            fmu.logged(&["layout", "packaged value small"]),
            "{}",
            fmu.log.dump()
        );

        if !in_init {
            assert_eq!(fmu.enter_init(), OK);
        }
        assert_eq!(
            read_settable(&mut fmu, t),
            start_values(),
            "in init: {in_init}"
        );

        // The same batches without the bad entry go through.
        assert_eq!(
            fmu.set_real(&[v("tau", 0), v("gain", 0), v("u", 1)], &[2.0, 3.0, 1.0]),
            OK
        );
        assert_eq!(fmu.set_integer(&[v("substeps", 0), v("n", 0)], &[8, 3]), OK);
        assert_eq!(
            fmu.set_string(&[v("label", 0), v("layout", 0)], &["new", "small"]),
            OK
        );
        assert_eq!(fmu.set_boolean(&[v("enabled", 0)], &[false]), OK);
        let mut want = start_values();
        want.reals[0] = 2.0;
        want.reals[1] = 3.0;
        want.reals[6] = 1.0;
        want.integers[1] = 8;
        want.booleans[0] = false;
        want.strings[1] = "new".into();
        assert_eq!(read_settable(&mut fmu, t), want);
    }
}

/// Between steps too: contiguous input batches (the runtime's fast path), scattered ones and
/// mixed ones.
#[test]
fn failed_batch_between_steps_changes_nothing() {
    let d = describe("small");
    let t = &d.table;
    let v = |name: &str, i: usize| vr(t, name, i);
    let mut fmu = open("small");
    fmu.init();
    assert_eq!(fmu.step(0.0, 0.1), OK);
    let before = read_settable(&mut fmu, t);
    let yd = fmu.get_reals_of(t, "yd");
    let batches: Vec<(Vec<u32>, Vec<f64>)> = vec![
        (vrs(t, "u"), vec![0.1, f64::NAN, 0.3]),
        (vec![v("u", 1), v("u", 2)], vec![0.5, f64::NEG_INFINITY]),
        (vec![v("u", 2), v("u", 0)], vec![0.1, f64::NAN]),
        (
            vec![v("u", 0), v("bias", 0), v("tau", 0)],
            vec![0.1, 0.2, 0.3],
        ),
        (vec![v("bias", 0), v("u", 0)], vec![0.2, f64::NAN]),
    ];
    for (vrs, vals) in &batches {
        assert_eq!(fmu.set_real(vrs, vals), ERROR, "{vrs:?} = {vals:?}");
    }
    assert_eq!(read_settable(&mut fmu, t), before);
    assert_eq!(fmu.get_reals_of(t, "yd"), yd);
    assert_eq!(fmu.log.entries().len(), batches.len(), "{}", fmu.log.dump());
}

/// After fmi2ExitInitializationMode only inputs and tunable parameters may be set; outputs
/// with a direct (elementwise) dependency on an input follow the input before the next step,
/// the others do not.
#[test]
fn tunable_and_inputs_only_after_initialisation() {
    let d = describe("small");
    let t = &d.table;
    let v = |name: &str, i: usize| vr(t, name, i);
    let mut fmu = open("small");
    assert_eq!(fmu.setup(0.0, None), OK);
    assert_eq!(fmu.enter_init(), OK);
    // Fixed parameters may be set in initialisation mode, and the calculated parameter
    // follows them before the exit.
    assert_eq!(fmu.set_real(&[v("tau", 0)], &[0.8]), OK);
    let corner = 1.0 / (2.0 * std::f64::consts::PI * 0.8);
    assert_eq!(fmu.get_reals_of(t, "corner"), [corner]);
    assert_eq!(fmu.exit_init(), OK);
    assert_eq!(fmu.step(0.0, 0.1), OK);

    // Fixed parameters are refused now, whatever their type.
    let refused: Vec<(&str, fmi2Status)> = vec![
        ("tau", fmu.set_real(&[v("tau", 0)], &[0.9])),
        ("gain", fmu.set_real(&[v("gain", 0)], &[1.0])),
        ("y0", fmu.set_real(&[v("y0", 0)], &[1.0])),
        ("panic_at", fmu.set_real(&[v("panic_at", 0)], &[1.0])),
        ("corner", fmu.set_real(&[v("corner", 0)], &[1.0])),
        ("yd[1]", fmu.set_real(&[v("yd", 0)], &[1.0])),
        ("n", fmu.set_integer(&[v("n", 0)], &[3])),
        ("substeps", fmu.set_integer(&[v("substeps", 0)], &[2])),
        ("enabled", fmu.set_boolean(&[v("enabled", 0)], &[true])),
        ("label", fmu.set_string(&[v("label", 0)], &["x"])),
        ("layout", fmu.set_string(&[v("layout", 0)], &["small"])),
    ];
    for (name, status) in refused {
        assert_eq!(status, ERROR, "{name}");
        assert!(
            fmu.logged(&[name, "cannot be set in state stepComplete"]),
            "{name}: {}",
            fmu.log.dump()
        );
    }
    assert_eq!(fmu.get_reals_of(t, "tau"), [0.8]);

    let y = fmu.get_reals_of(t, "y");
    let total = fmu.get_reals_of(t, "total");
    let gain = 2.0;
    let yd_of =
        |u: &[f64], bias: f64| -> Vec<f64> { (0..3).map(|i| y[i] + gain * u[i] + bias).collect() };
    assert_eq!(fmu.get_reals_of(t, "yd"), yd_of(&[0.25; 3], 0.0));

    // One input element: only its yd element changes, y and total do not.
    assert_eq!(fmu.set_real(&[v("u", 1)], &[1.5]), OK);
    assert_eq!(fmu.get_reals_of(t, "yd"), yd_of(&[0.25, 1.5, 0.25], 0.0));
    assert_eq!(fmu.get_reals_of(t, "y"), y);
    assert_eq!(fmu.get_reals_of(t, "total"), total);

    // The whole input and the tunable parameter.
    let u = [-1.0, 0.5, 2.0];
    assert_eq!(fmu.set_real(&vrs(t, "u"), &u), OK);
    assert_eq!(fmu.set_real(&[v("bias", 0)], &[0.125]), OK);
    assert_eq!(fmu.get_reals_of(t, "yd"), yd_of(&u, 0.125));
    assert_eq!(fmu.get_reals_of(t, "y"), y);
    assert!(fmu.log.take().len() == 11, "only the refusals were logged");

    // The next step integrates the new input: y(t+h) = u + (y - u) e^(-h/tau).
    assert_eq!(fmu.step(0.1, 0.1), OK);
    let y2 = fmu.get_reals_of(t, "y");
    for i in 0..3 {
        let want = u[i] + (y[i] - u[i]) * (-0.1f64 / 0.8).exp();
        assert!((y2[i] - want).abs() < 1e-12, "y[{i}] = {} != {want}", y2[i]);
    }
    let yd2 = fmu.get_reals_of(t, "yd");
    for i in 0..3 {
        assert_eq!(yd2[i], y2[i] + gain * u[i] + 0.125);
    }

    // After fmi2Terminate nothing may be set, but everything may be read.
    assert_eq!(fmu.terminate(), OK);
    assert_eq!(fmu.set_real(&[v("u", 0)], &[0.0]), ERROR);
    assert_eq!(fmu.set_real(&[v("bias", 0)], &[0.0]), ERROR);
    assert_eq!(fmu.get_reals_of(t, "y"), y2);
}

/// A step that produces a non-finite value fails (fmi2Error, state stepFailed): outputs stay
/// readable, nothing can be set or stepped, terminate is allowed.
#[test]
fn non_finite_step_result_fails_the_step() {
    let d = describe("small");
    let t = &d.table;
    let mut fmu = open("small");
    assert_eq!(fmu.enter_init(), OK);
    assert_eq!(fmu.set_real(&[vr(t, "gain", 0)], &[1e308]), OK);
    assert_eq!(fmu.exit_init(), OK);
    assert_eq!(fmu.set_real(&vrs(t, "u"), &[1000.0; 3]), OK);
    assert_eq!(fmu.step(0.0, 0.1), ERROR);
    assert!(
        fmu.logged(&["fmi2DoStep", "non-finite"]),
        "{}",
        fmu.log.dump()
    );
    assert!(fmu.get_reals_of(t, "yd").iter().all(|x| x.is_infinite()));
    assert_eq!(fmu.step(0.0, 0.1), ERROR);
    assert_eq!(fmu.set_real(&vrs(t, "u"), &[0.0; 3]), ERROR);
    assert_eq!(
        fmu.last_time(),
        0.0,
        "the failed step did not advance the time"
    );
    assert_eq!(fmu.terminate(), OK);
}

/// Inputs declared with a range check must be checked between steps too.
///
/// Fails today: `Instance::set_real` (instance.rs) takes a fast path in stepComplete for any
/// contiguous batch of one Real input and only rejects non-finite values, skipping the
/// variable's `Check` (`Range`, `Positive`, `NonNegative`), which the slow path applies.
#[test]

fn input_range_is_checked_between_steps() {
    let d = describe("small");
    let t = &d.table;
    let mut fmu = open("small");
    assert_eq!(fmu.enter_init(), OK);
    assert_eq!(
        fmu.set_real(&vrs(t, "u"), &[2000.0, 0.0, 0.0]),
        ERROR,
        "in init"
    );
    assert_eq!(fmu.exit_init(), OK);
    assert_eq!(
        fmu.set_real(&vrs(t, "u"), &[2000.0, 0.0, 0.0]),
        ERROR,
        "between steps, whole input"
    );
    assert_eq!(
        fmu.set_real(&[vr(t, "u", 1)], &[-2000.0]),
        ERROR,
        "between steps, one element"
    );
    assert_eq!(fmu.get_reals_of(t, "u"), [0.25; 3]);
}

/// `Instance::set_real` (the safe API, also usable in-process) with more values than value
/// references must not write past the named scalars.
///
/// Fails today: the fast path copies `vals.len()` values starting at the first value
/// reference (`reals[s..s + vals.len()]`), so `set_real(&[u1], &[1.0, 5.0])` also sets u[2]
/// (or, at the end of the store, panics with an out-of-range slice); the slow path zips and
/// ignores the surplus.
#[test]

fn instance_set_real_writes_only_the_named_scalars() {
    let d = describe("small");
    let t = &d.table;
    let mut inst = Instance::<Lag>::new("direct", &d.guid, None, None, false).unwrap();
    inst.enter_initialization_mode().unwrap();
    inst.exit_initialization_mode().unwrap();
    let r = inst.set_real(&[vr(t, "u", 0)], &[1.0, 5.0]);
    let mut u = [0.0; 3];
    inst.get_real(&vrs(t, "u"), &mut u).unwrap();
    match r {
        Err(_) => assert_eq!(u, [0.25; 3]),
        Ok(()) => assert_eq!(u, [1.0, 0.25, 0.25]),
    }
}

/// The in-process API agrees with the C shims (same table, same checks).
#[test]
fn instance_api_checks_like_the_shims() {
    let d = describe("small");
    let t = &d.table;
    let mut inst = Instance::<Lag>::new("direct", &d.guid, None, None, false).unwrap();
    assert_eq!(inst.variant(), "small");
    assert_eq!(inst.table(), t);
    assert_eq!(inst.state(), fmu::State::Instantiated);
    let e = inst.set_real(&[vr(t, "tau", 0)], &[-1.0]).unwrap_err();
    assert!(e.to_string().contains("tau"), "{e}");
    inst.enter_initialization_mode().unwrap();
    inst.exit_initialization_mode().unwrap();
    assert_eq!(inst.state(), fmu::State::StepComplete);
    let e = inst.set_real(&[vr(t, "gain", 0)], &[1.0]).unwrap_err();
    assert!(matches!(e, fmu::FmuError::NotSettable { .. }), "{e:?}");
    inst.do_step(0.0, 0.5).unwrap();
    assert_eq!(inst.time(), 0.5);
    assert!(inst.do_step(0.25, 0.5).is_err(), "time mismatch");
    assert!(inst.do_step(0.5, 0.0).is_err(), "h = 0");
    assert!(inst.do_step(0.5, f64::NAN).is_err(), "h = NaN");
}
