//! The dynamic studies: `m1cs coupling` (how large a communication step the segments and the
//! structure tolerate as two co-simulation components).

use clap::Args;
use serde_json::json;

use m1::analysis::coupling::{Exchange, Excitation, Mirror, SplitRun, split_vs_coupled};
use m1::plant::segment::SegmentModel;

use crate::plot;

/// `m1cs coupling`.
#[derive(Args, Debug)]
pub struct CouplingArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = "keck")]
    pub layout: String,
    /// Retained structure modes.
    #[arg(long, default_value_t = 30)]
    pub modes: usize,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
    /// Modal damping ratio of the structure.
    #[arg(long, default_value_t = 0.02)]
    pub damping: f64,
    /// Communication steps to try (s), comma-separated: multiples of the 0.2 ms servo period.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.0002,0.0004,0.0006,0.001"
    )]
    pub steps: Vec<f64>,
    /// Pier tone frequency (Hz).
    #[arg(long, default_value_t = 5.0)]
    pub tone: f64,
    /// Simulated time per run (s).
    #[arg(long, default_value_t = 1.0)]
    pub duration: f64,
    /// Relative rms error under which a stable run counts as accurate.
    #[arg(long, default_value_t = 0.01)]
    pub tolerance: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// PNG of the relative error against the step, per variant and order (unbounded runs are
    /// left out).
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs coupling`.
pub fn coupling(a: &CouplingArgs) -> Result<(), String> {
    let layout = crate::load_layout(&a.layout)?;
    if a.steps.is_empty() {
        return Err("--steps: give at least one communication step (s)".into());
    }
    if !(a.tolerance.is_finite() && a.tolerance > 0.0) {
        return Err(format!(
            "--tolerance {}: must be finite and > 0",
            a.tolerance
        ));
    }
    let cell = super::structure_modes(&a.structure, &layout)?;
    let ex = Excitation {
        frequency: a.tone,
        duration: a.duration,
        ..Excitation::default()
    };
    let variants = [
        ("voicecoil", SegmentModel::voice_coil()),
        ("piezo", SegmentModel::piezo()),
        ("piezo-damped", SegmentModel::piezo_damped_default()),
    ];
    let orders = [Exchange::GaussSeidel, Exchange::Jacobi];
    let bar = indicatif::ProgressBar::new((variants.len() * orders.len() * a.steps.len()) as u64);
    let mut runs: Vec<(&str, SplitRun)> = Vec::new();
    for (name, model) in &variants {
        let mirror = Mirror {
            n_segments: layout.n_segments(),
            model,
            cell: &cell,
            n_modes: a.modes,
            damping_ratio: a.damping,
        };
        for &order in &orders {
            for &step in &a.steps {
                let r = split_vs_coupled(&mirror, step, order, &ex)
                    .map_err(|e| format!("{name}, step {step} s: {e}"))?;
                runs.push((name, r));
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    // The largest accurate step per variant and order.
    let largest = |name: &str, order: Exchange| {
        runs.iter()
            .filter(|(n, r)| *n == name && r.order == order)
            .filter(|(_, r)| r.stable && r.relative_error <= a.tolerance)
            .map(|(_, r)| r.step)
            .fold(None, |m: Option<f64>, s| Some(m.map_or(s, |m| m.max(s))))
    };
    if let Some(p) = &a.plot {
        // One line per run of consecutive bounded steps (a diverged step breaks the line), in
        // the colour of its variant and order: the first piece carries the label.
        type Piece = (String, usize, Vec<(f64, f64)>);
        let mut series: Vec<Piece> = Vec::new();
        let mut colour = 0;
        for (name, _) in &variants {
            for &order in &orders {
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
        .map_err(|e| format!("--plot {p}: {e}"))?;
    }
    if a.json {
        let rows: Vec<_> = runs
            .iter()
            .map(|(n, r)| {
                json!({"variant": n, "step_s": r.step, "order": r.order, "stable": r.stable,
                       "reached_s": r.reached,
                       "relative_error": if r.relative_error.is_finite() { json!(r.relative_error) } else { json!(null) }})
            })
            .collect();
        let best: serde_json::Map<String, serde_json::Value> = variants
            .iter()
            .flat_map(|(name, _)| orders.iter().map(move |o| (*name, *o)))
            .map(|(name, order)| (format!("{name}/{order:?}"), json!(largest(name, order))))
            .collect();
        println!(
            "{}",
            json!({"layout": layout.name, "modes": a.modes, "tone_hz": a.tone,
                   "duration_s": a.duration, "tolerance": a.tolerance, "runs": rows,
                   "largest_accurate_step_s": best})
        );
        return Ok(());
    }
    println!(
        "Segments and structure as two components exchanging every step, against the coupled \
         solver ({}, {} modes, {} Hz pier tone, {} s):",
        layout.name, a.modes, a.tone, a.duration
    );
    println!(
        "{:<14} {:<12} {:>9} {:>10} {:>16}",
        "variant", "order", "step (ms)", "bounded", "rel. rms error"
    );
    for (name, r) in &runs {
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
    for (name, _) in &variants {
        for &order in &orders {
            let s = largest(name, order)
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
    Ok(())
}

/// `m1cs vibration`.
#[derive(Args, Debug)]
pub struct VibrationArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = "tmt")]
    pub layout: String,
    /// Retained structure modes.
    #[arg(long, default_value_t = 60)]
    pub modes: usize,
    #[arg(long, default_value = m1::plant::structure::DEFAULT_STRUCTURE, help = super::STRUCTURE_HELP)]
    pub structure: String,
    /// Modal damping ratio of the structure.
    #[arg(long, default_value_t = 0.02)]
    pub damping: f64,
    /// Lowest pier frequency (Hz).
    #[arg(long, default_value_t = 1.0)]
    pub fmin: f64,
    /// Highest pier frequency (Hz).
    #[arg(long, default_value_t = 60.0)]
    pub fmax: f64,
    /// Frequency step (Hz); 29.6 Hz is always added.
    #[arg(long, default_value_t = 0.25)]
    pub step: f64,
    /// Rms vertical pier motion the PSSN is evaluated for (m) (*assumed*; default 10 nm).
    #[arg(long, default_value_t = 10e-9)]
    pub pier_rms: f64,
    /// Evaluate the PSSN every this many frequency points (and at 29.6 Hz): each costs two
    /// pupil FFTs.
    #[arg(long, default_value_t = 4)]
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
const MOTOR_TONE_HZ: f64 = 29.6;

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

/// Runs `m1cs vibration`.
pub fn vibration(a: &VibrationArgs) -> Result<(), String> {
    use m1::aperture::geometry::{Geometry, GeometryParams};
    use m1::optics::metrics::MirrorMetrics;
    use m1::optics::pssn::{Pssn, PssnParams};
    use m1::plant::monolithic::FrequencyModel;
    let layout = crate::load_layout(&a.layout)?;
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
    let geometry =
        Geometry::new(&layout, GeometryParams::for_layout(&layout)).map_err(|e| e.to_string())?;
    let metrics = MirrorMetrics::new(&geometry).map_err(|e| e.to_string())?;
    let pssn = Pssn::new(&layout, PssnParams::default()).map_err(|e| e.to_string())?;
    let cell = super::structure_modes(&a.structure, &layout)?;
    let variants = [
        ("voicecoil", SegmentModel::voice_coil()),
        ("piezo", SegmentModel::piezo()),
        ("piezo-damped", SegmentModel::piezo_damped_default()),
    ];
    let n = layout.n_segments();
    let motor = freqs.iter().position(|f| (f - MOTOR_TONE_HZ).abs() < 1e-9);
    let mut curves = Vec::new();
    let mut maps = Vec::new();
    for (name, model) in &variants {
        let fm = FrequencyModel::new(n, model.clone(), cell.clone(), a.modes, a.damping)
            .map_err(|e| e.to_string())?;
        let mut rms = Vec::with_capacity(freqs.len());
        let mut pssn_pts = Vec::new();
        let mut responses = Vec::with_capacity(freqs.len());
        for (k, &f) in freqs.iter().enumerate() {
            let r = fm
                .pier_response(f)
                .map_err(|e| format!("{name} at {f} Hz: {e}"))?;
            rms.push(rms_ratio(&metrics, &r.mirror)?);
            if k % a.pssn_every.max(1) == 0 || Some(k) == motor {
                pssn_pts.push((f, tone_pssn(&pssn, &geometry, &r.mirror, a.pier_rms)?));
            }
            if *name == "voicecoil" {
                responses.push(r.mirror);
            }
        }
        if *name == "voicecoil" {
            let peak = (0..rms.len()).fold(0, |b, k| if rms[k] > rms[b] { k } else { b });
            for (label, k) in [("main resonance", Some(peak)), ("29.6 Hz", motor)] {
                if let Some(k) = k {
                    // Two quadrature samples, scaled so that the map is nm/nm of pier rms.
                    let s = std::f64::consts::SQRT_2 * 1e-9;
                    let z: Vec<Vec<f64>> = responses[k]
                        .iter()
                        .map(|v| vec![s * v.re, s * v.im])
                        .collect();
                    let map = super::cosim::segment_rms_map(&layout, &z)?;
                    maps.push((label, freqs[k], map));
                }
            }
        }
        curves.push((*name, rms, pssn_pts));
    }
    let at = |c: &(&str, Vec<f64>, Vec<(f64, f64)>), k: usize| c.1[k];
    let peak_of = |c: &(&str, Vec<f64>, Vec<(f64, f64)>)| {
        let k = (0..c.1.len()).fold(0, |b, k| if c.1[k] > c.1[b] { k } else { b });
        (freqs[k], c.1[k])
    };
    // The largest ratio of two variants' responses at one frequency of a band.
    let ratio_over = |i: usize, j: usize, band: std::ops::RangeInclusive<f64>| {
        freqs
            .iter()
            .enumerate()
            .filter(|(_, f)| band.contains(*f))
            .map(|(k, _)| curves[i].1[k] / curves[j].1[k])
            .fold(f64::NAN, f64::max)
    };
    let motor_pssn = |c: &(&str, Vec<f64>, Vec<(f64, f64)>)| {
        c.2.iter()
            .find(|(f, _)| (f - MOTOR_TONE_HZ).abs() < 1e-9)
            .map_or(f64::NAN, |p| p.1)
    };
    let ratio =
        |i: usize, j: usize| motor.map_or(f64::NAN, |k| at(&curves[i], k) / at(&curves[j], k));
    let ratio_band = |i: usize, j: usize| ratio_over(i, j, 29.4..=29.8);
    // How far apart the three variants are at low frequency: the largest ratio of any two
    // below 3 Hz, less one (NaN when the grid has no point there).
    let spread_low = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .filter(|(i, j)| i != j)
        .map(|(i, j)| ratio_over(i, j, 0.0..=3.0))
        .fold(f64::NAN, f64::max)
        - 1.0;
    if a.json {
        let out = json!({
            "layout": a.layout,
            "structure": a.structure,
            "modes": a.modes,
            "pier_rms_m": a.pier_rms,
            "frequencies_hz": freqs,
            "variants": curves.iter().map(|c| {
                let (fp, vp) = peak_of(c);
                json!({
                    "actuator": c.0,
                    "rms_surface_nm_per_nm": c.1,
                    "pssn": c.2.iter().map(|(f, p)| json!({"frequency_hz": f, "pssn": p})).collect::<Vec<_>>(),
                    "peak_frequency_hz": fp,
                    "peak_rms_surface_nm_per_nm": vp,
                    "rms_surface_at_29_6_hz_nm_per_nm": motor.map(|k| c.1[k]),
                    "pssn_at_29_6_hz": motor_pssn(c),
                })
            }).collect::<Vec<_>>(),
            "ratio_hard_over_soft_at_29_6_hz": ratio(1, 0),
            "ratio_undamped_over_damped_at_29_6_hz": ratio(1, 2),
            "ratio_hard_over_soft_max_29_4_to_29_8_hz": ratio_band(1, 0),
            "ratio_undamped_over_damped_max_29_4_to_29_8_hz": ratio_band(1, 2),
            "variant_spread_below_3_hz": spread_low,
        });
        println!("{out}");
    } else {
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
        for c in &curves {
            let (fp, vp) = peak_of(c);
            println!(
                "{:>13} {:>10.2} {:>14.4} {:>16.4} {:>14.6}",
                c.0,
                fp,
                vp,
                motor.map_or(f64::NAN, |k| c.1[k]),
                motor_pssn(c)
            );
        }
        println!(
            "at 29.6 Hz: hard/soft {:.2}, undamped/damped {:.2} (largest over 29.4-29.8 Hz: {:.2}, {:.2}); \
             below 3 Hz the variants are within {:.1} %",
            ratio(1, 0),
            ratio(1, 2),
            ratio_band(1, 0),
            ratio_band(1, 2),
            100.0 * spread_low
        );
    }
    if let Some(dir) = &a.plot {
        std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        let pts: Vec<Vec<(f64, f64)>> = curves
            .iter()
            .map(|c| freqs.iter().copied().zip(c.1.iter().copied()).collect())
            .collect();
        let series: Vec<(&str, &[(f64, f64)])> = curves
            .iter()
            .zip(&pts)
            .map(|(c, p)| (c.0, p.as_slice()))
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
        let pssn_series: Vec<(&str, &[(f64, f64)])> =
            curves.iter().map(|c| (c.0, c.2.as_slice())).collect();
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
        for (label, f, map) in &maps {
            let file = if *label == "main resonance" {
                "map_main_resonance.png"
            } else {
                "map_29_6_hz.png"
            };
            plot::mirror_map(
                dir.join(file),
                &layout,
                map,
                &format!(
                    "{}, voice coil, {label} ({f:.2} Hz): rms surface per segment per pier rms",
                    a.layout
                ),
                "nm/nm",
            )
            .map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
