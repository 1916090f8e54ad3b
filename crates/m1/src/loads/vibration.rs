//! Pier vibration sources: tones plus seeded band-limited noise, a deterministic function of
//! time.
//!
//! # Model
//!
//! ```text
//! z(t) = sum_j A_j sin(2 pi f_j t + phi_j) + n(t)      (m)
//! ```
//!
//! The tones are evaluated exactly at `t`. The noise `n(t)` is synthesised once, by inverse FFT,
//! as a periodic signal of period `T` (rounded to whole samples) sampled at
//! `f_s = 8 f_high` ([`OVERSAMPLING`]): every Fourier bin `m / T` inside the band
//! `[f_low, f_high]` (the mean excluded) gets a complex standard normal coefficient (seeded),
//! the others zero, and the samples are scaled so that their rms over one period is exactly
//! `sigma_n`. Between samples `n(t)` is the periodic cubic (Catmull-Rom) interpolant, whose
//! response is above 0.99 up to `f_high` at this oversampling. `z(t)` depends on `t` only: it is
//! the same whatever the communication steps that reach `t`.
//!
//! Equipment tones near 29.6 +/- 0.2 Hz (large induction motors) are typical at observatories;
//! amplitudes are site specific and *assumed*.

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex64;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

use crate::M1Error;
use crate::linalg::interpolation::periodic_stencil;

/// Noise sample rate over the upper band edge.
pub const OVERSAMPLING: f64 = 8.0;

/// Largest number of noise samples in one period (2^24, 128 MiB).
pub const MAX_NOISE_SAMPLES: usize = 1 << 24;

/// One sinusoidal component `A sin(2 pi f t + phi)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Tone {
    /// Frequency `f` (Hz, >= 0).
    pub frequency: f64,
    /// Amplitude `A` (m; 0 disables the tone).
    pub amplitude: f64,
    /// Phase `phi` (rad).
    pub phase: f64,
}

impl Tone {
    /// `A sin(2 pi f t + phi)`.
    pub fn at(&self, t: f64) -> f64 {
        self.amplitude * (TAU * self.frequency * t + self.phase).sin()
    }
}

/// Band-limited noise parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct NoiseParams {
    /// rms `sigma_n` (m, >= 0; 0 disables the noise). Default 1e-9 m (*assumed*).
    pub rms: f64,
    /// Lower band edge `f_low` (Hz, >= 0). Default 1 Hz.
    pub low: f64,
    /// Upper band edge `f_high` (Hz, > `f_low`). Default 100 Hz.
    pub high: f64,
    /// Period `T` after which the noise repeats (s). Default 100 s.
    pub period: f64,
    /// Seed. Default 1.
    pub seed: u64,
}

impl Default for NoiseParams {
    fn default() -> Self {
        NoiseParams {
            rms: 1e-9,
            low: 1.0,
            high: 100.0,
            period: 100.0,
            seed: 1,
        }
    }
}

fn invalid(name: &'static str, value: f64, reason: &'static str) -> M1Error {
    M1Error::InvalidParameter {
        name,
        value,
        reason,
    }
}

/// Periodic band-limited Gaussian noise, tabulated over one period.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BandNoise {
    rate: f64,
    samples: Vec<f64>,
}

