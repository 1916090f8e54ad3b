//! Zernike polynomials in Noll's ordering and their projection onto the piston, tip and tilt of
//! the segments of a [`Layout`].
//!
//! # Polynomials
//!
//! Noll's mode `j = 1, 2, ...` has radial degree `n` and azimuthal order `m` (see
//! [`noll_to_nm`]); with `k = (n - |m|) / 2`,
//!
//! $$Z_j(\rho, \theta) = N_{nm} R_n^{|m|}(\rho) \begin{cases} \cos m\theta & m > 0 \\
//! 1 & m = 0 \\ \sin |m|\theta & m < 0 \end{cases}, \qquad
//! N_{nm} = \sqrt{(2 - \delta_{m0})(n + 1)},$$
//!
//! normalised to unit rms over the unit disk: $\frac{1}{\pi}\int_{\rho \le 1} Z_i Z_j\,dA =
//! \delta_{ij}$. Even `j` carry the cosines, odd `j` the sines. The radial polynomial is evaluated
//! through the Jacobi polynomial $R_n^{m}(\rho) = (-1)^k \rho^m P_k^{(m,0)}(1 - 2\rho^2)$ with
//! its three-term recurrence, which is stable on the whole disk (no factorial sums and no
//! cancellation; within 1e-12 of the exact polynomial up to radial degree 24, tested). The polynomials are evaluated as
//! they are outside the unit disk too (no masking).
//!
//! In Cartesian form, with $u + iv = (x + iy)/R$ and $s = u^2 + v^2$,
//! $Z_j = N_{nm} Q_k(s) H_m(u, v)$ where $Q_k(s) = (-1)^k P_k^{(|m|,0)}(1 - 2s)$ and
//! $H_m = \mathrm{Re}\,(u + iv)^{|m|}$ or $\mathrm{Im}\,(u + iv)^{|m|}$: this is how
//! [`zernike_grad`] differentiates without a singularity at the centre.
//!
//! # Segment projection
//!
//! The common currency of segment states in this crate is a slice `&[[f64; 3]]` holding, for
//! every segment `i` of the layout in order, `[p, tx, ty]`: piston `p` (m) and the surface
//! slopes `tx = dz/dx`, `ty = dz/dy` (rad), i.e. the surface error inside hexagon `i` is
//! `z_i(x, y) = p + tx (x - cx_i) + ty (y - cy_i)` about the segment centre `c_i`.
//!
//! [`ZernikeBasis`] projects each mode onto that space by least squares within each hexagon
//! (circumradius `a`, the gap excluded). A regular hexagon is centrally symmetric, so the normal
//! equations are diagonal:
//!
//! $$p = \frac{1}{A}\int_{hex} Z\,dA, \quad t_x = \frac{1}{I}\int_{hex} Z\,(x - c_x)\,dA,
//! \quad t_y = \frac{1}{I}\int_{hex} Z\,(y - c_y)\,dA,$$
//!
//! with area $A = \frac{3\sqrt3}{2}a^2$ and second moment $I = \frac{5\sqrt3}{16}a^4$
//! ($I/A = 5a^2/24$). **Quadrature**: the integrands are polynomials of degree `n_max + 1`,
//! integrated exactly (to round-off) by [`hexagon_rule`]: Gauss–Legendre product rules on the
//! hexagon's central rectangle and on its two end triangles (collapsed towards their apex),
//! about `3 (n_max / 2 + 1)^2` points per hexagon (385 for radial degree 20).
//!
//! Coefficients of a segment state ([`ZernikeBasis::fit`]) are the least-squares fit of the
//! projected modes to the state in the surface metric of the segmented aperture,
//! $\|z\|^2 = \sum_i \int_{hex_i} z_i^2\,dA = \sum_i A p_i^2 + I (t_{x,i}^2 + t_{y,i}^2)$; the
//! projected modes are not orthogonal there, so the fit is a (weighted) pseudo-inverse. A state
//! built from the projected modes is recovered exactly.

use faer::Mat;

use crate::M1Error;
use crate::aperture::layout::Layout;

