//! `m1cs overall`: the overall quasi-static simulation of the control algorithm
//! ([`m1::analysis::overall`]): nights of tracking and weeks of operation with gravity and
//! thermal deformation, installed sensors, calibration, APS and optical feedback.

use std::path::{Path, PathBuf};

use clap::Args;
use serde_json::json;

use m1::analysis::overall::fit::FitFunction;
use m1::analysis::overall::{self, OverallParams, OverallResult};
use m1::analysis::quasistatic::default_geometry;
use m1::aperture::layout::DEFAULT_LAYOUT;
use m1::loads::deformation::{DeformationModel, DeformationTable};

use crate::plot;

/// `m1cs overall`.
#[derive(Args, Debug)]
pub struct OverallArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = DEFAULT_LAYOUT)]
    pub layout: String,
    /// Nights simulated (one star tracked each night).
    #[arg(long, default_value_t = OverallParams::default().schedule.days)]
    pub days: usize,
    /// Quasi-static step, minutes of simulated time.
    #[arg(long, default_value_t = OverallParams::default().schedule.step_minutes)]
    pub step_minutes: f64,
    /// Days between APS runs.
    #[arg(long, default_value_t = OverallParams::default().aps.interval_days)]
    pub aps_interval_days: f64,
    /// Optical-feedback bandwidth, Hz.
    #[arg(long, default_value_t = OverallParams::default().optical_feedback.bandwidth)]
    pub of_bandwidth: f64,
    /// Leave focus-mode to the edge sensors (the optical feedback closes global piston/tip/tilt
    /// only).
    #[arg(long)]
    pub of_no_focus: bool,
    /// Calibration fit function used in operation: constant, gap or gap_shear.
    #[arg(long, default_value = "gap_shear")]
    pub fit: String,
    /// FEA deformation results (.npz: zenith_deg, temperature_c, w, z_cell; see the m1 docs of
    /// loads::deformation) instead of the parametric model.
    #[arg(long)]
    pub fea: Option<PathBuf>,
    /// Minutes between PSSN evaluations (0: none).
    #[arg(long, default_value_t = OverallParams::default().pssn_every_minutes)]
    pub pssn_every_minutes: f64,
    /// Seed of the schedule, the noise and the drift.
    #[arg(long, default_value_t = OverallParams::default().seed)]
    pub seed: u64,
    /// Print one JSON object (every time series) instead of the summary.
    #[arg(long)]
    pub json: bool,
    /// Write PNG figures into this directory: the figures versus time and M1 maps.
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

fn params(a: &OverallArgs) -> Result<OverallParams, String> {
    let mut p = OverallParams::default();
    p.schedule.days = a.days;
    p.schedule.step_minutes = a.step_minutes;
    p.schedule.seed = a.seed;
    p.seed = a.seed;
    p.aps.interval_days = a.aps_interval_days;
    p.optical_feedback.bandwidth = a.of_bandwidth;
    p.optical_feedback.focus = !a.of_no_focus;
    p.pssn_every_minutes = a.pssn_every_minutes;
    p.calibration.function = FitFunction::from_name(&a.fit).ok_or_else(|| {
        format!(
            "--fit {}: expected one of {}",
            a.fit,
            FitFunction::ALL.map(FitFunction::name).join(", ")
        )
    })?;
    if !(a.pssn_every_minutes.is_finite() && a.pssn_every_minutes >= 0.0) {
        return Err(format!(
            "--pssn-every-minutes {}: must be >= 0",
            a.pssn_every_minutes
        ));
    }
    Ok(p)
}

