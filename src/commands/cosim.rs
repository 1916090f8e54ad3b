//! `m1cs system` and `m1cs run`: the standard closed-loop systems of the seed paper's Figure 8
//! (wind or pier vibration -> segments on the telescope structure -> edge sensors -> global
//! controller, with the optics metrics), written as SSP or run by the included master.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::{Args, ValueEnum};
use cosim::system::{Order, System, Value, run};
use serde_json::json;

use crate::plot;

/// Default simulated duration of a run (s).
pub const DURATION: f64 = 5.0;
/// Default base communication step (s): a multiple of the 0.2 ms servo period.
pub const STEP: f64 = 1e-3;
/// Default structure modes the mirror or structure FMU retains (its `n_modes`, an FMI
/// Integer): the studies' [`m1::analysis::defaults::STRUCTURE_MODES`].
pub const STRUCTURE_MODES: i32 = m1::analysis::defaults::STRUCTURE_MODES as i32;

/// Actuator variant of the segments.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Variant {
    /// Soft voice coil with offload spring (baseline).
    Voicecoil,
    /// Hard piezo stack.
    Piezo,
    /// Hard piezo with the resonant LR shunt.
    PiezoDamped,
}

/// Disturbance of the scenario.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Scenario {
    /// Frozen-flow wind pressure on the segments.
    Wind,
    /// A pier tone (29.6 Hz by default) through the structure.
    Vibration,
}

/// Mirror-cell model of a standard system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Cell {
    /// The mirror FMU: segments and structure solved together at every servo sample (stable
    /// and exact at any step that is a multiple of the 0.2 ms servo period).
    Coupled,
    /// The segments FMU and the structure FMU exchanging f_cell and z_cell once per step: for
    /// studies of the coupling delay. Stable only at short steps (voice coil: 0.2 ms in
    /// Gauss-Seidel order); the piezo diverges at every step tried.
    Split,
    /// The segments FMU alone: the cell does not move.
    Rigid,
    /// The mirror FMU's quasi-static plant (`quasi_static`): the structure's static response
    /// and each segment reduced to its low-frequency stiffness and servo integrator (seed
    /// paper, section 4.1). For wind: it follows the coupled plant within 2 % at 1 Hz and
    /// ignores everything faster.
    QuasiStatic,
}

/// What defines a standard system.
#[derive(Args, Debug, Clone)]
pub struct SystemArgs {
    /// Mirror layout (keck, tmt, elt): FMUs are taken from FMU_DIR/LAYOUT/.
    #[arg(long, default_value = m1::aperture::layout::DEFAULT_LAYOUT)]
    pub layout: String,
    /// Actuator variant of the segments (`m1cs run --scenario vibration` runs all three).
    #[arg(long, value_enum, default_value_t = Variant::Voicecoil)]
    pub actuator: Variant,
    /// Disturbance.
    #[arg(long, value_enum, default_value_t = Scenario::Wind)]
    pub scenario: Scenario,
    /// Where the packaged FMUs are (`cargo xtask package` writes them).
    #[arg(long, default_value = super::FMU_DIR)]
    pub fmu_dir: PathBuf,
    /// Mean wind speed across M1 (m/s); the default is the seed paper's Figure 12 case.
    #[arg(long, default_value_t = m1::loads::wind::WindParams::default().speed)]
    pub wind_speed: f64,
    /// Global-loop bandwidth on the modes of radial degrees >= 5 (every mode outside the three
    /// groups below) (Hz).
    #[arg(long, default_value_t = m1::control::controller::DEFAULT_BANDWIDTH)]
    pub bandwidth: f64,
    /// Global-loop bandwidth on radial degrees 3-4 (Z7 to Z15, without radial degree 2 and
    /// focus-mode) (Hz).
    #[arg(long, default_value_t = m1::control::controller::DEFAULT_BANDWIDTH_RADIAL34)]
    pub bandwidth_radial34: f64,
    /// Global-loop bandwidth on radial degree 2 without focus-mode (astigmatism) (Hz).
    #[arg(long, default_value_t = m1::control::controller::DEFAULT_BANDWIDTH_RADIAL2)]
    pub bandwidth_radial2: f64,
    /// Global-loop bandwidth on focus-mode (Hz).
    #[arg(long, default_value_t = m1::control::controller::DEFAULT_BANDWIDTH_FOCUS)]
    pub focus_bandwidth: f64,
    /// Mirror cell: `coupled` (the mirror FMU, segments and structure in one solve), `split`
    /// (segments and structure FMUs exchanging f_cell and z_cell every step; short steps only)
    /// or `rigid` (no structure, z_cell = 0).
    #[arg(long, value_enum, default_value_t = Cell::Coupled)]
    pub cell: Cell,
    /// Structure modes retained (the rest enter as a static correction).
    #[arg(long, default_value_t = STRUCTURE_MODES)]
    pub structure_modes: i32,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
    /// Step every component at the base step (no multi-rate), as fmpy.ssp does.
    #[arg(long)]
    pub uniform: bool,
    /// Simulated duration (s).
    #[arg(long, default_value_t = DURATION)]
    pub duration: f64,
    /// Base communication step (s): a multiple of the 0.2 ms servo period for the mirror and
    /// segments FMUs. With `--cell split` keep it at 2e-4 with Gauss-Seidel order.
    #[arg(long, default_value_t = STEP)]
    pub step: f64,
}

