//! Histograms ([`histogram`]): equal bins between the extremes, with the count, mean and
//! standard deviation in a corner, drawn by [`render_xy`] as bars.

use std::path::Path;

use super::PlotError;
use super::xy::{XyPlot, render_xy, significant};

/// Histogram of the finite `values` in `bins` equal bins between their minimum and maximum,
/// with the count, mean and standard deviation in a corner ([`PLOT_SIZE`](super::PLOT_SIZE)
/// pixels). Errors on `bins == 0` or no finite value.
// No command draws a histogram yet (the Monte Carlo studies of issue 16 will); tested below.
#[cfg_attr(not(test), allow(dead_code))]
pub fn histogram(
    path: impl AsRef<Path>,
    values: &[f64],
    bins: usize,
    title: &str,
    x_label: &str,
) -> Result<(), PlotError> {
    let path = path.as_ref();
    if bins == 0 {
        return Err(PlotError::Invalid("histogram: zero bins".into()));
    }
    let finite: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return Err(PlotError::Invalid(format!(
            "histogram: no finite value among {}",
            values.len()
        )));
    }
    let (mut lo, mut hi) = finite
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(*v), h.max(*v)));
    if hi <= lo {
        let half = if lo == 0.0 { 0.5 } else { 0.05 * lo.abs() };
        (lo, hi) = (lo - half, hi + half);
    }
    let width = (hi - lo) / bins as f64;
    let mut counts = vec![0_usize; bins];
    for v in &finite {
        let k = (((v - lo) / width).floor().max(0.0) as usize).min(bins - 1);
        counts[k] += 1;
    }
    let bars: Vec<(f64, f64, f64)> = counts
        .iter()
        .enumerate()
        .map(|(k, &c)| {
            let x0 = lo + width * k as f64;
            (x0, x0 + width, c as f64)
        })
        .collect();
    let n = finite.len() as f64;
    let mean = finite.iter().sum::<f64>() / n;
    let std = (finite.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    let top = counts.iter().copied().max().unwrap_or(0) as f64;
    let step = (hi - lo) / 10.0;
    let magnitude = lo.abs().max(hi.abs());
    let plot = XyPlot {
        title: title.into(),
        x_label: x_label.into(),
        y_label: "count".into(),
        log_x: false,
        log_y: false,
        x_range: lo - 0.02 * (hi - lo)..hi + 0.02 * (hi - lo),
        y_range: 0.0..(top * 1.08).max(1.0),
        curves: Vec::new(),
        marks: Vec::new(),
        bars,
        note: vec![
            format!("N = {}", finite.len()),
            format!("mean = {}", significant(mean, step, magnitude)),
            format!("std = {}", significant(std, step, magnitude)),
        ],
    };
    render_xy(path, &plot)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::testing::{assert_png, temp_dir};

    #[test]
    fn histogram_writes_a_png() {
        let values: Vec<f64> = (0..1000)
            .map(|i| ((i as f64) * 0.7).sin() * 3e-9 + 1e-9)
            .collect();
        let dir = temp_dir("histogram");
        let path = dir.join("histogram.png");
        histogram(&path, &values, 30, "Monte Carlo", "rms [m]").unwrap();
        assert_png(&path);
        let path = dir.join("constant.png");
        histogram(&path, &[2.0; 5], 10, "constant", "x").unwrap();
        assert_png(&path);
        assert!(matches!(
            histogram(&path, &values, 0, "t", "x"),
            Err(PlotError::Invalid(_))
        ));
        assert!(matches!(
            histogram(&path, &[f64::NAN], 3, "t", "x"),
            Err(PlotError::Invalid(_))
        ));
        std::fs::remove_dir_all(dir).ok();
    }
}
