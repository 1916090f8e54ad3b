//! Line figures: a spectrum of values against their index ([`spectrum`]), and series of
//! `(x, y)` points ([`lines`], in chosen colours [`lines_in_colours`], with labelled points
//! [`lines_marked`]), each turned into an [`XyPlot`] for [`render_xy`].

use std::ops::Range;
use std::path::Path;

use super::xy::{Curve, Mark, XyPlot, data_range, padded_range, render_xy};
use super::{PlotError, SERIES_COLOURS};

/// Plots `values[i]` against the index `i` (0-based) with a line and dots, logarithmic y axis
/// if `log_y`, and each `(index, label)` of `marks` circled and labelled
/// ([`PLOT_SIZE`](super::PLOT_SIZE) pixels). Errors on no plottable value or a mark index out
/// of range.
pub fn spectrum(
    path: impl AsRef<Path>,
    values: &[f64],
    title: &str,
    y_label: &str,
    log_y: bool,
    marks: &[(usize, &str)],
) -> Result<(), PlotError> {
    let path = path.as_ref();
    let usable = |v: f64| v.is_finite() && (!log_y || v > 0.0);
    let points: Vec<(f64, f64)> = values
        .iter()
        .enumerate()
        .filter(|(_, v)| usable(**v))
        .map(|(i, v)| (i as f64, *v))
        .collect();
    if points.is_empty() {
        return Err(PlotError::Invalid(format!(
            "spectrum: no {}value among {}",
            if log_y { "positive finite " } else { "finite " },
            values.len()
        )));
    }
    if let Some((i, _)) = marks.iter().find(|(i, _)| *i >= values.len()) {
        return Err(PlotError::Invalid(format!(
            "spectrum: mark at index {i} beyond the {} values",
            values.len()
        )));
    }
    let n = values.len() as f64;
    let x_pad = (0.02 * n).max(0.5);
    let x_range = -x_pad..(n - 1.0) + x_pad;
    let y_range = padded_range(points.iter().map(|p| p.1), log_y);

    let mut sorted: Vec<(usize, &str)> = marks.to_vec();
    sorted.sort_by_key(|m| m.0);
    let mut mark_list: Vec<Mark> = Vec::new();
    let mut previous: Option<(usize, i32)> = None;
    for (i, label) in sorted {
        if !usable(values[i]) {
            continue;
        }
        let level = match previous {
            Some((j, level)) if (i - j) as f64 <= 0.12 * n => (level + 1) % 4,
            _ => 0,
        };
        previous = Some((i, level));
        let height = if log_y {
            (values[i] / y_range.start).ln() / (y_range.end / y_range.start).ln()
        } else {
            (values[i] - y_range.start) / (y_range.end - y_range.start)
        };
        mark_list.push(Mark {
            at: (i as f64, values[i]),
            label: label.to_string(),
            left: i as f64 > 0.6 * (n - 1.0),
            below: height > 0.6,
            level,
        });
    }

    let plot = XyPlot {
        title: title.into(),
        x_label: "index".into(),
        y_label: y_label.into(),
        log_x: false,
        log_y,
        x_range,
        y_range,
        curves: vec![Curve {
            label: String::new(),
            points,
            colour: SERIES_COLOURS[0],
            markers: values.len() <= 200,
        }],
        marks: mark_list,
        bars: Vec::new(),
        note: Vec::new(),
    };
    render_xy(path, &plot)
}

/// Plots each `(label, points)` of `series` as a line (with markers when it has 12 points or
/// fewer), in its own colour, with a legend of the non-empty labels (an empty label keeps a
/// series out of the legend, e.g. for many Monte-Carlo runs); logarithmic axes on request
/// ([`PLOT_SIZE`](super::PLOT_SIZE) pixels). Errors when no point is plottable.
pub fn lines(
    path: impl AsRef<Path>,
    series: &[(&str, &[(f64, f64)])],
    title: &str,
    x_label: &str,
    y_label: &str,
    log_x: bool,
    log_y: bool,
) -> Result<(), PlotError> {
    let coloured: Vec<ColouredSeries> = series
        .iter()
        .enumerate()
        .map(|(k, (label, points))| (*label, k, *points))
        .collect();
    lines_in_colours(path, &coloured, title, x_label, y_label, log_x, log_y)
}

/// A series for [`lines_in_colours`]: label, colour index in the palette, points.
pub type ColouredSeries<'a> = (&'a str, usize, &'a [(f64, f64)]);

/// As [`lines`], with the colour of each series given (an index into the palette): pieces of
/// one curve (e.g. broken where a case diverged) keep one colour, only the first labelled.
pub fn lines_in_colours(
    path: impl AsRef<Path>,
    series: &[ColouredSeries],
    title: &str,
    x_label: &str,
    y_label: &str,
    log_x: bool,
    log_y: bool,
) -> Result<(), PlotError> {
    lines_marked(path, series, &[], title, x_label, y_label, log_x, log_y)
}

/// A labelled point for [`lines_marked`]: `((x, y), label)`.
pub type PointMark<'a> = ((f64, f64), &'a str);

