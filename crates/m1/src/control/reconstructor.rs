//! The reconstructor: actuator displacements estimated from edge-sensor readings, with global
//! piston/tip/tilt projected out and chosen modal gains.
//!
//! # Equations
//!
//! With $A$ ($n_s \times n_a$) the interaction matrix and $N$ an orthonormal basis of the modes
//! to project out (global piston, tip and tilt; exactly unobservable on a flat mirror, weakly
//! observable through the curvature otherwise), the estimate is the least-squares solution
//! orthogonal to $N$:
//! $$\hat z = B_0 y = (A P)^+ y, \qquad P = I - N N^T,$$
//! so that $B_0 A P = P$. On a flat mirror $A N = 0$ and $B_0 = A^+$. Modal gains scale chosen
//! orthonormal modes $\psi_k$ (e.g. focus-mode) by $\gamma_k$:
//! $$B = \left(I - \sum_k (1 - \gamma_k)\psi_k\psi_k^T\right) B_0 .$$
//!
//! Two exact paths compute $B y$:
//! - **dense**: $B$ formed once from the SVD of $A P$ (a dense matrix-vector product per use);
//! - **sparse**: the constrained normal equations $A^T A z + N\lambda = A^T y$, $N^T z = 0$ are
//!   solved with the sparse, block-structured (3 x 3 per segment) matrix
//!   $K = A^T A + G G^T$, where $G = \sqrt\beta\,[e_{p_1} \dots e_{p_k}]$ pins one actuator per
//!   column of $N$ (chosen by pivoted Gram-Schmidt on the rows of $N$, $\beta$ the mean diagonal
//!   of $A^T A$) so that $K$ is well conditioned even where $A N \approx 0$. Writing
//!   $A^T A = K - G G^T$, the solution is $z = x_0 + Z\,[c; \lambda]$ with $x_0 = K^{-1} A^T y$,
//!   $Z = [K^{-1} G, -K^{-1} N]$ and the $2k \times 2k$ system from $c = G^T z$, $N^T z = 0$:
//!   one block Cholesky solve ([`crate::linalg::blockchol`]) and $2k$ dot products and updates per
//!   use, no refinement step needed (agreement with the dense path ~1e-11 on TMT).

use faer::sparse::SparseColMat;
use faer::{Mat, MatRef};

use crate::M1Error;
use crate::linalg::blockchol::{Block, BlockCholesky};

/// One modal gain: an orthonormal mode (length n_a) and its gain (1 = unchanged).
#[derive(Debug, Clone)]
pub struct ModalGain {
    /// The mode shape, unit norm, orthogonal to the null space and to the other modes.
    pub mode: Vec<f64>,
    /// Its gain.
    pub gain: f64,
}

fn csc_parts(a: &SparseColMat<usize, f64>) -> (&[usize], &[usize], &[f64]) {
    let s = a.symbolic();
    (s.col_ptr(), s.row_idx(), a.val())
}

/// $y \mapsto A^T y$ for a CSC matrix (columns are actuators).
pub fn at_mul(a: &SparseColMat<usize, f64>, y: &[f64], out: &mut [f64]) {
    let (cp, ri, v) = csc_parts(a);
    for (j, o) in out.iter_mut().enumerate() {
        let mut s = 0.0;
        for k in cp[j]..cp[j + 1] {
            s += v[k] * y[ri[k]];
        }
        *o = s;
    }
}

/// $y = A x$ for a CSC matrix.
pub fn sparse_mul(a: &SparseColMat<usize, f64>, x: &[f64], y: &mut [f64]) {
    let (cp, ri, v) = csc_parts(a);
    y.fill(0.0);
    for (j, xj) in x.iter().enumerate() {
        for k in cp[j]..cp[j + 1] {
            y[ri[k]] += v[k] * xj;
        }
    }
}

