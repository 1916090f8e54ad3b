//! Tests of the optical metrics (`m1::optics::metrics`): identities and closed forms.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::optics::metrics::{
    MirrorMetrics, actuators_to_ptt, hexagon_area, hexagon_second_moment, ptt_to_actuators,
};
use m1::sensing::interaction::global_ptt;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

fn geometry(layout: &Layout) -> Geometry {
    Geometry::new(layout, GeometryParams::for_layout(layout)).unwrap()
}

/// Keck with its own focus-mode (fast to build).
fn keck() -> (Geometry, MirrorMetrics) {
    let g = geometry(&Layout::keck());
    let m = MirrorMetrics::new(&g).unwrap();
    (g, m)
}

fn random_z(n: usize, seed: u64, scale: f64) -> Vec<f64> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|_| scale * rng.random_range(-1.0..1.0))
        .collect()
}

/// Closed form: rms^2 after removing the global plane from the state `ptt`, with the Gram matrix
/// written out independently of the library (centroid-centred coordinates).
fn closed_form_rms(layout: &Layout, ptt: &[[f64; 3]]) -> f64 {
    let n = layout.n_segments() as f64;
    let a = layout.circumradius;
    let area = 1.5 * 3f64.sqrt() * a * a;
    let moment = 5.0 * 3f64.sqrt() / 16.0 * a.powi(4);
    let cx0 = layout.segments.iter().map(|s| s.center[0]).sum::<f64>() / n;
    let cy0 = layout.segments.iter().map(|s| s.center[1]).sum::<f64>() / n;
    let c: Vec<[f64; 2]> = layout
        .segments
        .iter()
        .map(|s| [s.center[0] - cx0, s.center[1] - cy0])
        .collect();
    let mut g = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    let mut ss = 0.0;
    for (ci, s) in c.iter().zip(ptt) {
        let basis = [[1.0, 0.0, 0.0], [ci[0], 1.0, 0.0], [ci[1], 0.0, 1.0]];
        for r in 0..3 {
            for k in 0..3 {
                let u = basis[r];
                let v = basis[k];
                g[(r, k)] += area * u[0] * v[0] + moment * (u[1] * v[1] + u[2] * v[2]);
            }
            let u = basis[r];
            b[r] += area * u[0] * s[0] + moment * (u[1] * s[1] + u[2] * s[2]);
        }
        ss += area * s[0] * s[0] + moment * (s[1] * s[1] + s[2] * s[2]);
    }
    let beta = g.try_inverse().unwrap() * b;
    ((ss - b.dot(&beta)) / (n * area)).sqrt()
}

#[test]
fn hexagon_moments_match_closed_forms() {
    // Area 3 sqrt(3)/2 a^2 and I = 5 sqrt(3)/16 a^4 against a midpoint rule on a fine grid
    // (the boundary cells limit it to about 1e-3).
    let a = 0.72;
    let n = 2000;
    let h = 2.0 * a / n as f64;
    let apothem = 0.5 * 3f64.sqrt() * a;
    let (mut area, mut ixx, mut iyy) = (0.0, 0.0, 0.0);
    for iy in 0..n {
        let y = -a + (iy as f64 + 0.5) * h;
        for ix in 0..n {
            let x = -a + (ix as f64 + 0.5) * h;
            let inside = (0..3).all(|k| {
                let t = (60.0 * k as f64).to_radians();
                (x * t.cos() + y * t.sin()).abs() <= apothem
            });
            if inside {
                area += h * h;
                ixx += h * h * x * x;
                iyy += h * h * y * y;
            }
        }
    }
    assert!((area / hexagon_area(a) - 1.0).abs() < 2e-3, "area {area}");
    let i = hexagon_second_moment(a);
    assert!((ixx / i - 1.0).abs() < 3e-3, "Ixx {ixx} vs {i}");
    assert!((iyy / i - 1.0).abs() < 3e-3, "Iyy {iyy} vs {i}");
}