/// Runs `m1cs overall`.
pub fn overall(a: &OverallArgs) -> Result<(), String> {
    let p = params(a)?;
    let layout = super::load_layout(&a.layout)?;
    let g = default_geometry(&layout, false, None).map_err(|e| e.to_string())?;
    let table = match &a.fea {
        Some(path) => Some(DeformationModel::Table(
            DeformationTable::from_npz(
                path,
                g.n_actuators(),
                p.deformation.baseline_zenith_deg,
                p.deformation.baseline_temperature,
            )
            .map_err(|e| format!("--fea: {e}"))?,
        )),
        None => None,
    };
    let bar = indicatif::ProgressBar::new(4);
    if a.json {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {msg} {pos}/{len} variants, {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
    );
    bar.set_message("calibration campaign and the nights:");
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    let t0 = std::time::Instant::now();
    let r = overall::run(&g, &p, table, &|k, _| bar.set_position(k as u64))
        .map_err(|e| e.to_string())?;
    bar.finish_and_clear();
    let seconds = t0.elapsed().as_secs_f64();
    if let Some(dir) = &a.plot {
        plots(dir, &layout, &g, &r).map_err(|e| format!("--plot {}: {e}", dir.display()))?;
    }
    if a.json {
        println!(
            "{}",
            json!({
                "layout": layout.name,
                "params": p,
                "seconds": seconds,
                "result": r,
            })
        );
        return Ok(());
    }
    print_summary(&layout.name, &p, &r, seconds);
    Ok(())
}

fn print_summary(layout: &str, p: &OverallParams, r: &OverallResult, seconds: f64) {
    let nm = 1e9;
    println!(
        "Overall quasi-static simulation, {layout}: {} nights, {} instants ({} min steps), APS at \
         day(s) {}",
        p.schedule.days,
        r.instants.len(),
        p.schedule.step_minutes,
        r.aps_days
            .iter()
            .map(|d| format!("{d:.1}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "Calibration campaign: {} APS runs (zenith {:?} deg x temperature {:?} K); fit \
         functions by leave-one-out residual:",
        r.calibration_runs, p.calibration.zenith_deg, p.calibration.temperature
    );
    for f in &r.calibration_fits {
        println!(
            "  {:<10} fit {:>7.2} nm   leave-one-out {:>7.2} nm{}",
            f.function.name(),
            f.fit_rms * nm,
            f.leave_one_out_rms * nm,
            if f.function == p.calibration.function {
                "   (used)"
            } else {
                ""
            }
        );
    }
    println!(
        "{:<32} {:>10} {:>10} {:>10} {:>12} {:>12} {:>10}",
        "variant", "rms nm", "p95 nm", "max nm", "w/o focus", "focus nm", "min PSSN"
    );
    for v in &r.variants {
        println!(
            "{:<32} {:>10.2} {:>10.2} {:>10.2} {:>12.2} {:>12.2} {:>10.4}",
            v.name,
            v.summary[0].rms * nm,
            v.summary[0].p95 * nm,
            v.summary[0].max * nm,
            v.summary[1].rms * nm,
            v.summary[2].rms * nm,
            v.pssn_min
        );
    }
    println!(
        "(rms over time of the rms surface, global piston/tip/tilt removed; calibration \
         residual rms: {}; {seconds:.1} s)",
        r.variants
            .iter()
            .map(|v| format!("{} {:.2} nm", v.name, v.summary[3].rms * nm))
            .collect::<Vec<_>>()
            .join(", ")
    );
}

fn plots(
    dir: &Path,
    layout: &m1::aperture::layout::Layout,
    g: &m1::aperture::geometry::Geometry,
    r: &OverallResult,
) -> Result<(), String> {
    std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
    let nm = 1e9;
    let t: Vec<f64> = r.instants.iter().map(|i| i.time_days).collect();
    let series =
        |f: &dyn Fn(&overall::VariantResult) -> &Vec<f64>| -> Vec<(String, Vec<(f64, f64)>)> {
            r.variants
                .iter()
                .map(|v| {
                    (
                        v.name.clone(),
                        t.iter()
                            .zip(f(v))
                            .map(|(a, b)| (*a, b.abs() * nm))
                            .collect(),
                    )
                })
                .collect()
        };
    let draw = |file: &str, s: Vec<(String, Vec<(f64, f64)>)>, title: &str, y: &str, log_y| {
        // One piece per night in the variant's colour (only the first labelled), so the
        // days between nights are gaps rather than lines.
        let mut pieces: Vec<plot::ColouredSeries> = Vec::new();
        for (k, (n, p)) in s.iter().enumerate() {
            let mut start = 0;
            for i in 1..=p.len() {
                if i == p.len() || p[i].0 - p[i - 1].0 > 0.25 {
                    let label = if start == 0 { n.as_str() } else { "" };
                    pieces.push((label, k, &p[start..i]));
                    start = i;
                }
            }
        }
        plot::lines_in_colours(
            dir.join(file),
            &pieces,
            title,
            "time (days)",
            y,
            false,
            log_y,
        )
        .map_err(|e| e.to_string())
    };
    let name = &layout.name;
    draw(
        "overall_rms.png",
        series(&|v| &v.rms),
        &format!("M1 rms surface (global PTT removed), {name}"),
        "rms surface (nm)",
        true,
    )?;
    draw(
        "overall_focus.png",
        series(&|v| &v.focus_rms),
        &format!("Focus-mode |rms surface|, {name}"),
        "focus-mode (nm)",
        true,
    )?;
    draw(
        "overall_calibration.png",
        series(&|v| &v.calibration_residual),
        &format!("Desired-reading error (rms over sensors), {name}"),
        "calibration residual (nm)",
        true,
    )?;
    if !r.pssn_index.is_empty() {
        let s: Vec<(String, Vec<(f64, f64)>)> = r
            .variants
            .iter()
            .map(|v| {
                (
                    v.name.clone(),
                    r.pssn_index
                        .iter()
                        .zip(&v.pssn)
                        .map(|(&k, p)| (t[k], *p))
                        .collect(),
                )
            })
            .collect();
        draw(
            "overall_pssn.png",
            s,
            &format!("PSSN (500 nm), {name}"),
            "PSSN",
            false,
        )?;
    }
    let metrics = m1::optics::metrics::MirrorMetrics::new(g).map_err(|e| e.to_string())?;
    for v in &r.variants {
        let mut res = vec![[0.0; 3]; g.n_segments()];
        metrics
            .residual_ptt(&v.worst_z, &mut res)
            .map_err(|e| e.to_string())?;
        let scaled: Vec<[f64; 3]> = res
            .iter()
            .map(|p| [p[0] * nm, p[1] * nm, p[2] * nm])
            .collect();
        let file = format!(
            "overall_map_{}.png",
            v.name.replace([' ', '+'], "_").replace("__", "_")
        );
        plot::mirror_map_ptt(
            dir.join(file),
            layout,
            &scaled,
            &format!("{}: worst instant, global PTT removed", v.name),
            "nm",
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}