/// Chooses `k` actuators to pin: pivoted Gram-Schmidt on the rows of the null-space basis, so
/// the pinned k x k block of N is as well conditioned as a greedy choice allows.
fn choose_pins(null: MatRef<'_, f64>) -> Vec<usize> {
    let (n, k) = (null.nrows(), null.ncols());
    // Work on the columns of N^T (rows of N).
    let mut rows: Vec<Vec<f64>> = (0..n)
        .map(|i| (0..k).map(|j| null[(i, j)]).collect())
        .collect();
    let mut pins = Vec::with_capacity(k);
    for _ in 0..k {
        let (best, _) = rows
            .iter()
            .enumerate()
            .filter(|(i, _)| !pins.contains(i))
            .map(|(i, r)| (i, r.iter().map(|x| x * x).sum::<f64>()))
            .fold((0, -1.0), |acc, x| if x.1 > acc.1 { x } else { acc });
        pins.push(best);
        let p = rows[best].clone();
        let pn: f64 = p.iter().map(|x| x * x).sum();
        if pn > 0.0 {
            for r in rows.iter_mut() {
                let d: f64 = r.iter().zip(&p).map(|(a, b)| a * b).sum::<f64>() / pn;
                for (x, y) in r.iter_mut().zip(&p) {
                    *x -= d * y;
                }
            }
        }
    }
    pins.sort_unstable();
    pins
}

/// Block size of the normal matrix: the three actuators of a segment.
const BLOCK: usize = 3;

/// Most modes the sparse path projects out (global piston/tip/tilt are 3; rigid-body 6).
const MAX_PROJECTED: usize = 8;

/// The sparse reconstructor.
#[derive(Debug, Clone)]
pub struct SparseReconstructor {
    a: SparseColMat<usize, f64>,
    /// Block Cholesky factor of $K = A^T A + G G^T$ (padded to a multiple of the block size).
    chol: BlockCholesky<BLOCK>,
    /// The pinned actuators and $\sqrt\beta$ (so $G = \sqrt\beta\,[e_p]$).
    pins: Vec<usize>,
    sqrt_beta: f64,
    /// N (orthonormal).
    null: Mat<f64>,
    /// $Z = [K^{-1} G, -K^{-1} N]$ ($n_a \times 2k$).
    z: Mat<f64>,
    /// $H = M^{-1}$, the inverse of the $2k \times 2k$ constraint system.
    h: Mat<f64>,
    modes: Vec<ModalGain>,
}

fn invert_small(m: &Mat<f64>) -> Result<Mat<f64>, M1Error> {
    let n = m.nrows();
    let d = nalgebra::DMatrix::from_fn(n, n, |i, j| m[(i, j)]);
    let inv = d
        .try_inverse()
        .ok_or_else(|| M1Error::Numerical("singular small matrix in the reconstructor".into()))?;
    Ok(Mat::from_fn(n, n, |i, j| inv[(i, j)]))
}

