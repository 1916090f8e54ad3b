//! The x-y figure every line plot, spectrum and histogram is drawn as: an [`XyPlot`] (axes,
//! bars, curves, marked points, a corner note) rendered on linear or logarithmic axes by
//! [`render_xy`]. [`draw_xy`] draws it in phases: the axes, the bars, the curves, the legend's
//! corner (where it hides the least data), the marks with their labels placed clear of one
//! another ([`LabelSpace`]), the legend and the note.

use std::error::Error;
use std::ops::Range;
use std::path::Path;

use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::{
    DESC_SIZE, DrawResult, LABEL_SIZE, PLOT_SIZE, PlotError, Root, SERIES_COLOURS, TITLE_SIZE,
    Y_LABEL_NUDGE, draw_error, font, linear_tick, prepare, tick_formatter,
};

/// One curve of an x-y plot.
pub(super) struct Curve {
    pub(super) label: String,
    pub(super) points: Vec<(f64, f64)>,
    pub(super) colour: RGBColor,
    pub(super) markers: bool,
}

/// A labelled point.
pub(super) struct Mark {
    pub(super) at: (f64, f64),
    pub(super) label: String,
    /// Label to the left of the point (the point is in the right part of the plot).
    pub(super) left: bool,
    /// Label below the point (the point is in the upper part of the plot).
    pub(super) below: bool,
    /// Stacking level of the label, to keep close labels apart.
    pub(super) level: i32,
}

/// Everything an x-y figure shows.
pub(super) struct XyPlot {
    pub(super) title: String,
    pub(super) x_label: String,
    pub(super) y_label: String,
    pub(super) log_x: bool,
    pub(super) log_y: bool,
    pub(super) x_range: Range<f64>,
    pub(super) y_range: Range<f64>,
    pub(super) curves: Vec<Curve>,
    pub(super) marks: Vec<Mark>,
    /// Histogram bars `(x0, x1, height)`, drawn from the bottom of the y range.
    pub(super) bars: Vec<(f64, f64, f64)>,
    /// Lines of text in the top-right corner.
    pub(super) note: Vec<String>,
}

/// `v` with a few more digits than the axis ticks (for the histogram's note).
#[cfg_attr(not(test), allow(dead_code))]
pub(super) fn significant(v: f64, step: f64, magnitude: f64) -> String {
    linear_tick(v, step / 100.0, magnitude)
}

/// Range of `values`, widened when degenerate (x axes: no padding).
pub(super) fn data_range(values: impl Iterator<Item = f64>, log: bool) -> Range<f64> {
    let (lo, hi) = values.fold((f64::MAX, f64::MIN), |(l, h), v| (l.min(v), h.max(v)));
    widen(lo, hi, log)
}

/// Range of `values` with 5 % room at both ends (of the decades on a log axis).
pub(super) fn padded_range(values: impl Iterator<Item = f64>, log: bool) -> Range<f64> {
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

/// `lo..hi`, widened when empty: by a factor 2 on a log axis, by 10 % of |lo| (or 0.5 about 0)
/// otherwise.
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

pub(super) fn render_xy(path: &Path, plot: &XyPlot) -> Result<(), PlotError> {
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

/// The chart of an x-y figure.
type XyChart<'a, 'b, X, Y> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<X, Y>>;

/// Colour of the marks and their labels.
const MARK_COLOUR: RGBColor = RGBColor(200, 30, 30);

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
    draw_axes(&mut chart, plot)?;
    draw_bars(&mut chart, plot)?;
    let legend = draw_curves(&mut chart, plot)?;
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
    let mut space = LabelSpace {
        area_x,
        area_y,
        centres,
        placed: Vec::new(),
    };
    // The legend goes to the corner its box hides the least data in, upper right on a tie;
    // labels then avoid it.
    let mut legend_corner = SeriesLabelPosition::UpperRight;
    if let Some((corner, bounds)) = legend_box(&root, &chart, plot, &space)? {
        space.placed.push(bounds);
        legend_corner = corner;
    }
    draw_marks(&root, &mut chart, plot, &mut space)?;
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
    draw_note(&root, &chart, plot)?;
    root.present()?;
    Ok(())
}

/// The axes: ticks, descriptions and a light grid.
fn draw_axes<X, Y>(chart: &mut XyChart<'_, '_, X, Y>, plot: &XyPlot) -> DrawResult
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
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
    Ok(())
}

/// The histogram bars, filled and outlined in white, from the bottom of the y range.
fn draw_bars<X, Y>(chart: &mut XyChart<'_, '_, X, Y>, plot: &XyPlot) -> DrawResult
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let base = plot.y_range.start;
    chart.draw_series(plot.bars.iter().map(|&(x0, x1, h)| {
        Rectangle::new([(x0, base), (x1, h)], SERIES_COLOURS[0].mix(0.75).filled())
    }))?;
    chart.draw_series(
        plot.bars
            .iter()
            .map(|&(x0, x1, h)| Rectangle::new([(x0, base), (x1, h)], WHITE.stroke_width(1))),
    )?;
    Ok(())
}

/// The curves with their markers, each labelled one entering the legend; whether any did.
fn draw_curves<X, Y>(
    chart: &mut XyChart<'_, '_, X, Y>,
    plot: &XyPlot,
) -> Result<bool, Box<dyn Error>>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
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
    Ok(legend)
}

/// A legend's corner and its box `[x0, y0, x1, y1]` (pixels).
type LegendBox = (SeriesLabelPosition, [i32; 4]);

