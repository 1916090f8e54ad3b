//! The lowest eigenpairs of a generalised symmetric eigenproblem $K x = \lambda M x$ ($K$
//! positive definite, given by its [`Skyline`] Cholesky factor; $M$ diagonal and positive): the
//! structure's retained modes without the dense eigensolve of every mode.
//!
//! **Method.** Block Lanczos with full re-orthogonalisation on the symmetric operator
//! $A = M^{1/2} K^{-1} M^{1/2}$, whose largest eigenvalues $\theta = 1/\lambda$ are the wanted
//! ones and are well separated from the bulk (the stiff modes crowd near $\theta = 0$), so the
//! Krylov space holds them to working precision after a few blocks more than `r` columns.
//!
//! - Each new block is $A$ applied to the last one (two envelope solves per column), then made
//!   orthogonal to the whole basis by two passes of block classical Gram-Schmidt (matrix
//!   products) and orthonormal within itself by two passes of modified Gram-Schmidt. A column
//!   that vanishes (an invariant subspace) is replaced by a fresh random direction, so the
//!   basis only ever needs to be orthonormal.
//! - The Rayleigh-Ritz step takes the projected matrix $H = Q^T (A Q)$ from the stored products
//!   $A Q$ (no three-term recurrence is trusted), and each Ritz pair $(\theta, y = Q s)$ is
//!   checked by its true residual $\lVert A y - \theta y \rVert$.
//! - Blocks (of at least four columns) find repeated eigenvalues: the hexagonal cells' modes
//!   come in exactly degenerate pairs, which a single-vector Lanczos would only find by
//!   round-off.
//! - The start block is pseudo-random with a fixed seed: the result is deterministic.
//!
//! The caller falls back to a dense eigensolve when the space reaches its bound without
//! converging ([`lowest_eigenpairs`] returns `None`), which has not been seen on the built-in
//! cells.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par, Side};

use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use super::kernels::axpy;
use super::skyline::Skyline;
use crate::M1Error;

/// Residual bound of an accepted Ritz pair, relative to the largest Ritz value (the operator's
/// norm): `|A y - theta y| <= RESIDUAL * theta_max`.
pub const RESIDUAL: f64 = 1e-12;

/// The lowest eigenpairs found by [`lowest_eigenpairs`].
#[derive(Debug, Clone, PartialEq)]
pub struct Eigenpairs {
    /// Eigenvalues `lambda`, ascending.
    pub values: Vec<f64>,
    /// Eigenvectors `x`, mass-normalised (`x^T M x = 1`), column-major `n x r`.
    pub vectors: Vec<f64>,
    /// Dimension of the Krylov space at convergence.
    pub krylov_dim: usize,
}

/// The number of columns per block for `r` wanted pairs.
fn block_size(r: usize) -> usize {
    (r / 8).clamp(4, 16).next_multiple_of(4)
}

/// A seeded pseudo-random generator of directions, uniform in `[-1, 1)` per entry.
struct Noise(StdRng);

