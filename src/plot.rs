//! PNG figures: mirror maps (one value per segment, or piston/tip/tilt surfaces), spectra,
//! line plots and histograms, drawn with `plotters` on its bitmap backend.
//!
//! Text uses the DejaVu Sans font embedded in the binary (`assets/DejaVuSans.ttf`), registered
//! once as plotters' `sans-serif` family before the first figure is drawn; no system font is
//! needed.
//!
//! # Conventions
//!
//! - Maps are seen from the sky (the layout's aperture-plane coordinates, `x` right, `y` up) with
//!   an equal aspect ratio, and use a diverging blue-white-red colour map symmetric about 0: white
//!   is 0, full red is `+max |value|`, full blue is `-max |value|`.
//! - Piston/tip/tilt triplets `[p, tx, ty]` describe the surface
//!   `z = p + tx (x - cx) + ty (y - cy)` over a segment centred at `(cx, cy)`: `p` in the map's
//!   unit, `tx` and `ty` in that unit per metre.
//! - On logarithmic axes, points that are not strictly positive are left out; non-finite points
//!   are always left out of spectra, line plots and histograms. Maps reject non-finite values.
//! - Every function creates the missing parent directories of `path` and overwrites `path`.
#![allow(dead_code)]

use std::error::Error;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Once;
use std::sync::atomic::{AtomicBool, Ordering};

use m1::aperture::layout::Layout;
use plotters::coord::ReverseCoordTranslate;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

/// Size of map figures (pixels).
pub const MAP_SIZE: (u32, u32) = (900, 800);
/// Size of spectrum, line and histogram figures (pixels).
pub const PLOT_SIZE: (u32, u32) = (900, 600);

/// Font family every text of the figures uses.
const FONT: &str = "sans-serif";
const TITLE_SIZE: f64 = 26.0;
const DESC_SIZE: f64 = 19.0;
const LABEL_SIZE: f64 = 16.0;
/// Plotters' ab_glyph text sits about 3 px above its anchor at these sizes: moves the y tick
/// labels down level with their ticks.
const Y_LABEL_NUDGE: i32 = 3;

/// DejaVu Sans (see `assets/DejaVuSans.LICENSE`).
static FONT_BYTES: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
static FONT_ONCE: Once = Once::new();
static FONT_OK: AtomicBool = AtomicBool::new(false);

/// Why a figure could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// A per-segment input does not have one entry per segment.
    #[error("{what}: {got} values for a layout of {expected} segments")]
    Length {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    /// Unusable input (empty data, non-finite map value, bad mark index, zero bins, ...).
    #[error("{0}")]
    Invalid(String),
    /// The embedded font could not be loaded.
    #[error("the embedded DejaVu Sans font could not be registered")]
    Font,
    /// The directory of the output file could not be created.
    #[error("cannot create the directory of {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    /// Drawing or writing the PNG failed.
    #[error("cannot draw {path}: {message}")]
    Draw { path: PathBuf, message: String },
}

type DrawResult = Result<(), Box<dyn Error>>;

/// Registers the embedded font as the `sans-serif` family, once per process.
fn ensure_font() -> Result<(), PlotError> {
    FONT_ONCE.call_once(|| {
        let ok = [FontStyle::Normal, FontStyle::Bold]
            .into_iter()
            .all(|style| plotters::style::register_font(FONT, style, FONT_BYTES).is_ok());
        FONT_OK.store(ok, Ordering::SeqCst);
    });
    if FONT_OK.load(Ordering::SeqCst) {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

/// Font set-up and parent directory of `path`.
fn prepare(path: &Path) -> Result<(), PlotError> {
    ensure_font()?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|source| PlotError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    }
    Ok(())
}

/// Wraps a drawing failure with the file it was meant for.
fn draw_error(path: &Path, e: Box<dyn Error>) -> PlotError {
    PlotError::Draw {
        path: path.to_path_buf(),
        message: e.to_string(),
    }
}

fn font(size: f64) -> TextStyle<'static> {
    (FONT, size).into_font().color(&BLACK)
}

// ------------------------------------------------------------------------------------------
// Colours and tick labels
// ------------------------------------------------------------------------------------------

/// ColorBrewer RdBu, from -1 (dark blue) through 0 (white) to +1 (dark red).
const DIVERGING: [(u8, u8, u8); 11] = [
    (5, 48, 97),
    (33, 102, 172),
    (67, 147, 195),
    (146, 197, 222),
    (209, 229, 240),
    (247, 247, 247),
    (253, 219, 199),
    (244, 165, 130),
    (214, 96, 77),
    (178, 24, 43),
    (103, 0, 31),
];