/// Normalisation radius of the TMT Zernike basis (m): half the 30 m aperture.
pub const TMT_ZERNIKE_RADIUS: f64 = 15.0;

/// Largest radial degree [`ZernikeBasis`] accepts (5151 modes).
pub const MAX_RADIAL_DEGREE: u32 = 100;

/// Radial degree `n` and azimuthal order `m` of Noll's mode `j` (`j >= 1`; `j = 0` is read as
/// 1). `m > 0` for the cosine modes (even `j`), `m < 0` for the sine modes (odd `j`):
/// 1 → (0, 0), 2 → (1, 1), 3 → (1, -1), 4 → (2, 0), 5 → (2, -2), 6 → (2, 2), 11 → (4, 0).
pub fn noll_to_nm(j: usize) -> (u32, i32) {
    let j = j.max(1);
    let mut n = 0_usize;
    while (n + 1) * (n + 2) / 2 < j {
        n += 1;
    }
    // Position of j within row n, from 0.
    let k = j - n * (n + 1) / 2 - 1;
    let abs_m = if n.is_multiple_of(2) {
        2 * k.div_ceil(2)
    } else {
        2 * (k / 2) + 1
    };
    let m = if abs_m == 0 {
        0
    } else if j.is_multiple_of(2) {
        abs_m as i32
    } else {
        -(abs_m as i32)
    };
    (n as u32, m)
}

/// Noll index of the mode of radial degree `n` and azimuthal order `m` (`m > 0` cosine,
/// `m < 0` sine), or `None` if `|m| > n` or `n - |m|` is odd.
pub fn nm_to_noll(n: u32, m: i32) -> Option<usize> {
    let abs_m = m.unsigned_abs();
    if abs_m > n || !(n - abs_m).is_multiple_of(2) {
        return None;
    }
    let n = n as usize;
    let start = n * (n + 1) / 2 + 1;
    if m == 0 {
        return Some(start);
    }
    let abs_m = abs_m as usize;
    // Within the row, |m| sits at positions |m| - 1 and |m|: the even index is the cosine.
    [start + abs_m - 1, start + abs_m]
        .into_iter()
        .find(|j| (j % 2 == 0) == (m > 0))
}

/// Radial degree `n` of Noll's mode `j`.
pub fn radial_degree(j: usize) -> u32 {
    noll_to_nm(j).0
}

/// Number of modes of radial degree up to `n`: `(n + 1)(n + 2) / 2`.
pub fn modes_up_to_degree(n: u32) -> usize {
    let n = n as usize;
    (n + 1) * (n + 2) / 2
}

/// Normalisation factor `sqrt((2 - δ_m0)(n + 1))` for unit rms over the unit disk.
fn norm(n: u32, m: i32) -> f64 {
    let f = f64::from(n + 1);
    if m == 0 { f.sqrt() } else { (2.0 * f).sqrt() }
}

/// Jacobi polynomial `P_k^(alpha, beta)(x)` by its three-term recurrence.
fn jacobi(k: u32, alpha: f64, beta: f64, x: f64) -> f64 {
    let mut prev = 1.0;
    if k == 0 {
        return prev;
    }
    let mut cur = (alpha + 1.0) + 0.5 * (alpha + beta + 2.0) * (x - 1.0);
    for kk in 2..=k {
        let (next, _) = jacobi_step(kk, alpha, beta, x, cur, prev);
        prev = cur;
        cur = next;
    }
    cur
}

/// One step of the Jacobi recurrence: `P_k` from `P_{k-1}` and `P_{k-2}` (`k >= 2`).
#[inline]
fn jacobi_step(k: u32, alpha: f64, beta: f64, x: f64, p1: f64, p2: f64) -> (f64, f64) {
    let k = f64::from(k);
    let s = 2.0 * k + alpha + beta;
    let a = 2.0 * k * (k + alpha + beta) * (s - 2.0);
    let b = (s - 1.0) * (s * (s - 2.0) * x + alpha * alpha - beta * beta);
    let c = 2.0 * (k + alpha - 1.0) * (k + beta - 1.0) * s;
    ((b * p1 - c * p2) / a, p1)
}

