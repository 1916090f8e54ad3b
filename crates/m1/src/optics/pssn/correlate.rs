//! The half OTF's lag rows by correlating the field's row spectra ([`super::OtfMethod::Correlation`]).
//!
//! With `F_y` the FFT of field row `y` (zero-padded to `M`), the FFT along `x` of the OTF's lag
//! row `y'` is `sum_y F_{y+y'} conj(F_y)`: the cross-correlation of rows `y + y'` and `y`, summed
//! over the rows (no wrap-around, `M >= 2N`). Where few lag rows carry weight (12 on the default
//! TMT grid at 500 nm), these sums, `rows x N x M` complex multiply-adds, cost a fraction of the
//! 2-D power spectrum's `M` column FFTs, `M / 2` inverse row FFTs and two transposes, and need
//! no `M x M` buffer.
//!
//! The sums run on panels of a few vectors of columns copied out of the field (their rows
//! contiguous, so that a panel stays in the L1 cache, where the field's power-of-two row stride
//! would map it onto one cache set), `GROUP` lag rows at a time in registers, with `pulp`'s
//! complex vectors at the widest width the processor has.

use pulp::{Simd, WithSimd};
use rustfft::num_complex::Complex;

/// Lag rows one pass over a panel sums together, each in its own accumulators.
const GROUP: usize = 4;

/// Real numbers of a panel row at most (two pairs of 512-bit vectors of single precision): a
/// partial last panel goes through a buffer of this size.
const SPARE: usize = 64;

/// A precision of the correlation: `pulp`'s vectors of it.
pub(super) trait Lane: super::Sample + pulp::bytemuck::Pod {
    /// A vector of values.
    type V<S: Simd>: Copy;
    /// Values per vector.
    fn lanes<S: Simd>() -> usize;
    /// The zero vector.
    fn zeros<S: Simd>(simd: S) -> Self::V<S>;
    /// The whole vectors at the start of `x`.
    fn vectors<S: Simd>(x: &[Self]) -> &[Self::V<S>];
    /// The whole vectors at the start of `x`, to write.
    fn vectors_mut<S: Simd>(x: &mut [Self]) -> &mut [Self::V<S>];
    /// `a b + c`.
    fn mul_add<S: Simd>(simd: S, a: Self::V<S>, b: Self::V<S>, c: Self::V<S>) -> Self::V<S>;
    /// `-a`.
    fn negate<S: Simd>(simd: S, a: Self::V<S>) -> Self::V<S>;
    /// Two vectors of interleaved complex values as the vector of their real parts and that of
    /// their imaginary parts (in an order of the lanes of the processor's choosing, the same
    /// for both).
    fn split<S: Simd>(simd: S, v: [Self::V<S>; 2]) -> [Self::V<S>; 2];
    /// The inverse of [`Lane::split`].
    fn join<S: Simd>(simd: S, v: [Self::V<S>; 2]) -> [Self::V<S>; 2];
}

macro_rules! lane {
    ($t:ty, $v:ident, $lanes:ident, $splat:ident, $as:ident, $as_mut:ident, $fma:ident, $neg:ident,
     $split:ident, $join:ident) => {
        impl Lane for $t {
            type V<S: Simd> = S::$v;
            fn lanes<S: Simd>() -> usize {
                S::$lanes
            }
            #[inline(always)]
            fn zeros<S: Simd>(simd: S) -> S::$v {
                simd.$splat(0.0)
            }
            #[inline(always)]
            fn vectors<S: Simd>(x: &[$t]) -> &[S::$v] {
                S::$as(x).0
            }
            #[inline(always)]
            fn vectors_mut<S: Simd>(x: &mut [$t]) -> &mut [S::$v] {
                S::$as_mut(x).0
            }
            #[inline(always)]
            fn mul_add<S: Simd>(simd: S, a: S::$v, b: S::$v, c: S::$v) -> S::$v {
                simd.$fma(a, b, c)
            }
            #[inline(always)]
            fn negate<S: Simd>(simd: S, a: S::$v) -> S::$v {
                simd.$neg(a)
            }
            #[inline(always)]
            fn split<S: Simd>(simd: S, v: [S::$v; 2]) -> [S::$v; 2] {
                simd.$split(v)
            }
            #[inline(always)]
            fn join<S: Simd>(simd: S, v: [S::$v; 2]) -> [S::$v; 2] {
                simd.$join(v)
            }
        }
    };
}

