//! Symmetric matrices stored in half precision (IEEE 754 binary16) by their upper block
//! triangle, scaled symmetrically so that every stored entry lies in `[-1, 1]`, and their
//! product with one or two single-precision vectors, summed in single precision as
//! [`sym_dot_rows_f32`](super::symmetric::sym_dot_rows_f32) sums.
//!
//! Why: the coupled mirror's servo tick multiplies by the symmetric form of its correction
//! `W - I` five times per 1 ms step. The correction is a small term of the solve (about 4e-7
//! in norm for the voice coil, 8e-5 for the piezo), so its entries need no more than half
//! precision, and at a thousand retained modes storing it so saves 5 of the 42.9 MB a TMT step
//! streams ([`CoupledMirror::set_correction_half`](crate::plant::mirror::CoupledMirror::set_correction_half)).
//! Matrices whose product is not a small correction (the Gram matrices) need single precision.
//!
//! **Scaling.** With `s_i = sqrt(max_j |A_ij|)` (1 for a zero row), `A = S A' S`,
//! `S = diag(s)`, and `|A'_ij| <= |A_ij| / sqrt(|A_ij| |A_ji|) = 1`: the stored entries use
//! half precision's range without overflow, each rounded to within `2^-11` of itself (or
//! `2^-25` absolute below its normal range, `2^-14`), so that `|A_ij - s_i A'_ij s_j| <=
//! 2^-11 |A_ij| + 2^-25 s_i s_j`. The caller scales the vector by `s` before the product and
//! the result by `s` after it ([`SymPackedHalf::scale`]), or folds the scale into its own
//! per-entry factors.
//!
//! **Kernels.** The entries are converted to single precision in registers (`vcvtph2ps`, AVX-512F
//! or F16C), sixteen or eight lanes at a time, and multiplied as the single-precision kernel
//! does (four rows at a time, each stored entry applied to its row's dot product and, past the
//! diagonal block, to its column's); a portable scalar path serves other processors. The path
//! is chosen once, at construction, by the processor's features.

use half::f16;

use super::kernels::{LINE_F32, prefetch};
use super::symmetric::{BLOCK, packed_offset, padded_order};

/// The instructions a [`SymPackedHalf`] product runs on (chosen by [`HalfPath::detect`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HalfPath {
    /// AVX-512F: sixteen lanes, `vcvtph2ps` on 512-bit registers.
    Avx512,
    /// AVX2, FMA and F16C: eight lanes.
    Avx2,
    /// Portable scalar code (one lane, the conversion in software).
    Scalar,
}

impl HalfPath {
    /// The widest path this processor supports.
    pub fn detect() -> Self {
        [Self::Avx512, Self::Avx2]
            .into_iter()
            .find(|p| p.available())
            .unwrap_or(Self::Scalar)
    }

    /// Whether this processor can run the path.
    pub fn available(self) -> bool {
        match self {
            Self::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Self::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(target_arch = "x86_64")]
            Self::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
                    && std::arch::is_x86_feature_detected!("f16c")
            }
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }
}

/// A symmetric `m x m` matrix `A = S A' S` with `A'` in half precision, stored as
/// [`SymPacked32`](super::symmetric::SymPacked32) stores (padded with zeros to `n = m` rounded up
/// to [`BLOCK`], by block rows from each diagonal block on), and the diagonal scale `S` in
/// single precision (the module's documentation).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
pub struct SymPackedHalf {
    m: usize,
    n: usize,
    /// `s_i`, zero past the order.
    scale: Vec<f32>,
    /// The bits of `A'`'s stored entries.
    data: Vec<u16>,
    #[serde(skip, default = "HalfPath::detect")]
    path: HalfPath,
}

impl SymPackedHalf {
    /// The matrix whose entry `(i, j)` is `f(i, j)` (`f` symmetric, which this does not check;
    /// every entry is read, to find the scale), scaled and rounded to half precision, or
    /// `None` if an entry is not finite.
    pub fn from_fn(m: usize, f: impl Fn(usize, usize) -> f64) -> Option<Self> {
        let n = padded_order(m);
        let mut row_max = vec![0.0f64; m];
        for (i, mx) in row_max.iter_mut().enumerate() {
            for j in 0..m {
                let v = f(i, j);
                if !v.is_finite() {
                    return None;
                }
                *mx = mx.max(v.abs());
            }
        }
        let s: Vec<f64> = row_max
            .iter()
            .map(|&x| if x > 0.0 { x.sqrt() } else { 1.0 })
            .collect();
        let mut data = vec![0u16; packed_offset(n, n)];
        for i in 0..m {
            let start = BLOCK * (i / BLOCK);
            let row = &mut data[packed_offset(n, i)..][..n - start];
            for (j, d) in (start..m).zip(row.iter_mut()) {
                *d = f16::from_f64(f(i, j) / (s[i] * s[j])).to_bits();
            }
        }
        let mut scale: Vec<f32> = s.iter().map(|&x| x as f32).collect();
        scale.resize(n, 0.0);
        Some(Self {
            m,
            n,
            scale,
            data,
            path: HalfPath::detect(),
        })
    }

