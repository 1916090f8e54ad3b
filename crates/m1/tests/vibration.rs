//! Pier vibration: tones recovered by least squares and FFT, noise rms and band, seeds, and
//! independence from the sampling (communication) step.

#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use std::f64::consts::TAU;

use m1::loads::vibration::{BandNoise, NoiseParams, PierVibration, Tone};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex64;

const NO_NOISE: NoiseParams = NoiseParams {
    rms: 0.0,
    low: 1.0,
    high: 100.0,
    period: 100.0,
    seed: 1,
};

/// Least-squares amplitude and phase of `A sin(2 pi f t + phi)` in samples `z` at times `t`.
fn fit(t: &[f64], z: &[f64], f: f64) -> (f64, f64) {
    // z = a sin + b cos; normal equations.
    let (mut ss, mut sc, mut cc, mut zs, mut zc) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (&ti, &zi) in t.iter().zip(z) {
        let (s, c) = (TAU * f * ti).sin_cos();
        ss += s * s;
        sc += s * c;
        cc += c * c;
        zs += zi * s;
        zc += zi * c;
    }
    let det = ss * cc - sc * sc;
    let a = (zs * cc - zc * sc) / det;
    let b = (zc * ss - zs * sc) / det;
    // a sin + b cos = A sin(x + phi): a = A cos phi, b = A sin phi.
    (a.hypot(b), b.atan2(a))
}

fn power_spectrum(z: &[f64]) -> Vec<f64> {
    let mut buf: Vec<Complex64> = z.iter().map(|&x| x.into()).collect();
    FftPlanner::new()
        .plan_fft_forward(buf.len())
        .process(&mut buf);
    buf.iter().map(|c| c.norm_sqr()).collect()
}

#[test]
fn tone_is_recovered_by_least_squares_and_fft() {
    let tone = Tone {
        frequency: 29.6,
        amplitude: 1e-8,
        phase: 0.7,
    };
    let v = PierVibration::new(&[tone], &NO_NOISE).unwrap();
    let t: Vec<f64> = (0..10_000).map(|k| k as f64 * 1e-3).collect();
    let z: Vec<f64> = t.iter().map(|&ti| v.at(ti)).collect();
    let (a, phi) = fit(&t, &z, 29.6);
    assert!((a / 1e-8 - 1.0).abs() < 1e-10, "{a}");
    assert!((phi - 0.7).abs() < 1e-10, "{phi}");
    // 10 s at 1 kHz: the tone sits on bin 296 (0.1 Hz bins).
    let p = power_spectrum(&z);
    let peak = (0..5000).max_by(|&i, &j| p[i].total_cmp(&p[j])).unwrap();
    assert_eq!(peak, 296);
    // With noise present the fit still recovers the tone (noise 1 nm over 1-100 Hz).
    let noisy = PierVibration::new(&[tone], &NoiseParams::default()).unwrap();
    let z: Vec<f64> = t.iter().map(|&ti| noisy.at(ti)).collect();
    let (a, phi) = fit(&t, &z, 29.6);
    assert!((a / 1e-8 - 1.0).abs() < 0.01, "{a}");
    assert!((phi - 0.7).abs() < 0.01, "{phi}");
    assert!((noisy.expected_rms() / (1e-16 / 2.0 + 1e-18_f64).sqrt() - 1.0).abs() < 1e-9);
}

#[test]
fn tone_does_not_depend_on_the_step() {
    // Times reached by accumulating steps of 1 ms and of 0.25 ms give the same samples.
    let v = PierVibration::new(
        &[Tone {
            frequency: 29.6,
            amplitude: 1e-8,
            phase: 0.3,
        }],
        &NO_NOISE,
    )
    .unwrap();
    let (mut t1, mut t2) = (0.0_f64, 0.0_f64);
    for _ in 0..1000 {
        t1 += 1e-3;
        for _ in 0..4 {
            t2 += 2.5e-4;
        }
        // The only difference is the rounding of the accumulated times: z depends on t alone.
        let bound = 1.01 * TAU * 29.6 * 1e-8 * (t1 - t2).abs() + 1e-14 * 1e-8;
        assert!(
            (v.at(t1) - v.at(t2)).abs() <= bound,
            "{} vs {} at {t1} {t2}",
            v.at(t1),
            v.at(t2)
        );
    }
}