/// The corner and pixel box of the legend (none without labelled curves): the corner whose box
/// hides the least data (curves sampled along their segments, marks counting more), upper
/// right on a tie.
fn legend_box<X, Y>(
    root: &Root<'_>,
    chart: &XyChart<'_, '_, X, Y>,
    plot: &XyPlot,
    space: &LabelSpace,
) -> Result<Option<LegendBox>, Box<dyn Error>>
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let legend_labels: Vec<&str> = plot
        .curves
        .iter()
        .map(|c| c.label.as_str())
        .filter(|l| !l.is_empty())
        .collect();
    if legend_labels.is_empty() {
        return Ok(None);
    }
    let legend_font = font(LABEL_SIZE);
    let mut w = 0;
    let mut th = 0;
    for l in &legend_labels {
        let (lw, lh) = root.estimate_text_size(l, &legend_font)?;
        w = w.max(lw as i32);
        th = th.max(lh as i32);
    }
    let (bw, bh) = (w + 50, legend_labels.len() as i32 * (th + 6) + 16);
    let (area_x, area_y) = (&space.area_x, &space.area_y);
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
                let lerp = |a: i32, b: i32| (f64::from(a) + t * f64::from(b - a)).round() as i32;
                pixels.push((lerp(pair[0].0, pair[1].0), lerp(pair[0].1, pair[1].1)));
            }
        }
        pixels.extend(px.last().copied());
    }
    let inside =
        |b: &[i32; 4], (x, y): (i32, i32)| x >= b[0] && x <= b[2] && y >= b[1] && y <= b[3];
    let score = |b: &[i32; 4]| {
        pixels.iter().filter(|&&p| inside(b, p)).count()
            + 50 * space.centres.iter().filter(|&&p| inside(b, p)).count()
    };
    let mut best = (usize::MAX, 0);
    for (k, (_, b)) in corners.iter().enumerate() {
        let sc = score(b);
        if sc < best.0 {
            best = (sc, k);
        }
    }
    Ok(corners.into_iter().nth(best.1))
}

/// Where the labels of the marks may go: the plotting area (pixels), the marked points, and
/// the boxes taken so far (the legend's, then each label's).
struct LabelSpace {
    area_x: Range<i32>,
    area_y: Range<i32>,
    centres: Vec<(i32, i32)>,
    placed: Vec<[i32; 4]>,
}

impl LabelSpace {
    /// Radii of the rings of candidate anchors around a point (pixels).
    const RINGS: [i32; 6] = [12, 26, 44, 66, 92, 122];

    /// The anchor of the label of `mark` at pixel `(px, py)` (relative to it) and the label's
    /// box (relative too) for a label of `w` by `h` pixels: the nearest free candidate, else
    /// a fallback stacked by the mark's level. The box is then taken.
    fn place(&mut self, mark: &Mark, (px, py): (i32, i32), (w, h): (i32, i32)) -> LabelPlace {
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
            let inside = b[0] >= self.area_x.start
                && b[2] <= self.area_x.end
                && b[1] >= self.area_y.start
                && b[3] <= self.area_y.end;
            let clear_of_labels = self
                .placed
                .iter()
                .all(|o| b[2] < o[0] || o[2] < b[0] || b[3] < o[1] || o[3] < b[1]);
            let clear_of_points = self
                .centres
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
        'search: for radius in Self::RINGS {
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
        self.placed
            .push([px + r[0], py + r[1], px + r[2], py + r[3]]);
        LabelPlace { anchor, bounds: r }
    }
}

/// A label's place relative to its point (pixels).
struct LabelPlace {
    /// Where the leader ends.
    anchor: (i32, i32),
    /// The label's box `[x0, y0, x1, y1]`.
    bounds: [i32; 4],
}

/// Each mark circled, with a leader to its label placed by `space`.
fn draw_marks<X, Y>(
    root: &Root<'_>,
    chart: &mut XyChart<'_, '_, X, Y>,
    plot: &XyPlot,
    space: &mut LabelSpace,
) -> DrawResult
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let mark_font = font(LABEL_SIZE).color(&MARK_COLOUR);
    for (k, mark) in plot.marks.iter().enumerate() {
        let (w, h) = root.estimate_text_size(&mark.label, &mark_font)?;
        let place = space.place(mark, space.centres[k], (w as i32, h as i32));
        let (anchor, r) = (place.anchor, place.bounds);
        let leader = if anchor.0.abs().max(anchor.1.abs()) > 12 {
            vec![(0, 0), anchor]
        } else {
            Vec::new()
        };
        chart.draw_series(std::iter::once(
            EmptyElement::at(mark.at)
                + Circle::new((0, 0), 7, MARK_COLOUR.stroke_width(2))
                + PathElement::new(leader, MARK_COLOUR.stroke_width(1))
                + Rectangle::new([(r[0], r[1]), (r[2], r[3])], WHITE.mix(0.8).filled())
                + Text::new(
                    mark.label.clone(),
                    (r[0] + 2, (r[1] + r[3]) / 2 + Y_LABEL_NUDGE),
                    mark_font.clone().pos(Pos::new(HPos::Left, VPos::Center)),
                ),
        ))?;
    }
    Ok(())
}

/// The note's lines in the top-right corner of the plotting area.
fn draw_note<X, Y>(root: &Root<'_>, chart: &XyChart<'_, '_, X, Y>, plot: &XyPlot) -> DrawResult
where
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    if !plot.note.is_empty() {
        let (px, py) = chart.plotting_area().get_pixel_range();
        let style = font(LABEL_SIZE).pos(Pos::new(HPos::Right, VPos::Top));
        for (k, line) in plot.note.iter().enumerate() {
            root.draw_text(line, &style, (px.end - 12, py.start + 10 + 22 * k as i32))?;
        }
    }
    Ok(())
}
