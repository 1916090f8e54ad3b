//! `m1cs csi`: control-structure interaction (the seed paper's Figure 11). (a) The actuator
//! servo loop: the largest singular value of the servo's sensitivity on the flexible cell in
//! Zernike bases of increasing radial degree, in segment bases and with all segments, and the
//! highest servo gain meeting the sensitivity criterion ([`m1::analysis::csi`]). (b) The global
//! edge-sensor loop: its principal loop gain and sensitivity in Zernike bases and with all
//! segments against the paper's criteria (with the allowance for interaction-matrix
//! uncertainty, set against the quasi-static Q), and the highest bandwidth meeting them
//! ([`m1::analysis::global_csi`]).

use clap::{Args, ValueEnum};
use serde_json::json;

use m1::analysis::csi::{
    ActuatorLoop, BasisCurve, CsiSweep, GainLimit, highest_gain, log_grid, sweep,
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
        .map_err(|e| format!("--max-degree {}: {e}", a.max_degree))?;
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
    let cell = super::structure_modes(&a.structure, &layout)?;
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

/// The servo loop's table: the peak sensitivity per basis, the all-segment peaks and the
/// highest gain.
fn print_servo(a: &CsiArgs, layout: &Layout, servo: &ServoLoop, range: (f64, f64)) {
    let (n, lp, sw, limit) = (layout.n_segments(), &servo.lp, &servo.sw, &servo.limit);
    println!(
        "Actuator servo sensitivity on the structure ({}, {} segments, {} modes, {}, {}-{} Hz, \
         {} points):",
        layout.name,
        n,
        a.modes,
        a.actuator.name(),
        a.fmin,
        a.fmax,
        sw.frequencies_hz.len()
    );
    println!(
        "{:<14} {:>9} {:>10} {:>12} {:>10} {:>6}",
        "basis", "vectors", "||S||inf", "at (Hz)", "rel. diff", "label"
    );
    let all = sw.all_segments.peak_sensitivity;
    let row = |name: String, c: &BasisCurve| {
        println!(
            "{:<14} {:>9} {:>10.4} {:>12.3} {:>10.4} {:>6}",
            name,
            c.n_vectors,
            c.peak_sensitivity,
            c.peak_frequency_hz,
            (c.peak_sensitivity - all) / all,
            c.peak_label.as_deref().unwrap_or("-")
        );
    };
    for c in &sw.zernike {
        row(
            format!("Zernike p<={}", c.max_radial_degree.unwrap_or(0)),
            c,
        );
    }
    for c in &sw.segments {
        row(format!("{} segments", c.n_segments.unwrap_or(0)), c);
    }
    row("all segments".into(), &sw.all_segments);
    if !sw.all_segment_peaks.is_empty() {
        println!(
            "all-segment peaks above {LABEL_THRESHOLD} (label from Zernike p<={}):",
            a.max_degree
        );
        for p in &sw.all_segment_peaks {
            let label = family(&p.label, p.noll);
            println!(
                "  {:>9.3} Hz  {:>8.4}  {label}",
                p.frequency_hz, p.sensitivity_max
            );
        }
    }
    let bw = |b: Option<f64>| b.map_or_else(|| "-".to_string(), |b| format!("{b:.2} Hz"));
    if limit.meets_criterion {
        println!(
            "highest servo gain with sigma_max(S) < {} up to {} Hz (all segments): factor {:.3} \
             (kp {:.3e}, ki {:.3e}, kd {:.3e}), bandwidth {} (nominal {}), peak {:.3} at {:.2} \
             Hz, limited by {}",
            limit.max_sensitivity,
            limit.below_hz,
            limit.gain_factor,
            limit.kp,
            limit.ki,
            limit.kd,
            bw(limit.bandwidth_hz),
            bw(limit.nominal_bandwidth_hz),
            limit.peak_sensitivity,
            limit.peak_frequency_hz,
            limit.limited_by
        );
    } else {
        println!(
            "no servo gain factor in [{}, {}] meets sigma_max(S) < {} up to {} Hz (all \
             segments; {}); peak {:.3} at {:.2} Hz with factor {:.3} (bandwidth {}, nominal \
             {})",
            range.0,
            range.1,
            limit.max_sensitivity,
            limit.below_hz,
            limit.limited_by,
            limit.peak_sensitivity,
            limit.peak_frequency_hz,
            limit.gain_factor,
            bw(limit.bandwidth_hz),
            bw(limit.nominal_bandwidth_hz)
        );
        if let (Some(f), Some(p)) = (limit.lowest_peak_factor, limit.lowest_peak_sensitivity) {
            println!(
                "lowest peak over the valid factors scanned: {p:.3} (all segments) at factor \
                 {f:.3} (bandwidth {})",
                bw(m1::analysis::csi::crossover(lp.model().model(), f))
            );
        }
    }
}

/// The worst $\sigma_{max}(\Gamma \Psi Q \Psi^T)$ over seeded 0.1 % sensor-gain errors (focus
/// gain reduced 4-fold in Gamma, as in `m1cs robustness`), to set against the allowance.
#[derive(Debug, Clone, serde::Serialize)]
struct QAllowance {
    case: String,
    realizations: usize,
    worst_sigma_gamma_q: f64,
    median_sigma_gamma_q: f64,
}

fn q_allowance(geometry: &Geometry, realizations: usize) -> Result<Option<QAllowance>, String> {
    if realizations == 0 {
        return Ok(None);
    }
    let nominal = Nominal::new(geometry.clone()).map_err(|e| format!("A-matrix: {e}"))?;
    let case = Case {
        name: "sensor gain 0.1%".into(),
        perturbation: Perturbation::SensorGain { rms: 1e-3 },
    };
    let params = RobustnessParams {
        realizations,
        ..RobustnessParams::default()
    };
    let r = quasistatic::robustness(&nominal, std::slice::from_ref(&case), &params, &|_, _| {})
        .map_err(|e| format!("interaction-matrix uncertainty: {e}"))?;
    let s = &r[0].sigma_gamma_q;
    Ok(Some(QAllowance {
        case: case.name,
        realizations,
        worst_sigma_gamma_q: s.worst,
        median_sigma_gamma_q: s.median,
    }))
}

/// A peak's label with its Noll index: `TT (Z7)`, or `Z11` alone.
fn family(label: &str, noll: usize) -> String {
    if label.starts_with('Z') {
        label.to_string()
    } else {
        format!("{label} (Z{noll})")
    }
}

fn print_global(g: &GlobalSweep, q: Option<&QAllowance>) {
    println!(
        "Global loop ({} modes, {} Hz, bandwidths {} / {} / {} / {} Hz on radial degrees >= 5 / \
         3-4 / 2 / focus-mode, {} images each side; {:.3}-{:.2} Hz, {} points):",
        g.modes,
        g.params.rate,
        g.params.bandwidth,
        g.params.bandwidth_radial34,
        g.params.bandwidth_radial2,
        g.params.bandwidth_focus,
        g.aliases,
        g.frequencies_hz.first().copied().unwrap_or(0.0),
        g.frequencies_hz.last().copied().unwrap_or(0.0),
        g.frequencies_hz.len()
    );
    println!(
        "{:<14} {:>9} {:>10} {:>9} {:>9} {:>13} {:>9} {:>9}",
        "basis",
        "vectors",
        "||S||inf",
        "at (Hz)",
        "label",
        format!("max L >={}Hz", g.criteria.band_start_hz),
        "at (Hz)",
        "label"
    );
    let lab = |l: &Option<String>, n: Option<usize>| match (l, n) {
        (Some(l), Some(n)) => family(l, n),
        _ => "-".into(),
    };
    let row = |name: String, c: &m1::analysis::global_csi::GlobalCurve| {
        println!(
            "{:<14} {:>9} {:>10.4} {:>9.3} {:>9} {:>13.4} {:>9.3} {:>9}",
            name,
            c.n_vectors,
            c.peak_sensitivity,
            c.peak_sensitivity_hz,
            lab(&c.peak_sensitivity_label, c.peak_sensitivity_noll),
            c.high_frequency_loop_gain,
            c.high_frequency_loop_gain_hz,
            lab(
                &c.high_frequency_loop_gain_label,
                c.high_frequency_loop_gain_noll
            )
        );
    };
    for c in &g.zernike {
        row(
            format!("Zernike p<={}", c.max_radial_degree.unwrap_or(0)),
            c,
        );
    }
    row("all segments".into(), &g.all_segments);
    if !g.all_segment_peaks.is_empty() {
        println!(
            "all-segment peaks (sensitivity above {SENSITIVITY_LABEL_FROM}, loop gain from {} Hz \
             above {}; label from Zernike p<={}):",
            g.criteria.band_start_hz,
            0.5 * g.loop_gain_limit,
            g.zernike.len().saturating_sub(1)
        );
        for p in &g.all_segment_peaks {
            println!(
                "  {:>9.3} Hz  {:<11} {:>8.4}  {}",
                p.frequency_hz,
                match p.quantity {
                    GlobalQuantity::Sensitivity => "sensitivity",
                    GlobalQuantity::LoopGain => "loop gain",
                },
                p.value,
                family(&p.label, p.noll)
            );
        }
    }
    let ok = |b: bool| if b { "met" } else { "NOT met" };
    println!(
        "criteria: ||S||inf < {} {}; principal loop gain < {} / {} = {} at and above {} Hz {}",
        g.criteria.max_sensitivity,
        ok(g.meets_sensitivity),
        g.criteria.max_loop_gain,
        g.criteria.allowance,
        g.loop_gain_limit,
        g.criteria.band_start_hz,
        ok(g.meets_loop_gain)
    );
    if let Some(q) = q {
        println!(
            "interaction-matrix uncertainty ({}, {} realizations): worst sigma(Gamma Psi Q \
             Psi^T) = {:.3} (median {:.3}), {} the allowance {}",
            q.case,
            q.realizations,
            q.worst_sigma_gamma_q,
            q.median_sigma_gamma_q,
            if q.worst_sigma_gamma_q <= g.criteria.allowance {
                "within"
            } else {
                "beyond"
            },
            g.criteria.allowance
        );
    }
    let h = &g.highest_bandwidth;
    println!(
        "highest global bandwidth of radial degrees >= 5 {} both (radial degrees 3-4 and 2 at \
         the same ratios, focus-mode as given): {:.3} Hz with all segments ({:.3} Hz in the Zernike basis; peak sensitivity \
         {:.3}, loop gain {:.3} at {:.2} Hz; limited by {})",
        if h.meets_criteria {
            "meeting"
        } else {
            "tried; none meets"
        },
        h.bandwidth_hz,
        h.zernike_bandwidth_hz,
        h.peak_sensitivity,
        h.high_frequency_loop_gain,
        h.high_frequency_loop_gain_hz,
        h.limited_by
    );
}

/// Draws `labels[k]` over `data[k]` with each `((f, value), text)` of `peaks` circled and
/// labelled, into `dir/file`.
#[allow(clippy::too_many_arguments)]
fn marked_plot(
    dir: &str,
    file: &str,
    labels: &[String],
    data: &[Vec<(f64, f64)>],
    peaks: &[((f64, f64), String)],
    title: &str,
    y_label: &str,
    log_axes: (bool, bool),
) -> Result<(), String> {
    let series: Vec<plot::ColouredSeries> = labels
        .iter()
        .zip(data)
        .enumerate()
        .map(|(k, (l, d))| (l.as_str(), k, d.as_slice()))
        .collect();
    let marks: Vec<plot::PointMark> = peaks.iter().map(|(at, t)| (*at, t.as_str())).collect();
    let path = std::path::Path::new(dir).join(file);
    plot::lines_marked(
        &path,
        &series,
        &marks,
        title,
        "frequency (Hz)",
        y_label,
        log_axes.0,
        log_axes.1,
    )
    .map_err(|e| format!("--plot {}: {e}", path.display()))
}

fn write_global_plot(dir: &str, name: &str, g: &GlobalSweep) -> Result<(), String> {
    let f = &g.frequencies_hz;
    let pts = |v: &[f64]| -> Vec<(f64, f64)> { f.iter().copied().zip(v.iter().copied()).collect() };
    let mut labels: Vec<String> = Vec::new();
    let mut data: Vec<Vec<(f64, f64)>> = Vec::new();
    labels.push("sensitivity, all segments".into());
    data.push(pts(&g.all_segments.sensitivity_max));
    labels.push("loop gain, all segments".into());
    data.push(pts(&g.all_segments.loop_gain_max));
    if let Some(c) = g.zernike.last() {
        labels.push(format!(
            "loop gain, Zernike p<={}",
            c.max_radial_degree.unwrap_or(0)
        ));
        data.push(pts(&c.loop_gain_max));
    }
    labels.push(format!("loop-gain limit {}", g.loop_gain_limit));
    data.push(
        f.iter()
            .filter(|&&x| x >= g.criteria.band_start_hz)
            .map(|&x| (x, g.loop_gain_limit))
            .collect(),
    );
    let peaks: Vec<((f64, f64), String)> = g
        .all_segment_peaks
        .iter()
        .map(|p| ((p.frequency_hz, p.value), family(&p.label, p.noll)))
        .collect();
    let about = format!(
        "{name} ({} Hz bandwidth, {} modes)",
        g.params.bandwidth, g.modes
    );
    marked_plot(
        dir,
        "global.png",
        &labels,
        &data,
        &peaks,
        &format!("global loop, {about}"),
        "max singular value",
        (true, true),
    )?;
    // The band of the loop-gain criterion on a linear axis, where the structure's peaks crowd.
    let from = g.criteria.band_start_hz;
    let band: Vec<Vec<(f64, f64)>> = data
        .iter()
        .map(|d| d.iter().copied().filter(|p| p.0 >= from).collect())
        .collect();
    if band.iter().all(|d| d.len() < 2) {
        return Ok(());
    }
    let peaks: Vec<((f64, f64), String)> = peaks.into_iter().filter(|p| p.0.0 >= from).collect();
    marked_plot(
        dir,
        "global_band.png",
        &labels,
        &band,
        &peaks,
        &format!("global loop from {from} Hz, {about}"),
        "max singular value",
        (false, false),
    )
}

fn write_plots(
    dir: &str,
    name: &str,
    a: &CsiArgs,
    sw: &m1::analysis::csi::CsiSweep,
    n: usize,
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("--plot {dir}: {e}"))?;
    let f = &sw.frequencies_hz;
    let pts = |v: &[f64]| -> Vec<(f64, f64)> { f.iter().copied().zip(v.iter().copied()).collect() };
    let mut labels: Vec<String> = Vec::new();
    let mut data: Vec<Vec<(f64, f64)>> = Vec::new();
    for c in &sw.zernike {
        labels.push(format!(
            "Zernike p<={} ({})",
            c.max_radial_degree.unwrap_or(0),
            c.n_vectors
        ));
        data.push(pts(&c.sensitivity_max));
    }
    labels.push(format!("all segments ({})", 3 * n));
    data.push(pts(&sw.all_segments.sensitivity_max));
    let peaks: Vec<((f64, f64), String)> = sw
        .all_segment_peaks
        .iter()
        .map(|p| {
            (
                (p.frequency_hz, p.sensitivity_max),
                family(&p.label, p.noll),
            )
        })
        .collect();
    marked_plot(
        dir,
        "sensitivity.png",
        &labels,
        &data,
        &peaks,
        &format!(
            "actuator servo sensitivity, {name} ({} modes, {})",
            a.modes,
            a.actuator.name()
        ),
        "max singular value of S",
        (true, false),
    )?;
    let zc: Vec<(f64, f64)> = sw
        .zernike
        .iter()
        .map(|c| (c.n_vectors as f64, c.peak_sensitivity))
        .collect();
    let sc: Vec<(f64, f64)> = sw
        .segments
        .iter()
        .map(|c| (c.n_vectors as f64, c.peak_sensitivity))
        .collect();
    let all = sw.all_segments.peak_sensitivity;
    let ac = vec![(1.0, all), ((3 * n) as f64, all)];
    let path = std::path::Path::new(dir).join("convergence.png");
    plot::lines(
        &path,
        &[
            ("Zernike bases", zc.as_slice()),
            ("segment bases", sc.as_slice()),
            ("all segments", ac.as_slice()),
        ],
        &format!("||S||inf vs basis size, {name}"),
        "basis vectors",
        "||S||inf",
        true,
        false,
    )
    .map_err(|e| format!("--plot {}: {e}", path.display()))?;
    Ok(())
}
