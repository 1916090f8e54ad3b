//! Built-in layouts (TMT, Keck, ELT-like) and the generic hexagonal-grid builder.
//!
//! Values marked *assumed* are not published; they are defaults that a user layout file can
//! override.

use super::hex::{self, Cube};
use super::{Layout, LayoutError, MAX_RINGS, Segment, check_dimensions, finite};

/// TMT segment circumradius a (m): 1.44 m across corners.
pub const TMT_CIRCUMRADIUS: f64 = 0.72;
/// TMT inter-segment gap (m).
pub const TMT_GAP: f64 = 0.0025;
/// TMT M1 radius of curvature (m): f/1, focal length 30 m.
pub const TMT_RADIUS_OF_CURVATURE: f64 = 60.0;
/// TMT M1 conic constant (hyperboloid; *assumed*).
pub const TMT_CONIC: f64 = -1.000953;
/// TMT sector letters, counter-clockwise.
pub const TMT_SECTORS: [char; 6] = ['A', 'B', 'C', 'D', 'E', 'F'];
/// Segments per TMT sector.
pub const TMT_SECTOR_SIZE: usize = 82;

/// Keck segment circumradius a (m): 1.8 m across corners.
pub const KECK_CIRCUMRADIUS: f64 = 0.9;
/// Keck inter-segment gap (m, approximate).
pub const KECK_GAP: f64 = 0.003;
/// Keck primary radius of curvature (m).
pub const KECK_RADIUS_OF_CURVATURE: f64 = 35.0;
/// Keck primary conic constant (approximate).
pub const KECK_CONIC: f64 = -1.003895;
/// Keck hex rings (around an empty centre).
pub const KECK_RINGS: u32 = 3;

/// ELT-like segment circumradius a (m): 1.4 m across corners.
pub const ELT_CIRCUMRADIUS: f64 = 0.7;
/// ELT-like inter-segment gap (m).
pub const ELT_GAP: f64 = 0.004;
/// ELT-like outermost hex ring.
pub const ELT_RINGS: u32 = 17;
/// ELT-like central hole: hex rings 0..=4 are empty.
pub const ELT_HOLE_RINGS: u32 = 4;
/// ELT-like radius cut on segment centres (m): 15.46 pitches. Any value between 15.40 and 15.52
/// pitches (18.73..18.88 m) keeps the same 798 segments.
pub const ELT_MAX_RADIUS: f64 = 18.8;
/// ELT-like radius of curvature (m, *assumed*: ESO ELT M1 design value).
pub const ELT_RADIUS_OF_CURVATURE: f64 = 68.734;
/// ELT-like conic constant (*assumed*: ESO ELT M1 design value, an ellipsoid).
pub const ELT_CONIC: f64 = -0.993295;

/// Number of rings in a TMT sector; sector ring `k` lies on hex ring `k + 1`.
const TMT_SECTOR_RINGS: i32 = 12;

/// Cube coordinates of TMT sector A, in segment-number order (A1..A82).
///
/// Sector ring `k` lies on hex ring `d = k + 1`, on the side running clockwise from the corner
/// `(-d, d, 0)` (at 120 degrees) towards the corner `(0, d, -d)` (at 60 degrees, which belongs to
/// sector F): position `c` is `(c - d, d, -c)`.
fn tmt_sector_a() -> Vec<Cube> {
    let mut out = Vec::with_capacity(TMT_SECTOR_SIZE);
    for k in 1..=TMT_SECTOR_RINGS {
        let d = k + 1;
        let positions = match k {
            // Ring 11: the corner (nearest sector B, 15 m from the axis) is missing.
            11 => 1..d,
            // Ring 12: the 6 middle positions of hex ring 13.
            12 => 4..10,
            _ => 0..d,
        };
        out.extend(positions.map(|c| [c - d, d, -c]));
    }
    out
}

impl Layout {
    /// The Thirty Meter Telescope's primary: 492 segments, sectors `A`..`F` of 82 (`A1`..`F82`,
    /// index `sector * 82 + n - 1`). See the [module documentation](super) for the numbering.
    pub fn tmt() -> Layout {
        let pitch = super::pitch_of(TMT_CIRCUMRADIUS, TMT_GAP);
        let sector_a = tmt_sector_a();
        let mut segments = Vec::with_capacity(TMT_SECTORS.len() * TMT_SECTOR_SIZE);
        for (rotations, letter) in TMT_SECTORS.iter().enumerate() {
            for (n, &h) in sector_a.iter().enumerate() {
                let h = (0..rotations).fold(h, |h, _| hex::rotate_ccw(h));
                segments.push(Segment {
                    name: format!("{letter}{}", n + 1),
                    center: hex::to_xy(h, pitch),
                    hex: Some(h),
                });
            }
        }
        Layout::assemble(
            "tmt".into(),
            segments,
            TMT_CIRCUMRADIUS,
            TMT_GAP,
            TMT_RADIUS_OF_CURVATURE,
            TMT_CONIC,
        )
    }

