//! Factorisation of the modes' complex symmetric stiffness $K = K^T$ (not Hermitian) for the
//! frequency sweeps: $K = L D L^T$ without pivoting (half the arithmetic of an LU) where that is
//! stable, faer's partially pivoted LU where it is not ([`ModalFactor`]).
//!
//! The modal stiffness of the frequency model, $D(\omega) - \sum_k c_k(\omega) \Phi_k^T \Phi_k$
//! with a diagonal $D$ and complex scalars $c_k$, is complex symmetric. Elimination without
//! pivoting needs no row exchange to keep it symmetric, and costs $n^3/3$ complex multiply-adds
//! against $2n^3/3$ for the LU; it is backward stable when its factors do not grow (for
//! example where the Hermitian part of $e^{i\theta} K$ is definite for some $\theta$, as for a
//! complex multiple of a positive definite matrix: bounded growth). The factors' growth is
//! checked after the factorisation: with $|L| |D| |L^T|$ the product of the entries' moduli,
//! the backward error is at most a small multiple of $n \varepsilon \| |L| |D| |L^T| \|$, so the
//! factorisation is kept when $\| |L| |D| |L^T| \|_\infty \le$ [`GROWTH_LIMIT`] $\|K\|_\infty$
//! and every pivot is finite and non-zero; otherwise the LU is computed instead. (Both norms
//! take $|\mathrm{re}| + |\mathrm{im}|$ as an entry's size, within $\sqrt 2$ of its modulus
//! and cheaper.)
//!
//! The factorisation is blocked: each panel of [`PANEL`] columns is eliminated column by
//! column over its whole height (vector updates), the trailing lower triangle updated by the
//! panel in one matrix product (faer's triangular matmul, the flops' bulk).
//!
//! Solves with one right-hand side use the factors repacked on the first such solve
//! ([`PackedLdlt`]: one contiguous stream, real and imaginary parts apart); $K^{-H} b =
//! \overline{K^{-1} \bar b}$ for a symmetric $K$. Solves with many use faer's triangular solves
//! on the factors in place.

use faer::linalg::matmul::triangular::{BlockStructure, matmul as tri_matmul};
use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::{Accum, Mat, MatMut, MatRef, Par, c64};
use pulp::Simd;

use std::sync::OnceLock;

use super::kernels::{axpy_c64, column_c64};
use super::lu_solve;
use super::packed_ldlt::PackedLdlt;

/// Columns per panel of the blocked factorisation.
pub const PANEL: usize = 48;
/// The largest $\| |L| |D| |L^T| \|_\infty / \|K\|_\infty$ kept: beyond it the LU is used.
pub const GROWTH_LIMIT: f64 = 64.0;

/// The factors of a complex symmetric matrix: $L D L^T$ where stable, else faer's LU.
#[derive(Debug)]
pub enum ModalFactor {
    /// $L D L^T$.
    Ldlt {
        /// Unit lower triangle $L$ strictly below the diagonal, $D$ on it (column-major).
        f: Mat<c64>,
        /// The same factors packed for single right-hand sides, made on the first one.
        packed: OnceLock<PackedLdlt>,
    },
    /// Partially pivoted LU (the fallback).
    Lu(PartialPivLu<c64>),
}

/// Column `j` of the column-major `m` from row `from` on.
#[inline(always)]
fn col_mut(m: &mut Mat<c64>, j: usize, from: usize) -> &mut [c64] {
    let n = m.nrows();
    match m.as_mut().col_mut(j).try_as_col_major_mut() {
        Some(c) => &mut c.as_slice_mut()[from..n],
        None => &mut [],
    }
}

/// Eliminates the panel of columns `k..k + kb` of `a` over its whole height (the lower
/// triangle holds the matrix updated by the previous panels). `false` on a zero or
/// non-finite pivot.
struct Panel<'a> {
    a: &'a mut Mat<c64>,
    k: usize,
    kb: usize,
}

