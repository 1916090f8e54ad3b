//! Krylov estimates of extreme eigenvalues of operators given only as matrix-vector products.
//!
//! Arnoldi with full re-orthogonalisation builds an orthonormal basis $V_m$ of the Krylov space
//! $\mathcal K_m(M, v_0)$ and the Hessenberg matrix $H_m = V_m^T M V_m$; the eigenvalues of $H_m$
//! (Ritz values) approximate the extreme eigenvalues of $M$ first, to high accuracy when they are
//! separated from the bulk. The largest singular value of $Q$ is the square root of the largest
//! eigenvalue of $Q^T Q$.

use nalgebra::{Complex, DMatrix};

/// Ritz values of `op` (an n x n operator, `op(x, out)` writes M x) from an m-step Arnoldi
/// process started at `v0`. Stops early on an invariant subspace (the Ritz values are then
/// exact eigenvalues of M restricted to it): when the new direction is below 1e-13 of `scale`
/// (the magnitude below which M x counts as round-off, e.g. 1 for Q - I with Q of order 1) or of
/// the largest |M v| seen.
pub fn ritz_values(
    n: usize,
    m: usize,
    v0: &[f64],
    scale: f64,
    mut op: impl FnMut(&[f64], &mut [f64]),
) -> Vec<Complex<f64>> {
    let m = m.min(n).max(1);
    let mut basis: Vec<Vec<f64>> = Vec::with_capacity(m + 1);
    let norm0 = v0.iter().map(|x| x * x).sum::<f64>().sqrt();
    if norm0 == 0.0 {
        return Vec::new();
    }
    basis.push(v0.iter().map(|x| x / norm0).collect());
    let mut h = DMatrix::<f64>::zeros(m + 1, m);
    let mut w = vec![0.0; n];
    let mut steps = m;
    let mut largest = scale.abs();
    for j in 0..m {
        op(&basis[j], &mut w);
        let wnorm0 = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        largest = largest.max(wnorm0);
        // Two passes of classical Gram-Schmidt: orthogonal to working precision.
        for _ in 0..2 {
            for (i, v) in basis.iter().enumerate() {
                let d: f64 = v.iter().zip(&w).map(|(a, b)| a * b).sum();
                h[(i, j)] += d;
                for (wk, vk) in w.iter_mut().zip(v) {
                    *wk -= d * vk;
                }
            }
        }
        let wn = w.iter().map(|x| x * x).sum::<f64>().sqrt();
        h[(j + 1, j)] = wn;
        if wn <= 1e-13 * largest || wn == 0.0 {
            steps = j + 1;
            break;
        }
        basis.push(w.iter().map(|x| x / wn).collect());
    }
    let hm = h.view((0, 0), (steps, steps)).into_owned();
    match nalgebra::linalg::Schur::try_new(hm.clone(), f64::EPSILON, 100_000) {
        Some(schur) => schur.complex_eigenvalues().iter().copied().collect(),
        // No convergence (not seen in practice): the diagonal is a crude fallback.
        None => (0..steps).map(|i| Complex::new(hm[(i, i)], 0.0)).collect(),
    }
}

/// Largest eigenvalue modulus estimate (spectral radius) of `op`.
pub fn spectral_radius(
    n: usize,
    m: usize,
    v0: &[f64],
    scale: f64,
    op: impl FnMut(&[f64], &mut [f64]),
) -> f64 {
    ritz_values(n, m, v0, scale, op)
        .iter()
        .map(|l| l.norm())
        .fold(0.0, f64::max)
}

/// Largest singular value estimate of Q from `q(x, out)` and `qt(x, out)` (its transpose).
pub fn largest_singular_value(
    n: usize,
    m: usize,
    v0: &[f64],
    mut q: impl FnMut(&[f64], &mut [f64]),
    mut qt: impl FnMut(&[f64], &mut [f64]),
) -> f64 {
    let mut tmp = vec![0.0; n];
    let lmax = ritz_values(n, m, v0, 0.0, |x, out| {
        q(x, &mut tmp);
        qt(&tmp, out);
    })
    .iter()
    .map(|l| l.re)
    .fold(0.0, f64::max);
    lmax.max(0.0).sqrt()
}

