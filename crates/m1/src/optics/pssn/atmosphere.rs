//! The von Karman phase statistics of the atmosphere and the lag weights of its OTF.

use super::*;

/// Kolmogorov phase structure function coefficient, `2 [24/5 Gamma(6/5)]^(5/6)` (the "6.88").
pub const KOLMOGOROV_COEFFICIENT: f64 = 6.883_877_182_293_812;

/// Wavelength at which the Fried parameter `r0` is given (m): 500 nm.
pub const R0_WAVELENGTH: f64 = 500e-9;

/// Gamma(1/6).
pub(super) const GAMMA_1_6: f64 = 5.566_316_001_780_235;
/// Gamma(5/6).
pub(super) const GAMMA_5_6: f64 = 1.128_787_029_908_126;
/// Order of the Bessel function of the von Kármán structure function.
pub(super) const NU: f64 = 5.0 / 6.0;

/// Relative weight below which an OTF sample is dropped (`exp(-D) < 1e-30`).
pub(super) const WEIGHT_FLOOR: f64 = 1e-30;

/// Modified Bessel function of the second kind `K_nu(x)` for real `nu` and `x > 0`, from
/// `K_nu(x) = integral_0^inf exp(-x cosh t) cosh(nu t) dt` by the trapezoidal rule (step
/// 0.05), which converges geometrically for this analytic, double-exponentially decaying
/// integrand: relative accuracy about 1e-14. `+inf` at `x = 0`, NaN for `x < 0` or NaN.
pub fn bessel_k(nu: f64, x: f64) -> f64 {
    if x.is_nan() || x < 0.0 || nu.is_nan() {
        return f64::NAN;
    }
    if x == 0.0 {
        return f64::INFINITY;
    }
    if x.is_infinite() {
        return 0.0;
    }
    const H: f64 = 0.05;
    let nu = nu.abs();
    // exp(-x) is factored out: terms exp(-x (cosh t - 1)) cosh(nu t), the first at half weight.
    let mut sum = 0.5;
    for k in 1..200_000_u32 {
        let t = f64::from(k) * H;
        let e = x * (t.cosh() - 1.0);
        sum += (-e).exp() * (nu * t).cosh();
        // Past the peak every further term is below exp(-40) of the sum, and falling fast.
        if e - nu * t > 40.0 {
            break;
        }
    }
    sum * H * (-x).exp()
}

/// Von Kármán constant `C` of [`phase_structure_function`]: `D(r) -> 6.88 (r/r0)^(5/3)` for
/// `r << L0`.
pub(super) fn von_karman_coefficient() -> f64 {
    // Leading small-x term of the bracket: a1 x^(5/3), a1 = Gamma(1/6) / (nu 2^(2 nu) Gamma(5/6)).
    let a1 = GAMMA_1_6 / (NU * 2.0_f64.powf(2.0 * NU) * GAMMA_5_6);
    KOLMOGOROV_COEFFICIENT / (a1 * (2.0 * PI).powf(5.0 / 3.0))
}

/// The bracket `1 - 2^(1/6) / Gamma(5/6) x^(5/6) K_(5/6)(x)` of the von Kármán structure
/// function, from 0 at `x = 0` to 1 at `x = inf`.
pub(super) fn von_karman_shape(x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x <= 1.0 {
        // x^nu K_nu(x) from the series of I_-nu and I_nu; its constant term cancels the 1.
        let y = 0.25 * x * x;
        let mut tp = 1.0 / (NU * GAMMA_5_6); // 1 / Gamma(1 + nu)
        let mut tm = 1.0 / GAMMA_1_6; // 1 / Gamma(1 - nu)
        let mut sum_p = tp;
        let mut sum_m = 0.0;
        for k in 1..100 {
            let k = f64::from(k);
            tp *= y / (k * (k + NU));
            tm *= y / (k * (k - NU));
            sum_p += tp;
            sum_m += tm;
            if tp.abs() <= 1e-18 * sum_p.abs() && tm.abs() <= 1e-18 * sum_m.abs() {
                break;
            }
        }
        GAMMA_1_6 * (2.0_f64.powf(-2.0 * NU) * x.powf(2.0 * NU) * sum_p - sum_m)
    } else {
        let c = 2.0_f64.powf(1.0 - NU) / GAMMA_5_6;
        1.0 - c * x.powf(NU) * bessel_k(NU, x)
    }
}

/// Phase structure function `D(r)` (rad^2) of the atmosphere at the separation `r` (m) for the
/// Fried parameter `r0` (m, at the wavelength of interest) and outer scale `l0` (m;
/// `f64::INFINITY` gives Kolmogorov). See the [module documentation](super).
pub fn phase_structure_function(r: f64, r0: f64, l0: f64) -> f64 {
    let r = r.abs();
    if r == 0.0 {
        return 0.0;
    }
    if l0.is_infinite() {
        return KOLMOGOROV_COEFFICIENT * (r / r0).powf(5.0 / 3.0);
    }
    von_karman_coefficient() * (l0 / r0).powf(5.0 / 3.0) * von_karman_shape(2.0 * PI * r / l0)
}

