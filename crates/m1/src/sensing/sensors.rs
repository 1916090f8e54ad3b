//! Edge-sensor readings with gain errors, noise and installation errors.
//!
//! # Readings
//!
//! For out-of-plane displacements `z` at the actuators (m, length `n_a = 3N`) and in-plane
//! segment motion `w` (`w[3 i]` radial m, `w[3 i + 1]` azimuthal m, `w[3 i + 2]` clocking rad;
//! see [`crate::sensing::interaction`] for the kinematics), sensor `n` reads
//!
//! ```text
//! y_n   = s_n (A_hz z + A_hw w)_n + sigma_y  nu_n        (m: height + Leff x dihedral)
//! gap_n = g_0 + (A_gz z + A_gw w)_n + sigma_g mu_n        (m: gap)
//! ```
//!
//! - the interaction blocks are those of the *installed* geometry (below); `A_hz = A` is the
//!   A-matrix, `A_gz` vanishes on a flat mirror and couples out-of-plane motion into the gap on
//!   the curved prescription;
//! - `g_0` is the layout's nominal gap;
//! - `s_n = 1 + delta_n`, `delta_n ~ N(0, gain_rms)`: sensor gain errors `S = I + delta_S`, drawn
//!   once per seed; they scale the height reading only;
//! - `nu_n`, `mu_n ~ N(0, 1)`: white noise, drawn once per sample: sample `k`'s noise comes
//!   from a generator seeded by `(seed, k)`, so it does not depend on how the time axis is cut
//!   into steps, and any sample can be recomputed;
//! - installation errors ([`install_sensors`]): each sensor point moved in its tangent plane by
//!   `N(0, position_rms)` along the gap and the shear directions, and the sensor's frame
//!   (height, gap, shear) rotated by `N(0, tilt_rms)` about the gap and then the shear axis, as
//!   [`crate::analysis::quasistatic`]'s `SensorInstall` perturbation (which tilts the height axis only).
//!
//! Each stream has its own seed derived from `seed` (gains, installation, height noise, gap
//! noise), so switching one error source on leaves the others' draws unchanged.

use faer::sparse::SparseColMat;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::sensing::interaction::interaction_matrices;

/// The error sources of the edge sensors (all zero by default: ideal sensors).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
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
        ] {
            if !(x.is_finite() && x >= 0.0) {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: x,
                    reason: "must be finite and >= 0",
                });
            }
        }
        Ok(())
    }
}

/// Stream tags mixed into the seed.
const STREAM_GAINS: u64 = 1;
const STREAM_INSTALL: u64 = 2;
const STREAM_NOISE: u64 = 3;
const STREAM_GAP_NOISE: u64 = 4;

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

/// `y += A x` for a CSC matrix, without allocating.
fn mul_add(a: &SparseColMat<usize, f64>, x: &[f64], y: &mut [f64]) {
    let s = a.symbolic();
    let (cp, ri, v) = (s.col_ptr(), s.row_idx(), a.val());
    for (j, &xj) in x.iter().enumerate() {
        if xj != 0.0 {
            for k in cp[j]..cp[j + 1] {
                y[ri[k]] += v[k] * xj;
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
    gains: Vec<f64>,
    nominal_gap: f64,
    noise_rms: f64,
    gap_noise_rms: f64,
    noise_seed: u64,
    gap_noise_seed: u64,
    install_change: f64,
}

impl EdgeSensors {
    /// The sensors of `geometry` (its `leff` is the sensors' effective moment arm) with the
    /// errors `errors`.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming the error rms that is negative or not finite.
    pub fn new(geometry: &Geometry, errors: &SensorErrors) -> Result<Self, M1Error> {
        errors.check()?;
        let installed = errors.position_rms > 0.0 || errors.tilt_rms > 0.0;
        let mut m = if installed {
            interaction_matrices(&install_sensors(
                geometry,
                errors.position_rms,
                errors.tilt_rms,
                errors.seed,
            ))
        } else {
            interaction_matrices(geometry)
        };
        let install_change = if installed {
            relative_difference(&m.a_hz, &interaction_matrices(geometry).a_hz)
        } else {
            0.0
        };
        let ns = geometry.n_sensors();
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
        Ok(Self {
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

    /// The true `S A_hz` (installed geometry, gains applied): readings per unit `z`.
    pub fn height_matrix(&self) -> &SparseColMat<usize, f64> {
        &self.height_z
    }

    /// The true `S A_hw`: readings per unit `w`.
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
    /// installation errors).
    pub fn install_change(&self) -> f64 {
        self.install_change
    }

    /// The readings of sample `sample` for displacements `z` and in-plane motion `w` into `y`
    /// and `gap` (length `n_s`), without allocating.
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
        y.fill(0.0);
        mul_add(&self.height_z, z, y);
        mul_add(&self.height_w, w, y);
        gap.fill(self.nominal_gap);
        mul_add(&self.gap_z, z, gap);
        mul_add(&self.gap_w, w, gap);
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