/// `m1cs system`.
#[derive(Args, Debug)]
pub struct SystemCmd {
    #[command(flatten)]
    pub system: SystemArgs,
    /// The .ssp archive to write.
    #[arg(short, long)]
    pub output: PathBuf,
}

/// `m1cs run`.
#[derive(Args, Debug)]
pub struct RunCmd {
    #[command(flatten)]
    pub system: SystemArgs,
    /// Run this .ssp (or .ssd) instead of a standard system. Its DefaultExperiment and master
    /// annotation set the stop time and the step; `--duration` and `--step` only fill in what
    /// the file leaves out.
    #[arg(long)]
    pub ssp: Option<PathBuf>,
    /// With `--ssp`: stop at this time (s) instead of the file's stop time.
    #[arg(long, requires = "ssp")]
    pub stop_time: Option<f64>,
    /// Results folder (CSV, plots, summary JSON).
    #[arg(long, default_value = "results")]
    pub out: PathBuf,
    /// Record every N base steps (the spectra reach half the recording rate).
    #[arg(long, default_value_t = 1)]
    pub decimation: usize,
    /// Stepping order of the master. Gauss-Seidel (default) steps the components in turn on
    /// their predecessors' newest outputs: one delay less per connection (needed by `--cell
    /// split`), and a component nobody reads right away (the edge sensors) steps on a second
    /// thread meanwhile (same values; see --no-lookahead). Jacobi steps them in
    /// parallel on the values of the last communication point (results independent of the
    /// component order; fmpy.ssp's convention).
    #[arg(long, value_enum, default_value_t = OrderArg::GaussSeidel)]
    pub order: OrderArg,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Start every connection at 0 instead of the FMUs' initial outputs (fmpy.ssp's
    /// convention; for comparisons with it).
    #[arg(long)]
    pub zero_start: bool,
    /// Gauss-Seidel without the look-ahead thread (every component in turn on this thread;
    /// the same values, for timing comparisons).
    #[arg(long)]
    pub no_lookahead: bool,
}

/// Stepping order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OrderArg {
    /// Parallel, on the last communication point's values (default).
    Jacobi,
    /// Sequential, each component on its predecessors' newest outputs.
    GaussSeidel,
}

fn fmu(a: &SystemArgs, name: &str) -> Result<PathBuf, String> {
    let p = a.fmu_dir.join(&a.layout).join(format!("{name}.fmu"));
    if p.is_file() {
        Ok(p)
    } else {
        Err(format!(
            "{} is missing: run `cargo xtask package {}` first (or pass --fmu-dir)",
            p.display(),
            a.layout
        ))
    }
}

