//! Edge-sensor interaction matrices from rigid-body kinematics (seed paper, section 2.2, eq. 1):
//! the height (with dihedral), gap and shear read by every edge sensor for small rigid motions of
//! every segment.
//!
//! # Kinematics
//!
//! Segment `i` (centre `c_i`, frame `(r_i, a_i, n_i)` = radial, azimuthal, normal; see
//! [`crate::aperture::geometry`]) moves by a small translation `d_i` and rotation `theta_i`; its point `r`
//! moves by
//!
//! ```text
//! u_i(r) = d_i + theta_i x (r - c_i).
//! ```
//!
//! Its six degrees of freedom are split into two coordinate vectors of length `3 N`:
//!
//! - **Out-of-plane `z`** (entries `3 i + k`, `k = 0, 1, 2`): the displacements of the three
//!   actuators along `n_i`. With `(p, alpha, beta) = P_i^-1 z_i`
//!   ([`Geometry::ptt_inverse`]): `d = p n_i`, `theta = alpha r_i + beta a_i`.
//! - **In-plane `w`** (entries `3 i + 0` radial `delta_r`, `3 i + 1` azimuthal `delta_a`,
//!   `3 i + 2` clocking `epsilon`), a motion *along the prescription*: the segment slides over the
//!   sphere of radius `R` (vertex radius) tangent to the mirror at `c_i`, centred at
//!   `C_i = c_i + R n_i`, i.e. it turns about `C_i`:
//!
//!   ```text
//!   d = delta_r r_i + delta_a a_i,
//!   theta = (d x n_i) / R + epsilon n_i = (delta_a r_i - delta_r a_i) / R + epsilon n_i,
//!   ```
//!
//!   so that `u_i(c_i) = d` and, to first order, the new normal `n_i + theta x n_i = n_i - d / R`
//!   still points at `C_i` (a radial move outward tilts the normal inward). For a flat mirror
//!   (`R` infinite) the rotation terms vanish. Note that `z` are coordinates, not total strokes:
//!   the tilt that goes with an in-plane move also moves the actuator points along `n_i`.
//!
//! The map from `(z_i, w_i)` to `(d_i, theta_i)` is invertible:
//! `p = d . n`, `delta_r = d . r`, `delta_a = d . a`, `epsilon = theta . n`,
//! `alpha = theta . r - delta_a / R`, `beta = theta . a + delta_r / R`, `z = P (p, alpha, beta)`
//! ([`segment_coordinates`]).
//!
//! # Sensor readings
//!
//! Sensor `n` on edge `(i, j)`, at point `s` with unit directions `h` (height, surface normal),
//! `g` (gap, tangent, from `i` to `j`) and `t = h x g` (shear), reads
//!
//! ```text
//! y_h = (u_i(s) - u_j(s)) . h + L_eff [((theta_i - theta_j) x g) . h + (u_i(s) - u_j(s)) . dh/dg],
//! y_g = (u_j(s) - u_i(s)) . g          (positive: the gap opens),
//! y_s = (u_i(s) - u_j(s)) . t.
//! ```
//!
//! The `L_eff` term is the dihedral sensitivity: on a flat mirror `(theta x g) . h` is the slope
//! of the segment across the edge, so `y_h = z_i(s) - z_j(s) + L_eff (t_i - t_j) . g`, the
//! classic A-matrix formula. On a curved mirror the dihedral is the change of the surfaces'
//! slope difference across the edge at the fixed sensor point: the derivative along `g` of the
//! normal displacement field `u(r) . h(r)`, which adds the curvature term `u . dh/dg`. With it a
//! rigid motion along a sphere (a segment clocked about its normal, or slid along the surface)
//! changes no dihedral, as it must; what remains on the conic comes from its asphericity.
//! A single segment `i` pistoned by `p` reads `y_h = +p` on the sensors
//! of edges where it is the first segment and `-p` where it is the second.
//!
//! # Matrices
//!
//! `y_h = A_hz z + A_hw w`, `y_g = A_gz z + A_gw w`, `y_s = A_sz z + A_sw w`, each block
//! `ns x 3N`; [`InteractionMatrices::full`] stacks them as the `3 ns x 6 N` matrix with rows
//! `[y_h; y_g; y_s]` and columns `[z; w]` (eq. 1 of the seed paper). `A = A_hz` is the standard
//! `ns x na` A-matrix. Each row of a block has at most six stored entries (three per segment);
//! entries that are exactly zero (e.g. the out-of-plane/in-plane couplings of a flat mirror) are
//! not stored.
//!
//! The six rigid-body motions of the whole mirror ([`global_rigid_modes`]) give exactly zero
//! readings, so the full matrix has rank `6 N - 6`. On a flat mirror the out-of-plane part of a
//! global translation along `z` and of rotations about `x` and `y` ([`global_ptt`]) is pure `z`
//! and `A` annihilates it exactly. On a curved mirror no rigid motion is purely out-of-plane in
//! these coordinates: the `z` part of global piston/tip/tilt leaves small readings (falling as
//! `1/R^4`; the `w` part of the rigid motion cancels them in the full matrix), so `A` is there
//! only nearly rank-deficient and the reconstructor projects global piston/tip/tilt out.

