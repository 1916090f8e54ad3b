//! Mirror maps: one value per segment ([`mirror_map`]) or piston/tip/tilt surfaces
//! ([`mirror_map_ptt`]), seen from the sky with an equal aspect ratio, on the diverging colour
//! map with its colour bar.

use std::ops::Range;
use std::path::Path;

use m1::aperture::layout::Layout;
use plotters::coord::ReverseCoordTranslate;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::{
    DESC_SIZE, DrawResult, LABEL_SIZE, MAP_SIZE, PlotError, Root, TITLE_SIZE, Y_LABEL_NUDGE,
    diverging, draw_error, font, prepare, tick_formatter,
};

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

/// Margin around the map and the colour bar (pixels).
const MARGIN: u32 = 15;
/// Height of the x tick labels and description (pixels).
const X_LABELS: u32 = 50;
/// Width of the y tick labels and description (pixels).
const Y_LABELS: u32 = 70;
/// Width of the colour bar's area (pixels).
const BAR_AREA: u32 = 170;
/// Room above the colour bar for its unit (pixels).
const BAR_TOP: u32 = 40;
/// Colour steps of the bar.
const BAR_STEPS: usize = 256;

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
    let (map_w, _) = map_area.dim_in_pixel();
    let (x_range, y_range) = map_ranges(layout, map_w, height);
    let mut chart = ChartBuilder::on(&map_area)
        .margin(MARGIN)
        .x_label_area_size(X_LABELS)
        .y_label_area_size(Y_LABELS)
        .build_cartesian_2d(x_range.clone(), y_range.clone())?;
    draw_map_axes(&mut chart, &x_range, &y_range)?;
    body(&mut chart, &root)?;
    draw_colour_bar(&bar_area, vmax, unit)?;
    root.present()?;
    Ok(())
}

/// Equal aspect: one scale (m per pixel) on both axes over a map area `map_w` by `height`
/// pixels, the layout centred with 2 % room.
fn map_ranges(layout: &Layout, map_w: u32, height: u32) -> (Range<f64>, Range<f64>) {
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
    let plot_w = f64::from(map_w.saturating_sub(2 * MARGIN + Y_LABELS).max(1));
    let plot_h = f64::from(height.saturating_sub(2 * MARGIN + X_LABELS).max(1));
    let scale = ((x1 - x0 + 2.0 * pad) / plot_w).max((y1 - y0 + 2.0 * pad) / plot_h);
    let (xc, yc) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
    let x_range = xc - scale * plot_w / 2.0..xc + scale * plot_w / 2.0;
    let y_range = yc - scale * plot_h / 2.0..yc + scale * plot_h / 2.0;
    (x_range, y_range)
}

/// The map's axes in metres, without a mesh.
fn draw_map_axes(
    chart: &mut MapChart<'_, '_>,
    x_range: &Range<f64>,
    y_range: &Range<f64>,
) -> DrawResult {
    let x_fmt = tick_formatter(x_range, false, 10);
    let y_fmt = tick_formatter(y_range, false, 10);
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
    Ok(())
}

/// The colour bar over `[-vmax, vmax]` in `bar_area`, its top and bottom level with the map's
/// plotting area, `unit` above it.
fn draw_colour_bar(bar_area: &Root<'_>, vmax: f64, unit: &str) -> DrawResult {
    let mut bar = ChartBuilder::on(bar_area)
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
    bar.draw_series((0..BAR_STEPS).map(|k| {
        let lo = -vmax + 2.0 * vmax * k as f64 / BAR_STEPS as f64;
        let hi = -vmax + 2.0 * vmax * (k + 1) as f64 / BAR_STEPS as f64;
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
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plot::testing::{assert_png, temp_dir};

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
}