/// `(-1)^k`.
fn sign(k: u32) -> f64 {
    if k.is_multiple_of(2) { 1.0 } else { -1.0 }
}

/// Radial polynomial `R_n^m(rho)` (unnormalised, `R_n^m(1) = 1`); zero unless `m <= n` and
/// `n - m` is even.
pub fn zernike_radial(n: u32, m: u32, rho: f64) -> f64 {
    if m > n || !(n - m).is_multiple_of(2) {
        return 0.0;
    }
    let k = (n - m) / 2;
    sign(k) * rho.powi(m as i32) * jacobi(k, f64::from(m), 0.0, 1.0 - 2.0 * rho * rho)
}

/// Noll's Zernike polynomial `Z_j(rho, theta)`, unit rms over the unit disk (`j >= 1`).
pub fn zernike(j: usize, rho: f64, theta: f64) -> f64 {
    let (n, m) = noll_to_nm(j);
    let abs_m = m.unsigned_abs();
    let radial = norm(n, m) * zernike_radial(n, abs_m, rho);
    match m {
        0 => radial,
        m if m > 0 => radial * (f64::from(abs_m) * theta).cos(),
        _ => radial * (f64::from(abs_m) * theta).sin(),
    }
}

/// `Z_j` at the aperture point `(x, y)` (m) for the normalisation radius `r_norm` (m):
/// `Z_j(hypot(x, y) / r_norm, atan2(y, x))`.
pub fn zernike_xy(j: usize, x: f64, y: f64, r_norm: f64) -> f64 {
    zernike(j, x.hypot(y) / r_norm, y.atan2(x))
}

/// `(u + i v)^p` as `(re, im)`.
fn cpow(u: f64, v: f64, p: u32) -> (f64, f64) {
    let (mut re, mut im) = (1.0, 0.0);
    for _ in 0..p {
        (re, im) = (re * u - im * v, re * v + im * u);
    }
    (re, im)
}

/// Gradient `(dZ/dx, dZ/dy)` (1/m) of [`zernike_xy`]`(j, x, y, r_norm)` with respect to the
/// aperture coordinates `(x, y)` (m): the gradient in normalised coordinates divided by
/// `r_norm`. Smooth everywhere, the centre included.
pub fn zernike_grad(j: usize, x: f64, y: f64, r_norm: f64) -> (f64, f64) {
    let (n, m) = noll_to_nm(j);
    let abs_m = m.unsigned_abs();
    let k = (n - abs_m) / 2;
    let (u, v) = (x / r_norm, y / r_norm);
    let s = u * u + v * v;
    let xj = 1.0 - 2.0 * s;
    let alpha = f64::from(abs_m);
    let q = sign(k) * jacobi(k, alpha, 0.0, xj);
    // dQ/ds = (-1)^(k+1) (k + |m| + 1) P_{k-1}^(|m|+1, 1)(1 - 2 s).
    let dq = if k == 0 {
        0.0
    } else {
        -sign(k) * f64::from(k + abs_m + 1) * jacobi(k - 1, alpha + 1.0, 1.0, xj)
    };
    let (h, dh_du, dh_dv) = if abs_m == 0 {
        (1.0, 0.0, 0.0)
    } else {
        let (hr, hi) = cpow(u, v, abs_m);
        let (dr, di) = cpow(u, v, abs_m - 1);
        let mm = alpha;
        if m > 0 {
            (hr, mm * dr, -mm * di)
        } else {
            (hi, mm * di, mm * dr)
        }
    };
    let c = norm(n, m) / r_norm;
    (
        c * (dq * 2.0 * u * h + q * dh_du),
        c * (dq * 2.0 * v * h + q * dh_dv),
    )
}

