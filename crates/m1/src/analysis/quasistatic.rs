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

/// One source of interaction-matrix error.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Perturbation {
    /// Sensor gains S = I + delta_S, delta_S ~ N(0, rms) per sensor.
    SensorGain {
        /// rms of the gain error (1 = 100 %).
        rms: f64,
    },
    /// L_eff of the true system = factor x nominal (deterministic).
    Leff {
        /// The ratio.
        factor: f64,
    },
    /// Every non-zero element of A multiplied by (1 + N(0, rms)).
    ElementErrors {
        /// rms relative error.
        rms: f64,
    },
    /// Sensor installation: each sensor point moved in-plane (gap and shear directions) by
    /// N(0, position_rms) and its height axis tilted by N(0, tilt_rms) about both in-plane axes.
    SensorInstall {
        /// m.
        position_rms: f64,
        /// rad.
        tilt_rms: f64,
    },
    /// Segment installation: each segment's actuators moved in-plane by N(0, position_rms) and
    /// clocked by N(0, clocking_rms) about its normal (sensors stay where they are).
    SegmentInstall {
        /// m.
        position_rms: f64,
        /// rad.
        clocking_rms: f64,
    },
}

/// A named robustness case.
#[derive(Debug, Clone, Serialize)]
pub struct Case {
    /// Label.
    pub name: String,
    /// The error source.
    pub perturbation: Perturbation,
}

impl Case {
    /// The default set of cases (values marked in the docs as *assumed* where not published).
    pub fn defaults() -> Vec<Case> {
        let c = |name: &str, p| Case {
            name: name.into(),
            perturbation: p,
        };
        vec![
            c("sensor gain 0.1%", Perturbation::SensorGain { rms: 1e-3 }),
            c("sensor gain 1%", Perturbation::SensorGain { rms: 1e-2 }),
            c("Leff +10%", Perturbation::Leff { factor: 1.1 }),
            c("Leff -10%", Perturbation::Leff { factor: 0.9 }),
            c(
                "sensor install",
                Perturbation::SensorInstall {
                    position_rms: 0.5e-3,
                    tilt_rms: 1e-3,
                },
            ),
            c(
                "segment install",
                Perturbation::SegmentInstall {
                    position_rms: 1e-3,
                    clocking_rms: 1e-3,
                },
            ),
            c("A elements 2%", Perturbation::ElementErrors { rms: 0.02 }),
            c("A elements 5%", Perturbation::ElementErrors { rms: 0.05 }),
        ]
    }
}

/// Distribution of a metric over the realizations.
#[derive(Debug, Clone, Serialize)]
pub struct Stats {
    /// Largest value (worst case).
    pub worst: f64,
    /// Median.
    pub median: f64,
    /// Mean.
    pub mean: f64,
    /// Every realization's value, in realization order.
    pub values: Vec<f64>,
}

impl Stats {
    fn of(values: Vec<f64>) -> Stats {
        let mut s = values.clone();
        s.sort_by(|a, b| a.total_cmp(b));
        let n = s.len().max(1);
        Stats {
            worst: s.last().copied().unwrap_or(f64::NAN),
            median: s.get(s.len() / 2).copied().unwrap_or(f64::NAN),
            mean: s.iter().sum::<f64>() / n as f64,
            values,
        }
    }
}

/// The metrics of one case.
#[derive(Debug, Clone, Serialize)]
pub struct CaseResult {
    /// The case.
    pub case: Case,
    /// Number of realizations.
    pub realizations: usize,
    /// rho(Q - I).
    pub rho_q_minus_i: Stats,
    /// sigma_max(Q).
    pub sigma_q: Stats,
    /// sigma_max(Gamma Psi Q Psi^T).
    pub sigma_gamma_q: Stats,
    /// Smallest real part of an eigenvalue of Q (instability if <= 0).
    pub min_real_eigenvalue: Stats,
    /// Fraction of realizations with an eigenvalue of Q with real part <= 0.
    pub unstable_fraction: f64,
}

/// Settings of the robustness analysis.
#[derive(Debug, Clone, Serialize)]
pub struct RobustnessParams {
    /// Realizations per random case (default: 100).
    pub realizations: usize,
    /// Focus-mode gain reduction factor of Gamma (default: 4).
    pub focus_gain_factor: f64,
    /// Seed (default: 1).
    pub seed: u64,
    /// Krylov dimension of the estimates (default: 60).
    pub krylov_dim: usize,
}

impl Default for RobustnessParams {
    fn default() -> Self {
        Self {
            realizations: 100,
            focus_gain_factor: 4.0,
            seed: 1,
            krylov_dim: 60,
        }
    }
}

fn rotate_about(v: [f64; 3], axis: [f64; 3], angle: f64) -> [f64; 3] {
    // Small rotation: v + angle axis x v (first order), renormalised.
    let c = [
        axis[1] * v[2] - axis[2] * v[1],
        axis[2] * v[0] - axis[0] * v[2],
        axis[0] * v[1] - axis[1] * v[0],
    ];
    let r = [
        v[0] + angle * c[0],
        v[1] + angle * c[1],
        v[2] + angle * c[2],
    ];
    let n = (r[0] * r[0] + r[1] * r[1] + r[2] * r[2]).sqrt();
    [r[0] / n, r[1] / n, r[2] / n]
}

