//! Robustness of the control to errors in the interaction matrix: the seed paper's Table 1.

use super::*;

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

pub(super) fn rotate_about(v: [f64; 3], axis: [f64; 3], angle: f64) -> [f64; 3] {
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
pub(super) fn realize(
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
pub(super) fn metrics(
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
