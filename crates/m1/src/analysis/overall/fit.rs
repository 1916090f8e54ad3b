//! Calibration fit functions: the desired reading of each sensor as a function of its local gap
//! and shear, fitted to APS runs at several zenith angles and temperatures.
//!
//! Each APS run `k` gives, per sensor `n`, the reading `r_nk` the sensor shows when the mirror
//! is phased at that condition, together with the sensor's measured gap change `g_nk` and the
//! shear `s_nk` estimated from all gaps (eq. 2). A fit function is linear in its coefficients,
//! `r_n(g, s) = c_n . phi(g, s)`, with the candidates
//!
//! - [`FitFunction::Constant`]: `phi = (1)`: no calibration, the last APS value;
//! - [`FitFunction::Gap`]: `phi = (1, g)`;
//! - [`FitFunction::GapShear`]: `phi = (1, g, s)`.
//!
//! The coefficients are least squares per sensor. The candidates are compared by their
//! leave-one-out residual: each run is predicted from a fit to the others, so a richer function
//! only wins if it predicts better, not merely because it has more coefficients.

use serde::Serialize;

use crate::M1Error;

/// A candidate fit function of the desired readings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FitFunction {
    /// A constant per sensor (no dependence on gap or shear).
    Constant,
    /// Constant plus a term linear in the sensor's gap change.
    Gap,
    /// Constant plus terms linear in the gap change and the estimated shear.
    GapShear,
}

impl FitFunction {
    /// Every candidate, simplest first.
    pub const ALL: [FitFunction; 3] = [Self::Constant, Self::Gap, Self::GapShear];

    /// The name used in reports and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Constant => "constant",
            Self::Gap => "gap",
            Self::GapShear => "gap_shear",
        }
    }

    /// Parses [`FitFunction::name`].
    pub fn from_name(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == s)
    }

    /// Number of coefficients.
    pub fn len(self) -> usize {
        match self {
            Self::Constant => 1,
            Self::Gap => 2,
            Self::GapShear => 3,
        }
    }

    /// Always false: every function has a constant term.
    pub fn is_empty(self) -> bool {
        false
    }

    fn basis(self, g: f64, s: f64) -> [f64; 3] {
        match self {
            Self::Constant => [1.0, 0.0, 0.0],
            Self::Gap => [1.0, g, 0.0],
            Self::GapShear => [1.0, g, s],
        }
    }
}

/// One APS run's calibration data: per sensor, the phased reading, gap change and shear.
#[derive(Debug, Clone, Serialize)]
pub struct CalibrationSample {
    /// Zenith angle of the run (deg).
    pub zenith_deg: f64,
    /// Temperature of the run (degC).
    pub temperature: f64,
    /// Phased reading `r_n` (m).
    pub reading: Vec<f64>,
    /// Measured gap change `g_n` (m).
    pub gap: Vec<f64>,
    /// Estimated shear `s_n` (m).
    pub shear: Vec<f64>,
}

/// Fitted coefficients of one fit function, per sensor.
#[derive(Debug, Clone, Serialize)]
pub struct Calibration {
    /// The fit function.
    pub function: FitFunction,
    /// Coefficients, `function.len()` per sensor, sensor-major.
    pub coefficients: Vec<f64>,
    /// Gap and shear scales used to condition the fit (m).
    scale: [f64; 2],
}

/// Least squares of up to 3 coefficients: normal equations with a tiny ridge, so a sensor whose
/// gap never changed falls back to its mean.
fn solve_small(phi: &[[f64; 3]], r: &[f64], k: usize) -> [f64; 3] {
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    for (p, &y) in phi.iter().zip(r) {
        for i in 0..k {
            b[i] += p[i] * y;
            for j in 0..k {
                m[(i, j)] += p[i] * p[j];
            }
        }
    }
    let trace: f64 = (0..k).map(|i| m[(i, i)]).sum::<f64>().max(1e-300);
    for i in 0..3 {
        m[(i, i)] += if i < k { 1e-12 * trace } else { 1.0 };
    }
    let x = m.lu().solve(&b).unwrap_or_default();
    [x[0], x[1], x[2]]
}

fn check_samples(samples: &[CalibrationSample]) -> Result<usize, M1Error> {
    let Some(first) = samples.first() else {
        return Err(M1Error::InvalidInput(
            "calibration needs at least one APS run".into(),
        ));
    };
    let ns = first.reading.len();
    for s in samples {
        crate::error::check_lengths(
            ns,
            &[
                ("calibration readings", &s.reading),
                ("calibration gaps", &s.gap),
                ("calibration shears", &s.shear),
            ],
        )?;
    }
    Ok(ns)
}

fn rms_scale(samples: &[CalibrationSample], f: impl Fn(&CalibrationSample) -> &Vec<f64>) -> f64 {
    let (mut s2, mut n) = (0.0, 0usize);
    for s in samples {
        for v in f(s) {
            s2 += v * v;
            n += 1;
        }
    }
    let r = (s2 / n.max(1) as f64).sqrt();
    if r > 0.0 { r } else { 1.0 }
}

