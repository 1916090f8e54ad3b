//! The quasi-static analyses of the A-matrix: its singular structure, robustness of the control
//! algorithm to interaction-matrix uncertainty, propagation of sensor noise, the error caused by
//! in-plane clocking, and shear estimation from gaps (sensor calibration).
//!
//! # Robustness (the seed paper's Table 1)
//!
//! With $B_0$ the pseudo-inverse of the nominal $A_0$ and the true system $S A$ (sensor gains
//! $S = I + \delta_S$), the algorithm sees $Q = B_0 S A$, ideally the identity on the observable
//! subspace. Metrics over seeded realizations: the spectral radius $\rho(Q - I)$, the largest
//! singular value $\bar\sigma(Q)$, and $\bar\sigma(\Gamma\Psi Q \Psi^T)$ with focus-mode's gain
//! reduced by a factor (4 in the paper); by unitary invariance the last is $\bar\sigma(G Q)$ with
//! $G = I - (1 - \gamma)\psi_f\psi_f^T$. $Q$ has an eigenvalue with real part $\le 0$ means the
//! loop is unstable at any bandwidth. All quantities come from Krylov (Arnoldi) estimates on the
//! operators $x \mapsto B_0 S A x$ and its transpose, applied through the sparse reconstructor,
//! restricted to the observable subspace.
//!
//! # Noise propagation
//!
//! White sensor noise of unit rms gives actuator-space errors $z = B n$ with
//! $E\|z\|^2 = \|B\|_F^2$: the rms per actuator is $\|B\|_F/\sqrt{n_a}$ (m per m of sensor noise),
//! global piston/tip/tilt removed by construction; without focus-mode it is
//! $\|(I - \psi_f\psi_f^T)B\|_F/\sqrt{n_a}$.
//!
//! # Clocking (eq. 3) and calibration (eq. 2)
//!
//! In-plane clocking $w$ of a segment moves the height readings by $A_{hw} w$, which the loop
//! reads as out-of-plane error and corrects: $\hat z = A_{hz}^+ A_{hw} w$. Shear is estimated from
//! the measured gaps as $\hat y_s = A_{sw} A_{gw}^+ y_g$; the torsion mode, unobservable in the
//! gaps, and gap noise limit it.
//!
//! # Files
//!
//! `mod.rs` the SVD summary, noise propagation, clocking and the default geometry;
//! `robustness.rs` Table 1 (perturbed interaction matrices and their statistics);
//! `calibration.rs` the shear estimator and the calibration study.

mod calibration;
mod robustness;
#[cfg(test)]
mod tests;

pub use calibration::{CalibrationMonteCarlo, CalibrationResult, ShearEstimator, calibration};
pub use robustness::{
    Case, CaseResult, ElementBasis, INSTALL_DEFAULTS, Perturbation, Published, RobustnessParams,
    Stats, robustness,
};

use faer::Mat;
use faer::sparse::SparseColMat;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use serde::Serialize;

use crate::M1Error;
use crate::aperture::geometry::{Geometry, GeometryParams};
use crate::aperture::layout::Layout;
use crate::control::nominal::{Nominal, project_out};
use crate::control::reconstructor::{SparseReconstructor, at_mul, sparse_mul};
use crate::linalg::krylov;
use crate::sensing::interaction::{a_matrix, interaction_matrices};

/// The SVD summary of an interaction matrix.
#[derive(Debug, Clone, Serialize)]
pub struct SvdSummary {
    /// Rows x columns.
    pub shape: (usize, usize),
    /// Numerical rank (singular values above `rank_tolerance` x the largest).
    pub rank: usize,
    /// The relative threshold used for the rank.
    pub rank_tolerance: f64,
    /// Largest singular value.
    pub largest: f64,
    /// Smallest singular value counted in the rank.
    pub smallest_nonzero: f64,
    /// largest / smallest_nonzero.
    pub condition_number: f64,
    /// All singular values, largest first.
    pub singular_values: Vec<f64>,
}

/// SVD of a dense matrix with its summary, and the right singular vectors (columns).
pub fn svd_summary(a: &Mat<f64>, rank_tolerance: f64) -> Result<(SvdSummary, Mat<f64>), M1Error> {
    let svd = a
        .thin_svd()
        .map_err(|e| M1Error::Numerical(format!("SVD did not converge: {e:?}")))?;
    let s = svd.S().column_vector();
    let sv: Vec<f64> = (0..s.nrows()).map(|i| s[i]).collect();
    let largest = sv.first().copied().unwrap_or(0.0);
    let rank = sv.iter().filter(|&&x| x > rank_tolerance * largest).count();
    let smallest = if rank > 0 { sv[rank - 1] } else { 0.0 };
    Ok((
        SvdSummary {
            shape: (a.nrows(), a.ncols()),
            rank,
            rank_tolerance,
            largest,
            smallest_nonzero: smallest,
            condition_number: if smallest > 0.0 {
                largest / smallest
            } else {
                f64::INFINITY
            },
            singular_values: sv,
        },
        svd.V().to_owned(),
    ))
}

