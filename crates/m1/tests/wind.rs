//! Wind loads: von Karman screen statistics (variance, spectrum), the aperture attenuation of
//! the segment integration, frozen flow, the periodic wrap, equivalent forces, seeds.

#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use std::f64::consts::{PI, TAU};

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::loads::wind::{
    OuterScale, ScreenParams, ScreenSpectrum, WindLoads, WindParams, equivalent_forces,
    polygon_transform, von_karman_psd,
};
use rustfft::FftPlanner;
use rustfft::num_complex::Complex64;

fn geometry(name: &str, flat: bool) -> Geometry {
    let layout = Layout::preset(name).unwrap();
    let params = GeometryParams {
        flat,
        ..GeometryParams::for_layout(&layout)
    };
    Geometry::new(&layout, params).unwrap()
}

fn screen(sigma: f64, scales: &[(f64, f64)], size: f64, samples: usize, seed: u64) -> ScreenParams {
    ScreenParams {
        pressure_rms: sigma,
        outer_scales: scales
            .iter()
            .map(|&(outer_scale, fraction)| OuterScale {
                outer_scale,
                fraction,
            })
            .collect(),
        size,
        samples,
        seed,
    }
}

const DEFAULT_SCALES: [(f64, f64); 2] = [(5.0, 0.75), (30.0, 0.25)];

fn mean_var(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    (m, x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / n)
}

#[test]
fn von_karman_spectrum_integrates_to_the_variance() {
    // 2 pi int_0^inf Phi(k) k dk = sigma^2, by the substitution k = k0 sinh(s).
    for l0 in [1.0, 5.0, 30.0] {
        let k0 = 1.0 / l0;
        let (n, smax) = (200_000, 25.0);
        let ds = smax / n as f64;
        let total: f64 = (0..n)
            .map(|i| {
                let s = (i as f64 + 0.5) * ds;
                let k = k0 * s.sinh();
                TAU * von_karman_psd(k, 2.0, l0) * k * k0 * s.cosh() * ds
            })
            .sum();
        assert!((total / 2.0 - 1.0).abs() < 1e-4, "L0 {l0}: {total}");
    }
}

#[test]
fn screen_variance_is_sigma_p_squared() {
    // The discrete spectrum sums to sigma_p^2 exactly; the spatial variance of one realisation
    // fluctuates (the 30 m component has few modes on a 128 m screen), so average 8 seeds:
    // the relative standard error is then about 2 %.
    let sigma = 2.0;
    let mut vars = Vec::new();
    for seed in 1..=8 {
        let p = screen(sigma, &DEFAULT_SCALES, 128.0, 256, seed);
        let psd = p.discrete_psd();
        let total: f64 = (0..256)
            .flat_map(|iy| (0..256).map(move |ix| (ix, iy)))
            .map(|(ix, iy)| psd.bin(ix, iy))
            .sum();
        assert!((total / sigma.powi(2) - 1.0).abs() < 1e-12, "{total}");
        let s = ScreenSpectrum::new(&p).unwrap().screen();
        let (mean, var) = mean_var(&s);
        // The mean (k = 0) is not part of the screen.
        assert!(mean.abs() < 1e-12 * sigma, "mean {mean}");
        assert!(
            (var / sigma.powi(2) - 1.0).abs() < 0.3,
            "seed {seed}: {var}"
        );
        vars.push(var);
    }
    let mean = vars.iter().sum::<f64>() / vars.len() as f64;
    assert!((mean / sigma.powi(2) - 1.0).abs() < 0.07, "{vars:?}");
}