impl BandNoise {
    /// Synthesises the noise. Fails with [`M1Error::InvalidParameter`] unless `rms` is finite
    /// and > 0, `0 <= low < high` (finite), `period` finite and > 0, the band holds at least
    /// one Fourier bin `m / T` (`m >= 1`), and one period has at most [`MAX_NOISE_SAMPLES`]
    /// samples.
    pub fn new(p: &NoiseParams) -> Result<BandNoise, M1Error> {
        if !(p.rms.is_finite() && p.rms > 0.0) {
            return Err(invalid("noise_rms", p.rms, "must be finite and > 0"));
        }
        if !(p.low.is_finite() && p.low >= 0.0) {
            return Err(invalid(
                "noise_low_frequency",
                p.low,
                "must be finite and >= 0",
            ));
        }
        if !(p.high.is_finite() && p.high > p.low) {
            return Err(invalid(
                "noise_high_frequency",
                p.high,
                "must be finite and above noise_low_frequency",
            ));
        }
        if !(p.period.is_finite() && p.period > 0.0) {
            return Err(invalid("noise_period", p.period, "must be finite and > 0"));
        }
        let rate = OVERSAMPLING * p.high;
        let n = (p.period * rate).round();
        if n > MAX_NOISE_SAMPLES as f64 {
            return Err(invalid(
                "noise_period",
                p.period,
                "gives more than 2^24 noise samples (noise_period x 8 noise_high_frequency)",
            ));
        }
        let n = (n as usize).max(8);
        let df = rate / n as f64;
        let lo = ((p.low / df).ceil() as usize).max(1);
        let hi = ((p.high / df).floor() as usize).min(n / 2 - 1);
        if hi < lo {
            return Err(invalid(
                "noise_period",
                p.period,
                "is too short to hold a frequency bin (1 / noise_period) inside the noise band",
            ));
        }
        let mut rng = StdRng::seed_from_u64(p.seed);
        let mut spec = vec![Complex64::ZERO; n];
        for c in &mut spec[lo..=hi] {
            let g1: f64 = StandardNormal.sample(&mut rng);
            let g2: f64 = StandardNormal.sample(&mut rng);
            *c = Complex64::new(g1, g2);
        }
        // One-sided spectrum: the real part of the inverse FFT is the band-limited signal.
        FftPlanner::new().plan_fft_inverse(n).process(&mut spec);
        let mut samples: Vec<f64> = spec.iter().map(|c| c.re).collect();
        let rms = (samples.iter().map(|x| x * x).sum::<f64>() / n as f64).sqrt();
        if rms > 0.0 {
            let s = p.rms / rms;
            samples.iter_mut().for_each(|x| *x *= s);
        }
        Ok(BandNoise { rate, samples })
    }

    /// Sample rate `f_s` of the table (Hz).
    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// The samples of one period, at `k / f_s`.
    pub fn samples(&self) -> &[f64] {
        &self.samples
    }

    /// Period `n / f_s` (s).
    pub fn period(&self) -> f64 {
        self.samples.len() as f64 / self.rate
    }

    /// `n(t)`: the periodic Catmull-Rom interpolant of the samples (m).
    pub fn at(&self, t: f64) -> f64 {
        let (idx, w) = periodic_stencil(t * self.rate, self.samples.len());
        idx.iter().zip(w).map(|(&i, wi)| wi * self.samples[i]).sum()
    }
}

/// Vertical pier motion: tones plus optional band-limited noise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PierVibration {
    tones: Vec<Tone>,
    noise: Option<BandNoise>,
}

impl PierVibration {
    /// The tones (each with finite frequency >= 0, amplitude and phase) and the noise (skipped
    /// when `noise.rms == 0`; see [`BandNoise::new`]).
    pub fn new(tones: &[Tone], noise: &NoiseParams) -> Result<PierVibration, M1Error> {
        for t in tones {
            if !(t.frequency.is_finite() && t.frequency >= 0.0) {
                return Err(invalid(
                    "tone_frequency",
                    t.frequency,
                    "must be finite and >= 0",
                ));
            }
            if !t.amplitude.is_finite() {
                return Err(invalid("tone_amplitude", t.amplitude, "must be finite"));
            }
            if !t.phase.is_finite() {
                return Err(invalid("tone_phase", t.phase, "must be finite"));
            }
        }
        let noise = if noise.rms == 0.0 {
            None
        } else {
            Some(BandNoise::new(noise)?)
        };
        Ok(PierVibration {
            tones: tones
                .iter()
                .copied()
                .filter(|t| t.amplitude != 0.0)
                .collect(),
            noise,
        })
    }

    /// `z(t)` (m).
    pub fn at(&self, t: f64) -> f64 {
        let tones: f64 = self.tones.iter().map(|tone| tone.at(t)).sum();
        tones + self.noise.as_ref().map_or(0.0, |n| n.at(t))
    }

    /// The noise, if any.
    pub fn noise(&self) -> Option<&BandNoise> {
        self.noise.as_ref()
    }

    /// Expected rms of `z` over a long time, `sqrt(sum A_j^2 / 2 + sigma_n^2)` (m; tones at
    /// distinct non-zero frequencies).
    pub fn expected_rms(&self) -> f64 {
        let tones: f64 = self.tones.iter().map(|t| t.amplitude.powi(2) / 2.0).sum();
        let noise = self.noise.as_ref().map_or(0.0, |n| {
            n.samples.iter().map(|x| x * x).sum::<f64>() / n.samples.len() as f64
        });
        (tones + noise).sqrt()
    }
}