/// Gauss–Legendre rule of `n` points on `[-1, 1]`: `(nodes, weights)`, nodes ascending.
/// Exact for polynomials of degree `2 n - 1`. Nodes by Newton's method on `P_n`.
pub fn gauss_legendre(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut nodes = vec![0.0; n];
    let mut weights = vec![0.0; n];
    let nf = n as f64;
    for i in 0..n {
        // Initial guess (Tricomi), descending in i.
        let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (nf + 0.5)).cos();
        let mut dp = 1.0;
        for _ in 0..100 {
            let (p, p_prev) = legendre_pair(n, x);
            dp = nf * (x * p - p_prev) / (x * x - 1.0);
            let dx = p / dp;
            x -= dx;
            if dx.abs() <= 1e-16 * x.abs().max(1.0) {
                break;
            }
        }
        let (p, p_prev) = legendre_pair(n, x);
        if p.is_finite() && p_prev.is_finite() {
            dp = nf * (x * p - p_prev) / (x * x - 1.0);
        }
        nodes[n - 1 - i] = x;
        weights[n - 1 - i] = 2.0 / ((1.0 - x * x) * dp * dp);
    }
    (nodes, weights)
}

/// `(P_n(x), P_{n-1}(x))` by Bonnet's recurrence (`n >= 1`).
fn legendre_pair(n: usize, x: f64) -> (f64, f64) {
    let (mut p0, mut p1) = (1.0, x);
    for k in 2..=n {
        let kf = k as f64;
        let p2 = ((2.0 * kf - 1.0) * x * p1 - (kf - 1.0) * p0) / kf;
        p0 = p1;
        p1 = p2;
    }
    (p1, p0)
}

/// Evaluates every mode `1..=n_modes` at once with `O(n_modes)` work: one Jacobi recurrence
/// per azimuthal order.
#[derive(Debug, Clone)]
struct ModeSet {
    n_modes: usize,
    max_n: u32,
    /// `slots[|m|][k]` = 0-based indices of the cosine and sine modes of radial degree
    /// `|m| + 2 k` (`usize::MAX` when absent), with their normalisation.
    slots: Vec<Vec<([usize; 2], f64)>>,
}

impl ModeSet {
    fn new(n_modes: usize) -> ModeSet {
        let max_n = radial_degree(n_modes.max(1));
        let mut slots: Vec<Vec<([usize; 2], f64)>> = (0..=max_n)
            .map(|abs_m| vec![([usize::MAX; 2], 0.0); ((max_n - abs_m) / 2 + 1) as usize])
            .collect();
        for j in 1..=n_modes {
            let (n, m) = noll_to_nm(j);
            let abs_m = m.unsigned_abs();
            let slot = &mut slots[abs_m as usize][((n - abs_m) / 2) as usize];
            slot.0[usize::from(m < 0)] = j - 1;
            slot.1 = norm(n, m);
        }
        ModeSet {
            n_modes,
            max_n,
            slots,
        }
    }

    /// `out[j - 1] = Z_j(u, v)` for `j = 1..=n_modes`, `(u, v)` in normalised coordinates.
    fn eval(&self, u: f64, v: f64, out: &mut [f64]) {
        let x = 1.0 - 2.0 * (u * u + v * v);
        let (mut hr, mut hi) = (1.0, 0.0);
        for (abs_m, row) in self.slots.iter().enumerate() {
            if abs_m > 0 {
                (hr, hi) = (hr * u - hi * v, hr * v + hi * u);
            }
            let alpha = abs_m as f64;
            let (mut p2, mut p1) = (0.0, 1.0);
            for (k, &([ic, is], nrm)) in row.iter().enumerate() {
                let p = match k {
                    0 => 1.0,
                    1 => (alpha + 1.0) + 0.5 * (alpha + 2.0) * (x - 1.0),
                    _ => jacobi_step(k as u32, alpha, 0.0, x, p1, p2).0,
                };
                if k > 0 {
                    p2 = p1;
                    p1 = p;
                }
                let radial = nrm * sign(k as u32) * p;
                if ic != usize::MAX {
                    out[ic] = radial * hr;
                }
                if is != usize::MAX {
                    out[is] = radial * hi;
                }
            }
        }
    }
}

