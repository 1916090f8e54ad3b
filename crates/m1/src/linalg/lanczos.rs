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
//!   orthogonal to the basis by two passes of block classical Gram-Schmidt (matrix products):
//!   the first against the last two blocks, where the recurrence puts all of the images in
//!   exact arithmetic, the second against the whole basis (the first pass's round-off and the
//!   older blocks' drift); then orthonormal within itself by two passes of modified
//!   Gram-Schmidt. A column that vanishes (an invariant subspace) is replaced by a fresh random
//!   direction, so the basis only ever needs to be orthonormal.
//! - The passes' coefficients are the new columns of the projected matrix $H = Q^T A Q$ (the
//!   upper triangle is whole; the rest by symmetry), and what they leave of the last block's
//!   images, $W$, is the projection's residual: $A Q = Q H + W E^T$ up to round-off ($E$: the
//!   last block's columns of the identity). A Ritz pair $(\theta, y = Q s)$ therefore has the
//!   residual $\lVert W s_{last} \rVert$, read from $W$'s small Gram matrix; only when every
//!   wanted pair's estimate meets the bound are the Ritz vectors formed and each checked by its
//!   true residual $\lVert A y - \theta y \rVert$ from the stored products $A Q$ (which decides:
//!   a replaced column breaks the relation above).
//! - $H$ is scaled to its largest diagonal entry before its eigensolve: on its own scale (about
//!   4e-4 for TMT's cell) faer's solver left residuals $\lVert H s - \theta s \rVert$ near 1e-12
//!   of the norm, which the bound rejects; scaled, near round-off (without it, TMT's 300
//!   lowest modes do not converge: `lowest_modes_alone_match_the_dense_solve_on_tmt`).
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

/// faer's global parallelism for a product of `flops` floating-point operations from
/// [`PARALLEL_FLOPS`] up, one thread below (where the hand-off costs more than it saves, and the
/// set-up's other components are using the second core anyway).
fn par_above(flops: usize) -> Par {
    if flops >= PARALLEL_FLOPS {
        faer::get_global_parallelism()
    } else {
        Par::Seq
    }
}

/// The smallest product [`par_above`] runs in parallel: TMT's 300 modes' projections from a
/// Krylov dimension of about 350 (`2 n k b`, 16 columns a block), not the default 60 modes'
/// (at most 4.5e6); both solves' final Ritz vectors (`2 n k r`: 3.4e7 at 60 modes).
const PARALLEL_FLOPS: usize = 1 << 24;

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
    let mut kr = Krylov::new(chol, mass, p, m_max);
    if !kr.start(p) {
        return Ok(None);
    }
    let mut next_check = (2 * r + p).min(m_max);
    loop {
        let b = kr.extend_image();
        if kr.applied >= next_check || kr.applied == m_max {
            if let Some(pairs) = kr.rayleigh_ritz(r, Check::Estimate)? {
                return Ok(Some(pairs));
            }
            if kr.applied == m_max {
                return Ok(None);
            }
            next_check = (kr.applied + p.max(kr.applied / 5)).min(m_max);
        }
        if !kr.extend_basis(b.min(m_max - kr.filled)) {
            // The whole space is spanned: the last check decides.
            return kr.rayleigh_ritz(r, Check::True);
        }
    }
}

/// How [`Krylov::rayleigh_ritz`] decides that a Ritz pair has converged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Check {
    /// By the block recurrence's estimate of each residual first (from the projected last
    /// block, cheap), then, if every estimate passes, by the true residuals.
    Estimate,
    /// By the true residuals alone.
    True,
}

/// The Krylov basis, the operator's images of it and the projected matrix, as they grow.
struct Krylov<'a> {
    chol: &'a Skyline,
    n: usize,
    /// The most columns the basis may have.
    m_max: usize,
    /// `sqrt(m)` per degree of freedom.
    sm: Vec<f64>,
    /// The orthonormal basis `Q`, column-major `n x m_max`; the first `filled` columns are set.
    q: Vec<f64>,
    /// `A Q` for the first `applied` columns (column-major `n x m_max`).
    aq: Vec<f64>,
    /// `H = Q^T A Q`, column-major `m_max x m_max`: column `j` holds the rows of the columns
    /// that existed when `A q_j` was projected on the basis (every row up to the end of `j`'s
    /// block, so the upper triangle is whole); the rest follows by symmetry.
    h: Vec<f64>,
    /// The last block's images with their components along the basis removed (`n x b`): the
    /// next block before its normalisation, and the residual of the projection `A Q - Q H`.
    w: Vec<f64>,
    /// Scratch: the envelope solves' right-hand sides by rows (`n x p`).
    rows: Vec<f64>,
    /// Scratch: one pass's coefficients (`m_max x p`).
    coef: Vec<f64>,
    noise: Noise,
    /// Columns of `Q` set.
    filled: usize,
    /// Columns of `Q` whose images `A q` are in `aq` and projected into `h`.
    applied: usize,
    /// The first column of the last block applied.
    last: usize,
}

