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
//!
//! # Layout
//!
//! This module holds what every figure shares: sizes, the font, errors, colours and tick
//! labels. The figures, by kind: [`maps`] (mirror maps), [`lines`](mod@lines) (spectra and line plots),
//! [`bars`] (histograms), all but the maps drawn by [`xy`] (axes, bars, curves, legend, marked
//! points and their labels, a corner note).

mod bars;
mod lines;
mod maps;
mod xy;

// No command draws a histogram at present; the figure is kept (and tested) for those that will.
#[allow(unused_imports)]
pub use bars::histogram;
pub use lines::{ColouredSeries, PointMark, lines, lines_in_colours, lines_marked, spectrum};
pub use maps::{mirror_map, mirror_map_ptt};

use std::error::Error;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Once;
use std::sync::atomic::{AtomicBool, Ordering};

use plotters::prelude::*;

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
static FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
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

/// The drawing area of a whole figure.
type Root<'b> = DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>;

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

#[cfg(test)]
pub(super) mod testing {
    //! What the figures' tests share: a fresh directory, and a check that a file is a PNG.
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use std::path::{Path, PathBuf};
    use std::sync::atomic::Ordering;

    const PNG_SIGNATURE: [u8; 8] = [0x89, b'P', b'N', b'G', 0x0d, 0x0a, 0x1a, 0x0a];

    /// A fresh directory under the system temporary directory.
    pub(super) fn temp_dir(name: &str) -> PathBuf {
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

    pub(super) fn assert_png(path: &Path) {
        let bytes = std::fs::read(path).unwrap();
        assert!(
            bytes.len() > 1000,
            "{} is only {} bytes",
            path.display(),
            bytes.len()
        );
        assert_eq!(bytes[..8], PNG_SIGNATURE, "{} is not a PNG", path.display());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
