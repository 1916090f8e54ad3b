//! Real matrices stored without their zero lower part, for memory-bound products with complex
//! vectors: an upper trapezoidal `m x k` matrix ([`UpperTrapezoid`]: `A` and `A^T` against a
//! vector) and a symmetric `k x k` one by its upper part
//! ([`UpperTrapezoid::symmetric_times_complex`]).
//!
//! The CSI's all-segment Lanczos streams the coupled basis twice and a Gram matrix once per
//! step ([`crate::analysis::csi`]); with the basis upper trapezoidal (an orthogonal change of the
//! subspace's coordinates, the `R` of a QR factorisation) and the Gram matrix by its upper
//! triangle, a step reads about a fifth fewer bytes.
//!
//! # Storage
//!
//! Rows go in groups of four, group `g` (rows `4g..4g + 4`, rows past `m` zero) from column
//! `4g` to `k`, row-major within the group, groups back to back: a group is four rows of one
//! length, which the four-row kernels of [`super::kernels`] take as they are. The entries
//! left of the diagonal inside a group's first four columns are stored as given (zero for a
//! trapezoidal matrix; the lower half of the diagonal block for a symmetric one); entries
//! left of column `4g` are never stored or read.

use faer::MatRef;
use pulp::Simd;

use super::kernels::{LINE_F64, axpy4x2, dot_block_f64, hsum, prefetch};

/// Rows per group (the four-row kernels' block).
const GROUP: usize = 4;

/// An `m x k` real matrix stored from the diagonal on, by groups of four rows (module
/// documentation).
#[derive(Debug, Clone, PartialEq)]
pub struct UpperTrapezoid {
    m: usize,
    k: usize,
    data: Vec<f64>,
    /// Start of each group in `data`.
    offsets: Vec<usize>,
}

impl UpperTrapezoid {
    /// The part of `a` from column `4 floor(i / 4)` on in each row `i` (the rest is taken as
    /// zero).
    pub fn new(a: MatRef<'_, f64>) -> Self {
        let (m, k) = a.shape();
        let groups = m.div_ceil(GROUP);
        let mut offsets = Vec::with_capacity(groups);
        let mut data = Vec::new();
        for g in 0..groups {
            offsets.push(data.len());
            let c0 = (GROUP * g).min(k);
            for r in 0..GROUP {
                let i = GROUP * g + r;
                data.extend((c0..k).map(|j| if i < m { a[(i, j)] } else { 0.0 }));
            }
        }
        Self {
            m,
            k,
            data,
            offsets,
        }
    }

    /// `wa A + wb B` for `B` of the same shape (stored alike).
    ///
    /// # Panics
    /// If the shapes differ (a programming error).
    pub fn scaled_sum(&self, wa: f64, b: &Self, wb: f64) -> Self {
        assert_eq!((self.m, self.k), (b.m, b.k), "scaled_sum: shapes differ");
        Self {
            m: self.m,
            k: self.k,
            data: self
                .data
                .iter()
                .zip(&b.data)
                .map(|(p, q)| wa * p + wb * q)
                .collect(),
            offsets: self.offsets.clone(),
        }
    }

    /// Rows.
    pub fn nrows(&self) -> usize {
        self.m
    }

    /// Columns.
    pub fn ncols(&self) -> usize {
        self.k
    }

    /// Values stored (the bytes a product reads, over eight).
    pub fn stored(&self) -> usize {
        self.data.len()
    }

    /// Group `g`: its first column, its four rows, and where the next group starts with its
    /// rows' length (at least 1), for the kernels' prefetch.
    fn group(&self, g: usize) -> (usize, [&[f64]; GROUP], (*const f64, usize)) {
        let c0 = (GROUP * g).min(self.k);
        let len = self.k - c0;
        let at = self.offsets[g];
        let rows = std::array::from_fn(|r| &self.data[at + r * len..at + (r + 1) * len]);
        let next = self.data.as_ptr().wrapping_add(at + GROUP * len);
        (c0, rows, (next, len.saturating_sub(GROUP).max(1)))
    }

