//! Exact integrals of a trigonometric screen over a polygon (the segment's hexagon) and the
//! equivalent forces at the actuators.

use super::*;

/// `sin(u) / u` and its derivative, by series near 0.
pub(super) fn sinc_and_derivative(u: f64) -> (f64, f64) {
    if u.abs() < 1e-3 {
        sinc_series(u)
    } else {
        let (s, c) = u.sin_cos();
        (s / u, (c - s / u) / u)
    }
}

/// `sin(u) / u` and its derivative near 0 (`|u| < 1e-3`), by their series.
fn sinc_series(u: f64) -> (f64, f64) {
    let u2 = u * u;
    (
        1.0 - u2 / 6.0 + u2 * u2 / 120.0,
        u * (-1.0 / 3.0 + u2 / 30.0),
    )
}

/// [`polygon_transform`] on a grid of wavenumbers `(kx[ix], ky[iy])`, for one polygon. The
/// phases of [`polygon_transform`] are separable: `exp(i q.r) = exp(i q_x x) exp(i q_y y)` for
/// the edges' midpoints and half-lengths, so one table per edge and axis (`O(n)` sines and
/// cosines) replaces the two `sin_cos` per edge and bin of the direct formula; each bin then
/// costs a few complex products per edge. A centrally symmetric polygon (the regular hexagon
/// about its centre: vertex `j + n/2` is vertex `j` negated) has real `H` and imaginary moment
/// transforms, its opposite edges' terms pair into the sines or cosines of one phase, and only
/// half the edges are visited, in real arithmetic. Agrees with [`polygon_transform`] to
/// rounding.
pub struct PolygonGrid {
    edges: Vec<Edge>,
    /// Centrally symmetric about the origin (to 1e-12 of its size): only the first half of
    /// `edges` is visited.
    pub(super) symmetric: bool,
    kx: Vec<f64>,
    ky: Vec<f64>,
    moments: [Complex64; 3],
}

/// One edge of a [`PolygonGrid`]: its vector, midpoint and normal times length, and the phase
/// tables `exp(i q_x m_x)`, `exp(i q_y m_y)`, `exp(i q_x e_x / 2)`, `exp(i q_y e_y / 2)`.
struct Edge {
    e: [f64; 2],
    m: [f64; 2],
    nn: [f64; 2],
    mid_x: Vec<Complex64>,
    mid_y: Vec<Complex64>,
    half_x: Vec<Complex64>,
    half_y: Vec<Complex64>,
}

impl PolygonGrid {
    /// The tables for `vertices` (counter-clockwise) on the wavenumbers `kx` x `ky`
    /// (cycles/m).
    pub fn new(vertices: &[[f64; 2]], kx: &[f64], ky: &[f64]) -> Self {
        let n = vertices.len();
        let table = |k: &[f64], x: f64| -> Vec<Complex64> {
            k.iter().map(|&k| Complex64::cis(TAU * k * x)).collect()
        };
        let edges = (0..n)
            .map(|j| {
                let a = vertices[j];
                let b = vertices[(j + 1) % n];
                let e = [b[0] - a[0], b[1] - a[1]];
                let m = [(a[0] + b[0]) / 2.0, (a[1] + b[1]) / 2.0];
                Edge {
                    e,
                    m,
                    nn: [e[1], -e[0]],
                    mid_x: table(kx, m[0]),
                    mid_y: table(ky, m[1]),
                    half_x: table(kx, e[0] / 2.0),
                    half_y: table(ky, e[1] / 2.0),
                }
            })
            .collect();
        let (a, mo) = polygon_moments(vertices);
        let scale = vertices
            .iter()
            .map(|v| v[0].abs().max(v[1].abs()))
            .fold(0.0, f64::max);
        let symmetric = n.is_multiple_of(2)
            && (0..n / 2).all(|j| {
                let (p, q) = (vertices[j], vertices[j + n / 2]);
                (p[0] + q[0]).abs() <= 1e-12 * scale && (p[1] + q[1]).abs() <= 1e-12 * scale
            });
        Self {
            edges,
            symmetric,
            kx: kx.to_vec(),
            ky: ky.to_vec(),
            moments: [a.into(), mo[0].into(), mo[1].into()],
        }
    }