#[test]
fn screen_spectrum_follows_von_karman() {
    // Periodogram of the screen: E |FFT s|^2 / N^4 = Phi_d(k). Averaged over annuli it matches
    // the spectrum, and its log-log slope well inside the inertial range is -11/3.
    let n = 512;
    let l0 = 5.0;
    let p = screen(1.0, &[(l0, 1.0)], 64.0, n, 7);
    let s = ScreenSpectrum::new(&p).unwrap().screen();
    let psd = p.discrete_psd();
    let mut buf: Vec<Complex64> = s.iter().map(|&x| x.into()).collect();
    let fft = FftPlanner::new().plan_fft_forward(n);
    fft.process(&mut buf);
    let mut t = vec![Complex64::ZERO; n * n];
    for i in 0..n {
        for j in 0..n {
            t[j * n + i] = buf[i * n + j];
        }
    }
    fft.process(&mut t);
    // Annuli of width 4 dk (dk = 1/64 cycle/m).
    let dk = 1.0 / 64.0;
    let nb = n / 8;
    let mut measured = vec![0.0; nb];
    let mut expected = vec![0.0; nb];
    let mut count = vec![0usize; nb];
    for iy in 0..n {
        for ix in 0..n {
            let kx = psd.wavenumber(ix);
            let ky = psd.wavenumber(iy);
            let b = (kx.hypot(ky) / (4.0 * dk)) as usize;
            if b < nb && psd.bin(ix, iy) > 0.0 {
                // t is the transposed spectrum: t[ix n + iy].
                measured[b] += t[ix * n + iy].norm_sqr() / (n as f64).powi(4);
                expected[b] += psd.bin(ix, iy);
                count[b] += 1;
            }
        }
    }
    let mut logk = Vec::new();
    let mut logp = Vec::new();
    for b in 2..nb {
        let ratio = measured[b] / expected[b];
        // Each annulus holds >= 50 bins of exponentially distributed power: a few % scatter.
        assert!(
            (ratio - 1.0).abs() < 0.3,
            "annulus {b}: {ratio} ({} bins)",
            count[b]
        );
        let k = (b as f64 + 0.5) * 4.0 * dk;
        if (1.5..3.5).contains(&k) {
            logk.push(k.ln());
            logp.push((measured[b] / count[b] as f64).ln());
        }
    }
    let (mk, _) = mean_var(&logk);
    let (mp, _) = mean_var(&logp);
    let slope = logk
        .iter()
        .zip(&logp)
        .map(|(x, y)| (x - mk) * (y - mp))
        .sum::<f64>()
        / logk.iter().map(|x| (x - mk).powi(2)).sum::<f64>();
    assert!((slope + 11.0 / 3.0).abs() < 0.15, "slope {slope}");
}

/// `int Phi(k) |H(k)|^2 d2k` over the continuous spectrum (polar quadrature, hexagon
/// symmetry), divided by `(sigma A)^2`: the aperture attenuation squared.
fn continuous_attenuation(a: f64, scales: &[(f64, f64)]) -> f64 {
    let hex: Vec<[f64; 2]> = (0..6)
        .map(|k| {
            let ang = (30.0 + 60.0 * k as f64).to_radians();
            [a * ang.cos(), a * ang.sin()]
        })
        .collect();
    let area = 1.5 * 3f64.sqrt() * a * a;
    let (nr, na) = (3000, 24);
    let (lo, hi) = (1e-4_f64.ln(), 40.0_f64.ln());
    let dl = (hi - lo) / nr as f64;
    let total: f64 = scales.iter().map(|s| s.1).sum();
    let mut sum = 0.0;
    for i in 0..nr {
        let k = (lo + (i as f64 + 0.5) * dl).exp();
        let phi: f64 = scales
            .iter()
            .map(|&(l0, f)| von_karman_psd(k, f / total, l0))
            .sum();
        // |H|^2 has the hexagon's 12-fold symmetry (6-fold and inversion): 0..30 degrees.
        let mut ang = 0.0;
        for j in 0..na {
            let th = (j as f64 + 0.5) * (PI / 6.0) / na as f64;
            let h = polygon_transform(&hex, [k * th.cos(), k * th.sin()])[0];
            ang += h.norm_sqr() / area.powi(2);
        }
        sum += phi * ang / na as f64 * TAU * k * k * dl;
    }
    sum
}

