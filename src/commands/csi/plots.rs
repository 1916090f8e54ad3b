//! The figures of `m1cs csi`.

use super::report::family;
use super::*;

/// Draws `labels[k]` over `data[k]` with each `((f, value), text)` of `peaks` circled and
/// labelled, into `dir/file`.
#[allow(clippy::too_many_arguments)]
pub(super) fn marked_plot(
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

pub(super) fn write_global_plot(dir: &str, name: &str, g: &GlobalSweep) -> Result<(), String> {
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

pub(super) fn write_plots(
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
