//! `m1cs report DIR`: every analysis of the quasi-static and dynamic studies with its default
//! parameters, written into DIR as one Markdown page (`index.md`) with the figures and the key
//! numbers of each. Each analysis runs as its own `m1cs` subcommand (this executable), with
//! `--json` for the numbers and `--plot` for the figures, so the page shows exactly what the
//! commands give.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use clap::Args;

/// `m1cs report`.
#[derive(Args, Debug)]
pub struct ReportArgs {
    /// Directory to write `index.md` and the figures into (created if missing).
    pub dir: PathBuf,
    /// Mirror layout every analysis runs on (keck, tmt, elt).
    #[arg(long, default_value = m1::aperture::layout::DEFAULT_LAYOUT)]
    pub layout: String,
    /// Where the packaged FMUs are, for the co-simulation analyses (`cargo xtask package`).
    #[arg(long, default_value = super::FMU_DIR)]
    pub fmu_dir: PathBuf,
    /// Leave out the analyses that run the co-simulation master (`run`, `wind`), e.g. without
    /// packaged FMUs.
    #[arg(long)]
    pub no_cosim: bool,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
}

/// Where an analysis draws: one PNG file, or a directory of them.
enum Plot {
    File(&'static str),
    Dir(&'static str),
    /// `m1cs run --out DIR` (CSV, PNG and `summary.json`; the numbers come from `--json`).
    Out(&'static str),
}

struct Analysis {
    title: &'static str,
    what: &'static str,
    args: &'static [&'static str],
    plot: Plot,
    cosim: bool,
    /// JSON paths (prefixes) shown in the section's table; empty: every scalar.
    keys: &'static [&'static str],
}

/// The analyses that build a dynamic plant (they take `--structure`).
const PLANT_COMMANDS: &[&str] = &["coupling", "csi", "vibration", "wind", "run"];

const ANALYSES: &[Analysis] = &[
    Analysis {
        title: "Layout",
        what: "The segments, actuators, edges and sensors.",
        args: &["geometry"],
        plot: Plot::File("geometry.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Interaction matrix",
        what: "SVD of the A-matrix: rank, the unobservable global piston/tip/tilt, focus-mode and \
               the next least observable modes.",
        args: &["amatrix"],
        plot: Plot::File("amatrix.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Robustness to interaction-matrix errors",
        what: "The seed paper's Table 1: rho(Q - I), sigma(Q) and sigma(Gamma Psi Q Psi^T) over \
               seeded realisations of each error source.",
        args: &["robustness"],
        plot: Plot::File("robustness.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Sensor noise",
        what: "White edge-sensor noise propagated to the mirror, with and without focus-mode.",
        args: &["noise"],
        plot: Plot::File("noise.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Segment clocking",
        what: "The out-of-plane correction the control makes for an in-plane clocking of one \
               segment (the seed paper's eq. 3).",
        args: &["clocking"],
        plot: Plot::File("clocking.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Calibration of the sensors' cross-sensitivity",
        what: "Shear estimated from the gap readings (eq. 2): the unobservable torsion mode and \
               the gap noise.",
        args: &["calibration"],
        plot: Plot::File("calibration.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Zernike basis",
        what: "Zernike modes on the segmented aperture and their segment piston/tip/tilt \
               projection (focus drawn).",
        args: &["zernike"],
        plot: Plot::File("zernike.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "PSSN",
        what: "PSSN of seeded random segment piston errors: the deficit grows as the square of \
               the error.",
        args: &["pssn"],
        plot: Plot::File("pssn.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Coupling delay between segments and structure",
        what: "Segments and structure as two co-simulation components against the coupled \
               solver: the largest communication step each actuator variant tolerates.",
        args: &["coupling"],
        plot: Plot::File("coupling.png"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Control-structure interaction",
        what: "The seed paper's Figure 11: the actuator servo loop's sensitivity in Zernike bases \
               of growing radial degree, in segment bases and with all segments, its peaks \
               labelled by Zernike family, and the highest servo gain meeting sigma_max(S) < 2 \
               below 15 Hz; the global loop's principal loop gain and sensitivity against 1/2 \
               over the interaction-matrix allowance, their peaks labelled the same way, and \
               its highest bandwidth.",
        args: &["csi"],
        plot: Plot::Dir("csi"),
        cosim: false,
        keys: &[
            "coupled_dimension",
            "sweep.all_segments.peak",
            "sweep.all_segment_peaks",
            "sweep.zernike[8].peak",
            "highest_gain.gain_factor",
            "highest_gain.bandwidth_hz",
            "highest_gain.peak",
            "highest_gain.meets_criterion",
            "highest_gain.limited_by",
            "global.modes",
            "global.loop_gain_limit",
            "global.all_segments.peak",
            "global.all_segments.high_frequency",
            "global.all_segment_peaks",
            "global.meets",
            "global.highest_bandwidth",
            "q_allowance.worst",
            "elapsed_s",
        ],
    },
    Analysis {
        title: "Vibration",
        what: "M1 rms surface and PSSN per vertical pier motion for the three actuator variants \
               (the seed paper's Figure 13), from the monolithic frequency model.",
        args: &["vibration"],
        plot: Plot::Dir("vibration"),
        cosim: false,
        keys: &[],
    },
    Analysis {
        title: "Wind",
        what: "M1 rms surface under wind versus wind speed and global-loop bandwidth, open and \
               closed loop (the seed paper's Figure 12), by the included master.",
        args: &["wind"],
        plot: Plot::Dir("wind"),
        cosim: true,
        keys: &[],
    },
    Analysis {
        title: "The closed-loop scenario (the main job)",
        what: "Wind at 1 m/s (the seed paper's Figure 12 case), voice-coil actuators, the \
               baseline global loop (1.5 / 1 / 0.75 Hz by radial degree, focus-mode at 0.1 Hz): \
               open and closed loop by the included master.",
        args: &["run"],
        plot: Plot::Out("run"),
        cosim: true,
        keys: &[],
    },
];

/// Flattens the scalars of a JSON value (arrays of up to 8 scalars as lists) into
/// `(path, text)` rows, depth-first.
fn scalars(v: &serde_json::Value, path: &str, out: &mut Vec<(String, String)>) {
    use serde_json::Value;
    let key = |k: &str| {
        if path.is_empty() {
            k.to_string()
        } else {
            format!("{path}.{k}")
        }
    };
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                scalars(x, &key(k), out);
            }
        }
        Value::Array(a) => {
            if a.len() <= 8 && a.iter().all(|x| !x.is_object() && !x.is_array()) {
                let items: Vec<String> = a.iter().map(text).collect();
                out.push((path.to_string(), format!("[{}]", items.join(", "))));
            } else if a.len() <= 16 && a.iter().all(flat_object) {
                // A table-like list (e.g. labelled peaks): one row per element.
                for (i, x) in a.iter().enumerate() {
                    let fields: Vec<String> = x
                        .as_object()
                        .map(|m| m.iter().map(|(k, y)| format!("{k} {}", text(y))).collect())
                        .unwrap_or_default();
                    out.push((format!("{path}[{i}]"), fields.join(", ")));
                }
            } else if a.len() <= 12 && a.iter().all(serde_json::Value::is_object) {
                for (i, x) in a.iter().enumerate() {
                    scalars(x, &format!("{path}[{i}]"), out);
                }
            } else {
                out.push((path.to_string(), format!("({} values)", a.len())));
            }
        }
        _ => out.push((path.to_string(), text(v))),
    }
}

/// An object of at most 6 scalar fields.
fn flat_object(v: &serde_json::Value) -> bool {
    v.as_object()
        .is_some_and(|m| m.len() <= 6 && m.values().all(|x| !x.is_object() && !x.is_array()))
}

fn text(v: &serde_json::Value) -> String {
    match v {
        serde_json::Value::Number(n) => n.as_f64().map_or_else(
            || n.to_string(),
            |x| {
                if x != 0.0 && (x.abs() < 1e-3 || x.abs() >= 1e6) {
                    format!("{x:.4e}")
                } else if x.fract() == 0.0 {
                    format!("{x:.0}")
                } else {
                    format!("{x:.6}")
                }
            },
        ),
        serde_json::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

fn pngs(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|it| {
            it.filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| p.extension().is_some_and(|e| e == "png"))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// Runs `m1cs report`.
pub fn report(a: &ReportArgs) -> Result<(), String> {
    let dir = &a.dir;
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let exe = std::env::current_exe().map_err(|e| format!("this executable: {e}"))?;
    let list: Vec<&Analysis> = ANALYSES
        .iter()
        .filter(|x| !(a.no_cosim && x.cosim))
        .collect();
    let bar = indicatif::ProgressBar::new(list.len() as u64);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} {msg}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix("report");
    let t0 = Instant::now();
    let mut md = String::new();
    let _ = writeln!(
        md,
        "# M1 control-system analyses: {}\n\nEvery analysis with its default parameters, as \
         `m1cs report` ran it (each section gives the command; `--json` gives the numbers, \
         `--plot` the figures).\n",
        a.layout
    );
    super::load_layout(&a.layout)?;
    let mut failures = Vec::new();
    for an in &list {
        bar.set_message(an.title);
        let mut args: Vec<String> = an.args.iter().map(|s| (*s).to_string()).collect();
        args.push("--layout".into());
        args.push(a.layout.clone());
        args.push("--json".into());
        let fmu_dir = a.fmu_dir.display().to_string();
        match an.plot {
            Plot::File(f) => {
                args.push("--plot".into());
                args.push(dir.join(f).display().to_string());
            }
            Plot::Dir(d) => {
                args.push("--plot".into());
                args.push(dir.join(d).display().to_string());
            }
            Plot::Out(d) => {
                args.push("--out".into());
                args.push(dir.join(d).display().to_string());
            }
        }
        if PLANT_COMMANDS.contains(&an.args[0]) {
            args.push("--structure".into());
            args.push(a.structure.clone());
        }
        if an.cosim {
            args.push("--fmu-dir".into());
            args.push(fmu_dir);
        }
        let t = Instant::now();
        let out = Command::new(&exe)
            .args(&args)
            .output()
            .map_err(|e| format!("{}: {e}", exe.display()))?;
        let secs = t.elapsed().as_secs_f64();
        let shown: Vec<String> = args
            .iter()
            .map(|s| {
                s.strip_prefix(&format!("{}/", dir.display()))
                    .map_or_else(|| s.clone(), |r| format!("DIR/{r}"))
            })
            .collect();
        let _ = writeln!(md, "## {}\n\n{}\n", an.title, an.what);
        let _ = writeln!(md, "`m1cs {}` ({secs:.1} s)\n", shown.join(" "));
        if !out.status.success() {
            let err = String::from_utf8_lossy(&out.stderr);
            let _ = writeln!(md, "**Failed:** `{}`\n", err.trim());
            failures.push(an.title);
            bar.inc(1);
            continue;
        }
        let stdout = String::from_utf8_lossy(&out.stdout);
        match serde_json::from_str::<serde_json::Value>(stdout.trim()) {
            Ok(v) => {
                let mut rows = Vec::new();
                scalars(&v, "", &mut rows);
                if !an.keys.is_empty() {
                    rows.retain(|(k, _)| an.keys.iter().any(|p| k.starts_with(p)));
                }
                let _ = writeln!(md, "| quantity | value |\n|---|---|");
                let prefix = format!("{}/", dir.display());
                for (k, val) in rows.iter().take(60) {
                    let val = val.replace(&prefix, "DIR/").replace('|', "/");
                    let _ = writeln!(md, "| `{k}` | {val} |");
                }
                if rows.len() > 60 {
                    let _ = writeln!(md, "| ... | {} more in `--json` |", rows.len() - 60);
                }
                md.push('\n');
            }
            Err(_) => {
                let _ = writeln!(md, "```\n{}\n```\n", stdout.trim());
            }
        }
        let figures = match an.plot {
            Plot::File(f) => {
                let p = dir.join(f);
                if p.is_file() { vec![p] } else { Vec::new() }
            }
            Plot::Dir(d) | Plot::Out(d) => pngs(&dir.join(d)),
        };
        for p in figures {
            let rel = p.strip_prefix(dir).unwrap_or(&p).display().to_string();
            let _ = writeln!(md, "![{rel}]({rel})\n");
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let _ = writeln!(
        md,
        "---\nGenerated in {:.0} s{}.",
        t0.elapsed().as_secs_f64(),
        if a.no_cosim {
            " (without the co-simulation analyses)"
        } else {
            ""
        }
    );
    let index = dir.join("index.md");
    std::fs::write(&index, md).map_err(|e| format!("{}: {e}", index.display()))?;
    println!(
        "{} analyses in {:.0} s: {}",
        list.len(),
        t0.elapsed().as_secs_f64(),
        index.display()
    );
    if failures.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "these analyses failed (see {}): {}",
            index.display(),
            failures.join(", ")
        ))
    }
}
