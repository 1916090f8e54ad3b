//! Build orchestration for the workspace (`cargo xtask <command>`, an alias in .cargo/config.toml).
//!
//! - `package [LAYOUT...]`: release-builds every FMU crate and writes
//!   `target/fmu/<layout>/<model>.fmu` (default layouts: keck, tmt, elt).
//! - `venv`: creates `.venv` with the Python packages the tests use (tests/python/requirements.txt).
//! - `test`: package, venv, `cargo test --release --workspace`, `cargo doc` (warnings are
//!   errors), then pytest on tests/python.
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
}

const FMUS: &[FmuCrate] = &[
    FmuCrate {
        name: "segments_voicecoil",
        write: fmu::package::write_fmu::<segments::VoiceCoil>,
    },
    FmuCrate {
        name: "segments_piezo",
        write: fmu::package::write_fmu::<segments::Piezo>,
    },
    FmuCrate {
        name: "mirror_voicecoil",
        write: fmu::package::write_fmu::<mirror::VoiceCoil>,
    },
    FmuCrate {
        name: "mirror_piezo",
        write: fmu::package::write_fmu::<mirror::Piezo>,
    },
    FmuCrate {
        name: "structure",
        write: fmu::package::write_fmu::<structure_model::Structure>,
    },
    FmuCrate {
        name: "wind",
        write: fmu::package::write_fmu::<wind_model::Wind>,
    },
    FmuCrate {
        name: "pier_vibration",
        write: fmu::package::write_fmu::<pier_vibration_model::PierVibrationFmu>,
    },
    FmuCrate {
        name: "optics",
        write: fmu::package::write_fmu::<optics_model::Optics>,
    },
    FmuCrate {
        name: "edge_sensors",
        write: fmu::package::write_fmu::<edge_sensors_model::EdgeSensorsModel>,
    },
    FmuCrate {
        name: "global_controller",
        write: fmu::package::write_fmu::<global_controller_model::GlobalControllerModel>,
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
    let status = cmd
        .current_dir(root())
        .status()
        .map_err(|e| format!("cannot start {cmd:?}: {e}"))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{cmd:?} failed with {status}"))
    }
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
    run(cargo().args(["test", "--release", "--workspace"]))?;
    // The API documentation builds without a warning (broken or private intra-doc links).
    run(cargo()
        .args(["doc", "--release", "--no-deps", "--workspace"])
        .env("RUSTDOCFLAGS", "-D warnings"))?;
    let mut pytest = Command::new(python);
    pytest
        .args(["-m", "pytest", "-q", "tests/python"])
        .args(extra)
        .env("M1CS_FMU_DIR", target_dir().join("fmu"));
    run(&mut pytest)
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
        "demo" => demo(rest),
        "run" => run_main(rest),
        _ => {
            eprintln!(
                "usage: cargo xtask <package [LAYOUT...] | venv | test [PYTEST ARGS] | run [M1CS RUN ARGS] | demo [ARGS]>"
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
