//! `m1cs csi`: control-structure interaction (the seed paper's Figure 11). (a) The actuator
//! servo loop: the largest singular value of the servo's sensitivity on the flexible cell in
//! Zernike bases of increasing radial degree, in segment bases and with all segments, and the
//! highest servo gain meeting the sensitivity criterion ([`m1::analysis::csi`]). (b) The global
//! edge-sensor loop: its principal loop gain and sensitivity in Zernike bases and with all
//! segments against the paper's criteria (with the allowance for interaction-matrix
//! uncertainty, set against the quasi-static Q), and the highest bandwidth meeting them
//! ([`m1::analysis::global_csi`]).
//!
//! `mod.rs` the arguments and the computation, `report.rs` what is printed, `plots.rs` the
//! figures.

mod plots;
mod report;

use plots::{write_global_plot, write_plots};
use report::{print_global, print_servo, q_allowance};

use clap::{Args, ValueEnum};
use serde_json::json;

use m1::analysis::csi::{
    ActuatorLoop, BasisCurve, CsiSweep, GainLimit, LANCZOS_STEPS, LANCZOS_STEPS_RANGE,
    highest_gain, log_grid, sweep,
};
use m1::analysis::defaults::{self as study, csi as servo_study, global_csi as global_study};
use m1::analysis::global_csi::{
    GlobalCriteria, GlobalCsi, GlobalQuantity, GlobalSweep, SENSITIVITY_LABEL_FROM, global_sweep,
};
use m1::analysis::quasistatic::{self, Case, Perturbation, RobustnessParams};
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::{self as controller, ControllerParams};
use m1::control::nominal::Nominal;
use m1::plant::monolithic::FrequencyModel;
use m1::plant::segment::SegmentModel;

use super::defaults::list;
use crate::plot;

/// `--help`'s form of the default gain range.
static GAIN_RANGE: std::sync::LazyLock<String> =
    std::sync::LazyLock::new(|| list(&servo_study::GAIN_RANGE));

/// Actuator variants.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum CsiActuator {
    /// Soft voice coil with offload spring (baseline).
    Voicecoil,
    /// Hard piezo stack, undamped.
    Piezo,
    /// Hard piezo stack with its LR shunt connected.
    PiezoDamped,
}

impl CsiActuator {
    fn model(self) -> SegmentModel {
        match self {
            CsiActuator::Voicecoil => SegmentModel::voice_coil(),
            CsiActuator::Piezo => SegmentModel::piezo(),
            CsiActuator::PiezoDamped => SegmentModel::piezo_damped_default(),
        }
    }

    fn name(self) -> &'static str {
        match self {
            CsiActuator::Voicecoil => "voicecoil",
            CsiActuator::Piezo => "piezo",
            CsiActuator::PiezoDamped => "piezo-damped",
        }
    }
}

