//! Cube coordinates on the hexagonal grid of segment centres.
//!
//! A grid position is `[q, r, s]` with `q + r + s = 0`. With centre-to-centre pitch `p`, its
//! centre in the aperture plane is
//!
//! $$x = p\,(q + r/2), \qquad y = p\,\tfrac{\sqrt 3}{2}\,r,$$
//!
//! so the six neighbour offsets ([`DIRECTIONS`]) point at 0, 60, ..., 300 degrees from +x and
//! have length `p`. The hex distance of a position from the centre is
//! `max(|q|, |r|, |s|)`; the positions at distance `d >= 1` form hex ring `d` (`6 d` positions,
//! its six corners along the neighbour directions).

/// Cube coordinates `[q, r, s]`, `q + r + s = 0`.
pub type Cube = [i32; 3];

/// The six unit steps to a neighbour, counter-clockwise from +x: 0, 60, 120, 180, 240 and 300
/// degrees.
pub const DIRECTIONS: [Cube; 6] = [
    [1, 0, -1],
    [0, 1, -1],
    [-1, 1, 0],
    [-1, 0, 1],
    [0, -1, 1],
    [1, -1, 0],
];

/// True when `h` is a valid cube coordinate (`q + r + s = 0`).
pub fn is_valid(h: Cube) -> bool {
    i64::from(h[0]) + i64::from(h[1]) + i64::from(h[2]) == 0
}

/// Hex distance of `h` from the centre: `max(|q|, |r|, |s|)`.
pub fn distance(h: Cube) -> u32 {
    h.iter().map(|c| c.unsigned_abs()).max().unwrap_or(0)
}

/// `h` rotated by +60 degrees (counter-clockwise) about the centre.
pub fn rotate_ccw(h: Cube) -> Cube {
    [-h[1], -h[2], -h[0]]
}

/// Sum of two cube coordinates.
pub fn add(a: Cube, b: Cube) -> Cube {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `h` scaled by `k`.
pub fn scale(h: Cube, k: i32) -> Cube {
    [h[0] * k, h[1] * k, h[2] * k]
}

/// Centre `[x, y]` (m) of grid position `h` for a centre-to-centre pitch `pitch` (m).
pub fn to_xy(h: Cube, pitch: f64) -> [f64; 2] {
    let q = f64::from(h[0]);
    let r = f64::from(h[1]);
    [pitch * (q + 0.5 * r), pitch * (0.75_f64.sqrt() * r)]
}

/// The positions of hex ring `d`, counter-clockwise, starting at the corner on the +x axis
/// (`[d, 0, -d]`). Ring 0 is the centre alone.
pub fn ring(d: u32) -> Vec<Cube> {
    // The number of rings is bounded by the callers (see `MAX_RINGS`), so it fits in an i32.
    let d = i32::try_from(d).unwrap_or(i32::MAX);
    if d == 0 {
        return vec![[0, 0, 0]];
    }
    let mut out = Vec::with_capacity(6 * d as usize);
    for k in 0..6 {
        let corner = scale(DIRECTIONS[k], d);
        let step = DIRECTIONS[(k + 2) % 6];
        for t in 0..d {
            out.push(add(corner, scale(step, t)));
        }
    }
    out
}