/// Zernike modes projected onto the piston, tip and tilt of every segment of a layout (see the
/// [module documentation](self) for the conventions, the projection and the quadrature).
#[derive(Debug, Clone)]
pub struct ZernikeBasis {
    radius: f64,
    circumradius: f64,
    modes: ModeSet,
    /// `3N x n_modes`: column `j - 1` holds `[p, tx, ty]` of every segment for a unit
    /// coefficient (1 m rms over the disk of radius `radius`) of `Z_j`.
    matrix: Mat<f64>,
    /// `n_modes x 3N`: the weighted least-squares fit, `(M^T W M)^-1 M^T W`.
    fit_matrix: Mat<f64>,
    /// Singular values of `W^(1/2) M`, descending.
    singular_values: Vec<f64>,
}

impl ZernikeBasis {
    /// Default normalisation radius of `layout` (m): [`TMT_ZERNIKE_RADIUS`] (15 m) for the layout
    /// named `tmt` (case-insensitive), else the largest centre radius plus the circumradius.
    pub fn default_radius(layout: &Layout) -> f64 {
        if layout.name.trim().eq_ignore_ascii_case("tmt") {
            return TMT_ZERNIKE_RADIUS;
        }
        let rmax = layout
            .segments
            .iter()
            .map(|s| s.center[0].hypot(s.center[1]))
            .fold(0.0, f64::max);
        rmax + layout.circumradius
    }

    /// Modes `Z_1..Z_n_modes` on `layout`, with the [default radius](Self::default_radius).
    pub fn new(layout: &Layout, n_modes: usize) -> Result<ZernikeBasis, M1Error> {
        Self::with_radius(layout, n_modes, Self::default_radius(layout))
    }

    /// All the modes of radial degree up to `max_degree` on `layout`, default radius.
    pub fn up_to_degree(layout: &Layout, max_degree: u32) -> Result<ZernikeBasis, M1Error> {
        if max_degree > MAX_RADIAL_DEGREE {
            return Err(M1Error::InvalidParameter {
                name: "max_degree",
                value: f64::from(max_degree),
                reason: "the radial degree is limited to MAX_RADIAL_DEGREE",
            });
        }
        Self::new(layout, modes_up_to_degree(max_degree))
    }