/// The largest eigenvalue of the symmetric tridiagonal matrix with diagonal `alpha` and
/// off-diagonal `beta` (length one less), by Sturm-count bisection, and its unit eigenvector, by inverse iteration just above it (where `T - sigma I` is negative
/// definite, so the unpivoted tridiagonal elimination is stable). O(m) per call.
pub fn top_ritz(alpha: &[f64], beta: &[f64]) -> (f64, Vec<f64>) {
    let m = alpha.len();
    if m == 0 {
        return (0.0, Vec::new());
    }
    if m == 1 {
        return (alpha[0], vec![1.0]);
    }
    let off = |i: usize| -> f64 {
        let l = if i > 0 { beta[i - 1].abs() } else { 0.0 };
        let r = if i + 1 < m { beta[i].abs() } else { 0.0 };
        l + r
    };
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (i, a) in alpha.iter().enumerate() {
        lo = lo.min(a - off(i));
        hi = hi.max(a + off(i));
    }
    let scale = lo.abs().max(hi.abs()).max(f64::MIN_POSITIVE);
    // Number of eigenvalues below x (negative pivots of the LDL^T of T - x I).
    let below = |x: f64| -> usize {
        let mut count = 0;
        let mut d = alpha[0] - x;
        for i in 0..m {
            if i > 0 {
                let dd = if d == 0.0 { f64::EPSILON * scale } else { d };
                d = alpha[i] - x - beta[i - 1] * beta[i - 1] / dd;
            }
            if d < 0.0 {
                count += 1;
            }
        }
        count
    };
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid <= lo || mid >= hi {
            break;
        }
        if below(mid) < m {
            lo = mid;
        } else {
            hi = mid;
        }
        if hi - lo <= 4.0 * f64::EPSILON * scale {
            break;
        }
    }
    let theta = 0.5 * (lo + hi);
    // Inverse iteration with (T - sigma I), sigma above the top eigenvalue.
    let sigma = hi + 1e-10 * scale;
    let mut y = vec![1.0; m];
    let mut diag = vec![0.0; m];
    for _ in 0..3 {
        // Forward elimination of (T - sigma I) y_new = y.
        diag[0] = alpha[0] - sigma;
        let mut rhs = y.clone();
        for i in 1..m {
            let l = beta[i - 1] / diag[i - 1];
            diag[i] = alpha[i] - sigma - l * beta[i - 1];
            rhs[i] -= l * rhs[i - 1];
        }
        y[m - 1] = rhs[m - 1] / diag[m - 1];
        for i in (0..m - 1).rev() {
            y[i] = (rhs[i] - beta[i] * y[i + 1]) / diag[i];
        }
        let n = y.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !(n.is_finite() && n > 0.0) {
            let mut e = vec![0.0; m];
            e[m - 1] = 1.0;
            return (theta, e);
        }
        for v in &mut y {
            *v /= n;
        }
    }
    (theta, y)
}

/// The largest eigenvalue of a complex Hermitian positive semi-definite operator (`op(x, out)`
/// writes $M x$), by Lanczos with full re-orthogonalisation from the start vector `v0`.
///
/// With the tridiagonal $T_j = V_j^H M V_j$, the largest Ritz value $\theta$ and its vector
/// $y$, the residual $\|M V_j y - \theta V_j y\| = \beta_j |y_j|$ bounds the distance from
/// $\theta$ to an eigenvalue of $M$; the iteration stops when it is below `tol` $\theta$ (after
/// at least `min(n, min_steps)` steps: 12 lets the top of the spectrum be reached from a
/// generic start, fewer suit a start close to the top vector), on an invariant subspace, or
/// after `max_steps`. Ritz values bound the eigenvalue from below, and converge to it first when
/// it is separated from the rest.
///
/// Returns the top Ritz pair, the steps taken and whether the test was met.
pub fn largest_hermitian_eigenpair(
    n: usize,
    (min_steps, max_steps): (usize, usize),
    v0: &[faer::c64],
    tol: f64,
    mut op: impl FnMut(&[faer::c64], &mut [faer::c64]),
) -> Eigenpair {
    use faer::{Mat, c64};
    let m = max_steps.min(n).max(1);
    let n0 = v0.iter().map(|x| x.norm_sqr()).sum::<f64>().sqrt();
    if n == 0 || n0 == 0.0 {
        return Eigenpair {
            value: 0.0,
            vector: vec![c64::new(0.0, 0.0); n],
            steps: 0,
            converged: true,
        };
    }
    // The basis as columns, re-orthogonalised with matrix-vector products.
    let mut basis = Mat::<c64>::zeros(n, m);
    for (i, x) in v0.iter().enumerate() {
        basis[(i, 0)] = x / n0;
    }
    let (mut alpha, mut beta): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    let mut w = vec![c64::new(0.0, 0.0); n];
    let mut x = vec![c64::new(0.0, 0.0); n];
    let norm = |a: &[c64]| a.iter().map(|v| v.norm_sqr()).sum::<f64>().sqrt();
    let mut theta = 0.0;
    let mut y = Vec::new();
    let min_steps = n.min(min_steps.max(1));
    for j in 0..m {
        for (i, xi) in x.iter_mut().enumerate() {
            *xi = basis[(i, j)];
        }
        op(&x, &mut w);
        let largest = norm(&w);
        alpha.push(
            x.iter()
                .zip(&w)
                .fold(c64::new(0.0, 0.0), |a, (p, q)| a + p.conj() * q)
                .re,
        );
        // Classical Gram-Schmidt against every basis vector, a second pass only when the
        // first removed most of the vector (Kahan's "twice is enough": below 1/sqrt(2) of it).
        let q = basis.subcols(0, j + 1);
        let mut b = largest;
        for _ in 0..2 {
            let before = b;
            let c = q.adjoint() * faer::MatRef::from_column_major_slice(&w, n, 1);
            let qc = q * &c;
            for (i, wi) in w.iter_mut().enumerate() {
                *wi -= qc[(i, 0)];
            }
            b = norm(&w);
            if b > std::f64::consts::FRAC_1_SQRT_2 * before {
                break;
            }
        }
        let steps = j + 1;
        let check = steps == m || (steps >= min_steps && steps % 2 == 0) || b == 0.0;
        if check {
            let (th, yv) = top_ritz(&alpha, &beta);
            theta = th;
            let invariant = b <= 1e-14 * largest.max(th.abs()) || b == 0.0;
            let residual = b * yv[steps - 1].abs();
            y = yv;
            if invariant || (steps >= min_steps && residual <= tol * th.abs()) {
                return Eigenpair {
                    value: theta,
                    vector: ritz_vector(basis.subcols(0, steps), &y),
                    steps,
                    converged: true,
                };
            }
        }
        if steps == m {
            break;
        }
        beta.push(b);
        for i in 0..n {
            basis[(i, j + 1)] = w[i] / b;
        }
    }
    Eigenpair {
        value: theta,
        vector: ritz_vector(basis.subcols(0, y.len()), &y),
        steps: m,
        converged: m == n,
    }
}