#[test]
fn segment_integration_attenuates_and_more_for_larger_segments() {
    let factors: Vec<f64> = [0.3, 0.72, 0.9, 1.5]
        .iter()
        .map(|&a| continuous_attenuation(a, &DEFAULT_SCALES).sqrt())
        .collect();
    assert!(factors.windows(2).all(|w| w[1] < w[0]), "{factors:?}");
    assert!(factors[0] < 1.0 && factors[3] > 0.1, "{factors:?}");

    // The model's expected force rms (the discrete sum over the screen's bins) agrees with the
    // continuous integral, for TMT and Keck; Keck's larger segments attenuate more.
    let mut model = Vec::new();
    for (name, a) in [("tmt", 0.72), ("keck", 0.9)] {
        let g = geometry(name, false);
        let params = WindParams {
            speed: 1.0,
            direction: 0.0,
            screen: screen(1.0, &DEFAULT_SCALES, 128.0, 512, 1),
        };
        let loads = WindLoads::new(&g, &params).unwrap();
        let area = 1.5 * 3f64.sqrt() * a * a;
        assert!((loads.segment_area() / area - 1.0).abs() < 1e-12);
        let f = loads.expected_force_rms() / area;
        let c = continuous_attenuation(a, &DEFAULT_SCALES).sqrt();
        // The discrete spectrum misses the lowest wavenumbers but is rescaled to sigma_p^2.
        assert!(
            (f / c - 1.0).abs() < 0.03,
            "{name}: model {f}, integral {c}"
        );
        model.push(f);
    }
    assert!(model[1] < model[0], "{model:?}");
}

#[test]
fn segment_force_variance_matches_the_filtered_spectrum() {
    // Sample variance of the force integrals of every TMT segment over one period of flow,
    // averaged over 4 seeds, against sum_k Phi_d(k) |H(k)|^2.
    let g = geometry("tmt", false);
    let n = 512;
    let mut ratios = Vec::new();
    for seed in 1..=4 {
        let params = WindParams {
            speed: 2.0,
            direction: 25.0,
            screen: screen(1.0, &DEFAULT_SCALES, 128.0, n, seed),
        };
        let loads = WindLoads::new(&g, &params).unwrap();
        let dt = loads.spacing() / 2.0;
        let mut x = Vec::new();
        for i in (0..g.n_segments()).step_by(3) {
            for m in (0..n).step_by(4) {
                x.push(loads.integrals(i, m as f64 * dt)[0]);
            }
        }
        let (_, var) = mean_var(&x);
        ratios.push(var / loads.expected_force_rms().powi(2));
    }
    let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
    assert!((mean - 1.0).abs() < 0.12, "{ratios:?}");
}

#[test]
fn integrals_match_direct_quadrature_of_the_screen() {
    // The tabulated integrals against a midpoint quadrature of the exact trigonometric screen
    // over the hexagon, with the wind at 30 degrees and the screen shifted.
    let g = geometry("keck", true);
    let sp = screen(1.0, &DEFAULT_SCALES, 32.0, 128, 3);
    let params = WindParams {
        speed: 2.0,
        direction: 30.0,
        screen: sp.clone(),
    };
    let loads = WindLoads::new(&g, &params).unwrap();
    let spectrum = ScreenSpectrum::new(&sp).unwrap();
    let (s, c) = 30f64.to_radians().sin_cos();
    let t = 3.7;
    let a = g.layout.circumradius;
    let m = 60;
    let h = 2.0 * a / m as f64;
    let f_rms = loads.expected_force_rms();
    for i in [0, 7, 20, 35] {
        let centre = g.layout.segments[i].center;
        let corners = g.layout.vertices(i).unwrap();
        let inside = |x: f64, y: f64| {
            (0..6).all(|j| {
                let p = corners[j];
                let q = corners[(j + 1) % 6];
                (q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0]) >= 0.0
            })
        };
        let mut direct = [0.0; 3];
        for ix in 0..m {
            for iy in 0..m {
                let dx = -a + (ix as f64 + 0.5) * h;
                let dy = -a + (iy as f64 + 0.5) * h;
                let (x, y) = (centre[0] + dx, centre[1] + dy);
                if inside(x, y) {
                    let xi = c * x + s * y - params.speed * t;
                    let eta = -s * x + c * y;
                    let p = spectrum.value_at(xi, eta) * h * h;
                    direct[0] += p;
                    direct[1] += p * dx;
                    direct[2] += p * dy;
                }
            }
        }
        let model = loads.integrals(i, t);
        let scale = [f_rms, f_rms * a / 2.0, f_rms * a / 2.0];
        for q in 0..3 {
            assert!(
                (model[q] - direct[q]).abs() < 0.03 * scale[q],
                "segment {i}, integral {q}: {} vs {}",
                model[q],
                direct[q]
            );
        }
    }
}