/// The standard closed-loop system; `closed` = false opens the global loop.
pub fn standard_system(a: &SystemArgs, closed: bool) -> Result<System, String> {
    if !(a.duration > 0.0 && a.step > 0.0 && a.duration >= a.step) {
        return Err(format!(
            "--duration {} and --step {} must be positive, the duration at least one step",
            a.duration, a.step
        ));
    }
    if !(a.wind_speed.is_finite() && a.wind_speed > 0.0) {
        return Err(format!("--wind-speed {}: must be positive", a.wind_speed));
    }
    // Zero bandwidths are allowed: the controller then runs with zero gains (its integrators
    // hold), the open loop with the controller in it.
    for (name, b) in [
        ("--bandwidth", a.bandwidth),
        ("--bandwidth-radial34", a.bandwidth_radial34),
        ("--bandwidth-radial2", a.bandwidth_radial2),
        ("--focus-bandwidth", a.focus_bandwidth),
    ] {
        if !(b.is_finite() && b >= 0.0) {
            return Err(format!("{name} {b}: must be finite and >= 0"));
        }
    }
    let per = |hz: f64| {
        if a.uniform {
            1
        } else {
            ((1.0 / hz) / a.step).round().max(1.0) as usize
        }
    };
    let (mirror, file) = match (a.cell, a.actuator) {
        (Cell::Coupled | Cell::QuasiStatic, Variant::Voicecoil) => ("mirror", "mirror_voicecoil"),
        (Cell::Coupled | Cell::QuasiStatic, _) => ("mirror", "mirror_piezo"),
        (_, Variant::Voicecoil) => ("segments", "segments_voicecoil"),
        (_, _) => ("segments", "segments_piezo"),
    };
    let mut s = System::new(a.duration, a.step);
    s = match a.scenario {
        Scenario::Wind => s
            .component("wind", fmu(a, "wind")?)
            .every(per(100.0))
            .parameter("wind", "wind_speed", Value::Real(a.wind_speed)),
        Scenario::Vibration => s.component("pier", fmu(a, "pier_vibration")?),
    };
    if matches!(a.cell, Cell::Rigid | Cell::QuasiStatic) && a.scenario == Scenario::Vibration {
        return Err(
            "--scenario vibration acts through the structure's dynamics: use --cell coupled or \
             split"
                .into(),
        );
    }
    s = s.component(mirror, fmu(a, file)?);
    // The structure is bound only where it differs from the FMUs' default, so a default system
    // has no String binding (some SSP importers, e.g. fmpy's container FMU, take none).
    let structure = structure_parameter(&a.structure)?;
    let structure = (structure != m1::plant::structure::DEFAULT_STRUCTURE).then_some(structure);
    if a.cell == Cell::QuasiStatic {
        s = s.parameter(mirror, "quasi_static", Value::Boolean(true));
    }
    let cell_fmu = match a.cell {
        Cell::Coupled | Cell::QuasiStatic => Some(mirror),
        Cell::Split => {
            s = s.component("structure", fmu(a, "structure")?);
            Some("structure")
        }
        Cell::Rigid => None,
    };
    if let Some(c) = cell_fmu {
        s = s.parameter(c, "n_modes", Value::Integer(a.structure_modes));
        if let Some(name) = structure {
            s = s.parameter(c, "structure", Value::String(name));
        }
    }
    s = s
        .component("sensors", fmu(a, "edge_sensors")?)
        .component("controller", fmu(a, "global_controller")?)
        .every(per(20.0))
        .parameter("controller", "enabled", Value::Boolean(closed))
        .parameter("controller", "bandwidth", Value::Real(a.bandwidth))
        .parameter(
            "controller",
            "bandwidth_radial34",
            Value::Real(a.bandwidth_radial34),
        )
        .parameter(
            "controller",
            "bandwidth_radial2",
            Value::Real(a.bandwidth_radial2),
        )
        .parameter(
            "controller",
            "bandwidth_focus",
            Value::Real(a.focus_bandwidth),
        )
        .component("optics", fmu(a, "optics")?)
        .every(per(1000.0));
    if a.actuator == Variant::PiezoDamped {
        s = s.parameter(mirror, "shunt_enabled", Value::Boolean(true));
    }
    let pier_target = if matches!(a.cell, Cell::Coupled | Cell::QuasiStatic) {
        "mirror.pier_z"
    } else {
        "structure.pier_z"
    };
    s = match a.scenario {
        Scenario::Wind => s.connect("wind.f_wind", &format!("{mirror}.f_wind")),
        Scenario::Vibration => s.connect("pier.pier_z", pier_target),
    };
    if a.cell == Cell::Split {
        s = s
            .connect("structure.z_cell", "segments.z_cell")
            .connect("segments.f_cell", "structure.f_cell");
    }
    Ok(s.connect("controller.u_cmd", &format!("{mirror}.u_cmd"))
        .connect(&format!("{mirror}.z"), "sensors.z")
        .connect("sensors.y", "controller.y")
        .connect(&format!("{mirror}.z"), "optics.z"))
}

