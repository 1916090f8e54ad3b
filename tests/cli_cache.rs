//! `m1cs cache` and the on-disk cache seen from the command line: a run stores the structure's
//! modes and the wind's tables, the next run reads them and records the same rows, `--clear`
//! empties the folder, `M1CS_CACHE=off` writes nothing.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;
use std::process::Command;

fn fmu_dir() -> String {
    std::env::var("M1CS_FMU_DIR")
        .unwrap_or_else(|_| concat!(env!("CARGO_MANIFEST_DIR"), "/target/fmu").to_string())
}

fn m1cs(cache: &Path, off: bool, args: &[&str]) -> String {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_m1cs"));
    cmd.args(args).env("M1CS_CACHE_DIR", cache);
    if off {
        cmd.env("M1CS_CACHE", "off");
    }
    let o = cmd.output().unwrap();
    assert!(
        o.status.success(),
        "m1cs {args:?}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn runs_fill_the_cache_and_read_it_back() {
    let dir = std::env::temp_dir().join(format!("m1cs-cli-cache-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let cache = dir.join("cache");
    let fmus = fmu_dir();
    let run = |out: &str, off: bool| {
        let out = dir.join(out);
        let out_s = out.to_string_lossy().into_owned();
        m1cs(
            &cache,
            off,
            &[
                "run",
                "--layout",
                "keck",
                "--duration",
                "0.05",
                "--no-plots",
                "--fmu-dir",
                &fmus,
                "--out",
                &out_s,
                "--json",
            ],
        );
        std::fs::read_to_string(out.join("closed_loop.csv")).unwrap()
    };
    let list = || -> serde_json::Value {
        serde_json::from_str(&m1cs(&cache, false, &["cache", "--json"])).unwrap()
    };
    let off = run("off", true);
    assert!(!cache.exists(), "M1CS_CACHE=off wrote {}", cache.display());
    let first = run("first", false);
    let v = list();
    let names: Vec<&str> = v["entries"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["file"].as_str().unwrap())
        .collect();
    assert_eq!(names.len(), 2, "{v}");
    assert!(names.iter().any(|n| n.starts_with("modes-")), "{v}");
    assert!(names.iter().any(|n| n.starts_with("wind-")), "{v}");
    let second = run("second", false);
    assert_eq!(first, off, "the cache changed the first run");
    assert_eq!(second, first, "the run from the cache differs");
    assert_eq!(list()["entries"].as_array().unwrap().len(), 2);
    let v: serde_json::Value =
        serde_json::from_str(&m1cs(&cache, false, &["cache", "--clear", "--json"])).unwrap();
    assert_eq!(v["removed"], 2, "{v}");
    assert!(list()["entries"].as_array().unwrap().is_empty());
    std::fs::remove_dir_all(&dir).ok();
}