/// Noise propagation: rms actuator-space error per unit rms white sensor noise.
#[derive(Debug, Clone, Serialize)]
pub struct NoiseResult {
    /// rms per actuator per unit sensor noise, global PTT removed (m/m).
    pub rms_per_noise: f64,
    /// The same without the focus-mode component.
    pub rms_per_noise_without_focus: f64,
    /// The focus-mode share of the variance.
    pub focus_share: f64,
    /// Per segment, the rms over its three actuators per unit sensor noise (m/m), in layout
    /// order: where on the mirror the noise lands.
    pub per_segment_rms: Vec<f64>,
    /// The same without the focus-mode component.
    pub per_segment_rms_without_focus: Vec<f64>,
}

/// $\|B\|_F/\sqrt{n_a}$ with and without focus-mode, and its distribution over the segments,
/// from B applied to every sensor unit vector.
pub fn noise_propagation(nominal: &Nominal) -> NoiseResult {
    let (na, ns) = (nominal.a.ncols(), nominal.a.nrows());
    let f = &nominal.focus;
    // Per actuator: sum_k z_i^2 and sum_k z_i (f . z); without focus (z - d f)_i^2 expands to
    // z_i^2 - 2 d z_i f_i + d^2 f_i^2.
    let mut var = vec![0.0; na];
    let mut cross = vec![0.0; na];
    let mut focus = 0.0;
    let mut e = vec![0.0; ns];
    let mut z = vec![0.0; na];
    let mut work = vec![0.0; nominal.b0.work_len()];
    for k in 0..ns {
        e[k] = 1.0;
        nominal.b0.apply_into(&e, &mut z, &mut work);
        e[k] = 0.0;
        let d: f64 = z.iter().zip(f).map(|(a, b)| a * b).sum();
        focus += d * d;
        for i in 0..na {
            var[i] += z[i] * z[i];
            cross[i] += d * z[i];
        }
    }
    let total: f64 = var.iter().sum();
    let without: Vec<f64> = (0..na)
        .map(|i| (var[i] - 2.0 * cross[i] * f[i] + focus * f[i] * f[i]).max(0.0))
        .collect();
    let per_segment = |v: &[f64]| -> Vec<f64> {
        v.chunks(3)
            .map(|c| (c.iter().sum::<f64>() / c.len() as f64).sqrt())
            .collect()
    };
    NoiseResult {
        rms_per_noise: (total / na as f64).sqrt(),
        rms_per_noise_without_focus: ((total - focus) / na as f64).sqrt(),
        focus_share: focus / total,
        per_segment_rms: per_segment(&var),
        per_segment_rms_without_focus: per_segment(&without),
    }
}

/// Clocking of one segment: the out-of-plane correction the loop makes.
#[derive(Debug, Clone, Serialize)]
pub struct ClockingResult {
    /// The clocked segment.
    pub segment: usize,
    /// rms of the correction over all actuators, per mrad of clocking (m/mrad).
    pub rms_per_mrad: f64,
    /// rms without focus-mode (m/mrad).
    pub rms_per_mrad_without_focus: f64,
    /// The correction per mrad at every actuator (m).
    pub z: Vec<f64>,
}

/// $\hat z = A_{hz}^+ A_{hw} w$ for a clocking of 1 mrad of `segment`.
pub fn clocking(nominal: &Nominal, segment: usize) -> Result<ClockingResult, M1Error> {
    let n = nominal.geometry.n_segments();
    if segment >= n {
        return Err(M1Error::SizeMismatch {
            what: "segment index",
            expected: n,
            found: segment,
        });
    }
    let im = interaction_matrices(&nominal.geometry);
    let mut w = vec![0.0; 3 * n];
    w[3 * segment + 2] = 1e-3;
    let mut y = vec![0.0; nominal.a.nrows()];
    sparse_mul(&im.a_hw, &w, &mut y);
    let z = nominal.b0.apply(&y);
    let na = z.len() as f64;
    let rms = (z.iter().map(|x| x * x).sum::<f64>() / na).sqrt();
    let d: f64 = z.iter().zip(&nominal.focus).map(|(a, b)| a * b).sum();
    let rest = (z.iter().map(|x| x * x).sum::<f64>() - d * d).max(0.0);
    Ok(ClockingResult {
        segment,
        rms_per_mrad: rms,
        rms_per_mrad_without_focus: (rest / na).sqrt(),
        z,
    })
}

/// Default relative singular-value threshold of [`ShearEstimator`]: on the curved prescription
/// the global in-plane modes are weakly observable in the gaps (singular values ~1e-5 of the
/// largest, TMT and Keck) and torsion is unobservable (~1e-9); the observable ones stay above
/// 1e-2. Inverting the weak ones would amplify gap noise 1e5-fold.
pub const SHEAR_RANK_TOLERANCE: f64 = 1e-4;

/// The default geometry of a layout (curved prescription, or flat).
pub fn default_geometry(
    layout: &Layout,
    flat: bool,
    leff: Option<f64>,
) -> Result<Geometry, M1Error> {
    let mut p = GeometryParams::for_layout(layout);
    p.flat = flat;
    if let Some(l) = leff {
        p.leff = l;
    }
    Geometry::new(layout, p)
}