/// The value of the FMUs' `structure` parameter for `--structure NAME`: a preset's name, or a
/// `.npz` path made absolute (checked to exist), so the system runs from any directory.
fn structure_parameter(name: &str) -> Result<String, String> {
    match m1::plant::structure::StructureSource::parse(name)
        .map_err(|e| format!("--structure: {e}"))?
    {
        m1::plant::structure::StructureSource::BuiltIn(_) => Ok(name.trim().to_string()),
        m1::plant::structure::StructureSource::File(path) => std::fs::canonicalize(&path)
            .map(|p| p.display().to_string())
            .map_err(|e| format!("--structure {}: {e}", path.display())),
    }
}

/// Runs `m1cs system`.
pub fn system(a: &SystemCmd) -> Result<(), String> {
    let s = standard_system(&a.system, true)?;
    let name = format!(
        "{}_{:?}_{:?}",
        a.system.layout, a.system.actuator, a.system.scenario
    )
    .to_lowercase();
    cosim::ssp::write_ssp(&s, &name, &a.output).map_err(|e| e.to_string())?;
    println!(
        "wrote {} ({} components, {} connections)",
        a.output.display(),
        s.components.len(),
        s.connections.len()
    );
    Ok(())
}

const METRICS: [&str; 4] = [
    "optics.rms_surface",
    "optics.focus_mode",
    "optics.rms_surface_without_focus",
    "optics.pssn",
];

pub(crate) struct Outcome {
    pub(crate) label: String,
    pub(crate) results: cosim::system::Results,
    pub(crate) seconds: f64,
}