impl SparseReconstructor {
    /// Factorises the reconstructor of `a` with the columns of `null` (any basis of the modes to
    /// project out, e.g. global piston/tip/tilt; orthonormalised here) projected out.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for a null-space basis or mode of the wrong length,
    /// [`M1Error::Numerical`] if $A$ has unobservable modes beyond those of `null`.
    pub fn new(
        a: &SparseColMat<usize, f64>,
        null: MatRef<'_, f64>,
        modes: Vec<ModalGain>,
    ) -> Result<Self, M1Error> {
        let na = a.ncols();
        if null.nrows() != na {
            return Err(M1Error::SizeMismatch {
                what: "null-space basis rows",
                expected: na,
                found: null.nrows(),
            });
        }
        for m in &modes {
            if m.mode.len() != na {
                return Err(M1Error::SizeMismatch {
                    what: "modal gain mode",
                    expected: na,
                    found: m.mode.len(),
                });
            }
        }
        let null = orthonormalize(null);
        let k = null.ncols();
        if k > MAX_PROJECTED {
            return Err(M1Error::InvalidInput(format!(
                "{k} modes to project out; the sparse reconstructor takes at most {MAX_PROJECTED}"
            )));
        }
        let pins = choose_pins(null.as_ref());
        let nb = na.div_ceil(BLOCK);
        // K = A^T A + beta sum_p e_p e_p^T in blocks, from the rows of A (each row couples
        // few actuators); beta = mean diagonal of A^T A keeps K's scale.
        let (cp, ri, v) = csc_parts(a);
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); a.nrows()];
        let mut diag_sum = 0.0;
        for j in 0..na {
            for kk in cp[j]..cp[j + 1] {
                rows[ri[kk]].push((j, v[kk]));
                diag_sum += v[kk] * v[kk];
            }
        }
        let beta = if diag_sum > 0.0 {
            diag_sum / na as f64
        } else {
            1.0
        };
        let mut blocks: Vec<(usize, usize, Block<BLOCK>)> = Vec::new();
        for row in &rows {
            for &(p, x) in row {
                for &(q, y) in row {
                    let (bp, bq) = (p / BLOCK, q / BLOCK);
                    if bp >= bq {
                        let mut b = [[0.0; BLOCK]; BLOCK];
                        b[p % BLOCK][q % BLOCK] = x * y;
                        blocks.push((bp, bq, b));
                    }
                }
            }
        }
        for &p in &pins {
            let mut b = [[0.0; BLOCK]; BLOCK];
            b[p % BLOCK][p % BLOCK] = beta;
            blocks.push((p / BLOCK, p / BLOCK, b));
        }
        // Padding unknowns (when n_a is not a multiple of the block size) are decoupled.
        for p in na..nb * BLOCK {
            let mut b = [[0.0; BLOCK]; BLOCK];
            b[p % BLOCK][p % BLOCK] = 1.0;
            blocks.push((p / BLOCK, p / BLOCK, b));
        }
        let chol = BlockCholesky::<BLOCK>::new(nb, &blocks).map_err(|e| match e {
            M1Error::Numerical(msg) => M1Error::Numerical(format!(
                "A^T A with {} pinned actuators is not positive definite ({msg}): A has \
                 unobservable modes beyond the {k} projected out",
                pins.len()
            )),
            other => other,
        })?;
        let sqrt_beta = beta.sqrt();
        // Z = [K^-1 G, -K^-1 N].
        let mut z = Mat::<f64>::zeros(na, 2 * k);
        let mut col = vec![0.0; nb * BLOCK];
        let mut work = vec![0.0; nb * BLOCK];
        for c in 0..2 * k {
            col.fill(0.0);
            if c < k {
                col[pins[c]] = sqrt_beta;
            } else {
                for i in 0..na {
                    col[i] = null[(i, c - k)];
                }
            }
            chol.solve_in_place(&mut col, &mut work);
            let sign = if c < k { 1.0 } else { -1.0 };
            for i in 0..na {
                z[(i, c)] = sign * col[i];
            }
        }
        // With z = x0 + Z [c; l], c = G^T z and N^T z = 0:
        // M = [[I - G^T Z_G, -G^T Z_N], [N^T Z_G, N^T Z_N]] (Z_N = -K^-1 N),
        // M [c; l] = [G^T x0; -N^T x0].
        let mut m = Mat::<f64>::zeros(2 * k, 2 * k);
        for c in 0..2 * k {
            for r in 0..k {
                let gz = sqrt_beta * z[(pins[r], c)];
                m[(r, c)] = if r == c { 1.0 - gz } else { -gz };
                m[(k + r, c)] = (0..na).map(|i| null[(i, r)] * z[(i, c)]).sum();
            }
        }
        let h = invert_small(&m)?;
        Ok(Self {
            a: a.clone(),
            chol,
            pins,
            sqrt_beta,
            null,
            z,
            h,
            modes,
        })
    }

    /// $v \mapsto z$: the constrained solution $z = (I + Z H R) K^{-1} v$ with
    /// $R x = [G^T x; -N^T x]$. `x` holds $v$ (padded) on entry and $z$ on exit.
    fn solve_constrained(&self, x: &mut [f64], work: &mut [f64]) {
        self.chol.solve_in_place(x, work);
        let k = self.pins.len();
        let mut r = [0.0; 2 * MAX_PROJECTED];
        let r = &mut r[..2 * k];
        for (c, &p) in self.pins.iter().enumerate() {
            r[c] = self.sqrt_beta * x[p];
            r[k + c] = -dot(self.null.col(c), x);
        }
        for c in 0..2 * k {
            let coef: f64 = (0..2 * k).map(|q| self.h[(c, q)] * r[q]).sum();
            axpy(coef, self.z.col(c), x);
        }
    }

    /// $v \mapsto (I + R^T H^T Z^T) v$, the transpose of the correction in
    /// [`Self::solve_constrained`], applied before $K^{-1}$.
    fn correct_transposed(&self, v: &mut [f64]) {
        let k = self.pins.len();
        let mut zt = [0.0; 2 * MAX_PROJECTED];
        let zt = &mut zt[..2 * k];
        for (c, t) in zt.iter_mut().enumerate() {
            *t = dot(self.z.col(c), v);
        }
        for q in 0..2 * k {
            let coef: f64 = (0..2 * k).map(|c| self.h[(c, q)] * zt[c]).sum();
            if q < k {
                v[self.pins[q]] += self.sqrt_beta * coef;
            } else {
                axpy(-coef, self.null.col(q - k), v);
            }
        }
    }

    /// The factor's dimension (n_a rounded up to whole blocks).
    fn padded(&self) -> usize {
        self.chol.dim()
    }

    /// $\hat z = B y$ into `z` (length n_a), without allocating: `work` must hold
    /// [`Self::work_len`] values.
    ///
    /// # Panics
    /// If a slice has the wrong length.
    pub fn apply_into(&self, y: &[f64], z: &mut [f64], work: &mut [f64]) {
        let na = self.a.ncols();
        let n = self.padded();
        assert_eq!(y.len(), self.a.nrows(), "reading vector length");
        assert_eq!(z.len(), na, "estimate length");
        assert_eq!(work.len(), 2 * n, "work length");
        let (x, w) = work.split_at_mut(n);
        at_mul(&self.a, y, &mut x[..na]);
        x[na..].fill(0.0);
        self.solve_constrained(x, w);
        z.copy_from_slice(&x[..na]);
        apply_modal_gains(&self.modes, z);
    }

    /// Length of the `work` slice of [`Self::apply_into`].
    pub fn work_len(&self) -> usize {
        2 * self.padded()
    }

    /// $\hat z = B y$.
    pub fn apply(&self, y: &[f64]) -> Vec<f64> {
        let mut z = vec![0.0; self.a.ncols()];
        let mut work = vec![0.0; self.work_len()];
        self.apply_into(y, &mut z, &mut work);
        z
    }

    /// $y = B^T x$ (length n_s): the transpose of [`Self::apply`], for singular-value
    /// estimates of products with B.
    pub fn apply_transpose(&self, x: &[f64]) -> Vec<f64> {
        let na = self.a.ncols();
        let n = self.padded();
        let mut v = vec![0.0; n];
        v[..na].copy_from_slice(x);
        apply_modal_gains(&self.modes, &mut v[..na]);
        self.correct_transposed(&mut v[..na]);
        let mut work = vec![0.0; n];
        self.chol.solve_in_place(&mut v, &mut work);
        let mut y = vec![0.0; self.a.nrows()];
        sparse_mul(&self.a, &v[..na], &mut y);
        y
    }

    /// Number of actuators and sensors.
    pub fn shape(&self) -> (usize, usize) {
        (self.a.ncols(), self.a.nrows())
    }

    /// The basis it projects out (orthonormal columns).
    pub fn null_space(&self) -> MatRef<'_, f64> {
        self.null.as_ref()
    }

    /// Number of 3 x 3 blocks in the Cholesky factor (its memory is 72 bytes per block).
    pub fn factor_blocks(&self) -> usize {
        self.chol.n_blocks()
    }
}

