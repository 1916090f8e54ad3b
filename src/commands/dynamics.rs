//! The dynamic studies: `m1cs coupling` (how large a communication step the segments and the
//! structure tolerate as two co-simulation components) and `m1cs vibration` (M1 under a pier
//! tone for the three actuator variants, from the monolithic frequency model).

use std::sync::LazyLock;

use clap::Args;
use serde_json::json;

use m1::analysis::coupling::{Exchange, Excitation, Mirror, SplitRun, split_vs_coupled};
use m1::analysis::defaults::{
    self as study, coupling as coupling_study, vibration as vibration_study,
};
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::optics::metrics::MirrorMetrics;
use m1::optics::pssn::{Pssn, PssnParams};
use m1::plant::monolithic::FrequencyModel;
use m1::plant::segment::SegmentModel;

use super::defaults::list;
use crate::plot;

/// `--help`'s form of the default communication steps.
static STEPS: LazyLock<String> = LazyLock::new(|| list(&coupling_study::STEPS));

/// The three actuator variants of both studies, by name.
fn variants() -> [(&'static str, SegmentModel); 3] {
    [
        ("voicecoil", SegmentModel::voice_coil()),
        ("piezo", SegmentModel::piezo()),
        ("piezo-damped", SegmentModel::piezo_damped_default()),
    ]
}

/// The exchange orders the coupling study tries.
const ORDERS: [Exchange; 2] = [Exchange::GaussSeidel, Exchange::Jacobi];

/// `m1cs coupling`.
#[derive(Args, Debug)]
pub struct CouplingArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = coupling_study::LAYOUT)]
    pub layout: String,
    /// Retained structure modes.
    #[arg(long, default_value_t = coupling_study::MODES)]
    pub modes: usize,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
    /// Modal damping ratio of the structure.
    #[arg(long, default_value_t = study::DAMPING_RATIO)]
    pub damping: f64,
    /// Communication steps to try (s), comma-separated: multiples of the 0.2 ms servo period.
    #[arg(long, value_delimiter = ',', default_value = STEPS.as_str())]
    pub steps: Vec<f64>,
    /// Pier tone frequency (Hz).
    #[arg(long, default_value_t = Excitation::default().frequency)]
    pub tone: f64,
    /// Simulated time per run (s).
    #[arg(long, default_value_t = Excitation::default().duration)]
    pub duration: f64,
    /// Relative rms error under which a stable run counts as accurate.
    #[arg(long, default_value_t = coupling_study::TOLERANCE)]
    pub tolerance: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// PNG of the relative error against the step, per variant and order (unbounded runs are
    /// left out).
    #[arg(long)]
    pub plot: Option<String>,
}

