//! Malformed inputs never crash the importer or the SSP reader: property tests that mutate a
//! valid modelDescription.xml and SSD (byte deletions, insertions, truncations, duplications)
//! and feed random bytes as .fmu and .ssp archives. Every case must come back as `Ok` or as an
//! error naming the file; a panic fails the property.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::Write;
use std::path::{Path, PathBuf};

use cosim::description::ModelDescription;
use cosim::{Fmu, ssp};
use proptest::prelude::*;

const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures");

fn tiny_xml() -> String {
    std::fs::read_to_string(Path::new(FIXTURES).join("tiny.xml")).expect("fixture")
}

fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("cosim-fuzz-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).expect("scratch");
    d
}

/// One edit of a byte string.
#[derive(Debug, Clone)]
enum Edit {
    Delete(usize, usize),
    Insert(usize, Vec<u8>),
    Truncate(usize),
    Duplicate(usize, usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    let snippet = prop_oneof![
        proptest::collection::vec(any::<u8>(), 1..8),
        Just(b"<".to_vec()),
        Just(b"\"".to_vec()),
        Just(b"/>".to_vec()),
        Just(b"&amp".to_vec()),
        Just(b"valueReference=\"-1\"".to_vec()),
        Just(b"<ScalarVariable name=\"x\">".to_vec()),
        Just(b"causality=\"output\"".to_vec()),
        Just(b"every=\"0\"".to_vec()),
        Just(b"stepSize=\"nan\"".to_vec()),
    ];
    prop_oneof![
        (any::<usize>(), 1usize..40).prop_map(|(a, n)| Edit::Delete(a, n)),
        (any::<usize>(), snippet).prop_map(|(a, s)| Edit::Insert(a, s)),
        any::<usize>().prop_map(Edit::Truncate),
        (any::<usize>(), 1usize..60).prop_map(|(a, n)| Edit::Duplicate(a, n)),
    ]
}

fn apply(text: &[u8], edits: &[Edit]) -> Vec<u8> {
    let mut t = text.to_vec();
    for e in edits {
        let len = t.len().max(1);
        match e {
            Edit::Delete(a, n) => {
                let a = a % len;
                let b = (a + n).min(t.len());
                if a < b {
                    t.drain(a..b);
                }
            }
            Edit::Insert(a, s) => {
                let a = a % (t.len() + 1);
                t.splice(a..a, s.iter().copied());
            }
            Edit::Truncate(a) => t.truncate(a % len),
            Edit::Duplicate(a, n) => {
                let a = a % len;
                let b = (a + n).min(t.len());
                let piece = t[a..b].to_vec();
                t.splice(b..b, piece);
            }
        }
    }
    t
}

const SSV: &str = "<?xml version=\"1.0\"?><ssv:ParameterSet xmlns:ssv=\"http://ssp-standard.org/SSP1/SystemStructureParameterValues\" version=\"1.0\" name=\"p\"><ssv:Parameters><ssv:Parameter name=\"u\"><ssv:Real value=\"1\"/></ssv:Parameter></ssv:Parameters></ssv:ParameterSet>";

/// A folder with the files the SSD fixture refers to.
fn ssd_dir(name: &str) -> PathBuf {
    let dir = scratch(name);
    std::fs::create_dir_all(dir.join("resources")).expect("resources");
    std::fs::write(dir.join("resources/params.ssv"), SSV).expect("ssv");
    std::fs::write(
        dir.join("resources/tiny.fmu"),
        b"not read by the SSD reader",
    )
    .expect("fmu");
    dir
}

fn ssd() -> String {
    std::fs::read_to_string(Path::new(FIXTURES).join("fuzz.ssd")).expect("fixture")
}

fn zip_bytes(entries: &[(&str, &[u8])]) -> Vec<u8> {
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut z = zip::ZipWriter::new(&mut buf);
        for (name, data) in entries {
            z.start_file(*name, zip::write::SimpleFileOptions::default())
                .expect("zip entry");
            z.write_all(data).expect("zip data");
        }
        z.finish().expect("zip");
    }
    buf.into_inner()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 300, ..ProptestConfig::default() })]

    #[test]
    fn mutated_model_descriptions_never_panic(edits in proptest::collection::vec(edit(), 1..6)) {
        let xml = apply(tiny_xml().as_bytes(), &edits);
        let text = String::from_utf8_lossy(&xml);
        if let Err(e) = ModelDescription::parse(&text, Path::new("modelDescription.xml")) {
            prop_assert!(e.to_string().contains("modelDescription.xml"), "{e}");
        }
    }

    #[test]
    fn mutated_ssds_never_panic(edits in proptest::collection::vec(edit(), 1..6)) {
        let dir = ssd_dir("ssd");
        let path = dir.join("fuzz.ssd");
        std::fs::write(&path, apply(ssd().as_bytes(), &edits)).expect("write");
        let _ = ssp::read(&path);
    }

    #[test]
    fn mutated_archives_never_panic(
        edits in proptest::collection::vec(edit(), 1..4),
        which in 0usize..2,
    ) {
        let dir = scratch("zip");
        let valid = if which == 0 {
            zip_bytes(&[("modelDescription.xml", tiny_xml().as_bytes())])
        } else {
            zip_bytes(&[
                ("SystemStructure.ssd", ssd().as_bytes()),
                ("resources/params.ssv", SSV.as_bytes()),
                ("resources/tiny.fmu", b"x"),
            ])
        };
        let bytes = apply(&valid, &edits);
        let (name, open): (&str, fn(&Path) -> bool) = if which == 0 {
            ("fuzz.fmu", |p| Fmu::open(p).is_ok())
        } else {
            ("fuzz.ssp", |p| ssp::read(p).is_ok())
        };
        let path = dir.join(name);
        std::fs::write(&path, bytes).expect("write");
        let _ = open(&path);
    }

    #[test]
    fn random_bytes_are_not_archives(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let dir = scratch("random");
        for name in ["random.fmu", "random.ssp"] {
            let path = dir.join(name);
            std::fs::write(&path, &bytes).expect("write");
            let e = if name.ends_with("fmu") {
                Fmu::open(&path).err().map(|e| e.to_string())
            } else {
                ssp::read(&path).err().map(|e| e.to_string())
            };
            let e = e.expect("random bytes accepted as an archive");
            prop_assert!(e.contains(name), "{e}");
        }
    }
}

/// The unmutated inputs are valid, so the mutations start from code paths that parse deep.
#[test]
fn the_seeds_parse() {
    ModelDescription::parse(&tiny_xml(), Path::new("modelDescription.xml")).expect("tiny.xml");
    let dir = ssd_dir("seed");
    let path = dir.join("fuzz.ssd");
    std::fs::write(&path, ssd()).expect("ssd");
    let s = ssp::read(&path).expect("fuzz.ssd");
    assert_eq!(s.system.components.len(), 2);
    assert_eq!(s.system.connections.len(), 1);
    assert_eq!(s.system.components[0].every, 2);
    assert_eq!(s.system.components[0].parameters.len(), 4);
    let archive = dir.join("seed.ssp");
    std::fs::write(
        &archive,
        zip_bytes(&[
            ("SystemStructure.ssd", ssd().as_bytes()),
            ("resources/params.ssv", SSV.as_bytes()),
            ("resources/tiny.fmu", b"x"),
        ]),
    )
    .expect("ssp");
    assert_eq!(
        ssp::read(&archive)
            .expect("seed.ssp")
            .system
            .components
            .len(),
        2
    );
}
