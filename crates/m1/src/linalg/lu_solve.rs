//! One right-hand side solved with a dense complex LU factorisation (faer's
//! [`PartialPivLu`]), `K x = b` and `K^H x = b`, each triangle read once in its storage order.
//!
//! faer's triangular solves recurse into blocks sized for many right-hand sides; the
//! all-segment Lanczos of `m1cs csi` makes two solves with one right-hand side per step, on the
//! 1000 x 1000 closed-loop modal stiffness. Here the factors stay where faer keeps them
//! (column-major) and each column is read once, contiguously:
//! - `K x = b` ([`solve_in_place`]): `x = U^-1 L^-1 P b`, both triangles by column axpys;
//! - `K^H x = b` ([`solve_adjoint_in_place`]): `x = P^T L^-H U^-H b`, both by column dot
//!   products with the conjugated columns.
//!
//! The arithmetic is that of plain substitution (backward stable, like faer's), in SIMD with
//! [`pulp`]; the sums are ordered by vector lane, so results agree with faer's to rounding.

use faer::MatRef;
use faer::c64;
use faer::linalg::solvers::PartialPivLu;
use pulp::Simd;

use super::kernels::{axpy_c64, column_c64, dot_conj_c64};

/// Whether every column of both factors is contiguous (the passes below read them as slices).
fn contiguous(lu: &PartialPivLu<c64>) -> bool {
    lu.L().row_stride() == 1 && lu.U().row_stride() == 1
}

/// faer's own solve, for factors whose columns are not contiguous (not produced by faer today).
fn faer_solve(lu: &PartialPivLu<c64>, x: &mut [c64], adjoint: bool) {
    use faer::linalg::solvers::Solve;
    let n = x.len();
    let rhs = faer::MatMut::from_column_major_slice_mut(x, n, 1);
    if adjoint {
        lu.solve_adjoint_in_place(rhs);
    } else {
        lu.solve_in_place(rhs);
    }
}

/// `x <- K^-1 x` with `lu` the factorisation of `K` (n x n, `x` of length n); `work` is
/// resized to n and overwritten.
///
/// # Panics
/// If `x`'s length is not the factorisation's order (a programming error).
pub fn solve_in_place(lu: &PartialPivLu<c64>, x: &mut [c64], work: &mut Vec<c64>) {
    solve(lu, x, work, false);
}

/// `x <- K^-H x` with `lu` the factorisation of `K` (n x n, `x` of length n); `work` is
/// resized to n and overwritten.
///
/// # Panics
/// If `x`'s length is not the factorisation's order (a programming error).
pub fn solve_adjoint_in_place(lu: &PartialPivLu<c64>, x: &mut [c64], work: &mut Vec<c64>) {
    solve(lu, x, work, true);
}

/// Both solves: the permutation, then the two triangles' passes in the processor's vectors.
fn solve(lu: &PartialPivLu<c64>, x: &mut [c64], work: &mut Vec<c64>, adjoint: bool) {
    let (l, u) = (lu.L(), lu.U());
    let n = l.nrows();
    assert_eq!(x.len(), n, "lu_solve: right-hand side of the wrong length");
    if !contiguous(lu) {
        return faer_solve(lu, x, adjoint);
    }
    // faer's row permutation P takes row fwd[i] to row i: K = P^T L U.
    let (fwd, _) = lu.P().arrays();
    if !adjoint {
        // P b.
        work.clear();
        work.extend(fwd.iter().map(|&p| x[p]));
        x.copy_from_slice(work);
    }
    pulp::Arch::new().dispatch(Passes {
        l,
        u,
        x: &mut *x,
        adjoint,
    });
    if adjoint {
        // P^T v: row i goes back to row fwd[i].
        work.clear();
        work.resize(n, c64::new(0.0, 0.0));
        for (i, &p) in fwd.iter().enumerate() {
            work[p] = x[i];
        }
        x.copy_from_slice(work);
    }
}

