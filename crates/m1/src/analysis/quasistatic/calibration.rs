//! Calibration: the shear estimated from the gaps (eq. 2) and the calibration study.

use super::*;

/// Shear estimated from gaps, $\hat y_s = A_{sw} A_{gw}^+ y_g$ (eq. 2), with the pseudo-inverse
/// truncated at a relative singular-value threshold.
#[derive(Debug, Clone)]
pub struct ShearEstimator {
    /// $A_{sw}$ dense ($n_s \times 3N$).
    a_sw: Mat<f64>,
    /// $U_r$ ($n_s \times r$) and $V_r S_r^{-1}$ ($3N \times r$) of $A_{gw}$.
    u_r: Mat<f64>,
    v_r_scaled: Mat<f64>,
    /// $V_r$ (for the projector onto the gap-observable in-plane motions).
    v_r: Mat<f64>,
    /// All singular values of $A_{gw}$, largest first.
    pub singular_values: Vec<f64>,
    /// Singular values kept (above `rank_tolerance` x the largest).
    pub rank: usize,
    /// The relative threshold.
    pub rank_tolerance: f64,
}

impl ShearEstimator {
    /// SVD of $A_{gw}$ (dense: seconds for TMT).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for a threshold outside (0, 1), [`M1Error::Numerical`] if
    /// the SVD fails.
    pub fn new(geometry: &Geometry, rank_tolerance: f64) -> Result<Self, M1Error> {
        if !(rank_tolerance > 0.0 && rank_tolerance < 1.0) {
            return Err(M1Error::InvalidParameter {
                name: "rank_tolerance",
                value: rank_tolerance,
                reason: "must be in (0, 1)",
            });
        }
        let im = interaction_matrices(geometry);
        let agw = im.a_gw.to_dense();
        let svd = agw
            .thin_svd()
            .map_err(|e| M1Error::Numerical(format!("SVD of A_gw did not converge: {e:?}")))?;
        let s = svd.S().column_vector();
        let singular_values: Vec<f64> = (0..s.nrows()).map(|i| s[i]).collect();
        let smax = singular_values.first().copied().unwrap_or(0.0);
        let rank = singular_values
            .iter()
            .filter(|&&x| x > rank_tolerance * smax)
            .count();
        let u_r = svd.U().get(.., ..rank).to_owned();
        let v_r = svd.V().get(.., ..rank).to_owned();
        let v_r_scaled = Mat::from_fn(v_r.nrows(), rank, |i, j| v_r[(i, j)] / singular_values[j]);
        Ok(Self {
            a_sw: im.a_sw.to_dense(),
            u_r,
            v_r_scaled,
            v_r,
            singular_values,
            rank,
            rank_tolerance,
        })
    }

    /// In-plane motion estimated from gaps, $\hat w = A_{gw}^+ y_g$ (one column per sample).
    pub fn in_plane(&self, gaps: faer::MatRef<'_, f64>) -> Mat<f64> {
        &self.v_r_scaled * (self.u_r.transpose() * gaps)
    }

    /// Shear estimated from gaps, $\hat y_s = A_{sw} A_{gw}^+ y_g$ (one column per sample).
    pub fn shear(&self, gaps: faer::MatRef<'_, f64>) -> Mat<f64> {
        &self.a_sw * self.in_plane(gaps)
    }

    /// Per sensor, the rms shear error per unit rms white gap noise: the row norms of
    /// $A_{sw} V_r S_r^{-1}$ (exact: $E\|A_{sw}A_{gw}^+ n\|^2 = \|A_{sw} V_r S_r^{-1}\|_F^2$).
    pub fn noise_gain_per_sensor(&self) -> Vec<f64> {
        row_norms(&(&self.a_sw * &self.v_r_scaled))
    }

    /// Per sensor, the rms shear error for white in-plane motion of unit rms, noiseless gaps:
    /// the row norms of $A_{sw}(I - V_r V_r^T)$, the shear of the gap-unobservable motion.
    pub fn unobservable_gain_per_sensor(&self) -> Vec<f64> {
        let asw_v = &self.a_sw * &self.v_r;
        let n2 = row_norms(&self.a_sw);
        let p2 = row_norms(&asw_v);
        // ||a (I - V V^T)||^2 = ||a||^2 - ||a V||^2 for orthonormal V.
        n2.iter()
            .zip(&p2)
            .map(|(a, b)| (a * a - b * b).max(0.0).sqrt())
            .collect()
    }
}

pub(super) fn row_norms(m: &Mat<f64>) -> Vec<f64> {
    (0..m.nrows())
        .map(|r| {
            (0..m.ncols())
                .map(|c| m[(r, c)] * m[(r, c)])
                .sum::<f64>()
                .sqrt()
        })
        .collect()
}

pub(super) fn rms_of(values: &[f64]) -> f64 {
    (values.iter().map(|v| v * v).sum::<f64>() / values.len().max(1) as f64).sqrt()
}