/// The true A and sensor gains of one realization.
fn realize(
    nominal: &Nominal,
    p: &Perturbation,
    rng: &mut StdRng,
) -> Result<(SparseColMat<usize, f64>, Vec<f64>), M1Error> {
    let ns = nominal.a.nrows();
    let gauss = |s: f64, rng: &mut StdRng| -> f64 {
        let x: f64 = StandardNormal.sample(rng);
        s * x
    };
    match p {
        Perturbation::SensorGain { rms } => Ok((
            nominal.a.clone(),
            (0..ns).map(|_| 1.0 + gauss(*rms, rng)).collect(),
        )),
        Perturbation::Leff { factor } => {
            let mut params = nominal.geometry.params;
            params.leff *= factor;
            let g = Geometry::new(&nominal.geometry.layout, params)?;
            Ok((a_matrix(&g), vec![1.0; ns]))
        }
        Perturbation::ElementErrors { rms } => {
            let mut a = nominal.a.clone();
            for v in a.val_mut() {
                *v *= 1.0 + gauss(*rms, rng);
            }
            Ok((a, vec![1.0; ns]))
        }
        Perturbation::SensorInstall {
            position_rms,
            tilt_rms,
        } => {
            let mut g = nominal.geometry.clone();
            for s in &mut g.sensors {
                let (a, b) = (gauss(*position_rms, rng), gauss(*position_rms, rng));
                for k in 0..3 {
                    s.point[k] += a * s.gap[k] + b * s.shear[k];
                }
                let (t1, t2) = (gauss(*tilt_rms, rng), gauss(*tilt_rms, rng));
                s.height = rotate_about(rotate_about(s.height, s.gap, t1), s.shear, t2);
            }
            Ok((a_matrix(&g), vec![1.0; ns]))
        }
        Perturbation::SegmentInstall {
            position_rms,
            clocking_rms,
        } => {
            let mut g = nominal.geometry.clone();
            for f in &mut g.segments {
                let (a, b, c) = (
                    gauss(*position_rms, rng),
                    gauss(*position_rms, rng),
                    gauss(*clocking_rms, rng),
                );
                for act in &mut f.actuators {
                    let d = [
                        act[0] - f.centre[0],
                        act[1] - f.centre[1],
                        act[2] - f.centre[2],
                    ];
                    let n = f.normal;
                    // Clock by c about the normal (first order), then shift in-plane.
                    let cross = [
                        n[1] * d[2] - n[2] * d[1],
                        n[2] * d[0] - n[0] * d[2],
                        n[0] * d[1] - n[1] * d[0],
                    ];
                    for k in 0..3 {
                        act[k] += c * cross[k] + a * f.radial[k] + b * f.azimuthal[k];
                    }
                }
            }
            Ok((a_matrix(&g), vec![1.0; ns]))
        }
    }
}

/// The metrics of one realization.
fn metrics(
    nominal: &Nominal,
    gamma: &SparseReconstructor,
    a: &SparseColMat<usize, f64>,
    gains: &[f64],
    m: usize,
    seed: u64,
) -> [f64; 4] {
    let (na, ns) = (a.ncols(), a.nrows());
    let null = nominal.b0.null_space();
    let mut v0: Vec<f64> = {
        let mut r = StdRng::seed_from_u64(seed);
        (0..na).map(|_| StandardNormal.sample(&mut r)).collect()
    };
    project_out(null, &mut v0);
    let sa = |x: &[f64]| {
        let mut y = vec![0.0; ns];
        sparse_mul(a, x, &mut y);
        for (yi, g) in y.iter_mut().zip(gains) {
            *yi *= g;
        }
        y
    };
    // Q^T x = P A^T S B^T x (restricted to the observable subspace).
    let at_s = |y: &mut Vec<f64>| {
        for (yi, g) in y.iter_mut().zip(gains) {
            *yi *= g;
        }
        let mut out = vec![0.0; na];
        at_mul(a, y, &mut out);
        project_out(null, &mut out);
        out
    };
    let q = |x: &[f64], out: &mut [f64]| {
        let mut xp = x.to_vec();
        project_out(null, &mut xp);
        out.copy_from_slice(&nominal.b0.apply(&sa(&xp)));
    };
    // (Q - I) restricted to the observable subspace: P (Q P - I) P, so round-off in the
    // projected-out directions cannot show up as spurious eigenvalues -1.
    let ritz = krylov::ritz_values(na, m, &v0, 1.0, |x, out| {
        q(x, out);
        for (o, xi) in out.iter_mut().zip(x) {
            *o -= xi;
        }
        project_out(null, out);
    });
    let rho = ritz.iter().map(|l| l.norm()).fold(0.0, f64::max);
    let min_re = ritz
        .iter()
        .map(|l| l.re + 1.0)
        .fold(f64::INFINITY, f64::min);
    let sigma = krylov::largest_singular_value(na, m, &v0, q, |x, out| {
        let mut y = nominal.b0.apply_transpose(x);
        out.copy_from_slice(&at_s(&mut y));
    });
    let qg = |x: &[f64], out: &mut [f64]| {
        let mut xp = x.to_vec();
        project_out(null, &mut xp);
        out.copy_from_slice(&gamma.apply(&sa(&xp)));
    };
    let sigma_g = krylov::largest_singular_value(na, m, &v0, qg, |x, out| {
        let mut y = gamma.apply_transpose(x);
        out.copy_from_slice(&at_s(&mut y));
    });
    [rho, sigma, sigma_g, min_re]
}

