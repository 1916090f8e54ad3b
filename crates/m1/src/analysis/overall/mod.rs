//! The overall quasi-static simulation of the control algorithm (the seed paper's Figure 3):
//! the mirror through nights of tracking and weeks of operation, with gravity and thermal
//! deformation, installed sensors that drift, calibration of the desired readings, APS runs and
//! real-time optical feedback.
//!
//! # Model
//!
//! At each quasi-static instant (minutes apart, [`schedule`]) of zenith angle `zeta` and
//! temperature `T`:
//!
//! 1. the deformation model ([`crate::loads::deformation`]) gives the in-plane motion
//!    `w = w_0 + w(zeta, T)` (with the segments' installation errors `w_0`) and the cell motion
//!    at the actuators `z_cell`;
//! 2. each installed sensor ([`crate::sensing::installed`]) has its gap change
//!    `dg = A_gw w + dg_sensor`, hence its gain and `L_eff` (gap law), and reads
//!
//!    ```text
//!    y = diag(s)(A_h + diag(L) A_d) z + r,     r = A_hw w + drift + noise,
//!    ```
//!
//!    where `z` are the segments' out-of-plane positions at the actuators (`z = 0` is the
//!    perfectly phased mirror), `A_hw` of the installed (tilted) sensors gives the cross-axis
//!    sensitivity to gap and shear, the drift is `c_n T + d_n t` with `c_n`, `d_n` uniform
//!    within the specification (1 nm/degC, 1 nm/week) and the noise is white of rms
//!    `noise_rms sqrt(g / (2 - g))`, the loop's average over the noise (`g` its integrator gain
//!    per sample), drawn once per instant. `r` is the reading of the phased mirror;
//! 3. the global loop has converged (its bandwidth is ~1 Hz, the step minutes): the actuator
//!    command `u` solves `B_0 (y - y_ref) = 0`, found by the loop's own iteration
//!    `u <- u - B_0 (y(z_cell + u + u_lo) - y_ref)` from the previous instant's `u` until the
//!    change is below 1e-12 m rms;
//! 4. the desired readings are `y_ref = y_APS + f(g, s) - f(g_APS, s_APS) + dy_OF`: the APS
//!    value, the calibration fit's change since the APS run ([`fit`], when calibration is on;
//!    the sensors' measured gap `g` and shear `s` estimated from the gaps by eq. 2) and the
//!    optical feedback's focus-mode offset;
//! 5. the optical feedback ([`crate::control::aps::OpticalFeedback`], when on) measures the
//!    settled mirror once per instant, integrates over the step (its time constant, seconds to a
//!    minute, is short against the step, so it converges within it) and commands global
//!    piston/tip/tilt directly (`u_lo`) and focus-mode through `y_ref`, on which the loop
//!    settles again; it restarts each night;
//! 6. every `interval_days` at the start of the night the APS measures the segments and resets
//!    `y_ref` ([`crate::control::aps::Aps`]).
//!
//! Before the first night, a calibration campaign runs the APS at a grid of zenith angles and
//! temperatures; its phased readings, measured gaps and estimated shears fit the calibration
//! functions, which are compared by leave-one-out residual ([`fit::compare`]).
//!
//! The simulation runs four variants on the same draws (common random numbers): with and
//! without calibration, with and without optical feedback. The figures at each instant are the
//! rms surface with global piston/tip/tilt removed, the same without focus-mode, focus-mode,
//! the calibration residual (rms over the sensors of `y_ref - r` before the optical-feedback
//! offset: how far the desired readings are from those of the phased mirror) and, every
//! `pssn_every_minutes`, the PSSN.

pub mod fit;
pub mod schedule;

use faer::Mat;
use faer::sparse::SparseColMat;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal, Uniform};
use serde::Serialize;

use crate::M1Error;
use crate::analysis::quasistatic::{INSTALL_DEFAULTS, SHEAR_RANK_TOLERANCE, ShearEstimator};
use crate::aperture::geometry::Geometry;
use crate::control::aps::{Aps, ApsParams, OpticalFeedback, OpticalFeedbackParams};
use crate::control::controller::{DEFAULT_BANDWIDTH, DEFAULT_RATE, integrator_gain};
use crate::control::nominal::Nominal;
use crate::control::reconstructor::sparse_mul;
use crate::loads::deformation::{Deformation, DeformationModel, DeformationParams};
use crate::optics::metrics::MirrorMetrics;
use crate::optics::pssn::{Pssn, PssnParams};
use crate::sensing::installed::{GapLaw, HeightSplit, Installation, Installed};
use crate::sensing::interaction::interaction_matrices;

