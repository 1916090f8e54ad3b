//! `m1cs`: the command-line tool of the segmented-mirror control-system toolset.

use clap::{Parser, Subcommand, ValueEnum};
use std::process::ExitCode;

use fmu::{Model, Values, VariableTable};
use m1::aperture::layout::Layout;
use m1::plant::segment::{Channel, SegmentModel};

mod commands;
mod plot;

#[derive(Parser)]
#[command(
    name = "m1cs",
    version,
    about = "Segmented primary-mirror control-system modelling: FMI components and analyses"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Runs the segments FMUs' model on a layout: command step response and static stiffness of
    /// each actuator variant.
    Demo {
        /// Mirror layout (keck, tmt, elt).
        #[arg(long, default_value = "tmt")]
        layout: String,
        /// Actuator variants to run (default: all).
        #[arg(long, value_enum)]
        actuator: Vec<Actuator>,
        /// Print one JSON object instead of the tables.
        #[arg(long)]
        json: bool,
    },
    /// SVD of the A-matrix: rank, near-null global piston/tip/tilt, focus-mode and the next
    /// least observable modes (with their dominant Zernike), optional full-matrix ranks.
    Amatrix(commands::quasistatic::AmatrixArgs),
    /// Robustness to A-matrix errors (the seed paper's Table 1): rho(Q - I), sigma(Q),
    /// sigma(Gamma Psi Q Psi^T) and the risk of instability over seeded realizations.
    Robustness(commands::quasistatic::RobustnessArgs),
    /// Propagation of white sensor noise to the mirror, with and without focus-mode.
    Noise(commands::quasistatic::NoiseArgs),
    /// Out-of-plane error the control introduces for in-plane clocking of one segment (eq. 3).
    Clocking(commands::quasistatic::ClockingArgs),
    /// Shear estimated from gap readings (eq. 2): the unobservable torsion mode and gap noise.
    Calibration(commands::quasistatic::CalibrationArgs),
    /// Zernike basis on the segmented aperture and its segment piston/tip/tilt projection.
    Zernike(commands::optics::ZernikeArgs),
    /// PSSN of a seeded random segment piston/tip/tilt state.
    Pssn(commands::optics::PssnArgs),
    /// Runs the closed-loop scenario (default: TMT, wind, voice coils, open and closed loop) or a
    /// user's .ssp with the included master; CSV, plots and a summary in --out.
    Run(commands::cosim::RunCmd),
    /// Segments and structure as two co-simulation components against the coupled solver: the
    /// largest communication step each actuator variant tolerates, and why one mirror FMU.
    Coupling(commands::dynamics::CouplingArgs),
    /// Control-structure interaction of the actuator servo loop: sensitivity in Zernike and
    /// segment bases and with all segments, and the highest servo gain meeting the criterion.
    Csi(commands::csi::CsiArgs),
    /// M1 rms surface under wind versus wind speed and global-loop bandwidth, open and closed
    /// loop, with the focus-mode share and M1 maps (the master on the standard wind system).
    Wind(commands::wind::WindArgs),
    /// M1 rms surface and PSSN versus pier frequency for the three actuator variants, from the
    /// monolithic frequency model; the hard/soft and undamped/damped ratios at 29.6 Hz.
    Vibration(commands::dynamics::VibrationArgs),
    /// Runs every analysis with its defaults into DIR: one Markdown page (index.md) with the
    /// figures and the key numbers of each.
    Report(commands::report::ReportArgs),
    /// Writes a standard closed-loop system (layout x actuator x scenario) as an SSP archive.
    System(commands::cosim::SystemCmd),
    /// Reports a layout: segments, actuators, edges, sensors and the neighbour histogram.
    #[command(alias = "layout")]
    Geometry {
        /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
        #[arg(long, default_value = "tmt")]
        layout: String,
        /// Print one JSON object.
        #[arg(long)]
        json: bool,
        /// Map PNG of the segments coloured by their number of neighbours.
        #[arg(long)]
        plot: Option<String>,
    },
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Actuator {
    /// Soft voice coil with offload spring (baseline).
    Voicecoil,
    /// Hard piezo stack, undamped.
    Piezo,
    /// Hard piezo stack with its LR shunt connected.
    PiezoDamped,
}

