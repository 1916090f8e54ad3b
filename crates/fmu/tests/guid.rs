//! The GUID identifies one table: stable for the same table, different for any change, and
//! what fmi2Instantiate uses to pick the packaged variant.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::path::PathBuf;

use common::*;
use fmu::Model;

fn guid_of(variant: &str, opts: Options) -> String {
    let (t, _) = lag_table(variant, opts).unwrap();
    fmu::xml::guid(&Lag::INFO, &t)
}

#[test]
fn same_table_same_guid() {
    let a = guid_of("small", Options::default());
    let b = guid_of("small", Options::default());
    assert_eq!(a, b);
    assert_eq!(a, describe("small").guid);
    assert_eq!(describe("small").guid, describe("small").guid);
    // {8-4-4-4-12} lower-case hex.
    let inner = a
        .strip_prefix('{')
        .and_then(|s| s.strip_suffix('}'))
        .unwrap();
    let groups: Vec<usize> = inner.split('-').map(str::len).collect();
    assert_eq!(groups, [8, 4, 4, 4, 12], "{a}");
    assert!(
        inner
            .chars()
            .all(|c| c == '-' || c.is_ascii_digit() || ('a'..='f').contains(&c)),
        "{a}"
    );
    // The XML carries the GUID it was hashed into.
    assert_eq!(parse_xml(&describe("small").xml).attrs["guid"], a);
}

#[test]
fn any_change_changes_the_guid() {
    let base = guid_of("small", Options::default());
    let tau = guid_of(
        "small",
        Options {
            tau_start: 0.6,
            ..Options::default()
        },
    );
    let extra = guid_of(
        "small",
        Options {
            extra: true,
            ..Options::default()
        },
    );
    let big = guid_of("big", Options::default());
    // The model information is hashed too: another default step is another description.
    let (t, _) = lag_table("small", Options::default()).unwrap();
    let step = fmu::xml::guid(
        &fmu::ModelInfo {
            default_step: Lag::INFO.default_step * 2.0,
            ..Lag::INFO
        },
        &t,
    );
    let all = [&base, &tau, &extra, &big, &step];
    for (i, a) in all.iter().enumerate() {
        for b in &all[i + 1..] {
            assert_ne!(a, b);
        }
    }
}

/// With a NULL resource location every packaged variant is tried: the GUID picks the layout.
#[test]
fn guid_selects_the_variant() {
    for (variant, n) in [("small", 3), ("big", 5)] {
        let d = describe(variant);
        let mut fmu = instantiate("v", &d.guid, None, false).unwrap();
        assert_eq!(fmu.enter_init(), OK);
        assert_eq!(fmu.get_integer(&[vr(&d.table, "n", 0)]).unwrap(), [n]);
        assert_eq!(
            fmu.get_string(&[vr(&d.table, "layout", 0)]).unwrap(),
            [variant]
        );
        // Every element of the variant's arrays exists, and nothing past the last Real.
        let u = fmu.get_reals_of(&d.table, "u");
        assert_eq!(u, vec![0.25; n as usize]);
        let yd = fmu.get_reals_of(&d.table, "yd");
        assert_eq!(yd.len(), n as usize);
        let n_reals = d.table.counts()[0] as u32;
        assert_eq!(fmu.get_real(&[n_reals]), Err(ERROR));
    }
    // The small variant has fewer Reals: a value reference valid in "big" is not a Real there.
    let small = describe("small");
    let big = describe("big");
    let last_big_real = big.table.counts()[0] as u32 - 1;
    let mut fmu = instantiate("s", &small.guid, None, false).unwrap();
    assert_eq!(fmu.enter_init(), OK);
    assert_eq!(fmu.get_real(&[last_big_real]), Err(ERROR));
}

#[test]
fn wrong_guid_is_refused_with_a_message() {
    let log = match instantiate("w", "{00000000-0000-0000-0000-000000000000}", None, false) {
        Ok(_) => panic!("instantiated with a wrong GUID"),
        Err(log) => log,
    };
    let e = log.entries();
    assert_eq!(e.len(), 1, "{}", log.dump());
    assert_eq!(e[0].status, ERROR as i32);
    assert_eq!(e[0].category, "logStatusError");
    assert_eq!(e[0].instance, "w");
    assert!(e[0].message.contains("GUID"), "{}", e[0].message);
    assert!(e[0].message.contains("fmi2Instantiate"), "{}", e[0].message);
    // The message lists what would have matched.
    assert!(
        e[0].message.contains(&describe("small").guid),
        "{}",
        e[0].message
    );

    // A GUID from another build of the model (one more variable).
    let other = guid_of(
        "small",
        Options {
            extra: true,
            ..Options::default()
        },
    );
    assert!(instantiate("w2", &other, None, false).is_err());
}

