//! fmi2GetFMUstate / fmi2SetFMUstate / fmi2FreeFMUstate and the serialisation functions.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use common::*;
use fmu::VariableTable;
use fmu::ffi;
use fmu::fmi_sys::fmi2::*;

const H: f64 = 0.05;

fn input(n: usize, k: usize) -> Vec<f64> {
    (0..n)
        .map(|i| ((k * 7 + i * 3) % 11) as f64 / 4.0 - 1.0)
        .collect()
}

/// Sets the input of step k, steps, returns (y, yd, total, steps).
fn advance(fmu: &mut Fmu, t: &VariableTable, k: usize) -> (Vec<f64>, i32) {
    let n = t.by_name("u").unwrap().len;
    assert_eq!(fmu.set_real(&vrs(t, "u"), &input(n, k)), OK);
    assert_eq!(fmu.step(k as f64 * H, H), OK, "{}", fmu.log.dump());
    outputs(fmu, t)
}

fn outputs(fmu: &mut Fmu, t: &VariableTable) -> (Vec<f64>, i32) {
    let mut out = fmu.get_reals_of(t, "y");
    out.extend(fmu.get_reals_of(t, "yd"));
    out.extend(fmu.get_reals_of(t, "total"));
    out.extend(fmu.get_reals_of(t, "u"));
    (out, fmu.get_integer(&[vr(t, "steps", 0)]).unwrap()[0])
}

fn run(fmu: &mut Fmu, t: &VariableTable, ks: std::ops::Range<usize>) -> Vec<(Vec<f64>, i32)> {
    ks.map(|k| advance(fmu, t, k)).collect()
}

/// An initialised "small" instance (tau = 0.3) stepped 10 times.
fn stepped() -> (Fmu, fmu::package::Description) {
    let d = describe("small");
    let mut fmu = open("small");
    assert_eq!(fmu.setup(0.0, None), OK);
    assert_eq!(fmu.enter_init(), OK);
    assert_eq!(fmu.set_real(&[vr(&d.table, "tau", 0)], &[0.3]), OK);
    assert_eq!(fmu.exit_init(), OK);
    run(&mut fmu, &d.table, 0..10);
    (fmu, d)
}

/// A new FMU state of `fmu` taken now, and its serialised bytes.
fn saved(fmu: &mut Fmu) -> (fmi2FMUstate, Vec<u8>) {
    let mut s: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.get_state(&mut s), OK);
    let blob = fmu.serialize(s).unwrap();
    (s, blob)
}

/// `blob` is refused by fmi2DeSerializeFMUstate, nothing is allocated, and one logged message
/// contains every one of `parts`.
fn assert_refused(fmu: &mut Fmu, blob: &[u8], parts: &[&str]) {
    let mut slot: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.deserialize(blob, &mut slot), ERROR);
    assert!(slot.is_null(), "nothing allocated");
    assert!(fmu.logged(parts), "{}", fmu.log.dump());
}

#[test]
fn get_and_set_state_restore() {
    let (mut fmu, d) = stepped();
    let t = &d.table;
    let at10 = outputs(&mut fmu, t);
    let mut s: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.get_state(&mut s), OK);
    assert!(!s.is_null());
    let first = run(&mut fmu, t, 10..30);
    assert_ne!(outputs(&mut fmu, t), at10);

    assert_eq!(fmu.set_state(s), OK, "{}", fmu.log.dump());
    assert_eq!(fmu.last_time(), 9.0 * H + H);
    assert_eq!(outputs(&mut fmu, t), at10);
    assert_eq!(
        run(&mut fmu, t, 10..30),
        first,
        "replay from the saved state"
    );

    // The state can be set again (it is not consumed), and a second get into the same slot
    // overwrites it in place.
    assert_eq!(fmu.set_state(s), OK);
    run(&mut fmu, t, 10..15);
    let at15 = outputs(&mut fmu, t);
    let before = s;
    assert_eq!(fmu.get_state(&mut s), OK);
    assert_eq!(s, before, "the slot's state was reused");
    run(&mut fmu, t, 15..20);
    assert_eq!(fmu.set_state(s), OK);
    assert_eq!(
        fmu.last_time(),
        14.0 * H + H,
        "the time after the step from t = 14 H"
    );
    assert_eq!(outputs(&mut fmu, t), at15);
    // A step from the wrong time is refused after the restore: the time was restored too.
    assert_eq!(fmu.step(20.0 * H, H), ERROR);
    assert_eq!(fmu.step(15.0 * H, H), OK);

    assert_eq!(fmu.free_state(&mut s), OK);
    assert!(s.is_null());
}

