//! Symmetric matrices in single precision stored by their upper block triangle, and their
//! product with one or two vectors reading each stored entry once, whole or by block rows.
//!
//! The coupled mirror's solve multiplies by a symmetric form of its small correction `W - I`
//! (`r x r`, hundreds to a thousand modes) at every servo sample, and from 700 modes by the
//! Gram matrices `G_p`, `G_t` with two right-hand sides. Stored whole a symmetric matrix is
//! twice the memory traffic the product needs; stored by its upper block triangle, each entry
//! read serves both its row's dot product and, transposed, its column's (two multiply-adds per
//! stored entry instead of one per entry of the whole matrix: the same arithmetic, half the
//! traffic). That pays where a product is bound by its traffic (the correction, and the Gram
//! matrices at 1000 modes); a product bound by its arithmetic gains nothing (the Gram
//! matrices' pass at 300 and 600 modes was slower stored so: BENCHMARKS.md, eighth and
//! eleventh rounds). [`sym_dot_rows_f32`] computes a range of block rows with column sums of
//! its own, so that two threads can share a product ([`balanced_split`]).

use pulp::Simd;

use super::kernels::{LINE_F32, prefetch};

/// Side of the diagonal blocks, which are stored whole: a multiple of the widest single-
/// precision vector (16 lanes), so that every stored row is a whole number of vectors.
pub const BLOCK: usize = 16;

/// `m` rounded up to a whole number of [`BLOCK`]s: the padded order of a [`SymPacked32`] of
/// order `m`.
pub const fn padded_order(m: usize) -> usize {
    m.div_ceil(BLOCK) * BLOCK
}

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
        let n = padded_order(m);
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

    /// Order of the matrix.
    pub fn order(&self) -> usize {
        self.m
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
    pub fn get(&self, i: usize, j: usize) -> f32 {
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
        packed_offset(n, i)
    }
}

/// Offset of row `i` in the storage by upper block triangle of a matrix of padded order `n`
/// (for `i = n`: the whole length): [`SymPacked32`] and
/// [`SymScaled`](super::symmetric_scaled::SymScaled) alike (in entries).
pub(crate) const fn packed_offset(n: usize, i: usize) -> usize {
    let b = i / BLOCK;
    // Whole block rows before `b`: BLOCK rows of n - BLOCK c each.
    BLOCK * (b * n - BLOCK * b * b.saturating_sub(1) / 2) + (i - BLOCK * b) * (n - BLOCK * b)
}

/// `y_l += A x_l` for `L` (1 or 2) right-hand sides, `A` symmetric and stored by
/// [`SymPacked32`]: one pass over the stored entries, each applied to its row's dot product
/// and (past the diagonal block) to its column's, four rows at a time.
///
/// `x_l` has at least `A.padded_order()` entries (those past the order are multiplied by the
/// padding's zeros), `y_l` at least `A.order()`; `t_l` is scratch of at least the padded order.
/// Each row's dot products are summed in single precision by lane and reduced once, the
/// transposed contributions in single precision per column, and both are added to the
/// double-precision `y_l`: the results agree with the whole matrix's product to single-
/// precision rounding, not bit for bit.
///
/// # Panics
/// If a slice is shorter than that, or `L` is not 1 or 2 (programming errors).
#[inline(always)]
pub fn sym_dot_f32<S: Simd, const L: usize>(
    simd: S,
    a: &SymPacked32,
    x: [&[f32]; L],
    y: [&mut [f64]; L],
    t: [&mut [f32]; L],
) {
    let mut y = y.map(|yl| &mut yl[..a.m]);
    let mut t = t;
    sym_dot_rows_f32::<S, L>(
        simd,
        a,
        x,
        y.each_mut().map(|v| &mut **v),
        t.each_mut().map(|v| &mut **v),
        0..a.n / BLOCK,
    );
    for (yl, tl) in y.iter_mut().zip(&t) {
        add_columns(yl, tl, 0);
    }
}

/// Block row at which [`sym_dot_rows_f32`] splits a product into two parts of about the same
/// number of stored entries (block row `b` stores `n / BLOCK - b` blocks).
pub fn balanced_split(a: &SymPacked32) -> usize {
    let nb = a.n / BLOCK;
    // sum_{b < s} (nb - b) = nb (nb + 1) / 4: s = nb + 1/2 - sqrt((nb + 1/2)^2 - nb (nb + 1) / 2).
    let h = nb as f64 + 0.5;
    let s = h - (h * h - (nb * (nb + 1)) as f64 / 2.0).max(0.0).sqrt();
    (s.round() as usize).min(nb)
}