use faer::Mat;
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use nalgebra::Vector3;

use crate::aperture::geometry::Geometry;

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

fn arr(v: Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

/// A small rigid motion of one segment: translation of its centre and rotation vector.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RigidMotion {
    /// Translation `d` of the segment centre (m).
    pub translation: [f64; 3],
    /// Small rotation vector `theta` (rad).
    pub rotation: [f64; 3],
}

impl RigidMotion {
    /// Displacement `d + theta x (point - centre)` of `point` of a body with centre `centre`.
    pub fn displacement(&self, centre: [f64; 3], point: [f64; 3]) -> [f64; 3] {
        let r = v3(point) - v3(centre);
        arr(v3(self.translation) + v3(self.rotation).cross(&r))
    }

    /// Sum of two motions (superposition of small motions).
    pub fn add(&self, other: &RigidMotion) -> RigidMotion {
        RigidMotion {
            translation: arr(v3(self.translation) + v3(other.translation)),
            rotation: arr(v3(self.rotation) + v3(other.rotation)),
        }
    }

    /// The motion scaled by `s`.
    pub fn scale(&self, s: f64) -> RigidMotion {
        RigidMotion {
            translation: arr(s * v3(self.translation)),
            rotation: arr(s * v3(self.rotation)),
        }
    }
}

/// The motion of segment `i` for out-of-plane coordinates `z` (its three actuator displacements
/// along the normal): `(p, alpha, beta) = P^-1 z`, `d = p n`, `theta = alpha r + beta a`.
///
/// # Panics
/// If `i >= geometry.n_segments()`.
pub fn out_of_plane_motion(geometry: &Geometry, i: usize, z: [f64; 3]) -> RigidMotion {
    let f = &geometry.segments[i];
    let inv = geometry.ptt_inverse(i);
    let ptt: [f64; 3] = std::array::from_fn(|r| (0..3).map(|k| inv[r][k] * z[k]).sum());
    let (n, r, a) = (v3(f.normal), v3(f.radial), v3(f.azimuthal));
    RigidMotion {
        translation: arr(ptt[0] * n),
        rotation: arr(ptt[1] * r + ptt[2] * a),
    }
}

/// The motion of segment `i` for in-plane coordinates `w = (delta_r, delta_a, epsilon)`: a slide
/// along the prescription, `d = delta_r r + delta_a a`, `theta = (d x n) / R + epsilon n`.
///
/// # Panics
/// If `i >= geometry.n_segments()`.
pub fn in_plane_motion(geometry: &Geometry, i: usize, w: [f64; 3]) -> RigidMotion {
    let f = &geometry.segments[i];
    let (n, r, a) = (v3(f.normal), v3(f.radial), v3(f.azimuthal));
    let d = w[0] * r + w[1] * a;
    let theta = geometry.curvature() * d.cross(&n) + w[2] * n;
    RigidMotion {
        translation: arr(d),
        rotation: arr(theta),
    }
}

/// The coordinates `(z, w)` of segment `i` for an arbitrary small rigid motion (inverse of
/// [`out_of_plane_motion`] + [`in_plane_motion`]).
///
/// # Panics
/// If `i >= geometry.n_segments()`.
pub fn segment_coordinates(
    geometry: &Geometry,
    i: usize,
    motion: &RigidMotion,
) -> ([f64; 3], [f64; 3]) {
    let f = &geometry.segments[i];
    let (n, r, a) = (v3(f.normal), v3(f.radial), v3(f.azimuthal));
    let (d, theta) = (v3(motion.translation), v3(motion.rotation));
    let kappa = geometry.curvature();
    let (dr, da) = (d.dot(&r), d.dot(&a));
    let ptt = [
        d.dot(&n),
        theta.dot(&r) - kappa * da,
        theta.dot(&a) + kappa * dr,
    ];
    let p = geometry.ptt_matrix(i);
    let z = std::array::from_fn(|k| (0..3).map(|c| p[k][c] * ptt[c]).sum());
    (z, [dr, da, theta.dot(&n)])
}

/// Derivative of the prescription's unit normal along the tangent `dir` at `point`, by a central
/// difference over 1 mm (the normal field depends on x and y only; error O(1e-6) relative).
fn normal_derivative(geometry: &Geometry, point: [f64; 3], dir: [f64; 3]) -> Vector3<f64> {
    let p = &geometry.prescription;
    if p.is_flat() {
        return Vector3::zeros();
    }
    let d = 1e-3;
    let plus = v3(p.normal(point[0] + d * dir[0], point[1] + d * dir[1]));
    let minus = v3(p.normal(point[0] - d * dir[0], point[1] - d * dir[1]));
    (plus - minus) / (2.0 * d)
}

