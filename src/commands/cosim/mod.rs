//! `m1cs system` and `m1cs run`: the standard closed-loop systems of the seed paper's Figure 8
//! (wind or pier vibration -> segments on the telescope structure -> edge sensors -> global
//! controller, with the optics metrics), written as SSP or run by the included master.
//!
//! `mod.rs` the arguments, the standard system and the commands, `execute.rs` running and
//! summarising the runs, `figures.rs` the mirror figures.

mod execute;
mod figures;
mod npy;

use execute::execute;
pub(crate) use execute::interrupted;
pub(crate) use figures::{segment_rms_map, split_off_z};

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
    /// Threads of the coupled mirror's large products (its `solver_threads` parameter): 1 on
    /// the thread that steps it, 2 split with a helper thread (the same results to the bit), 0
    /// two from 500 retained modes, and from 150 whichever of one and two a timed trial finds
    /// faster (every 1000 steps: on a VM two pay only while its cores share a cache). Use 1
    /// when other runs already occupy every core.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(i32).range(0..=2))]
    pub solver_threads: i32,
    /// Step every component at the base step (no multi-rate), as fmpy.ssp does.
    #[arg(long)]
    pub uniform: bool,
    /// Add the optical measurements: the `aps` FMU (a run at the start, then every 14 days)
    /// and the `optical_feedback` FMU (global piston/tip/tilt into the controller's `u_lo`,
    /// focus-mode through its `y_ref`), both reading the mirror's `z`.
    #[arg(long)]
    pub optical: bool,
    /// Add the `deformation` FMU at this zenith angle (deg; the baseline is 30): its in-plane
    /// segment motion `w` feeds the edge sensors.
    #[arg(long)]
    pub zenith: Option<f64>,
    /// With `--zenith`: the temperature change from the alignment baseline (K).
    #[arg(long, default_value_t = 0.0, requires = "zenith")]
    pub temperature: f64,
    /// Simulated duration (s) [default: 5]. With `--ssp`, overrides the file's stop time
    /// (saying so).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Base communication step (s) [default: 0.001]: a multiple of the 0.2 ms servo period for
    /// the mirror and segments FMUs. With `--cell split` keep it at 2e-4 with Gauss-Seidel
    /// order. With `--ssp`, overrides the file's step (saying so; components stepping slower than
    /// the base step keep their periods).
    #[arg(long)]
    pub step: Option<f64>,
}

impl SystemArgs {
    /// The simulated duration (s).
    pub fn duration(&self) -> f64 {
        self.duration.unwrap_or(DURATION)
    }

    /// The base communication step (s).
    pub fn step(&self) -> f64 {
        self.step.unwrap_or(STEP)
    }
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
    /// annotation set the stop time, the step, the rates and the order; `--stop-time` (or
    /// `--duration`), `--step`, `--uniform` and `--order` override them, each with a note on
    /// stderr, and fill in what the file leaves out.
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
    /// Also record these outputs into each run's results file (repeatable):
    /// `component.signal` (an array by its base name, e.g. `mirror.z`), or a pattern where `*`
    /// stands for any run of characters and `?` for one, e.g. `mirror.z[*]`, `*.rms_surface`,
    /// `sensors.*`. Real, Integer and Boolean outputs (a Boolean as 0/1). The file is written
    /// as the run goes.
    #[arg(long, value_name = "PATTERN")]
    pub record: Vec<String>,
    /// Draw no figures: the mirror displacement is not kept in memory, so a run takes the
    /// same memory whatever its length (the results file and the summary are written as usual).
    #[arg(long)]
    pub no_plots: bool,
    /// Format of each run's results file, written as the run goes: `csv` (a header row, time
    /// first) or `npy` (one float64 rows x columns NumPy array, memory-mappable, for TMT-size
    /// records such as `--record mirror.z`; the column names in `<run>.npy.json`).
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    pub format: Format,
    /// Stepping order of the master [default: gauss-seidel for the standard systems; with
    /// --ssp, the file's order (its master annotation; jacobi without one), which this flag
    /// overrides]. Gauss-Seidel steps the components in turn on their predecessors' newest
    /// outputs: one delay less per connection (needed by `--cell split`), and a component
    /// nobody reads right away (the edge sensors) steps on a second thread meanwhile (same
    /// values; see --no-lookahead). Jacobi steps them in parallel on the values of the last
    /// communication point (results independent of the component order; fmpy.ssp's
    /// convention). In both, a component nobody reads (the optics) steps on the second thread,
    /// its steps queued there.
    #[arg(long, value_enum)]
    pub order: Option<OrderArg>,
    /// Print the summary as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Start every connection at 0 instead of the FMUs' initial outputs (fmpy.ssp's
    /// convention; for comparisons with it).
    #[arg(long)]
    pub zero_start: bool,
    /// Without the master's second thread (every component in turn on this thread; the same
    /// values, for timing comparisons).
    #[arg(long)]
    pub no_lookahead: bool,
    /// Set every connected input at every step, also while its source's outputs have not
    /// changed (as fmpy's masters do), for FMUs that do not keep their inputs between steps as
    /// FMI 2.0 requires. By default an unchanged input is not set again.
    #[arg(long)]
    pub set_unchanged_inputs: bool,
}

