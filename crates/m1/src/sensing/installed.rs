//! Installed edge sensors: how a real sensor's reading depends on its gap, and the installation
//! errors of segments and sensors.
//!
//! # The gap law
//!
//! A sensor reads `y = s (h + L_eff d)`, height difference `h` plus `L_eff` times the dihedral
//! `d`. Both its gain `s` and its moment arm `L_eff` depend on the gap `g` across the sensor:
//!
//! ```text
//! s_n     = 1 + gamma_h (g_n - g_0),
//! L_eff,n = L_eff (1 + kappa (g_n - g_0)),
//! ```
//!
//! with `gamma_h` ([`GapLaw::height_gain_per_gap`]) the height gain's sensitivity to the gap
//! that remains after the sensor's own gap reading normalises its height sensitivity, and
//! `kappa` ([`GapLaw::leff_per_gap`]) the moment arm's. Both are *calibrated* to the seed
//! paper's Table 1: a uniform gap change (temperature) scales every sensor alike, which moves
//! an eigenvalue of `Q` but hardly its largest singular value (the table's temperature rows have
//! `rho(Q - I) = 14e-3` with `sigma(Q) = 1.13`), so most of it is in `gamma_h`; see
//! [`DEFAULT_HEIGHT_GAIN_PER_GAP`] and [`DEFAULT_LEFF_PER_GAP`].
//!
//! Since the readings are linear in `L_eff`, `A = A_h + L_eff A_d` with `A_h` the pure height
//! block and `A_d` the dihedral block; [`HeightSplit`] keeps both on one sparsity pattern and
//! assembles or applies `diag(s) (A_h + diag(L_eff,n / L_eff) L_eff A_d)` for any per-sensor
//! gains and arms without rebuilding the geometry (the edge-sensor model uses it per sample).
//!
//! # Installation
//!
//! [`Installation`] draws, reproducibly from a seed:
//! - per segment, an in-plane placement error `w_0` (radial and azimuthal, m; clocking, rad):
//!   the segment moves with its sensor halves and actuators, so the gaps at its sensors change by
//!   `A_gw w_0` (and the sensors' gains and arms with them by the gap law);
//! - per sensor, a placement error in its tangent plane and a tilt of its frame (as
//!   [`crate::sensing::sensors::install_sensors`]), so a tilted height axis reads some of the gap
//!   and shear motion (cross-axis sensitivity, through `A_hw` of the installed geometry), and an
//!   offset of the sensor's own gap from the segments' gap, `N(0, sensor_gap_rms)`.

use faer::sparse::{SparseColMat, Triplet};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::sensing::interaction::{a_matrix, interaction_matrices};
use crate::sensing::sensors::{install_sensors, mul_add};

/// Default `gamma_h`, the residual height-gain sensitivity to the gap after normalisation by the
/// gap reading (1/m): *calibrated* so that a 5 degC temperature change of the default
/// deformation model (a uniform gap change of 62 um) gives Table 1's `rho(Q - I) = 14e-3`.
pub const DEFAULT_HEIGHT_GAIN_PER_GAP: f64 = -210.0;

/// Default `kappa`, the relative change of `L_eff` per metre of gap change (1/m): *calibrated*
/// so that the same temperature change gives Table 1's `sigma(Q) = 1.13`.
pub const DEFAULT_LEFF_PER_GAP: f64 = 6.0;

/// How a sensor's height gain and moment arm depend on its gap (see the
/// [module documentation](self)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GapLaw {
    /// `gamma_h`: relative height-gain change per metre of gap change (1/m).
    pub height_gain_per_gap: f64,
    /// `kappa`: relative `L_eff` change per metre of gap change (1/m).
    pub leff_per_gap: f64,
}

impl Default for GapLaw {
    fn default() -> Self {
        Self {
            height_gain_per_gap: DEFAULT_HEIGHT_GAIN_PER_GAP,
            leff_per_gap: DEFAULT_LEFF_PER_GAP,
        }
    }
}

impl GapLaw {
    /// No dependence on the gap (the ideal sensors of the dynamic studies).
    pub const NONE: GapLaw = GapLaw {
        height_gain_per_gap: 0.0,
        leff_per_gap: 0.0,
    };

