//! The largest and the smallest singular value of a dense square complex matrix, without its
//! full singular value decomposition.
//!
//! The global loop's criteria need two numbers per frequency and per controller: $\sigma_{max}$
//! of the loop gain $L$ and $\sigma_{min}$ of the return difference $I + L$ (the sensitivity's
//! $\sigma_{max}$ is its inverse). A bidiagonalisation costs about $\frac{16}{3} n^3$ complex
//! multiply-adds in level-2 passes over the matrix; here:
//! - $\sigma_{max}(A)^2$ is the top eigenvalue of $A^H A$, by Lanczos
//!   ([`largest_hermitian_eigenpair`]) with products by $A$ and $A^H$ (both passes over the
//!   columns);
//! - $\sigma_{min}(A)^{-2}$ is the top eigenvalue of $A^{-H} A^{-1}$, by Lanczos with the two
//!   solves of one LU factorisation ($\frac{2}{3} n^3$, in matrix-matrix blocks).
//!
//! Lanczos stops when the top Ritz value is within [`TOL`] (relative) of an eigenvalue
//! (its residual test). Where it does not within [`MAX_STEPS`] steps (a top cluster), and for
//! matrices below [`LANCZOS_FROM`] rows, the full singular values are computed instead: the
//! value is then faer's. A Ritz value is a lower bound that reaches the top eigenvalue first
//! from a generic start (the start used here is a fixed vector with every component non-zero);
//! the test compares both routes on the global loop's points.

use faer::linalg::solvers::PartialPivLu;
use faer::{MatRef, c64};

use super::kernels::{axpy_c64, column_c64, dot_conj_c64};
use super::krylov::largest_hermitian_eigenpair;
use super::lu_solve;

/// Relative residual of the top Ritz value at which Lanczos stops (on the eigenvalue of the
/// Gram operator, so about half of it on the singular value).
pub const TOL: f64 = 1e-10;
/// Lanczos steps at most before the full singular values are computed instead.
pub const MAX_STEPS: usize = 80;
/// Matrices with fewer rows go straight to the full singular values (cheap there).
pub const LANCZOS_FROM: usize = 64;
/// Lanczos steps at least (the top of the spectrum reached before the test is trusted).
const MIN_STEPS: usize = 12;

/// A fixed start vector with no zero component.
fn start(n: usize) -> Vec<c64> {
    (0..n)
        .map(|i| {
            let t = i as f64;
            c64::new(1.0 + 0.5 * (0.7 * t).sin(), 0.5 * (1.3 * t).cos())
        })
        .collect()
}

/// faer's full singular values of `a`: (largest, smallest); `None` if the SVD fails.
fn full(a: MatRef<'_, c64>) -> Option<(f64, f64)> {
    let s = a.singular_values().ok()?;
    let max = s.iter().copied().fold(0.0f64, f64::max);
    let min = s.iter().copied().fold(f64::INFINITY, f64::min);
    Some((max, min))
}

/// `out = A^H A x` for a column-major `a` (n x n): `t = A x` by column axpys, then each
/// `out_j` a conjugate dot product with column j; `a` is read twice, in storage order.
struct GramProduct<'a> {
    a: MatRef<'a, c64>,
    x: &'a [c64],
    t: &'a mut [c64],
    out: &'a mut [c64],
}

impl pulp::WithSimd for GramProduct<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let GramProduct { a, x, t, out } = self;
        t.fill(c64::new(0.0, 0.0));
        for (j, &xj) in x.iter().enumerate() {
            axpy_c64(simd, xj, column_c64(a, j, 0, a.nrows()), t);
        }
        for (j, o) in out.iter_mut().enumerate() {
            *o = dot_conj_c64(simd, column_c64(a, j, 0, a.nrows()), t);
        }
    }
}

/// $\sigma_{max}$ of the square matrix `a` (module documentation); `None` if it is not square
/// or the fallback SVD fails (as it may on a non-finite entry).
pub fn largest_singular_value(a: MatRef<'_, c64>) -> Option<f64> {
    let n = a.nrows();
    if a.ncols() != n {
        return None;
    }
    if n == 0 {
        return Some(0.0);
    }
    if n < LANCZOS_FROM {
        return full(a).map(|s| s.0);
    }
    // Column-major storage for the passes (faer's owned matrices are).
    let owned;
    let a = if a.row_stride() == 1 {
        a
    } else {
        owned = a.to_owned();
        owned.as_ref()
    };
    let mut t = vec![c64::new(0.0, 0.0); n];
    let arch = pulp::Arch::new();
    let p = largest_hermitian_eigenpair(n, (MIN_STEPS, MAX_STEPS), &start(n), TOL, |x, out| {
        arch.dispatch(GramProduct {
            a,
            x,
            t: &mut t,
            out,
        });
    });
    if p.converged && p.value.is_finite() {
        Some(p.value.max(0.0).sqrt())
    } else {
        full(a).map(|s| s.0)
    }
}