use fit::{Calibration, CalibrationSample, FitComparison, FitFunction};
use schedule::{Instant, ScheduleParams};

/// The installed sensors' errors beyond the gap law.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SensorSpec {
    /// rms white noise of a height reading (m, default 5e-9: the specification).
    pub noise_rms: f64,
    /// rms white noise of a gap reading (m, default 5e-9, *assumed*).
    pub gap_noise_rms: f64,
    /// Temperature drift bound (m/degC, default 1e-9: the specification); each sensor's
    /// coefficient is uniform within +- this.
    pub drift_per_degc: f64,
    /// Time drift bound (m/week, default 1e-9: the specification).
    pub drift_per_week: f64,
}

impl Default for SensorSpec {
    fn default() -> Self {
        Self {
            noise_rms: 5e-9,
            gap_noise_rms: 5e-9,
            drift_per_degc: 1e-9,
            drift_per_week: 1e-9,
        }
    }
}

/// The calibration campaign before the first night.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CalibrationPlan {
    /// Zenith angles of the APS runs (deg, default 0, 20, 40, 60).
    pub zenith_deg: Vec<f64>,
    /// Temperatures of the APS runs (degC, default -4, 0, 4).
    pub temperature: Vec<f64>,
    /// The fit function used in operation (default gap and shear).
    pub function: FitFunction,
}

impl Default for CalibrationPlan {
    fn default() -> Self {
        Self {
            zenith_deg: vec![0.0, 20.0, 40.0, 60.0],
            temperature: vec![-4.0, 0.0, 4.0],
            function: FitFunction::GapShear,
        }
    }
}

/// Everything the overall simulation takes.
#[derive(Debug, Clone, Serialize)]
pub struct OverallParams {
    /// The nights.
    pub schedule: ScheduleParams,
    /// The parametric deformation model (used unless a table is given to [`run`]).
    pub deformation: DeformationParams,
    /// The sensors' gap law.
    pub gap_law: GapLaw,
    /// Installation errors (default: those of Table 1's install rows).
    pub installation: Installation,
    /// Noise and drift of the sensors.
    pub sensors: SensorSpec,
    /// The APS.
    pub aps: ApsParams,
    /// The optical feedback.
    pub optical_feedback: OpticalFeedbackParams,
    /// The calibration campaign.
    pub calibration: CalibrationPlan,
    /// Global loop rate (Hz) and bandwidth (Hz): set the noise average.
    pub loop_rate: f64,
    /// Global loop bandwidth (Hz).
    pub loop_bandwidth: f64,
    /// Most loop iterations per instant (default 100): the loop iterates until its command
    /// changes by less than 1e-12 m rms (the steady state of the integrator); a night's start,
    /// after a day of temperature change, needs tens of iterations since Q is not normal.
    /// Not converging within them is an error.
    pub iterations: usize,
    /// Minutes between PSSN evaluations (default 60; 0: none).
    pub pssn_every_minutes: f64,
    /// Samples across the aperture of the PSSN (default 128).
    pub pssn_samples: usize,
    /// Seed of the noise and drift draws (default 1).
    pub seed: u64,
}

impl Default for OverallParams {
    fn default() -> Self {
        Self {
            schedule: ScheduleParams::default(),
            deformation: DeformationParams::default(),
            gap_law: GapLaw::default(),
            installation: INSTALL_DEFAULTS,
            sensors: SensorSpec::default(),
            aps: ApsParams::default(),
            optical_feedback: OpticalFeedbackParams::default(),
            calibration: CalibrationPlan::default(),
            loop_rate: DEFAULT_RATE,
            loop_bandwidth: DEFAULT_BANDWIDTH,
            iterations: 100,
            pssn_every_minutes: 60.0,
            pssn_samples: 128,
            seed: 1,
        }
    }
}

