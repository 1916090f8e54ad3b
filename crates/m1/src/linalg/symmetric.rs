//! Symmetric matrices in single precision stored by their upper block triangle, and their
//! product with a vector reading each stored entry once.
//!
//! The coupled mirror's solve multiplies by a symmetric form of its small correction `W - I`
//! (`r x r`, hundreds to a thousand modes) at every servo sample. Stored whole it is twice the
//! memory traffic the product needs; stored by its upper block triangle, each entry read serves
//! both its row's dot product and, transposed, its column's (two multiply-adds per stored entry
//! instead of one per entry of the whole matrix: the same arithmetic, half the traffic). That
//! pays where a product is bound by its traffic (the correction at 1000 modes); a product bound
//! by its arithmetic gains nothing (the Gram matrices' pass with two right-hand sides was slower
//! stored so: BENCHMARKS.md, eighth round).

use pulp::Simd;

/// Side of the diagonal blocks, which are stored whole: a multiple of the widest single-
/// precision vector (16 lanes), so that every stored row is a whole number of vectors.
pub const BLOCK: usize = 16;

/// A symmetric `m x m` matrix in single precision, padded with zeros to `n = m` rounded up to
/// [`BLOCK`], stored by block rows: row `i` holds the columns from the start of its diagonal
/// block (`BLOCK * (i / BLOCK)`) to `n`. About half the entries of the whole matrix
/// (`m^2 / 2 + BLOCK m / 2`).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SymPacked32 {
    m: usize,
    n: usize,
    data: Vec<f32>,
}

impl SymPacked32 {
    /// The matrix whose entry `(i, j)` is `f(i, j)` (read for `j` from the start of `i`'s
    /// diagonal block on; `f` must be symmetric there, which this does not check), rounded to
    /// single precision.
    pub fn from_fn(m: usize, f: impl Fn(usize, usize) -> f64) -> Self {
        let n = m.div_ceil(BLOCK) * BLOCK;
        let mut data = vec![0.0f32; Self::offset_in(n, n)];
        for i in 0..m {
            let start = BLOCK * (i / BLOCK);
            let row = &mut data[Self::offset_in(n, i)..][..n - start];
            for (j, d) in (start..m).zip(row.iter_mut()) {
                *d = f(i, j) as f32;
            }
        }
        Self { m, n, data }
    }

    /// The padded order: the length the vectors of [`sym_dot_f32`] need.
    pub fn padded_order(&self) -> usize {
        self.n
    }

    /// The stored entries (the memory a product streams is their size).
    pub fn as_slice(&self) -> &[f32] {
        &self.data
    }

    /// Entry `(i, j)` as stored (either triangle), in single precision.
    #[cfg(test)]
    fn get(&self, i: usize, j: usize) -> f32 {
        let (i, j) = if j / BLOCK < i / BLOCK {
            (j, i)
        } else {
            (i, j)
        };
        self.data[Self::offset_in(self.n, i) + j - BLOCK * (i / BLOCK)]
    }

    /// Offset of row `i` in the storage of a matrix of padded order `n` (for `i = n`: the
    /// whole length).
    fn offset_in(n: usize, i: usize) -> usize {
        let b = i / BLOCK;
        // Whole block rows before `b`: BLOCK rows of n - BLOCK c each.
        BLOCK * (b * n - BLOCK * b * b.saturating_sub(1) / 2) + (i - BLOCK * b) * (n - BLOCK * b)
    }
}

/// Rows of [`sym_dot_f32`] computed together: four accumulators and their rows' broadcast
/// values stay in registers beside the column sums.
const ROWS: usize = 4;