    /// `y = A^T x` for a complex `x` given as its real and imaginary parts (length `m`; `y`
    /// length `k`): one pass over the stored values for both parts.
    ///
    /// # Panics
    /// If a slice is shorter than the dimensions say (a programming error).
    pub fn t_times_complex(&self, x: [&[f64]; 2], y: [&mut [f64]; 2]) {
        self.dispatch(Product::Transposed, x, y);
    }

    /// `y = A z` for a complex `z` given as its real and imaginary parts (length `k`; `y`
    /// length `m`): one pass over the stored values for both parts.
    ///
    /// # Panics
    /// If a slice is shorter than the dimensions say (a programming error).
    pub fn times_complex(&self, z: [&[f64]; 2], y: [&mut [f64]; 2]) {
        self.dispatch(Product::Direct, z, y);
    }

    /// `y = G z` for the symmetric `k x k` matrix `G` whose upper part this stores (made by
    /// [`Self::new`] from `G`; `m = k`), `z` complex given as its real and imaginary parts:
    /// each stored value read once, for its row's dot product and, right of the diagonal
    /// block, for its column's share.
    ///
    /// # Panics
    /// If the matrix is not square or a slice is shorter than the dimensions say (programming
    /// errors).
    pub fn symmetric_times_complex(&self, z: [&[f64]; 2], y: [&mut [f64]; 2]) {
        assert_eq!(self.m, self.k, "symmetric_times_complex: a square matrix");
        self.dispatch(Product::Symmetric, z, y);
    }

    /// Runs `product` with the processor's widest vectors.
    fn dispatch(&self, product: Product, v: [&[f64]; 2], y: [&mut [f64]; 2]) {
        struct Op<'a> {
            a: &'a UpperTrapezoid,
            product: Product,
            v: [&'a [f64]; 2],
            y: [&'a mut [f64]; 2],
        }
        impl pulp::WithSimd for Op<'_> {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: Simd>(self, simd: S) {
                let Op { a, product, v, y } = self;
                match product {
                    Product::Transposed => a.t_times_simd(simd, v, y),
                    Product::Direct => a.times_simd(simd, v, y),
                    Product::Symmetric => a.symmetric_simd(simd, v, y),
                }
            }
        }
        pulp::Arch::new().dispatch(Op {
            a: self,
            product,
            v,
            y,
        });
    }

    /// [`Self::t_times_complex`] with the vectors of `simd`.
    #[inline(always)]
    fn t_times_simd<S: Simd>(&self, simd: S, x: [&[f64]; 2], [y0, y1]: [&mut [f64]; 2]) {
        let k = self.k;
        y0[..k].fill(0.0);
        y1[..k].fill(0.0);
        for g in 0..self.offsets.len() {
            let (c0, rows, next) = self.group(g);
            if c0 == k {
                break;
            }
            let c = x.map(|xl| {
                std::array::from_fn(|r| {
                    let i = GROUP * g + r;
                    if i < self.m { xl[i] } else { 0.0 }
                })
            });
            axpy4x2(simd, rows, c, [&mut y0[c0..k], &mut y1[c0..k]], next);
        }
    }

    /// [`Self::times_complex`] with the vectors of `simd`.
    #[inline(always)]
    fn times_simd<S: Simd>(&self, simd: S, z: [&[f64]; 2], [y0, y1]: [&mut [f64]; 2]) {
        let k = self.k;
        for g in 0..self.offsets.len() {
            let (c0, rows, next) = self.group(g);
            let s = dot_block_f64(simd, rows, [&z[0][c0..k], &z[1][c0..k]], Some(next));
            for (r, [u, v]) in s.into_iter().enumerate() {
                let i = GROUP * g + r;
                if i < self.m {
                    y0[i] = u;
                    y1[i] = v;
                }
            }
        }
    }

    /// [`Self::symmetric_times_complex`] with the vectors of `simd`.
    #[inline(always)]
    fn symmetric_simd<S: Simd>(&self, simd: S, z: [&[f64]; 2], [y0, y1]: [&mut [f64]; 2]) {
        let k = self.k;
        y0[..k].fill(0.0);
        y1[..k].fill(0.0);
        for g in 0..self.offsets.len() {
            let (c0, rows, next) = self.group(g);
            let nb = GROUP.min(k - c0);
            // The diagonal block: dot products only.
            let mut acc = [[0.0f64; 2]; GROUP];
            for (r, accr) in acc.iter_mut().enumerate().take(nb) {
                for j in 0..nb {
                    accr[0] += rows[r][j] * z[0][c0 + j];
                    accr[1] += rows[r][j] * z[1][c0 + j];
                }
            }
            // Right of it: the rows' dot products and the columns' shares in one pass.
            let zg: [[f64; GROUP]; 2] = std::array::from_fn(|l| {
                std::array::from_fn(|r| if r < nb { z[l][c0 + r] } else { 0.0 })
            });
            let right = rows.map(|row| &row[nb..]);
            let (t0, t1) = (&mut y0[c0 + nb..k], &mut y1[c0 + nb..k]);
            let s = dot_axpy4x2(
                simd,
                right,
                [&z[0][c0 + nb..k], &z[1][c0 + nb..k]],
                zg,
                [t0, t1],
                next,
            );
            for r in 0..nb {
                y0[c0 + r] += acc[r][0] + s[r][0];
                y1[c0 + r] += acc[r][1] + s[r][1];
            }
        }
    }
}