impl Calibration {
    /// Fits `function` to `samples` (every sample has one value per sensor).
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] without samples; [`M1Error::SizeMismatch`] for samples of
    /// different sensor counts.
    pub fn fit(function: FitFunction, samples: &[CalibrationSample]) -> Result<Self, M1Error> {
        let ns = check_samples(samples)?;
        let scale = [
            rms_scale(samples, |s| &s.gap),
            rms_scale(samples, |s| &s.shear),
        ];
        let k = function.len();
        let mut coefficients = Vec::with_capacity(ns * k);
        let mut phi = vec![[0.0; 3]; samples.len()];
        let mut r = vec![0.0; samples.len()];
        for n in 0..ns {
            for (i, s) in samples.iter().enumerate() {
                phi[i] = function.basis(s.gap[n] / scale[0], s.shear[n] / scale[1]);
                r[i] = s.reading[n];
            }
            let c = solve_small(&phi, &r, k);
            coefficients.extend_from_slice(&c[..k]);
        }
        Ok(Self {
            function,
            coefficients,
            scale,
        })
    }

    /// Number of sensors.
    pub fn n_sensors(&self) -> usize {
        self.coefficients.len() / self.function.len()
    }

    /// The fitted desired readings for gap changes `gap` and shears `shear`, into `out`.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for slices of the wrong length.
    pub fn predict_into(&self, gap: &[f64], shear: &[f64], out: &mut [f64]) -> Result<(), M1Error> {
        crate::error::check_lengths(
            self.n_sensors(),
            &[("gap", gap), ("shear", shear), ("desired readings", out)],
        )?;
        let k = self.function.len();
        for n in 0..out.len() {
            let phi = self
                .function
                .basis(gap[n] / self.scale[0], shear[n] / self.scale[1]);
            out[n] = (0..k).map(|i| self.coefficients[n * k + i] * phi[i]).sum();
        }
        Ok(())
    }
}

/// How well one fit function predicts the phased readings.
#[derive(Debug, Clone, Serialize)]
pub struct FitComparison {
    /// The function.
    pub function: FitFunction,
    /// rms over sensors and runs of the fit residual on the data it was fitted to (m).
    pub fit_rms: f64,
    /// rms of the leave-one-out prediction error (m): the figure of merit.
    pub leave_one_out_rms: f64,
}

/// Fits every candidate and compares them (leave-one-out needs at least two runs; with one, the
/// leave-one-out figure is the fit residual).
///
/// # Errors
/// As [`Calibration::fit`].
pub fn compare(samples: &[CalibrationSample]) -> Result<Vec<FitComparison>, M1Error> {
    let ns = check_samples(samples)?;
    let mut out = Vec::new();
    let mut pred = vec![0.0; ns];
    for f in FitFunction::ALL {
        let all = Calibration::fit(f, samples)?;
        let (mut fit2, mut loo2, mut count) = (0.0, 0.0, 0usize);
        for (k, s) in samples.iter().enumerate() {
            all.predict_into(&s.gap, &s.shear, &mut pred)?;
            fit2 += s
                .reading
                .iter()
                .zip(&pred)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>();
            count += ns;
            if samples.len() > 1 {
                let rest: Vec<CalibrationSample> = samples
                    .iter()
                    .enumerate()
                    .filter(|(i, _)| *i != k)
                    .map(|(_, s)| s.clone())
                    .collect();
                Calibration::fit(f, &rest)?.predict_into(&s.gap, &s.shear, &mut pred)?;
                loo2 += s
                    .reading
                    .iter()
                    .zip(&pred)
                    .map(|(a, b)| (a - b) * (a - b))
                    .sum::<f64>();
            }
        }
        let fit_rms = (fit2 / count.max(1) as f64).sqrt();
        out.push(FitComparison {
            function: f,
            fit_rms,
            leave_one_out_rms: if samples.len() > 1 {
                (loo2 / count.max(1) as f64).sqrt()
            } else {
                fit_rms
            },
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings exactly linear in gap and shear, plus per-sensor offsets.
    fn samples(noise: f64) -> Vec<CalibrationSample> {
        let ns = 5;
        (0..6)
            .map(|k| {
                let gap: Vec<f64> = (0..ns)
                    .map(|n| 1e-5 * ((k * 7 + n * 3) as f64).sin())
                    .collect();
                let shear: Vec<f64> = (0..ns)
                    .map(|n| 2e-5 * ((k * 5 + n * 11) as f64).cos())
                    .collect();
                let reading = (0..ns)
                    .map(|n| {
                        1e-8 * n as f64 + 3e-3 * gap[n] - 2e-3 * shear[n]
                            + noise * ((k * 13 + n) as f64).sin()
                    })
                    .collect();
                CalibrationSample {
                    zenith_deg: 10.0 * k as f64,
                    temperature: 0.0,
                    reading,
                    gap,
                    shear,
                }
            })
            .collect()
    }

    #[test]
    fn the_right_function_recovers_the_law_and_wins_the_comparison() {
        let s = samples(0.0);
        let c = Calibration::fit(FitFunction::GapShear, &s).unwrap();
        let mut out = vec![0.0; 5];
        let (g, sh) = (vec![4e-6; 5], vec![-1e-5; 5]);
        c.predict_into(&g, &sh, &mut out).unwrap();
        for (n, v) in out.iter().enumerate() {
            let want = 1e-8 * n as f64 + 3e-3 * 4e-6 + 2e-3 * 1e-5;
            assert!((v - want).abs() < 1e-14, "{v} {want}");
        }
        let cmp = compare(&s).unwrap();
        assert_eq!(cmp.len(), 3);
        assert!(cmp[2].leave_one_out_rms < 1e-14);
        assert!(cmp[0].leave_one_out_rms > 1e-9 && cmp[1].leave_one_out_rms > 1e-9);
        // Residuals never grow with more coefficients on the fitted data.
        assert!(cmp[1].fit_rms <= cmp[0].fit_rms + 1e-18);
        assert!(Calibration::fit(FitFunction::Gap, &[]).is_err());
        assert_eq!(
            FitFunction::from_name("gap_shear"),
            Some(FitFunction::GapShear)
        );
    }
}