/// The triangular passes of one solve on the permuted right-hand side `x`.
struct Passes<'a> {
    l: MatRef<'a, c64>,
    u: MatRef<'a, c64>,
    x: &'a mut [c64],
    adjoint: bool,
}

impl pulp::WithSimd for Passes<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Passes { l, u, x, adjoint } = self;
        let n = x.len();
        if adjoint {
            // U^H w = b (lower triangular): row i of U^H is column i of U conjugated.
            for i in 0..n {
                let (done, rest) = x.split_at_mut(i);
                let s = dot_conj_c64(simd, column_c64(u, i, 0, i), done);
                rest[0] = (rest[0] - s) / column_c64(u, i, i, i + 1)[0].conj();
            }
            // L^H v = w (upper triangular, unit diagonal), from the last row up.
            for i in (0..n).rev() {
                let (head, done) = x.split_at_mut(i + 1);
                head[i] -= dot_conj_c64(simd, column_c64(l, i, i + 1, n), done);
            }
        } else {
            // L y = P b, unit diagonal: column j removes y_j from the rows below it.
            for j in 0..n {
                let (head, below) = x.split_at_mut(j + 1);
                let yj = head[j];
                axpy_c64(simd, -yj, column_c64(l, j, j + 1, n), below);
            }
            // U x = y: column j removes x_j = y_j / U_jj from the rows above it.
            for j in (0..n).rev() {
                let (above, rest) = x.split_at_mut(j);
                let xj = rest[0] / column_c64(u, j, j, j + 1)[0];
                rest[0] = xj;
                axpy_c64(simd, -xj, column_c64(u, j, 0, j), above);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    /// A well-conditioned complex matrix with a pivoting pattern (small diagonal entries).
    fn matrix(n: usize, seed: u64) -> Mat<c64> {
        let mut s = seed;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        };
        Mat::from_fn(n, n, |i, j| {
            let d = if i == j { 0.01 } else { 0.0 };
            c64::new(next() + d, next())
        })
    }

    fn rhs(n: usize) -> Vec<c64> {
        (0..n)
            .map(|i| c64::new((0.3 * i as f64).sin(), (0.7 * i as f64).cos()))
            .collect()
    }

    /// faer's own solve of `K x = b` or, from the factorisation of `K^H` formed explicitly,
    /// of `K^H x = b`.
    fn faer_solve(k: &Mat<c64>, b: &[c64], adjoint: bool) -> Vec<c64> {
        use faer::linalg::solvers::Solve;
        let bm = Mat::from_fn(b.len(), 1, |i, _| b[i]);
        let x = if adjoint {
            k.adjoint().to_owned().partial_piv_lu().solve(&bm)
        } else {
            k.partial_piv_lu().solve(&bm)
        };
        (0..b.len()).map(|i| x[(i, 0)]).collect()
    }

    #[test]
    fn agrees_with_faer_and_solves_both_systems() {
        for &n in &[0usize, 1, 2, 3, 5, 8, 17, 64, 203] {
            let k = matrix(n, 11 + n as u64);
            let lu = k.partial_piv_lu();
            let b = rhs(n);
            let mut work = Vec::new();
            for adjoint in [false, true] {
                let mut x = b.clone();
                if adjoint {
                    solve_adjoint_in_place(&lu, &mut x, &mut work);
                } else {
                    solve_in_place(&lu, &mut x, &mut work);
                }
                let reference = faer_solve(&k, &b, adjoint);
                let scale = reference.iter().map(|v| v.norm()).fold(1e-300, f64::max);
                for (p, q) in x.iter().zip(&reference) {
                    assert!((p - q).norm() <= 1e-10 * scale, "n {n} adjoint {adjoint}");
                }
                // The residual of the system itself: K x = b or K^H x = b.
                for i in 0..n {
                    let mut s = c64::new(0.0, 0.0);
                    for j in 0..n {
                        let kij = if adjoint { k[(j, i)].conj() } else { k[(i, j)] };
                        s += kij * x[j];
                    }
                    assert!((s - b[i]).norm() <= 1e-9, "n {n} adjoint {adjoint} row {i}");
                }
            }
        }
    }
}
