//! Random segment states and their statistics, for the PSSN studies (`m1cs pssn`): a seeded
//! Gaussian segment piston/tip/tilt state, the rms it realises, the piston pattern scaled to a
//! given rms, and the small-error coefficient `k` of a deficit curve `1 - PSSN = k rms^2`.
//!
//! Segment states are `[p, tx, ty]` per segment, in layout order: piston `p` (m) and the surface
//! slopes `tx = dz/dx`, `ty = dz/dy` (rad) about the segment centre (see
//! [`crate::aperture::zernike`]).
//!
//! # Random segment states
//!
//! [`random_state`] draws with the generator the rest of the crate uses: `rand`'s `StdRng`
//! seeded by `seed_from_u64(seed)`, standard normal deviates from `rand_distr`'s
//! `StandardNormal`. Segment `i` gets, in order, `p = piston_rms g`, `tx = tilt_rms g'`,
//! `ty = tilt_rms g''` from consecutive deviates, so the tilt rms is the rms of each tilt axis
//! and the pistons of a seed are the same pattern, scaled, whatever the tilt rms is. A seed gives
//! the same state on every platform for a given `rand` (Cargo.lock pins it; `StdRng`'s algorithm
//! may change between `rand` releases).

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};

/// Default rms of the random segment pistons (m): 10 nm.
pub const DEFAULT_PISTON_RMS: f64 = 10e-9;
/// Default rms of each random segment tilt axis, `tx` and `ty` (rad): 10 nrad.
pub const DEFAULT_TILT_RMS: f64 = 10e-9;
/// Default seed of the random segment state.
pub const DEFAULT_SEED: u64 = 1;

/// Random segment state of `n` segments: `[piston_rms g, tilt_rms g', tilt_rms g'']` per
/// segment from consecutive standard normal deviates of seed `seed` (see the
/// [module documentation](self)). The pistons of a given seed are the same pattern, scaled by
/// `piston_rms`, whatever `tilt_rms` is.
pub fn random_state(n: usize, piston_rms: f64, tilt_rms: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
    (0..n)
        .map(|_| {
            let p = piston_rms * g();
            let tx = tilt_rms * g();
            let ty = tilt_rms * g();
            [p, tx, ty]
        })
        .collect()
}

/// Rms of the segment pistons (about zero; 0 for no segment).
pub fn piston_rms(state: &[[f64; 3]]) -> f64 {
    if state.is_empty() {
        return 0.0;
    }
    (state.iter().map(|s| s[0] * s[0]).sum::<f64>() / state.len() as f64).sqrt()
}

/// Rms of one tilt axis: `sqrt(mean(tx^2 + ty^2) / 2)` (0 for no segment).
pub fn tilt_rms_per_axis(state: &[[f64; 3]]) -> f64 {
    if state.is_empty() {
        return 0.0;
    }
    (state.iter().map(|s| s[1] * s[1] + s[2] * s[2]).sum::<f64>() / (2 * state.len()) as f64).sqrt()
}

/// The pistons of `pattern` scaled to the rms `rms` (its [`piston_rms`] is `unit`), no tilt:
/// `[rms p / unit, 0, 0]` per segment.
pub fn scaled_pistons(pattern: &[[f64; 3]], unit: f64, rms: f64) -> Vec<[f64; 3]> {
    pattern
        .iter()
        .map(|p| [rms * p[0] / unit, 0.0, 0.0])
        .collect()
}