#[test]
fn global_plane_gives_zero_rms() {
    for name in ["keck", "tmt"] {
        let layout = Layout::preset(name).unwrap();
        let g = geometry(&layout);
        // Focus-mode from a cheap stand-in (the metric of a plane does not depend on it).
        let focus: Vec<f64> = (0..g.n_actuators())
            .map(|k| {
                let f = &g.segments[k / 3];
                let a = f.actuators[k % 3];
                a[0] * a[0] + a[1] * a[1]
            })
            .collect();
        let m = MirrorMetrics::with_focus(&g, &focus).unwrap();
        let (p, tx, ty) = (3e-6, 2e-7, -5e-7);
        let z: Vec<f64> = (0..g.n_actuators())
            .map(|k| {
                let a = g.segments[k / 3].actuators[k % 3];
                p + tx * a[0] + ty * a[1]
            })
            .collect();
        let scale = z.iter().map(|x| x * x).sum::<f64>().sqrt() / (z.len() as f64).sqrt();
        let r = m.evaluate(&z).unwrap();
        assert!(
            r.rms <= 1e-15 * scale,
            "{name}: rms {} for scale {scale}",
            r.rms
        );
        // The focus amplitude carries the round-off of <s, F> over all segments.
        let focus_rms = r.focus.abs() * m.focus_rms_per_unit();
        assert!(focus_rms <= 1e-14 * scale, "{name}: {r:?}");
        assert!(r.rms_without_focus <= 1e-14 * scale, "{name}: {r:?}");
        let c = m.centroid();
        let expected = [p + tx * c[0] + ty * c[1], tx, ty];
        for k in 0..3 {
            assert!(
                (r.global_ptt[k] - expected[k]).abs() <= 1e-12 * expected[k].abs(),
                "{name}: global {:?} vs {expected:?}",
                r.global_ptt
            );
        }
    }
}

#[test]
fn rigid_rotation_of_a_flat_mirror_gives_zero_rms() {
    // The 3-D rigid-body piston/tip/tilt of interaction::global_ptt is exactly an aperture plane
    // on a flat mirror.
    let layout = Layout::keck();
    let mut params = GeometryParams::for_layout(&layout);
    params.flat = true;
    let g = Geometry::new(&layout, params).unwrap();
    let m = MirrorMetrics::new(&g).unwrap();
    let modes = global_ptt(&g);
    for col in 0..3 {
        let z: Vec<f64> = (0..g.n_actuators())
            .map(|r| 1e-6 * modes[(r, col)])
            .collect();
        let r = m.evaluate(&z).unwrap();
        assert!(r.rms <= 1e-15 * 1e-6, "mode {col}: {r:?}");
        assert!(r.focus.abs() <= 1e-15 * 1e-6 * 100.0, "mode {col}: {r:?}");
    }
}

#[test]
fn single_segment_piston_matches_closed_form() {
    for name in ["keck", "tmt"] {
        let layout = Layout::preset(name).unwrap();
        let g = geometry(&layout);
        let m = MirrorMetrics::with_focus(&g, &vec![1.0; g.n_actuators()])
            .map(|_| ())
            .err();
        // A uniform vector is global piston: rejected as a focus-mode.
        assert!(m.is_some(), "{name}: a piston focus-mode must be rejected");
        let focus: Vec<f64> = (0..g.n_actuators())
            .map(|k| {
                let a = g.segments[k / 3].actuators[k % 3];
                a[0] * a[0] + a[1] * a[1]
            })
            .collect();
        let m = MirrorMetrics::with_focus(&g, &focus).unwrap();
        let n = layout.n_segments();
        let p = 10e-9;
        for j in [0, n / 3, n - 1] {
            let mut z = vec![0.0; g.n_actuators()];
            z[3 * j..3 * j + 3].fill(p);
            let r = m.evaluate(&z).unwrap();
            let mut ptt = vec![[0.0; 3]; n];
            ptt[j][0] = p;
            let expected = closed_form_rms(&layout, &ptt);
            assert!(
                (r.rms / expected - 1.0).abs() < 1e-10,
                "{name} segment {j}: rms {} expected {expected}",
                r.rms
            );
            // Explicit expression for a 6-fold symmetric layout (diagonal Gram matrix):
            // rms^2 = p^2/N [1 - 1/N - A cx^2/(A sum cx^2 + N I) - A cy^2/(A sum cy^2 + N I)].
            let a = hexagon_area(layout.circumradius);
            let i = hexagon_second_moment(layout.circumradius);
            let c = layout.segments[j].center;
            let sx: f64 = layout.segments.iter().map(|s| s.center[0].powi(2)).sum();
            let sy: f64 = layout.segments.iter().map(|s| s.center[1].powi(2)).sum();
            let nf = n as f64;
            let explicit = p
                * ((1.0
                    - 1.0 / nf
                    - a * c[0] * c[0] / (a * sx + nf * i)
                    - a * c[1] * c[1] / (a * sy + nf * i))
                    / nf)
                    .sqrt();
            assert!(
                (r.rms / explicit - 1.0).abs() < 1e-9,
                "{name} segment {j}: rms {} explicit {explicit}",
                r.rms
            );
            // Global tip/tilt removal only lowers the piston-only value p sqrt(N - 1) / N.
            let piston_only = p * ((nf - 1.0) / (nf * nf)).sqrt();
            assert!(r.rms < piston_only && r.rms > 0.9 * piston_only);
        }
    }
}