fn dot(a: faer::ColRef<'_, f64>, b: &[f64]) -> f64 {
    let mut s = 0.0;
    for (i, bi) in b.iter().enumerate().take(a.nrows()) {
        s += a[i] * bi;
    }
    s
}

fn axpy(alpha: f64, a: faer::ColRef<'_, f64>, y: &mut [f64]) {
    for (i, yi) in y.iter_mut().enumerate().take(a.nrows()) {
        *yi += alpha * a[i];
    }
}

/// Orthonormalises the columns of `m` (modified Gram-Schmidt, two passes).
pub fn orthonormalize(m: MatRef<'_, f64>) -> Mat<f64> {
    let mut q = m.to_owned();
    for j in 0..q.ncols() {
        for _ in 0..2 {
            for i in 0..j {
                let d: f64 = (0..q.nrows()).map(|r| q[(r, i)] * q[(r, j)]).sum();
                for r in 0..q.nrows() {
                    q[(r, j)] -= d * q[(r, i)];
                }
            }
        }
        let n = (0..q.nrows())
            .map(|r| q[(r, j)] * q[(r, j)])
            .sum::<f64>()
            .sqrt();
        if n > 0.0 {
            for r in 0..q.nrows() {
                q[(r, j)] /= n;
            }
        }
    }
    q
}