/// Colour of `value` on the diverging map spanning `[-vmax, vmax]` (clamped outside).
fn diverging(value: f64, vmax: f64) -> RGBColor {
    let t = if vmax > 0.0 && value.is_finite() {
        (value / vmax).clamp(-1.0, 1.0)
    } else {
        0.0
    };
    let s = (t + 1.0) / 2.0 * (DIVERGING.len() - 1) as f64;
    let k = (s.floor() as usize).min(DIVERGING.len() - 2);
    let f = s - k as f64;
    let (a, b) = (DIVERGING[k], DIVERGING[k + 1]);
    let mix = |x: u8, y: u8| (f64::from(x) + f * (f64::from(y) - f64::from(x))).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Colours of the series of a line plot (Tableau 10).
const SERIES_COLOURS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// `"1.500"` -> `"1.5"`, `"2.000e-9"` -> `"2e-9"`.
fn trim_number(s: String) -> String {
    let (mantissa, exponent) = match s.find('e') {
        Some(k) => (&s[..k], &s[k..]),
        None => (s.as_str(), ""),
    };
    let mantissa = if mantissa.contains('.') {
        mantissa.trim_end_matches('0').trim_end_matches('.')
    } else {
        mantissa
    };
    format!("{mantissa}{exponent}")
}

/// Label of the tick `v` on a linear axis whose ticks are at least `step` apart and whose
/// values reach `magnitude` in absolute value: plain decimals between 1e-3 and 1e5, scientific
/// notation otherwise, with as many digits as the step needs.
fn linear_tick(v: f64, step: f64, magnitude: f64) -> String {
    if !v.is_finite() {
        return String::new();
    }
    let step = if step > 0.0 && step.is_finite() {
        step
    } else {
        magnitude.abs().max(f64::MIN_POSITIVE)
    };
    if v.abs() < step * 1e-6 {
        return "0".into();
    }
    let step_exp = step.log10().floor();
    if (1e-3..1e5).contains(&magnitude.abs()) {
        let decimals = (-step_exp).clamp(0.0, 12.0) as usize;
        trim_number(format!("{v:.decimals$}"))
    } else {
        let decimals = (v.abs().log10().floor() - step_exp).clamp(0.0, 6.0) as usize;
        trim_number(format!("{v:.decimals$e}"))
    }
}

/// Label of the tick `v` on a logarithmic axis (three significant digits at most).
fn log_tick(v: f64) -> String {
    if !(v > 0.0 && v.is_finite()) {
        return String::new();
    }
    let exp = v.log10().floor();
    if (-3.0..5.0).contains(&exp) {
        let decimals = (2.0 - exp).max(0.0) as usize;
        trim_number(format!("{v:.decimals$}"))
    } else {
        trim_number(format!("{v:.2e}"))
    }
}

/// Tick formatter of an axis over `range` with about `n` labels.
fn tick_formatter(range: &Range<f64>, log: bool, n: usize) -> impl Fn(&f64) -> String + use<> {
    let step = (range.end - range.start).abs() / n.max(1) as f64;
    let magnitude = range.start.abs().max(range.end.abs());
    move |v: &f64| {
        if log {
            log_tick(*v)
        } else {
            linear_tick(*v, step, magnitude)
        }
    }
}

// ------------------------------------------------------------------------------------------
// Mirror maps
// ------------------------------------------------------------------------------------------

/// Draws `layout` with each segment a filled hexagon coloured by its entry of `values` (one per
/// segment, finite) on the diverging colour map, with a colour bar labelled `unit` and the
/// `title` on top ([`MAP_SIZE`] pixels).
pub fn mirror_map(
    path: impl AsRef<Path>,
    layout: &Layout,
    values: &[f64],
    title: &str,
    unit: &str,
) -> Result<(), PlotError> {
    let path = path.as_ref();
    check_segments(layout, values.len(), "mirror_map values")?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        return Err(PlotError::Invalid(format!(
            "mirror_map: value of segment {i} (`{}`) is {}",
            layout.segments[i].name, values[i]
        )));
    }
    let vmax = values.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    prepare(path)?;
    draw_map(path, layout, title, unit, vmax, |chart, _root| {
        for (i, &v) in values.iter().enumerate() {
            if let Some(corners) = layout.vertices(i) {
                let polygon: Vec<(f64, f64)> = corners.iter().map(|c| (c[0], c[1])).collect();
                chart.draw_series(std::iter::once(Polygon::new(
                    polygon,
                    diverging(v, vmax).filled(),
                )))?;
                draw_outline(chart, &corners)?;
            }
        }
        Ok(())
    })
    .map_err(|e| draw_error(path, e))
}