/// `V y` for the basis `V` and real coefficients `y`.
fn ritz_vector(v: faer::MatRef<'_, faer::c64>, y: &[f64]) -> Vec<faer::c64> {
    let yc = faer::Mat::from_fn(y.len(), 1, |i, _| faer::c64::new(y[i], 0.0));
    let x = v * &yc;
    (0..x.nrows()).map(|i| x[(i, 0)]).collect()
}

/// An eigenvalue estimate with its vector.
#[derive(Debug, Clone, PartialEq)]
pub struct Eigenpair {
    /// The top Ritz value (a lower bound on the largest eigenvalue).
    pub value: f64,
    /// Its Ritz vector (unit norm).
    pub vector: Vec<faer::c64>,
    /// Operator applications made.
    pub steps: usize,
    /// Whether the residual test (or an invariant subspace) was met.
    pub converged: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ritz_values_find_the_extreme_eigenvalues() {
        // Diagonal operator with a separated top and bottom eigenvalue.
        let n = 400;
        let d: Vec<f64> = (0..n)
            .map(|i| match i {
                0 => 10.0,
                1 => -3.0,
                _ => 1.0 + (i as f64) / n as f64,
            })
            .collect();
        let v0: Vec<f64> = (0..n).map(|i| 1.0 + ((i * 37) % 11) as f64).collect();
        let op = |x: &[f64], out: &mut [f64]| {
            for ((o, xi), di) in out.iter_mut().zip(x).zip(&d) {
                *o = di * xi;
            }
        };
        let ritz = ritz_values(n, 40, &v0, 0.0, op);
        let max = ritz.iter().map(|l| l.re).fold(f64::MIN, f64::max);
        let min = ritz.iter().map(|l| l.re).fold(f64::MAX, f64::min);
        assert!((max - 10.0).abs() < 1e-10, "{max}");
        assert!((min + 3.0).abs() < 1e-10, "{min}");
        assert!((spectral_radius(n, 40, &v0, 0.0, op) - 10.0).abs() < 1e-10);
    }

    #[test]
    fn singular_value_of_a_rotation_scaled() {
        // Q = 2 R (rotation by 90 degrees in pairs): all singular values 2, eigenvalues +-2i.
        let n = 50;
        let q = |x: &[f64], out: &mut [f64]| {
            for k in 0..n / 2 {
                out[2 * k] = -2.0 * x[2 * k + 1];
                out[2 * k + 1] = 2.0 * x[2 * k];
            }
        };
        let qt = |x: &[f64], out: &mut [f64]| {
            for k in 0..n / 2 {
                out[2 * k] = 2.0 * x[2 * k + 1];
                out[2 * k + 1] = -2.0 * x[2 * k];
            }
        };
        let v0: Vec<f64> = (0..n).map(|i| (i as f64).sin() + 2.0).collect();
        assert!((largest_singular_value(n, 20, &v0, q, qt) - 2.0).abs() < 1e-10);
        assert!((spectral_radius(n, 20, &v0, 0.0, q) - 2.0).abs() < 1e-10);
    }