/// A model-exchange request is refused, with a message.
#[test]
fn model_exchange_is_refused() {
    use fmu::fmi_sys::fmi2::*;
    use std::ffi::c_void;
    let guid = std::ffi::CString::new(describe("small").guid).unwrap();
    // SAFETY: valid strings, NULL callbacks (the failure goes to stderr).
    let c = unsafe {
        fmu::ffi::instantiate::<Lag>(
            c"me".as_ptr(),
            fmi2Type::fmi2ModelExchange as i32,
            guid.as_ptr(),
            std::ptr::null(),
            std::ptr::null(),
            fmi2False,
            fmi2False,
        )
    };
    assert_eq!(c, std::ptr::null_mut::<c_void>());
    // NULL GUID and NULL name are refused too.
    // SAFETY: as above.
    let c = unsafe {
        fmu::ffi::instantiate::<Lag>(
            c"x".as_ptr(),
            fmi2Type::fmi2CoSimulation as i32,
            std::ptr::null(),
            std::ptr::null(),
            std::ptr::null(),
            fmi2False,
            fmi2False,
        )
    };
    assert!(c.is_null());
    // SAFETY: as above.
    let c = unsafe {
        fmu::ffi::instantiate::<Lag>(
            std::ptr::null(),
            fmi2Type::fmi2CoSimulation as i32,
            guid.as_ptr(),
            std::ptr::null(),
            std::ptr::null(),
            fmi2False,
            fmi2False,
        )
    };
    assert!(c.is_null());
}

// ---------------------------------------------------------------------------------------------
// resources/variant.txt
// ---------------------------------------------------------------------------------------------

/// A temporary unpacked-FMU directory with `resources/variant.txt`, removed on drop.
struct Unpacked {
    root: PathBuf,
}

impl Unpacked {
    fn new(tag: &str, variant: &str) -> Self {
        let root = std::env::temp_dir().join(format!("fmu-guid-test-{}-{tag}", std::process::id()));
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(root.join("resources")).unwrap();
        std::fs::write(root.join("resources/variant.txt"), format!("{variant}\n")).unwrap();
        Self { root }
    }
    fn resources(&self) -> String {
        self.root.join("resources").to_str().unwrap().to_string()
    }
}

impl Drop for Unpacked {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.root);
    }
}

fn tiny_guid() -> String {
    guid_of("tiny", Options::default())
}

/// "tiny" is not among `Lag::variants()`: only `resources/variant.txt` can name it.
#[test]
fn resource_variant_file_names_the_variant() {
    let dir = Unpacked::new("tiny", "tiny");
    let res = dir.resources();
    assert!(
        instantiate("none", &tiny_guid(), None, false).is_err(),
        "tiny is not a packaged variant"
    );
    for uri in [
        format!("file://{res}"),
        format!("file://{res}/"),
        format!("file://localhost{res}"),
    ] {
        let mut fmu = instantiate("tiny", &tiny_guid(), Some(&uri), false)
            .unwrap_or_else(|l| panic!("{uri}: {}", l.dump()));
        assert_eq!(fmu.enter_init(), OK);
        let (t, _) = lag_table("tiny", Options::default()).unwrap();
        assert_eq!(fmu.get_integer(&[vr(&t, "n", 0)]).unwrap(), [2], "{uri}");
    }
}

/// The variant file is authoritative: a GUID of another variant is refused.
#[test]
fn resource_variant_file_must_agree_with_the_guid() {
    let dir = Unpacked::new("mismatch", "small");
    let uri = format!("file://{}", dir.resources());
    let log = match instantiate("m", &describe("big").guid, Some(&uri), false) {
        Ok(_) => panic!("big GUID accepted with variant.txt = small"),
        Err(l) => l,
    };
    assert!(log.dump().contains("GUID"), "{}", log.dump());
    assert!(instantiate("m", &describe("small").guid, Some(&uri), false).is_ok());
}

/// Percent-encoded resource URIs (spaces) are decoded.
#[test]
fn resource_uri_is_percent_decoded() {
    let dir = Unpacked::new("with space", "tiny");
    let uri = format!("file://{}", dir.resources().replace(' ', "%20"));
    assert!(
        instantiate("pct", &tiny_guid(), Some(&uri), false).is_ok(),
        "{uri}"
    );
}

/// `file:/abs/path` (one slash, as some importers write it) is documented in instance.rs as
/// accepted, but `resource_dir` strips "file://" first and returns None for it, so the
/// variant file is silently ignored and the instance falls back to the packaged variants.
#[test]

fn resource_uri_with_one_slash() {
    let dir = Unpacked::new("one-slash", "tiny");
    let uri = format!("file:{}", dir.resources());
    assert!(uri.starts_with("file:/") && !uri.starts_with("file://"));
    let r = instantiate("one", &tiny_guid(), Some(&uri), false);
    assert!(r.is_ok(), "{uri}: {}", r.err().unwrap().dump());
}

/// A '%' followed by a hex digit and a multi-byte UTF-8 character (a raw, unencoded path as
/// some C importers pass it) makes `percent_decode` slice a str inside a character: a panic,
/// caught by fmi2Instantiate, which returns NULL without calling the logger.
#[test]

fn resource_uri_with_raw_non_ascii_after_percent() {
    let dir = Unpacked::new("x%aé", "tiny");
    let uri = format!("file://{}", dir.resources());
    let r = instantiate("raw", &tiny_guid(), Some(&uri), false);
    assert!(r.is_ok(), "{uri}: {}", r.err().unwrap().dump());
}