    /// The Keck primary: 36 segments on hex rings 1..3, named `"1"`..`"36"` ring by ring
    /// outward, each ring counter-clockwise from its corner on +x.
    pub fn keck() -> Layout {
        let pitch = super::pitch_of(KECK_CIRCUMRADIUS, KECK_GAP);
        let segments = grid_segments(KECK_RINGS, 0, pitch, None, |n| n.to_string());
        Layout::assemble(
            "keck".into(),
            segments,
            KECK_CIRCUMRADIUS,
            KECK_GAP,
            KECK_RADIUS_OF_CURVATURE,
            KECK_CONIC,
        )
    }

    /// An ELT-like primary of 798 segments (1.4 m across corners, 4 mm gaps): hex rings 5..17
    /// ([`ELT_HOLE_RINGS`] + 1 ..= [`ELT_RINGS`]) with centres closer than [`ELT_MAX_RADIUS`]
    /// to the axis; six-fold symmetric, 133 segments per 60-degree sector. Named `S1`..`S798`
    /// as by [`Layout::hexagonal`].
    pub fn elt() -> Layout {
        let pitch = super::pitch_of(ELT_CIRCUMRADIUS, ELT_GAP);
        let segments = grid_segments(
            ELT_RINGS,
            ELT_HOLE_RINGS,
            pitch,
            Some(ELT_MAX_RADIUS),
            |n| format!("S{n}"),
        );
        Layout::assemble(
            "elt".into(),
            segments,
            ELT_CIRCUMRADIUS,
            ELT_GAP,
            ELT_RADIUS_OF_CURVATURE,
            ELT_CONIC,
        )
    }

    /// A generic hexagonal layout: every grid position whose hex distance from the centre is
    /// in `(hole_rings, rings]` and, if `max_radius` is given, whose centre is closer than
    /// `max_radius` (m) to the axis. Segments are named `S1`, `S2`, ... ring by ring outward,
    /// each ring counter-clockwise from its corner on +x. The mirror is flat
    /// (`radius_of_curvature = f64::INFINITY`, `conic = 0`); see [`Layout::with_optics`].
    ///
    /// Fails on non-finite or out-of-range sizes (`circumradius > 0`, `gap >= 0`,
    /// `max_radius > 0`), on `hole_rings >= rings` or `rings > MAX_RINGS`, and when no
    /// segment is left.
    pub fn hexagonal(
        name: &str,
        rings: u32,
        hole_rings: u32,
        circumradius: f64,
        gap: f64,
        max_radius: Option<f64>,
    ) -> Result<Layout, LayoutError> {
        check_dimensions(circumradius, gap)?;
        if let Some(r) = max_radius {
            finite(r, || "max_radius".into())?;
            if r <= 0.0 {
                return Err(LayoutError::OutOfRange {
                    what: "max_radius".into(),
                    value: r,
                    expected: "> 0 m",
                });
            }
        }
        if hole_rings >= rings || rings > MAX_RINGS {
            return Err(LayoutError::InvalidRings {
                rings,
                hole_rings,
                max_rings: MAX_RINGS,
            });
        }
        let pitch = super::pitch_of(circumradius, gap);
        let segments = grid_segments(rings, hole_rings, pitch, max_radius, |n| format!("S{n}"));
        if segments.is_empty() {
            return Err(LayoutError::Empty {
                name: name.to_string(),
            });
        }
        Ok(Layout::assemble(
            name.to_string(),
            segments,
            circumradius,
            gap,
            f64::INFINITY,
            0.0,
        ))
    }
}

/// Segments on hex rings `hole_rings + 1 ..= rings` (each counter-clockwise from its corner on
/// +x) with centre radius below `max_radius`, named by `name(n)` for n = 1, 2, ...
fn grid_segments(
    rings: u32,
    hole_rings: u32,
    pitch: f64,
    max_radius: Option<f64>,
    name: impl Fn(usize) -> String,
) -> Vec<Segment> {
    let mut segments = Vec::new();
    for d in hole_rings + 1..=rings {
        for h in hex::ring(d) {
            let center = hex::to_xy(h, pitch);
            if max_radius.is_some_and(|r| center[0].hypot(center[1]) >= r) {
                continue;
            }
            segments.push(Segment {
                name: name(segments.len() + 1),
                center,
                hex: Some(h),
            });
        }
    }
    segments
}