/// Von Kármán phase variance `sigma^2 = C/2 (L0/r0)^(5/3)` (rad^2, about
/// `0.0863 (L0/r0)^(5/3)`): `D(r) -> 2 sigma^2` for `r >> L0`. Infinite for `l0 = inf`.
pub fn phase_variance(r0: f64, l0: f64) -> f64 {
    0.5 * von_karman_coefficient() * (l0 / r0).powf(5.0 / 3.0)
}

/// Fried parameter at `wavelength` (m) from its value `r0_500` at 500 nm: `r0 ∝ lambda^(6/5)`.
pub fn r0_at_wavelength(r0_500: f64, wavelength: f64) -> f64 {
    r0_500 * (wavelength / R0_WAVELENGTH).powf(1.2)
}

/// Combined PSSN of several independent small errors: the product of their PSSNs (the
/// small-error property of PSSN, accurate while each deficit is small).
pub fn pssn_small_error(pssn: &[f64]) -> f64 {
    pssn.iter().product()
}

/// Weight of the OTF sample at the lag `(i, j) dx`: the integral of `exp(-D(r))` against the
/// bilinear hat function of that sample, `int exp(-D(dx (i + s, j + t))) (1 - |s|)(1 - |t|)
/// ds dt` over `[-1, 1]^2` (8 x 8 Gauss–Legendre points per quadrant), within
/// `3 r0 + 2 dx` of the origin, where `exp(-D)` changes on the scale of a sample; the point value
/// `exp(-D(r))` beyond. This product integration makes the weighted sum exact for an OTF that
/// is bilinear between samples instead of constant around each, so the PSSN deficit stays
/// accurate when `dx` approaches `r0` (the point-sampled weight puts nearly all the weight on
/// the error-blind zero lag then).
#[derive(Debug, Clone)]
pub(super) struct LagWeight {
    pub(super) dx: f64,
    pub(super) r0: f64,
    pub(super) l0: f64,
    pub(super) r_smooth: f64,
    /// Gauss–Legendre nodes on [0, 1] and their weights times the hat `1 - s`.
    pub(super) rule: Vec<(f64, f64)>,
}

impl LagWeight {
    pub(super) fn new(dx: f64, r0: f64, l0: f64) -> LagWeight {
        let (x, w) = crate::aperture::zernike::gauss_legendre(8);
        let rule = x
            .iter()
            .zip(&w)
            .map(|(&x, &w)| {
                let s = 0.5 * (1.0 + x);
                (s, 0.5 * w * (1.0 - s))
            })
            .collect();
        LagWeight {
            dx,
            r0,
            l0,
            r_smooth: 3.0 * r0 + 2.0 * dx,
            rule,
        }
    }

    fn point(&self, r: f64) -> f64 {
        (-phase_structure_function(r, self.r0, self.l0)).exp()
    }

    /// Weight of the lag `(i, j)` samples, relative to `dx^2` (1 for `D = 0`).
    pub(super) fn at(&self, i: f64, j: f64) -> f64 {
        let r = self.dx * i.hypot(j);
        if r >= self.r_smooth {
            return self.point(r);
        }
        let mut sum = 0.0;
        for &(s, ws) in &self.rule {
            for &(t, wt) in &self.rule {
                for (si, tj) in [(s, t), (-s, t), (s, -t), (-s, -t)] {
                    sum += ws * wt * self.point(self.dx * (i + si).hypot(j + tj));
                }
            }
        }
        sum
    }
}

/// OTF weights ([`LagWeight`]) on the half lag plane `y' = 0..=M/2` (rows) x `x' = 0..M`, lag
/// `(wrap(x'), y') dx`, doubled for `0 < y' < M/2` (the rows standing for their mirror image);
/// weights below [`WEIGHT_FLOOR`] set to zero and the trailing zero rows dropped.
/// Returns `(weights, rows)`.
pub(super) fn otf_weights(params: &PssnParams, m: usize, dx: f64) -> (Vec<f64>, usize) {
    let r0 = r0_at_wavelength(params.r0, params.wavelength);
    let l0 = params.l0;
    let d = |r: f64| phase_structure_function(r, r0, l0);
    let threshold = -WEIGHT_FLOOR.ln();
    // D is increasing in r: find the lag beyond which exp(-D) < WEIGHT_FLOOR; the hat weights
    // reach one sample further.
    let r_max = dx * m as f64;
    let r_cut = if d(r_max) <= threshold {
        f64::INFINITY
    } else {
        let (mut lo, mut hi) = (0.0, r_max);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if d(mid) > threshold {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi + 1.5 * dx
    };
    let half = m / 2;
    let rows = if r_cut.is_finite() {
        ((r_cut / dx).floor() as usize + 1).min(half + 1)
    } else {
        half + 1
    };
    let lag = LagWeight::new(dx, r0, l0);
    let mut weights = vec![0.0; rows * m];
    for y in 0..rows {
        let factor = if y == 0 || y == half { 1.0 } else { 2.0 };
        for x in 0..m {
            let xw = if x > half { m - x } else { x };
            let r = dx * ((xw * xw + y * y) as f64).sqrt();
            if r <= r_cut {
                let w = lag.at(xw as f64, y as f64);
                if w >= WEIGHT_FLOOR {
                    weights[y * m + x] = factor * w;
                }
            }
        }
    }
    (weights, rows)
}
