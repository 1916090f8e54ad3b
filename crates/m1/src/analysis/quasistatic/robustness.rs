//! Robustness of the control to errors in the interaction matrix: the seed paper's Table 1.

use super::*;
use crate::loads::deformation::{Deformation, DeformationParams, ParametricDeformation};
use crate::sensing::installed::{GapLaw, HeightSplit, Installation};
use rand::Rng;

/// Where the random errors of [`Perturbation::ElementErrors`] are applied.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ElementBasis {
    /// Every non-zero of A in the actuator basis (six per row).
    Actuator,
    /// Every non-zero of A in the segment piston/tip/tilt basis, `A P` with `P` the
    /// block-diagonal map from segment (p, alpha, beta) to actuator heights; the perturbed matrix
    /// is mapped back with `P^-1`.
    Ptt,
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
    /// Every non-zero element of A (in `basis`) multiplied by (1 + N(0, rms)).
    ElementErrors {
        /// rms relative error.
        rms: f64,
        /// The basis whose non-zeros are perturbed.
        basis: ElementBasis,
    },
    /// Sensor installation: each sensor point moved in-plane (gap and shear directions) by
    /// N(0, position_rms), its frame tilted by N(0, tilt_rms) about both in-plane axes, and its
    /// own gap offset by N(0, gap_rms), which changes its gain and L_eff by the gap law. With
    /// `gap_correction` the controller knows each sensor's gap (it measures it) and rebuilds its
    /// reconstructor from the A of the measured gaps.
    SensorInstall {
        /// m.
        position_rms: f64,
        /// rad.
        tilt_rms: f64,
        /// m.
        gap_rms: f64,
        /// Reconstructor recomputed from the measured gaps.
        gap_correction: bool,
    },
    /// Segment installation: each segment placed in-plane with an error N(0, position_rms)
    /// (radial and azimuthal) and clocked by N(0, clocking_rms); it carries its sensor halves
    /// and actuators, so the gaps at its sensors change and with them the sensors' gains and
    /// L_eff (gap law).
    SegmentInstall {
        /// m.
        position_rms: f64,
        /// rad.
        clocking_rms: f64,
    },
    /// The mirror at another zenith angle than the baseline at which A was computed: the
    /// deformation model's in-plane motion changes the gaps (deterministic).
    Zenith {
        /// deg.
        deg: f64,
    },
    /// The mirror at another temperature than the baseline (deterministic).
    Temperature {
        /// degC relative to the baseline.
        delta: f64,
    },
}

impl Perturbation {
    /// Deterministic perturbations are computed once.
    pub fn is_deterministic(&self) -> bool {
        matches!(
            self,
            Self::Leff { .. } | Self::Zenith { .. } | Self::Temperature { .. }
        )
    }
}

/// The seed paper's Table 1 entry of a case: `rho(Q - I)`, `sigma(Q)`,
/// `sigma(Gamma Psi Q Psi^T)` (worst of 100 realizations for the random cases), or the risk of
/// instability where the paper gives that instead.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Published {
    /// The three metrics.
    Metrics([f64; 3]),
    /// The fraction of realizations that are unstable (a lower bound when `at_least`).
    Risk {
        /// Fraction.
        fraction: f64,
        /// "over" this fraction.
        at_least: bool,
    },
}

/// A named robustness case.
#[derive(Debug, Clone, Serialize)]
pub struct Case {
    /// Label.
    pub name: String,
    /// The error source.
    pub perturbation: Perturbation,
    /// The seed paper's value, where it publishes one.
    pub published: Option<Published>,
}