/// Readings `(y_h, y_g, y_s)` of sensor `n` when its two segments move by `mi` (segment `i`) and
/// `mj` (segment `j`), by the formulas of the [module documentation](self).
///
/// # Panics
/// If `n >= geometry.n_sensors()`.
pub fn sensor_reading(
    geometry: &Geometry,
    n: usize,
    mi: &RigidMotion,
    mj: &RigidMotion,
) -> [f64; 3] {
    let s = &geometry.sensors[n];
    let (h, g, t) = (v3(s.height), v3(s.gap), v3(s.shear));
    let ui = v3(mi.displacement(geometry.segments[s.i].centre, s.point));
    let uj = v3(mj.displacement(geometry.segments[s.j].centre, s.point));
    let du = ui - uj;
    let dtheta = v3(mi.rotation) - v3(mj.rotation);
    // Dihedral: the change of the surfaces' slope difference across the edge at the (fixed)
    // sensor point. The normal displacement field is u(r).h(r); its derivative along g is
    // (theta x g).h + u.(dh/dg). The curvature term makes a motion along the prescription (a
    // clocking or sliding of a segment on a sphere) change no dihedral, as it must.
    let dh_dg = normal_derivative(geometry, s.point, s.gap);
    [
        du.dot(&h) + geometry.params.leff * (dtheta.cross(&g).dot(&h) + du.dot(&dh_dg)),
        -du.dot(&g),
        du.dot(&t),
    ]
}

/// The six `ns x 3N` blocks of the full interaction matrix (rows: sensors; columns: `z` or `w`
/// coordinates of all segments, `3 i + k`).
#[derive(Debug, Clone)]
pub struct InteractionMatrices {
    /// Height (with dihedral) versus out-of-plane motion: the A-matrix, `ns x na`.
    pub a_hz: SparseColMat<usize, f64>,
    /// Height (with dihedral) versus in-plane motion.
    pub a_hw: SparseColMat<usize, f64>,
    /// Gap versus out-of-plane motion.
    pub a_gz: SparseColMat<usize, f64>,
    /// Gap versus in-plane motion.
    pub a_gw: SparseColMat<usize, f64>,
    /// Shear versus out-of-plane motion.
    pub a_sz: SparseColMat<usize, f64>,
    /// Shear versus in-plane motion.
    pub a_sw: SparseColMat<usize, f64>,
}

/// Builds a compressed-column matrix from `(row, col, value)` triplets (indices in range),
/// summing duplicates and dropping entries that are exactly zero.
fn csc(
    nrows: usize,
    ncols: usize,
    mut entries: Vec<(usize, usize, f64)>,
) -> SparseColMat<usize, f64> {
    entries.sort_unstable_by_key(|&(r, c, _)| (c, r));
    let mut merged: Vec<(usize, usize, f64)> = Vec::with_capacity(entries.len());
    for (r, c, v) in entries {
        match merged.last_mut() {
            Some(last) if last.0 == r && last.1 == c => last.2 += v,
            _ => merged.push((r, c, v)),
        }
    }
    merged.retain(|e| e.2 != 0.0);
    let mut col_ptr = vec![0_usize; ncols + 1];
    for &(_, c, _) in &merged {
        col_ptr[c + 1] += 1;
    }
    for c in 0..ncols {
        col_ptr[c + 1] += col_ptr[c];
    }
    let row_idx = merged.iter().map(|e| e.0).collect();
    let values = merged.iter().map(|e| e.2).collect();
    SparseColMat::new(
        SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, None, row_idx),
        values,
    )
}