    /// [`polygon_transform`] at `(kx[ix], ky[iy])`.
    pub fn at(&self, ix: usize, iy: usize) -> [Complex64; 3] {
        let q = [TAU * self.kx[ix], TAU * self.ky[iy]];
        let q2 = q[0] * q[0] + q[1] * q[1];
        if q2 == 0.0 {
            return self.moments;
        }
        if self.symmetric {
            return self.at_symmetric(ix, iy, q, q2);
        }
        let mut s = Complex64::ZERO;
        let mut ds = [Complex64::ZERO; 2];
        for ed in &self.edges {
            let qn = q[0] * ed.nn[0] + q[1] * ed.nn[1];
            let u = (q[0] * ed.e[0] + q[1] * ed.e[1]) / 2.0;
            let (sc, dsc) = if u.abs() < 1e-3 {
                sinc_series(u)
            } else {
                let cs = ed.half_x[ix] * ed.half_y[iy];
                (cs.im / u, (cs.re - cs.im / u) / u)
            };
            let ph = ed.mid_x[ix] * ed.mid_y[iy];
            s += ph * (qn * sc);
            for (c, d) in ds.iter_mut().enumerate() {
                *d += ph
                    * Complex64::new(ed.nn[c] * sc + qn * dsc * ed.e[c] / 2.0, qn * sc * ed.m[c]);
            }
        }
        let h = Complex64::new(0.0, -1.0) * s / q2;
        let moment = |c: usize| -ds[c] / q2 + s * (2.0 * q[c] / (q2 * q2));
        [h, moment(0), moment(1)]
    }

    /// [`Self::at`] for a centrally symmetric polygon. Edge `j + n/2` has `-e`, `-m`, `-N`:
    /// with `ph = exp(i q.m)`, the pair contributes `2 i qn sinc Im(ph)` to the sum `s` and
    /// `2 i (A_c Im(ph) + B_c Re(ph))` to its derivatives (`A_c = N_c sinc + qn sinc' e_c / 2`,
    /// `B_c = qn sinc m_c`), so `s = i S`, `ds_c = i D_c` with `S`, `D_c` real.
    fn at_symmetric(&self, ix: usize, iy: usize, q: [f64; 2], q2: f64) -> [Complex64; 3] {
        let (mut s, mut d0, mut d1) = (0.0, 0.0, 0.0);
        for ed in &self.edges[..self.edges.len() / 2] {
            let qn = q[0] * ed.nn[0] + q[1] * ed.nn[1];
            let u = (q[0] * ed.e[0] + q[1] * ed.e[1]) / 2.0;
            let (sc, dsc) = if u.abs() < 1e-3 {
                sinc_series(u)
            } else {
                let (a, b) = (ed.half_x[ix], ed.half_y[iy]);
                let (re, im) = (a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re);
                let inv = 1.0 / u;
                (im * inv, (re - im * inv) * inv)
            };
            let (a, b) = (ed.mid_x[ix], ed.mid_y[iy]);
            let (re, im) = (a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re);
            let qs = qn * sc;
            s += qs * im;
            let half = qn * dsc / 2.0;
            d0 += (ed.nn[0] * sc + half * ed.e[0]) * im + qs * ed.m[0] * re;
            d1 += (ed.nn[1] * sc + half * ed.e[1]) * im + qs * ed.m[1] * re;
        }
        let (s, d) = (2.0 * s, [2.0 * d0, 2.0 * d1]);
        let moment = |c: usize| Complex64::new(0.0, -d[c] / q2 + s * (2.0 * q[c] / (q2 * q2)));
        [Complex64::new(s / q2, 0.0), moment(0), moment(1)]
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
