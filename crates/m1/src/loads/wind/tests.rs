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

/// The separable grid form agrees with the direct formula at every bin of a TMT-sized screen's
/// wavenumbers (a sparse sample of them), to rounding in the phases: the phases reach a few
/// hundred radians, so the agreement is 1e-13 relative to the largest value, not 1e-16.
#[test]
fn polygon_grid_matches_the_direct_transform() {
    let poly = hexagon(0.72, 17.0);
    let shifted: Vec<[f64; 2]> = poly.iter().map(|v| [v[0] + 11.3, v[1] - 7.9]).collect();
    let n = 1024;
    let dk = 1.0 / 128.0;
    let k: Vec<f64> = (0..n).map(|i| spectrum::signed(i, n) as f64 * dk).collect();
    for (p, symmetric) in [(&poly, true), (&shifted, false)] {
        let grid = PolygonGrid::new(p, &k, &k);
        assert_eq!(
            grid.symmetric, symmetric,
            "the centred hexagon takes the symmetric path"
        );
        let scale = polygon_transform(p, [0.0, 0.0])
            .iter()
            .map(|c| c.norm())
            .fold(0.0, f64::max);
        let mut worst: f64 = 0.0;
        for iy in (0..n).step_by(7) {
            for ix in (0..n).step_by(5) {
                let a = grid.at(ix, iy);
                let b = polygon_transform(p, [k[ix], k[iy]]);
                for (x, y) in a.iter().zip(&b) {
                    worst = worst.max((x - y).norm() / scale);
                }
            }
        }
        assert!(worst < 1e-12, "{worst:e}");
        assert_eq!(grid.at(0, 0), polygon_transform(p, [0.0, 0.0]));
    }
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

/// Two spectra through one packed transform, at some rows only, are the real parts of their
/// full inverse 2-D FFTs at those rows, on a grid small enough to see every index pairing
/// (`n` even, with the Nyquist row and column, and odd).
#[test]
fn packed_transforms_at_some_rows_are_the_full_transforms_real_parts() {
    for n in [16, 15] {
        let draw = |seed: f64| -> Vec<Complex64> {
            (0..n * n)
                .map(|i| {
                    let x = i as f64 + seed;
                    Complex64::new((1.3 * x).sin(), (0.7 * x + 0.2).cos())
                })
                .collect()
        };
        let (a, b) = (draw(0.0), draw(5.5));
        let rows = [0, 3, 7, n - 1];
        let packed = spectrum::real_inverse_fft_rows(&a, Some(&b), n, &rows);
        let single = spectrum::real_inverse_fft_rows(&a, None, n, &rows);
        let (mut fa, mut fb) = (a.clone(), b.clone());
        spectrum::inverse_fft_2d(&mut fa, n);
        spectrum::inverse_fft_2d(&mut fb, n);
        let scale = fa.iter().map(|c| c.norm()).fold(0.0, f64::max);
        assert_eq!(
            (packed.len(), single.len()),
            (rows.len() * n, rows.len() * n)
        );
        for (k, &r) in rows.iter().enumerate() {
            for x in 0..n {
                let (i, o) = (r * n + x, k * n + x);
                assert!(
                    (packed[o].re - fa[i].re).abs() < 1e-13 * scale,
                    "n {n} ({r}, {x})"
                );
                assert!(
                    (packed[o].im - fb[i].re).abs() < 1e-13 * scale,
                    "n {n} ({r}, {x})"
                );
                assert!(
                    (single[o].re - fa[i].re).abs() < 1e-13 * scale,
                    "n {n} ({r}, {x})"
                );
            }
        }
    }
}
