//! The crate's folders depend one way (issue 15): outside comments, a folder refers only to the
//! folders listed before it in `lib.rs`'s map (`linalg` serves all).
#![allow(clippy::unwrap_used, clippy::expect_used)] // tests panic on failure by design

use std::path::Path;

/// The map's order; `linalg` may be used from anywhere.
const ORDER: [&str; 7] = [
    "aperture", "sensing", "control", "optics", "loads", "plant", "analysis",
];

fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn folders_depend_one_way() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut bad = Vec::new();
    for (rank, folder) in ORDER.iter().enumerate() {
        let mut files = Vec::new();
        sources(&src.join(folder), &mut files);
        assert!(!files.is_empty(), "{folder}: no sources");
        for f in files {
            let text = std::fs::read_to_string(&f).unwrap();
            for later in &ORDER[rank + 1..] {
                // Doc comments are allowed to point downstream ("used by ..."); code is not.
                let uses = text
                    .lines()
                    .filter(|l| !l.trim_start().starts_with("//"))
                    .any(|l| l.contains(&format!("crate::{later}::")));
                if uses {
                    bad.push(format!("{} uses crate::{later}", f.display()));
                }
            }
        }
    }
    assert!(bad.is_empty(), "against the grain:\n{}", bad.join("\n"));
    // Every folder is in the map and the map lists every folder.
    let lib = std::fs::read_to_string(src.join("lib.rs")).unwrap();
    for folder in ORDER.iter().chain(&["linalg"]) {
        assert!(lib.contains(&format!("pub mod {folder};")), "{folder}");
        assert!(
            lib.contains(&format!("[`{folder}`]")),
            "{folder} not in the map"
        );
    }
}