/// Summary of one time series.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct SeriesSummary {
    /// Mean.
    pub mean: f64,
    /// Root mean square.
    pub rms: f64,
    /// 95th percentile of the absolute value.
    pub p95: f64,
    /// Largest absolute value.
    pub max: f64,
}

impl SeriesSummary {
    fn of(v: &[f64]) -> Self {
        let n = v.len().max(1) as f64;
        let mut a: Vec<f64> = v.iter().map(|x| x.abs()).collect();
        a.sort_by(|x, y| x.total_cmp(y));
        let idx = ((0.95 * a.len() as f64).ceil() as usize).clamp(1, a.len().max(1)) - 1;
        Self {
            mean: v.iter().sum::<f64>() / n,
            rms: (v.iter().map(|x| x * x).sum::<f64>() / n).sqrt(),
            p95: a.get(idx).copied().unwrap_or(0.0),
            max: a.last().copied().unwrap_or(0.0),
        }
    }
}

/// The time series of one variant (one value per instant; m unless stated).
#[derive(Debug, Clone, Serialize)]
pub struct VariantResult {
    /// Short name.
    pub name: String,
    /// Calibration fit on.
    pub calibration: bool,
    /// Optical feedback on.
    pub optical_feedback: bool,
    /// rms surface, global piston/tip/tilt removed.
    pub rms: Vec<f64>,
    /// The same without focus-mode.
    pub rms_without_focus: Vec<f64>,
    /// Focus-mode as rms surface (signed).
    pub focus_rms: Vec<f64>,
    /// rms over sensors of the desired readings' error.
    pub calibration_residual: Vec<f64>,
    /// PSSN at the instants `pssn_index`.
    pub pssn: Vec<f64>,
    /// Summaries of `rms`, `rms_without_focus`, `focus_rms`, `calibration_residual`.
    pub summary: [SeriesSummary; 4],
    /// Smallest PSSN.
    pub pssn_min: f64,
    /// The actuator-space surface `z` at the instant of its largest rms (for maps).
    pub worst_z: Vec<f64>,
}

/// The result of [`run`].
#[derive(Debug, Clone, Serialize)]
pub struct OverallResult {
    /// The instants.
    pub instants: Vec<Instant>,
    /// Indices of the instants with a PSSN.
    pub pssn_index: Vec<usize>,
    /// Times of the APS runs (days).
    pub aps_days: Vec<f64>,
    /// The calibration campaign: each candidate's fit and leave-one-out residuals.
    pub calibration_fits: Vec<FitComparison>,
    /// Number of APS runs in the campaign.
    pub calibration_runs: usize,
    /// The variants: neither, calibration, optical feedback, both.
    pub variants: Vec<VariantResult>,
}

/// What does not depend on the variant: per instant, the deformation, gaps, shears and the
/// phased readings.
struct Conditions {
    z_cell: Vec<Vec<f64>>,
    /// True gap change at every sensor (gap law).
    dgap: Vec<Vec<f64>>,
    /// Measured gap change (with noise and the sensors' own offsets).
    gap_meas: Vec<Vec<f64>>,
    /// Shear estimated from the measured gaps.
    shear: Vec<Vec<f64>>,
    /// Reading of the phased mirror, `r` (with noise).
    phased: Vec<Vec<f64>>,
}

/// The fixed parts of the simulation.
struct Setup {
    nominal: Nominal,
    metrics: MirrorMetrics,
    split: HeightSplit,
    a_hw: SparseColMat<usize, f64>,
    a_gw: SparseColMat<usize, f64>,
    shear: ShearEstimator,
    deformation: DeformationModel,
    installed: Installed,
    drift_t: Vec<f64>,
    drift_w: Vec<f64>,
    gap_law: GapLaw,
    noise_scale: f64,
}