impl pulp::WithSimd for Panel<'_> {
    type Output = bool;
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> bool {
        let Panel { a, k, kb } = self;
        let n = a.nrows();
        let mut lcol = vec![c64::new(0.0, 0.0); n];
        for j in k..k + kb {
            let d = a[(j, j)];
            if !(d.norm() > 0.0 && d.re.is_finite() && d.im.is_finite()) {
                return false;
            }
            let inv = c64::new(1.0, 0.0) / d;
            // v = the column below the pivot (D_j L_j), then L_j = v / d.
            lcol[j + 1..n].copy_from_slice(column_c64(a.as_ref(), j, j + 1, n));
            for x in col_mut(a, j, j + 1) {
                *x *= inv;
            }
            // The panel's remaining columns: A[c.., c] -= L_cj v[c..].
            for c in j + 1..k + kb {
                let s = -a[(c, j)];
                axpy_c64(simd, s, &lcol[c..n], col_mut(a, c, c));
            }
        }
        true
    }
}

/// `|re| + |im|`: the modulus within a factor sqrt(2), the same measure for the matrix and its
/// factors in the growth test.
#[inline(always)]
fn modulus(x: c64) -> f64 {
    x.re.abs() + x.im.abs()
}

/// `|L| |D| |L^T| 1` row by row, largest entry (the factors' growth, module documentation).
fn growth(f: MatRef<'_, c64>) -> f64 {
    let n = f.nrows();
    // u = |L^T| 1: u_j = 1 + sum_{i > j} |L_ij|; then v = |D| u; then |L| v.
    let v: Vec<f64> = (0..n)
        .map(|j| {
            let below: f64 = column_c64(f, j, j + 1, n).iter().map(|&x| modulus(x)).sum();
            (1.0 + below) * modulus(f[(j, j)])
        })
        .collect();
    // w = |L| v, L unit lower: w_i = v_i + sum_{j < i} |L_ij| v_j.
    let mut w = v.clone();
    for j in 0..n {
        let vj = v[j];
        for (wi, x) in w[j + 1..].iter_mut().zip(column_c64(f, j, j + 1, n)) {
            *wi += modulus(*x) * vj;
        }
    }
    w.into_iter().fold(0.0, f64::max)
}

impl ModalFactor {
    /// The factors of the complex symmetric matrix `build` returns (only its lower triangle is
    /// read): $L D L^T$ when its growth passes the test (module documentation), else faer's LU
    /// of the matrix built a second time (the factorisation overwrites the first).
    ///
    /// # Panics
    /// If the matrix is not square (a programming error).
    pub fn new(build: impl Fn() -> Mat<c64>) -> Self {
        let mut f = build();
        assert_eq!(f.nrows(), f.ncols(), "ModalFactor: a square matrix");
        let n = f.nrows();
        // ||K||_inf from the lower triangle (K symmetric).
        let mut rows = vec![0.0f64; n];
        for j in 0..n {
            for (i, x) in column_c64(f.as_ref(), j, j, n).iter().enumerate() {
                let m = modulus(*x);
                rows[j + i] += m;
                if i > 0 {
                    rows[j] += m;
                }
            }
        }
        let knorm = rows.iter().copied().fold(0.0, f64::max);
        if Self::ldlt_in_place(&mut f) {
            let g = growth(f.as_ref());
            if g.is_finite() && g <= GROWTH_LIMIT * knorm {
                return Self::Ldlt {
                    f,
                    packed: OnceLock::new(),
                };
            }
        }
        // The fallback reads the whole matrix: mirror the lower triangle first.
        let mut full = build();
        for j in 0..n {
            for i in j + 1..n {
                full[(j, i)] = full[(i, j)];
            }
        }
        Self::Lu(full.partial_piv_lu())
    }

    /// Blocked $L D L^T$ in place (module documentation); `false` on a zero or non-finite
    /// pivot.
    fn ldlt_in_place(a: &mut Mat<c64>) -> bool {
        let n = a.nrows();
        let arch = pulp::Arch::new();
        // W = L21 D1 of each panel, in one buffer.
        let mut wbuf = Mat::<c64>::zeros(n, PANEL.min(n));
        let mut k = 0;
        while k < n {
            let kb = PANEL.min(n - k);
            if !arch.dispatch(Panel { a: &mut *a, k, kb }) {
                return false;
            }
            let rest = n - k - kb;
            if rest > 0 {
                // A22 (lower) -= W L21^T.
                let (left, right) = a.as_mut().split_at_col_mut(k + kb);
                let l21 = left.as_ref().submatrix(k + kb, k, rest, kb);
                let mut w = wbuf.as_mut().submatrix_mut(0, 0, rest, kb);
                for j in 0..kb {
                    let d = left.as_ref()[(k + j, k + j)];
                    for i in 0..rest {
                        w[(i, j)] = l21[(i, j)] * d;
                    }
                }
                let a22: MatMut<'_, c64> = right.submatrix_mut(k + kb, 0, rest, rest);
                tri_matmul(
                    a22,
                    BlockStructure::TriangularLower,
                    Accum::Add,
                    w.as_ref(),
                    BlockStructure::Rectangular,
                    l21.transpose(),
                    BlockStructure::Rectangular,
                    c64::new(-1.0, 0.0),
                    Par::Seq,
                );
            }
            k += kb;
        }
        true
    }