/// A state saved before initialisation restores the state machine too.
#[test]
fn state_restores_the_state_machine() {
    let d = describe("small");
    let mut fmu = open("small");
    let mut s: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.get_state(&mut s), OK, "allowed in Instantiated");
    fmu.init();
    assert_eq!(fmu.step(0.0, H), OK);
    assert_eq!(fmu.enter_init(), ERROR);
    assert_eq!(fmu.set_state(s), OK);
    assert_eq!(fmu.enter_init(), OK, "back in Instantiated");
    assert_eq!(fmu.get_integer(&[vr(&d.table, "steps", 0)]).unwrap(), [0]);
    assert_eq!(fmu.free_state(&mut s), OK);
}

#[test]
fn serialize_deserialize_set_reproduces_exactly() {
    let (mut fmu, d) = stepped();
    let t = &d.table;
    let at10 = outputs(&mut fmu, t);
    let (mut s, blob) = saved(&mut fmu);
    assert!(blob.len() > 8);
    let first = run(&mut fmu, t, 10..30);
    assert_eq!(fmu.free_state(&mut s), OK);

    // Into a new state of the same instance.
    let mut r: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.deserialize(&blob, &mut r), OK, "{}", fmu.log.dump());
    assert!(!r.is_null());
    assert_eq!(fmu.serialize(r).unwrap(), blob, "byte-exact round trip");
    assert_eq!(fmu.set_state(r), OK);
    assert_eq!(fmu.last_time(), 9.0 * H + H);
    assert_eq!(outputs(&mut fmu, t), at10);
    assert_eq!(run(&mut fmu, t, 10..30), first);

    // Into an existing slot: overwritten in place.
    let before = r;
    assert_eq!(fmu.deserialize(&blob, &mut r), OK);
    assert_eq!(r, before);
    assert_eq!(fmu.free_state(&mut r), OK);

    // Into a fresh instance that was only instantiated: it continues exactly the same.
    let mut other = open("small");
    let mut r2: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(
        other.deserialize(&blob, &mut r2),
        OK,
        "{}",
        other.log.dump()
    );
    assert_eq!(other.set_state(r2), OK);
    assert_eq!(outputs(&mut other, t), at10);
    assert_eq!(run(&mut other, t, 10..30), first);
    assert_eq!(other.free_state(&mut r2), OK);
}

/// A state saved with another layout's tag (an older build of these FMUs) is refused with a
/// message naming both layouts; bytes that are no state of ours at all, with the plain one.
#[test]
fn state_of_another_layout_is_refused_naming_it() {
    let (mut fmu, _) = stepped();
    let (mut s, blob) = saved(&mut fmu);
    assert_eq!(fmu.free_state(&mut s), OK);
    assert!(blob.starts_with(b"M1CSST"), "{:?}", &blob[..8]);
    // The layout this build reads (it changes with the models' states), and an older one.
    let now = format!("reads {}", String::from_utf8_lossy(&blob[6..8]));
    assert_ne!(now, "reads 02");
    let mut old = blob.clone();
    old[6..8].copy_from_slice(b"02");
    assert_refused(
        &mut fmu,
        &old,
        &["another version of these FMUs", "layout 02", &now],
    );
    let mut junk = blob;
    junk[..8].copy_from_slice(b"NOTASTAT");
    assert_refused(&mut fmu, &junk, &["not a serialized state of this FMU"]);
}

#[test]
fn state_of_the_other_variant_is_refused() {
    let big = describe("big");
    let mut b = open("big");
    b.init();
    assert_eq!(b.step(0.0, H), OK);
    let mut sb: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(b.get_state(&mut sb), OK);
    let blob = b.serialize(sb).unwrap();

    let (mut small, d) = stepped();
    let before = outputs(&mut small, &d.table);
    assert_refused(&mut small, &blob, &["fmi2DeSerializeFMUstate", "GUID"]);
    // A live state of the other variant is refused by fmi2SetFMUstate as well.
    small.log.take();
    assert_eq!(small.set_state(sb), ERROR);
    assert!(
        small.logged(&["fmi2SetFMUstate", &big.guid]),
        "{}",
        small.log.dump()
    );
    // The instance is unchanged and still steps.
    assert_eq!(outputs(&mut small, &d.table), before);
    assert_eq!(small.step(10.0 * H, H), OK);
    assert_eq!(b.free_state(&mut sb), OK);
}

