//! Edge-sensor readings with gain errors, noise, installation errors, a gap-dependent gain and
//! moment arm, and drift.
//!
//! # Readings
//!
//! For out-of-plane displacements `z` at the actuators (m, length `n_a = 3N`) and in-plane
//! segment motion `w` (`w[3 i]` radial m, `w[3 i + 1]` azimuthal m, `w[3 i + 2]` clocking rad;
//! see [`crate::sensing::interaction`] for the kinematics), sensor `n` reads
//!
//! ```text
//! y_n   = s_n (A_hz z + A_hw w')_n + c_n T + d_n t / week + sigma_y nu_n
//! gap_n = g_0 + (A_gz z + A_gw w')_n + dg_sensor,n + sigma_g mu_n
//! ```
//!
//! (m: `y` is the height difference plus `L_eff` times the dihedral, `gap` the gap), where
//!
//! - the interaction blocks are those of the *installed* geometry (below); `A_hz = A` is the
//!   A-matrix, `A_gz` vanishes on a flat mirror and couples out-of-plane motion into the gap on
//!   the curved prescription;
//! - `w' = w + w_0`, with `w_0` the segments' installation errors (below; 0 by default);
//! - `g_0` is the layout's nominal gap;
//! - `s_n = 1 + delta_n`, `delta_n ~ N(0, gain_rms)`: sensor gain errors `S = I + delta_S`, drawn
//!   once per seed; they scale the height reading only;
//! - `nu_n`, `mu_n ~ N(0, 1)`: white noise, drawn once per sample: sample `k`'s noise comes
//!   from a generator seeded by `(seed, k)`, so it does not depend on how the time axis is cut
//!   into steps, and any sample can be recomputed;
//! - installation errors of the sensors ([`install_sensors`]): each sensor point moved in its
//!   tangent plane by `N(0, position_rms)` along the gap and the shear directions, and the
//!   sensor's frame (height, gap, shear) rotated by `N(0, tilt_rms)` about the gap and then the
//!   shear axis, as [`crate::analysis::quasistatic`]'s `SensorInstall` perturbation (which tilts
//!   the height axis only);
//! - installation errors of the segments ([`Installation`]): each segment placed off its nominal
//!   place by `w_0`, `N(0, segment_position_rms)` radially and azimuthally and
//!   `N(0, segment_clocking_rms)` in clocking; it carries its sensor halves, so `w_0` adds to `w`
//!   in both the gap and the height (cross-axis, `A_hw`) readings; and each sensor's own gap
//!   offset from the segments' gap, `dg_sensor,n ~ N(0, sensor_gap_rms)`;
//! - drift: `c_n ~ U(-drift_per_degc, drift_per_degc)` (m/K) and
//!   `d_n ~ U(-drift_per_week, drift_per_week)` (m), drawn once per seed, times the temperature
//!   change `T` (K) and the time `t` (s, one week = 604800 s) passed to
//!   [`EdgeSensors::read_into_at`] ([`EdgeSensors::read_into`] reads at `T = 0`, `t = 0`).
//!
//! # Gap law
//!
//! With a [`GapLaw`] other than [`GapLaw::NONE`] (the default) the sensors respond as installed
//! sensors do ([`crate::sensing::installed`]): the height gain and the moment arm depend on the
//! current gap change at the sensor,
//!
//! ```text
//! dg_n = (A_gz z + A_gw w')_n + dg_sensor,n
//! y_n  = s_n (1 + gamma_h dg_n) (h_n + (1 + kappa dg_n) l_n) + c_n T + d_n t / week
//!        + sigma_y nu_n
//! ```
//!
//! (`dg_n` is the gap reading without `g_0` and noise), with `h_n` the pure height part of
//! `(A_hz z + A_hw w')_n` (the reading with `L_eff = 0`) and `l_n` the rest, `L_eff` times the
//! dihedral, both evaluated per sample. The law scales the whole height reading, in-plane
//! (`A_hw`) part included, as the gain errors do.
//!
//! Each stream has its own seed derived from `seed` (gains, sensor installation, height noise,
//! gap noise, drift; the segment and sensor-gap installation draws are [`Installation`]'s own),
//! so switching one error source on leaves the others' draws unchanged, and the defaults
//! reproduce the readings of ideal sensors exactly.

use faer::sparse::SparseColMat;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::sensing::installed::{GapLaw, HeightSplit, Installation};
use crate::sensing::interaction::interaction_matrices;

/// The error sources of the edge sensors (all zero by default: ideal sensors).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SensorErrors {
    /// rms of the sensor gain errors `delta_S` (1 = 100 %) (default: 0).
    pub gain_rms: f64,
    /// rms of the white noise on the height reading, per sample (m) (default: 0; the
    /// specification is < 5 nm).
    pub noise_rms: f64,
    /// rms of the white noise on the gap reading, per sample (m) (default: 0).
    pub gap_noise_rms: f64,
    /// rms of the in-plane installation error of each sensor point, per axis (m) (default: 0).
    pub position_rms: f64,
    /// rms of the installation tilt of each sensor, about each in-plane axis (rad) (default: 0).
    pub tilt_rms: f64,
    /// Seed of every random draw (default: 1).
    pub seed: u64,
    /// How the height gain and the moment arm depend on the gap (default: [`GapLaw::NONE`],
    /// no dependence; [`GapLaw::default`] holds the values calibrated to Table 1).
    pub gap_law: GapLaw,
    /// rms in-plane placement error of each segment, radial and azimuthal (m) (default: 0).
    pub segment_position_rms: f64,
    /// rms clocking error of each segment about its normal (rad) (default: 0).
    pub segment_clocking_rms: f64,
    /// rms offset of each sensor's own gap from the segments' gap (m) (default: 0).
    pub sensor_gap_rms: f64,
    /// Bound of each sensor's temperature drift coefficient (m/K) (default: 0; the
    /// specification is 1 nm/degC).
    pub drift_per_degc: f64,
    /// Bound of each sensor's drift per week (m) (default: 0; the specification is 1 nm/week).
    pub drift_per_week: f64,
}

impl Default for SensorErrors {
    fn default() -> Self {
        Self {
            gain_rms: 0.0,
            noise_rms: 0.0,
            gap_noise_rms: 0.0,
            position_rms: 0.0,
            tilt_rms: 0.0,
            seed: 1,
            gap_law: GapLaw::NONE,
            segment_position_rms: 0.0,
            segment_clocking_rms: 0.0,
            sensor_gap_rms: 0.0,
            drift_per_degc: 0.0,
            drift_per_week: 0.0,
        }
    }
}

impl SensorErrors {
    fn check(&self) -> Result<(), M1Error> {
        for (name, x) in [
            ("gain_error_rms", self.gain_rms),
            ("noise_rms", self.noise_rms),
            ("gap_noise_rms", self.gap_noise_rms),
            ("install_position_rms", self.position_rms),
            ("install_tilt_rms", self.tilt_rms),
            ("install_segment_position_rms", self.segment_position_rms),
            ("install_segment_clocking_rms", self.segment_clocking_rms),
            ("install_sensor_gap_rms", self.sensor_gap_rms),
            ("drift_per_degc", self.drift_per_degc),
            ("drift_per_week", self.drift_per_week),
        ] {
            if !(x.is_finite() && x >= 0.0) {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: x,
                    reason: "must be finite and >= 0",
                });
            }
        }
        for (name, x) in [
            ("height_gain_per_gap", self.gap_law.height_gain_per_gap),
            ("leff_per_gap", self.gap_law.leff_per_gap),
        ] {
            if !x.is_finite() {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: x,
                    reason: "must be finite",
                });
            }
        }
        Ok(())
    }

    /// The segment and sensor installation errors as an [`Installation`] (same seed).
    fn installation(&self) -> Installation {
        Installation {
            segment_position_rms: self.segment_position_rms,
            segment_clocking_rms: self.segment_clocking_rms,
            sensor_position_rms: self.position_rms,
            sensor_tilt_rms: self.tilt_rms,
            sensor_gap_rms: self.sensor_gap_rms,
            seed: self.seed,
        }
    }
}