/// Format of the results file of `m1cs run`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Comma-separated text, full precision.
    Csv,
    /// A NumPy .npy array (float64, C order) and a .json with its column names.
    Npy,
}

/// Stepping order.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum OrderArg {
    /// Parallel, on the last communication point's values.
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
    let (duration, step) = (a.duration(), a.step());
    if !(duration > 0.0 && step > 0.0 && duration >= step) {
        return Err(format!(
            "--duration {duration} and --step {step} must be positive, the duration at least \
             one step"
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
            ((1.0 / hz) / step).round().max(1.0) as usize
        }
    };
    let (mirror, file) = match (a.cell, a.actuator) {
        (Cell::Coupled | Cell::QuasiStatic, Variant::Voicecoil) => ("mirror", "mirror_voicecoil"),
        (Cell::Coupled | Cell::QuasiStatic, _) => ("mirror", "mirror_piezo"),
        (_, Variant::Voicecoil) => ("segments", "segments_voicecoil"),
        (_, _) => ("segments", "segments_piezo"),
    };
    // Gauss-Seidel, `m1cs run`'s order for the standard systems, so a written .ssp runs as
    // `m1cs run` does.
    let mut s = System::new(duration, step).order(Order::GaussSeidel);
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
    if a.solver_threads != 0 && a.cell == Cell::Coupled {
        s = s.parameter(mirror, "solver_threads", Value::Integer(a.solver_threads));
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
    s = s
        .connect("controller.u_cmd", &format!("{mirror}.u_cmd"))
        .connect(&format!("{mirror}.z"), "sensors.z")
        .connect("sensors.y", "controller.y")
        .connect(&format!("{mirror}.z"), "optics.z");
    if a.optical {
        s = s
            .component("aps", fmu(a, "aps")?)
            .every(per(1.0))
            .component("optical_feedback", fmu(a, "optical_feedback")?)
            .every(per(1.0))
            .connect(&format!("{mirror}.z"), "aps.z")
            .connect(&format!("{mirror}.z"), "optical_feedback.z")
            .connect("aps.y_ref", "optical_feedback.y_ref_in")
            .connect("optical_feedback.y_ref", "controller.y_ref")
            .connect("optical_feedback.u_lo", "controller.u_lo");
    }
    if let Some(zenith) = a.zenith {
        if !(zenith.is_finite() && (0.0..=90.0).contains(&zenith)) {
            return Err(format!("--zenith {zenith}: must be in [0, 90] deg"));
        }
        if !a.temperature.is_finite() {
            return Err(format!("--temperature {}: must be finite", a.temperature));
        }
        s = s
            .component("deformation", fmu(a, "deformation")?)
            .every(per(1.0))
            .parameter("deformation", "zenith_angle", Value::Real(zenith))
            .parameter("deformation", "temperature", Value::Real(a.temperature))
            .connect("deformation.w", "sensors.w");
    }
    Ok(s)
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
    let scalars = cosim::ssp::write_ssp(&s, &name, &a.output).map_err(|e| e.to_string())?;
    println!(
        "wrote {} ({} components, {} signal connections = {scalars} scalar connections)",
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

/// One run recorded into memory (for the commands that analyse the whole series).
pub(crate) struct Outcome {
    pub(crate) results: cosim::system::Results,
}

pub(crate) fn run_one(
    label: &str,
    system: &System,
    decimation: usize,
    metrics: &[&str],
    partial_csv: Option<&Path>,
) -> Result<Outcome, String> {
    let record: Vec<String> = metrics.iter().map(|s| s.to_string()).collect();
    let mut progress = Progress::start(label);
    let outcome = run(system, &record, decimation, &mut |t, stop| {
        progress.show(t, stop);
    });
    progress.finish();
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
    Ok(Outcome { results })
}

/// The progress bar of a run labelled `label` (simulated time over the stop time).
fn progress_bar(label: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(1000);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{prefix:>12} [{bar:30}] {msg} ({elapsed})")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    bar.set_prefix(label.to_string());
    bar
}

/// A run's progress bar (simulated time over the stop time) and the speed since its start.
pub(crate) struct Progress {
    bar: indicatif::ProgressBar,
    t0: Instant,
    /// The position last computed (a thousandth of the run).
    shown: u64,
    /// When the bar was last updated.
    drawn: Instant,
}

/// The shortest wall time between two updates of a run's progress bar. An update takes the
/// bar's lock and formats its message: at every thousandth of a 5 s TMT run (every fifth step)
/// that cost the master's thread about 0.2 us per step on average, 0.5 % of the 60-mode loop
/// (BENCHMARKS.md, twentieth round of issue 18); the bar redraws at about this rate anyway.
const DRAW_EVERY: std::time::Duration = std::time::Duration::from_millis(50);

impl Progress {
    /// The bar of a run labelled `label`, started now.
    pub(crate) fn start(label: &str) -> Self {
        let now = Instant::now();
        Self {
            bar: progress_bar(label),
            t0: now,
            shown: 0,
            drawn: now,
        }
    }

    /// Moves the bar to simulated time `t` of `stop`: cheap when nothing is to be drawn (one
    /// division, and a clock read once per thousandth of the run).
    pub(crate) fn show(&mut self, t: f64, stop: f64) {
        let f = (t / stop).clamp(0.0, 1.0);
        let pos = (f * 1000.0) as u64;
        if pos == self.shown {
            return;
        }
        self.shown = pos;
        let now = Instant::now();
        if pos < 1000 && now.duration_since(self.drawn) < DRAW_EVERY {
            return;
        }
        self.drawn = now;
        self.bar.set_position(pos);
        let wall = now.duration_since(self.t0).as_secs_f64();
        self.bar.set_message(format!(
            "t = {t:.3} s, {:.2}x real time",
            t / wall.max(1e-9)
        ));
    }

    /// Clears the bar.
    pub(crate) fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

/// Mean square over the second half of a recorded column (settled part), as an rms.
pub(crate) fn settled_rms(v: &[f64]) -> f64 {
    let half = &v[v.len() / 2..];
    (half.iter().map(|x| x * x).sum::<f64>() / half.len().max(1) as f64).sqrt()
}

/// The command-line name of an order.
fn order_name(o: Order) -> &'static str {
    match o {
        Order::Jacobi => "jacobi",
        Order::GaussSeidel => "gauss-seidel",
    }
}

/// The system of `--ssp`: the file's stop time, step, rates and order, each overridden by the
/// flag given for it (`--stop-time` or `--duration`, `--step`, `--uniform`, `--order`), with a
/// note on stderr saying so; `--step` and `--duration` fill in what the file leaves out.
fn ssp_system(
    a: &RunCmd,
    path: &Path,
    s: &cosim::ssp::SspSystem,
    order: Option<Order>,
) -> Result<System, String> {
    let mut sys = s.system.clone();
    let file = path.display();
    match (a.system.step, s.has_step) {
        (Some(h), true) if h != sys.step => {
            if !(h.is_finite() && h > 0.0) {
                return Err(format!("--step {h}: must be positive"));
            }
            // Components at the base step follow it; slower ones keep their periods (s).
            let mut rescaled = Vec::new();
            for c in sys.components.iter_mut().filter(|c| c.every > 1) {
                let every = c.every as f64 * sys.step / h;
                if (every - every.round()).abs() > 1e-6 * every || every.round() < 1.0 {
                    return Err(format!(
                        "--step {h}: {} steps every {} s in {file}, not a whole number of {h} s \
                         steps",
                        c.name,
                        c.every as f64 * sys.step
                    ));
                }
                rescaled.push(format!("{} every {}", c.name, every.round()));
                c.every = every.round() as usize;
            }
            eprintln!(
                "note: --step {h} overrides the step of {file} ({} s){}",
                sys.step,
                if rescaled.is_empty() {
                    String::new()
                } else {
                    format!(
                        "; the slower components keep their periods: {}",
                        rescaled.join(", ")
                    )
                }
            );
            sys.step = h;
        }
        (Some(h), false) => sys.step = h,
        (None, false) => sys.step = STEP,
        _ => {}
    }
    let stop = match (a.stop_time, a.system.duration) {
        (Some(t), _) => Some(t),
        (None, Some(d)) => Some(sys.start_time + d),
        (None, None) => None,
    };
    match stop {
        Some(t) => {
            if !(t.is_finite() && t > sys.start_time + sys.step * 0.5) {
                return Err(format!(
                    "stop time {t} s must be after the system's start time {} s by a step at \
                     least",
                    sys.start_time
                ));
            }
            if sys.stop_time > sys.start_time && t != sys.stop_time {
                eprintln!(
                    "note: the command line's stop time {t} s overrides that of {file} ({} s)",
                    sys.stop_time
                );
            }
            sys.stop_time = t;
        }
        None if sys.stop_time <= sys.start_time => sys.stop_time = sys.start_time + DURATION,
        None => {}
    }
    if a.system.uniform && sys.components.iter().any(|c| c.every > 1) {
        eprintln!("note: --uniform steps every component of {file} at the base step");
        for c in &mut sys.components {
            c.every = 1;
        }
    }
    if let Some(o) = order {
        if o != sys.order {
            eprintln!(
                "note: --order {} overrides the order of {file} ({})",
                order_name(o),
                order_name(sys.order)
            );
        }
        sys.order = o;
    }
    Ok(sys)
}

impl RunCmd {
    /// The master's options of this command on system `s`: zero start, look-ahead thread,
    /// unchanged inputs.
    fn master_options(&self, s: &mut System) {
        s.zero_start = self.zero_start;
        s.no_lookahead = self.no_lookahead;
        s.set_unchanged_inputs = self.set_unchanged_inputs;
    }
}

/// Runs `m1cs run`.
pub fn run_cmd(a: &RunCmd) -> Result<(), String> {
    std::fs::create_dir_all(&a.out).map_err(|e| format!("{}: {e}", a.out.display()))?;
    let given = a.order.map(|o| match o {
        OrderArg::Jacobi => Order::Jacobi,
        OrderArg::GaussSeidel => Order::GaussSeidel,
    });
    let order = given.unwrap_or(Order::GaussSeidel);
    let mut runs: Vec<(String, System)> = Vec::new();
    if let Some(path) = &a.ssp {
        let s = cosim::ssp::read(path).map_err(|e| e.to_string())?;
        let mut sys = ssp_system(a, path, &s, given)?;
        a.master_options(&mut sys);
        runs.push(("system".into(), sys));
        // Keep the unpacked archive alive during the run.
        // The optics metrics are recorded when the system has an `optics` component.
        let has_optics = runs[0].1.components.iter().any(|c| c.name == "optics");
        let metrics: &[&str] = if has_optics { &METRICS } else { &[] };
        // Paths inside the unpacked archive are named as `X.ssp: resources/x.fmu`.
        let outcome = execute(a, runs, metrics).map_err(|e| s.localize(&e));
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
            a.master_options(&mut s);
            runs.push((label.into(), s));
        }
    } else {
        for (label, closed) in [("open loop", false), ("closed loop", true)] {
            let mut s = standard_system(&a.system, closed)?;
            s.order = order;
            a.master_options(&mut s);
            runs.push((label.into(), s));
        }
    }
    execute(a, runs, &METRICS)
}