impl Actuator {
    fn name(self) -> &'static str {
        match self {
            Actuator::Voicecoil => "voicecoil",
            Actuator::Piezo => "piezo",
            Actuator::PiezoDamped => "piezo-damped",
        }
    }
}

pub(crate) fn load_layout(name: &str) -> Result<Layout, String> {
    let path = std::path::Path::new(name);
    if path.extension().is_some_and(|e| e == "json") {
        Layout::from_json_file(path).map_err(|e| e.to_string())
    } else {
        Layout::preset(name).map_err(|e| e.to_string())
    }
}

/// The segments model of the FMU, driven in-process through the same variable table.
struct Sim<M: Model> {
    table: VariableTable,
    values: Values,
    model: M,
    time: f64,
}

impl<M: Model> Sim<M> {
    fn new(layout: &str, setup: impl FnOnce(&VariableTable, &mut Values)) -> Result<Self, String> {
        let (table, mut model) = M::new(layout).map_err(|e| e.to_string())?;
        let mut values = table.initial_values();
        setup(&table, &mut values);
        model
            .initialize(&mut values, 0.0)
            .map_err(|e| e.to_string())?;
        Ok(Self {
            table,
            values,
            model,
            time: 0.0,
        })
    }

    fn slot(&self, name: &str) -> usize {
        self.table.by_name(name).map_or(usize::MAX, |v| v.slot)
    }

    fn set(&mut self, name: &str, index: usize, x: f64) {
        let s = self.slot(name) + index;
        if let Some(v) = self.values.reals.get_mut(s) {
            *v = x;
        }
    }

    fn get(&self, name: &str, index: usize) -> f64 {
        self.values
            .reals
            .get(self.slot(name) + index)
            .copied()
            .unwrap_or(f64::NAN)
    }

    fn step(&mut self, h: f64) -> Result<(), String> {
        self.model
            .do_step(self.time, h, &mut self.values)
            .map_err(|e| e.to_string())?;
        self.time += h;
        Ok(())
    }
}

#[derive(serde::Serialize)]
struct DemoResult {
    actuator: &'static str,
    /// Piston command step of 1 um on segment 1: 10-90 % rise time (s).
    rise_time: f64,
    /// Overshoot (fraction of the step).
    overshoot: f64,
    /// Settling time to within 2 % (s).
    settling_time: f64,
    /// -3 dB bandwidth of the piston command response (Hz).
    bandwidth_piston: f64,
    /// -3 dB bandwidth of the tilt command response (Hz).
    bandwidth_tilt: f64,
    /// Static stiffness per actuator at the mirror, piston load, measured from a force step (N/m).
    stiffness_measured: f64,
    /// The same from the analytic formula (N/m).
    stiffness_analytic: f64,
    /// Compliance at 1 Hz, inverted (N/m), piston load.
    stiffness_1hz: f64,
    /// Response samples (time s, z m) every 10 ms over the first 0.3 s.
    response: Vec<(f64, f64)>,
}

fn bandwidth(model: &SegmentModel, ch: Channel) -> f64 {
    let mut f = 0.1;
    while f < 2000.0 {
        if model.mirror_response(ch, f)[0].norm() < std::f64::consts::FRAC_1_SQRT_2 {
            return f;
        }
        f *= 1.01;
    }
    f64::NAN
}

