//! Layouts as JSON documents.
//!
//! ```json
//! {
//!   "name": "my-mirror",
//!   "circumradius": 0.72,
//!   "gap": 0.0025,
//!   "radius_of_curvature": 60.0,
//!   "conic": -1.000953,
//!   "segments": [
//!     { "name": "S1", "x": 1.24958, "y": 0.0 },
//!     { "name": "S2", "x": 0.62479, "y": 1.08217, "hex": [0, 1, -1] }
//!   ]
//! }
//! ```
//!
//! Lengths are in metres, in the aperture-plane frame of the [module documentation](super).
//! `radius_of_curvature` may be `null` or absent for a flat mirror, and `conic` absent (0).
//! `hex` (cube coordinates on the grid of pitch `sqrt(3) a + gap`) is optional; when given, `x`
//! and `y` must agree with it (to 1e-6 of the pitch) and the segment is placed exactly at its
//! grid position. Unknown fields are rejected. Shared edges are not stored: they are found from the centres (centre distance
//! within 1 % of the pitch). The document is validated as by [`Layout::from_segments`].

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::{Layout, LayoutError, Segment};

/// The JSON document.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct LayoutFile {
    name: String,
    circumradius: f64,
    gap: f64,
    #[serde(default)]
    radius_of_curvature: Option<f64>,
    #[serde(default)]
    conic: f64,
    segments: Vec<SegmentFile>,
}

/// One segment of the JSON document.
#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentFile {
    name: String,
    x: f64,
    y: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    hex: Option<[i32; 3]>,
}

impl Layout {
    /// A layout from a JSON document (format in the [`json`](self) module documentation).
    pub fn from_json_str(s: &str) -> Result<Layout, LayoutError> {
        let file: LayoutFile =
            serde_json::from_str(s).map_err(|source| LayoutError::Json { path: None, source })?;
        Layout::from_file_document(file)
    }

    /// A layout from a JSON file (format in the [`json`](self) module documentation).
    pub fn from_json_file(path: &Path) -> Result<Layout, LayoutError> {
        let text = std::fs::read_to_string(path).map_err(|source| LayoutError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let file: LayoutFile = serde_json::from_str(&text).map_err(|source| LayoutError::Json {
            path: Some(path.to_path_buf()),
            source,
        })?;
        Layout::from_file_document(file)
    }

    /// The layout as a pretty-printed JSON document that [`Layout::from_json_str`] reads back
    /// into the same layout. Grid segments (with `hex`) come back bit for bit; other centres
    /// to the last bit only if `serde_json`'s `float_roundtrip` feature is enabled (without it
    /// the parser may be 1 ulp off on 17-digit numbers).
    pub fn to_json_string(&self) -> String {
        let file = LayoutFile {
            name: self.name.clone(),
            circumradius: self.circumradius,
            gap: self.gap,
            radius_of_curvature: self
                .radius_of_curvature
                .is_finite()
                .then_some(self.radius_of_curvature),
            conic: self.conic,
            segments: self
                .segments
                .iter()
                .map(|s| SegmentFile {
                    name: s.name.clone(),
                    x: s.center[0],
                    y: s.center[1],
                    hex: s.hex,
                })
                .collect(),
        };
        // Serialising plain structs of strings and numbers into a String cannot fail.
        serde_json::to_string_pretty(&file).unwrap_or_default()
    }

    /// Writes [`Layout::to_json_string`] to `path`.
    pub fn write_json_file(&self, path: &Path) -> Result<(), LayoutError> {
        std::fs::write(path, self.to_json_string()).map_err(|source| LayoutError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    fn from_file_document(file: LayoutFile) -> Result<Layout, LayoutError> {
        let segments = file
            .segments
            .into_iter()
            .map(|s| Segment {
                name: s.name,
                center: [s.x, s.y],
                hex: s.hex,
            })
            .collect();
        Layout::from_segments(
            file.name,
            segments,
            file.circumradius,
            file.gap,
            file.radius_of_curvature.unwrap_or(f64::INFINITY),
            file.conic,
        )
    }
}