/// The block rows `blocks` of [`sym_dot_f32`] without their columns' part: each row's dot
/// products go into `y_l` (whose first entry is row `BLOCK * blocks.start`; rows past the
/// order are not written), the transposed contributions into `t_l` (all `n` columns, set to
/// zero first), which [`add_columns`] adds to `y_l`. Calls on disjoint block ranges write
/// disjoint parts of `y_l` and their own `t_l`: they may run at once.
///
/// # Panics
/// If a slice is shorter than that, or `L` is not 1 or 2 (programming errors).
#[inline(always)]
pub fn sym_dot_rows_f32<S: Simd, const L: usize>(
    simd: S,
    a: &SymPacked32,
    x: [&[f32]; L],
    y: [&mut [f64]; L],
    t: [&mut [f32]; L],
    blocks: std::ops::Range<usize>,
) {
    assert!(L == 1 || L == 2, "one or two right-hand sides");
    // Four rows at a time: with two right-hand sides their accumulators and broadcast values
    // take sixteen vector registers (of AVX-512's 32).
    const R: usize = 4;
    const { assert!(BLOCK.is_multiple_of(R)) };
    let (m, n) = (a.m, a.n);
    let xh: [&[S::f32s]; L] = std::array::from_fn(|l| S::as_simd_f32s(&x[l][..n]).0);
    let mut th: [&mut [S::f32s]; L] = t.map(|tl| S::as_mut_simd_f32s(&mut tl[..n]).0);
    for tl in th.iter_mut() {
        tl.fill(simd.splat_f32s(0.0));
    }
    // Vectors per block (the scalar fallback has one lane).
    let vpb = BLOCK / S::F32_LANES;
    let zero = simd.splat_f32s(0.0);
    let row0 = BLOCK * blocks.start;
    let mut off = SymPacked32::offset_in(n, row0);
    for b in blocks {
        let len = n - BLOCK * b;
        let c0 = b * vpb;
        let mut i = BLOCK * b;
        while i < BLOCK * (b + 1) {
            let rows: [&[S::f32s]; R] = std::array::from_fn(|k| {
                S::as_simd_f32s(&a.data[off + k * len..off + (k + 1) * len]).0
            });
            let mut acc = [[zero; L]; R];
            // The diagonal block, stored whole: dot products only.
            for c in 0..vpb {
                for l in 0..L {
                    let xv = xh[l][c0 + c];
                    for k in 0..R {
                        acc[k][l] = simd.mul_add_f32s(rows[k][c], xv, acc[k][l]);
                    }
                }
            }
            // Past it: each entry also adds its row's value to its column's sum.
            let bc: [[S::f32s; L]; R] =
                std::array::from_fn(|k| std::array::from_fn(|l| simd.splat_f32s(x[l][i + k])));
            // The next group of rows, a group ahead (its 16 kB at 1000 modes cover the L3's
            // latency): each row is a stream of its own, a page or less long.
            let next = a.data.as_ptr().wrapping_add(off + R * len);
            for c in vpb..len / S::F32_LANES {
                if (c * S::F32_LANES).is_multiple_of(LINE_F32) {
                    for k in 0..R {
                        prefetch(next.wrapping_add(k * len + c * S::F32_LANES));
                    }
                }
                for l in 0..L {
                    let xv = xh[l][c0 + c];
                    let mut tv = th[l][c0 + c];
                    for k in 0..R {
                        let v = rows[k][c];
                        acc[k][l] = simd.mul_add_f32s(v, xv, acc[k][l]);
                        tv = simd.mul_add_f32s(v, bc[k][l], tv);
                    }
                    th[l][c0 + c] = tv;
                }
            }
            for (k, acck) in acc.iter().enumerate() {
                if i + k < m {
                    for l in 0..L {
                        y[l][i + k - row0] += f64::from(simd.reduce_sum_f32s(acck[l]));
                    }
                }
            }
            off += R * len;
            i += R;
        }
    }
}

