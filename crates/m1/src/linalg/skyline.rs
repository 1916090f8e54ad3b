//! Envelope (skyline) Cholesky of a symmetric positive definite matrix: the built-in FE mirror
//! cell's static solves (`crate::plant::structure`).

use serde::{Deserialize, Serialize};

use crate::M1Error;

/// Cholesky factor `K = L L^T` of a symmetric positive definite matrix in envelope (variable
/// band) storage: row `i` of `L` holds the columns `first[i]..=i`. Fill-in stays inside the
/// envelope, so a well-ordered banded FE matrix factorises in `O(n b^2)` and solves in `O(n b)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Skyline {
    first: Vec<usize>,
    ptr: Vec<usize>,
    vals: Vec<f64>,
}

impl Skyline {
    /// Factorises the dense symmetric matrix `k` (row-major, `n x n`; the lower triangle is read).
    pub fn factor(n: usize, k: &[f64]) -> Result<Self, M1Error> {
        if k.len() != n * n {
            return Err(M1Error::SizeMismatch {
                what: "stiffness matrix",
                expected: n * n,
                found: k.len(),
            });
        }
        let mut first = Vec::with_capacity(n);
        let mut ptr = Vec::with_capacity(n + 1);
        ptr.push(0);
        for i in 0..n {
            let row = &k[i * n..i * n + i + 1];
            let f = row.iter().position(|&x| x != 0.0).unwrap_or(i);
            first.push(f);
            ptr.push(ptr[i] + i - f + 1);
        }
        let mut vals = vec![0.0; ptr[n]];
        for i in 0..n {
            let fi = first[i];
            let (done, row_i) = vals.split_at_mut(ptr[i]);
            row_i[..i - fi + 1].copy_from_slice(&k[i * n + fi..i * n + i + 1]);
            for j in fi..=i {
                let fj = first[j];
                let lo = fi.max(fj);
                let mut s = row_i[j - fi];
                if j < i {
                    let row_j = &done[ptr[j]..ptr[j + 1]];
                    for c in lo..j {
                        s -= row_i[c - fi] * row_j[c - fj];
                    }
                    s /= row_j[j - fj];
                    row_i[j - fi] = s;
                } else {
                    for c in fi..i {
                        s -= row_i[c - fi] * row_i[c - fi];
                    }
                    let d0 = k[i * n + i];
                    if !(s.is_finite() && s > 1e-13 * d0.abs()) {
                        return Err(M1Error::Numerical(format!(
                            "the stiffness matrix is not positive definite (pivot {i}: {s:e})"
                        )));
                    }
                    row_i[i - fi] = s.sqrt();
                }
            }
        }
        Ok(Self { first, ptr, vals })
    }

    /// Dimension.
    pub fn dim(&self) -> usize {
        self.first.len()
    }

    /// Number of stored entries of `L` (the solve costs about twice this many multiply-adds).
    pub fn stored(&self) -> usize {
        self.vals.len()
    }

    /// Solves `K X = B` in place for `nrhs` right-hand sides at once, `x` row-major
    /// `n x nrhs` (row `i` holds every right-hand side's entry `i`): the multiply-adds of a row
    /// run across the right-hand sides, with the processor's widest vectors, instead of along
    /// one dependent chain per right-hand side.
    ///
    /// # Panics
    /// If `x` is shorter than `n * nrhs` (a programming error).
    pub fn solve_block_in_place(&self, x: &mut [f64], nrhs: usize) {
        struct Op<'a> {
            s: &'a Skyline,
            x: &'a mut [f64],
            nrhs: usize,
        }
        impl pulp::WithSimd for Op<'_> {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: pulp::Simd>(self, _simd: S) {
                self.s.solve_block(self.x, self.nrhs);
            }
        }
        if nrhs == 0 {
            return;
        }
        pulp::Arch::new().dispatch(Op { s: self, x, nrhs });
    }

    /// [`Self::solve_block_in_place`]'s loops (inlined into the dispatched body).
    #[inline(always)]
    fn solve_block(&self, x: &mut [f64], p: usize) {
        let n = self.dim();
        let x = &mut x[..n * p];
        for i in 0..n {
            let fi = self.first[i];
            let row = &self.vals[self.ptr[i]..self.ptr[i + 1]];
            let (done, rest) = x.split_at_mut(i * p);
            let xi = &mut rest[..p];
            for (l, xc) in row[..i - fi].iter().zip(done[fi * p..].chunks_exact(p)) {
                for (a, b) in xi.iter_mut().zip(xc) {
                    *a -= l * b;
                }
            }
            let d = row[i - fi];
            xi.iter_mut().for_each(|a| *a /= d);
        }
        for i in (0..n).rev() {
            let fi = self.first[i];
            let row = &self.vals[self.ptr[i]..self.ptr[i + 1]];
            let (done, rest) = x.split_at_mut(i * p);
            let xi = &mut rest[..p];
            let d = row[i - fi];
            xi.iter_mut().for_each(|a| *a /= d);
            for (l, xc) in row[..i - fi].iter().zip(done[fi * p..].chunks_exact_mut(p)) {
                for (b, a) in xc.iter_mut().zip(xi.iter()) {
                    *b -= l * a;
                }
            }
        }
    }

    /// Solves `K x = b` in place.
    pub fn solve_in_place(&self, x: &mut [f64]) {
        let n = self.dim();
        for i in 0..n {
            let fi = self.first[i];
            let row = &self.vals[self.ptr[i]..self.ptr[i + 1]];
            let mut s = x[i];
            for (l, y) in row[..i - fi].iter().zip(&x[fi..i]) {
                s -= l * y;
            }
            x[i] = s / row[i - fi];
        }
        for i in (0..n).rev() {
            let fi = self.first[i];
            let row = &self.vals[self.ptr[i]..self.ptr[i + 1]];
            let xi = x[i] / row[i - fi];
            x[i] = xi;
            for (l, y) in row[..i - fi].iter().zip(&mut x[fi..i]) {
                *y -= l * xi;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_solve_matches_its_columns_solved_one_by_one() {
        // A banded SPD matrix with a wider row (as the mount's) at the end.
        let n = 40;
        let mut k = vec![0.0; n * n];
        for i in 0..n {
            k[i * n + i] = 4.0 + (i % 3) as f64;
            for j in i.saturating_sub(3)..i {
                let v = -0.3 - 0.01 * (i + j) as f64 / n as f64;
                k[i * n + j] = v;
                k[j * n + i] = v;
            }
        }
        for j in (0..n - 1).step_by(5) {
            k[(n - 1) * n + j] = 0.2;
            k[j * n + n - 1] = 0.2;
        }
        let chol = Skyline::factor(n, &k).unwrap();
        for nrhs in [1, 3, 8] {
            let b: Vec<f64> = (0..n * nrhs).map(|i| (0.37 * i as f64).sin()).collect();
            let mut x = b.clone();
            chol.solve_block_in_place(&mut x, nrhs);
            for c in 0..nrhs {
                let mut one: Vec<f64> = (0..n).map(|i| b[i * nrhs + c]).collect();
                chol.solve_in_place(&mut one);
                for i in 0..n {
                    let got = x[i * nrhs + c];
                    assert!((got - one[i]).abs() <= 1e-14 * one[i].abs().max(1.0));
                }
                // And K x = b.
                for i in 0..n {
                    let kx: f64 = (0..n).map(|j| k[i * n + j] * one[j]).sum();
                    assert!((kx - b[i * nrhs + c]).abs() < 1e-12);
                }
            }
        }
    }
}