/// Draws `layout` with, inside each segment, the surface `z = p + tx (x - cx) + ty (y - cy)`
/// of its triplet `ptt[i] = [p, tx, ty]` (one per segment, finite), pixel by pixel on the
/// diverging colour map (symmetric about 0 with the largest |z| over the segment corners), so
/// that tips and tilts show; colour bar labelled `unit`, `title` on top ([`MAP_SIZE`] pixels).
pub fn mirror_map_ptt(
    path: impl AsRef<Path>,
    layout: &Layout,
    ptt: &[[f64; 3]],
    title: &str,
    unit: &str,
) -> Result<(), PlotError> {
    let path = path.as_ref();
    check_segments(layout, ptt.len(), "mirror_map_ptt triplets")?;
    if let Some(i) = ptt.iter().position(|t| t.iter().any(|v| !v.is_finite())) {
        return Err(PlotError::Invalid(format!(
            "mirror_map_ptt: triplet of segment {i} (`{}`) is {:?}",
            layout.segments[i].name, ptt[i]
        )));
    }
    let surface = |i: usize, x: f64, y: f64| {
        let c = layout.segments[i].center;
        let [p, tx, ty] = ptt[i];
        p + tx * (x - c[0]) + ty * (y - c[1])
    };
    // A plane over a convex polygon peaks at a corner.
    let mut vmax = 0.0_f64;
    for i in 0..layout.n_segments() {
        if let Some(corners) = layout.vertices(i) {
            for c in corners {
                vmax = vmax.max(surface(i, c[0], c[1]).abs());
            }
        }
    }
    prepare(path)?;
    draw_map(path, layout, title, unit, vmax, |chart, root| {
        let spec = chart.as_coord_spec().clone();
        for i in 0..layout.n_segments() {
            let Some(corners) = layout.vertices(i) else {
                continue;
            };
            let pixels: Vec<(i32, i32)> = corners
                .iter()
                .map(|c| chart.backend_coord(&(c[0], c[1])))
                .collect();
            let (px0, px1) = min_max(pixels.iter().map(|p| p.0));
            let (py0, py1) = min_max(pixels.iter().map(|p| p.1));
            for py in py0..=py1 {
                for px in px0..=px1 {
                    let Some((x, y)) = spec.reverse_translate((px, py)) else {
                        continue;
                    };
                    if inside_convex(&corners, x, y) {
                        root.draw_pixel((px, py), &diverging(surface(i, x, y), vmax))?;
                    }
                }
            }
            draw_outline(chart, &corners)?;
        }
        Ok(())
    })
    .map_err(|e| draw_error(path, e))
}

/// Thin grey outline of a segment, so that segments near 0 (white) stand out from the
/// background and neighbours stay distinct.
fn draw_outline(chart: &mut MapChart<'_, '_>, corners: &[[f64; 2]; 6]) -> DrawResult {
    let mut outline: Vec<(f64, f64)> = corners.iter().map(|c| (c[0], c[1])).collect();
    outline.push(outline[0]);
    chart.draw_series(std::iter::once(PathElement::new(
        outline,
        BLACK.mix(0.3).stroke_width(1),
    )))?;
    Ok(())
}

fn check_segments(layout: &Layout, got: usize, what: &'static str) -> Result<(), PlotError> {
    if got != layout.n_segments() {
        return Err(PlotError::Length {
            what,
            got,
            expected: layout.n_segments(),
        });
    }
    Ok(())
}

fn min_max(values: impl Iterator<Item = i32>) -> (i32, i32) {
    values.fold((i32::MAX, i32::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)))
}

/// Whether `(x, y)` is inside the counter-clockwise convex polygon `corners` (border included).
fn inside_convex(corners: &[[f64; 2]], x: f64, y: f64) -> bool {
    let n = corners.len();
    (0..n).all(|k| {
        let a = corners[k];
        let b = corners[(k + 1) % n];
        (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]) >= 0.0
    })
}

type MapChart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;
type Root<'b> = DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>;