/// Stream tags mixed into the seed.
const STREAM_GAINS: u64 = 1;
const STREAM_INSTALL: u64 = 2;
const STREAM_NOISE: u64 = 3;
const STREAM_GAP_NOISE: u64 = 4;
const STREAM_DRIFT: u64 = 5;

/// One week (s): the time unit of the drift bound `drift_per_week`.
pub const WEEK: f64 = 7.0 * 86400.0;

/// SplitMix64 finaliser of `a` combined with `b`: well-spread seeds from small integers.
fn mix(a: u64, b: u64) -> u64 {
    let mut x = a ^ b.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

fn gauss(rng: &mut StdRng) -> f64 {
    StandardNormal.sample(rng)
}

/// Whether every value is zero (either sign), as `w.iter().all(|v| *v == 0.0)`: their bits
/// without the sign or-ed over sixteen lanes, so that the loop vectorises. The TMT in-plane
/// motion (1476 values, zero in the standard runs) is checked at every reading: 0.85 against
/// 0.11 us with the early-exit loop on the baseline's vectors (twentieth round of issue 18).
fn all_zero(w: &[f64]) -> bool {
    let chunks = w.chunks_exact(16);
    let rest = chunks
        .remainder()
        .iter()
        .fold(0u64, |a, v| a | (v.to_bits() << 1));
    chunks.fold(rest, |a, c| {
        let mut lanes = [0u64; 16];
        for (l, v) in lanes.iter_mut().zip(c) {
            *l = v.to_bits() << 1;
        }
        a | lanes.iter().fold(0, |p, q| p | q)
    }) == 0
}

/// `v` rotated by `angle` (rad) about the unit `axis` (Rodrigues).
fn rotate(v: [f64; 3], axis: [f64; 3], angle: f64) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    let cross = [
        axis[1] * v[2] - axis[2] * v[1],
        axis[2] * v[0] - axis[0] * v[2],
        axis[0] * v[1] - axis[1] * v[0],
    ];
    let d = axis[0] * v[0] + axis[1] * v[1] + axis[2] * v[2];
    std::array::from_fn(|k| v[k] * c + cross[k] * s + axis[k] * d * (1.0 - c))
}

/// The geometry with installation errors on its sensors (see the
/// [module documentation](self)), reproducible from `seed`. Segments are unchanged.
pub fn install_sensors(
    geometry: &Geometry,
    position_rms: f64,
    tilt_rms: f64,
    seed: u64,
) -> Geometry {
    let mut g = geometry.clone();
    let mut rng = StdRng::seed_from_u64(mix(seed, STREAM_INSTALL));
    for s in &mut g.sensors {
        let (a, b) = (
            position_rms * gauss(&mut rng),
            position_rms * gauss(&mut rng),
        );
        for k in 0..3 {
            s.point[k] += a * s.gap[k] + b * s.shear[k];
        }
        let (t1, t2) = (tilt_rms * gauss(&mut rng), tilt_rms * gauss(&mut rng));
        // About the gap axis (moves height and shear), then about the (new) shear axis.
        s.height = rotate(s.height, s.gap, t1);
        s.shear = rotate(s.shear, s.gap, t1);
        s.height = rotate(s.height, s.shear, t2);
        s.gap = rotate(s.gap, s.shear, t2);
    }
    g
}

/// `y += A x` for a CSC matrix, without allocating: each product added with one rounding
/// (a fused multiply-add), column after column, as the readings' row operator adds them.
pub(crate) fn mul_add(a: &SparseColMat<usize, f64>, x: &[f64], y: &mut [f64]) {
    let s = a.symbolic();
    let (cp, ri, v) = (s.col_ptr(), s.row_idx(), a.val());
    for (j, &xj) in x.iter().enumerate() {
        if xj != 0.0 {
            for k in cp[j]..cp[j + 1] {
                y[ri[k]] = v[k].mul_add(xj, y[ri[k]]);
            }
        }
    }
}

/// `||A - B||_F / ||B||_F` of two CSC matrices of the same shape (rows sorted in each column).
fn relative_difference(a: &SparseColMat<usize, f64>, b: &SparseColMat<usize, f64>) -> f64 {
    let (sa, sb) = (a.symbolic(), b.symbolic());
    let (ca, ra, va) = (sa.col_ptr(), sa.row_idx(), a.val());
    let (cb, rb, vb) = (sb.col_ptr(), sb.row_idx(), b.val());
    let (mut diff, mut norm) = (0.0, 0.0);
    for j in 0..a.ncols().min(b.ncols()) {
        let (mut p, mut q) = (ca[j], cb[j]);
        while p < ca[j + 1] || q < cb[j + 1] {
            let r_a = if p < ca[j + 1] { ra[p] } else { usize::MAX };
            let r_b = if q < cb[j + 1] { rb[q] } else { usize::MAX };
            let (x, y) = match r_a.cmp(&r_b) {
                std::cmp::Ordering::Less => {
                    p += 1;
                    (va[p - 1], 0.0)
                }
                std::cmp::Ordering::Greater => {
                    q += 1;
                    (0.0, vb[q - 1])
                }
                std::cmp::Ordering::Equal => {
                    p += 1;
                    q += 1;
                    (va[p - 1], vb[q - 1])
                }
            };
            diff += (x - y) * (x - y);
            norm += y * y;
        }
    }
    if norm > 0.0 {
        (diff / norm).sqrt()
    } else {
        0.0
    }
}

/// Columns per block of [`BlockRows`]: a segment's three actuators (`z`) or its three in-plane
/// coordinates (`w`), the columns a sensor reads of each of its two segments.
const BLOCK: usize = 3;

/// Lanes of a [`BlockRows`] coefficient: the height and the gap coefficient of each of a pair
/// of rows, `[h_a, g_a, h_b, g_b]` (one AVX2 register of `f64`; narrower instruction sets take
/// two registers or scalars).
const LANES: usize = 4;

/// The readings' operators `[S A_hz  S A_hw]` and `[A_gz  A_gw]` stored by rows, for
/// [`EdgeSensors::read_into_at`]; see [`BlockRows`] for the layout.
///
/// Why: the reading runs every sample (1 kHz) in the closed loop. Scattering the four CSC
/// blocks column by column (`y[r] += v x_j`) costs a dependent read-modify-write of `y` per
/// entry and four passes over the outputs; gathering by rows reads `x` at the row's columns,
/// keeps the sums in registers and writes `y[n]` and `gap[n]` once. The `z` and `w` parts are
/// kept apart, so a reading with `w = 0` skips the `w` part.
///
/// Each row's sums run over its columns in increasing order, the `z` part first: the order in
/// which the column scatter ([`mul_add`]) accumulates, each product with one rounding as there,
/// so the readings are the same bit for bit (for finite inputs: the explicit zeros of the
/// padding add `0 x = ±0`, which leaves a sum unchanged).
#[derive(Debug, Clone)]
struct RowOperator {
    /// The `z` part (`S A_hz` and `A_gz`).
    z: BlockRows,
    /// The `w` part (`S A_hw` and `A_gw`).
    w: BlockRows,
}