#[test]
fn truncated_or_corrupt_blobs_are_refused() {
    let (mut fmu, d) = stepped();
    let (mut s, blob) = saved(&mut fmu);
    let before = outputs(&mut fmu, &d.table);
    let mut cuts = vec![0, 1, 4, 7, 8, 9, 16, blob.len() / 2, blob.len() - 1];
    cuts.retain(|&c| c < blob.len());
    for cut in cuts {
        let mut slot: fmi2FMUstate = std::ptr::null_mut();
        fmu.log.take();
        assert_eq!(
            fmu.deserialize(&blob[..cut], &mut slot),
            ERROR,
            "cut at {cut}"
        );
        assert!(slot.is_null(), "cut at {cut}");
        assert!(
            fmu.logged(&["fmi2DeSerializeFMUstate", "cannot deserialize"]),
            "cut at {cut}: {}",
            fmu.log.dump()
        );
    }
    // Another magic.
    let mut bad = blob.clone();
    bad[0] ^= 0xff;
    let mut slot: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.deserialize(&bad, &mut slot), ERROR);
    assert!(slot.is_null());
    // A failed deserialisation into an existing slot leaves that state as it was.
    let mut kept = s;
    assert_eq!(fmu.deserialize(&blob[..blob.len() - 1], &mut kept), ERROR);
    assert_eq!(kept, s);
    assert_eq!(fmu.serialize(s).unwrap(), blob);
    // The instance is unchanged.
    assert_eq!(outputs(&mut fmu, &d.table), before);
    assert_eq!(fmu.free_state(&mut s), OK);
}

#[test]
fn serialize_needs_the_exact_size() {
    let (mut fmu, _) = stepped();
    let mut s: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.get_state(&mut s), OK);
    let n = fmu.serialize(s).unwrap().len();
    for size in [n - 1, n + 1] {
        let mut buf = vec![0u8; size];
        // SAFETY: a buffer of `size` bytes.
        let st =
            unsafe { ffi::serialize::<Lag>(fmu.c, s, buf.as_mut_ptr() as *mut fmi2Byte, size) };
        assert_eq!(st, ERROR, "size {size} for {n}");
        assert!(buf.iter().all(|&b| b == 0), "nothing written");
    }
    assert_eq!(fmu.free_state(&mut s), OK);
}

#[test]
fn free_of_null_is_fine() {
    let mut fmu = open("small");
    let mut s: fmi2FMUstate = std::ptr::null_mut();
    assert_eq!(fmu.free_state(&mut s), OK, "slot holding NULL");
    // SAFETY: a NULL slot pointer is what is being tested.
    assert_eq!(
        unsafe { ffi::free_fmu_state::<Lag>(fmu.c, std::ptr::null_mut()) },
        OK,
        "NULL slot pointer"
    );
    assert_eq!(fmu.set_state(std::ptr::null_mut()), ERROR, "set NULL");
    // SAFETY: NULL slot pointer.
    assert_eq!(
        unsafe { ffi::get_fmu_state::<Lag>(fmu.c, std::ptr::null_mut()) },
        ERROR,
        "get into NULL"
    );
    assert!(fmu.log.entries().iter().all(|e| e.message.contains("NULL")));
}

/// fmi2Reset restores the start values and the initial model.
#[test]
fn reset_restores_the_start() {
    let (mut fmu, d) = stepped();
    assert_eq!(fmu.reset(), OK);
    assert_eq!(fmu.enter_init(), OK);
    assert_eq!(fmu.get_reals_of(&d.table, "tau"), [0.5]);
    assert_eq!(fmu.get_reals_of(&d.table, "u"), [0.25; 3]);
    assert_eq!(fmu.get_integer(&[vr(&d.table, "steps", 0)]).unwrap(), [0]);
    assert_eq!(fmu.exit_init(), OK);
    assert_eq!(fmu.last_time(), 0.0);
    assert_eq!(fmu.step(0.0, H), OK);
}

/// The bulk paths of fmi2SetReal and fmi2GetReal (a contiguous run of an array's value
/// references, between steps): a non-finite value anywhere in the run is refused, naming the
/// scalar, and nothing is written; finite values are written and read back in order.
#[test]
fn bulk_transfers_check_every_value_and_copy_in_order() {
    let (mut fmu, d) = stepped();
    let t = &d.table;
    let u = vrs(t, "u");
    let n = u.len();
    assert!(n >= 2, "the test model's u is an array");
    let before = fmu.get_reals_of(t, "u");
    for at in 0..n {
        for bad in [f64::NAN, f64::INFINITY] {
            let mut vals = input(n, 3);
            vals[at] = bad;
            fmu.log.take();
            assert_eq!(fmu.set_real(&u, &vals), ERROR);
            assert!(
                fmu.logged(&["fmi2SetReal", &format!("u[{}]", at + 1), "finite"]),
                "{}",
                fmu.log.dump()
            );
            assert_eq!(fmu.get_reals_of(t, "u"), before, "nothing written");
        }
    }
    let vals = input(n, 5);
    assert_eq!(fmu.set_real(&u, &vals), OK);
    assert_eq!(fmu.get_reals_of(t, "u"), vals);
}
