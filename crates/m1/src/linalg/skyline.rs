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