/// Frame of both maps: title, equal-aspect axes in metres over the layout, `body` drawing the
/// segments, colour bar over `[-vmax, vmax]` labelled `unit`.
fn draw_map(
    path: &Path,
    layout: &Layout,
    title: &str,
    unit: &str,
    vmax: f64,
    body: impl FnOnce(&mut MapChart<'_, '_>, &Root<'_>) -> DrawResult,
) -> DrawResult {
    const MARGIN: u32 = 15;
    const X_LABELS: u32 = 50;
    const Y_LABELS: u32 = 70;
    const BAR_AREA: u32 = 170;
    let vmax = if vmax > 0.0 && vmax.is_finite() {
        vmax
    } else {
        1.0
    };

    let root = BitMapBackend::new(path, MAP_SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let content = root.titled(title, font(TITLE_SIZE))?;
    let (width, height) = content.dim_in_pixel();
    let (map_area, bar_area) = content.split_horizontally(width.saturating_sub(BAR_AREA));

    // Equal aspect: one scale (m per pixel) on both axes, the layout centred.
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for i in 0..layout.n_segments() {
        for c in layout.vertices(i).into_iter().flatten() {
            (x0, x1, y0, y1) = (x0.min(c[0]), x1.max(c[0]), y0.min(c[1]), y1.max(c[1]));
        }
    }
    if x0 > x1 {
        (x0, x1, y0, y1) = (-1.0, 1.0, -1.0, 1.0);
    }
    let pad = 0.02 * (x1 - x0).max(y1 - y0);
    let (map_w, _) = map_area.dim_in_pixel();
    let plot_w = f64::from(map_w.saturating_sub(2 * MARGIN + Y_LABELS).max(1));
    let plot_h = f64::from(height.saturating_sub(2 * MARGIN + X_LABELS).max(1));
    let scale = ((x1 - x0 + 2.0 * pad) / plot_w).max((y1 - y0 + 2.0 * pad) / plot_h);
    let (xc, yc) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let x_range = xc - scale * plot_w / 2.0..xc + scale * plot_w / 2.0;
    let y_range = yc - scale * plot_h / 2.0..yc + scale * plot_h / 2.0;

    let mut chart = ChartBuilder::on(&map_area)
        .margin(MARGIN)
        .x_label_area_size(X_LABELS)
        .y_label_area_size(Y_LABELS)
        .build_cartesian_2d(x_range.clone(), y_range.clone())?;
    let x_fmt = tick_formatter(&x_range, false, 10);
    let y_fmt = tick_formatter(&y_range, false, 10);
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(10)
        .y_labels(10)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .x_desc("x [m]")
        .y_desc("y [m]")
        .label_style(font(LABEL_SIZE))
        .y_label_offset(Y_LABEL_NUDGE)
        .set_all_tick_mark_size(5)
        .axis_desc_style(font(DESC_SIZE))
        .draw()?;
    body(&mut chart, &root)?;

    // Colour bar, its top and bottom level with the map's plotting area.
    const BAR_TOP: u32 = 40;
    let mut bar = ChartBuilder::on(&bar_area)
        .margin_top(MARGIN + BAR_TOP)
        .margin_bottom(MARGIN + X_LABELS)
        .margin_left(20)
        .margin_right(10)
        .right_y_label_area_size(95)
        .build_cartesian_2d(0.0..1.0, -vmax..vmax)?;
    let bar_fmt = tick_formatter(&(-vmax..vmax), false, 10);
    bar.configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(10)
        .y_label_formatter(&bar_fmt)
        .label_style(font(LABEL_SIZE))
        .y_label_offset(Y_LABEL_NUDGE)
        .set_all_tick_mark_size(5)
        .draw()?;
    const STEPS: usize = 256;
    bar.draw_series((0..STEPS).map(|k| {
        let lo = -vmax + 2.0 * vmax * k as f64 / STEPS as f64;
        let hi = -vmax + 2.0 * vmax * (k + 1) as f64 / STEPS as f64;
        Rectangle::new(
            [(0.0, lo), (1.0, hi)],
            diverging((lo + hi) / 2.0, vmax).filled(),
        )
    }))?;
    bar.draw_series(std::iter::once(Rectangle::new(
        [(0.0, -vmax), (1.0, vmax)],
        BLACK.stroke_width(1),
    )))?;
    if !unit.is_empty() {
        let (bx, _) = bar.plotting_area().get_pixel_range();
        let (ax, _) = bar_area.get_base_pixel();
        let centre = (bx.start + bx.end) / 2 - ax;
        let style = font(DESC_SIZE).pos(Pos::new(HPos::Center, VPos::Bottom));
        let top = (MARGIN + BAR_TOP) as i32 - 12;
        bar_area.draw_text(unit, &style, (centre, top))?;
    }
    root.present()?;
    Ok(())
}

// ------------------------------------------------------------------------------------------
// Spectra, line plots and histograms
// ------------------------------------------------------------------------------------------

/// One curve of an x-y plot.
struct Curve {
    label: String,
    points: Vec<(f64, f64)>,
    colour: RGBColor,
    markers: bool,
}

/// A labelled point.
struct Mark {
    at: (f64, f64),
    label: String,
    /// Label to the left of the point (the point is in the right part of the plot).
    left: bool,
    /// Label below the point (the point is in the upper part of the plot).
    below: bool,
    /// Stacking level of the label, to keep close labels apart.
    level: i32,
}

/// Everything an x-y figure shows.
struct XyPlot {
    title: String,
    x_label: String,
    y_label: String,
    log_x: bool,
    log_y: bool,
    x_range: Range<f64>,
    y_range: Range<f64>,
    curves: Vec<Curve>,
    marks: Vec<Mark>,
    /// Histogram bars `(x0, x1, height)`, drawn from the bottom of the y range.
    bars: Vec<(f64, f64, f64)>,
    /// Lines of text in the top-right corner.
    note: Vec<String>,
}

/// Plots `values[i]` against the index `i` (0-based) with a line and dots, logarithmic y axis
/// if `log_y`, and each `(index, label)` of `marks` circled and labelled ([`PLOT_SIZE`]
/// pixels). Errors on no plottable value or a mark index out of range.
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
/// fewer), in its own colour, with a legend of the non-empty labels (an empty label keeps a series out of the legend, e.g. for many Monte-Carlo
/// runs); logarithmic axes on request ([`PLOT_SIZE`] pixels). Errors when no point is
/// plottable.
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

/// Histogram of the finite `values` in `bins` equal bins between their minimum and maximum,
/// with the count, mean and standard deviation in a corner ([`PLOT_SIZE`] pixels). Errors on
/// `bins == 0` or no finite value.
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

/// `v` with a few more digits than the axis ticks.
fn significant(v: f64, step: f64, magnitude: f64) -> String {
    linear_tick(v, step / 100.0, magnitude)
}

/// Range of `values`, widened when degenerate (x axes: no padding).
fn data_range(values: impl Iterator<Item = f64>, log: bool) -> Range<f64> {
    let (lo, hi) = values.fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(v), h.max(v)));
    widen(lo, hi, log)
}