/// Runs the robustness cases: deterministic cases (Leff) once, random ones `realizations` times,
/// each realization with its own seed derived from `params.seed`.
pub fn robustness(
    nominal: &Nominal,
    cases: &[Case],
    params: &RobustnessParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<CaseResult>, M1Error> {
    use rayon::prelude::*;
    let gamma = nominal.with_focus_gain(1.0 / params.focus_gain_factor)?;
    let total: usize = cases
        .iter()
        .map(|c| match c.perturbation {
            Perturbation::Leff { .. } => 1,
            _ => params.realizations,
        })
        .sum();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let mut out = Vec::new();
    for case in cases {
        let n = match case.perturbation {
            Perturbation::Leff { .. } => 1,
            _ => params.realizations,
        };
        let results: Result<Vec<[f64; 4]>, M1Error> = (0..n)
            .into_par_iter()
            .map(|r| {
                // Common random numbers: realization r of every case uses the same draws, so
                // cases of one kind differ only by their amplitude.
                let seed = params.seed.wrapping_mul(1_000_003).wrapping_add(r as u64);
                let mut rng = StdRng::seed_from_u64(seed);
                let (a, gains) = realize(nominal, &case.perturbation, &mut rng)?;
                let m = metrics(
                    nominal,
                    &gamma,
                    &a,
                    &gains,
                    params.krylov_dim,
                    seed ^ 0x5eed,
                );
                let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(k, total);
                Ok(m)
            })
            .collect();
        let results = results?;
        let col = |k: usize| results.iter().map(|m| m[k]).collect::<Vec<f64>>();
        let unstable = results.iter().filter(|m| m[3] <= 0.0).count();
        out.push(CaseResult {
            case: case.clone(),
            realizations: n,
            rho_q_minus_i: Stats::of(col(0)),
            sigma_q: Stats::of(col(1)),
            sigma_gamma_q: Stats::of(col(2)),
            min_real_eigenvalue: Stats::of(col(3)),
            unstable_fraction: unstable as f64 / n as f64,
        });
    }
    Ok(out)
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

fn row_norms(m: &Mat<f64>) -> Vec<f64> {
    (0..m.nrows())
        .map(|r| {
            (0..m.ncols())
                .map(|c| m[(r, c)] * m[(r, c)])
                .sum::<f64>()
                .sqrt()
        })
        .collect()
}

fn rms_of(values: &[f64]) -> f64 {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensor_gain_errors_never_destabilise_and_scale_with_the_error() {
        let g = default_geometry(&Layout::keck(), false, None).expect("geometry");
        let nominal = Nominal::new(g).expect("nominal");
        let params = RobustnessParams {
            realizations: 4,
            ..Default::default()
        };
        let cases = vec![
            Case {
                name: "0.1%".into(),
                perturbation: Perturbation::SensorGain { rms: 1e-3 },
            },
            Case {
                name: "1%".into(),
                perturbation: Perturbation::SensorGain { rms: 1e-2 },
            },
        ];
        let r = robustness(&nominal, &cases, &params, &|_, _| {}).expect("robustness");
        // Q - I is similar to the symmetric U^T dS U: with the same draws, rho scales exactly
        // with the gain error (to the Krylov estimate's accuracy).
        for k in 0..4 {
            let ratio = r[1].rho_q_minus_i.values[k] / r[0].rho_q_minus_i.values[k];
            assert!((ratio - 10.0).abs() < 1e-3, "{ratio}");
        }
        for c in &r {
            assert_eq!(c.unstable_fraction, 0.0);
            assert!(c.sigma_q.worst >= 1.0 - 1e-6);
            // Reducing focus-mode's gain can only lower the worst singular value.
            assert!(c.sigma_gamma_q.worst <= c.sigma_q.worst + 1e-9);
        }
    }

    #[test]
    fn no_error_gives_the_identity() {
        let g = default_geometry(&Layout::keck(), false, None).expect("geometry");
        let nominal = Nominal::new(g).expect("nominal");
        let gains = vec![1.0; nominal.a.nrows()];
        let gamma = nominal.with_focus_gain(0.25).expect("gamma");
        let m = metrics(&nominal, &gamma, &nominal.a, &gains, 40, 3);
        assert!(m[0] < 1e-9, "rho(Q - I) = {}", m[0]);
        assert!((m[1] - 1.0).abs() < 1e-9, "sigma(Q) = {}", m[1]);
        assert!((m[2] - 1.0).abs() < 1e-9, "sigma(GQ) = {}", m[2]);
    }
}