    /// Per-sensor gains `s_n` and arm factors `L_eff,n / L_eff` for the gap changes `dgap` (m),
    /// written into `gain` and `leff_factor`.
    pub fn factors_into(&self, dgap: &[f64], gain: &mut [f64], leff_factor: &mut [f64]) {
        for ((g, l), d) in gain.iter_mut().zip(leff_factor.iter_mut()).zip(dgap) {
            *g = 1.0 + self.height_gain_per_gap * d;
            *l = 1.0 + self.leff_per_gap * d;
        }
    }

    /// As [`GapLaw::factors_into`], allocating: `(gains, arm factors)`.
    pub fn factors(&self, dgap: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let mut g = vec![0.0; dgap.len()];
        let mut l = vec![0.0; dgap.len()];
        self.factors_into(dgap, &mut g, &mut l);
        (g, l)
    }
}

/// A height block of the interaction matrix split into its pure-height and dihedral parts on
/// one sparsity pattern, row by row: `A = A_h + A_l` with `A_l = L_eff A_d` (see the
/// [module documentation](self)). Each sensor's reading is then
/// `s_n (h_n + f_n l_n)` for a gain `s_n` and an arm factor `f_n = L_eff,n / L_eff`, computed
/// row by row without scratch.
#[derive(Debug, Clone)]
pub struct HeightSplit {
    nrows: usize,
    ncols: usize,
    /// Compressed rows: the entries of row `n` are `row_ptr[n]..row_ptr[n + 1]`.
    row_ptr: Vec<usize>,
    col: Vec<usize>,
    /// Pure height entries (the block with `L_eff = 0`).
    h: Vec<f64>,
    /// `L_eff` times the dihedral entries (the rest of the block).
    l: Vec<f64>,
}

impl HeightSplit {
    /// The split of `geometry`'s A-matrix (two interaction-matrix builds).
    pub fn new(geometry: &Geometry) -> Self {
        let mut g0 = geometry.clone();
        g0.params.leff = 0.0;
        Self::from_blocks(&a_matrix(&g0), &a_matrix(geometry))
    }

    /// The split of `full`, a height block (`A_hz` or `A_hw`), given `pure`, the same block of
    /// the geometry with `L_eff = 0`.
    pub fn from_blocks(pure: &SparseColMat<usize, f64>, full: &SparseColMat<usize, f64>) -> Self {
        let (nrows, ncols) = (full.nrows(), full.ncols());
        // (row, column, height, rest) of both blocks, merged on their union pattern.
        let mut t: Vec<(usize, usize, f64, f64)> = Vec::with_capacity(2 * full.val().len());
        for (a, is_pure) in [(pure, true), (full, false)] {
            let sym = a.symbolic();
            for c in 0..a.ncols() {
                for k in sym.col_ptr()[c]..sym.col_ptr()[c + 1] {
                    let v = a.val()[k];
                    let (h, l) = if is_pure { (v, -v) } else { (0.0, v) };
                    t.push((sym.row_idx()[k], c, h, l));
                }
            }
        }
        t.sort_unstable_by_key(|e| (e.0, e.1));
        let mut out = Self {
            nrows,
            ncols,
            row_ptr: vec![0; nrows + 1],
            col: Vec::new(),
            h: Vec::new(),
            l: Vec::new(),
        };
        let mut last = None;
        for (r, c, h, l) in t {
            if last == Some((r, c)) {
                let k = out.col.len() - 1;
                out.h[k] += h;
                out.l[k] += l;
            } else {
                out.col.push(c);
                out.h.push(h);
                out.l.push(l);
                out.row_ptr[r + 1] += 1;
                last = Some((r, c));
            }
        }
        for r in 0..nrows {
            out.row_ptr[r + 1] += out.row_ptr[r];
        }
        out
    }

    /// Number of sensors (rows).
    pub fn n_sensors(&self) -> usize {
        self.nrows
    }

    /// Number of columns (actuators, or in-plane coordinates).
    pub fn n_actuators(&self) -> usize {
        self.ncols
    }

    /// `(h_n, l_n)`: row `n`'s pure height and dihedral parts of the vector whose column `c` is
    /// `x(c)`.
    pub fn row(&self, n: usize, x: impl Fn(usize) -> f64) -> (f64, f64) {
        let (mut h, mut l) = (0.0, 0.0);
        for k in self.row_ptr[n]..self.row_ptr[n + 1] {
            let v = x(self.col[k]);
            h += self.h[k] * v;
            l += self.l[k] * v;
        }
        (h, l)
    }