/// Pairs (upstream, downstream, distance) of TMT segments on the same row along x.
fn row_pairs(g: &Geometry) -> Vec<(usize, usize, f64)> {
    let c: Vec<[f64; 2]> = g.layout.segments.iter().map(|s| s.center).collect();
    let mut pairs = Vec::new();
    for i in 0..c.len() {
        for j in 0..c.len() {
            if c[i][1] == c[j][1] && c[j][0] > c[i][0] + 5.0 {
                pairs.push((i, j, c[j][0] - c[i][0]));
            }
        }
    }
    pairs
}

#[test]
fn downstream_segment_sees_the_upstream_load_delayed() {
    let g = geometry("tmt", true);
    let pairs = row_pairs(&g);
    assert!(pairs.len() > 100);
    for direction in [0.0, 180.0] {
        let params = WindParams {
            speed: 3.0,
            direction,
            screen: screen(1.0, &DEFAULT_SCALES, 64.0, 256, 5),
        };
        let loads = WindLoads::new(&g, &params).unwrap();
        let tol = 1e-9 * loads.expected_force_rms();
        let mut fi = [0.0; 1476];
        let mut fj = [0.0; 1476];
        for &(a, b, d) in pairs.iter().step_by(17) {
            // Wind towards +x: b is downstream of a; towards -x, a is downstream of b.
            let (up, down) = if direction == 0.0 { (a, b) } else { (b, a) };
            for t in [0.0, 0.37, 5.0, 19.9] {
                let delayed = t + d / params.speed;
                let u = loads.integrals(up, t);
                let w = loads.integrals(down, delayed);
                for q in 0..3 {
                    assert!(
                        (u[q] - w[q]).abs() < tol,
                        "{up}->{down} t {t}: {u:?} vs {w:?}"
                    );
                }
                // On a flat mirror the normal force (sum of the actuator forces) follows too.
                loads.forces(t, &mut fi).unwrap();
                loads.forces(delayed, &mut fj).unwrap();
                let fu: f64 = fi[3 * up..3 * up + 3].iter().sum();
                let fd: f64 = fj[3 * down..3 * down + 3].iter().sum();
                assert!((fu - fd).abs() < tol, "{fu} vs {fd}");
            }
        }
    }
}