/// The three products of an [`UpperTrapezoid`].
#[derive(Debug, Clone, Copy)]
enum Product {
    Transposed,
    Direct,
    Symmetric,
}

/// For four rows of one length and two right-hand sides: returns the rows' dot products with
/// `x_l` and adds `sum_r c_l[r] row_r` to `y_l` (all of the rows' length), reading each chunk
/// of the rows once for the four sums; the next group (`next`, row stride `lda`) prefetched
/// along.
#[inline(always)]
fn dot_axpy4x2<S: Simd>(
    simd: S,
    rows: [&[f64]; GROUP],
    x: [&[f64]; 2],
    c: [[f64; GROUP]; 2],
    y: [&mut [f64]; 2],
    (next, lda): (*const f64, usize),
) -> [[f64; 2]; GROUP] {
    let [y0, y1] = y;
    let (yh0, yt0) = S::as_mut_simd_f64s(y0);
    let (yh1, yt1) = S::as_mut_simd_f64s(y1);
    let n = yh0.len();
    let xh: [&[S::f64s]; 2] = x.map(|xl| &S::as_simd_f64s(xl).0[..n]);
    let rh: [&[S::f64s]; GROUP] = rows.map(|row| &S::as_simd_f64s(row).0[..n]);
    let cv = c.map(|cl| cl.map(|v| simd.splat_f64s(v)));
    let zero = simd.splat_f64s(0.0);
    let mut acc = [[zero; 2]; GROUP];
    for j in 0..n {
        if (j * S::F64_LANES).is_multiple_of(LINE_F64) {
            for r in 0..GROUP {
                prefetch(next.wrapping_add(r * lda + j * S::F64_LANES));
            }
        }
        let (x0, x1) = (xh[0][j], xh[1][j]);
        let (mut u, mut v) = (yh0[j], yh1[j]);
        for r in 0..GROUP {
            let a = rh[r][j];
            acc[r][0] = simd.mul_add_f64s(a, x0, acc[r][0]);
            acc[r][1] = simd.mul_add_f64s(a, x1, acc[r][1]);
            u = simd.mul_add_f64s(a, cv[0][r], u);
            v = simd.mul_add_f64s(a, cv[1][r], v);
        }
        yh0[j] = u;
        yh1[j] = v;
    }
    let mut out: [[f64; 2]; GROUP] = std::array::from_fn(|r| acc[r].map(hsum::<S>));
    let at0 = n * S::F64_LANES;
    for (t, (yt0j, yt1j)) in yt0.iter_mut().zip(yt1.iter_mut()).enumerate() {
        let at = at0 + t;
        for r in 0..GROUP {
            let a = rows[r][at];
            out[r][0] += a * x[0][at];
            out[r][1] += a * x[1][at];
            *yt0j += a * c[0][r];
            *yt1j += a * c[1][r];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;

    /// A deterministic value in [-1, 1).
    fn val(i: usize, j: usize) -> f64 {
        ((i * 7919 + j * 104_729) % 2003) as f64 / 1001.5 - 1.0
    }

    fn vecs(n: usize, seed: usize) -> [Vec<f64>; 2] {
        [0, 1].map(|l| (0..n).map(|i| val(i + seed, 3 * l + 1)).collect())
    }

    #[test]
    fn trapezoid_products_match_the_dense_ones() {
        // Ragged shapes: rows not a multiple of four, tails past the vector width, m = k.
        for (m, k) in [
            (1, 1),
            (3, 5),
            (4, 4),
            (5, 9),
            (7, 7),
            (13, 31),
            (61, 64),
            (90, 203),
        ] {
            let a = Mat::<f64>::from_fn(m, k, |i, j| if j >= i { val(i, j) } else { 0.0 });
            let t = UpperTrapezoid::new(a.as_ref());
            let want: usize = (0..m.div_ceil(4)).map(|g| 4 * (k - (4 * g).min(k))).sum();
            assert_eq!(t.stored(), want, "{m} x {k}");
            let x = vecs(m, 1);
            let z = vecs(k, 2);
            let (mut y0, mut y1) = (vec![f64::NAN; k], vec![f64::NAN; k]);
            t.t_times_complex([&x[0], &x[1]], [&mut y0, &mut y1]);
            for j in 0..k {
                for (l, y) in [&y0, &y1].into_iter().enumerate() {
                    let want: f64 = (0..m).map(|i| a[(i, j)] * x[l][i]).sum();
                    assert!((y[j] - want).abs() < 1e-12, "A^T x, {m} x {k}, col {j}");
                }
            }
            let (mut u0, mut u1) = (vec![f64::NAN; m], vec![f64::NAN; m]);
            t.times_complex([&z[0], &z[1]], [&mut u0, &mut u1]);
            for i in 0..m {
                for (l, u) in [&u0, &u1].into_iter().enumerate() {
                    let want: f64 = (0..k).map(|j| a[(i, j)] * z[l][j]).sum();
                    assert!((u[i] - want).abs() < 1e-12, "A z, {m} x {k}, row {i}");
                }
            }
        }
    }

    #[test]
    fn the_lower_part_is_never_read() {
        // Entries left of each group's first column are NaN: a product reading one fails.
        let (m, k) = (11, 23);
        let a = Mat::<f64>::from_fn(m, k, |i, j| {
            if j >= 4 * (i / 4) {
                if j >= i { val(i, j) } else { 0.0 }
            } else {
                f64::NAN
            }
        });
        let t = UpperTrapezoid::new(a.as_ref());
        let (x, z) = (vecs(m, 3), vecs(k, 4));
        let (mut y0, mut y1) = (vec![0.0; k], vec![0.0; k]);
        t.t_times_complex([&x[0], &x[1]], [&mut y0, &mut y1]);
        let (mut u0, mut u1) = (vec![0.0; m], vec![0.0; m]);
        t.times_complex([&z[0], &z[1]], [&mut u0, &mut u1]);
        assert!(
            y0.iter()
                .chain(&y1)
                .chain(&u0)
                .chain(&u1)
                .all(|v| v.is_finite())
        );
    }

    #[test]
    fn symmetric_product_matches_the_dense_one() {
        for n in [1, 2, 4, 5, 8, 13, 37, 64, 101] {
            let b = Mat::<f64>::from_fn(n + 3, n, val);
            let g = b.transpose() * &b;
            // The lower triangle outside the diagonal blocks is NaN: never read.
            let stored = Mat::<f64>::from_fn(n, n, |i, j| {
                if j >= 4 * (i / 4) {
                    g[(i, j)]
                } else {
                    f64::NAN
                }
            });
            let t = UpperTrapezoid::new(stored.as_ref());
            let z = vecs(n, 5);
            let (mut y0, mut y1) = (vec![f64::NAN; n], vec![f64::NAN; n]);
            t.symmetric_times_complex([&z[0], &z[1]], [&mut y0, &mut y1]);
            for i in 0..n {
                for (l, y) in [&y0, &y1].into_iter().enumerate() {
                    let want: f64 = (0..n).map(|j| g[(i, j)] * z[l][j]).sum();
                    let scale: f64 = (0..n).map(|j| (g[(i, j)] * z[l][j]).abs()).sum();
                    assert!(
                        (y[i] - want).abs() <= 1e-14 * scale.max(1.0),
                        "G z, n {n}, row {i}: {} vs {want}",
                        y[i]
                    );
                }
            }
        }
    }
}