/// Small-error coefficient `k = lim y / x^2` (x -> 0) of the points `(x, y)` of a curve
/// `y = k x^2 - c x^4 + ...`: with the two smallest positive `x1 < x2` and `r = y / x^2`,
/// the Richardson extrapolation `(r1 x2^2 - r2 x1^2) / (x2^2 - x1^2)` (exact for
/// `y = k x^2 - c x^4`); `r1` with a single positive `x`; NaN with none.
pub fn small_error_coefficient(points: &[(f64, f64)]) -> f64 {
    let mut usable: Vec<(f64, f64)> = points
        .iter()
        .copied()
        .filter(|&(x, y)| x > 0.0 && x.is_finite() && y.is_finite())
        .collect();
    usable.sort_by(|a, b| a.0.total_cmp(&b.0));
    usable.dedup_by(|a, b| a.0 == b.0);
    match usable[..] {
        [] => f64::NAN,
        [(x, y)] => y / (x * x),
        [(x1, y1), (x2, y2), ..] => {
            let (q1, q2) = (x1 * x1, x2 * x2);
            (y1 / q1 * q2 - y2 / q2 * q1) / (q2 - q1)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deviates_have_zero_mean_and_unit_variance() {
        // 200 001 deviates in drawing order: p, tx, ty of each segment.
        let n = 66_667;
        let x: Vec<f64> = random_state(n, 1.0, 1.0, 42)
            .into_iter()
            .flatten()
            .collect();
        let n = x.len();
        let mean = x.iter().sum::<f64>() / n as f64;
        let var = x.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
        let kurt = x.iter().map(|v| (v - mean).powi(4)).sum::<f64>() / n as f64 / (var * var);
        // Standard errors: 1/sqrt(n) = 0.0022 (mean), sqrt(2/n) = 0.0032 (variance),
        // sqrt(24/n) = 0.011 (kurtosis).
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((var - 1.0).abs() < 0.015, "variance {var}");
        assert!((kurt - 3.0).abs() < 0.06, "kurtosis {kurt}");
        let within_1sigma = x.iter().filter(|v| v.abs() < 1.0).count() as f64 / n as f64;
        assert!((within_1sigma - 0.682_689).abs() < 0.005, "{within_1sigma}");
        assert!(x.iter().all(|v| v.is_finite()));
    }

    #[test]
    fn random_state_is_seeded_and_scaled() {
        let a = random_state(492, 10e-9, 20e-9, 3);
        assert_eq!(a, random_state(492, 10e-9, 20e-9, 3));
        assert_ne!(a, random_state(492, 10e-9, 20e-9, 4));
        // 492 samples: relative standard error of an rms about 1/sqrt(2 n) = 3 %.
        assert!((piston_rms(&a) / 10e-9 - 1.0).abs() < 0.1);
        assert!((tilt_rms_per_axis(&a) / 20e-9 - 1.0).abs() < 0.1);
        // The pistons of a seed do not depend on the tilt rms.
        let b = random_state(492, 1.0, 0.0, 3);
        for (s, t) in a.iter().zip(&b) {
            assert!((s[0] - 10e-9 * t[0]).abs() <= 1e-24);
            assert_eq!([t[1], t[2]], [0.0, 0.0]);
        }
        assert!(random_state(5, 0.0, 0.0, 1).iter().all(|s| *s == [0.0; 3]));
        assert_eq!(piston_rms(&[]), 0.0);
        assert_eq!(tilt_rms_per_axis(&[]), 0.0);
    }

    #[test]
    fn scaled_pistons_have_the_asked_rms() {
        let pattern = random_state(36, 1.0, 0.0, 1);
        let unit = piston_rms(&pattern);
        let s = scaled_pistons(&pattern, unit, 5e-9);
        assert!((piston_rms(&s) / 5e-9 - 1.0).abs() < 1e-12);
        assert_eq!(tilt_rms_per_axis(&s), 0.0);
    }

    #[test]
    fn small_error_coefficient_of_exact_and_degenerate_data() {
        // y = 3 x^2 - 0.5 x^4, unsorted, with the origin and a repeated point.
        let y = |x: f64| 3.0 * x * x - 0.5 * x.powi(4);
        let pts: Vec<(f64, f64)> = [2.0, 0.0, 0.5, 1.0, 0.5]
            .iter()
            .map(|&x| (x, y(x)))
            .collect();
        assert!((small_error_coefficient(&pts) - 3.0).abs() < 1e-12);
        assert!((small_error_coefficient(&[(0.0, 0.0), (2.0, 8.0)]) - 2.0).abs() < 1e-15);
        assert!(small_error_coefficient(&[(0.0, 1.0)]).is_nan());
        assert!(small_error_coefficient(&[]).is_nan());
    }
}