pub(crate) fn run_one(
    label: &str,
    system: &System,
    decimation: usize,
    metrics: &[&str],
    partial_csv: Option<&Path>,
) -> Result<Outcome, String> {
    let record: Vec<String> = metrics.iter().map(|s| s.to_string()).collect();
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{prefix:>12} [{bar:30}] {msg} ({elapsed})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    let t0 = Instant::now();
    let outcome = run(system, &record, decimation, &mut |t, stop| {
        let f = (t / stop).clamp(0.0, 1.0);
        let pos = (f * 1000.0) as u64;
        if pos != bar.position() {
            bar.set_position(pos);
            let wall = t0.elapsed().as_secs_f64();
            bar.set_message(format!(
                "t = {t:.3} s, {:.2}x real time",
                t / wall.max(1e-9)
            ));
        }
    });
    bar.finish_and_clear();
    let results = match outcome {
        Ok(r) => r,
        Err(f) => {
            // Keep what was recorded up to the failure.
            let kept = match (&f.partial, partial_csv) {
                (Some(p), Some(path)) if p.n_rows() > 1 => match p.write_csv(path) {
                    Ok(()) => format!(" (results up to the failure in {})", path.display()),
                    Err(e) => format!(" (could not keep the results: {e})"),
                },
                _ => String::new(),
            };
            return Err(format!("{label}: {}{kept}", f.error));
        }
    };
    Ok(Outcome {
        label: label.into(),
        results,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Mean square over the second half of a recorded column (settled part), as an rms.
pub(crate) fn settled_rms(v: &[f64]) -> f64 {
    let half = &v[v.len() / 2..];
    (half.iter().map(|x| x * x).sum::<f64>() / half.len().max(1) as f64).sqrt()
}

fn settled_mean(v: &[f64]) -> f64 {
    let half = &v[v.len() / 2..];
    half.iter().sum::<f64>() / half.len().max(1) as f64
}

/// Runs `m1cs run`.
pub fn run_cmd(a: &RunCmd) -> Result<(), String> {
    std::fs::create_dir_all(&a.out).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let order = match a.order {
        OrderArg::Jacobi => Order::Jacobi,
        OrderArg::GaussSeidel => Order::GaussSeidel,
    };
    let mut runs: Vec<(String, System)> = Vec::new();
    if let Some(path) = &a.ssp {
        let s = cosim::ssp::read(path).map_err(|e| e.to_string())?;
        let mut sys = s.system.clone();
        if !s.has_step {
            sys.step = a.system.step;
        }
        if let Some(t) = a.stop_time {
            if !(t.is_finite() && t > sys.start_time + sys.step * 0.5) {
                return Err(format!(
                    "--stop-time {t} must be after the system's start time {} by a step at least",
                    sys.start_time
                ));
            }
            sys.stop_time = t;
        } else if sys.stop_time <= sys.start_time {
            sys.stop_time = sys.start_time + a.system.duration;
        }
        sys.order = order;
        sys.zero_start = a.zero_start;
        sys.no_lookahead = a.no_lookahead;
        runs.push(("system".into(), sys));
        // Keep the unpacked archive alive during the run.
        // The optics metrics are recorded when the system has an `optics` component.
        let has_optics = runs[0].1.components.iter().any(|c| c.name == "optics");
        let metrics: &[&str] = if has_optics { &METRICS } else { &[] };
        let outcome = execute(a, runs, metrics);
        drop(s);
        return outcome;
    }
    if a.system.scenario == Scenario::Vibration {
        // The pier tone through each actuator variant, global loop closed.
        for (label, variant) in [
            ("voicecoil", Variant::Voicecoil),
            ("piezo", Variant::Piezo),
            ("piezo damped", Variant::PiezoDamped),
        ] {
            let mut args = a.system.clone();
            args.actuator = variant;
            let mut s = standard_system(&args, true)?;
            s.order = order;
            s.zero_start = a.zero_start;
            s.no_lookahead = a.no_lookahead;
            runs.push((label.into(), s));
        }
    } else {
        for (label, closed) in [("open loop", false), ("closed loop", true)] {
            let mut s = standard_system(&a.system, closed)?;
            s.order = order;
            s.zero_start = a.zero_start;
            s.no_lookahead = a.no_lookahead;
            runs.push((label.into(), s));
        }
    }
    execute(a, runs, &METRICS)
}

fn execute(a: &RunCmd, runs: Vec<(String, System)>, metrics: &[&str]) -> Result<(), String> {
    // Every FMU opened once for all the runs: they share its unpacked files and loaded library
    // (and so its caches, e.g. the structure's modes), instead of unpacking it per run.
    let _open = open_fmus(&runs)?;
    let recorded = record_runs(a, &runs, metrics)?;
    draw_z_plots(a, &recorded.maps, &recorded.spectra)?;
    let duration = runs.first().map_or(0.0, |r| r.1.stop_time - r.1.start_time);
    let table: Vec<serde_json::Value> = recorded
        .outcomes
        .iter()
        .map(|o| summary_row(o, duration))
        .collect();
    plot_metrics(a, &recorded.outcomes, metrics)?;
    let summary = match &a.ssp {
        // A user's system: what it is comes from its file, not from the standard-system flags.
        Some(path) => json!({
            "ssp": path.display().to_string(),
            "duration_s": duration,
            "runs": table,
            "results": a.out.display().to_string(),
        }),
        None => json!({
            "layout": a.system.layout,
            "actuator": format!("{:?}", a.system.actuator).to_lowercase(),
            "scenario": format!("{:?}", a.system.scenario).to_lowercase(),
            "duration_s": duration,
            "runs": table,
            "results": a.out.display().to_string(),
        }),
    };
    std::fs::write(a.out.join("summary.json"), summary.to_string())
        .map_err(|e| format!("{}: {e}", a.out.display()))?;
    if a.json {
        println!("{summary}");
        return Ok(());
    }
    print_summary(a, &table, duration);
    Ok(())
}

/// Every distinct FMU of `runs`, opened (kept open while the handles live).
fn open_fmus(runs: &[(String, System)]) -> Result<Vec<cosim::Fmu>, String> {
    let mut paths: Vec<&std::path::Path> = runs
        .iter()
        .flat_map(|(_, s)| s.components.iter().map(|c| c.fmu.as_path()))
        .collect();
    paths.sort();
    paths.dedup();
    paths
        .into_iter()
        .map(cosim::Fmu::open)
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())
}

/// What the runs recorded: the outcomes (their CSV written), and per run with a mirror its
/// displacement time series (for the map) and amplitude spectrum.
struct Recorded {
    outcomes: Vec<Outcome>,
    maps: Vec<(String, Vec<Vec<f64>>)>,
    spectra: Vec<(String, Vec<(f64, f64)>)>,
}

/// Runs each system recording `metrics` and the mirror displacement, and writes each run's
/// CSV (without the displacement) into `--out`.
fn record_runs(
    a: &RunCmd,
    runs: &[(String, System)],
    metrics: &[&str],
) -> Result<Recorded, String> {
    let mut recorded = Recorded {
        outcomes: Vec::new(),
        maps: Vec::new(),
        spectra: Vec::new(),
    };
    for (label, s) in runs {
        let csv = a.out.join(format!("{}.csv", label.replace(' ', "_")));
        // The mirror displacement is recorded for the map and the spectrum, not written.
        let mirror = ["mirror", "segments"]
            .into_iter()
            .find(|m| s.components.iter().any(|c| c.name == *m));
        let mut record: Vec<String> = metrics.iter().map(|m| m.to_string()).collect();
        if let Some(m) = mirror {
            record.push(format!("{m}.z"));
        }
        let record: Vec<&str> = record.iter().map(String::as_str).collect();
        let mut o = run_one(label, s, a.decimation, &record, Some(&csv))?;
        let dt = s.step * a.decimation.max(1) as f64;
        let z = split_off_z(&mut o.results);
        if !z.is_empty() {
            recorded
                .spectra
                .push((label.clone(), mirror_spectrum(&z, dt)));
            recorded.maps.push((label.clone(), z));
        }
        o.results.write_csv(&csv).map_err(|e| e.to_string())?;
        recorded.outcomes.push(o);
    }
    Ok(recorded)
}

/// A run's row of the summary: timings and the settled optics metrics.
fn summary_row(o: &Outcome, duration: f64) -> serde_json::Value {
    let col = |n: &str| o.results.column(n).unwrap_or_else(|| vec![f64::NAN]);
    json!({
        "run": o.label,
        "wall_seconds": o.seconds,
        "real_time_factor": duration / o.seconds.max(1e-9),
        // The step loop alone, without instantiation and initialisation (the FMUs' set-up,
        // e.g. the structure's eigensolve, is paid once per run whatever its length).
        "setup_seconds": (o.seconds - o.results.timing.loop_seconds).max(0.0),
        "loop_real_time_factor": duration / o.results.timing.loop_seconds.max(1e-9),
        "master_share": o.results.timing.master_share(),
        "component_seconds": o.results.timing.components.iter()
            .map(|(n, t)| (n.clone(), json!(t)))
            .collect::<serde_json::Map<_, _>>(),
        "component_setup_seconds": o.results.timing.setup_components.iter()
            .map(|(n, t)| (n.clone(), json!(t)))
            .collect::<serde_json::Map<_, _>>(),
        "rms_surface_m": settled_rms(&col("optics.rms_surface")),
        "focus_mode_m": settled_rms(&col("optics.focus_mode")),
        "rms_surface_without_focus_m": settled_rms(&col("optics.rms_surface_without_focus")),
        "pssn": settled_mean(&col("optics.pssn")),
    })
}

/// One plot per metric over time, all runs overlaid (nm, PSSN as is).
fn plot_metrics(a: &RunCmd, outcomes: &[Outcome], metrics: &[&str]) -> Result<(), String> {
    for m in metrics {
        let data: Vec<(String, Vec<(f64, f64)>)> = outcomes
            .iter()
            .filter_map(|o| {
                let t = o.results.column("time")?;
                let v = o.results.column(m)?;
                Some((o.label.clone(), t.into_iter().zip(v).collect()))
            })
            .collect();
        if data.is_empty() {
            continue;
        }
        let name = m.trim_start_matches("optics.");
        let (unit, scale) = if *m == "optics.pssn" {
            ("1", 1.0)
        } else {
            ("nm", 1e9)
        };
        let scaled: Vec<Vec<(f64, f64)>> = data
            .iter()
            .map(|(_, p)| p.iter().map(|(t, v)| (*t, v * scale)).collect())
            .collect();
        let series: Vec<(&str, &[(f64, f64)])> = data
            .iter()
            .zip(&scaled)
            .map(|((l, _), p)| (l.as_str(), p.as_slice()))
            .collect();
        plot::lines(
            a.out.join(format!("{name}.png")),
            &series,
            &format!("{name} ({})", a.system.layout),
            "time (s)",
            &format!("{name} ({unit})"),
            false,
            false,
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// The summary table, and the actuator variants' ratios when all three ran.
fn print_summary(a: &RunCmd, table: &[serde_json::Value], duration: f64) {
    match &a.ssp {
        Some(path) => println!(
            "{}: {duration} s simulated (statistics over the second half):",
            path.display()
        ),
        None => println!(
            "{} {:?} actuators, {:?} scenario, {duration} s simulated (statistics over the second half):",
            a.system.layout, a.system.actuator, a.system.scenario
        ),
    }
    println!(
        "{:<12} {:>14} {:>14} {:>18} {:>8} {:>9} {:>11} {:>16} {:>8}",
        "run",
        "rms surf (nm)",
        "focus (nm)",
        "rms w/o focus (nm)",
        "PSSN",
        "wall (s)",
        "set-up (s)",
        "x realtime loop",
        "master"
    );
    for r in table {
        let g = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
        println!(
            "{:<12} {:>14.3} {:>14.3} {:>18.3} {:>8.5} {:>9.2} {:>11.2} {:>16.2} {:>7.1}%",
            r["run"].as_str().unwrap_or(""),
            g("rms_surface_m") * 1e9,
            g("focus_mode_m") * 1e9,
            g("rms_surface_without_focus_m") * 1e9,
            g("pssn"),
            g("wall_seconds"),
            g("setup_seconds"),
            g("loop_real_time_factor"),
            100.0 * g("master_share")
        );
    }
    let rms_of = |label: &str| {
        table
            .iter()
            .find(|r| r["run"] == label)
            .and_then(|r| r["rms_surface_m"].as_f64())
    };
    if let (Some(soft), Some(hard), Some(damped)) =
        (rms_of("voicecoil"), rms_of("piezo"), rms_of("piezo damped"))
    {
        println!(
            "rms surface ratios: hard / soft = {:.2}, undamped / damped = {:.2}",
            hard / soft,
            hard / damped
        );
    }
    println!(
        "CSV, plots and summary.json in {}",
        Path::new(&a.out).display()
    );
}

/// Removes the recorded mirror displacement columns (`<component>.z[k]`) from `r` and returns
/// them as time series (one per actuator, settled second half of the run).
pub(crate) fn split_off_z(r: &mut cosim::system::Results) -> Vec<Vec<f64>> {
    let is_z = |c: &str| c.starts_with("mirror.z[") || c.starts_with("segments.z[");
    let keep: Vec<usize> = (0..r.columns.len())
        .filter(|&k| !is_z(&r.columns[k]))
        .collect();
    let zc: Vec<usize> = (0..r.columns.len())
        .filter(|&k| is_z(&r.columns[k]))
        .collect();
    let half = r.n_rows() / 2;
    let z: Vec<Vec<f64>> = zc
        .iter()
        .map(|&k| r.rows().skip(half).map(|row| row[k]).collect())
        .collect();
    r.keep_columns(&keep);
    z
}

/// Amplitude spectrum of the mirror displacement, power-averaged over the actuators (nm).
fn mirror_spectrum(z: &[Vec<f64>], dt: f64) -> Vec<(f64, f64)> {
    let signals: Vec<&[f64]> = z.iter().map(Vec::as_slice).collect();
    m1::optics::metrics::amplitude_spectrum(&signals, dt)
        .into_iter()
        .map(|(f, a)| (f, a * 1e9))
        .collect()
}

/// rms over time of the residual surface of each segment (global piston, tip and tilt removed),
/// in nm, from actuator time series.
pub(crate) fn segment_rms_map(
    layout: &m1::aperture::layout::Layout,
    z: &[Vec<f64>],
) -> Result<Vec<f64>, String> {
    use m1::aperture::geometry::{Geometry, GeometryParams};
    use m1::optics::metrics::{MirrorMetrics, hexagon_area, hexagon_second_moment};
    let g = Geometry::new(layout, GeometryParams::for_layout(layout)).map_err(|e| e.to_string())?;
    let m = MirrorMetrics::new(&g).map_err(|e| e.to_string())?;
    let n = layout.n_segments();
    let a = layout.circumradius;
    let slope_weight = hexagon_second_moment(a) / hexagon_area(a);
    let samples = z.first().map_or(0, Vec::len);
    let mut acc = vec![0.0; n];
    let mut state = vec![0.0; 3 * n];
    let mut ptt = vec![[0.0; 3]; n];
    for k in 0..samples {
        for (s, col) in state.iter_mut().zip(z) {
            *s = col[k];
        }
        m.residual_ptt(&state, &mut ptt)
            .map_err(|e| e.to_string())?;
        for (acc, [p, tx, ty]) in acc.iter_mut().zip(&ptt) {
            *acc += p * p + (tx * tx + ty * ty) * slope_weight;
        }
    }
    Ok(acc
        .iter()
        .map(|s| (s / samples.max(1) as f64).sqrt() * 1e9)
        .collect())
}

/// The M1 maps (one per run) and the overlaid amplitude spectra.
fn draw_z_plots(
    a: &RunCmd,
    maps: &[(String, Vec<Vec<f64>>)],
    spectra: &[(String, Vec<(f64, f64)>)],
) -> Result<(), String> {
    for (label, z) in maps {
        // The layout of the recorded mirror: the one asked for, else the preset of that size
        // (a user's .ssp).
        let Some(layout) = std::iter::once(a.system.layout.as_str())
            .chain(m1::aperture::layout::Layout::PRESETS.iter().copied())
            .filter_map(|name| m1::aperture::layout::Layout::preset(name).ok())
            .find(|l| l.n_actuators() == z.len())
        else {
            continue;
        };
        let rms = segment_rms_map(&layout, z)?;
        plot::mirror_map(
            a.out.join(format!("map_{}.png", label.replace(' ', "_"))),
            &layout,
            &rms,
            &format!(
                "{}, {label}: rms residual surface per segment (second half)",
                layout.name
            ),
            "nm",
        )
        .map_err(|e| e.to_string())?;
    }
    let series: Vec<(&str, &[(f64, f64)])> = spectra
        .iter()
        .filter(|(_, s)| !s.is_empty())
        .map(|(l, s)| (l.as_str(), s.as_slice()))
        .collect();
    if !series.is_empty() {
        plot::lines(
            a.out.join("spectrum.png"),
            &series,
            &format!(
                "{}: amplitude spectrum of the mirror displacement (actuator mean)",
                if a.ssp.is_some() {
                    "system"
                } else {
                    a.system.layout.as_str()
                }
            ),
            "frequency (Hz)",
            "amplitude (nm)",
            true,
            true,
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}