fn apply_modal_gains(modes: &[ModalGain], z: &mut [f64]) {
    for m in modes {
        let d: f64 = m.mode.iter().zip(z.iter()).map(|(a, b)| a * b).sum();
        let f = (1.0 - m.gain) * d;
        for (zi, mi) in z.iter_mut().zip(&m.mode) {
            *zi -= f * mi;
        }
    }
}

/// The dense reconstructor: $B$ formed from the SVD of $A$.
pub struct DenseReconstructor {
    /// $B$ ($n_a \times n_s$).
    pub b: Mat<f64>,
    /// Singular values of $A$ kept (the observable ones), largest first.
    pub singular_values: Vec<f64>,
}

impl DenseReconstructor {
    /// $(A P)^+$ over the singular values above `rel_tol` times the largest, with
    /// $P = I - N N^T$ for the columns of `null` (orthonormalised here), then modal gains.
    pub fn new(
        a: MatRef<'_, f64>,
        null: MatRef<'_, f64>,
        rel_tol: f64,
        modes: &[ModalGain],
    ) -> Result<Self, M1Error> {
        let n = orthonormalize(null);
        let ap = a.to_owned() - (a * &n) * n.transpose();
        let a = ap.as_ref();
        let svd = a
            .thin_svd()
            .map_err(|e| M1Error::Numerical(format!("SVD of A did not converge: {e:?}")))?;
        let s = svd.S().column_vector();
        let smax = (0..s.nrows()).map(|i| s[i]).fold(0.0, f64::max);
        let keep: Vec<usize> = (0..s.nrows()).filter(|&i| s[i] > rel_tol * smax).collect();
        let (u, v) = (svd.U(), svd.V());
        let (na, ns) = (a.ncols(), a.nrows());
        // B0 = V_k S_k^-1 U_k^T
        let mut vs = Mat::<f64>::zeros(na, keep.len());
        let mut uk = Mat::<f64>::zeros(ns, keep.len());
        for (c, &i) in keep.iter().enumerate() {
            for r in 0..na {
                vs[(r, c)] = v[(r, i)] / s[i];
            }
            for r in 0..ns {
                uk[(r, c)] = u[(r, i)];
            }
        }
        let mut b = &vs * uk.transpose();
        for m in modes {
            // B <- (I - (1 - g) m m^T) B
            let mut mt_b = vec![0.0; ns];
            for (c, x) in mt_b.iter_mut().enumerate() {
                *x = (0..na).map(|r| m.mode[r] * b[(r, c)]).sum();
            }
            for c in 0..ns {
                for r in 0..na {
                    b[(r, c)] -= (1.0 - m.gain) * m.mode[r] * mt_b[c];
                }
            }
        }
        Ok(Self {
            b,
            singular_values: keep.iter().map(|&i| s[i]).collect(),
        })
    }