/// Range of `values` with 5 % room at both ends (of the decades on a log axis).
fn padded_range(values: impl Iterator<Item = f64>, log: bool) -> Range<f64> {
    let (lo, hi) = values.fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(v), h.max(v)));
    let Range { start, end } = widen(lo, hi, log);
    if log {
        let factor = 10f64.powf(0.05 * (end / start).log10());
        start / factor..end * factor
    } else {
        let pad = 0.05 * (end - start);
        start - pad..end + pad
    }
}

fn widen(lo: f64, hi: f64, log: bool) -> Range<f64> {
    if hi > lo {
        lo..hi
    } else if log {
        lo / 2.0..hi * 2.0
    } else {
        let half = if lo == 0.0 { 0.5 } else { 0.1 * lo.abs() };
        lo - half..hi + half
    }
}

fn render_xy(path: &Path, plot: &XyPlot) -> Result<(), PlotError> {
    prepare(path)?;
    let (xr, yr) = (plot.x_range.clone(), plot.y_range.clone());
    let linear = |r: Range<f64>| RangedCoordf64::from(r);
    // Widened by a hair so that a decade at an end of the range gets its tick despite rounding.
    let log =
        |r: Range<f64>| LogCoord::from((r.start * (1.0 - 1e-9)..r.end * (1.0 + 1e-9)).log_scale());
    match (plot.log_x, plot.log_y) {
        (false, false) => draw_xy(path, plot, linear(xr), linear(yr)),
        (true, false) => draw_xy(path, plot, log(xr), linear(yr)),
        (false, true) => draw_xy(path, plot, linear(xr), log(yr)),
        (true, true) => draw_xy(path, plot, log(xr), log(yr)),
    }
    .map_err(|e| draw_error(path, e))
}