/// `m1cs csi`.
#[derive(Args, Debug)]
pub struct CsiArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = m1::aperture::layout::DEFAULT_LAYOUT)]
    pub layout: String,
    /// Retained structure modes.
    #[arg(long, default_value_t = study::STRUCTURE_MODES)]
    pub modes: usize,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
    /// Modal damping ratio of the structure.
    #[arg(long, default_value_t = study::DAMPING_RATIO)]
    pub damping: f64,
    /// Actuator variant.
    #[arg(long, value_enum, default_value_t = CsiActuator::Voicecoil)]
    pub actuator: CsiActuator,
    /// Largest radial degree of the Zernike bases.
    #[arg(long, default_value_t = servo_study::MAX_DEGREE)]
    pub max_degree: u32,
    /// Log-spaced grid points (a refinement around each peak is added).
    #[arg(long, default_value_t = servo_study::FREQUENCIES)]
    pub frequencies: usize,
    /// Lowest frequency (Hz).
    #[arg(long, default_value_t = servo_study::FMIN_HZ)]
    pub fmin: f64,
    /// Highest frequency (Hz).
    #[arg(long, default_value_t = servo_study::FMAX_HZ)]
    pub fmax: f64,
    /// Sensitivity criterion: sigma_max(S) below this...
    #[arg(long, default_value_t = servo_study::MAX_SENSITIVITY)]
    pub max_sensitivity: f64,
    /// ... at every grid frequency up to this (Hz).
    #[arg(long, default_value_t = servo_study::BELOW_HZ)]
    pub below: f64,
    /// Range of the factor on the servo gains searched (lo,hi).
    #[arg(long, value_delimiter = ',', default_value = GAIN_RANGE.as_str())]
    pub gain_range: Vec<f64>,
    /// Lanczos steps at most per all-segment value (12 to 10000): where the top singular values
    /// cluster this ends the iteration, the value then a lower bound (within 3e-5 of the exact
    /// one on TMT with 60 steps); more steps come closer at proportionally more time.
    #[arg(long, default_value_t = LANCZOS_STEPS)]
    pub lanczos_steps: usize,
    /// Global loop: bandwidth of the modes of radial degrees >= 5 (every mode outside the three
    /// groups below) (Hz).
    #[arg(long, default_value_t = controller::DEFAULT_BANDWIDTH)]
    pub bandwidth: f64,
    /// Global loop: bandwidth of radial degrees 3-4 (Z7 to Z15, without radial degree 2 and
    /// focus-mode) (Hz).
    #[arg(long, default_value_t = controller::DEFAULT_BANDWIDTH_RADIAL34)]
    pub bandwidth_radial34: f64,
    /// Global loop: bandwidth of radial degree 2 without focus-mode (astigmatism) (Hz).
    #[arg(long, default_value_t = controller::DEFAULT_BANDWIDTH_RADIAL2)]
    pub bandwidth_radial2: f64,
    /// Global loop: bandwidth of focus-mode (Hz).
    #[arg(long, default_value_t = controller::DEFAULT_BANDWIDTH_FOCUS)]
    pub bandwidth_focus: f64,
    /// Global loop: sample rate (Hz).
    #[arg(long, default_value_t = controller::DEFAULT_RATE)]
    pub loop_rate: f64,
    /// Global loop: structure modes (the lowest, at most --modes; the loop's band with its
    /// sampling images ends at 3.5 loop rates).
    #[arg(long, default_value_t = global_study::MODES)]
    pub global_modes: usize,
    /// Global loop: log-spaced grid points from --global-fmin to --loop-gain-from (then
    /// every --global-band-step Hz up to the loop's Nyquist frequency).
    #[arg(long, default_value_t = global_study::FREQUENCIES)]
    pub global_frequencies: usize,
    /// Global loop: grid step (Hz) from --loop-gain-from to the Nyquist frequency, fine enough
    /// for the structure's lightly damped modes (half-power width 2 zeta f = 0.36 Hz at 9 Hz).
    #[arg(long, default_value_t = global_study::BAND_STEP_HZ)]
    pub global_band_step: f64,
    /// Global loop: lowest frequency (Hz).
    #[arg(long, default_value_t = global_study::FMIN_HZ)]
    pub global_fmin: f64,
    /// Global loop: images of the sensors' sampling summed on each side.
    #[arg(long, default_value_t = global_study::ALIASES)]
    pub aliases: usize,
    /// Global loop: the principal loop gain must stay below 1/2 divided by this at high
    /// frequency (the seed paper's allowance for interaction-matrix uncertainty).
    #[arg(long, default_value_t = GlobalCriteria::default().allowance)]
    pub allowance: f64,
    /// Global loop: the loop-gain criterion applies at and above this frequency (Hz): the
    /// structural resonances (below 8 Hz the bare integrator's own loop gain approaches the
    /// limit).
    #[arg(long, default_value_t = m1::analysis::global_csi::DEFAULT_BAND_START_HZ)]
    pub loop_gain_from: f64,
    /// Realizations of 0.1 % sensor-gain errors whose worst sigma_max(Gamma Psi Q Psi^T) is
    /// set against the allowance (0 skips it).
    #[arg(long, default_value_t = global_study::Q_REALIZATIONS)]
    pub q_realizations: usize,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Directory for sensitivity.png, convergence.png, global.png and global_band.png (the
    /// loop-gain band on a linear axis); peaks are labelled with their Zernike family.
    #[arg(long)]
    pub plot: Option<String>,
}

/// Extra grid points between the neighbours of each curve's peak.
const REFINE: usize = 4;
/// Local maxima of the all-segment curve above this are labelled.
const LABEL_THRESHOLD: f64 = 1.2;
/// Largest segment basis beyond the sizes of the Zernike bases (vectors).
const SEGMENT_VECTORS: usize = 96;

