//! Wind loads on the segments: von Karman pressure screens in frozen flow across the mirror,
//! integrated over each segment's hexagon, as equivalent forces at the actuator points.
//!
//! # Pressure screen
//!
//! The pressure fluctuation on the front face of the mirror is a stationary random field with the
//! 2-D von Karman spectrum (wavenumber `k` in cycles/m, `k0 = 1 / L0`, `beta = 11/3`)
//!
//! ```text
//! Phi(k) = sigma^2 (beta/2 - 1) / pi  k0^(beta - 2) (k^2 + k0^2)^(-beta/2),   integral Phi d2k = sigma^2,
//! ```
//!
//! summed over several outer scales `L0_j` with energy fractions `f_j` (relative weights,
//! normalised by their sum; default 75 % at 5 m and 25 % at 30 m). It is synthesised once on a
//! periodic `N x N` grid of side `L` (spacing `dx = L / N`, `dk = 1 / L`) as the trigonometric
//! polynomial
//!
//! ```text
//! P(r) = sqrt(2) Re sum_k c_k exp(2 pi i k.r),   c_k = sqrt(Phi_d(k)) (g1 + i g2) / sqrt(2),
//! ```
//!
//! `g1, g2` independent standard normal draws (seeded), i.e. `N^2` times the inverse FFT of `c`.
//! `Phi_d(k)` is the *discrete* spectrum `Phi(k) dk^2` with the mean (`k = 0`) and the Nyquist
//! row and column removed, each outer-scale component rescaled so that its discrete sum is
//! exactly `f_j sigma_p^2`: the screen variance is `sigma_p^2` in expectation whatever the
//! screen size (a screen of a few outer scales misses a few per cent of the energy at the
//! lowest wavenumbers otherwise).
//!
//! # Frozen flow
//!
//! With the wind blowing at speed `U` towards direction `theta` (counter-clockwise from the
//! layout's `+x` axis), the pressure at time `t` is `p(r, t) = P(R(-theta) r - (U t, 0))`: the
//! screen is laid along the flow (`xi` along, `eta` across) and translated. Being periodic, the
//! flow repeats after `L / U` seconds without a seam.
//!
//! # Loads on a segment
//!
//! On segment `i` (centre `c`, hexagon `Hex_i` in the aperture plane) the integrals
//!
//! ```text
//! G_0 = int_Hex p dA,   G_xi = int_Hex p (xi - c_xi) dA,   G_eta = int_Hex p (eta - c_eta) dA
//! ```
//!
//! are exact for the trigonometric screen: in the Fourier domain they are products with the
//! hexagon's transform `H(k) = int_Hex0 exp(2 pi i k.rho) dA` and its first-moment transforms
//! (closed form for any polygon, [`polygon_transform`]), so one inverse FFT per integral gives
//! it for every segment position on the grid. This integration is the aperture filter that
//! attenuates the high spatial frequencies: the variance of `G_0` is
//! `sum_k Phi_d(k) |H(k)|^2` ([`WindLoads::expected_force_rms`]), well below `(sigma_p A)^2`.
//! For every segment the three integrals are tabulated at initialisation along the flow over one
//! screen period, at the grid spacing, on the row of the segment centre across the flow (cubic
//! Catmull-Rom interpolation between grid rows); each step interpolates the tables (cubic
//! Catmull-Rom, periodic) at the shift `U t`: no integration per step. Each segment's table
//! starts at its own centre, and the tables are stored by rows along the flow (a row holds one
//! sample of every segment's), so that at any time all the segments read the same five rows: a
//! step streams them and takes the segments a vector at a time, with the same values to the bit
//! as one segment at a time.
//!
//! The pressure pushes the front face along `-normal`. With the segment's tangent plane at
//! slope `s` (`g = sqrt(1 + s^2) = 1 / n_z`: area element `g dA` and radial moment arm `g u`),
//! the generalised forces conjugate to piston `p` and the tilts `alpha` (about `radial`) and
//! `beta` (about `azimuthal`) of [`Geometry::ptt_matrix`] are
//!
//! ```text
//! Q = [F, M_alpha, M_beta] = [-g int p dA,  -g int p v dA,  g^2 int p u dA]
//! ```
//!
//! (`u`, `v` the in-plane distances from the centre along the segment's radial and azimuthal
//! directions), and the equivalent forces at the three actuator points along the normal are
//! `f = P^-T Q` ([`equivalent_forces`]): `P^T f = Q`, so the three forces sum to `F` and
//! reproduce both moments.
//!
//! # Memory
//!
//! Initialisation holds three complex `N x N` grids (`48 N^2` bytes: 48 MiB at the default
//! `N = 1024`, 192 MiB at 2048) and keeps `24 N s` bytes of tables, `s` the segments rounded up
//! to a multiple of 8 (11.6 MiB for TMT, 0.94 MiB for Keck, 18.75 MiB for the ELT at
//! `N = 1024`).
//!
//! # Files
//!
//! `mod.rs` the parameters, `spectrum.rs` the von Karman screen and its synthesis,
//! `polygon.rs` the exact integrals over a segment and the equivalent forces, `loads.rs` the
//! tabulated loads of every segment in frozen flow.

