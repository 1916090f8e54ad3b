//! Segmented primary-mirror layouts: where each hexagonal segment sits, its name, and which
//! segments share an edge. This module is the single source of truth for a mirror's size: the
//! number of segments `N`, of actuators `na = 3 N` and of edge sensors `ns = 2 x` shared edges.
//!
//! # Conventions
//!
//! - **Coordinates** are in metres in the aperture plane (the mirror seen from the sky, looking
//!   down its optical axis), origin on the optical axis, `x` and `y` forming a right-handed
//!   frame with `z` towards the sky. Angles are measured counter-clockwise from +x.
//! - **Segments** are identical regular hexagons of circumradius `a` (centre to corner), all with
//!   the same orientation: *pointy-topped*, corners at 30, 90, ..., 330 degrees (a corner on +y)
//!   and flat sides facing 0, 60, ..., 300 degrees (a flat side facing +x).
//! - **Grid**: neighbouring centres are one *pitch* `p = sqrt(3) a + gap` apart along the side
//!   normals 0, 60, ..., 300 degrees. Grid layouts carry cube coordinates `[q, r, s]`
//!   (`q + r + s = 0`) with centre `x = p (q + r/2)`, `y = p sqrt(3)/2 r` (see [`hex`]).
//! - **Shared edges**: two segments share an edge when their centre distance is within 1 %
//!   ([`EDGE_TOLERANCE`]) of the pitch. An [`Edge`] has `i < j` and the in-plane unit normal
//!   from segment `i` towards segment `j`; edges are sorted by `(i, j)`. There are two edge
//!   sensors per shared edge.
//! - **Overlap**: a layout whose hexagons overlap (by more than [`OVERLAP_TOLERANCE`] of the
//!   flat-to-flat width) is rejected.
//! - **Optics**: `radius_of_curvature` `R` (m, > 0, concave towards the sky;
//!   `f64::INFINITY` = flat) and `conic` constant `k` of the parent surface
//!   `z = r^2 / (R (1 + sqrt(1 - (1 + k) r^2 / R^2)))`.
//!
//! # Presets
//!
//! - [`Layout::tmt`]: the Thirty Meter Telescope, 492 segments in six sectors `A`..`F` of 82.
//!   The sectors are 60-degree wedges running counter-clockwise: sector A spans the polar angles
//!   (60, 120] degrees (it is centred on +y), B (120, 180], ..., F (0, 60]; each sector is sector
//!   A rotated by a multiple of 60 degrees. Within a sector, segments are numbered 1..82 ring by
//!   ring outward (sector ring `k` lies on hex ring `k + 1`), and within a ring *clockwise*,
//!   starting at the ring's corner on the A/B (120 degree) boundary; so `A1` is the corner of hex
//!   ring 2 at 120 degrees and `A2` sits on +y. Rings 1..10 are complete (`k + 1` segments);
//!   ring 11 lacks its corner (11 segments) and ring 12 holds the 6 middle positions of hex ring
//!   13. Segment `<sector><n>` has index `sector * 82 + n - 1` (`A1` = 0, `F82` = 491).
//!   This reproduces TMT's published neighbour lists (e.g. `A15` borders `A10`, `A16`, `A21`,
//!   `A22`, `B20` and `B27`).
//! - [`Layout::keck`]: Keck, 36 segments on hex rings 1..3, named `"1"`..`"36"` ring by ring
//!   outward (ring 1: 1..6, ring 2: 7..18, ring 3: 19..36), each ring counter-clockwise starting
//!   at its corner on +x (segment 1 at `(p, 0)`).
//! - [`Layout::elt`]: an ELT-like mirror of 798 segments (six 60-degree sectors of 133): hex
//!   rings 5..17 with centres closer than 18.8 m to the axis.
//! - [`Layout::hexagonal`]: any hex grid with a central hole and an optional radius cut,
//!   numbered `S1`, `S2`, ... ring by ring outward, each ring counter-clockwise from its corner
//!   on +x.
//! - [`Layout::from_json_str`] / [`Layout::from_json_file`]: a user layout (see the [`json`]
//!   module for the format).
//! - [`Layout::load`]: a preset or a JSON file by name, as the command line takes `--layout`
//!   ([`DEFAULT_LAYOUT`] when none is given).

pub mod error;
pub mod hex;
pub mod json;

mod edges;
mod presets;

use std::collections::BTreeMap;