lane!(
    f32,
    f32s,
    F32_LANES,
    splat_f32s,
    as_simd_f32s,
    as_mut_simd_f32s,
    mul_add_f32s,
    neg_f32s,
    deinterleave_shfl_f32s,
    interleave_shfl_f32s
);
lane!(
    f64,
    f64s,
    F64_LANES,
    splat_f64s,
    as_simd_f64s,
    as_mut_simd_f64s,
    mul_add_f64s,
    neg_f64s,
    deinterleave_shfl_f64s,
    interleave_shfl_f64s
);

/// Writes `otf[y'][k] = sum_y F[y + y'][k] conj(F[y][k])` for `y' < rows`, with `F` the `n`
/// rows of `field` (`n x m`, row-major; rows past `n` are zero). `panel` is scratch, grown as
/// needed.
pub(super) fn lag_rows<T: Lane>(
    field: &[Complex<T>],
    n: usize,
    m: usize,
    rows: usize,
    otf: &mut [Complex<T>],
    panel: &mut Vec<T>,
) {
    pulp::Arch::new().dispatch(LagRows {
        field,
        n,
        m,
        rows,
        otf,
        panel,
    });
}

struct LagRows<'a, T> {
    field: &'a [Complex<T>],
    n: usize,
    m: usize,
    rows: usize,
    otf: &'a mut [Complex<T>],
    panel: &'a mut Vec<T>,
}

impl<T: Lane> WithSimd for LagRows<'_, T> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        // With 32 vector registers, two pairs of vectors of columns at a time (16
        // accumulators); with 16, one.
        if std::mem::size_of::<S::f32s>() >= 64 {
            self.run::<S, 2>(simd);
        } else {
            self.run::<S, 1>(simd);
        }
    }
}

