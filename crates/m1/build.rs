//! The build's fingerprint for the on-disk cache (`src/linalg/cache.rs`): a hash of this
//! crate's sources and of the workspace's Cargo.lock, so that an entry computed by another
//! version of the code, or with other versions of its dependencies, is never read.

use std::hash::{Hash, Hasher};
use std::path::Path;

fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let lock = root.join("../../Cargo.lock");
    println!("cargo:rerun-if-changed=src");
    println!("cargo:rerun-if-changed={}", lock.display());
    let mut files = Vec::new();
    sources(&root.join("src"), &mut files);
    files.sort();
    files.push(lock);
    // Two differently seeded SipHash-1-3 passes: 128 bits, enough to name builds apart.
    let mut a = std::collections::hash_map::DefaultHasher::new();
    let mut b = std::collections::hash_map::DefaultHasher::new();
    "m1cs-cache".hash(&mut b);
    for f in &files {
        let rel = f
            .strip_prefix(root)
            .unwrap_or(f)
            .to_string_lossy()
            .into_owned();
        let bytes = std::fs::read(f).unwrap_or_default();
        for h in [&mut a, &mut b] {
            rel.hash(h);
            bytes.hash(h);
        }
    }
    println!(
        "cargo:rustc-env=M1_BUILD_FINGERPRINT={:016x}{:016x}",
        a.finish(),
        b.finish()
    );
}