/// One part of a [`RowOperator`]: two `n_s x n_a` matrices (height and gap) on their union
/// pattern, by rows, two rows at a time, in blocks of [`BLOCK`] consecutive columns.
///
/// Why this layout: a sensor's row holds the three columns of each of its two segments, its
/// height and its gap depend on the same columns, and the two sensors of an edge (rows `2 e`
/// and `2 e + 1` of the geometry) read the same two segments. So rows `2 p` and `2 p + 1` are
/// stored together on the union of their patterns, in whole blocks: one block index (`u32`,
/// to cut memory traffic further) and one range check per block of 3 columns, and per column
/// one `x` value broadcast against the four coefficients `[h_a, g_a, h_b, g_b]`, i.e. one
/// vector multiply and add for four multiply-adds, with no shuffling of `x`. Every pair holds
/// `width` blocks (the most any pair has; shorter pairs, and the missing row of a last single
/// row, are padded with zeros in block 0), so the loops have fixed trip counts. On the sensors'
/// own patterns every pair holds the same two segments' blocks, so nothing is padded and a
/// non-finite input reaches only the readings that depend on it (tested); on other patterns
/// an explicit zero times a non-finite input would carry it to the pair's other row.
#[derive(Debug, Clone)]
struct BlockRows {
    /// Blocks per row pair.
    width: usize,
    /// Each block's index `c / BLOCK` (its columns are `c..c + BLOCK`): pair `p`'s blocks are
    /// `p width..(p + 1) width`, in increasing column order.
    block: Vec<u32>,
    /// The coefficients of each block's column `k`, `[h_a, g_a, h_b, g_b]` (rows `a = 2 p`,
    /// `b = 2 p + 1`).
    val: Vec<[[f64; LANES]; BLOCK]>,
}

impl BlockRows {
    /// The rows of `height` and `gap` (same shape, `n_a` columns a multiple of [`BLOCK`]) on
    /// their union pattern.
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] if the number of columns is not a multiple of [`BLOCK`] or
    /// does not fit in `u32`.
    fn new(
        height: &SparseColMat<usize, f64>,
        gap: &SparseColMat<usize, f64>,
    ) -> Result<Self, M1Error> {
        let (nrows, ncols) = (height.nrows(), height.ncols());
        if ncols % BLOCK != 0 || u32::try_from(ncols).is_err() {
            return Err(M1Error::InvalidInput(format!(
                "{ncols} sensor-matrix columns: not a multiple of {BLOCK} that fits in u32"
            )));
        }
        // Each row pair's blocks as (block index, coefficients).
        let mut pairs: Vec<Vec<(u32, [[f64; LANES]; BLOCK])>> = vec![Vec::new(); nrows.div_ceil(2)];
        for (a, output) in [(height, 0), (gap, 1)] {
            let sym = a.symbolic();
            let (cp, ri, v) = (sym.col_ptr(), sym.row_idx(), a.val());
            for j in 0..ncols.min(a.ncols()) {
                // `j < ncols`, which fits in u32 (checked above).
                let first = (j / BLOCK) as u32;
                for k in cp[j]..cp[j + 1] {
                    let (pair, lane) = (&mut pairs[ri[k] / 2], 2 * (ri[k] % 2) + output);
                    let b = match pair.iter().position(|e| e.0 == first) {
                        Some(b) => b,
                        None => {
                            pair.push((first, [[0.0; LANES]; BLOCK]));
                            pair.len() - 1
                        }
                    };
                    pair[b].1[j % BLOCK][lane] += v[k];
                }
            }
        }
        // At least one block, so that the rows split into chunks of `width` (a zero block
        // adds nothing).
        let width = pairs.iter().map(Vec::len).max().unwrap_or(0).max(1);
        let mut out = Self {
            width,
            block: vec![0; pairs.len() * width],
            val: vec![[[0.0; LANES]; BLOCK]; pairs.len() * width],
        };
        for (p, pair) in pairs.iter_mut().enumerate() {
            pair.sort_by_key(|e| e.0);
            for (b, (first, val)) in pair.iter().enumerate() {
                out.block[p * width + b] = *first;
                out.val[p * width + b] = *val;
            }
        }
        Ok(out)
    }
}

/// Adds the products of a row pair's blocks (indices `block`, coefficients `val`) with `x`,
/// split into blocks, to its sums `acc` (`[y_a, gap_a, y_b, gap_b]`), each row's in column
/// order, each product with one rounding (a fused multiply-add: half the instructions and half
/// the latency of a product and a sum; TMT's readings 6.4 -> 5.5 us, twentieth round of issue
/// 18). `f64::mul_add` rounds once on every processor, so the sums do not depend on it.
#[inline(always)]
fn pair_add(
    block: &[u32],
    val: &[[[f64; LANES]; BLOCK]],
    x: &[[f64; BLOCK]],
    acc: &mut [f64; LANES],
) {
    for (b, v) in block.iter().zip(val) {
        // Every block lies within `x` (the construction and the caller's size check see to
        // it); the fallback only spares a bounds check with a branch.
        let xb = x.get(*b as usize).unwrap_or(&[0.0; BLOCK]);
        for (vk, xk) in v.iter().zip(xb) {
            for (a, c) in acc.iter_mut().zip(vk) {
                *a = c.mul_add(*xk, *a);
            }
        }
    }
}

impl RowOperator {
    /// The operators of the four blocks (`n_a` a multiple of [`BLOCK`]).
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] if the number of columns is not a multiple of [`BLOCK`] or
    /// does not fit in `u32`.
    fn new(
        height_z: &SparseColMat<usize, f64>,
        height_w: &SparseColMat<usize, f64>,
        gap_z: &SparseColMat<usize, f64>,
        gap_w: &SparseColMat<usize, f64>,
    ) -> Result<Self, M1Error> {
        Ok(Self {
            z: BlockRows::new(height_z, gap_z)?,
            w: BlockRows::new(height_w, gap_w)?,
        })
    }

    /// `y = [H_z H_w] [z; w] (+ y_offset)` and `gap = g_0 + [G_z G_w] [z; w] (+ gap_offset)`,
    /// in one pass over the rows; the `w` part is skipped when `w_zero` (`w` all zero). Slices
    /// have the operator's sizes (the caller checks). Dispatched to the processor's widest
    /// vectors; each lane is one sum in column order whatever their width, so the result does
    /// not depend on the processor.
    #[allow(clippy::too_many_arguments)]
    fn read(
        &self,
        z: &[f64],
        w: &[f64],
        w_zero: bool,
        nominal_gap: f64,
        y_offset: Option<&[f64]>,
        gap_offset: Option<&[f64]>,
        y: &mut [f64],
        gap: &mut [f64],
    ) {
        struct Op<'a> {
            rows: &'a RowOperator,
            x: [&'a [[f64; BLOCK]]; 2],
            w_zero: bool,
            nominal_gap: f64,
            out: [&'a mut [f64]; 2],
        }
        impl pulp::WithSimd for Op<'_> {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, _simd: S) {
                // Every sensor reads two segments: with two blocks per pair, a constant the
                // compiler sees, the block loops unroll.
                match (self.rows.z.width, self.rows.w.width) {
                    (2, 2) => self.run(2, 2),
                    (wz, ww) => self.run(wz, ww),
                }
            }
        }
        impl Op<'_> {
            /// The readings, with `wz` and `ww` blocks per row pair in the `z` and `w` parts.
            #[inline(always)]
            fn run(self, wz: usize, ww: usize) {
                let Op {
                    rows,
                    x: [z, w],
                    w_zero,
                    nominal_gap,
                    out: [y, gap],
                } = self;
                let (zb, wb) = (&rows.z, &rows.w);
                let parts = (zb.block.chunks_exact(wz).zip(zb.val.chunks_exact(wz)))
                    .zip(wb.block.chunks_exact(ww).zip(wb.val.chunks_exact(ww)));
                let outputs = y.chunks_mut(2).zip(gap.chunks_mut(2));
                for ((yp, gp), ((zs, zv), (ws, wv))) in outputs.zip(parts) {
                    let mut acc = [0.0, nominal_gap, 0.0, nominal_gap];
                    pair_add(zs, zv, z, &mut acc);
                    if !w_zero {
                        pair_add(ws, wv, w, &mut acc);
                    }
                    for (r, (yr, gr)) in yp.iter_mut().zip(gp.iter_mut()).enumerate() {
                        *yr = acc[2 * r];
                        *gr = acc[2 * r + 1];
                    }
                }
            }
        }
        pulp::Arch::new().dispatch(Op {
            rows: self,
            x: [z.as_chunks::<BLOCK>().0, w.as_chunks::<BLOCK>().0],
            w_zero,
            nominal_gap,
            out: [y, gap],
        });
        // Added last, as the column scatter did: the same sums bit for bit.
        for (out, offset) in [(y, y_offset), (gap, gap_offset)] {
            if let Some(offset) = offset {
                for (v, o) in out.iter_mut().zip(offset) {
                    *v += o;
                }
            }
        }
    }
}