#[test]
fn flow_wraps_seamlessly_after_one_screen_period() {
    let g = geometry("keck", false);
    let params = WindParams {
        speed: 4.0,
        direction: 75.0,
        screen: screen(1.0, &DEFAULT_SCALES, 40.0, 128, 9),
    };
    let loads = WindLoads::new(&g, &params).unwrap();
    let period = loads.period().unwrap();
    assert!((period - 10.0).abs() < 1e-12);
    let na = g.n_actuators();
    let (mut a, mut b) = (vec![0.0; na], vec![0.0; na]);
    let rms = loads.expected_force_rms();
    // One period on and many, and one back (the screen's shift taken within a period once per
    // time, from below zero too).
    for t in [0.0, 1.234, 7.5] {
        loads.forces(t, &mut a).unwrap();
        for k in [-1.0, 1.0, 5.0, 37.0] {
            loads.forces(t + k * period, &mut b).unwrap();
            for (x, y) in a.iter().zip(&b) {
                assert!((x - y).abs() < 1e-9 * rms, "{k} periods on: {x} vs {y}");
            }
        }
    }
    // Continuity where a segment's table wraps: u = along - U t / dx crosses a multiple of N.
    // Sampled every 1e-5 s around that instant, the load changes by no more than elsewhere.
    let dx = loads.spacing();
    let c = g.layout.segments[0].center;
    let along = (c[0] * 75f64.to_radians().cos() + c[1] * 75f64.to_radians().sin()) / dx;
    let t_wrap = along.rem_euclid(128.0) * dx / params.speed;
    let step = |t0: f64| {
        (0..200)
            .map(|k| {
                let t = t0 + (k as f64 - 100.0) * 1e-5;
                (loads.integrals(0, t + 1e-5)[0] - loads.integrals(0, t)[0]).abs()
            })
            .fold(0.0, f64::max)
    };
    let at_wrap = step(t_wrap);
    let elsewhere = (1..20).map(|k| step(0.37 * k as f64)).fold(0.0, f64::max);
    assert!(at_wrap < 1e-3 * rms, "{at_wrap}");
    assert!(at_wrap <= 2.0 * elsewhere, "{at_wrap} vs {elsewhere}");
}

#[test]
fn equivalent_forces_reproduce_force_and_moments() {
    let g = geometry("tmt", false);
    for i in [0, 100, 491] {
        let s = &g.segments[i];
        for q in [[1.0, 0.0, 0.0], [0.3, -2.0, 0.7], [-5.0, 1.0, 4.0]] {
            let f = equivalent_forces(&g, i, q);
            // Sum of forces = F; moments about the radial and azimuthal axes, from the
            // actuator points in 3-D: M_alpha = sum f_k (a_k - c).az, M_beta = -sum f_k (a_k - c).rad.
            let mut back = [0.0; 3];
            for (k, fk) in f.iter().enumerate() {
                let d: Vec<f64> = (0..3).map(|x| s.actuators[k][x] - s.centre[x]).collect();
                let dot = |v: [f64; 3]| d[0] * v[0] + d[1] * v[1] + d[2] * v[2];
                back[0] += fk;
                back[1] += fk * dot(s.azimuthal);
                back[2] -= fk * dot(s.radial);
            }
            for x in 0..3 {
                assert!((back[x] - q[x]).abs() < 1e-12, "{i}: {back:?} vs {q:?}");
            }
        }
    }
    // The model's actuator forces are the equivalent forces of its segment loads, and on a flat
    // mirror the load is [-int p, -int p v, int p u] with (u, v) along (radial, azimuthal).
    let gf = geometry("tmt", true);
    let params = WindParams {
        speed: 2.0,
        direction: 40.0,
        screen: screen(1.0, &DEFAULT_SCALES, 64.0, 256, 2),
    };
    let loads = WindLoads::new(&gf, &params).unwrap();
    let mut f = vec![0.0; gf.n_actuators()];
    loads.forces(1.5, &mut f).unwrap();
    for i in [3, 250, 400] {
        let q = loads.segment_load(i, 1.5);
        let e = equivalent_forces(&gf, i, q);
        for k in 0..3 {
            assert!((e[k] - f[3 * i + k]).abs() < 1e-12 * q[0].abs().max(1e-3));
        }
        let [p, px, py] = loads.integrals(i, 1.5);
        let s = &gf.segments[i];
        let v = px * s.azimuthal[0] + py * s.azimuthal[1];
        let u = px * s.radial[0] + py * s.radial[1];
        let expect = [-p, -v, u];
        for x in 0..3 {
            assert!(
                (q[x] - expect[x]).abs() < 1e-12 * p.abs().max(1e-3),
                "{q:?} {expect:?}"
            );
        }
    }
}