impl Case {
    /// The default set of cases (values marked in the docs as *assumed* where not published).
    pub fn defaults() -> Vec<Case> {
        use Published::{Metrics, Risk};
        let c = |name: &str, p, published| Case {
            name: name.into(),
            perturbation: p,
            published,
        };
        let d = &INSTALL_DEFAULTS;
        let sensor = |gap_correction| Perturbation::SensorInstall {
            position_rms: d.sensor_position_rms,
            tilt_rms: d.sensor_tilt_rms,
            gap_rms: d.sensor_gap_rms,
            gap_correction,
        };
        let elements = |rms, basis| Perturbation::ElementErrors { rms, basis };
        let m = |a, b, c| Some(Metrics([a, b, c]));
        vec![
            c(
                "zenith 0 deg",
                Perturbation::Zenith { deg: 0.0 },
                m(2.5e-3, 1.34, 1.08),
            ),
            c(
                "zenith 15 deg",
                Perturbation::Zenith { deg: 15.0 },
                m(1.3e-3, 1.18, 1.04),
            ),
            c(
                "zenith 25 deg",
                Perturbation::Zenith { deg: 25.0 },
                m(0.5e-3, 1.06, 1.02),
            ),
            c(
                "zenith 65 deg",
                Perturbation::Zenith { deg: 65.0 },
                m(3.8e-3, 1.65, 1.16),
            ),
            c(
                "temperature -5 C",
                Perturbation::Temperature { delta: -5.0 },
                m(14e-3, 1.13, 1.02),
            ),
            c(
                "temperature +5 C",
                Perturbation::Temperature { delta: 5.0 },
                m(13e-3, 1.11, 1.02),
            ),
            c(
                "segment install",
                Perturbation::SegmentInstall {
                    position_rms: d.segment_position_rms,
                    clocking_rms: d.segment_clocking_rms,
                },
                m(10e-3, 3.81, 1.76),
            ),
            c("sensor install", sensor(false), m(6.1e-3, 1.91, 1.23)),
            c(
                "sensor install, gap corr.",
                sensor(true),
                m(4.4e-3, 1.24, 1.06),
            ),
            c(
                "sensor gain 0.1%",
                Perturbation::SensorGain { rms: 1e-3 },
                m(3.9e-3, 1.81, 1.20),
            ),
            c(
                "sensor gain 1%",
                Perturbation::SensorGain { rms: 1e-2 },
                m(35e-3, 12.6, 3.98),
            ),
            c("Leff +10%", Perturbation::Leff { factor: 1.1 }, None),
            c("Leff -10%", Perturbation::Leff { factor: 0.9 }, None),
            c(
                "A elements 2%",
                elements(0.02, ElementBasis::Actuator),
                Some(Risk {
                    fraction: 1.0 / 500.0,
                    at_least: false,
                }),
            ),
            c(
                "A elements 5%",
                elements(0.05, ElementBasis::Actuator),
                Some(Risk {
                    fraction: 0.1,
                    at_least: true,
                }),
            ),
            c(
                "A(ptt) elements 2%",
                elements(0.02, ElementBasis::Ptt),
                None,
            ),
            c(
                "A(ptt) elements 5%",
                elements(0.05, ElementBasis::Ptt),
                None,
            ),
        ]
    }
}

/// The installation errors of Table 1's install rows: *calibrated* to the rows
/// (segment install 3.81, sensor install 1.91 and 1.24 with gap correction, worst of 100).
pub const INSTALL_DEFAULTS: Installation = Installation {
    segment_position_rms: 9e-6,
    segment_clocking_rms: 9e-6,
    sensor_position_rms: 0.15e-3,
    sensor_tilt_rms: 0.4e-3,
    sensor_gap_rms: 4e-6,
    seed: 1,
};

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
    /// sigma_max(Q) (of the first `RobustnessParams::realizations` realizations: the risk
    /// realizations beyond them compute the eigenvalues only).
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
    /// Realizations per random case (default: 100, as the seed paper's Table 1).
    pub realizations: usize,
    /// Realizations of the random element-error cases, whose instability risk is to be
    /// resolved to 1 in 1000 (default: 1000).
    pub risk_realizations: usize,
    /// Focus-mode gain reduction factor of Gamma (default: 4).
    pub focus_gain_factor: f64,
    /// Seed (default: 1).
    pub seed: u64,
    /// Krylov dimension of the estimates (default: 60).
    pub krylov_dim: usize,
    /// The deformation model of the zenith and temperature cases.
    pub deformation: DeformationParams,
    /// How the sensors' gain and L_eff depend on their gap.
    pub gap_law: GapLaw,
}