/// The edge sensors of one mirror with one realisation of their errors.
#[derive(Debug, Clone)]
pub struct EdgeSensors {
    /// `S A_hz` of the installed geometry.
    height_z: SparseColMat<usize, f64>,
    /// `S A_hw` of the installed geometry.
    height_w: SparseColMat<usize, f64>,
    /// `A_gz` of the installed geometry.
    gap_z: SparseColMat<usize, f64>,
    /// `A_gw` of the installed geometry.
    gap_w: SparseColMat<usize, f64>,
    /// The four blocks above by rows, for reading (built with them; see [`RowOperator`]).
    rows: RowOperator,
    gains: Vec<f64>,
    nominal_gap: f64,
    noise_rms: f64,
    gap_noise_rms: f64,
    noise_seed: u64,
    gap_noise_seed: u64,
    install_change: f64,
    gap_law: GapLaw,
    /// The height and dihedral parts of `A_hz` and `A_hw` (without the gains), with a gap law
    /// only.
    split: Option<[HeightSplit; 2]>,
    /// The segments' placement errors `w_0` (length `n_a`, zeros without them).
    segment_w: Vec<f64>,
    /// `S A_hw w_0`, added to the readings when the segments have placement errors.
    height_offset: Option<Vec<f64>>,
    /// The installation's gap change `A_gw w_0 + dg_sensor` (zeros without it).
    gap_offset: Vec<f64>,
    gap_installed: bool,
    /// Drift coefficients per kelvin (m/K) and per week (m) (zeros without drift).
    drift_per_degc: Vec<f64>,
    drift_per_week: Vec<f64>,
    drifts: bool,
}

impl EdgeSensors {
    /// The sensors of `geometry` (its `leff` is the sensors' effective moment arm) with the
    /// errors `errors`.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming the error rms that is negative or not finite (or the
    /// gap law's coefficient that is not finite).
    pub fn new(geometry: &Geometry, errors: &SensorErrors) -> Result<Self, M1Error> {
        errors.check()?;
        let (na, ns) = (geometry.n_actuators(), geometry.n_sensors());
        let sensors_moved = errors.position_rms > 0.0 || errors.tilt_rms > 0.0;
        let segments_moved = errors.segment_position_rms > 0.0 || errors.segment_clocking_rms > 0.0;
        let gap_installed = segments_moved || errors.sensor_gap_rms > 0.0;
        let installed = if sensors_moved || gap_installed {
            Some(errors.installation().install(geometry)?)
        } else {
            None
        };
        let placed = installed.as_ref().map_or(geometry, |i| &i.geometry);
        let mut m = interaction_matrices(placed);
        let install_change = if sensors_moved {
            relative_difference(&m.a_hz, &interaction_matrices(geometry).a_hz)
        } else {
            0.0
        };
        let split = (errors.gap_law != GapLaw::NONE).then(|| {
            let mut g0 = placed.clone();
            g0.params.leff = 0.0;
            let pure = interaction_matrices(&g0);
            [
                HeightSplit::from_blocks(&pure.a_hz, &m.a_hz),
                HeightSplit::from_blocks(&pure.a_hw, &m.a_hw),
            ]
        });
        let mut rng = StdRng::seed_from_u64(mix(errors.seed, STREAM_GAINS));
        let gains: Vec<f64> = (0..ns)
            .map(|_| 1.0 + errors.gain_rms * gauss(&mut rng))
            .collect();
        for a in [&mut m.a_hz, &mut m.a_hw] {
            let rows: Vec<usize> = a.symbolic().row_idx().to_vec();
            for (v, r) in a.val_mut().iter_mut().zip(rows) {
                *v *= gains[r];
            }
        }
        let (segment_w, sensor_gap) = match installed {
            Some(i) => (i.segment_w, i.sensor_gap),
            None => (vec![0.0; na], vec![0.0; ns]),
        };
        let height_offset = segments_moved.then(|| {
            let mut y = vec![0.0; ns];
            mul_add(&m.a_hw, &segment_w, &mut y);
            y
        });
        let mut gap_offset = sensor_gap;
        mul_add(&m.a_gw, &segment_w, &mut gap_offset);
        let drifts = errors.drift_per_degc > 0.0 || errors.drift_per_week > 0.0;
        let (mut drift_per_degc, mut drift_per_week) = (vec![0.0; ns], vec![0.0; ns]);
        if drifts {
            let mut rng = StdRng::seed_from_u64(mix(errors.seed, STREAM_DRIFT));
            for (c, d) in drift_per_degc.iter_mut().zip(&mut drift_per_week) {
                *c = errors.drift_per_degc * rng.random_range(-1.0..=1.0);
                *d = errors.drift_per_week * rng.random_range(-1.0..=1.0);
            }
        }
        let rows = RowOperator::new(&m.a_hz, &m.a_hw, &m.a_gz, &m.a_gw)?;
        Ok(Self {
            rows,
            height_z: m.a_hz,
            height_w: m.a_hw,
            gap_z: m.a_gz,
            gap_w: m.a_gw,
            gains,
            nominal_gap: geometry.layout.gap,
            noise_rms: errors.noise_rms,
            gap_noise_rms: errors.gap_noise_rms,
            noise_seed: mix(errors.seed, STREAM_NOISE),
            gap_noise_seed: mix(errors.seed, STREAM_GAP_NOISE),
            install_change,
            gap_law: errors.gap_law,
            split,
            segment_w,
            height_offset,
            gap_offset,
            gap_installed,
            drift_per_degc,
            drift_per_week,
            drifts,
        })
    }

    /// Number of sensors `n_s`.
    pub fn n_sensors(&self) -> usize {
        self.height_z.nrows()
    }

    /// Number of actuators `n_a` (also the length of `w`).
    pub fn n_actuators(&self) -> usize {
        self.height_z.ncols()
    }

    /// The sensor gains `s_n = 1 + delta_n`.
    pub fn gains(&self) -> &[f64] {
        &self.gains
    }

    /// The true `S A_hz` (installed geometry, gains applied): readings per unit `z` (without
    /// the gap law).
    pub fn height_matrix(&self) -> &SparseColMat<usize, f64> {
        &self.height_z
    }

    /// The true `S A_hw`: readings per unit `w` (without the gap law).
    pub fn height_in_plane_matrix(&self) -> &SparseColMat<usize, f64> {
        &self.height_w
    }

    /// The true `A_gz` and `A_gw`: gap change per unit `z` and `w`.
    pub fn gap_matrices(&self) -> (&SparseColMat<usize, f64>, &SparseColMat<usize, f64>) {
        (&self.gap_z, &self.gap_w)
    }

    /// The nominal gap `g_0` (m).
    pub fn nominal_gap(&self) -> f64 {
        self.nominal_gap
    }