/// The six blocks of the full interaction matrix of `geometry` (see the
/// [module documentation](self) for the kinematics and sign conventions).
pub fn interaction_matrices(geometry: &Geometry) -> InteractionMatrices {
    let ns = geometry.n_sensors();
    let nc = geometry.n_actuators();
    // Basis motions of every segment: unit z_k and unit w_m.
    let basis: Vec<[[RigidMotion; 3]; 2]> = (0..geometry.n_segments())
        .map(|i| {
            let unit = |k: usize| std::array::from_fn(|m| if m == k { 1.0 } else { 0.0 });
            [
                std::array::from_fn(|k| out_of_plane_motion(geometry, i, unit(k))),
                std::array::from_fn(|m| in_plane_motion(geometry, i, unit(m))),
            ]
        })
        .collect();
    let still = RigidMotion::default();
    // blocks[kind][reading]: kind 0 = z, 1 = w; reading 0 = h, 1 = g, 2 = s.
    let mut blocks: [[Vec<(usize, usize, f64)>; 3]; 2] = Default::default();
    for (n, sensor) in geometry.sensors.iter().enumerate() {
        for (first, seg) in [(true, sensor.i), (false, sensor.j)] {
            for (kind, motions) in basis[seg].iter().enumerate() {
                for (k, motion) in motions.iter().enumerate() {
                    let y = if first {
                        sensor_reading(geometry, n, motion, &still)
                    } else {
                        sensor_reading(geometry, n, &still, motion)
                    };
                    for (reading, value) in y.into_iter().enumerate() {
                        blocks[kind][reading].push((n, 3 * seg + k, value));
                    }
                }
            }
        }
    }
    let [[hz, gz, sz], [hw, gw, sw]] = blocks;
    InteractionMatrices {
        a_hz: csc(ns, nc, hz),
        a_hw: csc(ns, nc, hw),
        a_gz: csc(ns, nc, gz),
        a_gw: csc(ns, nc, gw),
        a_sz: csc(ns, nc, sz),
        a_sw: csc(ns, nc, sw),
    }
}

/// The A-matrix `A = A_hz` (`ns x na`): sensor height-plus-dihedral readings per unit actuator
/// displacement.
pub fn a_matrix(geometry: &Geometry) -> SparseColMat<usize, f64> {
    interaction_matrices(geometry).a_hz
}

impl InteractionMatrices {
    /// The full interaction matrix, `3 ns x 6 N`: rows `[y_h; y_g; y_s]`, columns `[z; w]`:
    ///
    /// ```text
    /// [ A_hz  A_hw ]
    /// [ A_gz  A_gw ]
    /// [ A_sz  A_sw ]
    /// ```
    pub fn full(&self) -> SparseColMat<usize, f64> {
        let ns = self.a_hz.nrows();
        let nc = self.a_hz.ncols();
        let grid = [
            [&self.a_hz, &self.a_hw],
            [&self.a_gz, &self.a_gw],
            [&self.a_sz, &self.a_sw],
        ];
        let mut entries = Vec::new();
        for (block_row, row) in grid.iter().enumerate() {
            for (block_col, m) in row.iter().enumerate() {
                for t in m.triplet_iter() {
                    entries.push((block_row * ns + t.row, block_col * nc + t.col, *t.val));
                }
            }
        }
        csc(3 * ns, 2 * nc, entries)
    }
}

/// The six rigid-body motions of the whole mirror in `[z; w]` coordinates (`6 N x 6`): columns
/// are unit translations along `x`, `y`, `z` (1 m) and unit rotations about the `x`, `y`, `z`
/// axes through the origin (1 rad); segment `i` moves by `d_i = t + Omega x c_i`,
/// `theta_i = Omega`. Rows `0..3N` are `z`, `3N..6N` are `w`.
pub fn global_rigid_modes(geometry: &Geometry) -> Mat<f64> {
    let nseg = geometry.n_segments();
    let nc = 3 * nseg;
    let mut modes = Mat::<f64>::zeros(2 * nc, 6);
    for mode in 0..6 {
        let mut t = Vector3::zeros();
        let mut omega = Vector3::zeros();
        if mode < 3 {
            t[mode] = 1.0;
        } else {
            omega[mode - 3] = 1.0;
        }
        for (i, f) in geometry.segments.iter().enumerate() {
            let motion = RigidMotion {
                translation: arr(t + omega.cross(&v3(f.centre))),
                rotation: arr(omega),
            };
            let (z, w) = segment_coordinates(geometry, i, &motion);
            for k in 0..3 {
                modes[(3 * i + k, mode)] = z[k];
                modes[(nc + 3 * i + k, mode)] = w[k];
            }
        }
    }
    modes
}

/// Global piston, tip and tilt as actuator displacements (`na x 3`): the out-of-plane (`z`)
/// part of a rigid translation along `z` and of rotations about the `x` and `y` axes, each column
/// scaled to unit rms over the actuators. On a flat mirror `A` annihilates these exactly.
pub fn global_ptt(geometry: &Geometry) -> Mat<f64> {
    let nc = geometry.n_actuators();
    let rigid = global_rigid_modes(geometry);
    let mut ptt = Mat::<f64>::zeros(nc, 3);
    for (col, mode) in [2_usize, 3, 4].into_iter().enumerate() {
        let norm = (0..nc)
            .map(|r| rigid[(r, mode)].powi(2))
            .sum::<f64>()
            .sqrt();
        let scale = if norm > 0.0 {
            (nc as f64).sqrt() / norm
        } else {
            0.0
        };
        for r in 0..nc {
            ptt[(r, col)] = scale * rigid[(r, mode)];
        }
    }
    ptt
}

/// Dense copy of a sparse matrix.
pub fn to_dense(m: &SparseColMat<usize, f64>) -> Mat<f64> {
    m.to_dense()
}