    fn check(&self, gain: &[f64], leff_factor: &[f64]) -> Result<(), M1Error> {
        crate::error::check_lengths(
            self.nrows,
            &[("sensor gains", gain), ("L_eff factors", leff_factor)],
        )
    }

    /// `diag(gain) (A_h + diag(leff_factor) A_l)` as a sparse matrix.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] if a slice is not `n_sensors` long.
    pub fn assemble(
        &self,
        gain: &[f64],
        leff_factor: &[f64],
    ) -> Result<SparseColMat<usize, f64>, M1Error> {
        self.check(gain, leff_factor)?;
        let mut t = Vec::with_capacity(self.col.len());
        for n in 0..self.nrows {
            for k in self.row_ptr[n]..self.row_ptr[n + 1] {
                let v = gain[n] * (self.h[k] + leff_factor[n] * self.l[k]);
                t.push(Triplet::new(n, self.col[k], v));
            }
        }
        SparseColMat::try_new_from_triplets(self.nrows, self.ncols, &t)
            .map_err(|e| M1Error::Numerical(format!("assembling the height block: {e:?}")))
    }

    /// `y = diag(gain) (A_h + diag(leff_factor) A_l) z`, without allocating.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for a slice of the wrong length (nothing is written then).
    pub fn mul_into(
        &self,
        gain: &[f64],
        leff_factor: &[f64],
        z: &[f64],
        y: &mut [f64],
    ) -> Result<(), M1Error> {
        self.check(gain, leff_factor)?;
        crate::error::check_lengths(self.ncols, &[("z", z)])?;
        if y.len() != self.nrows {
            return Err(M1Error::SizeMismatch {
                what: "y",
                expected: self.nrows,
                found: y.len(),
            });
        }
        for (n, v) in y.iter_mut().enumerate() {
            let (h, l) = self.row(n, |c| z[c]);
            *v = gain[n] * (h + leff_factor[n] * l);
        }
        Ok(())
    }
}

/// Installation errors of segments and sensors (all zero by default).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Installation {
    /// rms in-plane placement error of each segment, radial and azimuthal (m).
    pub segment_position_rms: f64,
    /// rms clocking error of each segment about its normal (rad).
    pub segment_clocking_rms: f64,
    /// rms placement error of each sensor in its tangent plane, per axis (m).
    pub sensor_position_rms: f64,
    /// rms tilt of each sensor's frame about each in-plane axis (rad).
    pub sensor_tilt_rms: f64,
    /// rms offset of each sensor's own gap from the segments' gap (m).
    pub sensor_gap_rms: f64,
    /// Seed of the draws.
    pub seed: u64,
}

impl Default for Installation {
    fn default() -> Self {
        Self {
            segment_position_rms: 0.0,
            segment_clocking_rms: 0.0,
            sensor_position_rms: 0.0,
            sensor_tilt_rms: 0.0,
            sensor_gap_rms: 0.0,
            seed: 1,
        }
    }
}

/// One realisation of [`Installation`].
#[derive(Debug, Clone)]
pub struct Installed {
    /// The geometry with the installed sensors (segments at their nominal places: their
    /// placement errors are in `segment_w`).
    pub geometry: Geometry,
    /// In-plane placement error of every segment, `w` layout (length `3 N`).
    pub segment_w: Vec<f64>,
    /// Offset of each sensor's gap from the segments' gap (m, length `n_s`).
    pub sensor_gap: Vec<f64>,
    /// Gap change at every sensor from the installation: `A_gw segment_w + sensor_gap` (m).
    pub dgap: Vec<f64>,
}