    /// `||A_installed - A_nominal||_F / ||A_nominal||_F` of the height block (0 without
    /// installation errors of the sensors).
    pub fn install_change(&self) -> f64 {
        self.install_change
    }

    /// The gap law of the height gain and the moment arm.
    pub fn gap_law(&self) -> GapLaw {
        self.gap_law
    }

    /// The segments' placement errors `w_0` (`w` layout, length `n_a`; zeros without them).
    pub fn segment_placement(&self) -> &[f64] {
        &self.segment_w
    }

    /// The constant gap change from the installation at each sensor, `A_gw w_0 + dg_sensor`
    /// (m, length `n_s`; zeros without installation errors of the segments or sensor gaps).
    pub fn installation_gap(&self) -> &[f64] {
        &self.gap_offset
    }

    /// The drift coefficients of every sensor: per kelvin of temperature change (m/K) and per
    /// week (m) (zeros without drift).
    pub fn drift_coefficients(&self) -> (&[f64], &[f64]) {
        (&self.drift_per_degc, &self.drift_per_week)
    }

    /// The readings of sample `sample` for displacements `z` and in-plane motion `w` into `y`
    /// and `gap` (length `n_s`) at zero temperature change and time (no drift), without
    /// allocating: [`Self::read_into_at`] at `(0, 0)`.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] if a slice has the wrong length (nothing is written then).
    pub fn read_into(
        &self,
        z: &[f64],
        w: &[f64],
        sample: u64,
        y: &mut [f64],
        gap: &mut [f64],
    ) -> Result<(), M1Error> {
        self.read_into_at(z, w, 0.0, 0.0, sample, y, gap)
    }