impl Setup {
    fn new(
        geometry: &Geometry,
        params: &OverallParams,
        deformation: DeformationModel,
    ) -> Result<Self, M1Error> {
        let nominal = Nominal::new(geometry.clone())?;
        let metrics = MirrorMetrics::with_focus(geometry, &nominal.focus)?;
        let installed = params.installation.install(geometry)?;
        let im = interaction_matrices(&installed.geometry);
        let ns = geometry.n_sensors();
        let mut rng = StdRng::seed_from_u64(params.seed ^ 0xD71F);
        let u = Uniform::new_inclusive(-1.0, 1.0)
            .map_err(|e| M1Error::InvalidInput(format!("drift draw: {e}")))?;
        let drift_t = (0..ns)
            .map(|_| params.sensors.drift_per_degc * u.sample(&mut rng))
            .collect();
        let drift_w = (0..ns)
            .map(|_| params.sensors.drift_per_week * u.sample(&mut rng))
            .collect();
        let g = integrator_gain(params.loop_bandwidth, params.loop_rate);
        Ok(Self {
            split: HeightSplit::new(&installed.geometry),
            a_hw: im.a_hw,
            a_gw: im.a_gw,
            shear: ShearEstimator::new(geometry, SHEAR_RANK_TOLERANCE)?,
            metrics,
            nominal,
            deformation,
            installed,
            drift_t,
            drift_w,
            gap_law: params.gap_law,
            noise_scale: (g / (2.0 - g)).sqrt(),
        })
    }

    /// The conditions at `(zenith, temperature, time)` for each of `points`; `stream` seeds the
    /// noise of point `k` as `(seed, stream, k)`.
    fn conditions(
        &self,
        params: &OverallParams,
        points: &[(f64, f64, f64)],
        stream: u64,
    ) -> Result<Conditions, M1Error> {
        let ns = self.split.n_sensors();
        let n3 = self.split.n_actuators();
        let mut d = Deformation {
            w: vec![0.0; n3],
            z_cell: vec![0.0; n3],
        };
        let mut out = Conditions {
            z_cell: Vec::with_capacity(points.len()),
            dgap: Vec::with_capacity(points.len()),
            gap_meas: Vec::with_capacity(points.len()),
            shear: Vec::new(),
            phased: Vec::with_capacity(points.len()),
        };
        let mut gaps = Mat::<f64>::zeros(ns, points.len());
        let t0 = params.deformation.baseline_temperature;
        for (k, &(zenith, temp, days)) in points.iter().enumerate() {
            self.deformation.evaluate_into(zenith, t0 + temp, &mut d)?;
            let w: Vec<f64> =
                d.w.iter()
                    .zip(&self.installed.segment_w)
                    .map(|(a, b)| a + b)
                    .collect();
            let mut dgap = vec![0.0; ns];
            sparse_mul(&self.a_gw, &w, &mut dgap);
            let mut r = vec![0.0; ns];
            sparse_mul(&self.a_hw, &w, &mut r);
            let mut rng = StdRng::seed_from_u64(
                params
                    .seed
                    .wrapping_mul(0x2545_F491_4F6C_DD1D)
                    .wrapping_add(stream << 32)
                    .wrapping_add(k as u64),
            );
            let mut meas = vec![0.0; ns];
            for n in 0..ns {
                let (a, b): (f64, f64) = (
                    StandardNormal.sample(&mut rng),
                    StandardNormal.sample(&mut rng),
                );
                dgap[n] += self.installed.sensor_gap[n];
                meas[n] = dgap[n] + params.sensors.gap_noise_rms * self.noise_scale * b;
                gaps[(n, k)] = meas[n];
                r[n] += self.drift_t[n] * temp
                    + self.drift_w[n] * days / 7.0
                    + params.sensors.noise_rms * self.noise_scale * a;
            }
            out.z_cell.push(d.z_cell.clone());
            out.dgap.push(dgap);
            out.gap_meas.push(meas);
            out.phased.push(r);
        }
        // Shear from the segments' gap changes as the gaps measure them, all instants at once.
        let s = self.shear.shear(gaps.as_ref());
        out.shear = (0..points.len())
            .map(|k| (0..ns).map(|n| s[(n, k)]).collect())
            .collect();
        Ok(out)
    }
}

/// The loop has settled when its command changes by less than this rms (m).
const SETTLED: f64 = 1e-12;

/// The state of one variant's loop.
struct Loop {
    u: Vec<f64>,
    u_lo: Vec<f64>,
    z: Vec<f64>,
    y: Vec<f64>,
    gain: Vec<f64>,
    leff: Vec<f64>,
    /// Scratch of `settle`: the reading error, the command change, the reconstructor's work.
    err: Vec<f64>,
    du: Vec<f64>,
    work: Vec<f64>,
}