mod loads;
mod polygon;
mod spectrum;
#[cfg(test)]
mod tests;

pub use loads::WindLoads;
pub use polygon::{PolygonGrid, equivalent_forces, polygon_moments, polygon_transform};
pub use spectrum::{DiscretePsd, ScreenSpectrum};

use spectrum::{bin_wavenumber, signed};

use std::f64::consts::{PI, SQRT_2, TAU};

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use rayon::prelude::*;
use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;

/// Spectral exponent of the von Karman spectrum, `beta = 11/3`.
pub const BETA: f64 = 11.0 / 3.0;

/// Largest number of screen samples per side accepted (memory `48 N^2` bytes: 768 MiB).
pub const MAX_SAMPLES: usize = 4096;

/// Default outer scales and energy fractions: 75 % at 5 m (vents), 25 % at 30 m (aperture).
pub const DEFAULT_OUTER_SCALES: [OuterScale; 2] = [
    OuterScale {
        outer_scale: 5.0,
        fraction: 0.75,
    },
    OuterScale {
        outer_scale: 30.0,
        fraction: 0.25,
    },
];

/// Default air density at 4 km altitude (kg/m^3).
pub const DEFAULT_AIR_DENSITY: f64 = 0.82;

/// Default rms pressure coefficient `Cp` (`sigma_p = Cp q`): 1.13, *calibrated* so that the
/// default TMT plant's open-loop response to 1 m/s wind is the seed paper's Figure 12 figure,
/// 39 nm rms surface (global piston/tip/tilt removed). The published figure does not state its
/// pressure; a Cp above 1 is at the top of what measured enclosure pressures suggest, so read
/// the absolute wind figures as scaled to the paper's and the ratios (closed/open, focus-mode
/// share) as the model's own.
pub const DEFAULT_PRESSURE_COEFFICIENT: f64 = 1.13;

/// The 2-D von Karman spectrum `Phi(k)` (Pa^2 m^2 per (cycle/m)^2) of a field of variance
/// `variance` and outer scale `outer_scale` (m), at wavenumber magnitude `k` (cycles/m).
pub fn von_karman_psd(k: f64, variance: f64, outer_scale: f64) -> f64 {
    VonKarman::new(variance, outer_scale).at(k)
}

/// [`von_karman_psd`] of one variance and outer scale, its factor independent of `k` computed
/// once: the same values, bit for bit, at half the powers.
#[derive(Debug, Clone, Copy)]
struct VonKarman {
    /// `variance (beta/2 - 1) / pi k0^(beta - 2)`.
    scale: f64,
    /// `k0^2`.
    k0_squared: f64,
}

impl VonKarman {
    fn new(variance: f64, outer_scale: f64) -> Self {
        let k0 = 1.0 / outer_scale;
        Self {
            scale: variance * (BETA / 2.0 - 1.0) / PI * k0.powf(BETA - 2.0),
            k0_squared: k0 * k0,
        }
    }

    fn at(self, k: f64) -> f64 {
        self.scale * (k * k + self.k0_squared).powf(-BETA / 2.0)
    }
}

/// rms pressure `sigma_p = Cp q` from the dynamic pressure `q = rho U^2 / 2` (Pa).
pub fn pressure_rms_from_cp(cp: f64, air_density: f64, speed: f64) -> f64 {
    cp * 0.5 * air_density * speed * speed
}

/// One outer-scale component of the pressure spectrum.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OuterScale {
    /// Outer scale `L0` (m, > 0).
    pub outer_scale: f64,
    /// Energy fraction (>= 0; the fractions are normalised by their sum; 0 disables).
    pub fraction: f64,
}

/// The pressure screen: rms, spectrum, grid and seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScreenParams {
    /// rms pressure `sigma_p` (Pa, >= 0). Default 0.463 Pa ([`pressure_rms_from_cp`] with
    /// [`DEFAULT_PRESSURE_COEFFICIENT`], 0.82 kg/m^3 and 1 m/s).
    pub pressure_rms: f64,
    /// Outer scales and energy fractions. Default [`DEFAULT_OUTER_SCALES`].
    pub outer_scales: Vec<OuterScale>,
    /// Side `L` of the square periodic screen (m). Default 128 m.
    pub size: f64,
    /// Samples per side `N` (even, 16..=[`MAX_SAMPLES`]). Default 1024 (`dx` = 0.125 m).
    pub samples: usize,
    /// Seed of the random draws. Default 1.
    pub seed: u64,
}

impl Default for ScreenParams {
    /// `sigma_p` from [`DEFAULT_PRESSURE_COEFFICIENT`], 0.82 kg/m^3 and 1 m/s (0.463 Pa); 75 %
    /// at 5 m and 25 % at
    /// 30 m; a 128 m screen of 1024 x 1024 samples; seed 1.
    fn default() -> Self {
        ScreenParams {
            pressure_rms: pressure_rms_from_cp(
                DEFAULT_PRESSURE_COEFFICIENT,
                DEFAULT_AIR_DENSITY,
                1.0,
            ),
            outer_scales: DEFAULT_OUTER_SCALES.to_vec(),
            size: 128.0,
            samples: 1024,
            seed: 1,
        }
    }
}