#[test]
fn noise_has_its_rms_and_stays_in_its_band() {
    let p = NoiseParams {
        rms: 2e-9,
        low: 5.0,
        high: 50.0,
        period: 20.0,
        seed: 3,
    };
    let noise = BandNoise::new(&p).unwrap();
    assert_eq!(noise.rate(), 400.0);
    assert!((noise.period() - 20.0).abs() < 1e-12);
    // The table: rms exact, no power outside the band (0.05 Hz bins).
    let s = noise.samples();
    let rms = (s.iter().map(|x| x * x).sum::<f64>() / s.len() as f64).sqrt();
    assert!((rms / 2e-9 - 1.0).abs() < 1e-12);
    let spec = power_spectrum(s);
    let df = 1.0 / noise.period();
    let total: f64 = spec.iter().sum();
    let outside: f64 = spec
        .iter()
        .enumerate()
        .filter(|&(k, _)| {
            let f = k.min(s.len() - k) as f64 * df;
            !(5.0 - 1e-9..=50.0 + 1e-9).contains(&f)
        })
        .map(|(_, p)| p)
        .sum();
    assert!(outside < 1e-20 * total, "{outside} of {total}");
    // Sampled at 1 kHz between the table's samples: rms within 1 % (interpolation loss), and
    // more than 99.9 % of the power inside the band.
    let z: Vec<f64> = (0..20_000).map(|k| noise.at(k as f64 * 1e-3)).collect();
    let rms = (z.iter().map(|x| x * x).sum::<f64>() / z.len() as f64).sqrt();
    assert!((rms / 2e-9 - 1.0).abs() < 0.01, "{rms}");
    let spec = power_spectrum(&z);
    let total: f64 = spec.iter().sum();
    let inside: f64 = spec
        .iter()
        .enumerate()
        .filter(|&(k, _)| (5.0..=50.0).contains(&(k.min(z.len() - k) as f64 * df)))
        .map(|(_, p)| p)
        .sum();
    assert!(inside > 0.999 * total, "{}", inside / total);
}

#[test]
fn seeds_reproduce_and_differ() {
    let p = NoiseParams::default();
    let a = BandNoise::new(&p).unwrap();
    assert_eq!(a, BandNoise::new(&p).unwrap());
    let b = BandNoise::new(&NoiseParams { seed: 2, ..p }).unwrap();
    let (x, y) = (a.samples(), b.samples());
    let rho = x.iter().zip(y).map(|(u, v)| u * v).sum::<f64>()
        / (x.iter().map(|u| u * u).sum::<f64>() * y.iter().map(|v| v * v).sum::<f64>()).sqrt();
    assert!(rho.abs() < 0.05, "{rho}");
}

#[test]
fn bad_parameters_are_refused_with_their_name() {
    let name = |p: NoiseParams| match PierVibration::new(&[], &p) {
        Err(m1::M1Error::InvalidParameter { name, .. }) => name,
        other => panic!("{other:?}"),
    };
    let ok = NoiseParams::default();
    assert_eq!(name(NoiseParams { rms: -1e-9, ..ok }), "noise_rms");
    assert_eq!(
        name(NoiseParams { high: 0.5, ..ok }),
        "noise_high_frequency"
    );
    assert_eq!(
        name(NoiseParams {
            low: 10.2,
            high: 10.3,
            period: 1.0,
            ..ok
        }),
        "noise_period"
    );
    assert_eq!(name(NoiseParams { period: 1e9, ..ok }), "noise_period");
    let bad_tone = Tone {
        frequency: -1.0,
        amplitude: 1e-9,
        phase: 0.0,
    };
    assert!(PierVibration::new(&[bad_tone], &ok).is_err());
}