impl Loop {
    fn new(na: usize, ns: usize, work: usize) -> Self {
        Self {
            u: vec![0.0; na],
            u_lo: vec![0.0; na],
            z: vec![0.0; na],
            y: vec![0.0; ns],
            gain: vec![1.0; ns],
            leff: vec![1.0; ns],
            err: vec![0.0; ns],
            du: vec![0.0; na],
            work: vec![0.0; work],
        }
    }

    /// Converges `u` for the conditions `k` and the desired readings `y_ref`; leaves the
    /// segments' positions in `z`.
    fn settle(
        &mut self,
        setup: &Setup,
        c: &Conditions,
        k: usize,
        y_ref: &[f64],
        iterations: usize,
    ) -> Result<(), M1Error> {
        setup
            .gap_law
            .factors_into(&c.dgap[k], &mut self.gain, &mut self.leff);
        for _ in 0..iterations {
            for i in 0..self.z.len() {
                self.z[i] = c.z_cell[k][i] + self.u[i] + self.u_lo[i];
            }
            setup
                .split
                .mul_into(&self.gain, &self.leff, &self.z, &mut self.y)?;
            for (((e, y), p), r) in self
                .err
                .iter_mut()
                .zip(&self.y)
                .zip(&c.phased[k])
                .zip(y_ref)
            {
                *e = y + p - r;
            }
            setup
                .nominal
                .b0
                .apply_into(&self.err, &mut self.du, &mut self.work);
            for (u, d) in self.u.iter_mut().zip(&self.du) {
                *u -= d;
            }
            let change = (self.du.iter().map(|d| d * d).sum::<f64>() / self.du.len() as f64).sqrt();
            if change < SETTLED {
                for i in 0..self.z.len() {
                    self.z[i] = c.z_cell[k][i] + self.u[i] + self.u_lo[i];
                }
                return Ok(());
            }
        }
        Err(M1Error::Numerical(format!(
            "the global loop did not settle within {iterations} iterations at instant {k}"
        )))
    }
}

/// Runs the calibration campaign: APS runs at the plan's grid, each from the previous one's
/// desired readings. Returns the samples.
fn campaign(
    setup: &Setup,
    params: &OverallParams,
    aps: &Aps,
) -> Result<Vec<CalibrationSample>, M1Error> {
    let plan = &params.calibration;
    let points: Vec<(f64, f64, f64)> = plan
        .zenith_deg
        .iter()
        .flat_map(|&z| plan.temperature.iter().map(move |&t| (z, t, 0.0)))
        .collect();
    let c = setup.conditions(params, &points, 1)?;
    let (na, ns) = (setup.split.n_actuators(), setup.split.n_sensors());
    let mut lp = Loop::new(na, ns, setup.nominal.b0.work_len());
    let mut y_ref = vec![0.0; ns];
    let mut out = Vec::new();
    for (k, &(zenith, temp, _)) in points.iter().enumerate() {
        lp.settle(setup, &c, k, &y_ref, params.iterations)?;
        let e = aps.measure(&lp.z, 1_000_000 + k as u64)?;
        Aps::reset_reference(&setup.nominal.a, &mut y_ref, &e)?;
        out.push(CalibrationSample {
            zenith_deg: zenith,
            temperature: temp,
            reading: y_ref.clone(),
            gap: c.gap_meas[k].clone(),
            shear: c.shear[k].clone(),
        });
    }
    Ok(out)
}