fn demo_one<M: Model>(layout: &str, act: Actuator) -> Result<DemoResult, String> {
    let shunt = act == Actuator::PiezoDamped;
    let setup = |t: &VariableTable, v: &mut Values| {
        if let Some(var) = t.by_name("shunt_enabled") {
            v.booleans[var.slot] = shunt;
        }
    };
    let h = 1e-3;
    // Command step.
    let mut sim = Sim::<M>::new(layout, setup)?;
    for k in 0..3 {
        sim.set("u_cmd", k, 1e-6);
    }
    let mut z = vec![0.0];
    for _ in 0..1000 {
        sim.step(h)?;
        z.push(sim.get("z", 0));
    }
    let t_at = |k: usize| k as f64 * h;
    let first = |th: f64| {
        z.iter()
            .position(|&x| x >= th * 1e-6)
            .map_or(f64::NAN, t_at)
    };
    let rise_time = first(0.9) - first(0.1);
    let peak = z.iter().fold(0.0f64, |m, &x| m.max(x));
    let settle = z
        .iter()
        .rposition(|&x| (x / 1e-6 - 1.0).abs() > 0.02)
        .map_or(0.0, |k| t_at(k + 1));
    let response = z
        .iter()
        .enumerate()
        .step_by(10)
        .take(31)
        .map(|(k, &x)| (t_at(k), x))
        .collect();

    // Force step: static stiffness.
    let mut sim = Sim::<M>::new(layout, setup)?;
    let f = 100.0;
    for k in 0..3 {
        sim.set("f_wind", k, f);
    }
    for _ in 0..3000 {
        sim.step(h)?;
    }
    let stiffness_measured = f / sim.get("z", 0);
    let stiffness_analytic = sim.get("static_stiffness_piston", 0);
    // The physics' own frequency response (default parameters, as in the FMU), for the
    // bandwidth and the 1 Hz stiffness.
    let array_model = match act {
        Actuator::Voicecoil => SegmentModel::voice_coil(),
        Actuator::Piezo => SegmentModel::piezo(),
        Actuator::PiezoDamped => SegmentModel {
            actuator: m1::plant::segment::ActuatorParams::piezo_damped(),
            ..SegmentModel::piezo()
        },
    };
    let stiffness_1hz = 1.0 / array_model.mirror_response(Channel::Piston, 1.0)[2].norm();
    Ok(DemoResult {
        actuator: act.name(),
        rise_time,
        overshoot: peak / 1e-6 - 1.0,
        settling_time: settle,
        bandwidth_piston: bandwidth(&array_model, Channel::Piston),
        bandwidth_tilt: bandwidth(&array_model, Channel::Tilt),
        stiffness_measured,
        stiffness_analytic,
        stiffness_1hz,
        response,
    })
}

fn demo(layout: &str, actuators: &[Actuator], json: bool) -> Result<(), String> {
    let l = load_layout(layout)?;
    let all = [Actuator::Voicecoil, Actuator::Piezo, Actuator::PiezoDamped];
    let acts = if actuators.is_empty() {
        &all[..]
    } else {
        actuators
    };
    let mut results = Vec::new();
    for &a in acts {
        results.push(match a {
            Actuator::Voicecoil => demo_one::<segments::VoiceCoil>(&l.name, a)?,
            _ => demo_one::<segments::Piezo>(&l.name, a)?,
        });
    }
    if json {
        let out = serde_json::json!({
            "layout": l.name,
            "segments": l.n_segments(),
            "actuators": l.n_actuators(),
            "results": results,
        });
        println!("{out}");
        return Ok(());
    }
    println!(
        "Segments FMU model, layout {} ({} segments, {} actuators), 1 ms communication step, servo 5 kHz",
        l.name,
        l.n_segments(),
        l.n_actuators()
    );
    println!("Command step of 1 um (piston of segment 1) and force step of 100 N per actuator:\n");
    println!(
        "{:<14} {:>10} {:>10} {:>10} {:>12} {:>12} {:>14} {:>14} {:>12}",
        "actuator",
        "rise (ms)",
        "overshoot",
        "settle(ms)",
        "BW pist(Hz)",
        "BW tilt(Hz)",
        "K static meas",
        "K analytic",
        "K @1Hz"
    );
    for r in &results {
        println!(
            "{:<14} {:>10.1} {:>9.1}% {:>10.0} {:>12.1} {:>12.1} {:>10.2} N/um {:>9.2} N/um {:>7.2} N/um",
            r.actuator,
            r.rise_time * 1e3,
            r.overshoot * 100.0,
            r.settling_time * 1e3,
            r.bandwidth_piston,
            r.bandwidth_tilt,
            r.stiffness_measured * 1e-6,
            r.stiffness_analytic * 1e-6,
            r.stiffness_1hz * 1e-6
        );
    }
    println!("\nStep response z (nm) of actuator 1, every 20 ms:");
    print!("{:<14}", "t (ms)");
    for k in (0..=300).step_by(20) {
        print!("{k:>6}");
    }
    println!();
    for r in &results {
        print!("{:<14}", r.actuator);
        for (_, z) in r.response.iter().step_by(2) {
            print!("{:>6.0}", z * 1e9);
        }
        println!();
    }
    println!(
        "\nFMUs: target/fmu/<layout>/segments_voicecoil.fmu and segments_piezo.fmu (cargo xtask package)."
    );
    Ok(())
}