fn check_args(a: &CsiArgs) -> Result<(f64, f64), String> {
    if a.modes == 0 {
        return Err("--modes: must be at least 1".into());
    }
    if !(a.damping.is_finite() && a.damping >= 0.0) {
        return Err(format!("--damping {}: must be finite and >= 0", a.damping));
    }
    if !LANCZOS_STEPS_RANGE.contains(&a.lanczos_steps) {
        return Err(format!(
            "--lanczos-steps {}: must be from {} to {}",
            a.lanczos_steps,
            LANCZOS_STEPS_RANGE.start(),
            LANCZOS_STEPS_RANGE.end()
        ));
    }
    if a.frequencies < 3 {
        return Err(format!(
            "--frequencies {}: must be at least 3",
            a.frequencies
        ));
    }
    if !(a.fmin.is_finite() && a.fmin > 0.0) {
        return Err(format!("--fmin {}: must be finite and > 0", a.fmin));
    }
    if !(a.fmax.is_finite() && a.fmax > a.fmin) {
        return Err(format!("--fmax {}: must be finite and > --fmin", a.fmax));
    }
    if !(a.max_sensitivity.is_finite() && a.max_sensitivity > 1.0) {
        return Err(format!(
            "--max-sensitivity {}: must be finite and > 1",
            a.max_sensitivity
        ));
    }
    if !(a.below.is_finite() && a.below >= a.fmin) {
        return Err(format!("--below {}: must be finite and >= --fmin", a.below));
    }
    for (name, v) in [
        ("--bandwidth", a.bandwidth),
        ("--bandwidth-radial34", a.bandwidth_radial34),
        ("--bandwidth-radial2", a.bandwidth_radial2),
        ("--bandwidth-focus", a.bandwidth_focus),
    ] {
        if !(v.is_finite() && v >= 0.0 && v < 0.5 * a.loop_rate) {
            return Err(format!(
                "{name} {v}: must be finite, >= 0 and below half the loop rate ({} Hz)",
                0.5 * a.loop_rate
            ));
        }
    }
    if !(a.loop_rate.is_finite() && a.loop_rate > 0.0) {
        return Err(format!(
            "--loop-rate {}: must be finite and > 0",
            a.loop_rate
        ));
    }
    if a.global_modes == 0 {
        return Err("--global-modes: must be at least 1".into());
    }
    if a.global_frequencies < 3 {
        return Err(format!(
            "--global-frequencies {}: must be at least 3",
            a.global_frequencies
        ));
    }
    if !(a.global_fmin.is_finite() && a.global_fmin > 0.0 && a.global_fmin < 0.5 * a.loop_rate) {
        return Err(format!(
            "--global-fmin {}: must be finite, > 0 and below half the loop rate",
            a.global_fmin
        ));
    }
    if !(a.global_band_step.is_finite() && a.global_band_step > 0.0) {
        return Err(format!(
            "--global-band-step {}: must be finite and > 0",
            a.global_band_step
        ));
    }
    if a.loop_gain_from <= a.global_fmin {
        return Err(format!(
            "--loop-gain-from {}: must be above --global-fmin {}",
            a.loop_gain_from, a.global_fmin
        ));
    }
    if !(a.allowance.is_finite() && a.allowance >= 1.0) {
        return Err(format!(
            "--allowance {}: must be finite and >= 1",
            a.allowance
        ));
    }
    if !(a.loop_gain_from.is_finite() && a.loop_gain_from > 0.0) {
        return Err(format!(
            "--loop-gain-from {}: must be finite and > 0",
            a.loop_gain_from
        ));
    }
    if a.max_degree > 30 {
        return Err(format!("--max-degree {}: at most 30", a.max_degree));
    }
    match a.gain_range.as_slice() {
        &[lo, hi] if lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo => Ok((lo, hi)),
        _ => Err(format!(
            "--gain-range {:?}: give lo,hi with 0 < lo < hi",
            a.gain_range
        )),
    }
}

/// The actuator servo loop (a): its sweep and highest gain, and when each was done (s from
/// the start of the command).
struct ServoLoop {
    lp: ActuatorLoop,
    sw: CsiSweep,
    limit: GainLimit,
    sweep_s: f64,
    servo_s: f64,
}

/// Segment bases with as many vectors as each Zernike basis up to `max_degree` (rounded up to
/// whole segments), then doubling (and all segments) while the basis stays within
/// [`SEGMENT_VECTORS`] vectors.
fn segment_counts(max_degree: u32, n: usize) -> Vec<usize> {
    let mut counts: Vec<usize> = (0..=max_degree)
        .map(|p| {
            m1::aperture::zernike::modes_up_to_degree(p)
                .div_ceil(3)
                .clamp(1, n)
        })
        .collect();
    let mut m = counts.last().copied().unwrap_or(1);
    while m < n && 3 * (2 * m).min(n) <= SEGMENT_VECTORS {
        m = (2 * m).min(n);
        counts.push(m);
    }
    counts
}

/// The servo loop's sweep over the bases and its highest gain, on the model `fm`.
fn servo_loop(
    a: &CsiArgs,
    layout: &Layout,
    geometry: &Geometry,
    fm: FrequencyModel,
    range: (f64, f64),
    started: std::time::Instant,
) -> Result<ServoLoop, String> {
    let counts = segment_counts(a.max_degree, layout.n_segments());
    let lp = ActuatorLoop::new(fm, layout, geometry, a.max_degree, &counts)
        .map_err(|e| format!("--max-degree {}: {e}", a.max_degree))?
        .with_lanczos_steps(a.lanczos_steps)
        .map_err(|e| format!("--lanczos-steps {}: {e}", a.lanczos_steps))?;
    let grid = log_grid(a.fmin, a.fmax, a.frequencies);
    let sw = sweep(&lp, &grid, REFINE, LABEL_THRESHOLD).map_err(|e| e.to_string())?;
    let sweep_s = started.elapsed().as_secs_f64();
    let limit = highest_gain(&lp, &sw, a.below, a.max_sensitivity, range)
        .map_err(|e| format!("gain search: {e}"))?;
    let servo_s = started.elapsed().as_secs_f64();
    Ok(ServoLoop {
        lp,
        sw,
        limit,
        sweep_s,
        servo_s,
    })
}