/// Every run of the coupling study: per variant, order and step.
type Runs = Vec<(&'static str, SplitRun)>;

/// Runs every variant in every order at every step against the coupled solver.
fn split_runs(a: &CouplingArgs, layout: &Layout) -> Result<Runs, String> {
    let cell = super::structure_modes(&a.structure, layout, a.modes)?;
    let ex = Excitation {
        frequency: a.tone,
        duration: a.duration,
        ..Excitation::default()
    };
    let variants = variants();
    let bar = indicatif::ProgressBar::new((variants.len() * ORDERS.len() * a.steps.len()) as u64);
    let mut runs: Runs = Vec::new();
    for (name, model) in &variants {
        let mirror = Mirror {
            n_segments: layout.n_segments(),
            model,
            cell: &cell,
            n_modes: a.modes,
            damping_ratio: a.damping,
        };
        for &order in &ORDERS {
            for &step in &a.steps {
                let r = split_vs_coupled(&mirror, step, order, &ex)
                    .map_err(|e| format!("{name}, step {step} s: {e}"))?;
                runs.push((name, r));
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    Ok(runs)
}

/// The largest accurate step (within `tolerance`, bounded) of variant `name` in `order`.
fn largest_step(runs: &Runs, name: &str, order: Exchange, tolerance: f64) -> Option<f64> {
    runs.iter()
        .filter(|(n, r)| *n == name && r.order == order)
        .filter(|(_, r)| r.stable && r.relative_error <= tolerance)
        .map(|(_, r)| r.step)
        .fold(None, |m: Option<f64>, s| Some(m.map_or(s, |m| m.max(s))))
}

/// `--plot`: one line per run of consecutive bounded steps (a diverged step breaks the line),
/// in the colour of its variant and order: the first piece carries the label.
fn plot_coupling(p: &str, a: &CouplingArgs, layout: &Layout, runs: &Runs) -> Result<(), String> {
    type Piece = (String, usize, Vec<(f64, f64)>);
    let mut series: Vec<Piece> = Vec::new();
    let mut colour = 0;
    for (name, _) in &variants() {
        for &order in &ORDERS {
            colour += 1;
            let mut label = format!("{name}, {order:?}");
            let mut piece: Vec<(f64, f64)> = Vec::new();
            let case = runs.iter().filter(|(n, r)| n == name && r.order == order);
            for (_, r) in case {
                if r.stable {
                    piece.push((r.step * 1e3, r.relative_error));
                } else if !piece.is_empty() {
                    series.push((
                        std::mem::take(&mut label),
                        colour - 1,
                        std::mem::take(&mut piece),
                    ));
                }
            }
            if !piece.is_empty() || !label.is_empty() {
                series.push((label, colour - 1, piece));
            }
        }
    }
    let refs: Vec<plot::ColouredSeries> = series
        .iter()
        .map(|(l, c, p)| (l.as_str(), *c, p.as_slice()))
        .collect();
    plot::lines_in_colours(
        p,
        &refs,
        &format!(
            "split segments/structure vs coupled, {} ({} modes, {} Hz pier tone)",
            layout.name, a.modes, a.tone
        ),
        "communication step (ms)",
        "relative rms error of the mirror displacement",
        false,
        true,
    )
    .map_err(|e| format!("--plot {p}: {e}"))
}

fn coupling_json(a: &CouplingArgs, layout: &Layout, runs: &Runs) -> serde_json::Value {
    let rows: Vec<_> = runs
        .iter()
        .map(|(n, r)| {
            json!({"variant": n, "step_s": r.step, "order": r.order, "stable": r.stable,
                   "reached_s": r.reached,
                   "relative_error": if r.relative_error.is_finite() { json!(r.relative_error) } else { json!(null) }})
        })
        .collect();
    let best: serde_json::Map<String, serde_json::Value> = variants()
        .iter()
        .flat_map(|(name, _)| ORDERS.iter().map(move |o| (*name, *o)))
        .map(|(name, order)| {
            (
                format!("{name}/{order:?}"),
                json!(largest_step(runs, name, order, a.tolerance)),
            )
        })
        .collect();
    json!({"layout": layout.name, "modes": a.modes, "tone_hz": a.tone,
           "duration_s": a.duration, "tolerance": a.tolerance, "runs": rows,
           "largest_accurate_step_s": best})
}

fn print_coupling(a: &CouplingArgs, layout: &Layout, runs: &Runs) {
    println!(
        "Segments and structure as two components exchanging every step, against the coupled \
         solver ({}, {} modes, {} Hz pier tone, {} s):",
        layout.name, a.modes, a.tone, a.duration
    );
    println!(
        "{:<14} {:<12} {:>9} {:>10} {:>16}",
        "variant", "order", "step (ms)", "bounded", "rel. rms error"
    );
    for (name, r) in runs {
        let err = if r.stable {
            format!("{:.2e}", r.relative_error)
        } else {
            format!("diverged at {:.3} s", r.reached)
        };
        println!(
            "{:<14} {:<12} {:>9.2} {:>10} {:>16}",
            name,
            format!("{:?}", r.order),
            r.step * 1e3,
            r.stable,
            err
        );
    }
    for (name, _) in &variants() {
        for &order in &ORDERS {
            let s = largest_step(runs, name, order, a.tolerance)
                .map_or_else(|| "none".to_string(), |s| format!("{:.1} ms", s * 1e3));
            println!(
                "largest step within {:.1} %: {name}, {order:?}: {s}",
                100.0 * a.tolerance
            );
        }
    }
    println!(
        "The mirror FMUs (mirror_voicecoil, mirror_piezo) solve the two together at every servo \
         sample: stable for every variant at any multiple of 0.2 ms."
    );
}

/// Runs `m1cs coupling`.
pub fn coupling(a: &CouplingArgs) -> Result<(), String> {
    let layout = super::load_layout(&a.layout)?;
    if a.modes == 0 {
        return Err("--modes: at least one structure mode".into());
    }
    if a.steps.is_empty() {
        return Err("--steps: give at least one communication step (s)".into());
    }
    if !(a.tolerance.is_finite() && a.tolerance > 0.0) {
        return Err(format!(
            "--tolerance {}: must be finite and > 0",
            a.tolerance
        ));
    }
    let runs = split_runs(a, &layout)?;
    if let Some(p) = &a.plot {
        plot_coupling(p, a, &layout, &runs)?;
    }
    if a.json {
        println!("{}", coupling_json(a, &layout, &runs));
        return Ok(());
    }
    print_coupling(a, &layout, &runs);
    Ok(())
}

/// `m1cs vibration`.
#[derive(Args, Debug)]
pub struct VibrationArgs {
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
    /// Lowest pier frequency (Hz).
    #[arg(long, default_value_t = vibration_study::FMIN_HZ)]
    pub fmin: f64,
    /// Highest pier frequency (Hz).
    #[arg(long, default_value_t = vibration_study::FMAX_HZ)]
    pub fmax: f64,
    /// Frequency step (Hz); 29.6 Hz is always added.
    #[arg(long, default_value_t = vibration_study::STEP_HZ)]
    pub step: f64,
    /// Rms vertical pier motion the PSSN is evaluated for (m) (*assumed*; default 10 nm).
    #[arg(long, default_value_t = vibration_study::PIER_RMS)]
    pub pier_rms: f64,
    /// Evaluate the PSSN every this many frequency points (and at 29.6 Hz): each costs two
    /// pupil FFTs.
    #[arg(long, default_value_t = vibration_study::PSSN_EVERY)]
    pub pssn_every: usize,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Write rms_surface.png, pssn.png and the voice coil's M1 maps at its main resonance and
    /// at 29.6 Hz into this directory.
    #[arg(long)]
    pub plot: Option<std::path::PathBuf>,
}

/// The tone of the induction motors the seed paper singles out (Hz).
const MOTOR_TONE_HZ: f64 = vibration_study::MOTOR_TONE_HZ;

/// Time-rms surface (global piston/tip/tilt removed) of the response `x` (complex, per metre of
/// pier amplitude) relative to the pier's time-rms: `sqrt(S(Re x)^2 + S(Im x)^2)`.
fn rms_ratio(metrics: &m1::optics::metrics::MirrorMetrics, x: &[faer::c64]) -> Result<f64, String> {
    let re: Vec<f64> = x.iter().map(|v| v.re).collect();
    let im: Vec<f64> = x.iter().map(|v| v.im).collect();
    let a = metrics.evaluate(&re).map_err(|e| e.to_string())?.rms;
    let b = metrics.evaluate(&im).map_err(|e| e.to_string())?.rms;
    Ok((a * a + b * b).sqrt())
}

/// Period-averaged PSSN of the response to a pier tone of rms `pier_rms`: the deficit is
/// quadratic in small errors, so its mean over a period is the mean of the deficits of the
/// two quadrature patterns at amplitude sqrt(2) `pier_rms`.
fn tone_pssn(
    pssn: &m1::optics::pssn::Pssn,
    geometry: &m1::aperture::geometry::Geometry,
    x: &[faer::c64],
    pier_rms: f64,
) -> Result<f64, String> {
    let amp = std::f64::consts::SQRT_2 * pier_rms;
    let mut deficit = 0.0;
    for part in [0, 1] {
        let z: Vec<f64> = x
            .iter()
            .map(|v| amp * if part == 0 { v.re } else { v.im })
            .collect();
        let ptt = m1::optics::metrics::actuators_to_ptt(geometry, &z).map_err(|e| e.to_string())?;
        deficit += 1.0 - pssn.pssn_ptt(&ptt).map_err(|e| e.to_string())?;
    }
    Ok(1.0 - 0.5 * deficit)
}

/// One variant's response over the pier frequencies.
struct Curve {
    name: &'static str,
    /// M1 rms surface per pier motion at each frequency (nm/nm).
    rms: Vec<f64>,
    /// `(frequency Hz, PSSN)` every `--pssn-every` points and at the motor tone.
    pssn: Vec<(f64, f64)>,
}

/// The vibration study: the curves of the three variants and the voice coil's maps.
struct VibrationStudy {
    freqs: Vec<f64>,
    /// Index of [`MOTOR_TONE_HZ`] in `freqs`, when in range.
    motor: Option<usize>,
    curves: Vec<Curve>,
    /// The voice coil's maps.
    maps: Vec<Map>,
}

/// `(label, frequency Hz, rms surface per segment nm/nm)` of a map.
type Map = (&'static str, f64, Vec<f64>);

fn check_vibration_args(a: &VibrationArgs) -> Result<(), String> {
    if !(a.fmin.is_finite() && a.fmin > 0.0 && a.fmax.is_finite() && a.fmax > a.fmin) {
        return Err(format!(
            "--fmin {} and --fmax {}: need 0 < fmin < fmax",
            a.fmin, a.fmax
        ));
    }
    if !(a.step.is_finite() && a.step > 0.0) || (a.fmax - a.fmin) / a.step > 1e5 {
        return Err(format!(
            "--step {}: must be > 0 and give at most 1e5 points",
            a.step
        ));
    }
    if !(a.pier_rms.is_finite() && a.pier_rms > 0.0) {
        return Err(format!("--pier-rms {}: must be > 0 (m)", a.pier_rms));
    }
    if a.modes == 0 {
        return Err("--modes: at least one structure mode".into());
    }
    Ok(())
}

/// `--fmin` to `--fmax` by `--step`, with [`MOTOR_TONE_HZ`] added when in range.
fn pier_frequencies(a: &VibrationArgs) -> Vec<f64> {
    let mut freqs: Vec<f64> = (0..)
        .map(|k| a.fmin + a.step * f64::from(k))
        .take_while(|f| *f <= a.fmax + 1e-9)
        .collect();
    if (a.fmin..=a.fmax).contains(&MOTOR_TONE_HZ)
        && !freqs.iter().any(|f| (f - MOTOR_TONE_HZ).abs() < 1e-9)
    {
        freqs.push(MOTOR_TONE_HZ);
        freqs.sort_by(f64::total_cmp);
    }
    freqs
}

/// What the optics of the study are evaluated with.
struct Optics {
    geometry: Geometry,
    metrics: MirrorMetrics,
    pssn: Pssn,
}

/// The curves of one variant, and its complex mirror responses when `keep` (for the maps).
fn variant_curve(
    a: &VibrationArgs,
    fm: &FrequencyModel,
    name: &'static str,
    optics: &Optics,
    freqs: &[f64],
    motor: Option<usize>,
    keep: bool,
) -> Result<(Curve, Vec<Vec<faer::c64>>), String> {
    let mut rms = Vec::with_capacity(freqs.len());
    let mut pssn_pts = Vec::new();
    let mut responses = Vec::with_capacity(freqs.len());
    for (k, &f) in freqs.iter().enumerate() {
        let r = fm
            .pier_response(f)
            .map_err(|e| format!("{name} at {f} Hz: {e}"))?;
        rms.push(rms_ratio(&optics.metrics, &r.mirror)?);
        if k % a.pssn_every.max(1) == 0 || Some(k) == motor {
            pssn_pts.push((
                f,
                tone_pssn(&optics.pssn, &optics.geometry, &r.mirror, a.pier_rms)?,
            ));
        }
        if keep {
            responses.push(r.mirror);
        }
    }
    let curve = Curve {
        name,
        rms,
        pssn: pssn_pts,
    };
    Ok((curve, responses))
}

/// Index of the largest value (the first of equals).
fn peak_index(v: &[f64]) -> usize {
    (0..v.len()).fold(0, |b, k| if v[k] > v[b] { k } else { b })
}

/// The voice coil's maps at its main resonance and at the motor tone: the rms surface per
/// segment per pier rms (nm/nm) from the two quadrature samples of each response.
fn voice_coil_maps(
    layout: &Layout,
    curve: &Curve,
    responses: &[Vec<faer::c64>],
    freqs: &[f64],
    motor: Option<usize>,
) -> Result<Vec<Map>, String> {
    let mut maps = Vec::new();
    let peak = peak_index(&curve.rms);
    for (label, k) in [("main resonance", Some(peak)), ("29.6 Hz", motor)] {
        if let Some(k) = k {
            // Two quadrature samples, scaled so that the map is nm/nm of pier rms.
            let s = std::f64::consts::SQRT_2 * 1e-9;
            let z: Vec<Vec<f64>> = responses[k]
                .iter()
                .map(|v| vec![s * v.re, s * v.im])
                .collect();
            let map = super::cosim::segment_rms_map(layout, &z)?;
            maps.push((label, freqs[k], map));
        }
    }
    Ok(maps)
}

fn vibration_study(a: &VibrationArgs, layout: &Layout) -> Result<VibrationStudy, String> {
    let freqs = pier_frequencies(a);
    let geometry =
        Geometry::new(layout, GeometryParams::for_layout(layout)).map_err(|e| e.to_string())?;
    let metrics = MirrorMetrics::new(&geometry).map_err(|e| e.to_string())?;
    let pssn = Pssn::new(layout, PssnParams::default()).map_err(|e| e.to_string())?;
    let optics = Optics {
        geometry,
        metrics,
        pssn,
    };
    let cell = super::structure_modes(&a.structure, layout, a.modes)?;
    let n = layout.n_segments();
    let motor = freqs.iter().position(|f| (f - MOTOR_TONE_HZ).abs() < 1e-9);
    let mut curves = Vec::new();
    let mut maps = Vec::new();
    for (name, model) in variants() {
        let fm = FrequencyModel::new(n, model, cell.clone(), a.modes, a.damping)
            .map_err(|e| e.to_string())?;
        let voice_coil = name == "voicecoil";
        let (curve, responses) = variant_curve(a, &fm, name, &optics, &freqs, motor, voice_coil)?;
        if voice_coil {
            maps = voice_coil_maps(layout, &curve, &responses, &freqs, motor)?;
        }
        curves.push(curve);
    }
    Ok(VibrationStudy {
        freqs,
        motor,
        curves,
        maps,
    })
}

impl VibrationStudy {
    /// `(frequency Hz, rms surface)` of the peak of `c`.
    fn peak_of(&self, c: &Curve) -> (f64, f64) {
        let k = peak_index(&c.rms);
        (self.freqs[k], c.rms[k])
    }

    /// The largest ratio of two variants' responses at one frequency of a band.
    fn ratio_over(&self, i: usize, j: usize, band: std::ops::RangeInclusive<f64>) -> f64 {
        self.freqs
            .iter()
            .enumerate()
            .filter(|(_, f)| band.contains(*f))
            .map(|(k, _)| self.curves[i].rms[k] / self.curves[j].rms[k])
            .fold(f64::NAN, f64::max)
    }

    /// The PSSN of `c` at the motor tone (NaN when out of range).
    fn motor_pssn(c: &Curve) -> f64 {
        c.pssn
            .iter()
            .find(|(f, _)| (f - MOTOR_TONE_HZ).abs() < 1e-9)
            .map_or(f64::NAN, |p| p.1)
    }

    /// The rms surface of `c` at the motor tone (NaN when out of range).
    fn motor_rms(&self, c: &Curve) -> f64 {
        self.motor.map_or(f64::NAN, |k| c.rms[k])
    }

    /// Ratio of variants `i` and `j` at the motor tone.
    fn ratio(&self, i: usize, j: usize) -> f64 {
        self.motor
            .map_or(f64::NAN, |k| self.curves[i].rms[k] / self.curves[j].rms[k])
    }

    /// The largest ratio of variants `i` and `j` over 29.4-29.8 Hz.
    fn ratio_band(&self, i: usize, j: usize) -> f64 {
        self.ratio_over(i, j, 29.4..=29.8)
    }

    /// How far apart the three variants are at low frequency: the largest ratio of any two
    /// below 3 Hz, less one (NaN when the grid has no point there).
    fn spread_low(&self) -> f64 {
        (0..3)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .filter(|(i, j)| i != j)
            .map(|(i, j)| self.ratio_over(i, j, 0.0..=3.0))
            .fold(f64::NAN, f64::max)
            - 1.0
    }
}

fn vibration_json(a: &VibrationArgs, st: &VibrationStudy) -> serde_json::Value {
    json!({
        "layout": a.layout,
        "structure": a.structure,
        "modes": a.modes,
        "pier_rms_m": a.pier_rms,
        "frequencies_hz": st.freqs,
        "variants": st.curves.iter().map(|c| {
            let (fp, vp) = st.peak_of(c);
            json!({
                "actuator": c.name,
                "rms_surface_nm_per_nm": c.rms,
                "pssn": c.pssn.iter().map(|(f, p)| json!({"frequency_hz": f, "pssn": p})).collect::<Vec<_>>(),
                "peak_frequency_hz": fp,
                "peak_rms_surface_nm_per_nm": vp,
                "rms_surface_at_29_6_hz_nm_per_nm": st.motor.map(|k| c.rms[k]),
                "pssn_at_29_6_hz": VibrationStudy::motor_pssn(c),
            })
        }).collect::<Vec<_>>(),
        "ratio_hard_over_soft_at_29_6_hz": st.ratio(1, 0),
        "ratio_undamped_over_damped_at_29_6_hz": st.ratio(1, 2),
        "ratio_hard_over_soft_max_29_4_to_29_8_hz": st.ratio_band(1, 0),
        "ratio_undamped_over_damped_max_29_4_to_29_8_hz": st.ratio_band(1, 2),
        "variant_spread_below_3_hz": st.spread_low(),
    })
}

fn print_vibration(a: &VibrationArgs, st: &VibrationStudy) {
    println!(
        "{}: M1 rms surface per vertical pier motion, {} structure modes (PSSN for {} nm rms \
         of pier motion):",
        a.layout,
        a.modes,
        a.pier_rms * 1e9
    );
    println!(
        "{:>13} {:>10} {:>14} {:>16} {:>14}",
        "actuator", "peak (Hz)", "peak (nm/nm)", "29.6 Hz (nm/nm)", "PSSN 29.6 Hz"
    );
    for c in &st.curves {
        let (fp, vp) = st.peak_of(c);
        println!(
            "{:>13} {:>10.2} {:>14.4} {:>16.4} {:>14.6}",
            c.name,
            fp,
            vp,
            st.motor_rms(c),
            VibrationStudy::motor_pssn(c)
        );
    }
    println!(
        "at 29.6 Hz: hard/soft {:.2}, undamped/damped {:.2} (largest over 29.4-29.8 Hz: {:.2}, {:.2}); \
         below 3 Hz the variants are within {:.1} %",
        st.ratio(1, 0),
        st.ratio(1, 2),
        st.ratio_band(1, 0),
        st.ratio_band(1, 2),
        100.0 * st.spread_low()
    );
}

/// `--plot DIR`: rms_surface.png, pssn.png and the voice coil's maps.
fn plot_vibration(
    dir: &std::path::Path,
    a: &VibrationArgs,
    layout: &Layout,
    st: &VibrationStudy,
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let pts: Vec<Vec<(f64, f64)>> = st
        .curves
        .iter()
        .map(|c| {
            st.freqs
                .iter()
                .copied()
                .zip(c.rms.iter().copied())
                .collect()
        })
        .collect();
    let series: Vec<(&str, &[(f64, f64)])> = st
        .curves
        .iter()
        .zip(&pts)
        .map(|(c, p)| (c.name, p.as_slice()))
        .collect();
    plot::lines(
        dir.join("rms_surface.png"),
        &series,
        &format!("{}: M1 rms surface per vertical pier motion", a.layout),
        "pier frequency (Hz)",
        "rms surface (nm/nm)",
        false,
        true,
    )
    .map_err(|e| e.to_string())?;
    let pssn_series: Vec<(&str, &[(f64, f64)])> = st
        .curves
        .iter()
        .map(|c| (c.name, c.pssn.as_slice()))
        .collect();
    plot::lines(
        dir.join("pssn.png"),
        &pssn_series,
        &format!(
            "{}: PSSN for {} nm rms of vertical pier motion",
            a.layout,
            a.pier_rms * 1e9
        ),
        "pier frequency (Hz)",
        "PSSN",
        false,
        false,
    )
    .map_err(|e| e.to_string())?;
    for (label, f, map) in &st.maps {
        let file = if *label == "main resonance" {
            "map_main_resonance.png"
        } else {
            "map_29_6_hz.png"
        };
        plot::mirror_map(
            dir.join(file),
            layout,
            map,
            &format!(
                "{}, voice coil, {label} ({f:.2} Hz): rms surface per segment per pier rms",
                a.layout
            ),
            "nm/nm",
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// Runs `m1cs vibration`.
pub fn vibration(a: &VibrationArgs) -> Result<(), String> {
    let layout = super::load_layout(&a.layout)?;
    check_vibration_args(a)?;
    let st = vibration_study(a, &layout)?;
    if a.json {
        println!("{}", vibration_json(a, &st));
    } else {
        print_vibration(a, &st);
    }
    if let Some(dir) = &a.plot {
        plot_vibration(dir, a, &layout, &st)?;
    }
    Ok(())
}