impl<T: Lane> LagRows<'_, T> {
    /// The sums, `B` vectors of complex values (held as their real and imaginary parts) per
    /// panel.
    #[inline(always)]
    fn run<S: Simd, const B: usize>(self, simd: S) {
        let Self {
            field,
            n,
            m,
            rows,
            otf,
            panel,
        } = self;
        let zero = Complex::new(T::zero(), T::zero());
        let otf = &mut otf[..rows * m];
        // Lags of n rows or more have no pair of rows.
        let live = rows.min(n);
        otf[live * m..].fill(zero);
        let lanes = T::lanes::<S>();
        // Complex values per panel row, and their real numbers.
        let width = B * lanes;
        let stride = 2 * width;
        let groups = live.div_ceil(GROUP);
        // Rows n.. of every panel stay zero: the last group's lags read up to them.
        let height = n + groups * GROUP;
        // The last panel's columns past `m` are zeros (their sums are not written).
        let blocks = m.div_ceil(width);
        let size = height * stride;
        let mut spare = [T::zero(); SPARE];
        let spare = &mut spare[..stride];
        if panel.len() != blocks * size {
            panel.clear();
            panel.resize(blocks * size, T::zero());
        }
        // Every panel's rows contiguous (its real parts, then its imaginary parts, per vector),
        // from one pass along the field's rows: read by columns, the field's power-of-two row
        // stride would put every row of a panel on a new page, out of the prefetchers' reach.
        let reals: &[T] = pulp::bytemuck::cast_slice(field);
        for y in 0..n {
            let row = &reals[2 * y * m..][..2 * m];
            for blk in 0..blocks {
                let from = 2 * blk * width;
                let src = if from + stride <= row.len() {
                    &row[from..from + stride]
                } else {
                    spare.fill(T::zero());
                    spare[..row.len() - from].copy_from_slice(&row[from..]);
                    &spare[..]
                };
                let src = T::vectors::<S>(src);
                let dst = T::vectors_mut::<S>(&mut panel[blk * size + y * stride..][..stride]);
                for b in 0..B {
                    let [re, im] = T::split(simd, [src[2 * b], src[2 * b + 1]]);
                    dst[2 * b] = re;
                    dst[2 * b + 1] = im;
                }
            }
        }
        for (blk, panel) in panel.chunks_exact(size).enumerate() {
            let c0 = blk * width;
            let row = |y: usize| -> &[T::V<S>] { T::vectors::<S>(&panel[y * stride..][..stride]) };
            for g in 0..groups {
                let first = g * GROUP;
                let mut acc = [[[T::zeros(simd); 2]; B]; GROUP];
                for y in 0..n {
                    let a = row(y);
                    let ar: [T::V<S>; B] = std::array::from_fn(|b| a[2 * b]);
                    let ai: [T::V<S>; B] = std::array::from_fn(|b| a[2 * b + 1]);
                    let nai: [T::V<S>; B] = std::array::from_fn(|b| T::negate(simd, ai[b]));
                    for (j, acc) in acc.iter_mut().enumerate() {
                        let c = row(y + first + j);
                        for (b, [re, im]) in acc.iter_mut().enumerate() {
                            let (cr, ci) = (c[2 * b], c[2 * b + 1]);
                            // conj(a) c = (ar cr + ai ci) + i (ar ci - ai cr).
                            *re = T::mul_add(simd, ar[b], cr, *re);
                            *re = T::mul_add(simd, ai[b], ci, *re);
                            *im = T::mul_add(simd, ar[b], ci, *im);
                            *im = T::mul_add(simd, nai[b], cr, *im);
                        }
                    }
                }
                for (j, acc) in acc.iter().enumerate().take(live - first) {
                    let valid = width.min(m - c0);
                    let out = &mut otf[(first + j) * m + c0..][..valid];
                    let out: &mut [T] = pulp::bytemuck::cast_slice_mut(out);
                    let whole = out.len() == stride;
                    let to = T::vectors_mut::<S>(if whole { &mut out[..] } else { &mut spare[..] });
                    for (b, &pair) in acc.iter().enumerate() {
                        let [lo, hi] = T::join(simd, pair);
                        to[2 * b] = lo;
                        to[2 * b + 1] = hi;
                    }
                    if !whole {
                        let n = out.len();
                        out.copy_from_slice(&spare[..n]);
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    /// `sum_y F[y + lag][c] conj(F[y][c])` term by term, in double precision.
    fn reference<T: Lane>(
        field: &[Complex<T>],
        n: usize,
        m: usize,
        lag: usize,
        c: usize,
    ) -> [f64; 2] {
        let mut s = [0.0; 2];
        for y in 0..n.saturating_sub(lag) {
            let (a, b) = (field[y * m + c], field[(y + lag) * m + c]);
            let (ar, ai, br, bi) = (a.re.wide(), a.im.wide(), b.re.wide(), b.im.wide());
            s[0] += ar * br + ai * bi;
            s[1] += ar * bi - ai * br;
        }
        s
    }

    /// Runs the kernel with `simd` on pseudo-random rows and checks every sum: more lag rows
    /// than a group and than the field's rows, columns that end in a partial panel.
    fn check<T: Lane, S: Simd>(simd: S, tolerance: f64) {
        let (n, m, rows) = (11, 37, 13);
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            T::of(((state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0)
        };
        let field: Vec<Complex<T>> = (0..n * m).map(|_| Complex::new(next(), next())).collect();
        let mut otf = vec![Complex::new(T::one(), T::one()); rows * m];
        let mut panel = Vec::new();
        for _ in 0..2 {
            simd.vectorize(LagRows {
                field: &field,
                n,
                m,
                rows,
                otf: &mut otf,
                panel: &mut panel,
            });
            for lag in 0..rows {
                for c in 0..m {
                    let want = reference(&field, n, m, lag, c);
                    let got = otf[lag * m + c];
                    let err = (got.re.wide() - want[0]).abs() + (got.im.wide() - want[1]).abs();
                    assert!(
                        err <= tolerance,
                        "{:?} lag {lag} column {c}: {got:?} against {want:?}",
                        simd
                    );
                }
            }
        }
    }

    #[test]
    fn lag_rows_match_plain_sums_at_every_vector_width() {
        check::<f64, _>(pulp::Scalar::new(), 1e-13);
        check::<f32, _>(pulp::Scalar::new(), 1e-5);
        #[cfg(target_arch = "x86_64")]
        {
            if let Some(simd) = pulp::x86::V3::try_new() {
                check::<f64, _>(simd, 1e-13);
                check::<f32, _>(simd, 1e-5);
            }
            if let Some(simd) = pulp::x86::V4::try_new() {
                check::<f64, _>(simd, 1e-13);
                check::<f32, _>(simd, 1e-5);
            }
        }
    }
}