/// Shear estimation from gaps.
#[derive(Debug, Clone, Serialize)]
pub struct CalibrationResult {
    /// Rank of A_gw kept by the estimator, and the number of in-plane coordinates (3N).
    pub gap_rank: usize,
    /// Number of in-plane coordinates (3N).
    pub in_plane_dofs: usize,
    /// The relative singular-value threshold of the pseudo-inverse.
    pub rank_tolerance: f64,
    /// Singular values of A_gw dropped although above 1e-9 of the largest: in-plane modes only
    /// weakly observable in the gaps (through the curvature).
    pub weakly_observable: usize,
    /// The smallest kept singular value and the largest dropped one, relative to the largest.
    pub smallest_kept_relative: f64,
    /// Largest dropped singular value relative to the largest (0 if none).
    pub largest_dropped_relative: f64,
    /// rms shear estimation error for white in-plane motion of unit rms, noiseless gaps: the
    /// shear of the gap-unobservable modes (m/m, exact).
    pub shear_error_unobservable: f64,
    /// rms shear estimation error per unit rms white gap noise (m/m, exact).
    pub shear_error_per_gap_noise: f64,
    /// The same two by seeded Monte Carlo over `samples` draws (a check of the exact values).
    pub monte_carlo: CalibrationMonteCarlo,
    /// Per segment (layout order), the rms shear error from gap-unobservable motion over the
    /// sensors of its edges (m/m).
    pub per_segment_shear_error_unobservable: Vec<f64>,
}

/// The Monte Carlo check of [`CalibrationResult`].
#[derive(Debug, Clone, Serialize)]
pub struct CalibrationMonteCarlo {
    /// Number of draws.
    pub samples: usize,
    /// Seed.
    pub seed: u64,
    /// rms shear error from white in-plane motion, noiseless gaps.
    pub shear_error_unobservable: f64,
    /// rms shear error from white gap noise.
    pub shear_error_per_gap_noise: f64,
}

/// Sensor calibration, $\hat y_s = A_{sw}A_{gw}^+ y_g$ (eq. 2): the shear errors from the
/// gap-unobservable in-plane modes and from gap noise, exactly and by seeded Monte Carlo over
/// `samples` draws (dense SVD of A_gw: about 2 s for TMT).
pub fn calibration(
    geometry: &Geometry,
    samples: usize,
    seed: u64,
    rank_tolerance: f64,
) -> Result<CalibrationResult, M1Error> {
    let est = ShearEstimator::new(geometry, rank_tolerance)?;
    let im = interaction_matrices(geometry);
    let (ns, nw) = (im.a_gw.nrows(), im.a_gw.ncols());
    let mut rng = StdRng::seed_from_u64(seed);
    let w = Mat::<f64>::from_fn(nw, samples, |_, _| StandardNormal.sample(&mut rng));
    let noise = Mat::<f64>::from_fn(ns, samples, |_, _| StandardNormal.sample(&mut rng));
    let agw = im.a_gw.to_dense();
    let ys = &est.a_sw * &w;
    let err = &ys - est.shear((&agw * &w).as_ref());
    let err_noise = est.shear(noise.as_ref());
    let rms_mat = |m: &Mat<f64>| {
        let mut s2 = 0.0;
        for c in 0..m.ncols() {
            for r in 0..m.nrows() {
                s2 += m[(r, c)] * m[(r, c)];
            }
        }
        (s2 / (m.nrows() * m.ncols()).max(1) as f64).sqrt()
    };
    let unobs = est.unobservable_gain_per_sensor();
    let n_seg = geometry.n_segments();
    let (mut sum, mut count) = (vec![0.0; n_seg], vec![0usize; n_seg]);
    for (k, sensor) in geometry.sensors.iter().enumerate() {
        for seg in [sensor.i, sensor.j] {
            sum[seg] += unobs[k] * unobs[k];
            count[seg] += 1;
        }
    }
    let smax = est.singular_values.first().copied().unwrap_or(1.0);
    let weakly_observable = est.singular_values[est.rank..]
        .iter()
        .filter(|&&x| x > 1e-9 * smax)
        .count();
    Ok(CalibrationResult {
        gap_rank: est.rank,
        in_plane_dofs: nw,
        rank_tolerance,
        weakly_observable,
        smallest_kept_relative: est
            .rank
            .checked_sub(1)
            .map_or(0.0, |i| est.singular_values[i] / smax),
        largest_dropped_relative: est.singular_values.get(est.rank).map_or(0.0, |x| x / smax),
        shear_error_unobservable: rms_of(&unobs),
        shear_error_per_gap_noise: rms_of(&est.noise_gain_per_sensor()),
        monte_carlo: CalibrationMonteCarlo {
            samples,
            seed,
            shear_error_unobservable: rms_mat(&err),
            shear_error_per_gap_noise: rms_mat(&err_noise),
        },
        per_segment_shear_error_unobservable: sum
            .iter()
            .zip(&count)
            .map(|(s, &c)| if c > 0 { (s / c as f64).sqrt() } else { 0.0 })
            .collect(),
    })
}