    /// Order of the matrix.
    pub fn order(&self) -> usize {
        self.m
    }

    /// The padded order: the length the vectors of a product need.
    pub fn padded_order(&self) -> usize {
        self.n
    }

    /// The diagonal scale `s` (the padded order's length, zero past the order): `A = S A' S`.
    pub fn scale(&self) -> &[f32] {
        &self.scale
    }

    /// The stored entries' bits (the memory a product streams is their size).
    pub fn as_bits(&self) -> &[u16] {
        &self.data
    }

    /// The path the products run on.
    pub fn path(&self) -> HalfPath {
        self.path
    }

    /// Runs the products on `path` instead of the detected one (for tests and comparisons):
    /// `false`, and nothing changed, if this processor cannot run it.
    pub fn set_path(&mut self, path: HalfPath) -> bool {
        let ok = path.available();
        if ok {
            self.path = path;
        }
        ok
    }

    /// Entry `(i, j)` of `A` as stored (either triangle).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if j / BLOCK < i / BLOCK {
            (j, i)
        } else {
            (i, j)
        };
        let v = f16::from_bits(self.data[packed_offset(self.n, i) + j - BLOCK * (i / BLOCK)]);
        f64::from(self.scale[i]) * v.to_f64() * f64::from(self.scale[j])
    }

    /// Block rows `blocks` of the product with the *scaled* matrix `A'`, for `L` (1 or 2)
    /// right-hand sides `xs_l` (already multiplied by [`Self::scale`]): each row's dot product
    /// is added to `y_l` (whose first entry is row `BLOCK * blocks.start`; rows past the order
    /// are not written), the transposed contributions go into `t_l` (all `n` columns, set to
    /// zero first), to be added to the rows' results
    /// ([`add_columns`](super::symmetric::add_columns)) before the result is multiplied by the
    /// scale. Calls on disjoint block ranges write disjoint parts of `y_l` and their own `t_l`:
    /// they may run at once.
    ///
    /// # Panics
    /// If a slice is shorter than that, the blocks run past the padded order, or `L` is not 1
    /// or 2 (programming errors).
    pub fn scaled_rows<const L: usize>(
        &self,
        xs: [&[f32]; L],
        y: [&mut [f64]; L],
        t: [&mut [f32]; L],
        blocks: std::ops::Range<usize>,
    ) {
        assert!(L == 1 || L == 2, "one or two right-hand sides");
        assert!(blocks.start <= blocks.end && blocks.end <= self.n / BLOCK);
        let rows = (BLOCK * blocks.end).min(self.m);
        let rows = rows.saturating_sub(BLOCK * blocks.start);
        for l in 0..L {
            assert!(xs[l].len() >= self.n && t[l].len() >= self.n && y[l].len() >= rows);
        }
        assert!(self.data.len() == packed_offset(self.n, self.n));
        let mut t = t;
        for tl in t.iter_mut() {
            tl[..self.n].fill(0.0);
        }
        // SAFETY: the slices' lengths are checked above; the path was checked to run on this
        // processor (detected at construction, or `set_path`).
        unsafe {
            match self.path {
                #[cfg(target_arch = "x86_64")]
                HalfPath::Avx512 => x86::rows_avx512::<L>(self, xs, y, t, blocks),
                #[cfg(target_arch = "x86_64")]
                HalfPath::Avx2 => x86::rows_avx2::<L>(self, xs, y, t, blocks),
                _ => rows_impl::<Scalar, L>(self, xs, y, t, blocks),
            }
        }
    }
}

/// The vector operations a kernel path needs.
trait Lanes {
    type V: Copy;
    const N: usize;
    unsafe fn zero() -> Self::V;
    unsafe fn splat(v: f32) -> Self::V;
    unsafe fn load(p: *const f32) -> Self::V;
    unsafe fn store(p: *mut f32, v: Self::V);
    unsafe fn load_half(p: *const u16) -> Self::V;
    unsafe fn fma(a: Self::V, b: Self::V, c: Self::V) -> Self::V;
    unsafe fn sum(v: Self::V) -> f32;
}