pub use error::LayoutError;
pub use presets::{
    ELT_CIRCUMRADIUS, ELT_CONIC, ELT_GAP, ELT_HOLE_RINGS, ELT_MAX_RADIUS, ELT_RADIUS_OF_CURVATURE,
    ELT_RINGS, KECK_CIRCUMRADIUS, KECK_CONIC, KECK_GAP, KECK_RADIUS_OF_CURVATURE, KECK_RINGS,
    TMT_CIRCUMRADIUS, TMT_CONIC, TMT_GAP, TMT_RADIUS_OF_CURVATURE, TMT_SECTOR_SIZE, TMT_SECTORS,
};

/// Relative tolerance on the pitch within which two centres are said to share an edge (1 %).
pub const EDGE_TOLERANCE: f64 = 0.01;

/// Overlap allowed between two segments before a layout is rejected, as a fraction of the
/// flat-to-flat width `sqrt(3) a` (1e-4, i.e. 0.12 mm for TMT): room for rounded coordinates.
pub const OVERLAP_TOLERANCE: f64 = 1e-4;

/// Largest distance between a segment's given centre and the grid position of its hex
/// coordinates, as a fraction of the pitch (1e-6, about 1 um): the hex coordinates are
/// authoritative, the centre only confirms them.
pub const HEX_TOLERANCE: f64 = 1e-6;

/// Largest number of hex rings [`Layout::hexagonal`] accepts (3 R (R + 1) segments at most).
pub const MAX_RINGS: u32 = 1000;

/// The layout the tools use when none is named: the Thirty Meter Telescope ([`Layout::tmt`]).
pub const DEFAULT_LAYOUT: &str = "tmt";

/// One hexagonal mirror segment.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Unique name, e.g. `A1` (TMT), `17` (Keck) or `S5`.
    pub name: String,
    /// Centre `[x, y]` in the aperture plane (m).
    pub center: [f64; 2],
    /// Cube coordinates `[q, r, s]` on the layout's hex grid, when the segment is on one.
    pub hex: Option<[i32; 3]>,
}

/// An edge shared by two segments; it carries two edge sensors.
#[derive(Debug, Clone, PartialEq)]
pub struct Edge {
    /// Index of the first segment (`i < j`).
    pub i: usize,
    /// Index of the second segment.
    pub j: usize,
    /// In-plane unit normal of the edge, from segment `i` towards segment `j`.
    pub normal: [f64; 2],
}

/// A segmented mirror: segments, shared edges, segment size and optical prescription.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    /// Name of the layout (e.g. `tmt`).
    pub name: String,
    /// The segments; their index is the segment index used everywhere else.
    pub segments: Vec<Segment>,
    /// Shared edges, sorted by `(i, j)`.
    pub edges: Vec<Edge>,
    /// Segment circumradius `a`, centre to corner (m).
    pub circumradius: f64,
    /// Gap between the facing sides of neighbouring segments (m).
    pub gap: f64,
    /// Radius of curvature `R` of the parent surface (m); `f64::INFINITY` for a flat mirror.
    pub radius_of_curvature: f64,
    /// Conic constant `k` of the parent surface.
    pub conic: f64,
}