impl Noise {
    fn next(&mut self) -> f64 {
        self.0.random_range(-1.0..1.0)
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The `r` lowest eigenpairs of `K x = lambda M x`, `K = L L^T` given by `chol`, `M =
/// diag(mass)`; `None` if the Krylov space reached its bound (`5 r` plus ten blocks, at most
/// `n`) before every pair met [`RESIDUAL`].
///
/// # Errors
/// [`M1Error::SizeMismatch`] if `mass` is not of the factor's dimension,
/// [`M1Error::InvalidParameter`] for a non-positive mass or `r = 0`, [`M1Error::Numerical`] for
/// a non-positive Ritz value (a factor that is not of a positive definite matrix).
pub fn lowest_eigenpairs(
    chol: &Skyline,
    mass: &[f64],
    r: usize,
) -> Result<Option<Eigenpairs>, M1Error> {
    let n = chol.dim();
    if mass.len() != n {
        return Err(M1Error::SizeMismatch {
            what: "mass",
            expected: n,
            found: mass.len(),
        });
    }
    if let Some(&m) = mass.iter().find(|m| !(m.is_finite() && **m > 0.0)) {
        return Err(M1Error::InvalidParameter {
            name: "mass",
            value: m,
            reason: "every mass must be finite and > 0",
        });
    }
    if r == 0 {
        return Err(M1Error::InvalidParameter {
            name: "r",
            value: 0.0,
            reason: "must be >= 1",
        });
    }
    let r = r.min(n);
    let p = block_size(r).min(n);
    let m_max = (5 * r + 10 * p).min(n);
    let sm: Vec<f64> = mass.iter().map(|m| m.sqrt()).collect();
    let mut q = vec![0.0; n * m_max];
    let mut aq = vec![0.0; n * m_max];
    let mut rows = vec![0.0; n * p];
    let mut noise = Noise(StdRng::seed_from_u64(0x5EED_CE11));
    for v in &mut q[..n * p] {
        *v = noise.next();
    }
    if !orthonormalise(&mut q, n, 0, p, &mut noise) {
        return Ok(None);
    }
    let (mut filled, mut applied) = (p, 0);
    let mut next_check = (2 * r + p).min(m_max);
    loop {
        // A applied to the columns not yet applied (the last block), all at once.
        let b = filled - applied;
        for (c, j) in (applied..filled).enumerate() {
            for (i, (x, s)) in q[j * n..(j + 1) * n].iter().zip(&sm).enumerate() {
                rows[i * b + c] = x * s;
            }
        }
        chol.solve_block_in_place(&mut rows[..n * b], b);
        for (c, j) in (applied..filled).enumerate() {
            for (i, (a, s)) in aq[j * n..(j + 1) * n].iter_mut().zip(&sm).enumerate() {
                *a = rows[i * b + c] * s;
            }
        }
        let last = applied..filled;
        applied = filled;
        if applied >= next_check || applied == m_max {
            if let Some(pairs) = rayleigh_ritz(&q, &aq, n, applied, r, &sm)? {
                return Ok(Some(pairs));
            }
            if applied == m_max {
                return Ok(None);
            }
            next_check = (applied + p.max(applied / 5)).min(m_max);
        }
        let nb = last.len().min(m_max - filled);
        q[filled * n..(filled + nb) * n]
            .copy_from_slice(&aq[last.start * n..(last.start + nb) * n]);
        if !orthonormalise(&mut q, n, filled, nb, &mut noise) {
            // The whole space is spanned: the last check decides.
            return rayleigh_ritz(&q, &aq, n, applied, r, &sm);
        }
        filled += nb;
    }
}

/// Makes columns `from..from + nb` of `q` (column-major, `n` rows) orthonormal and orthogonal
/// to the columns before them; a column that vanishes is replaced by a random direction.
/// `false` if no direction is left (the basis spans the space).
fn orthonormalise(q: &mut [f64], n: usize, from: usize, nb: usize, noise: &mut Noise) -> bool {
    let (old, new) = q.split_at_mut(from * n);
    let new = &mut new[..nb * n];
    let basis = MatRef::from_column_major_slice(old, n, from);
    let mut coef = vec![0.0; from * nb];
    let project = |w: &mut [f64], cols: usize, coef: &mut [f64]| {
        if from == 0 {
            return;
        }
        for _ in 0..2 {
            let mut c = MatMut::from_column_major_slice_mut(&mut coef[..from * cols], from, cols);
            let wm = MatRef::from_column_major_slice(w, n, cols);
            matmul(
                c.as_mut(),
                Accum::Replace,
                basis.transpose(),
                wm,
                1.0,
                Par::Seq,
            );
            let wm = MatMut::from_column_major_slice_mut(w, n, cols);
            matmul(wm, Accum::Add, basis, c.as_ref(), -1.0, Par::Seq);
        }
    };
    project(new, nb, &mut coef);
    for j in 0..nb {
        let (done, rest) = new.split_at_mut(j * n);
        let w = &mut rest[..n];
        let before = dot(w, w).sqrt();
        let mut fresh = false;
        for attempt in 0..4 {
            for _ in 0..2 {
                for i in 0..j {
                    let v = &done[i * n..(i + 1) * n];
                    let d = dot(v, w);
                    axpy(w, -d, v);
                }
            }
            let norm = dot(w, w).sqrt();
            let scale = if fresh { 1.0 } else { before };
            if norm > 1e-10 * scale && norm > 0.0 {
                w.iter_mut().for_each(|a| *a /= norm);
                break;
            }
            if attempt == 3 {
                return false;
            }
            // A vanished column: restart it from noise, orthogonal to the basis.
            w.iter_mut().for_each(|a| *a = noise.next());
            fresh = true;
            project(w, 1, &mut coef);
        }
    }
    true
}

/// The Rayleigh-Ritz step on the first `k` columns: the `r` largest Ritz pairs if each meets
/// [`RESIDUAL`], as eigenpairs of the generalised problem.
fn rayleigh_ritz(
    q: &[f64],
    aq: &[f64],
    n: usize,
    k: usize,
    r: usize,
    sm: &[f64],
) -> Result<Option<Eigenpairs>, M1Error> {
    if k < r {
        return Ok(None);
    }
    let qk = MatRef::from_column_major_slice(&q[..n * k], n, k);
    let aqk = MatRef::from_column_major_slice(&aq[..n * k], n, k);
    let mut h = faer::Mat::<f64>::zeros(k, k);
    matmul(
        h.as_mut(),
        Accum::Replace,
        qk.transpose(),
        aqk,
        1.0,
        Par::Seq,
    );
    let hs = faer::Mat::<f64>::from_fn(k, k, |i, j| 0.5 * (h[(i, j)] + h[(j, i)]));
    let evd = hs
        .self_adjoint_eigen(Side::Lower)
        .map_err(|e| M1Error::Numerical(format!("Rayleigh-Ritz eigensolve: {e:?}")))?;
    let theta = evd.S().column_vector();
    let u = evd.U();
    let theta_max = theta[k - 1];
    // The r largest, largest first (the lowest lambda first).
    let pick: Vec<usize> = (k - r..k).rev().collect();
    let s = faer::Mat::<f64>::from_fn(k, r, |i, j| u[(i, pick[j])]);
    let mut y = faer::Mat::<f64>::zeros(n, r);
    let mut ay = faer::Mat::<f64>::zeros(n, r);
    matmul(y.as_mut(), Accum::Replace, qk, s.as_ref(), 1.0, Par::Seq);
    matmul(ay.as_mut(), Accum::Replace, aqk, s.as_ref(), 1.0, Par::Seq);
    let mut values = Vec::with_capacity(r);
    for (j, &i) in pick.iter().enumerate() {
        let th = theta[i];
        if !(th > 0.0 && th.is_finite()) {
            return Err(M1Error::Numerical(format!(
                "Ritz value {th:e} <= 0: the stiffness factor is not of a positive definite matrix"
            )));
        }
        let res: f64 = (0..n)
            .map(|row| {
                let e = ay[(row, j)] - th * y[(row, j)];
                e * e
            })
            .sum::<f64>()
            .sqrt();
        if res > RESIDUAL * theta_max {
            return Ok(None);
        }
        values.push(1.0 / th);
    }
    let mut vectors = vec![0.0; n * r];
    for j in 0..r {
        for (row, s) in sm.iter().enumerate() {
            vectors[j * n + row] = y[(row, j)] / s;
        }
    }
    Ok(Some(Eigenpairs {
        values,
        vectors,
        krylov_dim: k,
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 1-D chain of springs with masses (tridiagonal K), grounded at one end.
    fn chain(n: usize) -> (Vec<f64>, Vec<f64>) {
        let mut k = vec![0.0; n * n];
        for i in 0..n {
            k[i * n + i] = if i + 1 < n { 2.0 } else { 1.0 };
            if i > 0 {
                k[i * n + i - 1] = -1.0;
                k[(i - 1) * n + i] = -1.0;
            }
        }
        let mass = (0..n).map(|i| 1.0 + 0.3 * (i as f64 * 0.7).sin()).collect();
        (k, mass)
    }

    fn dense_lowest(n: usize, k: &[f64], mass: &[f64]) -> Vec<f64> {
        let a = faer::Mat::<f64>::from_fn(n, n, |i, j| k[i * n + j] / (mass[i] * mass[j]).sqrt());
        a.self_adjoint_eigenvalues(Side::Lower).unwrap()
    }

    /// The `r` lowest pairs of `K x = lambda M x` (dense `k`), their eigenvalues checked against
    /// the dense solve's to 1e-11.
    fn lowest_checked(n: usize, k: &[f64], mass: &[f64], r: usize) -> Eigenpairs {
        let chol = Skyline::factor(n, k).unwrap();
        let pairs = lowest_eigenpairs(&chol, mass, r)
            .unwrap()
            .expect("converged");
        let dense = dense_lowest(n, k, mass);
        for (j, (a, b)) in pairs.values.iter().zip(&dense).enumerate() {
            assert!(
                (a - b).abs() <= 1e-11 * b,
                "eigenvalue {j}: {a:e} against {b:e}"
            );
        }
        pairs
    }

    #[test]
    fn lowest_pairs_of_a_chain_match_the_dense_solve() {
        let n = 300;
        let (k, mass) = chain(n);
        let r = 20;
        let pairs = lowest_checked(n, &k, &mass, r);
        // K x = lambda M x and x^T M x = 1, column by column.
        for j in 0..r {
            let x = &pairs.vectors[j * n..(j + 1) * n];
            let lam = pairs.values[j];
            let mnorm: f64 = x.iter().zip(&mass).map(|(a, m)| a * a * m).sum();
            assert!((mnorm - 1.0).abs() < 1e-12, "mode {j}: x^T M x = {mnorm}");
            let kx: Vec<f64> = (0..n).map(|i| dot(&k[i * n..(i + 1) * n], x)).collect();
            let res: f64 = (0..n).map(|i| (kx[i] - lam * mass[i] * x[i]).powi(2)).sum();
            let scale: f64 = kx.iter().map(|v| v * v).sum();
            let rel = (res / scale).sqrt();
            assert!(rel <= 1e-8, "mode {j}: relative residual {rel:e}");
        }
    }

    #[test]
    fn repeated_eigenvalues_are_found_with_their_multiplicity() {
        // Three identical uncoupled chains: every eigenvalue is triple.
        let (n1, copies) = (60, 3);
        let (k1, _) = chain(n1);
        let n = n1 * copies;
        let mut k = vec![0.0; n * n];
        for c in 0..copies {
            for i in 0..n1 {
                for j in 0..n1 {
                    k[(c * n1 + i) * n + c * n1 + j] = k1[i * n1 + j];
                }
            }
        }
        let mass = vec![2.0; n];
        let r = 12;
        let pairs = lowest_checked(n, &k, &mass, r);
        assert!((pairs.values[0] - pairs.values[2]).abs() <= 1e-12 * pairs.values[0]);
        // The three vectors of the lowest triple are M-orthonormal.
        for a in 0..3 {
            for b in 0..3 {
                let xa = &pairs.vectors[a * n..(a + 1) * n];
                let xb = &pairs.vectors[b * n..(b + 1) * n];
                let g: f64 = xa.iter().zip(xb).map(|(u, v)| u * v * 2.0).sum();
                let want = if a == b { 1.0 } else { 0.0 };
                assert!((g - want).abs() < 1e-12, "x{a}^T M x{b} = {g}");
            }
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let (k, mut mass) = chain(10);
        let chol = Skyline::factor(10, &k).unwrap();
        assert!(lowest_eigenpairs(&chol, &mass[..9], 2).is_err());
        assert!(lowest_eigenpairs(&chol, &mass, 0).is_err());
        mass[3] = 0.0;
        assert!(lowest_eigenpairs(&chol, &mass, 2).is_err());
    }

    #[test]
    fn asking_for_every_pair_of_a_small_problem_spans_the_space() {
        let (k, mass) = chain(10);
        let pairs = lowest_checked(10, &k, &mass, 10);
        assert_eq!(pairs.values.len(), 10);
        assert_eq!(pairs.krylov_dim, 10, "the whole space, no more");
    }
}