/// `y += A x`, `A` symmetric and stored by [`SymPacked32`]: one pass over the stored entries,
/// each applied to its row's dot product and (past the diagonal block) to its column's, four
/// rows at a time.
///
/// `x` has at least `A.padded_order()` entries (those past the order are multiplied by the
/// padding's zeros), `y` at least the order; `t` is scratch of at least the padded order.
/// Each row's dot product is summed in single precision by lane and reduced once, the
/// transposed contributions in single precision per column, and both are added to the
/// double-precision `y`: the result agrees with the whole matrix's product to single-
/// precision rounding, not bit for bit.
///
/// # Panics
/// If a slice is shorter than that (a programming error).
#[inline(always)]
pub fn sym_dot_f32<S: Simd>(simd: S, a: &SymPacked32, x: &[f32], y: &mut [f64], t: &mut [f32]) {
    const { assert!(BLOCK.is_multiple_of(ROWS)) };
    let (m, n) = (a.m, a.n);
    let xh = S::as_simd_f32s(&x[..n]).0;
    let th = S::as_mut_simd_f32s(&mut t[..n]).0;
    let zero = simd.splat_f32s(0.0);
    th.fill(zero);
    // Vectors per block (the scalar fallback has one lane).
    let vpb = BLOCK / S::F32_LANES;
    let mut off = 0;
    for b in 0..n / BLOCK {
        let len = n - BLOCK * b;
        let c0 = b * vpb;
        for i in (BLOCK * b..BLOCK * (b + 1)).step_by(ROWS) {
            let rows: [&[S::f32s]; ROWS] = std::array::from_fn(|k| {
                S::as_simd_f32s(&a.data[off + k * len..off + (k + 1) * len]).0
            });
            let mut acc = [zero; ROWS];
            // The diagonal block, stored whole: dot products only.
            for c in 0..vpb {
                let xv = xh[c0 + c];
                for k in 0..ROWS {
                    acc[k] = simd.mul_add_f32s(rows[k][c], xv, acc[k]);
                }
            }
            // Past it: each entry also adds its row's value to its column's sum.
            let bc: [S::f32s; ROWS] = std::array::from_fn(|k| simd.splat_f32s(x[i + k]));
            for c in vpb..len / S::F32_LANES {
                let xv = xh[c0 + c];
                let mut tv = th[c0 + c];
                for k in 0..ROWS {
                    let v = rows[k][c];
                    acc[k] = simd.mul_add_f32s(v, xv, acc[k]);
                    tv = simd.mul_add_f32s(v, bc[k], tv);
                }
                th[c0 + c] = tv;
            }
            for (k, acck) in acc.into_iter().enumerate() {
                if i + k < m {
                    y[i + k] += f64::from(simd.reduce_sum_f32s(acck));
                }
            }
            off += ROWS * len;
        }
    }
    let tl: &[f32] = pulp::bytemuck::cast_slice(&*th);
    for (yj, tj) in y[..m].iter_mut().zip(tl) {
        *yj += f64::from(*tj);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Run<'a> {
        a: &'a SymPacked32,
        x: Vec<f32>,
        y: Vec<f64>,
    }

    impl pulp::WithSimd for Run<'_> {
        type Output = Vec<f64>;
        fn with_simd<S: Simd>(self, simd: S) -> Vec<f64> {
            let mut t = vec![f32::NAN; self.a.padded_order()];
            let mut y = self.y;
            sym_dot_f32::<S>(simd, self.a, &self.x, &mut y, &mut t);
            y
        }
    }

    /// A symmetric matrix with entries of both signs and a few magnitudes, seeded.
    fn entry(i: usize, j: usize) -> f64 {
        let (p, q) = (i.min(j) as f64, i.max(j) as f64);
        ((0.37 * p + 1.3 * q).sin() + 0.1 * (p - q).cos()) * (1.0 + 0.01 * (p + q))
    }

    /// The product against plain double-precision sums over the whole matrix (its entries
    /// rounded to single precision as stored), at orders around the block size, in every
    /// instruction set pulp picks here and in its scalar fallback.
    #[test]
    fn products_match_the_whole_matrix() {
        for m in [1, 5, 15, 16, 17, 31, 33, 48, 70, 150] {
            let a = SymPacked32::from_fn(m, entry);
            let n = a.padded_order();
            assert_eq!(n % BLOCK, 0);
            assert!(n >= m && n < m + BLOCK);
            let x: [Vec<f32>; 2] = std::array::from_fn(|l| {
                let mut v: Vec<f32> = (0..n)
                    .map(|j| ((j * (l + 3)) as f32 * 0.61).cos())
                    .collect();
                v[m..].fill(1e30); // past the order: multiplied by zeros only
                v
            });
            let y0: [Vec<f64>; 2] = std::array::from_fn(|l| vec![0.5 * l as f64; m]);
            let want: [Vec<f64>; 2] = std::array::from_fn(|l| {
                (0..m)
                    .map(|i| {
                        y0[l][i]
                            + (0..m)
                                .map(|j| f64::from(entry(i, j) as f32) * f64::from(x[l][j]))
                                .sum::<f64>()
                    })
                    .collect()
            });
            let scale: f64 = (0..m).map(|j| entry(0, j).abs()).sum::<f64>() + 1.0;
            let check = |got: &[f64], want: &[f64], what: &str| {
                for (g, w) in got.iter().zip(want) {
                    assert!(
                        (g - w).abs() <= 1e-6 * scale,
                        "order {m}, {what}: {g} against {w}"
                    );
                }
            };
            use pulp::WithSimd;
            for l in 0..2 {
                let run = || Run {
                    a: &a,
                    x: x[l].clone(),
                    y: y0[l].clone(),
                };
                let what = format!("right-hand side {l}");
                check(&pulp::Arch::new().dispatch(run()), &want[l], &what);
                check(&run().with_simd(pulp::Scalar), &want[l], &what);
                check(&run().with_simd(pulp::Scalar256b), &want[l], &what);
                check(&run().with_simd(pulp::Scalar512b), &want[l], &what);
            }
            // Storage: about half the whole matrix, both triangles read back.
            let b = n / BLOCK;
            assert_eq!(
                a.as_slice().len(),
                BLOCK * BLOCK * b * (b + 1) / 2,
                "order {m}"
            );
            for i in 0..m {
                for j in 0..m {
                    assert_eq!(a.get(i, j), entry(i, j) as f32, "({i}, {j}) of {m}");
                }
            }
        }
    }
}
