#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::*;
use rustfft::FftPlanner;

/// Direct computation (full complex 2-D FFTs, all lags) of the weighted OTF power, to check
/// the packed fast path.
fn reference(pssn: &Pssn, surface: &[f64]) -> f64 {
    let (n, m) = (pssn.grid.samples, pssn.size);
    let mut planner = FftPlanner::<f64>::new();
    let fwd = planner.plan_fft_forward(m);
    let inv = planner.plan_fft_inverse(m);
    let fft2 = |buf: &mut Vec<Complex64>, f: &Arc<dyn Fft<f64>>| {
        f.process(buf);
        let mut t = vec![Complex64::new(0.0, 0.0); m * m];
        for r in 0..m {
            for c in 0..m {
                t[c * m + r] = buf[r * m + c];
            }
        }
        f.process(&mut t);
        *buf = t; // transposed: fine for isotropic weights
    };
    let mut e = vec![Complex64::new(0.0, 0.0); m * m];
    let k = pssn.phase_per_metre;
    for iy in 0..n {
        for ix in 0..n {
            if pssn.grid.segment[iy * n + ix].is_some() {
                let (s, c) = (k * surface[iy * n + ix]).sin_cos();
                e[iy * m + ix] = Complex64::new(c, s);
            }
        }
    }
    fft2(&mut e, &fwd);
    let mut p: Vec<Complex64> = e
        .iter()
        .map(|z| Complex64::new(z.norm_sqr(), 0.0))
        .collect();
    fft2(&mut p, &inv);
    let lag = LagWeight::new(pssn.grid.spacing, pssn.r0(), pssn.params.l0);
    let mut sum = 0.0;
    for y in 0..m {
        for x in 0..m {
            let xw = x.min(m - x) as f64;
            let yw = y.min(m - y) as f64;
            sum += lag.at(xw, yw) * p[y * m + x].norm_sqr();
        }
    }
    sum
}

#[test]
fn fast_path_matches_direct_computation() {
    let layout = Layout::keck();
    let params = PssnParams {
        samples: 48,
        wavelength: 1.0e-6,
        r0: 0.2,
        l0: 30.0,
        pad_factor: 2,
    };
    let pssn = Pssn::new(&layout, params).unwrap();
    let n = pssn.grid.samples;
    let surface: Vec<f64> = (0..n * n)
        .map(|i| 40e-9 * ((i as f64 * 0.37).sin() + (i as f64 * 0.011).cos()))
        .collect();
    let fast = pssn.with_workspace(|ws| {
        let k = pssn.phase_per_metre;
        pssn.weighted_otf_power(ws, |s| k * surface[s.grid])
    });
    let direct = reference(&pssn, &surface);
    assert!(
        ((fast - direct) / direct).abs() < 1e-10,
        "fast {fast} direct {direct}"
    );
}