/// Runs one variant over the instants.
#[allow(clippy::too_many_arguments)]
fn run_variant(
    setup: &Setup,
    params: &OverallParams,
    c: &Conditions,
    instants: &[Instant],
    aps: &Aps,
    calibration: Option<&Calibration>,
    optical: Option<OpticalFeedback>,
    pssn: Option<(&Pssn, &[usize])>,
) -> Result<(VariantResult, Vec<f64>), M1Error> {
    let (na, ns) = (setup.split.n_actuators(), setup.split.n_sensors());
    let mut lp = Loop::new(na, ns, setup.nominal.b0.work_len());
    let mut optical = optical;
    // Desired readings: the APS value, and the calibration prediction at the last APS run.
    let mut y_aps = vec![0.0; ns];
    let mut f_aps = vec![0.0; ns];
    let mut f_now = vec![0.0; ns];
    let mut y_ref = vec![0.0; ns];
    let dt = params.schedule.step_minutes * 60.0;
    let mut res = VariantResult {
        name: String::new(),
        calibration: calibration.is_some(),
        optical_feedback: optical.is_some(),
        rms: Vec::with_capacity(instants.len()),
        rms_without_focus: Vec::with_capacity(instants.len()),
        focus_rms: Vec::with_capacity(instants.len()),
        calibration_residual: Vec::with_capacity(instants.len()),
        pssn: Vec::new(),
        summary: [SeriesSummary::of(&[]); 4],
        pssn_min: f64::NAN,
        worst_z: vec![0.0; na],
    };
    let mut aps_days = Vec::new();
    let mut worst = -1.0;
    let mut ptt = vec![[0.0; 3]; setup.metrics.n_segments()];
    let mut last_aps_night: Option<usize> = None;
    let mut next_pssn = 0;
    for (k, inst) in instants.iter().enumerate() {
        if inst.first_of_night
            && let Some(of) = optical.as_mut()
        {
            of.reset();
            lp.u_lo.fill(0.0);
        }
        if let Some(cal) = calibration {
            cal.predict_into(&c.gap_meas[k], &c.shear[k], &mut f_now)?;
        }
        let compose = |y_ref: &mut [f64], y_aps: &[f64], f_aps: &[f64], f_now: &[f64]| {
            for n in 0..y_ref.len() {
                y_ref[n] = y_aps[n] + f_now[n] - f_aps[n];
            }
        };
        compose(&mut y_ref, &y_aps, &f_aps, &f_now);
        let residual = y_ref
            .iter()
            .zip(&c.phased[k])
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>();
        if let Some(of) = &optical {
            of.add_reference_offset(&mut y_ref);
        }
        lp.settle(setup, c, k, &y_ref, params.iterations)?;
        let aps_due = inst.first_of_night
            && last_aps_night
                .is_none_or(|d| (inst.night - d) as f64 >= params.aps.interval_days - 1e-9);
        if aps_due {
            // The APS resets the desired readings; the loop follows.
            let e = aps.measure(&lp.z, inst.night as u64)?;
            let mut y_cur = y_ref.clone();
            if let Some(of) = &optical {
                // Keep the optical-feedback offset out of the APS value.
                let mut off = vec![0.0; ns];
                of.add_reference_offset(&mut off);
                for (y, o) in y_cur.iter_mut().zip(&off) {
                    *y -= o;
                }
            }
            Aps::reset_reference(&setup.nominal.a, &mut y_cur, &e)?;
            y_aps.copy_from_slice(&y_cur);
            f_aps.copy_from_slice(&f_now);
            compose(&mut y_ref, &y_aps, &f_aps, &f_now);
            if let Some(of) = &optical {
                of.add_reference_offset(&mut y_ref);
            }
            lp.settle(setup, c, k, &y_ref, params.iterations)?;
            last_aps_night = Some(inst.night);
            aps_days.push(inst.time_days);
        }
        if let Some(of) = optical.as_mut() {
            // The optical feedback's time constant (seconds to a minute) is short against the
            // step: it measures and corrects, and the loop settles on its new offsets.
            of.update(&lp.z, dt)?;
            of.low_order_command_into(&mut lp.u_lo);
            compose(&mut y_ref, &y_aps, &f_aps, &f_now);
            of.add_reference_offset(&mut y_ref);
            lp.settle(setup, c, k, &y_ref, params.iterations)?;
        }
        let m = setup.metrics.evaluate(&lp.z)?;
        res.rms.push(m.rms);
        res.rms_without_focus.push(m.rms_without_focus);
        res.focus_rms.push(m.focus_rms);
        res.calibration_residual
            .push((residual / ns.max(1) as f64).sqrt());
        if m.rms > worst {
            worst = m.rms;
            res.worst_z.copy_from_slice(&lp.z);
        }
        if let Some((p, idx)) = pssn
            && idx.get(next_pssn) == Some(&k)
        {
            setup.metrics.residual_ptt(&lp.z, &mut ptt)?;
            res.pssn.push(p.pssn_ptt(&ptt)?);
            next_pssn += 1;
        }
    }
    res.summary = [
        SeriesSummary::of(&res.rms),
        SeriesSummary::of(&res.rms_without_focus),
        SeriesSummary::of(&res.focus_rms),
        SeriesSummary::of(&res.calibration_residual),
    ];
    res.pssn_min = res.pssn.iter().copied().fold(f64::NAN, f64::min);
    Ok((res, aps_days))
}