pub(super) fn invalid(name: &'static str, value: f64, reason: &'static str) -> M1Error {
    M1Error::InvalidParameter {
        name,
        value,
        reason,
    }
}

impl ScreenParams {
    /// Grid spacing `dx = L / N` (m).
    pub fn spacing(&self) -> f64 {
        self.size / self.samples as f64
    }

    /// Checks every field: `pressure_rms` finite and >= 0; every outer scale finite and > 0;
    /// fractions finite and >= 0 with a positive sum; `size` finite and > 0; `samples` even and
    /// in `16..=MAX_SAMPLES`.
    pub fn check(&self) -> Result<(), M1Error> {
        if !(self.pressure_rms.is_finite() && self.pressure_rms >= 0.0) {
            return Err(invalid(
                "pressure_rms",
                self.pressure_rms,
                "must be finite and >= 0",
            ));
        }
        let mut sum = 0.0;
        for c in &self.outer_scales {
            if !(c.outer_scale.is_finite() && c.outer_scale > 0.0) {
                return Err(invalid(
                    "outer_scale",
                    c.outer_scale,
                    "must be finite and > 0",
                ));
            }
            if !(c.fraction.is_finite() && c.fraction >= 0.0) {
                return Err(invalid(
                    "energy_fraction",
                    c.fraction,
                    "must be finite and >= 0",
                ));
            }
            sum += c.fraction;
        }
        if sum <= 0.0 {
            return Err(invalid(
                "energy_fraction",
                sum,
                "the energy fractions must have a positive sum",
            ));
        }
        if !(self.size.is_finite() && self.size > 0.0) {
            return Err(invalid("screen_size", self.size, "must be finite and > 0"));
        }
        if self.samples < 16 || self.samples > MAX_SAMPLES || !self.samples.is_multiple_of(2) {
            return Err(invalid(
                "screen_samples",
                self.samples as f64,
                "must be even and within 16..=4096",
            ));
        }
        Ok(())
    }

    /// The discrete spectrum `Phi_d(kx, ky)` (Pa^2: the variance carried by the grid bin),
    /// normalised so that the bins sum to `sigma_p^2`; 0 at the mean and on the Nyquist row and
    /// column. Assumes [`ScreenParams::check`] passed.
    pub fn discrete_psd(&self) -> DiscretePsd {
        let n = self.samples;
        let dk = 1.0 / self.size;
        let total: f64 = self.outer_scales.iter().map(|c| c.fraction).sum();
        // The spectrum is even in kx and in ky: each component's values on a quarter of the
        // grid, by (|signed ix|, |signed iy|), serve every bin (a quarter of the power laws).
        let h = n / 2 + 1;
        let quarter = |l0: f64| -> Vec<f64> {
            let vk = VonKarman::new(1.0, l0);
            let mut q = vec![0.0; h * h];
            q.par_chunks_mut(h).enumerate().for_each(|(ay, row)| {
                for (ax, v) in row.iter_mut().enumerate() {
                    let (kx, ky) = (ax as f64 * dk, ay as f64 * dk);
                    *v = vk.at(kx.hypot(ky));
                }
            });
            q
        };
        let mut weights = Vec::new();
        let mut units = Vec::new();
        for c in &self.outer_scales {
            if c.fraction <= 0.0 {
                continue;
            }
            let unit = quarter(c.outer_scale);
            // Summed over the whole grid in bin order, as the bins are drawn.
            let mut sum = 0.0;
            for iy in 0..n {
                for ix in 0..n {
                    if bin_wavenumber(ix, iy, n, dk).is_some() {
                        sum += unit[signed(iy, n).unsigned_abs() as usize * h
                            + signed(ix, n).unsigned_abs() as usize];
                    }
                }
            }
            let variance = self.pressure_rms.powi(2) * c.fraction / total;
            // Each bin carries Phi(k) dk^2; the unit-variance sum above is rescaled to the
            // component's variance.
            weights.push((c.outer_scale, if sum > 0.0 { variance / sum } else { 0.0 }));
            units.push(unit);
        }
        // The weighted sum in the order DiscretePsd::at takes the components.
        let quadrant = (0..h * h)
            .map(|j| {
                weights
                    .iter()
                    .zip(&units)
                    .map(|(&(_, w), u)| w * u[j])
                    .sum()
            })
            .collect();
        DiscretePsd {
            n,
            dk,
            weights,
            quadrant,
        }
    }
}

/// The wind: speed, direction and pressure screen.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindParams {
    /// Mean wind speed `U` across the mirror (m/s, >= 0). Default 1 m/s.
    pub speed: f64,
    /// Direction the wind blows towards, counter-clockwise from the layout's `+x` axis (deg).
    /// Default 0.
    pub direction: f64,
    /// The pressure screen.
    pub screen: ScreenParams,
}

impl Default for WindParams {
    fn default() -> Self {
        WindParams {
            speed: 1.0,
            direction: 0.0,
            screen: ScreenParams::default(),
        }
    }
}
