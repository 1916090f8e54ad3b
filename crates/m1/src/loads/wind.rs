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
//! Catmull-Rom, periodic) at the shift `U t`: no integration per step.
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
//! `N = 1024`, 192 MiB at 2048) and keeps `24 N n_segments` bytes of tables (11.5 MiB for TMT,
//! 0.8 MiB for Keck, 18.7 MiB for the ELT at `N = 1024`).

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
    let k0 = 1.0 / outer_scale;
    variance * (BETA / 2.0 - 1.0) / PI * k0.powf(BETA - 2.0) * (k * k + k0 * k0).powf(-BETA / 2.0)
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

fn invalid(name: &'static str, value: f64, reason: &'static str) -> M1Error {
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
        let mut weights = Vec::new();
        for c in &self.outer_scales {
            if c.fraction <= 0.0 {
                continue;
            }
            let mut sum = 0.0;
            for iy in 0..n {
                for ix in 0..n {
                    if let Some((kx, ky)) = bin_wavenumber(ix, iy, n, dk) {
                        sum += von_karman_psd(kx.hypot(ky), 1.0, c.outer_scale);
                    }
                }
            }
            let variance = self.pressure_rms.powi(2) * c.fraction / total;
            // Each bin carries Phi(k) dk^2; the unit-variance sum above is rescaled to the
            // component's variance.
            weights.push((c.outer_scale, if sum > 0.0 { variance / sum } else { 0.0 }));
        }
        DiscretePsd { n, dk, weights }
    }
}

/// The discrete pressure spectrum of a screen (see [`ScreenParams::discrete_psd`]).
#[derive(Debug, Clone, PartialEq)]
pub struct DiscretePsd {
    n: usize,
    dk: f64,
    /// (outer scale, factor on the unit-variance von Karman spectrum) per component.
    weights: Vec<(f64, f64)>,
}

impl DiscretePsd {
    /// Variance (Pa^2) carried by the bin `(ix, iy)` of the FFT grid (0 at the mean and Nyquist).
    pub fn bin(&self, ix: usize, iy: usize) -> f64 {
        match bin_wavenumber(ix, iy, self.n, self.dk) {
            Some((kx, ky)) => self.at(kx, ky),
            None => 0.0,
        }
    }

    /// Variance density times `dk^2` at wavenumber `(kx, ky)` (cycles/m), as for a grid bin.
    pub fn at(&self, kx: f64, ky: f64) -> f64 {
        let k = kx.hypot(ky);
        self.weights
            .iter()
            .map(|&(l0, w)| w * von_karman_psd(k, 1.0, l0))
            .sum()
    }

    /// Signed wavenumber (cycles/m) of FFT index `i` (`i - N` above `N / 2`).
    pub fn wavenumber(&self, i: usize) -> f64 {
        signed(i, self.n) as f64 * self.dk
    }
}

/// Signed FFT frequency index.
fn signed(i: usize, n: usize) -> i64 {
    if i < n / 2 {
        i as i64
    } else {
        i as i64 - n as i64
    }
}

/// Wavenumber of bin `(ix, iy)`, or None at the mean and on the Nyquist row and column.
fn bin_wavenumber(ix: usize, iy: usize, n: usize, dk: f64) -> Option<(f64, f64)> {
    if (ix == 0 && iy == 0) || ix == n / 2 || iy == n / 2 {
        return None;
    }
    Some((signed(ix, n) as f64 * dk, signed(iy, n) as f64 * dk))
}

/// The random Fourier coefficients `c_k` of a pressure screen.
#[derive(Debug, Clone)]
pub struct ScreenSpectrum {
    params: ScreenParams,
    /// `c[iy N + ix]`, bin `(kx, ky)` of FFT indices `(ix, iy)`.
    coefficients: Vec<Complex64>,
}