#[test]
fn single_segment_tilt_gives_hexagon_rms() {
    let layout = Layout::tmt();
    let g = geometry(&layout);
    let focus: Vec<f64> = (0..g.n_actuators())
        .map(|k| {
            let a = g.segments[k / 3].actuators[k % 3];
            a[0] * a[0] + a[1] * a[1]
        })
        .collect();
    let m = MirrorMetrics::with_focus(&g, &focus).unwrap();
    let n = layout.n_segments();
    let t = 1e-7; // rad, surface slope
    let j = 100;
    for axis in 0..2 {
        let mut ptt = vec![[0.0; 3]; n];
        ptt[j][1 + axis] = t;
        let z = ptt_to_actuators(&g, &ptt).unwrap();
        let r = m.evaluate(&z).unwrap();
        // The tilted hexagon alone: rms over it = t sqrt(I/A) = t a sqrt(5/24); over the
        // aperture the mean square is divided by N, less the global tilt it carries.
        let a = layout.circumradius;
        let hex_rms = t * a * (5.0_f64 / 24.0).sqrt();
        let expected = closed_form_rms(&layout, &ptt);
        assert!(
            (r.rms / expected - 1.0).abs() < 1e-10,
            "{r:?} vs {expected}"
        );
        let no_global = hex_rms / (n as f64).sqrt();
        assert!(
            r.rms < no_global && r.rms > 0.99 * no_global,
            "{} vs {no_global}",
            r.rms
        );
    }
}

#[test]
fn matches_dense_least_squares_on_sampled_hexagons() {
    // Independent computation: sample every hexagon on a fine grid, fit the global plane by
    // least squares over the samples, rms of the residual.
    let (g, m) = keck();
    let layout = &g.layout;
    let z = random_z(g.n_actuators(), 7, 50e-9);
    let ptt = actuators_to_ptt(&g, &z).unwrap();
    let a = layout.circumradius;
    let apothem = 0.5 * 3f64.sqrt() * a;
    let k = 120;
    let h = 2.0 * a / k as f64;
    let mut pts: Vec<(f64, f64, f64)> = Vec::new();
    for (s, st) in layout.segments.iter().zip(&ptt) {
        for iy in 0..k {
            let dy = -a + (iy as f64 + 0.5) * h;
            for ix in 0..k {
                let dx = -a + (ix as f64 + 0.5) * h;
                let inside = (0..3).all(|q| {
                    let t = (60.0 * q as f64).to_radians();
                    (dx * t.cos() + dy * t.sin()).abs() <= apothem
                });
                if inside {
                    let v = st[0] + st[1] * dx + st[2] * dy;
                    pts.push((s.center[0] + dx, s.center[1] + dy, v));
                }
            }
        }
    }
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = nalgebra::Vector3::<f64>::zeros();
    for &(x, y, v) in &pts {
        let row = nalgebra::Vector3::new(1.0, x, y);
        ata += row * row.transpose();
        atb += row * v;
    }
    let beta = ata.try_inverse().unwrap() * atb;
    let ms = pts
        .iter()
        .map(|&(x, y, v)| (v - beta[0] - beta[1] * x - beta[2] * y).powi(2))
        .sum::<f64>()
        / pts.len() as f64;
    let r = m.evaluate(&z).unwrap();
    assert!(
        (r.rms / ms.sqrt() - 1.0).abs() < 2e-3,
        "metric {} sampled {}",
        r.rms,
        ms.sqrt()
    );
}

#[test]
fn focus_mode_has_unit_amplitude_and_nothing_else() {
    let (g, m) = keck();
    let f = m.focus_mode().to_vec();
    let r = m.evaluate(&f).unwrap();
    assert!((r.focus - 1.0).abs() < 1e-12, "{r:?}");
    assert!(r.rms_without_focus <= 1e-14 * r.rms, "{r:?}");
    assert!((r.rms / m.focus_rms_per_unit() - 1.0).abs() < 1e-12);
    // Focus-mode plus a global plane: the same amplitude.
    let plane: Vec<f64> = (0..g.n_actuators())
        .map(|k| {
            let a = g.segments[k / 3].actuators[k % 3];
            1e-6 + 1e-7 * a[0] - 3e-7 * a[1]
        })
        .collect();
    let z: Vec<f64> = f.iter().zip(&plane).map(|(a, b)| 2e-9 * a + b).collect();
    let r = m.evaluate(&z).unwrap();
    assert!((r.focus / 2e-9 - 1.0).abs() < 1e-8, "{r:?}");
    assert!(r.rms_without_focus <= 1e-6 * r.rms, "{r:?}");
}