/// The global loop's frequency grid: log-spaced from `--global-fmin` to the start of the
/// loop-gain band, then every `--global-band-step` Hz up to the Nyquist frequency.
fn global_grid(a: &CsiArgs) -> Vec<f64> {
    let nyquist = 0.4999 * a.loop_rate;
    let band_start = a.loop_gain_from.min(nyquist);
    let mut ggrid = log_grid(a.global_fmin, band_start, a.global_frequencies + 1);
    ggrid.pop();
    let steps = ((nyquist - band_start) / a.global_band_step)
        .ceil()
        .max(1.0) as usize;
    ggrid
        .extend((0..=steps).map(|k| band_start + (nyquist - band_start) * k as f64 / steps as f64));
    ggrid
}

/// The global loop (b) on the `--global-modes` lowest modes, against its criteria.
fn global_loop(
    a: &CsiArgs,
    layout: &Layout,
    geometry: &Geometry,
    cell: m1::plant::structure::ModalModel,
) -> Result<GlobalSweep, String> {
    let params = ControllerParams {
        rate: a.loop_rate,
        bandwidth: a.bandwidth,
        bandwidth_radial34: a.bandwidth_radial34,
        bandwidth_radial2: a.bandwidth_radial2,
        bandwidth_focus: a.bandwidth_focus,
        ..ControllerParams::default()
    };
    let gmodes = a.global_modes.min(a.modes);
    let gfm = FrequencyModel::new(
        layout.n_segments(),
        a.actuator.model(),
        cell,
        gmodes,
        a.damping,
    )
    .map_err(|e| format!("--global-modes {gmodes}: {e}"))?;
    let gl = GlobalCsi::new(gfm, layout, geometry, params, a.max_degree, a.aliases)
        .map_err(|e| format!("global loop: {e}"))?;
    let criteria = GlobalCriteria {
        allowance: a.allowance,
        band_start_hz: a.loop_gain_from,
        ..GlobalCriteria::default()
    };
    global_sweep(&gl, &global_grid(a), &criteria).map_err(|e| format!("global loop: {e}"))
}

/// Runs `m1cs csi`.
pub fn csi(a: &CsiArgs) -> Result<(), String> {
    let range = check_args(a)?;
    let layout = super::load_layout(&a.layout)?;
    let n = layout.n_segments();
    let started = std::time::Instant::now();
    let cell = super::structure_modes(&a.structure, &layout, a.modes)?;
    let fm = FrequencyModel::new(n, a.actuator.model(), cell.clone(), a.modes, a.damping)
        .map_err(|e| format!("--modes {}: {e}", a.modes))?;
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout))
        .map_err(|e| format!("geometry of {}: {e}", layout.name))?;
    let servo = servo_loop(a, &layout, &geometry, fm, range, started)?;
    let gsw = global_loop(a, &layout, &geometry, cell)?;
    let q = q_allowance(&geometry, a.q_realizations)?;
    let elapsed = started.elapsed().as_secs_f64();
    let (sweep_s, servo_s, sw, limit) = (servo.sweep_s, servo.servo_s, &servo.sw, &servo.limit);
    if let Some(dir) = &a.plot {
        write_plots(dir, &layout.name, a, sw, n)?;
        write_global_plot(dir, &layout.name, &gsw)?;
    }
    if a.json {
        println!(
            "{}",
            json!({"layout": layout.name, "structure": a.structure, "modes": a.modes, "damping": a.damping,
                   "actuator": a.actuator.name(), "max_degree": a.max_degree,
                   "lanczos_steps": a.lanczos_steps,
                   "coupled_dimension": servo.lp.coupled_dimension(),
                   "sweep": sw, "highest_gain": limit, "global": gsw, "q_allowance": q,
                   "elapsed_s": elapsed, "sweep_s": sweep_s, "servo_s": servo_s})
        );
        return Ok(());
    }
    print_servo(a, &layout, &servo, range);
    print_global(&gsw, q.as_ref());
    println!(
        "({elapsed:.1} s: the servo loop's sweep {sweep_s:.1} s and gain search {:.1} s, the \
         global loop {:.1} s)",
        servo_s - sweep_s,
        elapsed - servo_s
    );
    Ok(())
}
