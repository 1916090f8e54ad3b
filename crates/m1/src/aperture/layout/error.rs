//! Errors raised while building, validating or reading a mirror layout.

use std::path::PathBuf;

use thiserror::Error;

/// Why a layout could not be built, validated or read. Every variant names the quantity or the
/// segments at fault.
#[derive(Debug, Error)]
pub enum LayoutError {
    /// The layout has no segment at all.
    #[error("layout `{name}` has no segments")]
    Empty {
        /// Name of the layout.
        name: String,
    },
    /// A number that must be finite is NaN or infinite.
    #[error("{what} must be a finite number, got {value}")]
    NonFinite {
        /// What the number is (e.g. `circumradius`, `x of segment S3`).
        what: String,
        /// The offending value.
        value: f64,
    },
    /// A number is finite but outside its allowed range.
    #[error("{what} = {value} is out of range: it must be {expected}")]
    OutOfRange {
        /// What the number is.
        what: String,
        /// The offending value.
        value: f64,
        /// The allowed range, e.g. `> 0`.
        expected: &'static str,
    },
    /// The ring numbers of a hexagonal layout are inconsistent.
    #[error(
        "invalid hexagonal grid: rings = {rings}, hole_rings = {hole_rings} \
         (need hole_rings < rings <= {max_rings})"
    )]
    InvalidRings {
        /// Outermost hex ring requested.
        rings: u32,
        /// Number of central rings left empty (the centre counts as ring 0).
        hole_rings: u32,
        /// Largest number of rings accepted.
        max_rings: u32,
    },
    /// A segment has an empty name.
    #[error("segment #{index} has an empty name")]
    EmptyName {
        /// Index of the segment.
        index: usize,
    },
    /// Two segments have the same name.
    #[error("duplicate segment name `{name}` (segments #{first} and #{second})")]
    DuplicateName {
        /// The repeated name.
        name: String,
        /// Index of its first occurrence.
        first: usize,
        /// Index of its second occurrence.
        second: usize,
    },
    /// Two hexagonal segments overlap.
    #[error(
        "segments `{first}` (#{i}) and `{second}` (#{j}) overlap: their centres are {distance:.6} m \
         apart, {separation:.6} m along the closest edge normal, less than the segment \
         flat-to-flat width {width:.6} m"
    )]
    Overlap {
        /// Index of the first segment.
        i: usize,
        /// Index of the second segment.
        j: usize,
        /// Name of the first segment.
        first: String,
        /// Name of the second segment.
        second: String,
        /// Centre-to-centre distance (m).
        distance: f64,
        /// Largest projection of the centre offset on the three edge-normal directions (m).
        separation: f64,
        /// Flat-to-flat width sqrt(3) a of a segment (m).
        width: f64,
    },
    /// A segment's hex (cube) coordinates are invalid or disagree with its centre.
    #[error("segment `{name}`: hex coordinates {hex:?} {reason}")]
    InvalidHex {
        /// Name of the segment.
        name: String,
        /// The cube coordinates given.
        hex: [i32; 3],
        /// What is wrong with them.
        reason: String,
    },
    /// `Layout::preset` was given a name it does not know.
    #[error("unknown layout preset `{name}`; known presets: {known:?}")]
    UnknownPreset {
        /// The name asked for.
        name: String,
        /// The names accepted (case-insensitive).
        known: &'static [&'static str],
    },
    /// A layout file could not be read or written.
    #[error("I/O error on layout file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A layout document is not valid JSON or does not have the expected fields.
    #[error("invalid layout JSON{}: {source}", path.as_ref().map(|p| format!(" in {}", p.display())).unwrap_or_default())]
    Json {
        /// The file the document came from, if any.
        path: Option<PathBuf>,
        /// The parser's error (with line and column).
        #[source]
        source: serde_json::Error,
    },
}