#[test]
fn seeds_reproduce_and_differ() {
    let g = geometry("keck", false);
    let run = |seed: u64| {
        let params = WindParams {
            speed: 5.0,
            direction: 10.0,
            screen: screen(1.0, &DEFAULT_SCALES, 64.0, 256, seed),
        };
        let loads = WindLoads::new(&g, &params).unwrap();
        let mut out = Vec::new();
        let mut f = vec![0.0; g.n_actuators()];
        for k in 0..200 {
            loads.forces(0.05 * k as f64, &mut f).unwrap();
            out.extend_from_slice(&f);
        }
        out
    };
    let a = run(11);
    assert_eq!(a, run(11));
    let b = run(12);
    let (ma, va) = mean_var(&a);
    let (mb, vb) = mean_var(&b);
    let cov = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - ma) * (y - mb))
        .sum::<f64>()
        / a.len() as f64;
    let rho = cov / (va * vb).sqrt();
    assert!(rho.abs() < 0.2, "correlation {rho}");
    assert!((va / vb).ln().abs() < 1.0, "{va} vs {vb}");
}

#[test]
fn bad_parameters_are_refused_with_their_name() {
    let g = geometry("keck", false);
    let ok = WindParams {
        screen: screen(1.0, &DEFAULT_SCALES, 64.0, 64, 1),
        ..WindParams::default()
    };
    let name = |p: &WindParams| match WindLoads::new(&g, p) {
        Err(m1::M1Error::InvalidParameter { name, .. }) => name,
        other => panic!("{:?}", other.map(|_| ())),
    };
    let mut p = ok.clone();
    p.speed = -1.0;
    assert_eq!(name(&p), "wind_speed");
    let mut p = ok.clone();
    p.screen.outer_scales[0].fraction = 0.0;
    p.screen.outer_scales[1].fraction = 0.0;
    assert_eq!(name(&p), "energy_fraction");
    let mut p = ok.clone();
    p.screen.size = 10.0; // narrower than Keck
    assert_eq!(name(&p), "screen_size");
    let mut p = ok.clone();
    p.screen.samples = 63;
    assert_eq!(name(&p), "screen_samples");
    assert!(WindLoads::new(&g, &ok).is_ok());
}

/// Another speed and rms pressure from the same tables is exactly a fresh build, and the loads
/// scale with the rms pressure: twice the pressure, twice every force; zero pressure, none.
#[test]
fn with_flow_is_a_fresh_build() {
    let g = geometry("keck", false);
    let at = |speed: f64, sigma: f64| WindParams {
        speed,
        direction: 20.0,
        screen: screen(sigma, &DEFAULT_SCALES, 32.0, 128, 5),
    };
    let base = WindLoads::new(&g, &at(3.0, 0.05)).unwrap();
    let fresh = WindLoads::new(&g, &at(7.0, 0.2)).unwrap();
    let reused = base.with_flow(7.0, 0.2).unwrap();
    let n = g.layout.n_actuators();
    let (mut a, mut b, mut c) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
    for t in [0.0, 0.37, 2.9] {
        fresh.forces(t, &mut a).unwrap();
        reused.forces(t, &mut b).unwrap();
        assert_eq!(a, b, "t = {t}");
        base.with_flow(7.0, 0.4).unwrap().forces(t, &mut c).unwrap();
        for (x, y) in a.iter().zip(&c) {
            assert!((2.0 * x - y).abs() <= 1e-15 * y.abs().max(1e-30), "{x} {y}");
        }
        assert_eq!(fresh.integrals(3, t), reused.integrals(3, t));
        base.with_flow(7.0, 0.0).unwrap().forces(t, &mut c).unwrap();
        assert!(c.iter().all(|&x| x == 0.0));
    }
    assert_eq!(fresh.expected_force_rms(), reused.expected_force_rms());
    assert_eq!(fresh.period(), reused.period());
    assert!(base.with_flow(-1.0, 0.1).is_err());
    assert!(base.with_flow(1.0, f64::NAN).is_err());
}