impl Layout {
    /// Names accepted by [`Layout::preset`].
    pub const PRESETS: &'static [&'static str] = &["keck", "tmt", "elt"];

    /// The preset layout called `name` (`"keck"`, `"tmt"` or `"elt"`, case-insensitive,
    /// surrounding white space ignored).
    pub fn preset(name: &str) -> Result<Layout, LayoutError> {
        match name.trim().to_ascii_lowercase().as_str() {
            "keck" => Ok(Layout::keck()),
            "tmt" => Ok(Layout::tmt()),
            "elt" => Ok(Layout::elt()),
            _ => Err(LayoutError::UnknownPreset {
                name: name.to_string(),
                known: Self::PRESETS,
            }),
        }
    }

    /// The layout `name` names: a JSON file (format in the [`json`] module) when `name` ends
    /// in `.json` (any case, e.g. `my-mirror.JSON`), else the preset `name` as by
    /// [`Layout::preset`] (`"keck"`, `"tmt"`, `"elt"`, case-insensitive, surrounding white
    /// space ignored). A file name keeps its exact spelling.
    ///
    /// # Errors
    /// As [`Layout::from_json_file`] for a file (I/O, JSON, validation), as
    /// [`Layout::preset`] ([`LayoutError::UnknownPreset`]) otherwise.
    pub fn load(name: &str) -> Result<Layout, LayoutError> {
        let path = std::path::Path::new(name);
        if path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"))
        {
            Layout::from_json_file(path)
        } else {
            Layout::preset(name)
        }
    }

    /// A layout from explicit segments, validated: at least one segment; finite numbers;
    /// `circumradius > 0`, `gap >= 0`, `radius_of_curvature > 0` (`f64::INFINITY` = flat);
    /// non-empty, unique names; valid hex coordinates that agree with the centres (within
    /// [`HEX_TOLERANCE`] of the pitch); no overlapping segments. A segment with hex coordinates
    /// is then placed exactly at its grid position, and shared edges are found geometrically.
    pub fn from_segments(
        name: impl Into<String>,
        mut segments: Vec<Segment>,
        circumradius: f64,
        gap: f64,
        radius_of_curvature: f64,
        conic: f64,
    ) -> Result<Layout, LayoutError> {
        let name = name.into();
        if segments.is_empty() {
            return Err(LayoutError::Empty { name });
        }
        check_dimensions(circumradius, gap)?;
        check_optics(radius_of_curvature, conic)?;
        let pitch = pitch_of(circumradius, gap);
        let mut seen: BTreeMap<&str, usize> = BTreeMap::new();
        for (index, s) in segments.iter().enumerate() {
            if s.name.trim().is_empty() {
                return Err(LayoutError::EmptyName { index });
            }
            if let Some(&first) = seen.get(s.name.as_str()) {
                return Err(LayoutError::DuplicateName {
                    name: s.name.clone(),
                    first,
                    second: index,
                });
            }
            seen.insert(&s.name, index);
            for (axis, value) in ["x", "y"].iter().zip(s.center) {
                finite(value, || format!("{axis} of segment `{}`", s.name))?;
            }
            if let Some(h) = s.hex {
                check_hex(&s.name, h, s.center, pitch)?;
            }
        }
        // A segment on the grid sits exactly at its grid position.
        for s in &mut segments {
            if let Some(h) = s.hex {
                s.center = hex::to_xy(h, pitch);
            }
        }
        edges::check_overlaps(&segments, circumradius)?;
        Ok(Layout::assemble(
            name,
            segments,
            circumradius,
            gap,
            radius_of_curvature,
            conic,
        ))
    }

    /// Builds the layout and finds its edges, without validation (for layouts valid by
    /// construction).
    fn assemble(
        name: String,
        segments: Vec<Segment>,
        circumradius: f64,
        gap: f64,
        radius_of_curvature: f64,
        conic: f64,
    ) -> Layout {
        let centers: Vec<[f64; 2]> = segments.iter().map(|s| s.center).collect();
        let edges = edges::find_edges(&centers, pitch_of(circumradius, gap));
        Layout {
            name,
            segments,
            edges,
            circumradius,
            gap,
            radius_of_curvature,
            conic,
        }
    }

    /// The same layout with another optical prescription (`radius_of_curvature > 0` in m,
    /// `f64::INFINITY` for flat; finite `conic`).
    pub fn with_optics(
        mut self,
        radius_of_curvature: f64,
        conic: f64,
    ) -> Result<Layout, LayoutError> {
        check_optics(radius_of_curvature, conic)?;
        self.radius_of_curvature = radius_of_curvature;
        self.conic = conic;
        Ok(self)
    }

    /// Number of segments `N`.
    pub fn n_segments(&self) -> usize {
        self.segments.len()
    }

    /// Number of actuators, `3 N` (three per segment).
    pub fn n_actuators(&self) -> usize {
        3 * self.segments.len()
    }

    /// Number of shared edges.
    pub fn n_edges(&self) -> usize {
        self.edges.len()
    }

    /// Number of edge sensors, two per shared edge.
    pub fn n_sensors(&self) -> usize {
        2 * self.edges.len()
    }

    /// Centre-to-centre pitch of neighbouring segments, `sqrt(3) a + gap` (m).
    pub fn pitch(&self) -> f64 {
        pitch_of(self.circumradius, self.gap)
    }

    /// Indices of the segments sharing an edge with segment `i`, ascending (empty if `i` is
    /// out of range).
    pub fn neighbours(&self, i: usize) -> Vec<usize> {
        let mut out: Vec<usize> = self
            .edges
            .iter()
            .filter_map(|e| {
                if e.i == i {
                    Some(e.j)
                } else if e.j == i {
                    Some(e.i)
                } else {
                    None
                }
            })
            .collect();
        out.sort_unstable();
        out
    }

    /// Number of neighbours -> number of segments with that many neighbours.
    pub fn neighbour_histogram(&self) -> BTreeMap<usize, usize> {
        let mut degree = vec![0_usize; self.segments.len()];
        for e in &self.edges {
            degree[e.i] += 1;
            degree[e.j] += 1;
        }
        let mut histogram = BTreeMap::new();
        for d in degree {
            *histogram.entry(d).or_insert(0) += 1;
        }
        histogram
    }

    /// Index of the segment called `name` (exact match).
    pub fn find(&self, name: &str) -> Option<usize> {
        self.segments.iter().position(|s| s.name == name)
    }

    /// Corners of segment `i` (m), counter-clockwise from the corner at 30 degrees: corner `k`
    /// is at `center + a (cos(30 + 60 k), sin(30 + 60 k))`. Side `k` (from corner `k - 1` to
    /// corner `k`, cyclically) faces the direction `60 k` degrees.
    pub fn vertices(&self, i: usize) -> Option<[[f64; 2]; 6]> {
        let c = self.segments.get(i)?.center;
        let a = self.circumradius;
        Some(std::array::from_fn(|k| {
            let angle = (30.0 + 60.0 * k as f64).to_radians();
            [c[0] + a * angle.cos(), c[1] + a * angle.sin()]
        }))
    }
}