    /// The readings of sample `sample` for displacements `z` and in-plane motion `w`, at the
    /// temperature change `temperature` (K) and the time `time` (s) of the drift, into `y` and
    /// `gap` (length `n_s`), without allocating (see the [module documentation](self)).
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] if a slice has the wrong length, [`M1Error::InvalidParameter`]
    /// naming `temperature` or `time` if it is not finite (nothing is written then).
    #[allow(clippy::too_many_arguments)]
    pub fn read_into_at(
        &self,
        z: &[f64],
        w: &[f64],
        temperature: f64,
        time: f64,
        sample: u64,
        y: &mut [f64],
        gap: &mut [f64],
    ) -> Result<(), M1Error> {
        let (na, ns) = (self.n_actuators(), self.n_sensors());
        for (what, expected, found) in [
            ("z", na, z.len()),
            ("w", na, w.len()),
            ("y", ns, y.len()),
            ("gap", ns, gap.len()),
        ] {
            if expected != found {
                return Err(M1Error::SizeMismatch {
                    what,
                    expected,
                    found,
                });
            }
        }
        for (name, value) in [("temperature", temperature), ("time", time)] {
            if !value.is_finite() {
                return Err(M1Error::InvalidParameter {
                    name,
                    value,
                    reason: "must be finite",
                });
            }
        }
        // One check here saves the w part's gather on every row when w is zero (as the
        // column scatter skipped zero entries).
        let w_zero = all_zero(w);
        let gap_offset = self.gap_installed.then_some(self.gap_offset.as_slice());
        match &self.split {
            None => self.rows.read(
                z,
                w,
                w_zero,
                self.nominal_gap,
                self.height_offset.as_deref(),
                gap_offset,
                y,
                gap,
            ),
            Some([split_z, split_w]) => {
                // The gap (the law needs it before the height; `y` is overwritten below).
                self.rows
                    .read(z, w, w_zero, self.nominal_gap, None, gap_offset, y, gap);
                let law = &self.gap_law;
                for (n, v) in y.iter_mut().enumerate() {
                    let dg = gap[n] - self.nominal_gap;
                    let (hz, lz) = split_z.row(n, |c| z[c]);
                    let (hw, lw) = split_w.row(n, |c| w[c] + self.segment_w[c]);
                    let (h, l) = (hz + hw, lz + lw);
                    *v = self.gains[n]
                        * (1.0 + law.height_gain_per_gap * dg)
                        * (h + (1.0 + law.leff_per_gap * dg) * l);
                }
            }
        }
        if self.drifts {
            let weeks = time / WEEK;
            for ((v, c), d) in y
                .iter_mut()
                .zip(&self.drift_per_degc)
                .zip(&self.drift_per_week)
            {
                *v += c * temperature + d * weeks;
            }
        }
        if self.noise_rms > 0.0 {
            let mut rng = StdRng::seed_from_u64(mix(self.noise_seed, sample));
            for v in y.iter_mut() {
                *v += self.noise_rms * gauss(&mut rng);
            }
        }
        if self.gap_noise_rms > 0.0 {
            let mut rng = StdRng::seed_from_u64(mix(self.gap_noise_seed, sample));
            for v in gap.iter_mut() {
                *v += self.gap_noise_rms * gauss(&mut rng);
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::geometry::GeometryParams;
    use crate::aperture::layout::Layout;

    /// `all_zero` is `all(|v| *v == 0.0)` for zeros of either sign and any other value
    /// (subnormal, infinite, NaN) at any position, around the lane count.
    #[test]
    fn all_zero_is_the_comparison_with_zero() {
        let others = [
            5e-324,
            -5e-324,
            1.0,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ];
        for n in [0usize, 1, 15, 16, 17, 31, 32, 33, 100] {
            let zeros: Vec<f64> = (0..n)
                .map(|k| if k % 3 == 0 { -0.0 } else { 0.0 })
                .collect();
            assert!(all_zero(&zeros), "{n}");
            for at in 0..n {
                for v in others {
                    let mut w = zeros.clone();
                    w[at] = v;
                    assert_eq!(all_zero(&w), w.iter().all(|x| *x == 0.0), "{n} {at} {v}");
                    assert!(!all_zero(&w), "{n} {at} {v}");
                }
            }
        }
    }

    fn keck() -> Geometry {
        let l = Layout::preset("keck").unwrap();
        Geometry::new(&l, GeometryParams::for_layout(&l)).unwrap()
    }

    /// A deterministic vector of amplitude `scale`.
    fn pattern(n: usize, scale: f64, phase: f64) -> Vec<f64> {
        (0..n)
            .map(|i| scale * ((i as f64 * 0.731 + phase).sin() + 0.3 * (i as f64 * 2.17).cos()))
            .collect()
    }

    fn read_at(s: &EdgeSensors, z: &[f64], w: &[f64], t: f64, time: f64) -> (Vec<f64>, Vec<f64>) {
        let ns = s.n_sensors();
        let (mut y, mut gap) = (vec![0.0; ns], vec![0.0; ns]);
        s.read_into_at(z, w, t, time, 3, &mut y, &mut gap).unwrap();
        (y, gap)
    }

    fn read(s: &EdgeSensors, z: &[f64], w: &[f64]) -> (Vec<f64>, Vec<f64>) {
        read_at(s, z, w, 0.0, 0.0)
    }

    /// `y = A x` of a CSC matrix with row scales, column by column, as the sensors accumulate.
    fn accumulate(a: &SparseColMat<usize, f64>, scale: &[f64], x: &[f64], y: &mut [f64]) {
        let s = a.symbolic();
        for (j, &xj) in x.iter().enumerate() {
            if xj != 0.0 {
                for k in s.col_ptr()[j]..s.col_ptr()[j + 1] {
                    let r = s.row_idx()[k];
                    y[r] = (scale[r] * a.val()[k]).mul_add(xj, y[r]);
                }
            }
        }
    }

    fn max_abs(x: &[f64]) -> f64 {
        x.iter().fold(0.0, |m, v| m.max(v.abs()))
    }

    /// With the new error sources at their defaults the readings are, bit for bit, those of the
    /// interaction matrices with the gains applied: `S (A_hz z + A_hw w)` and
    /// `g_0 + A_gz z + A_gw w`, accumulated in the same order.
    #[test]
    fn the_defaults_reproduce_the_previous_readings_bit_for_bit() {
        let g = keck();
        let (na, ns) = (g.n_actuators(), g.n_sensors());
        let z = pattern(na, 1e-6, 0.1);
        let w = pattern(na, 1e-5, 1.3);
        for errors in [
            SensorErrors::default(),
            SensorErrors {
                gain_rms: 0.01,
                seed: 5,
                ..SensorErrors::default()
            },
        ] {
            let s = EdgeSensors::new(&g, &errors).unwrap();
            assert_eq!(s.gap_law(), GapLaw::NONE);
            let m = interaction_matrices(&g);
            let (mut y, mut gap) = (vec![0.0; ns], vec![g.layout.gap; ns]);
            accumulate(&m.a_hz, s.gains(), &z, &mut y);
            accumulate(&m.a_hw, s.gains(), &w, &mut y);
            let ones = vec![1.0; ns];
            accumulate(&m.a_gz, &ones, &z, &mut gap);
            accumulate(&m.a_gw, &ones, &w, &mut gap);
            let (ys, gs) = read(&s, &z, &w);
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&ys), bits(&y));
            assert_eq!(bits(&gs), bits(&gap));
            // The old entry point is the new one at zero temperature change and time.
            let (mut y2, mut gap2) = (vec![0.0; ns], vec![0.0; ns]);
            s.read_into(&z, &w, 3, &mut y2, &mut gap2).unwrap();
            assert_eq!(bits(&y2), bits(&ys));
            assert_eq!(bits(&gap2), bits(&gs));
            assert!(s.installation_gap().iter().all(|d| *d == 0.0));
            assert!(s.segment_placement().iter().all(|d| *d == 0.0));
        }
        // The height split agrees with the A-matrix to round-off.
        let split = HeightSplit::new(&g);
        let ones = vec![1.0; ns];
        let mut ya = vec![0.0; ns];
        split.mul_into(&ones, &ones, &z, &mut ya).unwrap();
        let (yz, _) = read(
            &EdgeSensors::new(&g, &SensorErrors::default()).unwrap(),
            &z,
            &vec![0.0; na],
        );
        for (a, b) in ya.iter().zip(&yz) {
            assert!((a - b).abs() <= 1e-14 * max_abs(&yz));
        }
    }

    /// A uniform expansion of the segment pattern opens every gap by (nearly) the same amount;
    /// with a gap law each reading scales by its gain `1 + gamma_h dg` (kappa = 0), and with
    /// both coefficients the readings are those of the height split with the law's gains and
    /// moment arms.
    #[test]
    fn a_gap_law_scales_the_readings_by_its_gain() {
        let g = keck();
        let (na, ns) = (g.n_actuators(), g.n_sensors());
        let z = pattern(na, 1e-6, 0.4);
        // Each segment slides radially by eps times its distance from the axis.
        let eps = 2e-5;
        let mut w = vec![0.0; na];
        for (i, f) in g.segments.iter().enumerate() {
            w[3 * i] = eps * f.centre[0].hypot(f.centre[1]);
        }
        let ideal = EdgeSensors::new(&g, &SensorErrors::default()).unwrap();
        let (y0, gap0) = read(&ideal, &z, &w);
        let dg: Vec<f64> = gap0.iter().map(|x| x - g.layout.gap).collect();
        let mean = dg.iter().sum::<f64>() / ns as f64;
        assert!(mean > 1e-5, "the gaps open: {mean}");
        assert!(
            dg.iter().all(|d| (d - mean).abs() < 0.05 * mean),
            "uniform gap change"
        );
        let gamma = -210.0;
        let law = GapLaw {
            height_gain_per_gap: gamma,
            leff_per_gap: 0.0,
        };
        let s = EdgeSensors::new(
            &g,
            &SensorErrors {
                gap_law: law,
                ..SensorErrors::default()
            },
        )
        .unwrap();
        let (y, gap) = read(&s, &z, &w);
        assert_eq!(gap, gap0, "the law leaves the gap reading alone");
        let scale = max_abs(&y0);
        for n in 0..ns {
            let expected = (1.0 + gamma * dg[n]) * y0[n];
            assert!((y[n] - expected).abs() <= 1e-13 * scale, "y[{n}]");
            assert!((y[n] - (1.0 + gamma * mean) * y0[n]).abs() <= 1e-3 * scale);
        }
        // Both coefficients, gain errors and sensor gap offsets, z alone: the height split with
        // the gains s_n (1 + gamma dg_n) and the arms 1 + kappa dg_n.
        let errors = SensorErrors {
            gap_law: GapLaw::default(),
            gain_rms: 0.01,
            sensor_gap_rms: 2e-5,
            seed: 9,
            ..SensorErrors::default()
        };
        let s = EdgeSensors::new(&g, &errors).unwrap();
        let zero = vec![0.0; na];
        let (y, gap) = read(&s, &z, &zero);
        let dg: Vec<f64> = gap.iter().map(|x| x - g.layout.gap).collect();
        assert!(dg.iter().any(|d| d.abs() > 1e-5));
        let (mut gain, mut leff) = GapLaw::default().factors(&dg);
        for (a, b) in gain.iter_mut().zip(s.gains()) {
            *a *= b;
        }
        let split = HeightSplit::new(&g);
        let mut expected = vec![0.0; ns];
        split.mul_into(&gain, &leff, &z, &mut expected).unwrap();
        for n in 0..ns {
            assert!(
                (y[n] - expected[n]).abs() <= 1e-13 * max_abs(&expected),
                "y[{n}]"
            );
        }
        // The arm factor matters: without it the readings differ.
        leff.fill(1.0);
        split.mul_into(&gain, &leff, &z, &mut expected).unwrap();
        assert!(
            y.iter()
                .zip(&expected)
                .any(|(a, b)| (a - b).abs() > 1e-6 * max_abs(&expected))
        );
    }

    /// Each sensor drifts by c_n T + d_n t / week, with c_n and d_n within their bounds,
    /// reproducibly from the seed and independently of the other draws.
    #[test]
    fn drift_grows_linearly_with_temperature_and_time_within_the_bounds() {
        let g = keck();
        let (na, ns) = (g.n_actuators(), g.n_sensors());
        let errors = SensorErrors {
            drift_per_degc: 1e-9,
            drift_per_week: 2e-9,
            gain_rms: 0.01,
            seed: 4,
            ..SensorErrors::default()
        };
        let s = EdgeSensors::new(&g, &errors).unwrap();
        let zero = vec![0.0; na];
        let (y, _) = read(&s, &zero, &zero);
        assert!(y.iter().all(|v| *v == 0.0), "no drift at T = 0, t = 0");
        let (c, d) = s.drift_coefficients();
        assert!(c.iter().all(|x| x.abs() <= 1e-9) && d.iter().all(|x| x.abs() <= 2e-9));
        // Uniform draws: they fill the interval (168 draws), centred.
        assert!(max_abs(c) > 0.9e-9 && max_abs(d) > 1.8e-9);
        assert!((c.iter().sum::<f64>() / ns as f64).abs() < 0.2e-9);
        let (y1, _) = read_at(&s, &zero, &zero, 2.0, 0.0);
        let (y2, _) = read_at(&s, &zero, &zero, 4.0, 0.0);
        let (yw, gw) = read_at(&s, &zero, &zero, 0.0, 3.0 * WEEK);
        let (yb, _) = read_at(&s, &zero, &zero, 2.0, 3.0 * WEEK);
        for n in 0..ns {
            assert_eq!(y1[n], 2.0 * c[n]);
            assert!((y2[n] - 2.0 * y1[n]).abs() <= 1e-24);
            assert!((yw[n] - 3.0 * d[n]).abs() <= 1e-24);
            assert!((yb[n] - y1[n] - yw[n]).abs() <= 1e-24);
            assert!(y2[n].abs() <= 4e-9 && yw[n].abs() <= 6e-9);
        }
        assert!(
            gw.iter().all(|x| *x == g.layout.gap),
            "the gap does not drift"
        );
        // The drift draws leave the gains alone, and another seed draws others.
        let no_drift = SensorErrors {
            drift_per_degc: 0.0,
            drift_per_week: 0.0,
            ..errors
        };
        assert_eq!(EdgeSensors::new(&g, &no_drift).unwrap().gains(), s.gains());
        let other = EdgeSensors::new(&g, &SensorErrors { seed: 5, ..errors }).unwrap();
        assert_ne!(other.drift_coefficients().0, c);
        // A temperature or time that is not finite is refused, naming it.
        let mut out = (vec![0.0; ns], vec![0.0; ns]);
        let e = s
            .read_into_at(&zero, &zero, f64::NAN, 0.0, 0, &mut out.0, &mut out.1)
            .unwrap_err();
        assert!(e.to_string().contains("temperature"), "{e}");
    }

    /// Segment placement errors move the segments with their sensor halves: the gaps change by
    /// `A_gw w_0` and the readings by `S A_hw w_0`, as if `w_0` were added to `w`; the sensors'
    /// own gap offsets add to the gap. The draws are [`Installation`]'s.
    #[test]
    fn segment_installation_changes_the_gaps_by_a_gw_w0() {
        let g = keck();
        let (na, ns) = (g.n_actuators(), g.n_sensors());
        let errors = SensorErrors {
            segment_position_rms: 1e-4,
            segment_clocking_rms: 1e-4,
            seed: 6,
            ..SensorErrors::default()
        };
        let s = EdgeSensors::new(&g, &errors).unwrap();
        let inst = Installation {
            segment_position_rms: 1e-4,
            segment_clocking_rms: 1e-4,
            seed: 6,
            ..Installation::default()
        }
        .install(&g)
        .unwrap();
        assert_eq!(s.segment_placement(), inst.segment_w.as_slice());
        assert_eq!(
            s.install_change(),
            0.0,
            "the sensors sit on their nominal places"
        );
        let w0 = &inst.segment_w;
        let m = interaction_matrices(&g);
        let (mut gw0, mut hw0) = (vec![0.0; ns], vec![0.0; ns]);
        mul_add(&m.a_gw, w0, &mut gw0);
        mul_add(&m.a_hw, w0, &mut hw0);
        assert!(max_abs(&gw0) > 1e-5);
        let ideal = EdgeSensors::new(&g, &SensorErrors::default()).unwrap();
        let z = pattern(na, 1e-6, 0.7);
        let w = pattern(na, 1e-5, 0.2);
        let (y0, gap0) = read(&ideal, &z, &w);
        let (y, gap) = read(&s, &z, &w);
        for n in 0..ns {
            assert!((gap[n] - gap0[n] - gw0[n]).abs() <= 1e-18, "gap[{n}]");
            assert!((y[n] - y0[n] - hw0[n]).abs() <= 1e-18, "y[{n}]");
            assert!((s.installation_gap()[n] - inst.dgap[n]).abs() <= 1e-18);
        }
        // The same as the ideal sensors reading w + w0.
        let shifted: Vec<f64> = w.iter().zip(w0).map(|(a, b)| a + b).collect();
        let (ys, gaps) = read(&ideal, &z, &shifted);
        for n in 0..ns {
            assert!((gap[n] - gaps[n]).abs() <= 1e-17, "{}", gap[n] - gaps[n]);
            assert!((y[n] - ys[n]).abs() <= 1e-18, "{}", y[n] - ys[n]);
        }
        // With a gap law too: the law sees the installed gap and scales the w0 reading.
        let law = SensorErrors {
            gap_law: GapLaw {
                height_gain_per_gap: -210.0,
                leff_per_gap: 0.0,
            },
            ..errors
        };
        let (yl, gapl) = read(&EdgeSensors::new(&g, &law).unwrap(), &z, &w);
        assert_eq!(gapl, gap);
        for n in 0..ns {
            let dg = gap[n] - g.layout.gap;
            assert!((yl[n] - (1.0 - 210.0 * dg) * y[n]).abs() <= 1e-13 * max_abs(&y));
        }
        // The sensors' own gap offsets add to the gap, drawn apart from the segments.
        let both = SensorErrors {
            sensor_gap_rms: 1e-5,
            ..errors
        };
        let sb = EdgeSensors::new(&g, &both).unwrap();
        assert_eq!(sb.segment_placement(), w0.as_slice());
        let (_, gapb) = read(&sb, &z, &w);
        let rms = (gapb
            .iter()
            .zip(&gap)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            / ns as f64)
            .sqrt();
        assert!((rms / 1e-5 - 1.0).abs() < 0.3, "{rms}");
        let bad = SensorErrors {
            segment_clocking_rms: -1.0,
            ..errors
        };
        let e = EdgeSensors::new(&g, &bad).unwrap_err();
        assert!(
            e.to_string().contains("install_segment_clocking_rms"),
            "{e}"
        );
    }

    /// `A` as a dense row-major matrix, from its CSC entries.
    fn dense(a: &SparseColMat<usize, f64>) -> Vec<Vec<f64>> {
        let mut d = vec![vec![0.0; a.ncols()]; a.nrows()];
        for t in a.triplet_iter() {
            d[t.row][t.col] += *t.val;
        }
        d
    }

    /// `sum_c a[n][c] x[c]` and `sum_c |a[n][c] x[c]|` of a dense row.
    fn dot_and_scale(row: &[f64], x: &[f64]) -> (f64, f64) {
        row.iter()
            .zip(x)
            .fold((0.0, 0.0), |(s, m), (a, b)| (s + a * b, m + (a * b).abs()))
    }

    /// `|a - b| <= 1e-12 scale` for each entry, with `scale` the sum of the magnitudes of the
    /// terms summed (the size of the round-off of any summation order).
    fn assert_close(what: &str, a: &[f64], b: &[f64], scale: &[f64]) {
        for (n, ((a, b), s)) in a.iter().zip(b).zip(scale).enumerate() {
            assert!(
                (a - b).abs() <= 1e-12 * s,
                "{what}[{n}]: {a} vs {b} (scale {s})"
            );
        }
    }

    /// The readings (row-gathered) equal a dense reference `H_z z + H_w (w + w_0)` and
    /// `g_0 + G_z z + G_w w + dg_installed` built from the CSC matrices, to round-off: for
    /// ideal sensors, with gain and installation errors of the sensors and the segments (the
    /// offsets), on the curved and the flat mirror (ideal: `A_gz = 0`, `A_hw = 0`, so the gap's
    /// pattern differs from the height's), with `w` random and zero.
    #[test]
    fn the_readings_equal_a_dense_reference() {
        let l = Layout::preset("keck").unwrap();
        let mut flat = GeometryParams::for_layout(&l);
        flat.flat = true;
        let installed = SensorErrors {
            gain_rms: 0.01,
            position_rms: 1e-3,
            tilt_rms: 1e-3,
            segment_position_rms: 1e-4,
            segment_clocking_rms: 1e-4,
            sensor_gap_rms: 1e-5,
            seed: 11,
            ..SensorErrors::default()
        };
        let mut rng = StdRng::seed_from_u64(42);
        for (params, errors) in [
            (GeometryParams::for_layout(&l), SensorErrors::default()),
            (GeometryParams::for_layout(&l), installed),
            (flat, installed),
            (flat, SensorErrors::default()),
        ] {
            let g = Geometry::new(&l, params).unwrap();
            let s = EdgeSensors::new(&g, &errors).unwrap();
            let (na, ns) = (s.n_actuators(), s.n_sensors());
            let (gz, gw) = s.gap_matrices();
            if params.flat && errors == SensorErrors::default() {
                // The ideal flat mirror: no gap from z, no height from w.
                assert!(gz.val().is_empty() && s.height_in_plane_matrix().val().is_empty());
            }
            let [hz, hw, gz, gw] =
                [s.height_matrix(), s.height_in_plane_matrix(), gz, gw].map(dense);
            let w0 = s.segment_placement().to_vec();
            let z: Vec<f64> = (0..na).map(|_| 1e-6 * gauss(&mut rng)).collect();
            let random: Vec<f64> = (0..na).map(|_| 1e-5 * gauss(&mut rng)).collect();
            for w in [random, vec![0.0; na]] {
                let shifted: Vec<f64> = w.iter().zip(&w0).map(|(a, b)| a + b).collect();
                let (mut y_ref, mut y_scale) = (vec![0.0; ns], vec![0.0; ns]);
                let (mut gap_ref, mut gap_scale) = (vec![0.0; ns], vec![0.0; ns]);
                for n in 0..ns {
                    let (a, sa) = dot_and_scale(&hz[n], &z);
                    let (b, sb) = dot_and_scale(&hw[n], &shifted);
                    (y_ref[n], y_scale[n]) = (a + b, sa + sb);
                    let (a, sa) = dot_and_scale(&gz[n], &z);
                    let (b, sb) = dot_and_scale(&gw[n], &w);
                    let d = s.installation_gap()[n];
                    gap_ref[n] = g.layout.gap + a + b + d;
                    gap_scale[n] = g.layout.gap + sa + sb + d.abs();
                }
                let (y, gap) = read(&s, &z, &w);
                assert_close("y", &y, &y_ref, &y_scale);
                assert_close("gap", &gap, &gap_ref, &gap_scale);
            }
        }
    }

    /// A non-finite displacement reaches only the readings that depend on it (in process,
    /// without the FMU's input check; Keck and TMT, columns of a few segments): the row pairs
    /// of the sensors' patterns hold the same blocks, so no explicit zero meets it.
    #[test]
    fn a_non_finite_input_reaches_only_its_readings() {
        for name in ["keck", "tmt"] {
            let l = Layout::preset(name).unwrap();
            let g = Geometry::new(&l, GeometryParams::for_layout(&l)).unwrap();
            let s = EdgeSensors::new(&g, &SensorErrors::default()).unwrap();
            let (na, ns) = (s.n_actuators(), s.n_sensors());
            let (gz, _) = s.gap_matrices();
            let [hz, gz] = [s.height_matrix(), gz].map(dense);
            let w = vec![0.0; na];
            for c in [0, 1, 2, na / 2, na - 1] {
                let mut z = pattern(na, 1e-7, 0.3);
                z[c] = f64::NAN;
                let (y, gap) = read(&s, &z, &w);
                for n in 0..ns {
                    assert_eq!(
                        y[n].is_nan(),
                        hz[n][c] != 0.0,
                        "{name}: y[{n}], NaN in z[{c}]"
                    );
                    assert_eq!(
                        gap[n].is_nan(),
                        gz[n][c] != 0.0,
                        "{name}: gap[{n}], NaN in z[{c}]"
                    );
                }
            }
        }
    }

    /// A CSC matrix from a dense row-major one (its zeros left out).
    fn sparse(d: &[Vec<f64>]) -> SparseColMat<usize, f64> {
        let (nrows, ncols) = (d.len(), d[0].len());
        let (mut col_ptr, mut row_idx, mut val) = (vec![0], Vec::new(), Vec::new());
        for c in 0..ncols {
            for (r, row) in d.iter().enumerate() {
                if row[c] != 0.0 {
                    row_idx.push(r);
                    val.push(row[c]);
                }
            }
            col_ptr.push(row_idx.len());
        }
        SparseColMat::new(
            faer::sparse::SymbolicSparseColMat::new_checked(nrows, ncols, col_ptr, None, row_idx),
            val,
        )
    }

    /// The row operator on matrices of no sensor geometry: an odd number of rows, row pairs
    /// touching different and more than two blocks, height and gap patterns unrelated, with
    /// and without offsets and `w`, equals the dense products to round-off; and the scatter's
    /// sums bit for bit.
    #[test]
    fn the_row_operator_equals_dense_products_on_any_pattern() {
        let (nrows, ncols) = (7, 12);
        let mut rng = StdRng::seed_from_u64(3);
        let mut random = |density: f64| -> Vec<Vec<f64>> {
            (0..nrows)
                .map(|_| {
                    (0..ncols)
                        .map(|_| {
                            if rng.random_range(0.0..1.0) < density {
                                gauss(&mut rng)
                            } else {
                                0.0
                            }
                        })
                        .collect()
                })
                .collect()
        };
        let [hz, hw, gz, gw] = [random(0.3), random(0.5), random(0.2), random(0.0)];
        let op = RowOperator::new(&sparse(&hz), &sparse(&hw), &sparse(&gz), &sparse(&gw)).unwrap();
        assert!(op.z.width > 2, "the general path: {}", op.z.width);
        let mut rng = StdRng::seed_from_u64(4);
        let mut draw = |n: usize| -> Vec<f64> { (0..n).map(|_| gauss(&mut rng)).collect() };
        let (z, w, y_off, gap_off) = (draw(ncols), draw(ncols), draw(nrows), draw(nrows));
        let g0 = 0.5;
        for (w, offsets) in [(w.clone(), false), (w, true), (vec![0.0; ncols], true)] {
            let w_zero = w.iter().all(|v| *v == 0.0);
            let (yo, go) = if offsets {
                (Some(y_off.as_slice()), Some(gap_off.as_slice()))
            } else {
                (None, None)
            };
            let (mut y, mut gap) = (vec![f64::NAN; nrows], vec![f64::NAN; nrows]);
            op.read(&z, &w, w_zero, g0, yo, go, &mut y, &mut gap);
            let (mut y_scatter, mut gap_scatter) = (vec![0.0; nrows], vec![g0; nrows]);
            mul_add(&sparse(&hz), &z, &mut y_scatter);
            mul_add(&sparse(&hw), &w, &mut y_scatter);
            mul_add(&sparse(&gz), &z, &mut gap_scatter);
            mul_add(&sparse(&gw), &w, &mut gap_scatter);
            for n in 0..nrows {
                let (a, sa) = dot_and_scale(&hz[n], &z);
                let (b, sb) = dot_and_scale(&hw[n], &w);
                let o = yo.map_or(0.0, |o| o[n]);
                assert!(
                    (y[n] - (a + b + o)).abs() <= 1e-12 * (sa + sb + o.abs()),
                    "y[{n}]"
                );
                let (a, sa) = dot_and_scale(&gz[n], &z);
                let (b, sb) = dot_and_scale(&gw[n], &w);
                let o = go.map_or(0.0, |o| o[n]);
                let scale = g0 + sa + sb + o.abs();
                assert!(
                    (gap[n] - (g0 + a + b + o)).abs() <= 1e-12 * scale,
                    "gap[{n}]"
                );
            }
            for (out, offset) in [(&mut y_scatter, yo), (&mut gap_scatter, go)] {
                if let Some(offset) = offset {
                    for (v, o) in out.iter_mut().zip(offset) {
                        *v += o;
                    }
                }
            }
            let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&y), bits(&y_scatter));
            assert_eq!(bits(&gap), bits(&gap_scatter));
        }
        // Columns that do not split into segments' blocks are refused.
        let odd = sparse(&vec![vec![1.0; 4]; 2]);
        assert!(RowOperator::new(&odd, &odd, &odd, &odd).is_err());
    }
}