    /// Modes `Z_1..Z_n_modes` on `layout` normalised over a disk of radius `radius` (m).
    ///
    /// Fails if `n_modes` is 0, beyond radial degree [`MAX_RADIAL_DEGREE`] or more than the `3N`
    /// segment degrees of freedom, if `radius` is not finite and positive, or if the projected
    /// modes are linearly dependent on this aperture (condition number above 1e12).
    pub fn with_radius(
        layout: &Layout,
        n_modes: usize,
        radius: f64,
    ) -> Result<ZernikeBasis, M1Error> {
        if !(radius.is_finite() && radius > 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "radius",
                value: radius,
                reason: "the normalisation radius must be finite and > 0 m",
            });
        }
        let n_seg = layout.n_segments();
        if n_modes == 0 || n_modes > 3 * n_seg {
            return Err(M1Error::InvalidParameter {
                name: "n_modes",
                value: n_modes as f64,
                reason: "need 1 <= n_modes <= 3 x number of segments",
            });
        }
        if radial_degree(n_modes) > MAX_RADIAL_DEGREE {
            return Err(M1Error::InvalidParameter {
                name: "n_modes",
                value: n_modes as f64,
                reason: "the radial degree is limited to MAX_RADIAL_DEGREE",
            });
        }
        let a = layout.circumradius;
        let modes = ModeSet::new(n_modes);
        let rule = hexagon_rule(a, modes.max_n + 1);
        let area = 1.5 * 3.0_f64.sqrt() * a * a;
        let second = area * 5.0 / 24.0 * a * a;

        let mut matrix = Mat::<f64>::zeros(3 * n_seg, n_modes);
        let mut z = vec![0.0; n_modes];
        let mut acc = vec![[0.0; 3]; n_modes];
        for (i, seg) in layout.segments.iter().enumerate() {
            acc.iter_mut().for_each(|s| *s = [0.0; 3]);
            for &[dx, dy, w] in &rule {
                let u = (seg.center[0] + dx) / radius;
                let v = (seg.center[1] + dy) / radius;
                modes.eval(u, v, &mut z);
                for (s, &zj) in acc.iter_mut().zip(&z) {
                    let wz = w * zj;
                    s[0] += wz;
                    s[1] += wz * dx;
                    s[2] += wz * dy;
                }
            }
            for (j, s) in acc.iter().enumerate() {
                matrix[(3 * i, j)] = s[0] / area;
                matrix[(3 * i + 1, j)] = s[1] / second;
                matrix[(3 * i + 2, j)] = s[2] / second;
            }
        }

        // Weighted least squares in the surface metric: rows scaled by sqrt of (A, I, I) / A.
        let g = (5.0_f64 / 24.0).sqrt() * a;
        let scale = |row: usize| if row.is_multiple_of(3) { 1.0 } else { g };
        let weighted = Mat::<f64>::from_fn(3 * n_seg, n_modes, |r, c| scale(r) * matrix[(r, c)]);
        let svd = weighted.thin_svd().map_err(|_| M1Error::InvalidParameter {
            name: "n_modes",
            value: n_modes as f64,
            reason: "the singular value decomposition of the projected modes did not converge",
        })?;
        let s = svd.S().column_vector();
        let singular_values: Vec<f64> = (0..n_modes).map(|k| s[k]).collect();
        let smax = singular_values.first().copied().unwrap_or(0.0);
        let smin = singular_values.last().copied().unwrap_or(0.0);
        if smin.is_nan() || smin <= 1e-12 * smax {
            return Err(M1Error::InvalidParameter {
                name: "n_modes",
                value: n_modes as f64,
                reason: "the projected modes are linearly dependent on this aperture \
                         (condition number > 1e12): use fewer modes",
            });
        }
        let (u, v) = (svd.U(), svd.V());
        // fit = V S^-1 U^T diag(scale).
        let vs = Mat::<f64>::from_fn(n_modes, n_modes, |r, c| v[(r, c)] / singular_values[c]);
        let ut = Mat::<f64>::from_fn(n_modes, 3 * n_seg, |r, c| u[(c, r)] * scale(c));
        let fit_matrix = &vs * &ut;
        Ok(ZernikeBasis {
            radius,
            circumradius: a,
            modes,
            matrix,
            fit_matrix,
            singular_values,
        })
    }

    /// Number of modes (`Z_1..Z_n_modes`).
    pub fn n_modes(&self) -> usize {
        self.modes.n_modes
    }

    /// Number of segments `N`.
    pub fn n_segments(&self) -> usize {
        self.matrix.nrows() / 3
    }

    /// Normalisation radius (m).
    pub fn radius(&self) -> f64 {
        self.radius
    }

    /// Segment circumradius of the layout (m).
    pub fn circumradius(&self) -> f64 {
        self.circumradius
    }

    /// Highest radial degree among the modes.
    pub fn max_degree(&self) -> u32 {
        self.modes.max_n
    }

    /// Radial degree of Noll's mode `j` (same as [`radial_degree`]).
    pub fn radial_degree(&self, j: usize) -> u32 {
        radial_degree(j)
    }

    /// The projection matrix, `3N x n_modes`: row `3 i + {0, 1, 2}` is `p, tx, ty` of segment
    /// `i`, column `j - 1` is Noll's mode `j` for a coefficient of 1 m rms.
    pub fn matrix(&self) -> &Mat<f64> {
        &self.matrix
    }

    /// The fitting matrix, `n_modes x 3N`: coefficients = fit matrix x segment state.
    pub fn fit_matrix(&self) -> &Mat<f64> {
        &self.fit_matrix
    }

    /// Ratio of the largest to the smallest singular value of the projected modes in the
    /// surface metric (1 when they are orthonormal there).
    pub fn condition_number(&self) -> f64 {
        let smax = self.singular_values.first().copied().unwrap_or(0.0);
        let smin = self.singular_values.last().copied().unwrap_or(0.0);
        smax / smin
    }

    /// Segment state `[p, tx, ty]` per segment of a unit coefficient of Noll's mode `j`
    /// (`None` unless `1 <= j <= n_modes`).
    pub fn mode(&self, j: usize) -> Option<Vec<[f64; 3]>> {
        if j == 0 || j > self.n_modes() {
            return None;
        }
        let c = j - 1;
        Some(
            (0..self.n_segments())
                .map(|i| {
                    [
                        self.matrix[(3 * i, c)],
                        self.matrix[(3 * i + 1, c)],
                        self.matrix[(3 * i + 2, c)],
                    ]
                })
                .collect(),
        )
    }

    /// Segment state of the mode combination `sum_j coefficients[j - 1] Z_j`
    /// (`coefficients.len() == n_modes`, m rms).
    pub fn synthesize(&self, coefficients: &[f64]) -> Result<Vec<[f64; 3]>, M1Error> {
        if coefficients.len() != self.n_modes() {
            return Err(M1Error::SizeMismatch {
                what: "Zernike coefficients",
                expected: self.n_modes(),
                found: coefficients.len(),
            });
        }
        Ok((0..self.n_segments())
            .map(|i| {
                std::array::from_fn(|k| {
                    coefficients
                        .iter()
                        .enumerate()
                        .map(|(c, &x)| self.matrix[(3 * i + k, c)] * x)
                        .sum()
                })
            })
            .collect())
    }

    /// Zernike coefficients (m rms) of the segment state `ptt` (`[p, tx, ty]` per segment), by
    /// least squares over the segmented aperture (see the [module documentation](self)).
    pub fn fit(&self, ptt: &[[f64; 3]]) -> Result<Vec<f64>, M1Error> {
        if ptt.len() != self.n_segments() {
            return Err(M1Error::SizeMismatch {
                what: "segment piston/tip/tilt",
                expected: self.n_segments(),
                found: ptt.len(),
            });
        }
        Ok((0..self.n_modes())
            .map(|j| {
                ptt.iter()
                    .enumerate()
                    .map(|(i, s)| {
                        self.fit_matrix[(j, 3 * i)] * s[0]
                            + self.fit_matrix[(j, 3 * i + 1)] * s[1]
                            + self.fit_matrix[(j, 3 * i + 2)] * s[2]
                    })
                    .sum()
            })
            .collect())
    }
}