    /// Whether the stable $L D L^T$ was kept (else the LU).
    pub fn is_ldlt(&self) -> bool {
        matches!(self, Self::Ldlt { .. })
    }

    /// `x <- K^-1 x` (`work` resized and overwritten by the LU path).
    ///
    /// # Panics
    /// If `x`'s length is not the order (a programming error).
    pub fn solve_in_place(&self, x: &mut [c64], work: &mut Vec<c64>) {
        match self {
            Self::Ldlt { f, packed } => packed
                .get_or_init(|| PackedLdlt::new(f.as_ref()))
                .solve_in_place(x, false),
            Self::Lu(lu) => lu_solve::solve_in_place(lu, x, work),
        }
    }

    /// `x <- K^-H x`: for a symmetric K, `conj(K^-1 conj(x))`.
    ///
    /// # Panics
    /// If `x`'s length is not the order (a programming error).
    pub fn solve_adjoint_in_place(&self, x: &mut [c64], work: &mut Vec<c64>) {
        match self {
            Self::Ldlt { f, packed } => packed
                .get_or_init(|| PackedLdlt::new(f.as_ref()))
                .solve_in_place(x, true),
            Self::Lu(lu) => lu_solve::solve_adjoint_in_place(lu, x, work),
        }
    }

    /// `B^T K^-1 B` (complex symmetric): from the $L D L^T$ factors $W^T D^{-1} W$ with $W =
    /// L^{-1} B$, one triangular solve where `K^-1 B` takes two; from the LU, `B^T (K^-1 B)`.
    pub fn bilinear(&self, b: MatRef<'_, c64>) -> Mat<c64> {
        match self {
            Self::Ldlt { f, .. } => {
                let mut w = b.to_owned();
                faer::linalg::triangular_solve::solve_unit_lower_triangular_in_place(
                    f.as_ref(),
                    w.as_mut(),
                    Par::Seq,
                );
                let v = Mat::from_fn(w.nrows(), w.ncols(), |i, j| w[(i, j)] / f[(i, i)]);
                w.transpose() * v
            }
            Self::Lu(lu) => b.transpose() * lu.solve(b),
        }
    }