impl ScreenSpectrum {
    /// Draws the coefficients (two standard normals per bin, in row-major bin order, from
    /// `StdRng::seed_from_u64(seed)`).
    pub fn new(params: &ScreenParams) -> Result<ScreenSpectrum, M1Error> {
        params.check()?;
        let n = params.samples;
        let psd = params.discrete_psd();
        let mut rng = StdRng::seed_from_u64(params.seed);
        let mut coefficients = vec![Complex64::ZERO; n * n];
        for iy in 0..n {
            for ix in 0..n {
                let g1: f64 = StandardNormal.sample(&mut rng);
                let g2: f64 = StandardNormal.sample(&mut rng);
                let a = (psd.bin(ix, iy) / 2.0).sqrt();
                coefficients[iy * n + ix] = Complex64::new(a * g1, a * g2);
            }
        }
        Ok(ScreenSpectrum {
            params: params.clone(),
            coefficients,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ScreenParams {
        &self.params
    }

    /// The screen at any point `(x, y)` of its plane (Pa): the trigonometric polynomial
    /// evaluated exactly, in `O(N^2)` (for checks; [`ScreenSpectrum::screen`] gives the grid).
    pub fn value_at(&self, x: f64, y: f64) -> f64 {
        let n = self.params.samples;
        let dk = 1.0 / self.params.size;
        let phase = |i: usize, r: f64| {
            Complex64::cis(TAU * signed(i, n) as f64 * dk * r.rem_euclid(self.params.size))
        };
        let ex: Vec<Complex64> = (0..n).map(|i| phase(i, x)).collect();
        let sum: Complex64 = self
            .coefficients
            .chunks_exact(n)
            .enumerate()
            .map(|(iy, row)| {
                let inner: Complex64 = row.iter().zip(&ex).map(|(c, e)| c * e).sum();
                inner * phase(iy, y)
            })
            .sum();
        SQRT_2 * sum.re
    }

    /// The pressure screen on the grid (Pa), row-major: sample `[iy N + ix]` at
    /// `(ix dx, iy dx)`.
    pub fn screen(&self) -> Vec<f64> {
        let n = self.params.samples;
        let mut buf = self.coefficients.clone();
        inverse_fft_2d(&mut buf, n);
        buf.iter().map(|c| SQRT_2 * c.re).collect()
    }
}

/// In-place unnormalised inverse 2-D FFT (`sum_k c_k exp(+2 pi i k.r)`) of a row-major
/// `n x n` grid.
fn inverse_fft_2d(buf: &mut [Complex64], n: usize) {
    let fft: std::sync::Arc<dyn Fft<f64>> = FftPlanner::new().plan_fft_inverse(n);
    let mut scratch = vec![Complex64::ZERO; fft.get_inplace_scratch_len()];
    fft.process_with_scratch(buf, &mut scratch);
    transpose(buf, n);
    fft.process_with_scratch(buf, &mut scratch);
    transpose(buf, n);
}

/// In-place transpose of a square row-major matrix, by blocks.
fn transpose(buf: &mut [Complex64], n: usize) {
    const B: usize = 32;
    for bi in (0..n).step_by(B) {
        for bj in (bi..n).step_by(B) {
            for i in bi..(bi + B).min(n) {
                let j0 = if bi == bj { i + 1 } else { bj };
                for j in j0..(bj + B).min(n) {
                    buf.swap(i * n + j, j * n + i);
                }
            }
        }
    }
}

/// `sin(u) / u` and its derivative, by series near 0.
fn sinc_and_derivative(u: f64) -> (f64, f64) {
    if u.abs() < 1e-3 {
        let u2 = u * u;
        (
            1.0 - u2 / 6.0 + u2 * u2 / 120.0,
            u * (-1.0 / 3.0 + u2 / 30.0),
        )
    } else {
        let (s, c) = u.sin_cos();
        (s / u, (c - s / u) / u)
    }
}

/// Area and first moments `(int x dA, int y dA)` of a simple polygon (vertices
/// counter-clockwise; clockwise gives negated values).
pub fn polygon_moments(vertices: &[[f64; 2]]) -> (f64, [f64; 2]) {
    let n = vertices.len();
    let (mut area, mut mx, mut my) = (0.0, 0.0, 0.0);
    for j in 0..n {
        let a = vertices[j];
        let b = vertices[(j + 1) % n];
        let cross = a[0] * b[1] - b[0] * a[1];
        area += cross / 2.0;
        mx += (a[0] + b[0]) * cross / 6.0;
        my += (a[1] + b[1]) * cross / 6.0;
    }
    (area, [mx, my])
}

/// Fourier transforms of a polygon's indicator and first moments at wavenumber `k`
/// (cycles/m): `[int exp(2 pi i k.r) dA, int x exp(..) dA, int y exp(..) dA]`, the
/// vertices counter-clockwise in the frame the moments refer to.
///
/// By the divergence theorem (`q = 2 pi k`, edge `j` from `a_j` to `b_j`, `e_j = b_j - a_j`,
/// midpoint `m_j`, outward normal times length `N_j = (e_y, -e_x)`):
/// `H(q) = -i / |q|^2 sum_j (q.N_j) exp(i q.m_j) sinc(q.e_j / 2)`, and the moment transforms
/// are `-i dH/dq`, differentiated analytically.
pub fn polygon_transform(vertices: &[[f64; 2]], k: [f64; 2]) -> [Complex64; 3] {
    let q = [TAU * k[0], TAU * k[1]];
    let q2 = q[0] * q[0] + q[1] * q[1];
    if q2 == 0.0 {
        let (a, m) = polygon_moments(vertices);
        return [a.into(), m[0].into(), m[1].into()];
    }
    let n = vertices.len();
    let mut s = Complex64::ZERO;
    let mut ds = [Complex64::ZERO; 2];
    for j in 0..n {
        let a = vertices[j];
        let b = vertices[(j + 1) % n];
        let e = [b[0] - a[0], b[1] - a[1]];
        let m = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
        let nn = [e[1], -e[0]];
        let qn = q[0] * nn[0] + q[1] * nn[1];
        let (sc, dsc) = sinc_and_derivative((q[0] * e[0] + q[1] * e[1]) / 2.0);
        let ph = Complex64::cis(q[0] * m[0] + q[1] * m[1]);
        s += ph * (qn * sc);
        for c in 0..2 {
            ds[c] += ph * Complex64::new(nn[c] * sc + qn * dsc * e[c] / 2.0, qn * sc * m[c]);
        }
    }
    let h = Complex64::new(0.0, -1.0) * s / q2;
    let moment = |c: usize| -ds[c] / q2 + s * (2.0 * q[c] / (q2 * q2));
    [h, moment(0), moment(1)]
}

/// Catmull-Rom weights of samples `-1, 0, 1, 2` at fraction `t` in `[0, 1)`.
#[inline]
pub(crate) fn catmull_rom(t: f64) -> [f64; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        0.5 * (-t3 + 2.0 * t2 - t),
        0.5 * (3.0 * t3 - 5.0 * t2 + 2.0),
        0.5 * (-3.0 * t3 + 4.0 * t2 + t),
        0.5 * (t3 - t2),
    ]
}

/// Index of the sample before position `u` (in samples, periodic of period `n`), the four
/// indices around it and the Catmull-Rom weights.
#[inline]
pub(crate) fn periodic_stencil(u: f64, n: usize) -> ([usize; 4], [f64; 4]) {
    let u = u.rem_euclid(n as f64);
    let fl = u.floor();
    // rem_euclid can round up to n itself.
    let i0 = (fl as usize) % n;
    let w = catmull_rom(u - fl);
    let idx = [(i0 + n - 1) % n, i0, (i0 + 1) % n, (i0 + 2) % n];
    (idx, w)
}

/// Equivalent forces along the normal at the three actuators of segment `i`,
/// `f = P^-T [F, M_alpha, M_beta]` (N): `P^T f` reproduces the normal force and the moments
/// about the segment's radial and azimuthal axes.
///
/// # Panics
/// If `i >= geometry.n_segments()`.
pub fn equivalent_forces(geometry: &Geometry, i: usize, q: [f64; 3]) -> [f64; 3] {
    let pinv = geometry.ptt_inverse(i);
    // (P^-T)_{kj} = (P^-1)_{jk}.
    std::array::from_fn(|k| (0..3).map(|j| pinv[j][k] * q[j]).sum())
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

/// Tabulated wind loads of every segment over one screen period of frozen flow.
#[derive(Debug, Clone)]
pub struct WindLoads {
    /// The tables, for a unit rms pressure (shared: [`WindLoads::with_flow`] reuses them).
    screen: std::sync::Arc<UnitScreen>,
    speed: f64,
    pressure_rms: f64,
}

/// What the loads of a screen of unit rms pressure are made of (the screen is linear in its rms
/// pressure, which scales them at the end).
#[derive(Debug)]
struct UnitScreen {
    samples: usize,
    spacing: f64,
    /// (cos theta, sin theta).
    direction: [f64; 2],
    /// Segment centre along the flow, in samples.
    along: Vec<f64>,
    /// Wind-frame integrals `[G_0, G_xi, G_eta]` -> `Q = [F, M_alpha, M_beta]`, per segment.
    to_load: Vec<[[f64; 3]; 3]>,
    /// Wind-frame integrals -> actuator forces (`P^-T` times `to_load`), per segment.
    to_forces: Vec<[[f64; 3]; 3]>,
    /// `tables[(3 i + q) N + n]`: integral `q` of segment `i` with the screen shifted by
    /// `(along_i - n) dx`.
    tables: Vec<f64>,
    /// Expected rms of `G_0`.
    force_rms: f64,
    area: f64,
}

impl WindLoads {
    /// Synthesises the screen and tabulates every segment's loads.
    ///
    /// Fails with [`M1Error::InvalidParameter`] for a bad screen ([`ScreenParams::check`]), a
    /// negative or non-finite speed, a non-finite direction, or a screen narrower than the
    /// mirror (`size` must exceed `2 max|c| + 2 a`: across the flow the screen repeats too).
    ///
    /// The tables are those of the screen of unit rms pressure (the screen is linear in
    /// `pressure_rms`), and the integrals read from them are scaled by it: so
    /// [`WindLoads::with_flow`] gives for another speed or rms pressure exactly what `new`
    /// gives.
    pub fn new(geometry: &Geometry, params: &WindParams) -> Result<WindLoads, M1Error> {
        params.screen.check()?;
        let unit = ScreenParams {
            pressure_rms: 1.0,
            ..params.screen.clone()
        };
        let sp = &unit;
        if !(params.speed.is_finite() && params.speed >= 0.0) {
            return Err(invalid(
                "wind_speed",
                params.speed,
                "must be finite and >= 0",
            ));
        }
        if !params.direction.is_finite() {
            return Err(invalid(
                "wind_direction",
                params.direction,
                "must be finite",
            ));
        }
        let layout = &geometry.layout;
        let nseg = layout.n_segments();
        let a = layout.circumradius;
        let extent = layout
            .segments
            .iter()
            .map(|s| s.center[0].hypot(s.center[1]))
            .fold(0.0, f64::max);
        if sp.size <= 2.0 * (extent + a) {
            return Err(invalid(
                "screen_size",
                sp.size,
                "must exceed the mirror's diameter (2 max|centre| + 2 a): the screen repeats across the flow",
            ));
        }
        let n = sp.samples;
        let dx = sp.spacing();
        let theta = params.direction.to_radians();
        let (sin, cos) = theta.sin_cos();
        let to_wind = |p: [f64; 2]| [cos * p[0] + sin * p[1], -sin * p[0] + cos * p[1]];

        // The hexagon relative to its centre, in the wind frame (counter-clockwise).
        let c0 = layout.segments[0].center;
        let corners = layout.vertices(0).ok_or(M1Error::SizeMismatch {
            what: "layout segments",
            expected: 1,
            found: 0,
        })?;
        let mut hexagon: Vec<[f64; 2]> = corners
            .iter()
            .map(|v| to_wind([v[0] - c0[0], v[1] - c0[1]]))
            .collect();
        let (area, _) = polygon_moments(&hexagon);
        if area < 0.0 {
            hexagon.reverse();
        }
        let area = area.abs();

        // Filtered spectra: c H, c H_xi, c H_eta; and the expected variance of G_0.
        let spectrum = ScreenSpectrum::new(sp)?;
        let psd = sp.discrete_psd();
        let mut b0 = spectrum.coefficients;
        let mut b1 = vec![Complex64::ZERO; n * n];
        let mut b2 = vec![Complex64::ZERO; n * n];
        let variance: f64 = b0
            .par_chunks_mut(n)
            .zip(b1.par_chunks_mut(n))
            .zip(b2.par_chunks_mut(n))
            .enumerate()
            .map(|(iy, ((r0, r1), r2))| {
                let ky = psd.wavenumber(iy);
                let mut var = 0.0;
                for ix in 0..n {
                    let c = r0[ix];
                    if c == Complex64::ZERO {
                        continue;
                    }
                    let kx = psd.wavenumber(ix);
                    let [h, hx, hy] = polygon_transform(&hexagon, [kx, ky]);
                    var += psd.bin(ix, iy) * h.norm_sqr();
                    r0[ix] = c * h;
                    r1[ix] = c * hx;
                    r2[ix] = c * hy;
                }
                var
            })
            .sum();

        // Segment positions in the wind frame, in samples.
        let centres: Vec<[f64; 2]> = layout.segments.iter().map(|s| to_wind(s.center)).collect();
        let along: Vec<f64> = centres.iter().map(|c| c[0] / dx).collect();
        let mut tables = vec![0.0; 3 * nseg * n];
        for (q, buf) in [b0, b1, b2].into_iter().enumerate() {
            let mut buf = buf;
            inverse_fft_2d(&mut buf, n);
            for (i, c) in centres.iter().enumerate() {
                let (rows, w) = periodic_stencil(c[1] / dx, n);
                let out = &mut tables[(3 * i + q) * n..(3 * i + q + 1) * n];
                for (r, wr) in rows.iter().zip(w) {
                    let row = &buf[r * n..(r + 1) * n];
                    for (o, v) in out.iter_mut().zip(row) {
                        *o += wr * SQRT_2 * v.re;
                    }
                }
            }
        }

        // Wind-frame integrals -> generalised forces -> actuator forces.
        let mut to_load = Vec::with_capacity(nseg);
        let mut to_forces = Vec::with_capacity(nseg);
        for i in 0..nseg {
            let s = &geometry.segments[i];
            let g = 1.0 / s.normal[2];
            let rad = unit2([s.radial[0], s.radial[1]]);
            let az = unit2([s.azimuthal[0], s.azimuthal[1]]);
            let (rad, az) = (to_wind(rad), to_wind(az));
            let b = [
                [-g, 0.0, 0.0],
                [0.0, -g * az[0], -g * az[1]],
                [0.0, g * g * rad[0], g * g * rad[1]],
            ];
            let pinv = geometry.ptt_inverse(i);
            let m: [[f64; 3]; 3] = std::array::from_fn(|k| {
                std::array::from_fn(|col| (0..3).map(|j| pinv[j][k] * b[j][col]).sum())
            });
            to_load.push(b);
            to_forces.push(m);
        }

        let screen = std::sync::Arc::new(UnitScreen {
            samples: n,
            spacing: dx,
            direction: [cos, sin],
            along,
            to_load,
            to_forces,
            tables,
            force_rms: variance.sqrt(),
            area,
        });
        WindLoads {
            screen,
            speed: 0.0,
            pressure_rms: 0.0,
        }
        .with_flow(params.speed, params.screen.pressure_rms)
    }

    /// The same screen and direction at another wind `speed` (m/s, finite, >= 0) and rms
    /// pressure `pressure_rms` (Pa, finite, >= 0), sharing the tables: identical to
    /// [`WindLoads::new`] with those values (a sweep over wind speed builds the screen once).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for a bad speed or rms pressure.
    pub fn with_flow(&self, speed: f64, pressure_rms: f64) -> Result<WindLoads, M1Error> {
        if !(speed.is_finite() && speed >= 0.0) {
            return Err(invalid("wind_speed", speed, "must be finite and >= 0"));
        }
        if !(pressure_rms.is_finite() && pressure_rms >= 0.0) {
            return Err(invalid(
                "pressure_rms",
                pressure_rms,
                "must be finite and >= 0",
            ));
        }
        Ok(WindLoads {
            screen: self.screen.clone(),
            speed,
            pressure_rms,
        })
    }

    /// Mean wind speed (m/s).
    pub fn speed(&self) -> f64 {
        self.speed
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.screen.along.len()
    }

    /// Number of actuators (3 per segment).
    pub fn n_actuators(&self) -> usize {
        3 * self.screen.along.len()
    }

    /// Screen spacing `dx` (m): the shift between table entries.
    pub fn spacing(&self) -> f64 {
        self.screen.spacing
    }

    /// Time after which the flow repeats, `L / U` (s); None for `U = 0`.
    pub fn period(&self) -> Option<f64> {
        (self.speed > 0.0).then(|| self.screen.samples as f64 * self.screen.spacing / self.speed)
    }

    /// Area of a segment's hexagon in the aperture plane (m^2).
    pub fn segment_area(&self) -> f64 {
        self.screen.area
    }

    /// The rms pressure `sigma_p` (Pa).
    pub fn pressure_rms(&self) -> f64 {
        self.pressure_rms
    }

    /// Expected rms of `int_Hex p dA` over the aperture-plane hexagon (N):
    /// `sqrt(sum_k Phi_d(k) |H(k)|^2)`; compare with `sigma_p A` for the aperture attenuation.
    pub fn expected_force_rms(&self) -> f64 {
        self.pressure_rms * self.screen.force_rms
    }

    /// Bytes held by the tables and maps.
    pub fn memory_bytes(&self) -> usize {
        8 * (self.screen.tables.len() + self.screen.along.len() + 18 * self.screen.to_load.len())
    }

    /// Wind-frame integrals `[G_0, G_xi, G_eta]` of segment `i` at time `t` (the unit screen's,
    /// times the rms pressure).
    fn wind_integrals(&self, i: usize, t: f64) -> [f64; 3] {
        let n = self.screen.samples;
        let u = self.screen.along[i] - self.speed * t / self.screen.spacing;
        let (idx, w) = periodic_stencil(u, n);
        std::array::from_fn(|q| {
            let tab = &self.screen.tables[(3 * i + q) * n..(3 * i + q + 1) * n];
            self.pressure_rms * idx.iter().zip(w).map(|(&j, wj)| wj * tab[j]).sum::<f64>()
        })
    }

    /// `[int p dA, int p (x - c_x) dA, int p (y - c_y) dA]` over segment `i`'s hexagon in the
    /// aperture plane at time `t` (N, N.m), in the layout's axes (p the front-face pressure).
    ///
    /// # Panics
    /// If `i >= n_segments()`.
    pub fn integrals(&self, i: usize, t: f64) -> [f64; 3] {
        let [g0, g1, g2] = self.wind_integrals(i, t);
        let [c, s] = self.screen.direction;
        [g0, c * g1 - s * g2, s * g1 + c * g2]
    }

    /// Generalised load `[F, M_alpha, M_beta]` on segment `i` at time `t`: the normal force
    /// (N, along `+normal`) and the moments (N.m) about its radial and azimuthal axes.
    ///
    /// # Panics
    /// If `i >= n_segments()`.
    pub fn segment_load(&self, i: usize, t: f64) -> [f64; 3] {
        let g = self.wind_integrals(i, t);
        let b = &self.screen.to_load[i];
        std::array::from_fn(|r| (0..3).map(|c| b[r][c] * g[c]).sum())
    }

    /// Equivalent forces at every actuator at time `t` (N, along each segment's normal;
    /// actuator `k` of segment `i` at `3 i + k`).
    pub fn forces(&self, t: f64, out: &mut [f64]) -> Result<(), M1Error> {
        if out.len() != self.n_actuators() {
            return Err(M1Error::SizeMismatch {
                what: "f_wind",
                expected: self.n_actuators(),
                found: out.len(),
            });
        }
        for (i, f) in out.chunks_exact_mut(3).enumerate() {
            let g = self.wind_integrals(i, t);
            let m = &self.screen.to_forces[i];
            for (k, fk) in f.iter_mut().enumerate() {
                *fk = m[k][0] * g[0] + m[k][1] * g[1] + m[k][2] * g[2];
            }
        }
        Ok(())
    }
}

fn unit2(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    if n > 0.0 {
        [v[0] / n, v[1] / n]
    } else {
        [1.0, 0.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hexagon(a: f64, rot: f64) -> Vec<[f64; 2]> {
        (0..6)
            .map(|k| {
                let ang = (30.0 + 60.0 * k as f64 + rot).to_radians();
                [a * ang.cos(), a * ang.sin()]
            })
            .collect()
    }

    /// Midpoint-rule transform on a fine grid (point-in-convex-polygon test).
    fn brute(poly: &[[f64; 2]], k: [f64; 2], m: usize) -> [Complex64; 3] {
        let r = poly.iter().map(|v| v[0].hypot(v[1])).fold(0.0, f64::max);
        let h = 2.0 * r / m as f64;
        let inside = |x: f64, y: f64| {
            (0..poly.len()).all(|j| {
                let a = poly[j];
                let b = poly[(j + 1) % poly.len()];
                (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]) >= 0.0
            })
        };
        let mut out = [Complex64::ZERO; 3];
        for i in 0..m {
            for j in 0..m {
                let x = -r + (i as f64 + 0.5) * h;
                let y = -r + (j as f64 + 0.5) * h;
                if inside(x, y) {
                    let e = Complex64::cis(TAU * (k[0] * x + k[1] * y)) * (h * h);
                    out[0] += e;
                    out[1] += e * x;
                    out[2] += e * y;
                }
            }
        }
        out
    }

    #[test]
    fn polygon_transform_matches_quadrature() {
        let poly = hexagon(0.72, 17.0);
        for k in [
            [0.0, 0.0],
            [1.0 / 128.0, 0.0],
            [0.3, -0.2],
            [1.1, 0.7],
            [-2.5, 3.0],
        ] {
            let exact = polygon_transform(&poly, k);
            let num = brute(&poly, k, 2000);
            for (e, b) in exact.iter().zip(num) {
                assert!((e - b).norm() < 2e-4, "k {k:?}: {e} vs {b}");
            }
        }
        // Area of a regular hexagon, 3 sqrt(3) a^2 / 2.
        let a = polygon_transform(&poly, [0.0, 0.0])[0].re;
        assert!((a - 1.5 * 3f64.sqrt() * 0.72 * 0.72).abs() < 1e-12);
    }

    #[test]
    fn moment_transforms_are_regular_near_zero() {
        // H_x ~ i J q_x for small q, J = 5 sqrt(3) a^4 / 16. The closed form loses about
        // 1e-16 / (|q| a)^2 to cancellation: 5e-12 here, 1e-13 at the smallest wavenumber of a
        // 128 m screen.
        let poly = hexagon(0.72, 0.0);
        let j = 5.0 * 3f64.sqrt() * 0.72f64.powi(4) / 16.0;
        let k = 1e-3;
        let [h, hx, hy] = polygon_transform(&poly, [k, 0.0]);
        assert!((h.re / (1.5 * 3f64.sqrt() * 0.72 * 0.72) - 1.0).abs() < 1e-5);
        assert!((hx.im / (j * TAU * k) - 1.0).abs() < 1e-5, "{hx}");
        assert!(
            hx.re.abs() < 1e-8 * hx.im && hy.norm() < 1e-8 * hx.im,
            "{hx} {hy}"
        );
    }

    #[test]
    fn catmull_rom_is_a_partition_of_unity_and_interpolates() {
        for t in [0.0, 0.25, 0.5, 0.9] {
            let w = catmull_rom(t);
            assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        }
        assert_eq!(catmull_rom(0.0), [0.0, 1.0, 0.0, 0.0]);
        let (idx, _) = periodic_stencil(-0.5, 8);
        assert_eq!(idx, [6, 7, 0, 1]);
    }
}
