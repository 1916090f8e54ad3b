//! Build orchestration for the workspace (`cargo xtask <command>`, an alias in .cargo/config.toml).
//!
//! - `package [LAYOUT...]`: release-builds every FMU crate and writes
//!   `target/fmu/<layout>/<model>.fmu` (default layouts: keck, tmt, elt).
//! - `venv`: creates `.venv` with the Python packages the tests use (tests/python/requirements.txt).
//! - `test`: package, venv, `cargo test --release --workspace`, `cargo doc` (warnings are
//!   errors), then pytest on tests/python.
//! - `doc [ARGS]`: the API documentation (`cargo doc --workspace`, maths rendered with KaTeX,
//!   warnings are errors) into target/doc.
//! - `run [ARGS]`: the main job: package the TMT FMUs, then `m1cs run ARGS` (with no arguments,
//!   the TMT wind scenario, open and closed loop, into results/).
//! - `demo`: package, then run `m1cs demo` (the segments' step responses and stiffness).

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use fmu::FmuError;

/// One FMU crate: its cdylib name and its packaging functions.
struct FmuCrate {
    name: &'static str,
    write: fn(&str, &Path, &Path) -> Result<PathBuf, FmuError>,
    /// Read by the test of the README's FMU table.
    #[cfg_attr(not(test), allow(dead_code))]
    describe: fn(&str) -> Result<fmu::package::Description, FmuError>,
}

const FMUS: &[FmuCrate] = &[
    FmuCrate {
        name: "segments_voicecoil",
        write: fmu::package::write_fmu::<segments::VoiceCoil>,
        describe: fmu::package::describe::<segments::VoiceCoil>,
    },
    FmuCrate {
        name: "segments_piezo",
        write: fmu::package::write_fmu::<segments::Piezo>,
        describe: fmu::package::describe::<segments::Piezo>,
    },
    FmuCrate {
        name: "mirror_voicecoil",
        write: fmu::package::write_fmu::<mirror::VoiceCoil>,
        describe: fmu::package::describe::<mirror::VoiceCoil>,
    },
    FmuCrate {
        name: "mirror_piezo",
        write: fmu::package::write_fmu::<mirror::Piezo>,
        describe: fmu::package::describe::<mirror::Piezo>,
    },
    FmuCrate {
        name: "structure",
        write: fmu::package::write_fmu::<structure_model::Structure>,
        describe: fmu::package::describe::<structure_model::Structure>,
    },
    FmuCrate {
        name: "wind",
        write: fmu::package::write_fmu::<wind_model::Wind>,
        describe: fmu::package::describe::<wind_model::Wind>,
    },
    FmuCrate {
        name: "pier_vibration",
        write: fmu::package::write_fmu::<pier_vibration_model::PierVibrationFmu>,
        describe: fmu::package::describe::<pier_vibration_model::PierVibrationFmu>,
    },
    FmuCrate {
        name: "deformation",
        write: fmu::package::write_fmu::<deformation_model::DeformationFmu>,
        describe: fmu::package::describe::<deformation_model::DeformationFmu>,
    },
    FmuCrate {
        name: "aps",
        write: fmu::package::write_fmu::<aps_model::ApsFmu>,
        describe: fmu::package::describe::<aps_model::ApsFmu>,
    },
    FmuCrate {
        name: "optical_feedback",
        write: fmu::package::write_fmu::<optical_feedback_model::OpticalFeedbackFmu>,
        describe: fmu::package::describe::<optical_feedback_model::OpticalFeedbackFmu>,
    },
    FmuCrate {
        name: "optics",
        write: fmu::package::write_fmu::<optics_model::Optics>,
        describe: fmu::package::describe::<optics_model::Optics>,
    },
    FmuCrate {
        name: "edge_sensors",
        write: fmu::package::write_fmu::<edge_sensors_model::EdgeSensorsModel>,
        describe: fmu::package::describe::<edge_sensors_model::EdgeSensorsModel>,
    },
    FmuCrate {
        name: "global_controller",
        write: fmu::package::write_fmu::<global_controller_model::GlobalControllerModel>,
        describe: fmu::package::describe::<global_controller_model::GlobalControllerModel>,
    },
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_default()
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root().join("target"))
}