struct Scalar;

impl Lanes for Scalar {
    type V = f32;
    const N: usize = 1;
    #[inline(always)]
    unsafe fn zero() -> f32 {
        0.0
    }
    #[inline(always)]
    unsafe fn splat(v: f32) -> f32 {
        v
    }
    #[inline(always)]
    unsafe fn load(p: *const f32) -> f32 {
        unsafe { *p }
    }
    #[inline(always)]
    unsafe fn store(p: *mut f32, v: f32) {
        unsafe { *p = v }
    }
    #[inline(always)]
    unsafe fn load_half(p: *const u16) -> f32 {
        f16::from_bits(unsafe { *p }).to_f32()
    }
    #[inline(always)]
    unsafe fn fma(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
    #[inline(always)]
    unsafe fn sum(v: f32) -> f32 {
        v
    }
}

/// The kernel: [`SymPackedHalf::scaled_rows`] on the path `T`.
///
/// # Safety
/// The processor runs `T`'s instructions; the slices have the lengths
/// [`SymPackedHalf::scaled_rows`] checks, `t_l` is zero.
#[inline(always)]
unsafe fn rows_impl<T: Lanes, const L: usize>(
    a: &SymPackedHalf,
    xs: [&[f32]; L],
    y: [&mut [f64]; L],
    t: [&mut [f32]; L],
    blocks: std::ops::Range<usize>,
) {
    // Four rows at a time: with two right-hand sides their accumulators and broadcast values
    // take sixteen vector registers (of AVX-512's 32).
    const R: usize = 4;
    const { assert!(BLOCK.is_multiple_of(R)) };
    let (m, n) = (a.m, a.n);
    let xp: [*const f32; L] = std::array::from_fn(|l| xs[l].as_ptr());
    let tp: [*mut f32; L] = t.map(|tl| tl.as_mut_ptr());
    let data = a.data.as_ptr();
    let row0 = BLOCK * blocks.start;
    let mut off = packed_offset(n, row0);
    // SAFETY (every access below): rows `i .. i + R` of block row `b` are stored at
    // `off .. off + R len` within `data` (its length is `packed_offset(n, n)`), the columns
    // `BLOCK b + c` for `c < len` are below `n`, the length of `xs_l` and `t_l`.
    unsafe {
        for b in blocks {
            let len = n - BLOCK * b;
            let col0 = BLOCK * b;
            let mut i = col0;
            while i < col0 + BLOCK {
                let rp: [*const u16; R] = std::array::from_fn(|k| data.add(off + k * len));
                let mut acc = [[T::zero(); L]; R];
                // The diagonal block, stored whole: dot products only.
                let mut c = 0;
                while c < BLOCK {
                    let v: [T::V; R] = std::array::from_fn(|k| T::load_half(rp[k].add(c)));
                    for l in 0..L {
                        let xv = T::load(xp[l].add(col0 + c));
                        for k in 0..R {
                            acc[k][l] = T::fma(v[k], xv, acc[k][l]);
                        }
                    }
                    c += T::N;
                }
                // Past it: each entry also adds its row's value to its column's sum.
                let bc: [[T::V; L]; R] =
                    std::array::from_fn(|k| std::array::from_fn(|l| T::splat(*xp[l].add(i + k))));
                // The next group of rows, a group ahead (as in `sym_dot_rows_f32`).
                let next = data.wrapping_add(off + R * len);
                while c < len {
                    // Once per cache line of half-precision values.
                    if c.is_multiple_of(2 * LINE_F32) {
                        for k in 0..R {
                            prefetch(next.wrapping_add(k * len + c));
                        }
                    }
                    let v: [T::V; R] = std::array::from_fn(|k| T::load_half(rp[k].add(c)));
                    for l in 0..L {
                        let xv = T::load(xp[l].add(col0 + c));
                        let mut tv = T::load(tp[l].add(col0 + c));
                        for k in 0..R {
                            acc[k][l] = T::fma(v[k], xv, acc[k][l]);
                            tv = T::fma(v[k], bc[k][l], tv);
                        }
                        T::store(tp[l].add(col0 + c), tv);
                    }
                    c += T::N;
                }
                for (k, acck) in acc.iter().enumerate() {
                    if i + k < m {
                        for l in 0..L {
                            y[l][i + k - row0] += f64::from(T::sum(acck[l]));
                        }
                    }
                }
                off += R * len;
                i += R;
            }
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::{Lanes, SymPackedHalf, rows_impl};
    use core::arch::x86_64::*;

    pub(super) struct Avx512;

    impl Lanes for Avx512 {
        type V = __m512;
        const N: usize = 16;
        #[inline(always)]
        unsafe fn zero() -> __m512 {
            unsafe { _mm512_setzero_ps() }
        }
        #[inline(always)]
        unsafe fn splat(v: f32) -> __m512 {
            unsafe { _mm512_set1_ps(v) }
        }
        #[inline(always)]
        unsafe fn load(p: *const f32) -> __m512 {
            unsafe { _mm512_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn store(p: *mut f32, v: __m512) {
            unsafe { _mm512_storeu_ps(p, v) }
        }
        #[inline(always)]
        unsafe fn load_half(p: *const u16) -> __m512 {
            unsafe { _mm512_cvtph_ps(_mm256_loadu_si256(p.cast())) }
        }
        #[inline(always)]
        unsafe fn fma(a: __m512, b: __m512, c: __m512) -> __m512 {
            unsafe { _mm512_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        unsafe fn sum(v: __m512) -> f32 {
            unsafe { _mm512_reduce_add_ps(v) }
        }
    }

    pub(super) struct Avx2;

    impl Lanes for Avx2 {
        type V = __m256;
        const N: usize = 8;
        #[inline(always)]
        unsafe fn zero() -> __m256 {
            unsafe { _mm256_setzero_ps() }
        }
        #[inline(always)]
        unsafe fn splat(v: f32) -> __m256 {
            unsafe { _mm256_set1_ps(v) }
        }
        #[inline(always)]
        unsafe fn load(p: *const f32) -> __m256 {
            unsafe { _mm256_loadu_ps(p) }
        }
        #[inline(always)]
        unsafe fn store(p: *mut f32, v: __m256) {
            unsafe { _mm256_storeu_ps(p, v) }
        }
        #[inline(always)]
        unsafe fn load_half(p: *const u16) -> __m256 {
            unsafe { _mm256_cvtph_ps(_mm_loadu_si128(p.cast())) }
        }
        #[inline(always)]
        unsafe fn fma(a: __m256, b: __m256, c: __m256) -> __m256 {
            unsafe { _mm256_fmadd_ps(a, b, c) }
        }
        #[inline(always)]
        unsafe fn sum(v: __m256) -> f32 {
            unsafe {
                let h = _mm_add_ps(_mm256_castps256_ps128(v), _mm256_extractf128_ps::<1>(v));
                let h = _mm_add_ps(h, _mm_movehl_ps(h, h));
                let h = _mm_add_ss(h, _mm_shuffle_ps::<1>(h, h));
                _mm_cvtss_f32(h)
            }
        }
    }

    /// # Safety
    /// As [`rows_impl`], on a processor with AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn rows_avx512<const L: usize>(
        a: &SymPackedHalf,
        xs: [&[f32]; L],
        y: [&mut [f64]; L],
        t: [&mut [f32]; L],
        blocks: std::ops::Range<usize>,
    ) {
        unsafe { rows_impl::<Avx512, L>(a, xs, y, t, blocks) }
    }

    /// # Safety
    /// As [`rows_impl`], on a processor with AVX2, FMA and F16C.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub(super) unsafe fn rows_avx2<const L: usize>(
        a: &SymPackedHalf,
        xs: [&[f32]; L],
        y: [&mut [f64]; L],
        t: [&mut [f32]; L],
        blocks: std::ops::Range<usize>,
    ) {
        unsafe { rows_impl::<Avx2, L>(a, xs, y, t, blocks) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A symmetric test matrix with entries over six decades (so that the scale matters) and
    /// an order that is not a whole number of blocks.
    fn entry(i: usize, j: usize) -> f64 {
        let (a, b) = (i.min(j) as f64, i.max(j) as f64);
        let mag = 10f64.powf(-((a + b) % 7.0)) * (1.0 + 0.1 * a);
        mag * ((0.37 * a + 0.11 * b).sin() + 0.05)
    }

    /// Every path's product with one and two right-hand sides, whole and in two parts of
    /// block rows, against the double-precision product with the matrix as stored (within
    /// single-precision summation), and the stored matrix against the exact one (within half
    /// precision's bound of the module's documentation).
    #[test]
    fn products_match_the_stored_matrix_on_every_path() {
        let m = 83;
        let a = SymPackedHalf::from_fn(m, entry).expect("finite");
        let n = a.padded_order();
        assert_eq!(n, 96);
        for i in 0..m {
            for j in 0..m {
                let (exact, stored) = (entry(i, j), a.get(i, j));
                let bound = 2f64.powi(-11) * exact.abs()
                    + 2f64.powi(-24) * f64::from(a.scale()[i] * a.scale()[j]);
                assert!(
                    (exact - stored).abs() <= bound,
                    "({i}, {j}): {exact} {stored}"
                );
                assert_eq!(stored, a.get(j, i));
            }
        }
        let x: [Vec<f32>; 2] = std::array::from_fn(|l| {
            (0..n)
                .map(|j| {
                    if j < m {
                        ((j * (l + 3)) as f32 * 0.7).cos()
                    } else {
                        0.0
                    }
                })
                .collect()
        });
        let reference: [Vec<f64>; 2] = std::array::from_fn(|l| {
            (0..m)
                .map(|i| (0..m).map(|j| a.get(i, j) * f64::from(x[l][j])).sum())
                .collect()
        });
        let scale_of = |i: usize| -> f64 {
            (0..m)
                .map(|j| (a.get(i, j) * f64::from(x[0][j])).abs())
                .sum::<f64>()
                .max(1e-300)
        };
        let mut paths = 0;
        for path in [HalfPath::Avx512, HalfPath::Avx2, HalfPath::Scalar] {
            let mut a = a.clone();
            if !a.set_path(path) {
                continue;
            }
            paths += 1;
            // Whole, two right-hand sides: the vectors scaled, the rows' and the columns'
            // sums added, the result scaled.
            let xs: [Vec<f32>; 2] =
                std::array::from_fn(|l| x[l].iter().zip(a.scale()).map(|(v, s)| v * s).collect());
            let mut y = [vec![0.0f64; m], vec![0.0f64; m]];
            let mut t = [vec![f32::NAN; n], vec![f32::NAN; n]];
            {
                let [y0, y1] = &mut y;
                let [t0, t1] = &mut t;
                a.scaled_rows::<2>([&xs[0], &xs[1]], [y0, y1], [t0, t1], 0..n / BLOCK);
            }
            for (yl, tl) in y.iter_mut().zip(&t) {
                for ((yj, tj), s) in yl.iter_mut().zip(tl).zip(a.scale()) {
                    *yj = (*yj + f64::from(*tj)) * f64::from(*s);
                }
            }
            for l in 0..2 {
                for i in 0..m {
                    let err = (y[l][i] - reference[l][i]).abs();
                    assert!(
                        err <= 1e-5 * scale_of(i).max(reference[l][i].abs()),
                        "{path:?} rhs {l} row {i}: {} vs {}",
                        y[l][i],
                        reference[l][i]
                    );
                }
            }
            // One right-hand side in two parts of block rows, summed as the mirror does.
            let xs0 = &xs[0];
            let cut = 2;
            let mut lo = vec![0.0f64; m];
            let (y0, y1) = lo.split_at_mut(BLOCK * cut);
            let (mut t0, mut t1) = (vec![0.0f32; n], vec![0.0f32; n]);
            a.scaled_rows::<1>([xs0], [y0], [&mut t0], 0..cut);
            a.scaled_rows::<1>([xs0], [y1], [&mut t1], cut..n / BLOCK);
            for j in 0..m {
                let v = (lo[j] + f64::from(t0[j]) + f64::from(t1[j])) * f64::from(a.scale()[j]);
                assert!(
                    (v - y[0][j]).abs() <= 1e-5 * scale_of(j),
                    "{path:?} in two parts, row {j}: {v} vs {}",
                    y[0][j]
                );
            }
        }
        assert!(paths >= 1 && HalfPath::Scalar.available());
        assert!(HalfPath::detect().available());
    }

    #[test]
    fn entries_that_are_not_finite_are_refused() {
        assert!(SymPackedHalf::from_fn(20, |i, j| if i == j { f64::NAN } else { 1.0 }).is_none());
        // A zero matrix keeps a unit scale and zero entries.
        let z = SymPackedHalf::from_fn(20, |_, _| 0.0).expect("finite");
        assert!(z.scale()[..20].iter().all(|&s| s == 1.0) && z.get(3, 7) == 0.0);
    }
}