/// Quadrature rule over a regular pointy-topped hexagon of circumradius `a` centred on the
/// origin, exact (to round-off) for polynomials of total degree up to `degree`: `[dx, dy,
/// weight]`. The hexagon is cut into the central rectangle `|x| <= h, |y| <= a/2` (`h` the
/// apothem), with a `q x q` Gauss–Legendre product rule, `q = degree / 2 + 1`, and the two
/// triangles above and below it, each mapped from the square by collapsing its width linearly
/// towards the apex, with `q x q'` points, `q' = (degree + 1) / 2 + 1` along the height (the
/// map's Jacobian adds one degree there).
pub fn hexagon_rule(a: f64, degree: u32) -> Vec<[f64; 3]> {
    let q = (degree / 2 + 1) as usize;
    let q_height = (degree.div_ceil(2) + 1) as usize;
    let (x, w) = gauss_legendre(q);
    let (xh, wh) = gauss_legendre(q_height);
    let h = 0.5 * 3.0_f64.sqrt() * a;
    let mut rule = Vec::with_capacity(q * q + 2 * q * q_height);
    // Rectangle [-h, h] x [-a/2, a/2].
    for (&xi, &wi) in x.iter().zip(&w) {
        for (&yj, &wj) in x.iter().zip(&w) {
            rule.push([h * xi, 0.5 * a * yj, wi * wj * h * 0.5 * a]);
        }
    }
    // Triangles: y = ±(a/2)(1 + eta), eta in [0, 1]; x = h (1 - eta) xi, xi in [-1, 1].
    for side in [1.0, -1.0] {
        for (&ej, &wj) in xh.iter().zip(&wh) {
            let eta = 0.5 * (1.0 + ej);
            let half_width = h * (1.0 - eta);
            let y = side * 0.5 * a * (1.0 + eta);
            for (&xi, &wi) in x.iter().zip(&w) {
                // d(eta) = d(ej) / 2; dy = (a/2) d(eta); dx = half_width d(xi).
                rule.push([half_width * xi, y, wi * 0.5 * wj * 0.5 * a * half_width]);
            }
        }
    }
    rule
}