fn layout_report(name: &str, json: bool, plot: Option<&str>) -> Result<(), String> {
    let l = load_layout(name)?;
    let hist = l.neighbour_histogram();
    if let Some(p) = plot {
        let degree: Vec<f64> = (0..l.n_segments())
            .map(|i| l.neighbours(i).len() as f64)
            .collect();
        plot::mirror_map(
            p,
            &l,
            &degree,
            &format!("{}: neighbours per segment", l.name),
            "neighbours",
        )
        .map_err(|e| e.to_string())?;
    }
    if json {
        let out = serde_json::json!({
            "layout": l.name,
            "segments": l.n_segments(),
            "actuators": l.n_actuators(),
            "edges": l.n_edges(),
            "sensors": l.n_sensors(),
            "neighbours": hist,
            "circumradius_m": l.circumradius,
            "gap_m": l.gap,
            "pitch_m": l.pitch(),
        });
        println!("{out}");
    } else {
        println!(
            "{}: {} segments, {} actuators, {} shared edges, {} edge sensors; pitch {:.5} m",
            l.name,
            l.n_segments(),
            l.n_actuators(),
            l.n_edges(),
            l.n_sensors(),
            l.pitch()
        );
        for (k, n) in hist {
            println!("  {n:>4} segments with {k} neighbours");
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    // Like other Unix tools, end quietly when the reader of our output goes away
    // (`m1cs run | head`) instead of failing on the broken pipe.
    #[cfg(unix)]
    // SAFETY: called first in main, before any other thread exists; SIG_DFL is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let r = match cli.command {
        Cmd::Demo {
            layout,
            actuator,
            json,
        } => demo(&layout, &actuator, json),
        Cmd::Geometry { layout, json, plot } => layout_report(&layout, json, plot.as_deref()),
        Cmd::Amatrix(a) => commands::quasistatic::amatrix(&a),
        Cmd::Run(a) => commands::cosim::run_cmd(&a),
        Cmd::System(a) => commands::cosim::system(&a),
        Cmd::Coupling(a) => commands::dynamics::coupling(&a),
        Cmd::Csi(a) => commands::csi::csi(&a),
        Cmd::Wind(a) => commands::wind::wind(&a),
        Cmd::Vibration(a) => commands::dynamics::vibration(&a),
        Cmd::Report(a) => commands::report::report(&a),
        Cmd::Robustness(a) => commands::quasistatic::robustness(&a),
        Cmd::Noise(a) => commands::quasistatic::noise(&a),
        Cmd::Clocking(a) => commands::quasistatic::clocking(&a),
        Cmd::Calibration(a) => commands::quasistatic::calibration(&a),
        Cmd::Zernike(a) => commands::optics::run_zernike(&a),
        Cmd::Pssn(a) => commands::optics::run_pssn(&a),
    };
    match r {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