/// $\sigma_{min}$ of the square matrix `a` (module documentation), from the fallback SVD for
/// a singular one (round-off above 0); `None` if it is not square or that SVD fails.
pub fn smallest_singular_value(a: MatRef<'_, c64>) -> Option<f64> {
    let n = a.nrows();
    if a.ncols() != n {
        return None;
    }
    if n == 0 {
        return Some(f64::INFINITY);
    }
    if n < LANCZOS_FROM {
        return full(a).map(|s| s.1);
    }
    let lu = PartialPivLu::new(a);
    let mut work = Vec::with_capacity(n);
    let p = largest_hermitian_eigenpair(n, (MIN_STEPS, MAX_STEPS), &start(n), TOL, |x, out| {
        out.copy_from_slice(x);
        lu_solve::solve_in_place(&lu, out, &mut work);
        lu_solve::solve_adjoint_in_place(&lu, out, &mut work);
    });
    if p.converged && p.value.is_finite() && p.value > 0.0 {
        Some(1.0 / p.value.sqrt())
    } else {
        full(a).map(|s| s.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    /// A matrix with known singular values: U diag(s) V^H with U, V unitary (complex
    /// reflections times diagonal phases).
    fn with_singular_values(s: &[f64]) -> Mat<c64> {
        let n = s.len();
        let reflector = |seed: f64| {
            let u: Vec<c64> = (0..n)
                .map(|i| {
                    c64::new(
                        (seed * i as f64).sin() + 1.1,
                        (0.37 * seed * i as f64).cos(),
                    )
                })
                .collect();
            let uu: f64 = u.iter().map(|x| x.norm_sqr()).sum();
            Mat::from_fn(n, n, |i, j| {
                let d = if i == j { 1.0 } else { 0.0 };
                let ph = c64::new((seed * j as f64).cos(), (seed * j as f64).sin());
                (c64::new(d, 0.0) - u[i] * u[j].conj() * (2.0 / uu)) * ph
            })
        };
        let (u, v) = (reflector(0.31), reflector(0.77));
        let d = Mat::from_fn(n, n, |i, j| c64::new(if i == j { s[i] } else { 0.0 }, 0.0));
        &u * &d * v.adjoint()
    }

    #[test]
    fn extremes_of_a_known_spectrum_by_lanczos() {
        let n = 150;
        // A separated top (7.5) and bottom (0.02) among values in [0.5, 3].
        let s: Vec<f64> = (0..n)
            .map(|i| match i {
                3 => 7.5,
                90 => 0.02,
                _ => 0.5 + 2.5 * ((i * 37) % n) as f64 / n as f64,
            })
            .collect();
        let a = with_singular_values(&s);
        let max = largest_singular_value(a.as_ref()).unwrap();
        let min = smallest_singular_value(a.as_ref()).unwrap();
        assert!((max - 7.5).abs() < 1e-9 * 7.5, "{max}");
        assert!((min - 0.02).abs() < 1e-9 * 0.02, "{min}");
    }

    #[test]
    fn a_top_cluster_falls_back_to_the_full_values() {
        // Ten singular values within 1e-9 of each other at the top: Lanczos cannot resolve
        // them to its tolerance in time, and the answer is still the exact top.
        let n = 120;
        let s: Vec<f64> = (0..n)
            .map(|i| {
                if i < 10 {
                    4.0 + 1e-10 * i as f64
                } else {
                    1.0 + (i % 17) as f64 / 17.0
                }
            })
            .collect();
        let a = with_singular_values(&s);
        let max = largest_singular_value(a.as_ref()).unwrap();
        let (fmax, _) = full(a.as_ref()).unwrap();
        assert!((max - fmax).abs() <= 1e-10 * fmax, "{max} {fmax}");
        assert!((max - (4.0 + 9e-10)).abs() < 1e-9, "{max}");
    }

    #[test]
    fn small_singular_and_empty_matrices() {
        // Below LANCZOS_FROM: the full values.
        let s: Vec<f64> = (0..10).map(|i| 1.0 + i as f64).collect();
        let a = with_singular_values(&s);
        assert!((largest_singular_value(a.as_ref()).unwrap() - 10.0).abs() < 1e-12);
        assert!((smallest_singular_value(a.as_ref()).unwrap() - 1.0).abs() < 1e-12);
        // Exactly singular (a zero column): the smallest is 0, not an error.
        let z = Mat::from_fn(80, 80, |i, j| {
            if j == 5 {
                c64::new(0.0, 0.0)
            } else {
                c64::new(((i * 3 + j * 7) % 11) as f64, (i == j) as u8 as f64)
            }
        });
        let zmin = smallest_singular_value(z.as_ref()).unwrap();
        assert!(zmin < 1e-12, "{zmin}");
        let e = Mat::<c64>::zeros(0, 0);
        assert_eq!(largest_singular_value(e.as_ref()), Some(0.0));
        assert_eq!(smallest_singular_value(e.as_ref()), Some(f64::INFINITY));
        assert_eq!(
            largest_singular_value(Mat::<c64>::zeros(3, 2).as_ref()),
            None
        );
    }
}
