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
//! - **sparse**: the constraint $N^T z = 0$ is solved for one pinned actuator per column of $N$
//!   (pins chosen by pivoted Gram-Schmidt on the rows of $N$): $z = E z_r$ with
//!   $z_p = -N_p^{-T} N_r^T z_r$. Then $A E = A_r - U N_r^T$ with $U = A_p N_p^{-T}$ (three
//!   columns), and the normal matrix $E^T A^T A E = K + W C W^T$ is the sparse
//!   $K = A_r^T A_r$ (sparse Cholesky) plus a rank-6 term handled by the Woodbury identity.

use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, MatRef, Side};

use crate::M1Error;

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

/// The sparse reconstructor.
pub struct SparseReconstructor {
    a: SparseColMat<usize, f64>,
    /// Full index of each reduced unknown.
    keep: Vec<usize>,
    /// The pinned actuators.
    pins: Vec<usize>,
    llt: faer::sparse::linalg::solvers::Llt<usize, f64>,
    /// N (orthonormal), and its rows at the kept indices.
    null: Mat<f64>,
    /// T = N_p^{-T} (k x k).
    t: Mat<f64>,
    /// W = [A_r^T U, N_r] and Y = K^{-1} W (n x 2k).
    w: Mat<f64>,
    y: Mat<f64>,
    /// S^{-1} with S = C^{-1} + W^T K^{-1} W (2k x 2k).
    s_inv: Mat<f64>,
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
    pub fn new(
        a: &SparseColMat<usize, f64>,
        null: MatRef<'_, f64>,
        modes: Vec<ModalGain>,
    ) -> Result<Self, M1Error> {
        use faer::linalg::solvers::Solve;
        let na = a.ncols();
        let ns = a.nrows();
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
        let pins = choose_pins(null.as_ref());
        let keep: Vec<usize> = (0..na).filter(|i| pins.binary_search(i).is_err()).collect();
        let mut reduced_of = vec![usize::MAX; na];
        for (r, &i) in keep.iter().enumerate() {
            reduced_of[i] = r;
        }
        // K = A_r^T A_r, lower triangle, from the rows of A (each row couples few actuators).
        let (cp, ri, v) = csc_parts(a);
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::new(); ns];
        for j in 0..na {
            if reduced_of[j] == usize::MAX {
                continue;
            }
            for kk in cp[j]..cp[j + 1] {
                rows[ri[kk]].push((reduced_of[j], v[kk]));
            }
        }
        let mut trip = Vec::new();
        for row in &rows {
            for &(p, x) in row {
                for &(q, y) in row {
                    if p >= q {
                        trip.push(Triplet::new(p, q, x * y));
                    }
                }
            }
        }
        let n = keep.len();
        let ata = SparseColMat::<usize, f64>::try_new_from_triplets(n, n, &trip)
            .map_err(|e| M1Error::Numerical(format!("building A^T A: {e:?}")))?;
        let llt = ata.sp_cholesky(Side::Lower).map_err(|e| {
            M1Error::Numerical(format!(
                "A^T A with {} pinned actuators is not positive definite ({e:?}): A has \
                 unobservable modes beyond the {k} projected out",
                pins.len()
            ))
        })?;
        // T = N_p^{-T}, U = A_p T.
        let np = Mat::from_fn(k, k, |i, j| null[(pins[i], j)]);
        let t = invert_small(&np.transpose().to_owned())?;
        let mut ap = Mat::<f64>::zeros(ns, k);
        for (c, &p) in pins.iter().enumerate() {
            for kk in cp[p]..cp[p + 1] {
                ap[(ri[kk], c)] = v[kk];
            }
        }
        let u = &ap * &t;
        // W = [A_r^T U, N_r].
        let mut w = Mat::<f64>::zeros(n, 2 * k);
        let mut col = vec![0.0; na];
        for c in 0..k {
            let uc: Vec<f64> = (0..ns).map(|r| u[(r, c)]).collect();
            at_mul(a, &uc, &mut col);
            for (r, &i) in keep.iter().enumerate() {
                w[(r, c)] = col[i];
                w[(r, k + c)] = null[(i, c)];
            }
        }
        let mut y = w.clone();
        llt.solve_in_place(y.as_mut());
        // C^{-1} = [[-U^T U, -I], [-I, 0]].
        let utu = u.transpose() * &u;
        let mut s_mat = w.transpose() * &y;
        for i in 0..k {
            for j in 0..k {
                s_mat[(i, j)] -= utu[(i, j)];
            }
            s_mat[(i, k + i)] -= 1.0;
            s_mat[(k + i, i)] -= 1.0;
        }
        let s_inv = invert_small(&s_mat)?;
        Ok(Self {
            a: a.clone(),
            keep,
            pins,
            llt,
            null,
            t,
            w,
            y,
            s_inv,
            modes,
        })
    }

    /// $x \leftarrow M^{-1} x$ for the reduced normal matrix $M = K + W C W^T$ (Woodbury).
    fn solve_reduced(&self, x: &mut Mat<f64>) {
        use faer::linalg::solvers::Solve;
        self.llt.solve_in_place(x.as_mut());
        let wt_x = self.w.transpose() * &*x;
        let corr = &self.y * (&self.s_inv * wt_x);
        for r in 0..x.nrows() {
            x[(r, 0)] -= corr[(r, 0)];
        }
    }

    /// $z = E z_r$: the pinned entries from the constraint $N^T z = 0$.
    fn expand(&self, zr: &Mat<f64>, z: &mut [f64]) {
        let k = self.pins.len();
        z.fill(0.0);
        for (r, &i) in self.keep.iter().enumerate() {
            z[i] = zr[(r, 0)];
        }
        // z_p = -T N_r^T z_r
        let mut nrz = vec![0.0; k];
        for (c, v) in nrz.iter_mut().enumerate() {
            *v = self
                .keep
                .iter()
                .enumerate()
                .map(|(r, &i)| self.null[(i, c)] * zr[(r, 0)])
                .sum();
        }
        for (pi, &p) in self.pins.iter().enumerate() {
            z[p] = -(0..k).map(|c| self.t[(pi, c)] * nrz[c]).sum::<f64>();
        }
    }

    /// $E^T x$ (length n_a - k).
    fn restrict(&self, x: &[f64]) -> Mat<f64> {
        let k = self.pins.len();
        // E^T x = x_r - N_r T^T x_p
        let xp: Vec<f64> = self.pins.iter().map(|&p| x[p]).collect();
        let ttxp: Vec<f64> = (0..k)
            .map(|c| (0..k).map(|pi| self.t[(pi, c)] * xp[pi]).sum())
            .collect();
        Mat::from_fn(self.keep.len(), 1, |r, _| {
            let i = self.keep[r];
            x[i] - (0..k).map(|c| self.null[(i, c)] * ttxp[c]).sum::<f64>()
        })
    }

    /// $\hat z = B y$.
    pub fn apply(&self, y: &[f64]) -> Vec<f64> {
        let na = self.a.ncols();
        let mut aty = vec![0.0; na];
        at_mul(&self.a, y, &mut aty);
        // E^T A^T y = A_r^T y - N_r U^T y, and the pinned rows of A^T y enter through E^T.
        let b = self.restrict(&aty);
        let mut zr = b.clone();
        self.solve_reduced(&mut zr);
        // One step of iterative refinement on the normal equations E^T A^T A E z_r = b: the
        // factorisation's error grows with the condition number of A^T A.
        let mut z = vec![0.0; na];
        self.expand(&zr, &mut z);
        let mut az = vec![0.0; self.a.nrows()];
        sparse_mul(&self.a, &z, &mut az);
        at_mul(&self.a, &az, &mut aty);
        let mut r = self.restrict(&aty);
        for i in 0..r.nrows() {
            r[(i, 0)] = b[(i, 0)] - r[(i, 0)];
        }
        self.solve_reduced(&mut r);
        for i in 0..zr.nrows() {
            zr[(i, 0)] += r[(i, 0)];
        }
        self.expand(&zr, &mut z);
        apply_modal_gains(&self.modes, &mut z);
        z
    }

    /// $y = B^T x = A E M^{-1} E^T G x$ (length n_s): the transpose of [`Self::apply`], for
    /// singular-value estimates of products with B.
    pub fn apply_transpose(&self, x: &[f64]) -> Vec<f64> {
        let mut v = x.to_vec();
        apply_modal_gains(&self.modes, &mut v);
        let mut r = self.restrict(&v);
        self.solve_reduced(&mut r);
        let mut z = vec![0.0; self.a.ncols()];
        self.expand(&r, &mut z);
        let mut y = vec![0.0; self.a.nrows()];
        sparse_mul(&self.a, &z, &mut y);
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
