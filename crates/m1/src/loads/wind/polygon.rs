//! Exact integrals of a trigonometric screen over a polygon (the segment's hexagon) and the
//! equivalent forces at the actuators.

use super::*;

/// `sin(u) / u` and its derivative, by series near 0.
pub(super) fn sinc_and_derivative(u: f64) -> (f64, f64) {
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