impl Default for RobustnessParams {
    fn default() -> Self {
        Self {
            realizations: 100,
            risk_realizations: 1000,
            focus_gain_factor: 4.0,
            seed: 1,
            krylov_dim: 60,
            deformation: DeformationParams::default(),
            gap_law: GapLaw::default(),
        }
    }
}

impl RobustnessParams {
    /// Realizations of `p`: 1 if deterministic, `risk_realizations` for element errors, else
    /// `realizations`.
    pub fn realizations_of(&self, p: &Perturbation) -> usize {
        match p {
            p if p.is_deterministic() => 1,
            Perturbation::ElementErrors { .. } => self.risk_realizations,
            _ => self.realizations,
        }
    }
}

/// What a realization needs beyond the nominal setup: the A-matrix split and the baseline
/// deformation model, built once per analysis.
pub(super) struct Context<'a> {
    pub nominal: &'a Nominal,
    pub split: HeightSplit,
    pub deformation: ParametricDeformation,
    pub gap_law: GapLaw,
    pub a_gw: SparseColMat<usize, f64>,
    /// Gamma's focus-mode gain.
    pub focus_gain: f64,
}

impl<'a> Context<'a> {
    pub fn new(nominal: &'a Nominal, params: &RobustnessParams) -> Result<Self, M1Error> {
        let g = &nominal.geometry;
        Ok(Self {
            nominal,
            split: HeightSplit::new(g),
            deformation: ParametricDeformation::new(g, params.deformation)?,
            gap_law: params.gap_law,
            a_gw: interaction_matrices(g).a_gw,
            focus_gain: 1.0 / params.focus_gain_factor,
        })
    }

    /// A of the nominal sensors with the gap changes `dgap` (gap law).
    fn with_gaps(
        &self,
        split: &HeightSplit,
        dgap: &[f64],
    ) -> Result<SparseColMat<usize, f64>, M1Error> {
        let (g, l) = self.gap_law.factors(dgap);
        split.assemble(&g, &l)
    }

    /// A at the deformation state (zenith, temperature) relative to the baseline.
    fn deformed(&self, zenith: f64, temperature: f64) -> Result<SparseColMat<usize, f64>, M1Error> {
        let n3 = self.nominal.geometry.n_actuators();
        let mut d = Deformation {
            w: vec![0.0; n3],
            z_cell: vec![0.0; n3],
        };
        let p = self.deformation.params();
        self.deformation
            .evaluate_into(zenith, p.baseline_temperature + temperature, &mut d)?;
        let mut dgap = vec![0.0; self.nominal.a.nrows()];
        sparse_mul(&self.a_gw, &d.w, &mut dgap);
        self.with_gaps(&self.split, &dgap)
    }
}

/// One realization: the true A, the sensor gains and, if the controller rebuilt its
/// reconstructor (gap correction), the rebuilt B0 and Gamma.
pub(super) struct Realized {
    pub a: SparseColMat<usize, f64>,
    pub gains: Vec<f64>,
    pub rebuilt: Option<(SparseReconstructor, SparseReconstructor)>,
}