#[test]
fn metrics_are_linear_and_scale() {
    let (_, m) = keck();
    let z1 = random_z(m.n_actuators(), 1, 30e-9);
    let z2 = random_z(m.n_actuators(), 2, 30e-9);
    let r1 = m.evaluate(&z1).unwrap();
    let r2 = m.evaluate(&z2).unwrap();
    for s in [-3.0, 0.5, 1e3] {
        let zs: Vec<f64> = z1.iter().map(|x| s * x).collect();
        let rs = m.evaluate(&zs).unwrap();
        assert!((rs.rms / (s.abs() * r1.rms) - 1.0).abs() < 1e-12);
        assert!((rs.rms_without_focus / (s.abs() * r1.rms_without_focus) - 1.0).abs() < 1e-12);
        assert!((rs.focus - s * r1.focus).abs() <= 1e-12 * (s * r1.focus).abs());
    }
    let sum: Vec<f64> = z1.iter().zip(&z2).map(|(a, b)| a + b).collect();
    let rsum = m.evaluate(&sum).unwrap();
    assert!((rsum.focus - (r1.focus + r2.focus)).abs() <= 1e-12 * r1.focus.abs().max(1e-9));
    // The residual states add up.
    let n = m.n_segments();
    let (mut a, mut b, mut c) = (vec![[0.0; 3]; n], vec![[0.0; 3]; n], vec![[0.0; 3]; n]);
    m.residual_ptt(&z1, &mut a).unwrap();
    m.residual_ptt(&z2, &mut b).unwrap();
    m.residual_ptt(&sum, &mut c).unwrap();
    for i in 0..n {
        for k in 0..3 {
            assert!((c[i][k] - a[i][k] - b[i][k]).abs() <= 1e-12 * 1e-6);
        }
    }
    // Pythagoras: rms^2 = rms_without_focus^2 + (focus * focus_rms_per_unit)^2.
    let lhs = r1.rms.powi(2);
    let rhs = r1.rms_without_focus.powi(2) + (r1.focus * m.focus_rms_per_unit()).powi(2);
    assert!((lhs / rhs - 1.0).abs() < 1e-10);
    // The same with the surface figure itself, signed as the coefficient.
    let rhs = r1.rms_without_focus.powi(2) + r1.focus_rms.powi(2);
    assert!((lhs / rhs - 1.0).abs() < 1e-10);
    assert_eq!(r1.focus_rms.signum(), r1.focus.signum());
}

#[test]
fn issue_14_focus_rms_is_the_surface_of_the_focus_component() {
    // Independent reference: the rms surface of c f (global plane removed) is evaluated as a
    // whole mirror state, and must equal |focus_rms| of c f plus anything orthogonal.
    let (_, m) = keck();
    let f = m.focus_mode().to_vec();
    for c in [3e-9, -7e-9] {
        let z: Vec<f64> = f.iter().map(|x| c * x).collect();
        let r = m.evaluate(&z).unwrap();
        assert!(
            (r.focus_rms / (c.signum() * r.rms) - 1.0).abs() < 1e-12,
            "{r:?}"
        );
        // The coefficient is an actuator-space amplitude, larger than the surface by
        // 1 / focus_rms_per_unit (sqrt(na / 3) for a smooth mode, about 8 on Keck's 108).
        let ratio = r.focus / r.focus_rms;
        assert!(ratio > 3.0 && ratio < 12.0, "coefficient / surface {ratio}");
    }
}

#[test]
fn wrong_sizes_are_errors() {
    let (_, m) = keck();
    assert!(m.evaluate(&[0.0; 5]).is_err());
    let mut out = vec![[0.0; 3]; 3];
    assert!(
        m.residual_ptt(&vec![0.0; m.n_actuators()], &mut out)
            .is_err()
    );
}

/// Random states over every segment of TMT (492) and Keck (36) against the closed form with
/// its Gram matrix written out here, and the split of the rms between focus-mode and the rest.
/// (With eight lanes both have segments after the last whole vector; the evaluation on every
/// instruction set is checked against scalar passes in the crate's own tests.)
#[test]
fn random_states_match_the_closed_form_on_every_segment() {
    for (layout, seed) in [(Layout::tmt(), 11), (Layout::keck(), 12)] {
        let g = geometry(&layout);
        let m = MirrorMetrics::new(&g).unwrap();
        for k in 0..3 {
            let z = random_z(g.n_actuators(), seed + 100 * k, 40e-9);
            let r = m.evaluate(&z).unwrap();
            let ptt = actuators_to_ptt(&g, &z).unwrap();
            let expected = closed_form_rms(&layout, &ptt);
            assert!(
                (r.rms / expected - 1.0).abs() < 1e-10,
                "{}: rms {} expected {expected}",
                layout.name,
                r.rms
            );
            let split = (r.rms_without_focus.powi(2) + r.focus_rms.powi(2)).sqrt();
            assert!(
                (split / r.rms - 1.0).abs() < 1e-10,
                "{}: {r:?}",
                layout.name
            );
        }
    }
}