    /// $\hat z = B y$.
    pub fn apply(&self, y: &[f64]) -> Vec<f64> {
        let yv = faer::Col::<f64>::from_fn(self.b.ncols(), |i| y[i]);
        let z = &self.b * &yv;
        (0..z.nrows()).map(|i| z[i]).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::Triplet;

    /// A ring of n nodes with differences between neighbours: null space = constants; `leak`
    /// adds a weak absolute reading so the constant is only weakly observable (full rank).
    fn ring_with(n: usize, leak: f64) -> (SparseColMat<usize, f64>, Mat<f64>) {
        let mut t = Vec::new();
        for i in 0..n {
            t.push(Triplet::new(i, i, 1.0 + 0.1 * i as f64));
            t.push(Triplet::new(i, (i + 1) % n, -(1.0 + 0.1 * i as f64)));
            // Second sensor on the same pair, other weights.
            t.push(Triplet::new(n + i, i, 0.5));
            t.push(Triplet::new(n + i, (i + 1) % n, -0.5));
            if leak != 0.0 {
                t.push(Triplet::new(n + i, i, leak * (1.0 + (i % 3) as f64)));
            }
        }
        let a = SparseColMat::try_new_from_triplets(2 * n, n, &t).expect("triplets");
        let null = Mat::from_fn(n, 1, |_, _| 1.0 / (n as f64).sqrt());
        (a, null)
    }

    fn ring(n: usize) -> (SparseColMat<usize, f64>, Mat<f64>) {
        ring_with(n, 0.0)
    }

    #[test]
    fn weakly_observable_modes_are_projected_out_exactly() {
        let n = 30;
        let (a, null) = ring_with(n, 1e-4);
        let sp = SparseReconstructor::new(&a, null.as_ref(), vec![]).expect("sparse");
        let de = DenseReconstructor::new(a.to_dense().as_ref(), null.as_ref(), 1e-12, &[])
            .expect("dense");
        let y: Vec<f64> = (0..2 * n).map(|i| (i as f64 * 1.3).sin()).collect();
        let (zs, zd) = (sp.apply(&y), de.apply(&y));
        let scale = zd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for (a, b) in zs.iter().zip(&zd) {
            assert!((a - b).abs() <= 1e-9 * scale, "{a} vs {b}");
        }
        // B0 A P = P: a pattern orthogonal to the constant comes back unchanged.
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.4).cos()).collect();
        let mean = x.iter().sum::<f64>() / n as f64;
        let x: Vec<f64> = x.iter().map(|v| v - mean).collect();
        let mut ax = vec![0.0; 2 * n];
        let ad = a.to_dense();
        for r in 0..2 * n {
            ax[r] = (0..n).map(|c| ad[(r, c)] * x[c]).sum();
        }
        let back = sp.apply(&ax);
        for (a, b) in back.iter().zip(&x) {
            assert!((a - b).abs() < 1e-9, "{a} vs {b}");
        }
    }

    #[test]
    fn sparse_equals_dense_pseudo_inverse() {
        let n = 40;
        let (a, null) = ring(n);
        let mode: Vec<f64> = {
            let v: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).sin()).collect();
            let mean = v.iter().sum::<f64>() / n as f64;
            let v: Vec<f64> = v.iter().map(|x| x - mean).collect();
            let norm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            v.iter().map(|x| x / norm).collect()
        };
        let modes = vec![ModalGain { mode, gain: 0.25 }];
        let sp = SparseReconstructor::new(&a, null.as_ref(), modes.clone()).expect("sparse");
        let de = DenseReconstructor::new(a.to_dense().as_ref(), null.as_ref(), 1e-10, &modes)
            .expect("dense");
        let y: Vec<f64> = (0..2 * n).map(|i| ((i * 7) % 11) as f64 - 5.0).collect();
        let zs = sp.apply(&y);
        let zd = de.apply(&y);
        let scale = zd.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        for (a, b) in zs.iter().zip(&zd) {
            assert!((a - b).abs() <= 1e-9 * scale, "{a} vs {b}");
        }
        // Orthogonal to the null space.
        let s: f64 = zs.iter().sum();
        assert!(s.abs() < 1e-9 * scale);
        // The transpose agrees with the dense B^T.
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).cos()).collect();
        let ys = sp.apply_transpose(&x);
        for (c, yc) in ys.iter().enumerate() {
            let yd: f64 = (0..n).map(|r| de.b[(r, c)] * x[r]).sum();
            assert!((yc - yd).abs() <= 1e-9 * scale.max(1.0), "{yc} vs {yd}");
        }
    }
}