/// `A P` in the segment piston/tip/tilt basis, perturbed element-wise by `1 + N(0, rms)`, and
/// mapped back to the actuator basis.
fn ptt_element_errors(
    geometry: &Geometry,
    a: &SparseColMat<usize, f64>,
    rms: f64,
    rng: &mut StdRng,
) -> Result<SparseColMat<usize, f64>, M1Error> {
    let sym = a.symbolic();
    let mut triplets = Vec::with_capacity(a.val().len());
    let mut rows: Vec<(usize, usize, f64)> = Vec::new();
    for i in 0..geometry.n_segments() {
        let p = geometry.ptt_matrix(i);
        let pinv = geometry.ptt_inverse(i);
        // The rows of the segment's three columns, row by row.
        rows.clear();
        for k in 0..3 {
            let c = 3 * i + k;
            for e in sym.col_ptr()[c]..sym.col_ptr()[c + 1] {
                rows.push((sym.row_idx()[e], k, a.val()[e]));
            }
        }
        rows.sort_unstable_by_key(|e| (e.0, e.1));
        for chunk in rows.chunk_by(|x, y| x.0 == y.0) {
            let mut row = [0.0; 3];
            for &(_, k, v) in chunk {
                row[k] = v;
            }
            // (A P)_r = row . P[:, c]
            let mut ap: [f64; 3] = std::array::from_fn(|c| (0..3).map(|k| row[k] * p[k][c]).sum());
            for v in &mut ap {
                if *v != 0.0 {
                    let x: f64 = StandardNormal.sample(rng);
                    *v *= 1.0 + rms * x;
                }
            }
            for k in 0..3 {
                let v: f64 = ap.iter().zip(pinv).map(|(a, row)| a * row[k]).sum();
                triplets.push(faer::sparse::Triplet::new(chunk[0].0, 3 * i + k, v));
            }
        }
    }
    SparseColMat::try_new_from_triplets(a.nrows(), a.ncols(), &triplets)
        .map_err(|e| M1Error::Numerical(format!("A in the piston/tip/tilt basis: {e:?}")))
}

/// The true A and sensor gains of one realization.
pub(super) fn realize(
    ctx: &Context<'_>,
    p: &Perturbation,
    rng: &mut StdRng,
) -> Result<Realized, M1Error> {
    let nominal = ctx.nominal;
    let ns = nominal.a.nrows();
    let gauss = |s: f64, rng: &mut StdRng| -> f64 {
        let x: f64 = StandardNormal.sample(rng);
        s * x
    };
    let plain = |a| Realized {
        a,
        gains: vec![1.0; ns],
        rebuilt: None,
    };
    match p {
        Perturbation::SensorGain { rms } => Ok(Realized {
            a: nominal.a.clone(),
            gains: (0..ns).map(|_| 1.0 + gauss(*rms, rng)).collect(),
            rebuilt: None,
        }),
        Perturbation::Leff { factor } => {
            let mut params = nominal.geometry.params;
            params.leff *= factor;
            let g = Geometry::new(&nominal.geometry.layout, params)?;
            Ok(plain(a_matrix(&g)))
        }
        Perturbation::ElementErrors { rms, basis } => match basis {
            ElementBasis::Actuator => {
                let mut a = nominal.a.clone();
                for v in a.val_mut() {
                    *v *= 1.0 + gauss(*rms, rng);
                }
                Ok(plain(a))
            }
            ElementBasis::Ptt => Ok(plain(ptt_element_errors(
                &nominal.geometry,
                &nominal.a,
                *rms,
                rng,
            )?)),
        },
        Perturbation::SensorInstall {
            position_rms,
            tilt_rms,
            gap_rms,
            gap_correction,
        } => {
            let inst = Installation {
                sensor_position_rms: *position_rms,
                sensor_tilt_rms: *tilt_rms,
                sensor_gap_rms: *gap_rms,
                seed: rng.next_u64(),
                ..Installation::default()
            }
            .install(&nominal.geometry)?;
            let split = HeightSplit::new(&inst.geometry);
            let a = ctx.with_gaps(&split, &inst.dgap)?;
            let rebuilt = if *gap_correction {
                // The controller measures each sensor's gap and uses the nominal geometry's A
                // with the gain and L_eff of the measured gaps.
                let a0 = ctx.with_gaps(&ctx.split, &inst.dgap)?;
                let null = nominal.b0.null_space();
                let b0 = SparseReconstructor::new(&a0, null, Vec::new())?;
                let gamma = SparseReconstructor::new(
                    &a0,
                    null,
                    vec![crate::control::reconstructor::ModalGain {
                        mode: nominal.focus.clone(),
                        gain: ctx.focus_gain,
                    }],
                )?;
                Some((b0, gamma))
            } else {
                None
            };
            Ok(Realized {
                a,
                gains: vec![1.0; ns],
                rebuilt,
            })
        }
        Perturbation::SegmentInstall {
            position_rms,
            clocking_rms,
        } => {
            let inst = Installation {
                segment_position_rms: *position_rms,
                segment_clocking_rms: *clocking_rms,
                seed: rng.next_u64(),
                ..Installation::default()
            }
            .install(&nominal.geometry)?;
            Ok(plain(ctx.with_gaps(&ctx.split, &inst.dgap)?))
        }
        Perturbation::Zenith { deg } => Ok(plain(ctx.deformed(*deg, 0.0)?)),
        Perturbation::Temperature { delta } => Ok(plain(
            ctx.deformed(ctx.deformation.params().baseline_zenith_deg, *delta)?,
        )),
    }
}