    /// `K^-1 B` for many right-hand sides.
    pub fn solve(&self, b: MatRef<'_, c64>) -> Mat<c64> {
        match self {
            Self::Ldlt { f, .. } => {
                let mut x = b.to_owned();
                let l = f.as_ref();
                faer::linalg::triangular_solve::solve_unit_lower_triangular_in_place(
                    l,
                    x.as_mut(),
                    Par::Seq,
                );
                for j in 0..x.ncols() {
                    for i in 0..x.nrows() {
                        x[(i, j)] /= f[(i, i)];
                    }
                }
                faer::linalg::triangular_solve::solve_unit_upper_triangular_in_place(
                    l.transpose(),
                    x.as_mut(),
                    Par::Seq,
                );
                x
            }
            Self::Lu(lu) => lu.solve(b),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `D - a G1 - b G2` with `G_k = R_k^T R_k` (as the modal stiffness is built).
    fn modal_like(n: usize, a: c64, b: c64) -> Mat<c64> {
        let r1 = Mat::<f64>::from_fn(n / 2, n, |i, j| {
            ((i * 31 + j * 17) % 29) as f64 / 29.0 - 0.4
        });
        let r2 = Mat::<f64>::from_fn(n, n, |i, j| ((i * 13 + j * 7) % 23) as f64 / 23.0 - 0.5);
        let (g1, g2) = (r1.transpose() * &r1, r2.transpose() * &r2);
        Mat::from_fn(n, n, |i, j| {
            let w2 = (1.0 + i as f64).powi(2);
            let d = if i == j {
                c64::new(w2 - 30.0, 0.04 * w2.sqrt() * 5.0)
            } else {
                c64::new(0.0, 0.0)
            };
            d - a * g1[(i, j)] - b * g2[(i, j)]
        })
    }

    fn residual(k: &Mat<c64>, x: &[c64], b: &[c64]) -> f64 {
        let n = b.len();
        let xm = MatRef::from_column_major_slice(x, n, 1);
        let r = k * xm;
        let num: f64 = (0..n)
            .map(|i| (r[(i, 0)] - b[i]).norm_sqr())
            .sum::<f64>()
            .sqrt();
        let den: f64 = b.iter().map(|v| v.norm_sqr()).sum::<f64>().sqrt();
        num / den
    }

    #[test]
    fn ldlt_solves_match_the_matrix() {
        let n = 203; // several panels and a ragged last one
        let k = modal_like(n, c64::new(-40.0, 3.0), c64::new(-25.0, -1.0));
        let f = ModalFactor::new(|| k.clone());
        assert!(f.is_ldlt());
        let b: Vec<c64> = (0..n)
            .map(|i| c64::new((0.3 * i as f64).sin(), (0.7 * i as f64).cos()))
            .collect();
        let mut work = Vec::new();
        let mut x = b.clone();
        f.solve_in_place(&mut x, &mut work);
        assert!(residual(&k, &x, &b) < 1e-12, "{}", residual(&k, &x, &b));
        // K^H x = b.
        let mut y = b.clone();
        f.solve_adjoint_in_place(&mut y, &mut work);
        let kh = k.adjoint().to_owned();
        assert!(residual(&kh, &y, &b) < 1e-12);
        // Many right-hand sides equal the single ones.
        let bm = Mat::from_fn(n, 3, |i, j| b[i] * c64::new(1.0 + j as f64, -(j as f64)));
        let xm = f.solve(bm.as_ref());
        for i in 0..n {
            assert!((xm[(i, 0)] - x[i]).norm() <= 1e-12 * (1.0 + x[i].norm()));
            assert!(
                (xm[(i, 2)] - x[i] * c64::new(3.0, -2.0)).norm() <= 1e-11 * (1.0 + x[i].norm())
            );
        }
        // B^T K^-1 B from the factors equals B^T times the solves, for either factors.
        let lu = ModalFactor::Lu(k.partial_piv_lu());
        let want = bm.transpose() * &xm;
        for fac in [&f, &lu] {
            let got = fac.bilinear(bm.as_ref());
            for i in 0..3 {
                for j in 0..3 {
                    let e = (got[(i, j)] - want[(i, j)]).norm();
                    assert!(e <= 1e-11 * want[(i, j)].norm(), "{i} {j} {e:e}");
                }
            }
        }
        // Agrees with faer's LU.
        let mut z = b.clone();
        lu.solve_in_place(&mut z, &mut work);
        for i in 0..n {
            assert!((z[i] - x[i]).norm() <= 1e-10 * (1.0 + x[i].norm()));
        }
    }

    #[test]
    fn growth_sends_a_bad_pivot_order_to_the_lu() {
        // [[eps, 1], [1, 1]] (symmetric): without pivoting the factors grow like 1/eps.
        let n = 60;
        let mut k = Mat::<c64>::identity(n, n);
        k[(0, 0)] = c64::new(1e-12, 0.0);
        k[(1, 0)] = c64::new(1.0, 0.0);
        k[(0, 1)] = c64::new(1.0, 0.0);
        let f = ModalFactor::new(|| k.clone());
        assert!(!f.is_ldlt());
        let b: Vec<c64> = (0..n).map(|i| c64::new(1.0, i as f64)).collect();
        let mut x = b.clone();
        f.solve_in_place(&mut x, &mut Vec::new());
        assert!(residual(&k, &x, &b) < 1e-13);
        // A zero pivot too.
        k[(0, 0)] = c64::new(0.0, 0.0);
        assert!(!ModalFactor::new(|| k.clone()).is_ldlt());
    }
}
