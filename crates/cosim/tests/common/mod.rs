//! Helpers shared by the importer's test binaries: scratch folders, the system C compiler on the
//! fixtures (FMUs written in plain C), and zipped FMUs.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The fixtures folder.
pub const FIXTURES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures");

/// An empty folder `<tmp>/<prefix>-<pid>-<name>`.
pub fn scratch(prefix: &str, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs the C compiler (`$CC`, else `cc`) on `args`, failing the test with its messages.
pub fn cc(args: &[&std::ffi::OsStr]) {
    let out = Command::new(std::env::var("CC").unwrap_or_else(|_| "cc".into()))
        .args(args)
        .output()
        .expect("run the C compiler");
    assert!(
        out.status.success(),
        "cc failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Compiles the fixture `source` (e.g. `tiny.c`) to a shared library of the same stem in `dir`,
/// with the preprocessor `defines` (`NAME` or `NAME=VALUE`).
pub fn compile_fixture(dir: &Path, source: &str, defines: &[&str]) -> PathBuf {
    let stem = Path::new(source)
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap();
    let so = dir.join(format!("{stem}.so"));
    let src = Path::new(FIXTURES).join(source);
    let defines: Vec<String> = defines.iter().map(|d| format!("-D{d}")).collect();
    let mut args: Vec<&std::ffi::OsStr> = vec![
        "-shared".as_ref(),
        "-fPIC".as_ref(),
        "-O1".as_ref(),
        "-o".as_ref(),
        so.as_os_str(),
        src.as_os_str(),
    ];
    args.extend(defines.iter().map(std::ffi::OsStr::new));
    cc(&args);
    so
}

/// Zips `entries` (archive path, bytes) into `path`.
pub fn zip_fmu(path: &Path, entries: &[(&str, Vec<u8>)]) {
    let f = std::fs::File::create(path).unwrap();
    let mut z = zip::ZipWriter::new(f);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (name, bytes) in entries {
        z.start_file(*name, opts).unwrap();
        z.write_all(bytes).unwrap();
    }
    z.finish().unwrap();
}
