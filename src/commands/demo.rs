//! `m1cs demo`: the segments FMUs' model driven in-process on a layout, through the FMU's own
//! variable table: the command step response and the static stiffness of each actuator
//! variant, with the bandwidths and the 1 Hz stiffness from the physics' frequency response
//! ([`m1::analysis::step_response`]).

use clap::{Args, ValueEnum};

use fmu::{Model, Running, Values, VariableTable};
use m1::analysis::step_response::{StepFigures, command_bandwidth};
use m1::plant::segment::{ActuatorParams, Channel, SegmentModel};

/// Communication step of the runs (s).
const STEP: f64 = 1e-3;
/// Piston command step on the first segment (m).
const COMMAND_STEP: f64 = 1e-6;
/// Steps of the command-step run.
const COMMAND_STEPS: usize = 1000;
/// Force step per actuator of the stiffness run (N).
const FORCE_STEP: f64 = 100.0;
/// Steps of the force-step run (to its static value).
const FORCE_STEPS: usize = 3000;
/// The response is kept every this many steps...
const RESPONSE_EVERY: usize = 10;
/// ... for this many samples (the first 0.3 s).
const RESPONSE_SAMPLES: usize = 31;

/// `m1cs demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Mirror layout (keck, tmt, elt).
    #[arg(long, default_value = m1::aperture::layout::DEFAULT_LAYOUT)]
    pub layout: String,
    /// Actuator variants to run (default: all).
    #[arg(long, value_enum)]
    pub actuator: Vec<Actuator>,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    pub json: bool,
}

/// Actuator variant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Actuator {
    /// Soft voice coil with offload spring (baseline).
    Voicecoil,
    /// Hard piezo stack, undamped.
    Piezo,
    /// Hard piezo stack with its LR shunt connected.
    PiezoDamped,
}

impl Actuator {
    const ALL: [Actuator; 3] = [Actuator::Voicecoil, Actuator::Piezo, Actuator::PiezoDamped];

    fn name(self) -> &'static str {
        match self {
            Actuator::Voicecoil => "voicecoil",
            Actuator::Piezo => "piezo",
            Actuator::PiezoDamped => "piezo-damped",
        }
    }

    /// The physics' model of the variant (default parameters, as in the FMU).
    fn model(self) -> SegmentModel {
        match self {
            Actuator::Voicecoil => SegmentModel::voice_coil(),
            Actuator::Piezo => SegmentModel::piezo(),
            Actuator::PiezoDamped => SegmentModel {
                actuator: ActuatorParams::piezo_damped(),
                ..SegmentModel::piezo()
            },
        }
    }
}

/// The segments model of the FMU, driven in-process through the same variable table.
struct Sim<M: Model> {
    table: VariableTable,
    values: Values,
    model: M::Running,
    time: f64,
}

impl<M: Model> Sim<M> {
    fn new(layout: &str, setup: impl FnOnce(&VariableTable, &mut Values)) -> Result<Self, String> {
        let (table, model) = M::new(layout).map_err(|e| e.to_string())?;
        let mut values = table.initial_values();
        setup(&table, &mut values);
        let model = model
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

/// Sets the piezo's shunt of the FMU (a no-op on the voice coil, which has none).
fn shunt_setup(shunt: bool) -> impl Fn(&VariableTable, &mut Values) + Copy {
    move |t: &VariableTable, v: &mut Values| {
        if let Some(var) = t.by_name("shunt_enabled") {
            v.booleans[var.slot] = shunt;
        }
    }
}

/// Actuator 1's displacement (m) from 0 over a piston command step of [`COMMAND_STEP`] on
/// segment 1, every [`STEP`].
fn command_step<M: Model>(layout: &str, shunt: bool) -> Result<Vec<f64>, String> {
    let mut sim = Sim::<M>::new(layout, shunt_setup(shunt))?;
    for k in 0..3 {
        sim.set("u_cmd", k, COMMAND_STEP);
    }
    let mut z = vec![0.0];
    for _ in 0..COMMAND_STEPS {
        sim.step(STEP)?;
        z.push(sim.get("z", 0));
    }
    Ok(z)
}

/// Static stiffness per actuator (N/m) measured from a force step of [`FORCE_STEP`] on the
/// actuators of segment 1, and the FMU's analytic value.
fn force_step<M: Model>(layout: &str, shunt: bool) -> Result<(f64, f64), String> {
    let mut sim = Sim::<M>::new(layout, shunt_setup(shunt))?;
    for k in 0..3 {
        sim.set("f_wind", k, FORCE_STEP);
    }
    for _ in 0..FORCE_STEPS {
        sim.step(STEP)?;
    }
    Ok((
        FORCE_STEP / sim.get("z", 0),
        sim.get("static_stiffness_piston", 0),
    ))
}

fn demo_one<M: Model>(layout: &str, act: Actuator) -> Result<DemoResult, String> {
    let shunt = act == Actuator::PiezoDamped;
    let z = command_step::<M>(layout, shunt)?;
    let step = StepFigures::of(&z, STEP, COMMAND_STEP);
    let response = z
        .iter()
        .enumerate()
        .step_by(RESPONSE_EVERY)
        .take(RESPONSE_SAMPLES)
        .map(|(k, &x)| (k as f64 * STEP, x))
        .collect();
    let (stiffness_measured, stiffness_analytic) = force_step::<M>(layout, shunt)?;
    // The physics' own frequency response (default parameters, as in the FMU), for the
    // bandwidth and the 1 Hz stiffness.
    let model = act.model();
    let stiffness_1hz = 1.0 / model.mirror_response(Channel::Piston, 1.0)[2].norm();
    Ok(DemoResult {
        actuator: act.name(),
        rise_time: step.rise_time,
        overshoot: step.overshoot,
        settling_time: step.settling_time,
        bandwidth_piston: command_bandwidth(&model, Channel::Piston),
        bandwidth_tilt: command_bandwidth(&model, Channel::Tilt),
        stiffness_measured,
        stiffness_analytic,
        stiffness_1hz,
        response,
    })
}

/// Runs `m1cs demo`.
pub fn demo(a: &DemoArgs) -> Result<(), String> {
    let l = super::load_layout(&a.layout)?;
    let acts = if a.actuator.is_empty() {
        &Actuator::ALL[..]
    } else {
        &a.actuator[..]
    };
    let mut results = Vec::new();
    for &act in acts {
        results.push(match act {
            Actuator::Voicecoil => demo_one::<segments::VoiceCoil>(&l.name, act)?,
            _ => demo_one::<segments::Piezo>(&l.name, act)?,
        });
    }
    if a.json {
        let out = serde_json::json!({
            "layout": l.name,
            "segments": l.n_segments(),
            "actuators": l.n_actuators(),
            "results": results,
        });
        println!("{out}");
        return Ok(());
    }
    print_tables(&l, &results);
    Ok(())
}

fn print_tables(l: &m1::aperture::layout::Layout, results: &[DemoResult]) {
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
    for r in results {
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
    for r in results {
        print!("{:<14}", r.actuator);
        for (_, z) in r.response.iter().step_by(2) {
            print!("{:>6.0}", z * 1e9);
        }
        println!();
    }
    println!(
        "\nFMUs: target/fmu/<layout>/segments_voicecoil.fmu and segments_piezo.fmu (cargo xtask package)."
    );
}