/// `sqrt(3) a + gap`.
fn pitch_of(circumradius: f64, gap: f64) -> f64 {
    3.0_f64.sqrt() * circumradius + gap
}

/// Fails with [`LayoutError::NonFinite`] unless `value` is finite.
fn finite(value: f64, what: impl FnOnce() -> String) -> Result<f64, LayoutError> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(LayoutError::NonFinite {
            what: what(),
            value,
        })
    }
}

/// `circumradius` finite and > 0, `gap` finite and >= 0.
fn check_dimensions(circumradius: f64, gap: f64) -> Result<(), LayoutError> {
    finite(circumradius, || "circumradius".into())?;
    finite(gap, || "gap".into())?;
    if circumradius <= 0.0 {
        return Err(LayoutError::OutOfRange {
            what: "circumradius".into(),
            value: circumradius,
            expected: "> 0 m",
        });
    }
    if gap < 0.0 {
        return Err(LayoutError::OutOfRange {
            what: "gap".into(),
            value: gap,
            expected: ">= 0 m",
        });
    }
    Ok(())
}

/// `radius_of_curvature` > 0 (infinity allowed: flat) and not NaN, `conic` finite.
fn check_optics(radius_of_curvature: f64, conic: f64) -> Result<(), LayoutError> {
    if radius_of_curvature.is_nan() || radius_of_curvature == f64::NEG_INFINITY {
        return Err(LayoutError::NonFinite {
            what: "radius_of_curvature".into(),
            value: radius_of_curvature,
        });
    }
    if radius_of_curvature <= 0.0 {
        return Err(LayoutError::OutOfRange {
            what: "radius_of_curvature".into(),
            value: radius_of_curvature,
            expected: "> 0 m (or infinite for a flat mirror)",
        });
    }
    finite(conic, || "conic".into())?;
    Ok(())
}

/// The hex coordinates `h` of segment `name` are valid and put it at `center` (within
/// [`HEX_TOLERANCE`]).
fn check_hex(name: &str, h: [i32; 3], center: [f64; 2], pitch: f64) -> Result<(), LayoutError> {
    if !hex::is_valid(h) {
        return Err(LayoutError::InvalidHex {
            name: name.to_string(),
            hex: h,
            reason: "do not sum to zero".into(),
        });
    }
    let expected = hex::to_xy(h, pitch);
    let offset = (expected[0] - center[0]).hypot(expected[1] - center[1]);
    if offset > HEX_TOLERANCE * pitch {
        return Err(LayoutError::InvalidHex {
            name: name.to_string(),
            hex: h,
            reason: format!(
                "place the centre at ({:.6}, {:.6}) m, {offset:.6} m from the given centre \
                 ({:.6}, {:.6}) m",
                expected[0], expected[1], center[0], center[1]
            ),
        });
    }
    Ok(())
}