/// Indices of the instants at which the PSSN is evaluated: the first of each night, then every
/// `every_minutes`.
fn pssn_instants(instants: &[Instant], every_minutes: f64) -> Vec<usize> {
    if every_minutes <= 0.0 {
        return Vec::new();
    }
    let mut out = Vec::new();
    let mut next = f64::NEG_INFINITY;
    for (k, i) in instants.iter().enumerate() {
        if i.first_of_night || i.time_days >= next - 1e-9 {
            out.push(k);
            next = i.time_days + every_minutes / 1440.0;
        }
    }
    out
}

/// Runs the overall simulation of `geometry` (see the [module documentation](self)); the
/// deformation comes from `table` if given, else from the parametric model.
/// `progress(done, total)` is called as variants finish.
///
/// # Errors
/// [`M1Error::InvalidParameter`] naming a parameter out of range, or any model's error.
pub fn run(
    geometry: &Geometry,
    params: &OverallParams,
    table: Option<DeformationModel>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<OverallResult, M1Error> {
    use rayon::prelude::*;
    if params.iterations == 0 {
        return Err(M1Error::InvalidParameter {
            name: "iterations",
            value: 0.0,
            reason: "must be at least 1",
        });
    }
    if params.calibration.zenith_deg.is_empty() || params.calibration.temperature.is_empty() {
        return Err(M1Error::InvalidInput(
            "the calibration campaign needs at least one zenith angle and one temperature".into(),
        ));
    }
    let instants = params.schedule.instants()?;
    let deformation = match table {
        Some(t) => t,
        None => DeformationModel::parametric(geometry, params.deformation)?,
    };
    let setup = Setup::new(geometry, params, deformation)?;
    let aps = Aps::new(geometry, params.aps)?;
    let samples = campaign(&setup, params, &aps)?;
    let calibration_fits = fit::compare(&samples)?;
    let calibration = Calibration::fit(params.calibration.function, &samples)?;
    let points: Vec<(f64, f64, f64)> = instants
        .iter()
        .map(|i| (i.zenith_deg, i.temperature, i.time_days))
        .collect();
    let c = setup.conditions(params, &points, 2)?;
    let pssn = if params.pssn_every_minutes > 0.0 {
        Some(Pssn::new(
            &geometry.layout,
            PssnParams {
                samples: params.pssn_samples,
                ..PssnParams::default()
            },
        )?)
    } else {
        None
    };
    let pssn_index = pssn_instants(&instants, params.pssn_every_minutes);
    let variants = [(false, false), (true, false), (false, true), (true, true)];
    let done = std::sync::atomic::AtomicUsize::new(0);
    let results: Result<Vec<(VariantResult, Vec<f64>)>, M1Error> = variants
        .par_iter()
        .map(|&(cal, of)| {
            let optical = if of {
                Some(OpticalFeedback::new(
                    geometry,
                    &setup.nominal.a,
                    &setup.nominal.focus,
                    params.optical_feedback,
                )?)
            } else {
                None
            };
            let (mut r, aps_days) = run_variant(
                &setup,
                params,
                &c,
                &instants,
                &aps,
                cal.then_some(&calibration),
                optical,
                pssn.as_ref().map(|p| (p, pssn_index.as_slice())),
            )?;
            r.name = match (cal, of) {
                (false, false) => "APS only",
                (true, false) => "calibration",
                (false, true) => "optical feedback",
                (true, true) => "calibration + optical feedback",
            }
            .into();
            let k = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            progress(k, variants.len());
            Ok((r, aps_days))
        })
        .collect();
    let results = results?;
    let aps_days = results.first().map(|r| r.1.clone()).unwrap_or_default();
    Ok(OverallResult {
        instants,
        pssn_index,
        aps_days,
        calibration_fits,
        calibration_runs: samples.len(),
        variants: results.into_iter().map(|r| r.0).collect(),
    })
}

#[cfg(test)]
mod tests;