impl Installation {
    fn check(&self) -> Result<(), M1Error> {
        for (name, x) in [
            ("segment_position_rms", self.segment_position_rms),
            ("segment_clocking_rms", self.segment_clocking_rms),
            ("sensor_position_rms", self.sensor_position_rms),
            ("sensor_tilt_rms", self.sensor_tilt_rms),
            ("sensor_gap_rms", self.sensor_gap_rms),
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

    /// Draws the installation of `geometry` (see the [module documentation](self)). The
    /// segment, sensor-placement and sensor-gap draws use separate streams of the seed.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming a negative or non-finite rms.
    pub fn install(&self, geometry: &Geometry) -> Result<Installed, M1Error> {
        self.check()?;
        let gauss = |rng: &mut StdRng| -> f64 { StandardNormal.sample(rng) };
        let mut rng = StdRng::seed_from_u64(self.seed.wrapping_mul(31).wrapping_add(7));
        let segment_w: Vec<f64> = (0..geometry.n_actuators())
            .map(|k| {
                let s = if k % 3 == 2 {
                    self.segment_clocking_rms
                } else {
                    self.segment_position_rms
                };
                s * gauss(&mut rng)
            })
            .collect();
        let installed = if self.sensor_position_rms > 0.0 || self.sensor_tilt_rms > 0.0 {
            install_sensors(
                geometry,
                self.sensor_position_rms,
                self.sensor_tilt_rms,
                self.seed,
            )
        } else {
            geometry.clone()
        };
        let mut rng = StdRng::seed_from_u64(self.seed.wrapping_mul(31).wrapping_add(11));
        let sensor_gap: Vec<f64> = (0..geometry.n_sensors())
            .map(|_| self.sensor_gap_rms * gauss(&mut rng))
            .collect();
        let im = interaction_matrices(geometry);
        let mut dgap = sensor_gap.clone();
        mul_add(&im.a_gw, &segment_w, &mut dgap);
        Ok(Installed {
            geometry: installed,
            segment_w,
            sensor_gap,
            dgap,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::geometry::GeometryParams;
    use crate::aperture::layout::Layout;

    fn keck() -> Geometry {
        let l = Layout::preset("keck").unwrap();
        Geometry::new(&l, GeometryParams::for_layout(&l)).unwrap()
    }

    #[test]
    fn split_reassembles_the_a_matrix_and_scales_each_row() {
        let g = keck();
        let split = HeightSplit::new(&g);
        let ns = g.n_sensors();
        let a = a_matrix(&g).to_dense();
        let ones = vec![1.0; ns];
        let back = split.assemble(&ones, &ones).unwrap().to_dense();
        let diff = (&back - &a).norm_max();
        assert!(diff < 1e-12 * a.norm_max(), "{diff}");
        // Doubling one sensor's arm equals the A-matrix of L_eff 2x on that row.
        let mut lf = ones.clone();
        lf[5] = 2.0;
        let mut g2 = g.clone();
        g2.params.leff *= 2.0;
        let a2 = a_matrix(&g2).to_dense();
        let m = split.assemble(&ones, &lf).unwrap().to_dense();
        for c in 0..a.ncols() {
            assert!((m[(5, c)] - a2[(5, c)]).abs() < 1e-12);
            assert!((m[(4, c)] - a[(4, c)]).abs() < 1e-12);
        }
        // mul_into agrees with the assembled matrix.
        let gains: Vec<f64> = (0..ns).map(|k| 1.0 + 1e-3 * k as f64).collect();
        let z: Vec<f64> = (0..g.n_actuators()).map(|k| (k as f64).sin()).collect();
        let mut y = vec![0.0; ns];
        split.mul_into(&gains, &lf, &z, &mut y).unwrap();
        let mut y2 = vec![0.0; ns];
        mul_add(&split.assemble(&gains, &lf).unwrap(), &z, &mut y2);
        for (a, b) in y.iter().zip(&y2) {
            assert!((a - b).abs() < 1e-15);
        }
        assert!(split.mul_into(&gains, &lf, &z[1..], &mut y).is_err());
    }

    #[test]
    fn a_uniform_segment_expansion_opens_every_gap_alike() {
        // A segment moved radially outward opens its outer gaps and closes its inner ones by the
        // same amount; installation with zero rms leaves everything nominal.
        let g = keck();
        let none = Installation::default().install(&g).unwrap();
        assert!(none.dgap.iter().all(|d| *d == 0.0));
        assert_eq!(none.geometry, g);
        let inst = Installation {
            segment_position_rms: 1e-4,
            sensor_gap_rms: 1e-5,
            ..Installation::default()
        }
        .install(&g)
        .unwrap();
        let rms = |v: &[f64]| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
        // Each gap sees two segments' placement errors projected on its normal: ~ sqrt(2) x.
        let r = rms(&inst.dgap);
        assert!(r > 0.8e-4 && r < 2.2e-4, "{r}");
        assert!((rms(&inst.sensor_gap) - 1e-5).abs() < 0.3e-5);
        let bad = Installation {
            sensor_tilt_rms: -1.0,
            ..Installation::default()
        };
        assert!(matches!(
            bad.install(&g),
            Err(M1Error::InvalidParameter {
                name: "sensor_tilt_rms",
                ..
            })
        ));
    }
}