fn draw_xy<X, Y>(path: &Path, plot: &XyPlot, x: X, y: Y) -> DrawResult
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let root = BitMapBackend::new(path, PLOT_SIZE).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(&plot.title, font(TITLE_SIZE))
        .margin(15)
        .margin_right(30)
        .x_label_area_size(55)
        .y_label_area_size(90)
        .build_cartesian_2d(x, y)?;
    let x_fmt = tick_formatter(&plot.x_range, plot.log_x, 10);
    let y_fmt = tick_formatter(&plot.y_range, plot.log_y, 10);
    chart
        .configure_mesh()
        .x_labels(10)
        .y_labels(10)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .x_desc(plot.x_label.as_str())
        .y_desc(plot.y_label.as_str())
        .label_style(font(LABEL_SIZE))
        .y_label_offset(Y_LABEL_NUDGE)
        .set_all_tick_mark_size(5)
        .axis_desc_style(font(DESC_SIZE))
        .bold_line_style(BLACK.mix(0.15))
        .light_line_style(BLACK.mix(0.05))
        .draw()?;

    let base = plot.y_range.start;
    chart.draw_series(plot.bars.iter().map(|&(x0, x1, h)| {
        Rectangle::new([(x0, base), (x1, h)], SERIES_COLOURS[0].mix(0.75).filled())
    }))?;
    chart.draw_series(
        plot.bars
            .iter()
            .map(|&(x0, x1, h)| Rectangle::new([(x0, base), (x1, h)], WHITE.stroke_width(1))),
    )?;

    let mut legend = false;
    for curve in &plot.curves {
        let colour = curve.colour;
        // Segment by segment: plotters joins the segments of a wide path with unbounded miters,
        // which shoot spikes across the figure at sharp turns (e.g. a spectrum's final drop).
        let anno = chart.draw_series(
            curve
                .points
                .windows(2)
                .map(|w| PathElement::new(vec![w[0], w[1]], colour.stroke_width(2))),
        )?;
        if !curve.label.is_empty() {
            legend = true;
            anno.label(curve.label.as_str()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3))
            });
        }
        if curve.markers {
            chart.draw_series(
                curve
                    .points
                    .iter()
                    .map(|&p| Circle::new(p, 3, colour.filled())),
            )?;
        }
    }

    let mark_colour = RGBColor(200, 30, 30);
    let mark_font = font(LABEL_SIZE).color(&mark_colour);
    // Greedy placement: each label takes the nearest free spot around its point (rings of
    // growing radius, eight directions, the preferred side first), free meaning inside the
    // plotting area and clear of the labels placed before it and of every marked point, so
    // that the leader stays short and labels of close peaks do not overlap.
    let (area_x, area_y) = chart.plotting_area().get_pixel_range();
    let centres: Vec<(i32, i32)> = plot
        .marks
        .iter()
        .map(|m| chart.backend_coord(&m.at))
        .collect();
    // The legend goes to the corner its box hides the least data in (curves sampled along
    // their segments, marks counting more), upper right on a tie; labels then avoid it.
    let legend_labels: Vec<&str> = plot
        .curves
        .iter()
        .map(|c| c.label.as_str())
        .filter(|l| !l.is_empty())
        .collect();
    let mut placed: Vec<[i32; 4]> = Vec::new();
    let mut legend_corner = SeriesLabelPosition::UpperRight;
    if !legend_labels.is_empty() {
        let legend_font = font(LABEL_SIZE);
        let mut w = 0;
        let mut th = 0;
        for l in &legend_labels {
            let (lw, lh) = root.estimate_text_size(l, &legend_font)?;
            w = w.max(lw as i32);
            th = th.max(lh as i32);
        }
        let (bw, bh) = (w + 50, legend_labels.len() as i32 * (th + 6) + 16);
        let (m, x0, x1, y0, y1) = (12, area_x.start, area_x.end, area_y.start, area_y.end);
        let corners = [
            (
                SeriesLabelPosition::UpperRight,
                [x1 - m - bw, y0 + m, x1 - m, y0 + m + bh],
            ),
            (
                SeriesLabelPosition::UpperLeft,
                [x0 + m, y0 + m, x0 + m + bw, y0 + m + bh],
            ),
            (
                SeriesLabelPosition::LowerRight,
                [x1 - m - bw, y1 - m - bh, x1 - m, y1 - m],
            ),
            (
                SeriesLabelPosition::LowerLeft,
                [x0 + m, y1 - m - bh, x0 + m + bw, y1 - m],
            ),
        ];
        let mut pixels: Vec<(i32, i32)> = Vec::new();
        for c in &plot.curves {
            let px: Vec<(i32, i32)> = c.points.iter().map(|p| chart.backend_coord(p)).collect();
            for pair in px.windows(2) {
                for k in 0..4 {
                    let t = f64::from(k) / 4.0;
                    let lerp =
                        |a: i32, b: i32| (f64::from(a) + t * f64::from(b - a)).round() as i32;
                    pixels.push((lerp(pair[0].0, pair[1].0), lerp(pair[0].1, pair[1].1)));
                }
            }
            pixels.extend(px.last().copied());
        }
        let inside =
            |b: &[i32; 4], (x, y): (i32, i32)| x >= b[0] && x <= b[2] && y >= b[1] && y <= b[3];
        let score = |b: &[i32; 4]| {
            pixels.iter().filter(|&&p| inside(b, p)).count()
                + 50 * centres.iter().filter(|&&p| inside(b, p)).count()
        };
        let mut best = (usize::MAX, 0);
        for (k, (_, b)) in corners.iter().enumerate() {
            let sc = score(b);
            if sc < best.0 {
                best = (sc, k);
            }
        }
        placed.push(corners[best.1].1);
        if let Some((corner, _)) = corners.into_iter().nth(best.1) {
            legend_corner = corner;
        }
    }
    for (mark, &(px, py)) in plot.marks.iter().zip(&centres) {
        let (w, h) = root.estimate_text_size(&mark.label, &mark_font)?;
        let (w, h) = (w as i32, h as i32);
        // The label's box relative to the point for an anchor (dx, dy): beside the anchor on
        // the side it points to, centred where it points straight up, down or sideways.
        let rel = |dx: i32, dy: i32| {
            let x0 = match dx.signum() {
                1 => dx,
                -1 => dx - w - 4,
                _ => -(w + 4) / 2,
            };
            let y0 = match dy.signum() {
                1 => dy,
                -1 => dy - h - 4,
                _ => -(h + 4) / 2,
            };
            [x0, y0, x0 + w + 4, y0 + h + 4]
        };
        let free = |r: &[i32; 4]| {
            let b = [px + r[0], py + r[1], px + r[2], py + r[3]];
            let inside = b[0] >= area_x.start
                && b[2] <= area_x.end
                && b[1] >= area_y.start
                && b[3] <= area_y.end;
            let clear_of_labels = placed
                .iter()
                .all(|o| b[2] < o[0] || o[2] < b[0] || b[3] < o[1] || o[3] < b[1]);
            let clear_of_points = centres
                .iter()
                .all(|&(cx, cy)| cx + 8 < b[0] || b[2] < cx - 8 || cy + 8 < b[1] || b[3] < cy - 8);
            inside && clear_of_labels && clear_of_points
        };
        let sx = if mark.left { -1 } else { 1 };
        let sy = if mark.below { 1 } else { -1 };
        let directions = [
            (sx, sy),
            (sx, 0),
            (-sx, sy),
            (-sx, 0),
            (0, sy),
            (sx, -sy),
            (-sx, -sy),
            (0, -sy),
        ];
        let mut choice = None;
        'search: for radius in [12, 26, 44, 66, 92, 122] {
            for (ux, uy) in directions {
                // Diagonals at the same distance as the axes.
                let k = if ux != 0 && uy != 0 { 0.7 } else { 1.0 };
                let d = (k * f64::from(radius)).round() as i32;
                let anchor = (ux * d, uy * d);
                let r = rel(anchor.0, anchor.1);
                if free(&r) {
                    choice = Some((anchor, r));
                    break 'search;
                }
            }
        }
        let (anchor, r) = choice.unwrap_or_else(|| {
            let a = (18 * sx, (24 + 22 * mark.level) * sy);
            (a, rel(a.0, a.1))
        });
        placed.push([px + r[0], py + r[1], px + r[2], py + r[3]]);
        let leader = if anchor.0.abs().max(anchor.1.abs()) > 12 {
            vec![(0, 0), anchor]
        } else {
            Vec::new()
        };
        chart.draw_series(std::iter::once(
            EmptyElement::at(mark.at)
                + Circle::new((0, 0), 7, mark_colour.stroke_width(2))
                + PathElement::new(leader, mark_colour.stroke_width(1))
                + Rectangle::new([(r[0], r[1]), (r[2], r[3])], WHITE.mix(0.8).filled())
                + Text::new(
                    mark.label.clone(),
                    (r[0] + 2, (r[1] + r[3]) / 2 + Y_LABEL_NUDGE),
                    mark_font.clone().pos(Pos::new(HPos::Left, VPos::Center)),
                ),
        ))?;
    }

    if legend {
        chart
            .configure_series_labels()
            .position(legend_corner)
            .margin(12)
            .label_font(font(LABEL_SIZE))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()?;
    }

    if !plot.note.is_empty() {
        let (px, py) = chart.plotting_area().get_pixel_range();
        let style = font(LABEL_SIZE).pos(Pos::new(HPos::Right, VPos::Top));
        for (k, line) in plot.note.iter().enumerate() {
            root.draw_text(line, &style, (px.end - 12, py.start + 10 + 22 * k as i32))?;
        }
    }
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

    /// A fresh directory under the system temporary directory.
    fn temp_dir(name: &str) -> PathBuf {
        use std::sync::atomic::AtomicUsize;
        static COUNTER: AtomicUsize = AtomicUsize::new(0);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!(
            "m1cs-plot-{name}-{}-{nanos}-{}",
            std::process::id(),
            COUNTER.fetch_add(1, Ordering::SeqCst)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn assert_png(path: &Path) {
        let bytes = std::fs::read(path).unwrap();
        assert!(
            bytes.len() > 1000,
            "{} is only {} bytes",
            path.display(),
            bytes.len()
        );
        assert_eq!(bytes[..8], PNG_SIGNATURE, "{} is not a PNG", path.display());
    }

    #[test]
    fn mirror_map_writes_a_png() {
        let layout = Layout::keck();
        let values: Vec<f64> = layout.segments.iter().map(|s| s.center[0]).collect();
        let dir = temp_dir("map");
        let path = dir.join("map.png");
        mirror_map(&path, &layout, &values, "Keck: x", "m").unwrap();
        assert_png(&path);
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn mirror_map_ptt_writes_a_png() {
        let layout = Layout::keck();
        let ptt: Vec<[f64; 3]> = layout
            .segments
            .iter()
            .map(|s| [0.0, s.center[0] / 100.0, s.center[1] / 100.0])
            .collect();
        let dir = temp_dir("ptt");
        let path = dir.join("sub").join("ptt.png");
        mirror_map_ptt(&path, &layout, &ptt, "Keck: focus-like tilts", "m").unwrap();
        assert_png(&path);
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn maps_check_the_number_of_values() {
        let layout = Layout::keck();
        let dir = temp_dir("size");
        let path = dir.join("bad.png");
        let err = mirror_map(&path, &layout, &[1.0; 35], "bad", "m").unwrap_err();
        assert!(
            matches!(
                err,
                PlotError::Length {
                    got: 35,
                    expected: 36,
                    ..
                }
            ),
            "{err}"
        );
        let err = mirror_map_ptt(&path, &layout, &[[0.0; 3]; 37], "bad", "m").unwrap_err();
        assert!(
            matches!(
                err,
                PlotError::Length {
                    got: 37,
                    expected: 36,
                    ..
                }
            ),
            "{err}"
        );
        let mut values = vec![0.0; 36];
        values[3] = f64::NAN;
        assert!(matches!(
            mirror_map(&path, &layout, &values, "bad", "m"),
            Err(PlotError::Invalid(_))
        ));
        assert!(!path.exists());
        std::fs::remove_dir_all(dir).ok();
    }

    #[test]
    fn uniform_map_draws() {
        // All zeros: the colour scale must not divide by zero.
        let layout = Layout::keck();
        let dir = temp_dir("zeros");
        let path = dir.join("zeros.png");
        mirror_map(&path, &layout, &[0.0; 36], "zeros", "").unwrap();
        assert_png(&path);
        std::fs::remove_dir_all(dir).ok();
    }

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

    #[test]
    fn tick_labels() {
        assert_eq!(linear_tick(0.5, 0.1, 1.0), "0.5");
        assert_eq!(linear_tick(10.0, 5.0, 20.0), "10");
        assert_eq!(linear_tick(1e-17, 0.1, 1.0), "0");
        assert_eq!(linear_tick(-2.5e-9, 5e-10, 3e-9), "-2.5e-9");
        assert_eq!(linear_tick(2e-9, 5e-10, 3e-9), "2e-9");
        assert_eq!(log_tick(1e-9), "1e-9");
        assert_eq!(log_tick(0.01), "0.01");
        assert_eq!(log_tick(300.0), "300");
    }

    #[test]
    fn colour_map_is_symmetric() {
        assert_eq!(diverging(0.0, 1.0), RGBColor(247, 247, 247));
        assert_eq!(diverging(-1.0, 1.0), RGBColor(5, 48, 97));
        assert_eq!(diverging(2.0, 1.0), RGBColor(103, 0, 31));
        assert_eq!(diverging(1.0, 0.0), RGBColor(247, 247, 247));
    }
}