/// The metrics of one realization.
pub(super) fn metrics(
    b0: &SparseReconstructor,
    gamma: &SparseReconstructor,
    a: &SparseColMat<usize, f64>,
    gains: &[f64],
    m: usize,
    seed: u64,
    eigen_only: bool,
) -> [f64; 4] {
    let (na, ns) = (a.ncols(), a.nrows());
    let null = b0.null_space();
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
        out.copy_from_slice(&b0.apply(&sa(&xp)));
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
    if eigen_only {
        return [rho, f64::NAN, f64::NAN, min_re];
    }
    let sigma = krylov::largest_singular_value(na, m, &v0, q, |x, out| {
        let mut y = b0.apply_transpose(x);
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

/// Runs the robustness cases: deterministic cases once, element errors
/// `params.risk_realizations` times, the other random ones `params.realizations` times, each
/// realization with its own seed derived from `params.seed`.
pub fn robustness(
    nominal: &Nominal,
    cases: &[Case],
    params: &RobustnessParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Vec<CaseResult>, M1Error> {
    use rayon::prelude::*;
    let gamma = nominal.with_focus_gain(1.0 / params.focus_gain_factor)?;
    let ctx = Context::new(nominal, params)?;
    let total: usize = cases
        .iter()
        .map(|c| params.realizations_of(&c.perturbation))
        .sum();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let mut out = Vec::new();
    for case in cases {
        let n = params.realizations_of(&case.perturbation);
        let results: Result<Vec<[f64; 4]>, M1Error> = (0..n)
            .into_par_iter()
            .map(|r| {
                // Common random numbers: realization r of every case uses the same draws, so
                // cases of one kind differ only by their amplitude.
                let seed = params.seed.wrapping_mul(1_000_003).wrapping_add(r as u64);
                let mut rng = StdRng::seed_from_u64(seed);
                let real = realize(&ctx, &case.perturbation, &mut rng)?;
                let (b0, g) = match &real.rebuilt {
                    Some((b, g)) => (b, g),
                    None => (&nominal.b0, &gamma),
                };
                // Beyond `realizations`, the risk realizations need the eigenvalues only.
                let eigen_only = r >= params.realizations;
                let m = metrics(
                    b0,
                    g,
                    &real.a,
                    &real.gains,
                    params.krylov_dim,
                    seed ^ 0x5eed,
                    eigen_only,
                );
                let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(k, total);
                Ok(m)
            })
            .collect();
        let results = results?;
        // The singular values exist for the first `realizations` only (see `eigen_only`).
        let col = |k: usize| {
            results
                .iter()
                .map(|m| m[k])
                .filter(|v| !v.is_nan())
                .collect::<Vec<f64>>()
        };
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