    /// A Hermitian operator with a known spectrum: the top eigenvalue to 1e-12 and a bound from
    /// below at every stage.
    #[test]
    fn lanczos_finds_the_top_of_a_hermitian_spectrum() {
        use faer::c64;
        let n = 300;
        // M = U diag(d) U^H with U a product of a diagonal phase and a complex reflection.
        let d: Vec<f64> = (0..n)
            .map(|i| {
                if i == 17 {
                    9.5
                } else {
                    1.0 + (i % 23) as f64 / 4.0
                }
            })
            .collect();
        let ph: Vec<c64> = (0..n)
            .map(|i| c64::new((0.3 * i as f64).cos(), (0.3 * i as f64).sin()))
            .collect();
        let u: Vec<c64> = (0..n)
            .map(|i| c64::new(1.0 + (i % 7) as f64, (i % 5) as f64 - 2.0))
            .collect();
        let uu: f64 = u.iter().map(|x| x.norm_sqr()).sum();
        let reflect = |x: &mut [c64]| {
            // (I - 2 u u^H / u^H u) x
            let s = u
                .iter()
                .zip(x.iter())
                .fold(c64::new(0.0, 0.0), |a, (p, q)| a + p.conj() * q);
            for (xi, ui) in x.iter_mut().zip(&u) {
                *xi -= ui * s * (2.0 / uu);
            }
        };
        let op = |x: &[c64], out: &mut [c64]| {
            let mut y: Vec<c64> = x.to_vec();
            reflect(&mut y);
            for ((yi, p), di) in y.iter_mut().zip(&ph).zip(&d) {
                *yi = p * (p.conj() * *yi * *di);
            }
            reflect(&mut y);
            out.copy_from_slice(&y);
        };
        let v0: Vec<c64> = (0..n)
            .map(|i| c64::new(1.0 + ((i * 37) % 11) as f64, ((i * 13) % 7) as f64))
            .collect();
        let p = largest_hermitian_eigenpair(n, (12, 120), &v0, 1e-13, op);
        assert!(p.converged, "{}", p.steps);
        assert!(
            (p.value - 9.5).abs() < 1e-11,
            "{} after {}",
            p.value,
            p.steps
        );
        // The vector is the eigenvector: M v = 9.5 v.
        let mut mv = vec![c64::new(0.0, 0.0); n];
        op(&p.vector, &mut mv);
        let res: f64 = mv
            .iter()
            .zip(&p.vector)
            .map(|(a, b)| (a - b * 9.5).norm_sqr())
            .sum();
        assert!(res.sqrt() < 1e-5, "{}", res.sqrt());
        // Started from it, one step suffices.
        let again = largest_hermitian_eigenpair(n, (12, 120), &p.vector, 1e-9, op);
        assert!(
            again.steps <= 12 && (again.value - 9.5).abs() < 1e-9,
            "{again:?}"
        );
        let early = largest_hermitian_eigenpair(n, (12, 3), &v0, 1e-13, op);
        assert!(early.value <= 9.5 + 1e-12, "{}", early.value);
    }

    /// The tridiagonal's top eigenpair against a dense eigensolver.
    #[test]
    fn top_ritz_matches_the_dense_eigenpair() {
        for m in [1usize, 2, 7, 60] {
            let alpha: Vec<f64> = (0..m)
                .map(|i| ((i * 7) % 5) as f64 + 0.1 * i as f64)
                .collect();
            let beta: Vec<f64> = (0..m.saturating_sub(1))
                .map(|i| 0.5 + ((i * 3) % 4) as f64 / 3.0)
                .collect();
            let t = DMatrix::<f64>::from_fn(m, m, |r, c| {
                if r == c {
                    alpha[r]
                } else if r + 1 == c {
                    beta[r]
                } else if c + 1 == r {
                    beta[c]
                } else {
                    0.0
                }
            });
            let eig = nalgebra::SymmetricEigen::new(t);
            let imax = (0..m)
                .max_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))
                .unwrap();
            let (th, y) = top_ritz(&alpha, &beta);
            assert!(
                (th - eig.eigenvalues[imax]).abs() < 1e-12 * th.abs().max(1.0),
                "{m}: {th}"
            );
            // The whole vector, up to sign.
            let sign = if y[m - 1] * eig.eigenvectors[(m - 1, imax)] < 0.0 {
                -1.0
            } else {
                1.0
            };
            for i in 0..m {
                let want = eig.eigenvectors[(i, imax)];
                assert!(
                    (sign * y[i] - want).abs() < 1e-8,
                    "{m}: {y:?} vs {want} at {i}"
                );
            }
        }
    }
}