fn run(cmd: &mut Command) -> Result<(), String> {
    eprintln!("+ {cmd:?}");
    let start = std::time::Instant::now();
    let status = cmd
        .current_dir(root())
        .status()
        .map_err(|e| format!("cannot start {cmd:?}: {e}"))?;
    // Each step's wall time, so that a CI log shows where the suite's time goes.
    eprintln!("  ({:.0} s)", start.elapsed().as_secs_f64());
    if status.success() {
        Ok(())
    } else {
        Err(format!("{cmd:?} failed with {status}"))
    }
}

/// Whether `cargo <tool> --version` runs (rustfmt and clippy are rustup components that a
/// minimal toolchain lacks); says so on stderr when it does not.
fn has_component(tool: &str) -> bool {
    let ok = cargo()
        .args([tool, "--version"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        eprintln!("note: `cargo {tool}` is not installed: its check is skipped");
    }
    ok
}

fn cargo() -> Command {
    Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
}

fn package(layouts: &[String]) -> Result<(), String> {
    let mut build = cargo();
    build.args(["build", "--release"]);
    for f in FMUS {
        build.args(["-p", f.name]);
    }
    run(&mut build)?;
    let layouts: Vec<String> = if layouts.is_empty() {
        m1::aperture::layout::Layout::PRESETS
            .iter()
            .map(|s| s.to_string())
            .collect()
    } else {
        layouts.to_vec()
    };
    for layout in &layouts {
        let out = target_dir().join("fmu").join(layout);
        for f in FMUS {
            let lib = target_dir()
                .join("release")
                .join(format!("lib{}.so", f.name));
            let path = (f.write)(layout, &lib, &out).map_err(|e| format!("{}: {e}", f.name))?;
            eprintln!("wrote {}", path.display());
        }
    }
    Ok(())
}

fn venv() -> Result<PathBuf, String> {
    let dir = root().join(".venv");
    let python = dir.join("bin").join("python");
    let req = root().join("tests").join("python").join("requirements.txt");
    let stamp = dir.join(".requirements");
    let wanted = std::fs::read_to_string(&req).map_err(|e| format!("{}: {e}", req.display()))?;
    if std::fs::read_to_string(&stamp).ok().as_deref() == Some(wanted.as_str()) && python.exists() {
        return Ok(python);
    }
    let py = std::env::var("PYTHON").unwrap_or_else(|_| "python3".into());
    run(Command::new(&py).args(["-m", "venv"]).arg(&dir))?;
    run(Command::new(&python).args(["-m", "pip", "install", "--quiet", "--upgrade", "pip"]))?;
    run(Command::new(&python)
        .args(["-m", "pip", "install", "--quiet", "-r"])
        .arg(&req))?;
    std::fs::write(&stamp, wanted).map_err(|e| e.to_string())?;
    Ok(python)
}

fn test(extra: &[String]) -> Result<(), String> {
    package(&[])?;
    let python = venv()?;
    // The tests' own on-disk cache of computed arrays (m1::linalg::cache), emptied first: the
    // suite computes the modes and wind tables it needs once and reads them after, without
    // touching the user's cache.
    let cache = target_dir().join("test-cache");
    let _ = std::fs::remove_dir_all(&cache);
    // The sources are formatted and lint-free (every target: tests and benches too), where
    // the toolchain has rustfmt and clippy (rustup's default profile does).
    if has_component("fmt") {
        run(cargo().args(["fmt", "--all", "--check"]))?;
    }
    if has_component("clippy") {
        run(cargo().args([
            "clippy",
            "--release",
            "--workspace",
            "--all-targets",
            "--",
            "-D",
            "warnings",
        ]))?;
    }
    run(cargo()
        .args(["test", "--release", "--workspace"])
        .env("M1CS_CACHE_DIR", &cache))?;
    // The API documentation builds without a warning (broken or private intra-doc links).
    doc(&[])?;
    // One pytest worker per core (pytest-xdist): the suite is single-threaded Python for most
    // of its time (fmpy's validation of the ELT and TMT descriptions above all), and
    // work-stealing evens out its few long cases. Arguments after `test` come last, so an
    // explicit `-n 0` runs it in one process.
    let workers = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut pytest = Command::new(python);
    pytest
        .args(["-m", "pytest", "-q", "tests/python"])
        .args(["-n", &workers.to_string(), "--dist", "worksteal"])
        .args(extra)
        .env("M1CS_FMU_DIR", target_dir().join("fmu"))
        .env("M1CS_CACHE_DIR", &cache);
    run(&mut pytest)
}

/// `cargo doc` for the workspace with the maths rendered (KaTeX, docs/rustdoc/katex-header.html)
/// and every rustdoc warning an error.
fn doc(extra: &[String]) -> Result<(), String> {
    let header = root()
        .join("docs")
        .join("rustdoc")
        .join("katex-header.html");
    run(cargo()
        .args(["doc", "--release", "--no-deps", "--workspace"])
        .args(extra)
        // The encoded form (arguments separated by 0x1f) keeps a path with spaces whole.
        .env(
            "CARGO_ENCODED_RUSTDOCFLAGS",
            format!("-D\x1fwarnings\x1f--html-in-header\x1f{}", header.display()),
        ))
}

fn demo(extra: &[String]) -> Result<(), String> {
    package(&["keck".into(), "tmt".into()])?;
    run(cargo()
        .args(["run", "--quiet", "--release", "-p", "m1cs", "--", "demo"])
        .args(extra))
}

fn run_main(extra: &[String]) -> Result<(), String> {
    package(&["tmt".into()])?;
    run(cargo()
        .args(["run", "--quiet", "--release", "-p", "m1cs", "--", "run"])
        .args(extra))
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (cmd, rest) = match args.split_first() {
        Some((c, r)) => (c.as_str(), r),
        None => ("help", &[][..]),
    };
    let r = match cmd {
        "package" => package(rest),
        "venv" => venv().map(|p| eprintln!("python: {}", p.display())),
        "test" => test(rest),
        "doc" => doc(rest),
        "demo" => demo(rest),
        "run" => run_main(rest),
        _ => {
            eprintln!(
                "usage: cargo xtask <package [LAYOUT...] | venv | test [PYTEST ARGS] | doc [CARGO DOC ARGS] | run [M1CS RUN ARGS] | demo [ARGS]>"
            );
            return if cmd == "help" {
                ExitCode::SUCCESS
            } else {
                ExitCode::FAILURE
            };
        }
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::variables::Causality;

    /// The signals a cell of the README's FMU table lists: `name[size]` or `name`, each
    /// followed by its unit in parentheses or sharing the next one (`z[na]`, `z_cell[na]` (m)).
    fn signals(cell: &str) -> Vec<(String, String, String)> {
        let mut out = Vec::new();
        let mut pending: Vec<(String, String)> = Vec::new();
        let mut rest = cell;
        while let Some(open) = rest.find('`') {
            let after = &rest[open + 1..];
            let Some(close) = after.find('`') else { break };
            let token = &after[..close];
            let (name, size) = match token.split_once('[') {
                Some((n, s)) => (n.to_string(), s.trim_end_matches(']').to_string()),
                None => (token.to_string(), "1".to_string()),
            };
            pending.push((name, size));
            rest = &after[close + 1..];
            let next_tick = rest.find('`').unwrap_or(rest.len());
            if let Some(p) = rest[..next_tick].find('(') {
                let unit_end = rest[p..].find(')').map_or(rest.len(), |e| p + e);
                let unit = rest[p + 1..unit_end].to_string();
                out.extend(pending.drain(..).map(|(n, s)| (n, s, unit.clone())));
            }
        }
        out.extend(pending.drain(..).map(|(n, s)| (n, s, String::new())));
        out
    }

    /// Every FMU of the README's table (section "The FMUs") lists exactly the inputs and
    /// outputs its variable table declares, with their sizes and units, on every layout; and
    /// every packaged FMU has a row.
    #[test]
    fn the_readme_fmu_table_is_the_variable_tables() {
        let readme = std::fs::read_to_string(root().join("README.md")).expect("README.md");
        let section = readme
            .split("\n## The FMUs")
            .nth(1)
            .expect("a section The FMUs");
        let rows: Vec<Vec<&str>> = section
            .lines()
            .skip_while(|l| !l.starts_with("| FMU |"))
            .skip(2)
            .take_while(|l| l.starts_with('|'))
            .map(|l| l.trim_matches('|').split(" | ").map(str::trim).collect())
            .collect();
        let mut seen = Vec::new();
        let mut previous: Option<(Vec<_>, Vec<_>)> = None;
        for row in &rows {
            let [names, _, inputs, outputs] = row.as_slice() else {
                panic!("a row of 4 columns: {row:?}")
            };
            let same = |cell: &str, prev: Option<&Vec<_>>| {
                if cell.trim() == "same" {
                    prev.expect("'same' after a row").clone()
                } else {
                    signals(cell)
                }
            };
            let ins = same(inputs, previous.as_ref().map(|p| &p.0));
            let outs = same(outputs, previous.as_ref().map(|p| &p.1));
            for name in names.split(',').map(|n| n.trim().trim_matches('`')) {
                let fmu = FMUS
                    .iter()
                    .find(|f| f.name == name)
                    .unwrap_or_else(|| panic!("README lists {name}, which is not packaged"));
                seen.push(name);
                for layout in ["keck", "tmt"] {
                    let table = (fmu.describe)(layout).expect("describe").table;
                    let layout = m1::aperture::layout::Layout::preset(layout).expect("layout");
                    let size = |s: &str| match s {
                        "na" => layout.n_actuators(),
                        "ns" => layout.n_sensors(),
                        n => n.parse().unwrap_or_else(|_| panic!("size {n}")),
                    };
                    for (causality, listed) in
                        [(Causality::Input, &ins), (Causality::Output, &outs)]
                    {
                        let declared: Vec<_> = table
                            .variables()
                            .iter()
                            .filter(|v| v.causality == causality)
                            .collect();
                        let mut a: Vec<&str> = declared.iter().map(|v| v.name.as_str()).collect();
                        let mut b: Vec<&str> = listed.iter().map(|s| s.0.as_str()).collect();
                        a.sort_unstable();
                        b.sort_unstable();
                        assert_eq!(a, b, "{name} {}s", causality.xml());
                        for (signal, sz, unit) in listed.iter() {
                            let v = declared.iter().find(|v| &v.name == signal).expect("listed");
                            assert_eq!(v.len, size(sz), "{name}.{signal} size {sz}");
                            if let Some(u) = &v.unit {
                                assert!(
                                    unit.split(", ").any(|x| x == u) || unit == u,
                                    "{name}.{signal}: README says ({unit}), declared {u}"
                                );
                            }
                        }
                    }
                }
            }
            previous = Some((ins, outs));
        }
        let mut packaged: Vec<&str> = FMUS.iter().map(|f| f.name).collect();
        packaged.sort_unstable();
        seen.sort_unstable();
        assert_eq!(seen, packaged, "every packaged FMU has a row");
    }

    #[test]
    fn signal_cells_parse() {
        let s = signals("`z[na]`, `z_cell[na]` (m), `f_cell[na]` (N), `pssn` (1)");
        let want = [
            ("z", "na", "m"),
            ("z_cell", "na", "m"),
            ("f_cell", "na", "N"),
            ("pssn", "1", "1"),
        ];
        assert_eq!(s.len(), want.len());
        for (got, w) in s.iter().zip(want) {
            assert_eq!((got.0.as_str(), got.1.as_str(), got.2.as_str()), w);
        }
    }
}