impl<'a> Krylov<'a> {
    fn new(chol: &'a Skyline, mass: &[f64], p: usize, m_max: usize) -> Self {
        let n = chol.dim();
        Self {
            chol,
            n,
            m_max,
            sm: mass.iter().map(|m| m.sqrt()).collect(),
            q: vec![0.0; n * m_max],
            aq: vec![0.0; n * m_max],
            h: vec![0.0; m_max * m_max],
            w: vec![0.0; n * p],
            rows: vec![0.0; n * p],
            coef: vec![0.0; m_max * p],
            noise: Noise(StdRng::seed_from_u64(0x5EED_CE11)),
            filled: 0,
            applied: 0,
            last: 0,
        }
    }

    /// The pseudo-random start block of `p` columns; `false` if it could not be made
    /// orthonormal.
    fn start(&mut self, p: usize) -> bool {
        for v in &mut self.q[..self.n * p] {
            *v = self.noise.next();
        }
        self.filled = 0;
        self.extend_basis(p)
    }

    /// Applies `A` to the columns not yet applied (the last block, all at once) and projects
    /// the images on the basis: their columns of `H` and the residual block `w`. Returns the
    /// block's width.
    fn extend_image(&mut self) -> usize {
        let (n, from, to) = (self.n, self.applied, self.filled);
        let b = to - from;
        for (c, j) in (from..to).enumerate() {
            for (i, (x, s)) in self.q[j * n..(j + 1) * n].iter().zip(&self.sm).enumerate() {
                self.rows[i * b + c] = x * s;
            }
        }
        self.chol.solve_block_in_place(&mut self.rows[..n * b], b);
        for (c, j) in (from..to).enumerate() {
            let col = &mut self.aq[j * n..(j + 1) * n];
            for (i, (a, s)) in col.iter_mut().zip(&self.sm).enumerate() {
                *a = self.rows[i * b + c] * s;
            }
        }
        self.w[..n * b].copy_from_slice(&self.aq[from * n..to * n]);
        // Two passes of block Gram-Schmidt: the first on the last two blocks, where the
        // recurrence puts every component of the images in exact arithmetic, the second on the
        // whole basis (what the first left: its round-off, and the older blocks' drift).
        let prev = if from == 0 { 0 } else { self.last };
        self.project(prev..to, from, b);
        self.project(0..to, from, b);
        self.last = from;
        self.applied = to;
        b
    }

    /// One pass of block classical Gram-Schmidt: removes from the `b` columns of `w` their
    /// components along `Q`'s columns `cols`, adding the coefficients to those rows of `H`'s
    /// columns `hcol..hcol + b`.
    fn project(&mut self, cols: std::ops::Range<usize>, hcol: usize, b: usize) {
        let (n, k) = (self.n, cols.len());
        let basis = MatRef::from_column_major_slice(&self.q[cols.start * n..cols.end * n], n, k);
        let mut c = MatMut::from_column_major_slice_mut(&mut self.coef[..k * b], k, b);
        let w = MatRef::from_column_major_slice(&self.w[..n * b], n, b);
        let par = par_above(2 * n * k * b);
        matmul(c.as_mut(), Accum::Replace, basis.transpose(), w, 1.0, par);
        let w = MatMut::from_column_major_slice_mut(&mut self.w[..n * b], n, b);
        matmul(w, Accum::Add, basis, c.as_ref(), -1.0, par);
        for j in 0..b {
            let col = &mut self.h[(hcol + j) * self.m_max..][cols.clone()];
            for (hv, cv) in col.iter_mut().zip(&self.coef[j * k..(j + 1) * k]) {
                *hv += cv;
            }
        }
    }

