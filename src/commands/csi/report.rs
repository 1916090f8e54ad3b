//! What `m1cs csi` prints: the servo loop, the Q allowance, the global loop.

use super::*;

/// The servo loop's table: the peak sensitivity per basis, the all-segment peaks and the
/// highest gain.
pub(super) fn print_servo(a: &CsiArgs, layout: &Layout, servo: &ServoLoop, range: (f64, f64)) {
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
pub(super) struct QAllowance {
    case: String,
    realizations: usize,
    worst_sigma_gamma_q: f64,
    median_sigma_gamma_q: f64,
}

pub(super) fn q_allowance(
    geometry: &Geometry,
    realizations: usize,
) -> Result<Option<QAllowance>, String> {
    if realizations == 0 {
        return Ok(None);
    }
    let nominal = Nominal::new(geometry.clone()).map_err(|e| format!("A-matrix: {e}"))?;
    let case = Case {
        name: "sensor gain 0.1%".into(),
        perturbation: Perturbation::SensorGain { rms: 1e-3 },
        published: None,
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
pub(super) fn family(label: &str, noll: usize) -> String {
    if label.starts_with('Z') {
        label.to_string()
    } else {
        format!("{label} (Z{noll})")
    }
}

pub(super) fn print_global(g: &GlobalSweep, q: Option<&QAllowance>) {
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
