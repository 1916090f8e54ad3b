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