    /// Appends `nb` columns to the basis: the first `nb` of the residual block `w` (or, at the
    /// start, the columns already in place), made orthonormal within themselves by two passes of
    /// modified Gram-Schmidt; a column that vanishes is replaced by a random direction
    /// orthogonal to the basis. `false` if no direction is left (the basis spans the space).
    fn extend_basis(&mut self, nb: usize) -> bool {
        let (n, from) = (self.n, self.filled);
        if from > 0 {
            self.q[from * n..(from + nb) * n].copy_from_slice(&self.w[..nb * n]);
        }
        for j in from..from + nb {
            let (done, rest) = self.q.split_at_mut(j * n);
            let w = &mut rest[..n];
            let before = dot(w, w).sqrt();
            let mut fresh = false;
            for attempt in 0..4 {
                for _ in 0..2 {
                    for i in from..j {
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
                // A vanished column: restart it from noise, orthogonal to the basis before the
                // block (twice), then to the block's columns by the passes above.
                w.iter_mut().for_each(|a| *a = self.noise.next());
                fresh = true;
                if from > 0 {
                    let basis = MatRef::from_column_major_slice(&done[..from * n], n, from);
                    let mut c =
                        MatMut::from_column_major_slice_mut(&mut self.coef[..from], from, 1);
                    for _ in 0..2 {
                        let wm = MatRef::from_column_major_slice(w, n, 1);
                        matmul(
                            c.as_mut(),
                            Accum::Replace,
                            basis.transpose(),
                            wm,
                            1.0,
                            Par::Seq,
                        );
                        let wm = MatMut::from_column_major_slice_mut(w, n, 1);
                        matmul(wm, Accum::Add, basis, c.as_ref(), -1.0, Par::Seq);
                    }
                }
            }
        }
        self.filled = from + nb;
        true
    }

    /// The `r` largest Ritz pairs of the columns applied (`None` if fewer than `r`).
    ///
    /// # Errors
    /// [`M1Error::Numerical`] for a non-positive Ritz value or a failed eigensolve.
    fn ritz(&self, r: usize) -> Result<Option<Ritz>, M1Error> {
        let (k, m_max) = (self.applied, self.m_max);
        if k < r || k == 0 {
            return Ok(None);
        }
        // H scaled to its largest diagonal entry: on H's own scale (about 4e-4 for TMT's cell)
        // faer's eigensolver left residuals |H s - theta s| near 1e-12 of the norm, on this
        // one near round-off.
        let scale = (0..k).map(|j| self.h[j * m_max + j]).fold(0.0, f64::max);
        if !(scale > 0.0 && scale.is_finite()) {
            return Err(M1Error::Numerical(format!(
                "the projected operator's largest diagonal entry is {scale:e}: the stiffness \
                 factor is not of a positive definite matrix"
            )));
        }
        let hs = faer::Mat::<f64>::from_fn(k, k, |i, j| {
            let (row, col) = if i <= j { (i, j) } else { (j, i) };
            self.h[col * m_max + row] / scale
        });
        let evd = hs
            .self_adjoint_eigen(Side::Lower)
            .map_err(|e| M1Error::Numerical(format!("Rayleigh-Ritz eigensolve: {e:?}")))?;
        let all = evd.S().column_vector();
        let u = evd.U();
        // The r largest, largest first (the lowest lambda first).
        let pick: Vec<usize> = (k - r..k).rev().collect();
        let theta: Vec<f64> = pick.iter().map(|&i| all[i] * scale).collect();
        if let Some(th) = theta.iter().find(|th| !(**th > 0.0 && th.is_finite())) {
            return Err(M1Error::Numerical(format!(
                "Ritz value {th:e} <= 0: the stiffness factor is not of a positive definite matrix"
            )));
        }
        Ok(Some(Ritz {
            theta_max: all[k - 1] * scale,
            theta,
            s: faer::Mat::<f64>::from_fn(k, r, |i, j| u[(i, pick[j])]),
        }))
    }

    /// The residuals `|A y - theta y|` of the Ritz pairs `(theta, y = Q s)` as the recurrence
    /// gives them: `A Q = Q H + W E^T` up to round-off (`E`: the last block's columns of the
    /// identity), so the residual is `|W s_last|`, from `W`'s Gram matrix and `s`'s last rows.
    fn estimated_residuals(&self, ritz: &Ritz) -> Vec<f64> {
        let (n, b) = (self.n, self.applied - self.last);
        let wm = MatRef::from_column_major_slice(&self.w[..n * b], n, b);
        let mut g = faer::Mat::<f64>::zeros(b, b);
        matmul(
            g.as_mut(),
            Accum::Replace,
            wm.transpose(),
            wm,
            1.0,
            Par::Seq,
        );
        (0..ritz.theta.len())
            .map(|j| {
                let sl = |a: usize| ritz.s[(self.last + a, j)];
                let sq: f64 = (0..b)
                    .map(|a| sl(a) * (0..b).map(|c| g[(a, c)] * sl(c)).sum::<f64>())
                    .sum();
                sq.max(0.0).sqrt()
            })
            .collect()
    }

    /// The Ritz vectors `y = Q s` (`n x r`) and their true residuals `|A y - theta y|` (from
    /// the stored images: `A y = (A Q) s`).
    fn true_residuals(&self, ritz: &Ritz) -> (faer::Mat<f64>, Vec<f64>) {
        let (n, k, r) = (self.n, self.applied, ritz.theta.len());
        let qk = MatRef::from_column_major_slice(&self.q[..n * k], n, k);
        let aqk = MatRef::from_column_major_slice(&self.aq[..n * k], n, k);
        let mut y = faer::Mat::<f64>::zeros(n, r);
        let mut ay = faer::Mat::<f64>::zeros(n, r);
        let par = par_above(2 * n * k * r);
        matmul(y.as_mut(), Accum::Replace, qk, ritz.s.as_ref(), 1.0, par);
        matmul(ay.as_mut(), Accum::Replace, aqk, ritz.s.as_ref(), 1.0, par);
        let res = (0..r)
            .map(|j| {
                let th = ritz.theta[j];
                (0..n)
                    .map(|row| (ay[(row, j)] - th * y[(row, j)]).powi(2))
                    .sum::<f64>()
                    .sqrt()
            })
            .collect();
        (y, res)
    }

    /// The Rayleigh-Ritz step on the columns applied: the `r` largest Ritz pairs, as eigenpairs
    /// of the generalised problem, if each one's true residual meets [`RESIDUAL`] (with
    /// [`Check::Estimate`], only once every estimated residual does).
    ///
    /// # Errors
    /// As [`Self::ritz`].
    fn rayleigh_ritz(&self, r: usize, check: Check) -> Result<Option<Eigenpairs>, M1Error> {
        let Some(ritz) = self.ritz(r)? else {
            return Ok(None);
        };
        let tol = RESIDUAL * ritz.theta_max;
        if check == Check::Estimate && self.estimated_residuals(&ritz).iter().any(|e| *e > tol) {
            return Ok(None);
        }
        let (y, res) = self.true_residuals(&ritz);
        if res.iter().any(|e| *e > tol) {
            return Ok(None);
        }
        let n = self.n;
        let mut vectors = vec![0.0; n * r];
        for (j, col) in vectors.chunks_exact_mut(n).enumerate() {
            for (row, (v, s)) in col.iter_mut().zip(&self.sm).enumerate() {
                *v = y[(row, j)] / s;
            }
        }
        Ok(Some(Eigenpairs {
            values: ritz.theta.iter().map(|th| 1.0 / th).collect(),
            vectors,
            krylov_dim: self.applied,
        }))
    }
}

/// Ritz pairs of the projected operator.
struct Ritz {
    /// The wanted Ritz values, largest first.
    theta: Vec<f64>,
    /// Their coefficients in the basis, `k x r`.
    s: faer::Mat<f64>,
    /// The largest Ritz value (the operator's norm, as far as the space shows it).
    theta_max: f64,
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
    fn the_recurrences_residual_estimate_is_the_true_residual() {
        // Step by step on a chain, for converged and unconverged pairs alike: the estimate from
        // the last block (|W s_last|) and the true |A y - theta y| agree to round-off, far
        // below the acceptance bound, while the residuals themselves span many decades.
        let n = 300;
        let (k, mass) = chain(n);
        let chol = Skyline::factor(n, &k).unwrap();
        let r = 8;
        let mut kr = Krylov::new(&chol, &mass, 4, 120);
        assert!(kr.start(4));
        let (mut compared, mut largest, mut smallest) = (0, 0.0f64, f64::INFINITY);
        for _ in 0..25 {
            let b = kr.extend_image();
            if let Some(ritz) = kr.ritz(r).unwrap() {
                let est = kr.estimated_residuals(&ritz);
                let (_, truth) = kr.true_residuals(&ritz);
                for (j, (e, t)) in est.iter().zip(&truth).enumerate() {
                    let rel = (e - t).abs() / ritz.theta_max;
                    assert!(
                        rel <= 1e-14,
                        "k = {}, pair {j}: estimate {e:e}, true {t:e}",
                        kr.applied
                    );
                    largest = largest.max(t / ritz.theta_max);
                    smallest = smallest.min(t / ritz.theta_max);
                    compared += 1;
                }
            }
            assert!(kr.extend_basis(b));
        }
        assert!(compared >= 100, "{compared} pairs compared");
        assert!(
            largest > 1e-3 && smallest < 1e-13,
            "residuals {smallest:e}..{largest:e}"
        );
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