/// `y[j] += t[j]` for the columns `j >= from` of [`sym_dot_rows_f32`] (`y` from row 0, as
/// long as the order).
#[inline(always)]
pub fn add_columns(y: &mut [f64], t: &[f32], from: usize) {
    let from = from.min(y.len());
    for (yj, tj) in y[from..].iter_mut().zip(&t[from..]) {
        *yj += f64::from(*tj);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Run<'a, const L: usize> {
        a: &'a SymPacked32,
        x: [Vec<f32>; L],
        y: [Vec<f64>; L],
    }

    impl<const L: usize> pulp::WithSimd for Run<'_, L> {
        type Output = [Vec<f64>; L];
        fn with_simd<S: Simd>(self, simd: S) -> [Vec<f64>; L] {
            let n = self.a.padded_order();
            let mut t: [Vec<f32>; L] = std::array::from_fn(|_| vec![f32::NAN; n]);
            let mut y = self.y;
            {
                let ys: [&mut [f64]; L] = {
                    let mut it = y.iter_mut();
                    std::array::from_fn(|_| it.next().unwrap().as_mut_slice())
                };
                let ts: [&mut [f32]; L] = {
                    let mut it = t.iter_mut();
                    std::array::from_fn(|_| it.next().unwrap().as_mut_slice())
                };
                sym_dot_f32::<S, L>(
                    simd,
                    self.a,
                    std::array::from_fn(|l| self.x[l].as_slice()),
                    ys,
                    ts,
                );
            }
            y
        }
    }

    /// The product in two parts at every block row (the columns' part added after both), with
    /// one and two right-hand sides, against the whole product: the same to single-precision
    /// rounding; and the balanced split halves the stored entries.
    #[test]
    fn products_in_two_parts_match_the_whole() {
        for m in [17, 48, 70, 150, 300] {
            let a = SymPacked32::from_fn(m, entry);
            let n = a.padded_order();
            let nb = n / BLOCK;
            let x: [Vec<f32>; 2] = std::array::from_fn(|l| {
                (0..n)
                    .map(|j| ((j * (l + 3)) as f32 * 0.61).cos())
                    .collect()
            });
            let want = pulp::Arch::new().dispatch(Run::<2> {
                a: &a,
                x: x.clone(),
                y: [vec![0.25; m], vec![-0.5; m]],
            });
            let scale: f64 = (0..m).map(|j| entry(0, j).abs()).sum::<f64>() + 1.0;
            for s in 0..=nb {
                let two = pulp::Arch::new().dispatch(Parts::<2> {
                    a: &a,
                    x: [&x[0], &x[1]],
                    y0: [0.25, -0.5],
                    split: s,
                });
                let one = pulp::Arch::new().dispatch(Parts::<1> {
                    a: &a,
                    x: [&x[1]],
                    y0: [-0.5],
                    split: s,
                });
                for (got, want) in [
                    (&two[0], &want[0]),
                    (&two[1], &want[1]),
                    (&one[0], &want[1]),
                ] {
                    for (g, w) in got.iter().zip(want) {
                        assert!((g - w).abs() <= 1e-6 * scale, "{m} {s}: {g} {w}");
                    }
                }
            }
            let s = balanced_split(&a);
            let stored = |b: std::ops::Range<usize>| b.map(|b| nb - b).sum::<usize>() as f64;
            let (lo, hi) = (stored(0..s), stored(s..nb));
            assert!((lo - hi).abs() <= nb as f64, "{m}: {lo} {hi}");
        }
    }

    struct Parts<'a, const L: usize> {
        a: &'a SymPacked32,
        x: [&'a [f32]; L],
        y0: [f64; L],
        split: usize,
    }

    impl<const L: usize> pulp::WithSimd for Parts<'_, L> {
        type Output = [Vec<f64>; L];
        fn with_simd<S: Simd>(self, simd: S) -> [Vec<f64>; L] {
            let (a, n, m) = (self.a, self.a.padded_order(), self.a.m);
            let mut y: [Vec<f64>; L] = self.y0.map(|v| vec![v; m]);
            let mut ta: [Vec<f32>; L] = std::array::from_fn(|_| vec![f32::NAN; n]);
            let mut tb: [Vec<f32>; L] = std::array::from_fn(|_| vec![f32::NAN; n]);
            let cut = (BLOCK * self.split).min(m);
            {
                let mut halves = y.each_mut().map(|v| v.split_at_mut(cut));
                sym_dot_rows_f32::<S, L>(
                    simd,
                    a,
                    self.x,
                    halves.each_mut().map(|h| &mut *h.0),
                    ta.each_mut().map(|v| v.as_mut_slice()),
                    0..self.split,
                );
                sym_dot_rows_f32::<S, L>(
                    simd,
                    a,
                    self.x,
                    halves.each_mut().map(|h| &mut *h.1),
                    tb.each_mut().map(|v| v.as_mut_slice()),
                    self.split..n / BLOCK,
                );
            }
            for (l, yl) in y.iter_mut().enumerate() {
                add_columns(yl, &ta[l], 0);
                add_columns(yl, &tb[l], cut);
            }
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
            let two = || Run::<2> {
                a: &a,
                x: x.clone(),
                y: y0.clone(),
            };
            let one = || Run::<1> {
                a: &a,
                x: [x[1].clone()],
                y: [y0[1].clone()],
            };
            use pulp::WithSimd;
            let runs = [
                (
                    pulp::Arch::new().dispatch(two()),
                    pulp::Arch::new().dispatch(one()),
                ),
                (two().with_simd(pulp::Scalar), one().with_simd(pulp::Scalar)),
                (
                    two().with_simd(pulp::Scalar256b),
                    one().with_simd(pulp::Scalar256b),
                ),
                (
                    two().with_simd(pulp::Scalar512b),
                    one().with_simd(pulp::Scalar512b),
                ),
            ];
            for (got2, got1) in runs {
                check(&got2[0], &want[0], "two right-hand sides, first");
                check(&got2[1], &want[1], "two right-hand sides, second");
                check(&got1[0], &want[1], "one right-hand side");
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