/// As [`lines_in_colours`], with each `((x, y), label)` of `marks` circled and labelled (e.g.
/// the peaks of a curve); marks outside the plotted range (or not positive on a logarithmic
/// axis) are left out. Labels of marks close in x are stacked apart.
#[allow(clippy::too_many_arguments)]
pub fn lines_marked(
    path: impl AsRef<Path>,
    series: &[ColouredSeries],
    marks: &[PointMark],
    title: &str,
    x_label: &str,
    y_label: &str,
    log_x: bool,
    log_y: bool,
) -> Result<(), PlotError> {
    let path = path.as_ref();
    let usable = |v: f64, log: bool| v.is_finite() && (!log || v > 0.0);
    let curves: Vec<Curve> = series
        .iter()
        .map(|(label, k, points)| Curve {
            label: label.to_string(),
            points: points
                .iter()
                .copied()
                .filter(|p| usable(p.0, log_x) && usable(p.1, log_y))
                .collect(),
            colour: SERIES_COLOURS[k % SERIES_COLOURS.len()],
            // Few points (a handful of cases, or a single one) are shown as markers too.
            markers: points.len() <= 12,
        })
        .collect();
    if curves.iter().all(|c| c.points.is_empty()) {
        return Err(PlotError::Invalid(format!(
            "lines: no plottable point in {} series",
            series.len()
        )));
    }
    let all = || curves.iter().flat_map(|c| c.points.iter());
    let x_range = data_range(all().map(|p| p.0), log_x);
    let y_range = padded_range(all().map(|p| p.1), log_y);
    // Position of a value in a range, 0 to 1 (logarithmic on a log axis).
    let frac = |v: f64, r: &Range<f64>, log: bool| {
        if log {
            (v / r.start).ln() / (r.end / r.start).ln()
        } else {
            (v - r.start) / (r.end - r.start)
        }
    };
    let mut sorted: Vec<(f64, f64, f64, &str)> = marks
        .iter()
        .filter(|((x, y), _)| usable(*x, log_x) && usable(*y, log_y))
        .map(|&((x, y), l)| (frac(x, &x_range, log_x), x, y, l))
        .filter(|m| (0.0..=1.0).contains(&m.0) && (0.0..=1.0).contains(&frac(m.2, &y_range, log_y)))
        .collect();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut mark_list: Vec<Mark> = Vec::new();
    let mut previous: Option<(f64, i32)> = None;
    for (fx, x, y, label) in sorted {
        let level = match previous {
            Some((px, level)) if fx - px <= 0.12 => (level + 1) % 4,
            _ => 0,
        };
        previous = Some((fx, level));
        mark_list.push(Mark {
            at: (x, y),
            label: label.to_string(),
            left: fx > 0.6,
            below: frac(y, &y_range, log_y) > 0.6,
            level,
        });
    }
    let plot = XyPlot {
        title: title.into(),
        x_label: x_label.into(),
        y_label: y_label.into(),
        log_x,
        log_y,
        x_range,
        y_range,
        curves,
        marks: mark_list,
        bars: Vec::new(),
        note: Vec::new(),
    };
    render_xy(path, &plot)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::testing::{assert_png, temp_dir};

    #[test]
    fn spectrum_writes_a_png() {
        let values: Vec<f64> = (0..108).map(|i| 10f64.powf(-(i as f64) / 20.0)).collect();
        let dir = temp_dir("spectrum");
        for log_y in [false, true] {
            let path = dir.join(format!("spectrum-{log_y}.png"));
            spectrum(
                &path,
                &values,
                "singular values",
                "sigma",
                log_y,
                &[(105, "focus-mode"), (107, "last"), (0, "first")],
            )
            .unwrap();
            assert_png(&path);
        }
        let path = dir.join("bad.png");
        assert!(matches!(
            spectrum(&path, &values, "t", "y", false, &[(108, "out")]),
            Err(PlotError::Invalid(_))
        ));
        assert!(matches!(
            spectrum(&path, &[0.0, -1.0], "t", "y", true, &[]),
            Err(PlotError::Invalid(_))
        ));
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn lines_writes_a_png() {
        let a: Vec<(f64, f64)> = (1..200)
            .map(|i| (i as f64, 1.0 / (1.0 + (i as f64 / 30.0).powi(2))))
            .collect();
        let b: Vec<(f64, f64)> = a.iter().map(|&(x, y)| (x, 2.0 * y)).collect();
        let dir = temp_dir("lines");
        for (log_x, log_y) in [(false, false), (true, false), (false, true), (true, true)] {
            let path = dir.join(format!("lines-{log_x}-{log_y}.png"));
            lines(
                &path,
                &[("a", &a), ("b", &b), ("", &a[..10])],
                "response",
                "f [Hz]",
                "gain",
                log_x,
                log_y,
            )
            .unwrap();
            assert_png(&path);
        }
        let path = dir.join("bad.png");
        assert!(matches!(
            lines(&path, &[("a", &[])], "t", "x", "y", false, false),
            Err(PlotError::Invalid(_))
        ));
        std::fs::remove_dir_all(dir).ok();
    }
}
