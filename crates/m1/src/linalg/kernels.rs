//! Streaming matrix-vector kernels for the coupled mirror's step loop, in explicit SIMD.
//!
//! The mirror's per-step products are tall and thin (the `3N x r` mode shapes against two or
//! three vectors) or square against one vector (the coupling matrix). A general matrix product
//! packs its operand into a buffer first, to reuse it across many right-hand sides: here that
//! reads and writes the matrix twice more than the product needs, and profiling showed the
//! packing alone taking a quarter of a TMT step. These kernels read each matrix once, in its
//! storage order, with every right-hand side applied while a chunk of it is in registers.
//!
//! Matrices are **row-major** with a row stride `lda`: row `i` of an `m x k` matrix is
//! `a[i * lda..i * lda + k]`. The products are of two kinds:
//! - `y = A x` (or `y += A x`), a dot product per row, a block of rows at a time
//!   ([`rows_dot`], [`rows_dot_f32`], [`rows_dot2_f32`]);
//! - `y = A^T x`, the rows combined a block at a time into `y` ([`rows_axpy2_f32`]; the CSI's
//!   upper trapezoidal basis in [`super::trapezoid`]).
//!
//! They are generic over a [`pulp::Simd`] instruction set: call them inside
//! [`pulp::Arch::dispatch`] so they run with the widest vectors the processor has, with a
//! portable scalar fallback. The sums are ordered by vector lane, so results agree with a
//! plain sum to rounding (about 1e-16 relative), not bit for bit, and may differ in the last
//! bits between processors with different vector widths.

use faer::c64;
use pulp::Simd;
use serde::{Deserialize, Serialize};

/// Rows of [`state_map`] computed together: independent chains of fused multiply-adds in
/// flight (four hide the latency of one addition behind the others on the project's machine).
pub const ROW_GROUP: usize = 4;

/// `k` rounded up to a whole number of the widest single-precision vectors (16 lanes): the row
/// stride that lets the single-precision kernels run without a scalar tail on any processor
/// (the padding holds zeros).
pub const fn padded_len(k: usize) -> usize {
    k.div_ceil(16) * 16
}

/// `y += A x`; `A` is `m x k` row-major with row stride `lda`, `x` has length `k`, `y`
/// length `m`.
///
/// # Panics
/// If a slice is shorter than the dimensions say (a programming error).
#[inline(always)]
pub fn rows_dot<S: Simd>(
    simd: S,
    a: &[f64],
    lda: usize,
    m: usize,
    k: usize,
    x: &[f64],
    y: &mut [f64],
) {
    let row = |i: usize| &a[i * lda..][..k];
    let mut i = 0;
    while i + 4 <= m {
        let s = dot4(simd, [row(i), row(i + 1), row(i + 2), row(i + 3)], x);
        for r in 0..4 {
            y[i + r] += s[r];
        }
        i += 4;
    }
    while i < m {
        let [[v]] = dot_block_f64(simd, [row(i)], [x], None);
        y[i] += v;
        i += 1;
    }
}

/// Asks the processor to bring the cache line of `p` into its caches (a hint: no effect on
/// values, no fault on any address). The streaming products prefetch the next group of rows
/// while they read one: each row is a stream of its own, a page or less long (4 kB at 1000
/// modes), which the processor's own prefetchers start on only after its first misses
/// (TMT at 1000 modes, the mirror about a tenth faster per step; BENCHMARKS.md, twenty-fifth
/// round).
#[inline(always)]
pub fn prefetch<T>(p: *const T) {
    #[cfg(target_arch = "x86_64")]
    // SAFETY: a prefetch reads nothing and does not fault, whatever the address.
    unsafe {
        std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p.cast());
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = p;
}

/// Single-precision values in a 64-byte cache line: the products prefetch every this many
/// values along a row (once per line, whatever their vectors' width).
pub const LINE_F32: usize = 16;
/// Double-precision values in a 64-byte cache line.
pub const LINE_F64: usize = 8;

/// `y += A x` for a single-precision `A` (`m x k` row-major, row stride `lda`) and `x`, each
/// row's products summed in single precision, by lane and then across the lanes (one vector
/// reduction), and added to the double-precision `y`: half the memory traffic of
/// [`rows_dot`], for products whose result is a small correction (relative error about 1e-7
/// of the row's magnitude).
///
/// # Panics
/// If a slice is shorter than the dimensions say (a programming error).
#[inline(always)]
pub fn rows_dot_f32<S: Simd>(
    simd: S,
    a: &[f32],
    lda: usize,
    m: usize,
    k: usize,
    x: &[f32],
    y: &mut [f64],
) {
    let x = &x[..k];
    let (xh, xt) = S::as_simd_f32s(x);
    let n = xh.len();
    let lanes = |v: S::f32s| -> f64 { f64::from(simd.reduce_sum_f32s(v)) };
    let tail = |row: &[f32]| -> f64 { tail_dot(S::as_simd_f32s(row).1, xt) };
    let row = |i: usize| &a[i * lda..][..k];
    let mut i = 0;
    // Four rows at a time: four independent accumulation chains.
    while i + 4 <= m {
        let r = [row(i), row(i + 1), row(i + 2), row(i + 3)];
        let (r0, _) = S::as_simd_f32s(r[0]);
        let (r1, _) = S::as_simd_f32s(r[1]);
        let (r2, _) = S::as_simd_f32s(r[2]);
        let (r3, _) = S::as_simd_f32s(r[3]);
        let (r0, r1, r2, r3) = (&r0[..n], &r1[..n], &r2[..n], &r3[..n]);
        let zero = simd.splat_f32s(0.0);
        let (mut a0, mut a1, mut a2, mut a3) = (zero, zero, zero, zero);
        // The next four rows, a group ahead.
        let next = a.as_ptr().wrapping_add((i + 4) * lda);
        for c in 0..n {
            if (c * S::F32_LANES).is_multiple_of(LINE_F32) {
                for j in 0..4 {
                    prefetch(next.wrapping_add(j * lda + c * S::F32_LANES));
                }
            }
            let xv = xh[c];
            a0 = simd.mul_add_f32s(r0[c], xv, a0);
            a1 = simd.mul_add_f32s(r1[c], xv, a1);
            a2 = simd.mul_add_f32s(r2[c], xv, a2);
            a3 = simd.mul_add_f32s(r3[c], xv, a3);
        }
        for (j, acc) in [a0, a1, a2, a3].into_iter().enumerate() {
            y[i + j] += lanes(acc) + tail(r[j]);
        }
        i += 4;
    }
    while i < m {
        let (rh, _) = S::as_simd_f32s(row(i));
        let mut acc = simd.splat_f32s(0.0);
        for (p, q) in rh[..n].iter().zip(xh) {
            acc = simd.mul_add_f32s(*p, *q, acc);
        }
        y[i] += lanes(acc) + tail(row(i));
        i += 1;
    }
}

/// `y_l += A x_l` for two right-hand sides with a single-precision `A` (`m x k` row-major,
/// row stride `lda`) and `x_l`, summed as [`rows_dot_f32`] sums (each row's products in
/// single precision by lane, one vector reduction, then added to the double-precision `y_l`):
/// one pass over `A` for both, four rows at a time (eight accumulation chains).
///
/// # Panics
/// If a slice is shorter than the dimensions say (a programming error).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn rows_dot2_f32<S: Simd>(
    simd: S,
    a: &[f32],
    lda: usize,
    m: usize,
    k: usize,
    x: [&[f32]; 2],
    y: [&mut [f64]; 2],
) {
    let [y0, y1] = y;
    let x = [&x[0][..k], &x[1][..k]];
    let n = S::as_simd_f32s(x[0]).0.len();
    let xh: [&[S::f32s]; 2] = std::array::from_fn(|l| &S::as_simd_f32s(x[l]).0[..n]);
    let xt: [&[f32]; 2] = std::array::from_fn(|l| S::as_simd_f32s(x[l]).1);
    let row = |i: usize| &a[i * lda..][..k];
    let mut i = 0;
    while i + 4 <= m {
        let rows = [row(i), row(i + 1), row(i + 2), row(i + 3)];
        let rh: [&[S::f32s]; 4] = std::array::from_fn(|r| &S::as_simd_f32s(rows[r]).0[..n]);
        let zero = simd.splat_f32s(0.0);
        let (r0, r1, r2, r3) = (rh[0], rh[1], rh[2], rh[3]);
        let (x0, x1) = (xh[0], xh[1]);
        let (mut a0, mut a1, mut a2, mut a3) = (zero, zero, zero, zero);
        let (mut b0, mut b1, mut b2, mut b3) = (zero, zero, zero, zero);
        // The next four rows, a group ahead.
        let next = a.as_ptr().wrapping_add((i + 4) * lda);
        for c in 0..n {
            if (c * S::F32_LANES).is_multiple_of(LINE_F32) {
                for j in 0..4 {
                    prefetch(next.wrapping_add(j * lda + c * S::F32_LANES));
                }
            }
            let (u, w) = (x0[c], x1[c]);
            let (v0, v1, v2, v3) = (r0[c], r1[c], r2[c], r3[c]);
            a0 = simd.mul_add_f32s(v0, u, a0);
            b0 = simd.mul_add_f32s(v0, w, b0);
            a1 = simd.mul_add_f32s(v1, u, a1);
            b1 = simd.mul_add_f32s(v1, w, b1);
            a2 = simd.mul_add_f32s(v2, u, a2);
            b2 = simd.mul_add_f32s(v2, w, b2);
            a3 = simd.mul_add_f32s(v3, u, a3);
            b3 = simd.mul_add_f32s(v3, w, b3);
        }
        let acc = [[a0, b0], [a1, b1], [a2, b2], [a3, b3]];
        for (r, accr) in acc.iter().enumerate() {
            let rt = S::as_simd_f32s(rows[r]).1;
            for (l, yl) in [&mut *y0, &mut *y1].into_iter().enumerate() {
                yl[i + r] += f64::from(simd.reduce_sum_f32s(accr[l])) + tail_dot(rt, xt[l]);
            }
        }
        i += 4;
    }
    while i < m {
        let (rh, rt) = S::as_simd_f32s(row(i));
        let zero = simd.splat_f32s(0.0);
        let (mut p, mut q) = (zero, zero);
        for (c, v) in rh[..n].iter().enumerate() {
            p = simd.mul_add_f32s(*v, xh[0][c], p);
            q = simd.mul_add_f32s(*v, xh[1][c], q);
        }
        for (l, (yl, acc)) in [(&mut *y0, p), (&mut *y1, q)].into_iter().enumerate() {
            yl[i] += f64::from(simd.reduce_sum_f32s(acc)) + tail_dot(rt, xt[l]);
        }
        i += 1;
    }
}

/// `y[i - rows.start] = sum_j x_j A[j, i]` for `i` in `rows`: a single-precision `A` (`k x n`
/// row-major, row stride `lda`) read by columns, each output one lane of a vector summed over
/// `j` in order in single precision (no reduction across lanes), [`COLS_BLOCK`] vectors of
/// outputs at a time, then written in double precision.
///
/// The transposed form of [`rows_dot_f32`], for short rows: a row of 60 modes is four vectors,
/// and its reduction across the lanes cost as much as its products (the coupled mirror's pass
/// back to the actuators at 60 modes, BENCHMARKS.md twenty-second round). Each output's sum does
/// not depend on `rows` (a row gives the same bits whatever range computes it); its relative
/// error is about `k` units in the last place of single precision at most, of the sum of the
/// terms' magnitudes (about `sqrt(k)` typically).
///
/// # Panics
/// If a slice is shorter than the dimensions say (a programming error).
#[inline(always)]
pub fn cols_dot_f32<S: Simd>(
    simd: S,
    a: &[f32],
    lda: usize,
    k: usize,
    rows: std::ops::Range<usize>,
    x: &[f32],
    y: &mut [f64],
) {
    const B: usize = COLS_BLOCK;
    let lanes = S::F32_LANES;
    let x = &x[..k];
    let y = &mut y[..rows.len()];
    let zero = simd.splat_f32s(0.0);
    let mut lane = [0.0f32; 16];
    let mut i = rows.start;
    while i < rows.end {
        // Every block sums B vectors (constant bounds: the sums stay in registers); the last
        // loads the outputs it has with partial loads, zeros past them.
        let valid = (rows.end - i).min(B * lanes);
        let mut acc = [zero; B];
        if valid == B * lanes {
            for (j, &xj) in x.iter().enumerate() {
                let xv = simd.splat_f32s(xj);
                let (ch, _) = S::as_simd_f32s(&a[j * lda + i..][..B * lanes]);
                for (acc, c) in acc.iter_mut().zip(&ch[..B]) {
                    *acc = simd.mul_add_f32s(*c, xv, *acc);
                }
            }
        } else {
            for (j, &xj) in x.iter().enumerate() {
                let xv = simd.splat_f32s(xj);
                let col = &a[j * lda + i..][..valid];
                for (b, acc) in acc.iter_mut().enumerate() {
                    let lo = (b * lanes).min(valid);
                    let c = simd.partial_load_f32s(&col[lo..(lo + lanes).min(valid)]);
                    *acc = simd.mul_add_f32s(c, xv, *acc);
                }
            }
        }
        for (b, acc) in acc.iter().enumerate() {
            let from = b * lanes;
            if from >= valid {
                break;
            }
            let n = (valid - from).min(lanes);
            simd.partial_store_f32s(&mut lane[..n], *acc);
            let at = i - rows.start + from;
            for (o, v) in y[at..at + n].iter_mut().zip(&lane[..n]) {
                *o = f64::from(*v);
            }
        }
        i += valid;
    }
}

/// Vectors of outputs [`cols_dot_f32`] sums together (each its own chain of multiply-adds).
pub const COLS_BLOCK: usize = 8;

/// The products of a single-precision row's scalar tail with the vector's, summed in double
/// precision.
#[inline(always)]
fn tail_dot(t: &[f32], x: &[f32]) -> f64 {
    t.iter()
        .zip(x)
        .map(|(u, w)| f64::from(*u) * f64::from(*w))
        .sum()
}

/// Sum of the lanes of a vector.
#[inline(always)]
pub(crate) fn hsum<S: Simd>(v: S::f64s) -> f64 {
    let lanes: &[f64] = pulp::bytemuck::cast_slice(std::slice::from_ref(&v));
    let mut s = 0.0;
    for x in lanes {
        s += x;
    }
    s
}

/// Dot products of four rows with one vector.
#[inline(always)]
fn dot4<S: Simd>(simd: S, rows: [&[f64]; 4], x: &[f64]) -> [f64; 4] {
    let (xh, xt) = S::as_simd_f64s(x);
    let n = xh.len();
    let (r0, t0) = S::as_simd_f64s(rows[0]);
    let (r1, t1) = S::as_simd_f64s(rows[1]);
    let (r2, t2) = S::as_simd_f64s(rows[2]);
    let (r3, t3) = S::as_simd_f64s(rows[3]);
    let (r0, r1, r2, r3) = (&r0[..n], &r1[..n], &r2[..n], &r3[..n]);
    let zero = simd.splat_f64s(0.0);
    let (mut a0, mut a1, mut a2, mut a3) = (zero, zero, zero, zero);
    for c in 0..n {
        let xv = xh[c];
        a0 = simd.mul_add_f64s(r0[c], xv, a0);
        a1 = simd.mul_add_f64s(r1[c], xv, a1);
        a2 = simd.mul_add_f64s(r2[c], xv, a2);
        a3 = simd.mul_add_f64s(r3[c], xv, a3);
    }
    let tail = |t: &[f64]| -> f64 {
        let mut s = 0.0;
        for (p, q) in t.iter().zip(xt) {
            s += p * q;
        }
        s
    };
    [
        hsum::<S>(a0) + tail(t0),
        hsum::<S>(a1) + tail(t1),
        hsum::<S>(a2) + tail(t2),
        hsum::<S>(a3) + tail(t3),
    ]
}

/// Element `c` of each of the `N` slices. A loop, not `std::array::from_fn`: that closure over
/// SIMD vectors was not always inlined into the dispatched kernel, and then ran once per
/// column as a call compiled for baseline x86-64, copying the vectors through the stack (7 %
/// of the Keck mirror's step in one such call, BENCHMARKS.md, thirteenth round).
#[inline(always)]
fn at_column<T: Copy, const N: usize>(slices: &[&[T]; N], c: usize, fill: T) -> [T; N] {
    let mut out = [fill; N];
    for (o, s) in out.iter_mut().zip(slices) {
        *o = s[c];
    }
    out
}

/// The elements from `from` on of each of the `N` slices (fewer than a vector's lanes), as
/// vectors filled with zeros; a loop for the reason of [`at_column`].
#[inline(always)]
fn partial_at<S: Simd, const N: usize>(simd: S, slices: &[&[f64]; N], from: usize) -> [S::f64s; N] {
    let mut out = [simd.splat_f64s(0.0); N];
    for (o, s) in out.iter_mut().zip(slices) {
        *o = simd.partial_load_f64s(&s[from..]);
    }
    out
}

/// Dot products of `R` rows with `L` vectors (`R L` independent accumulation chains), each
/// summed by lane, across the lanes, then with the scalar tail.
#[inline(always)]
pub(crate) fn dot_block_f64<S: Simd, const R: usize, const L: usize>(
    simd: S,
    rows: [&[f64]; R],
    x: [&[f64]; L],
    ahead: Option<(*const f64, usize)>,
) -> [[f64; L]; R] {
    let n = S::as_simd_f64s(x[0]).0.len();
    let xh: [&[S::f64s]; L] = std::array::from_fn(|l| &S::as_simd_f64s(x[l]).0[..n]);
    let xt: [&[f64]; L] = std::array::from_fn(|l| S::as_simd_f64s(x[l]).1);
    let rh: [&[S::f64s]; R] = std::array::from_fn(|r| &S::as_simd_f64s(rows[r]).0[..n]);
    let zero = simd.splat_f64s(0.0);
    let mut acc = [[zero; L]; R];
    for c in 0..n {
        if let Some((next, lda)) = ahead
            && (c * S::F64_LANES).is_multiple_of(LINE_F64)
        {
            for j in 0..R {
                prefetch(next.wrapping_add(j * lda + c * S::F64_LANES));
            }
        }
        let xv: [S::f64s; L] = at_column(&xh, c, zero);
        for (accr, rr) in acc.iter_mut().zip(&rh) {
            let a = rr[c];
            for (acc, xv) in accr.iter_mut().zip(&xv) {
                *acc = simd.mul_add_f64s(a, *xv, *acc);
            }
        }
    }
    std::array::from_fn(|r| {
        let t = S::as_simd_f64s(rows[r]).1;
        std::array::from_fn(|l| {
            let mut s = hsum::<S>(acc[r][l]);
            for (p, q) in t.iter().zip(xt[l]) {
                s += p * q;
            }
            s
        })
    })
}

/// `y_l += sum_r c_l[r] row_r` for four rows and two outputs, in one pass over the rows, the
/// next four (`next`, row stride `lda`) prefetched along (the CSI's coupled basis: rows of
/// 8 kB, streams of their own).
#[inline(always)]
pub(crate) fn axpy4x2<S: Simd>(
    simd: S,
    rows: [&[f64]; 4],
    c: [[f64; 4]; 2],
    y: [&mut [f64]; 2],
    (next, lda): (*const f64, usize),
) {
    let [y0, y1] = y;
    let (yh0, yt0) = S::as_mut_simd_f64s(y0);
    let (yh1, yt1) = S::as_mut_simd_f64s(y1);
    let n = yh0.len();
    let rh: [&[S::f64s]; 4] = std::array::from_fn(|r| &S::as_simd_f64s(rows[r]).0[..n]);
    let cv = c.map(|cl| cl.map(|v| simd.splat_f64s(v)));
    for j in 0..n {
        if (j * S::F64_LANES).is_multiple_of(LINE_F64) {
            for r in 0..4 {
                prefetch(next.wrapping_add(r * lda + j * S::F64_LANES));
            }
        }
        let (mut u, mut v) = (yh0[j], yh1[j]);
        for r in 0..4 {
            let a = rh[r][j];
            u = simd.mul_add_f64s(a, cv[0][r], u);
            v = simd.mul_add_f64s(a, cv[1][r], v);
        }
        yh0[j] = u;
        yh1[j] = v;
    }
    for (l, yt) in [yt0, yt1].into_iter().enumerate() {
        for (j, yv) in yt.iter_mut().enumerate() {
            let at = n * S::F64_LANES + j;
            *yv += rows[0][at] * c[l][0]
                + rows[1][at] * c[l][1]
                + rows[2][at] * c[l][2]
                + rows[3][at] * c[l][3];
        }
    }
}

/// `y_l = A^T x_l` for two right-hand sides with a single-precision `A` (`m x k` row-major,
/// row stride `lda`) and `x_l`: the rows are combined four at a time, each chunk of them
/// loaded once for both right-hand sides, into the single-precision
/// `acc_l` (length `k`, scratch), which is added into the double-precision `y_l` every
/// `FLUSH` rows, so no single-precision sum runs over more than `FLUSH` rows (relative error
/// about 1e-7 of the sum of the magnitudes of the terms). `y_l` may be shorter than `k`: the
/// sums past its length are dropped (the zero columns of a matrix padded to whole vectors,
/// [`padded_len`]).
///
/// # Panics
/// If a slice is shorter than the dimensions say (a programming error).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn rows_axpy2_f32<S: Simd>(
    simd: S,
    a: &[f32],
    lda: usize,
    m: usize,
    k: usize,
    x: [&[f32]; 2],
    y: [&mut [f64]; 2],
    acc: [&mut [f32]; 2],
) {
    const FLUSH: usize = 64;
    let [y0, y1] = y;
    let (k0, k1) = (y0.len().min(k), y1.len().min(k));
    let (y0, y1) = (&mut y0[..k0], &mut y1[..k1]);
    let [a0, a1] = acc;
    let (a0, a1) = (&mut a0[..k], &mut a1[..k]);
    y0.fill(0.0);
    y1.fill(0.0);
    a0.fill(0.0);
    a1.fill(0.0);
    let row = |i: usize| &a[i * lda..][..k];
    let flush = |acc: &mut [f32], y: &mut [f64]| {
        for (yv, av) in y.iter_mut().zip(acc.iter_mut()) {
            *yv += f64::from(*av);
            *av = 0.0;
        }
    };
    let mut i = 0;
    let mut since = 0;
    while i < m {
        // AXPY_ROWS rows at a time (repeating the last with a zero weight at the end).
        let idx: [usize; AXPY_ROWS] = std::array::from_fn(|r| (i + r).min(m - 1));
        let w = |x: &[f32]| -> [f32; AXPY_ROWS] {
            std::array::from_fn(|r| if i + r < m { x[i + r] } else { 0.0 })
        };
        let rows = idx.map(row);
        axpy_rows_x2_f32(simd, rows, [w(x[0]), w(x[1])], [&mut *a0, &mut *a1]);
        i += AXPY_ROWS;
        since += AXPY_ROWS;
        if since >= FLUSH || i >= m {
            flush(a0, y0);
            flush(a1, y1);
            since = 0;
        }
    }
}

/// Rows combined at a time by [`rows_axpy2_f32`]: with two right-hand sides, their weights
/// and the two sums stay in the sixteen vector registers of AVX2 (measured at TMT size with
/// 300 modes: 4 and 6 rows alike, 8 slower).
const AXPY_ROWS: usize = 4;

/// `y_l += sum_r c_lr row_r` for two right-hand sides in single precision: each chunk of the
/// `R` rows is loaded once for both.
#[inline(always)]
fn axpy_rows_x2_f32<S: Simd, const R: usize>(
    simd: S,
    rows: [&[f32]; R],
    c: [[f32; R]; 2],
    y: [&mut [f32]; 2],
) {
    let [y0, y1] = y;
    let (yh0, yt0) = S::as_mut_simd_f32s(y0);
    let (yh1, yt1) = S::as_mut_simd_f32s(y1);
    let n = yh0.len().min(yh1.len());
    let rh: [&[S::f32s]; R] = std::array::from_fn(|r| &S::as_simd_f32s(rows[r]).0[..n]);
    let c0: [S::f32s; R] = std::array::from_fn(|r| simd.splat_f32s(c[0][r]));
    let c1: [S::f32s; R] = std::array::from_fn(|r| simd.splat_f32s(c[1][r]));
    for j in 0..n {
        let (mut u, mut v) = (yh0[j], yh1[j]);
        for r in 0..R {
            let a = rh[r][j];
            u = simd.mul_add_f32s(a, c0[r], u);
            v = simd.mul_add_f32s(a, c1[r], v);
        }
        yh0[j] = u;
        yh1[j] = v;
    }
    for (l, yt) in [yt0, yt1].into_iter().enumerate() {
        for (j, yv) in yt.iter_mut().enumerate() {
            for r in 0..R {
                *yv += S::as_simd_f32s(rows[r]).1[j] * c[l][r];
            }
        }
    }
}

/// The same small linear map applied to many columns stored by state ("structure of
/// arrays": state `s` of column `c` at `x[s n + c]`):
///
/// `out[i n + c] = sum_s a[i][s] x[s n + c] + sum_l b[i][l] u_l[c]`, for `i < NS`, `c < n`;
///
/// and, if `dot` is given as `(w, d)`, also `d[c] += sum_i w[i] out[i n + c]`.
///
/// Each vector of columns is read once (all its states and inputs) and its new states are
/// written once, with the sums in registers: a pass of state-by-state axpys reads and writes
/// every state `NS` times. The rows are computed [`ROW_GROUP`] at a time, so that as many
/// independent chains of fused multiply-adds are in flight (one row's chain alone waits on the
/// latency of each addition), and a source (state or input) whose coefficients are zero for
/// every row of a group is skipped (`masks`, the map's [`SourceMasks::of`]): the segment
/// channels' maps have whole zero columns (the drive, an absent shunt) and sparse servo rows
/// (the voice coil's: 66 of 144 entries non-zero). Each output
/// is summed in the order of `a`'s columns, then `b`'s, with fused multiply-adds where the
/// instruction set has them (never emulated in software); a skipped term is an exact zero for
/// finite states, so the result is the dense sum's.
///
/// # Panics
/// If a slice is shorter than `NS n` (`x`, `out`) or `n` (`u_l`, `d`): a programming error.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn state_map<S: Simd, const NS: usize, const NI: usize>(
    simd: S,
    a: &[[f64; NS]; NS],
    b: &[[f64; NI]; NS],
    masks: &SourceMasks,
    x: &[f64],
    u: [&[f64]; NI],
    n: usize,
    out: &mut [f64],
    dot: Option<(&[f64; NS], &mut [f64])>,
) {
    const G: usize = ROW_GROUP;
    const { assert!(NS <= ROWS_MAP_MAX, "state_map: too many states") };
    if n == 0 {
        return;
    }
    let (xs, us) = columns::<NS, NI>(x, u, n);
    let mut rows = out[..NS * n].chunks_exact_mut(n);
    let mut outs: [&mut [f64]; NS] = std::array::from_fn(|_| rows.next().unwrap_or_default());
    let m = S::as_simd_f64s(xs[0]).0.len();
    let tail = n - S::as_simd_f64s(xs[0]).1.len();
    let xh: [&[S::f64s]; NS] = std::array::from_fn(|j| &S::as_simd_f64s(xs[j]).0[..m]);
    let uh: [&[S::f64s]; NI] = std::array::from_fn(|l| &S::as_simd_f64s(us[l]).0[..m]);
    let groups = NS.div_ceil(G);
    debug_assert_eq!(
        *masks,
        SourceMasks::of(a, b),
        "state_map: masks of another map"
    );
    let (w, mut d) = match dot {
        Some((w, d)) => (Some(w), Some(d)),
        None => (None, None),
    };
    {
        let mut it = outs.iter_mut();
        let oh: [&mut [S::f64s]; NS] = std::array::from_fn(|_| match it.next() {
            Some(o) => S::as_mut_simd_f64s(o).0,
            None => Default::default(),
        });
        let mut dh = d.as_deref_mut().map(|d| S::as_mut_simd_f64s(&mut d[..n]).0);
        let zero = simd.splat_f64s(0.0);
        for c in 0..m {
            let xv: [S::f64s; NS] = at_column(&xh, c, zero);
            let uv: [S::f64s; NI] = at_column(&uh, c, zero);
            let mut dacc = zero;
            for g in 0..groups {
                let acc = group_sums(simd, a, b, g, masks, &xv, &uv);
                for (r, acc) in acc.into_iter().enumerate() {
                    let i = G * g + r;
                    if i < NS {
                        oh[i][c] = acc;
                        if let Some(w) = w {
                            dacc = simd.mul_add_e_f64s(simd.splat_f64s(w[i]), acc, dacc);
                        }
                    }
                }
            }
            if let Some(dh) = dh.as_deref_mut() {
                dh[c] = simd.add_f64s(dh[c], dacc);
            }
        }
    }
    // The columns after the last whole vector: one vector loaded with zeros past `n`, summed
    // as the others.
    if tail < n {
        let xv: [S::f64s; NS] = partial_at(simd, &xs, tail);
        let uv: [S::f64s; NI] = partial_at(simd, &us, tail);
        let mut dacc = simd.splat_f64s(0.0);
        for g in 0..groups {
            let acc = group_sums(simd, a, b, g, masks, &xv, &uv);
            for (r, acc) in acc.into_iter().enumerate() {
                let i = G * g + r;
                if i < NS {
                    simd.partial_store_f64s(&mut outs[i][tail..], acc);
                    if let Some(w) = w {
                        dacc = simd.mul_add_e_f64s(simd.splat_f64s(w[i]), acc, dacc);
                    }
                }
            }
        }
        if let Some(d) = d {
            let dt = &mut d[tail..n];
            let sum = simd.add_f64s(simd.partial_load_f64s(dt), dacc);
            simd.partial_store_f64s(dt, sum);
        }
    }
}

/// The `NS` state columns of `x` (`NS n`, state-major) and the `NI` input columns, each `n`
/// long.
#[inline(always)]
#[allow(clippy::type_complexity)]
fn columns<'a, const NS: usize, const NI: usize>(
    x: &'a [f64],
    u: [&'a [f64]; NI],
    n: usize,
) -> ([&'a [f64]; NS], [&'a [f64]; NI]) {
    (
        std::array::from_fn(|j| &x[j * n..(j + 1) * n]),
        std::array::from_fn(|l| &u[l][..n]),
    )
}

/// Groups of [`ROW_GROUP`] rows of the maps of [`state_map`] and [`rows_map`], at most.
const MAX_GROUPS: usize = ROWS_MAP_MAX / ROW_GROUP;

/// Which sources (the states, then the inputs) each group of [`ROW_GROUP`] rows of a map
/// `[a b]` reads with a non-zero coefficient, a bit per source (bit `j` state `j`, bit
/// `NS + l` input `l`): what [`state_map`] and [`rows_map`] skip. Made once per map
/// ([`Self::of`]) and kept with it: found again at every pass, they took 2.5 % of a profile of
/// the coupled mirror's step at 60 modes (BENCHMARKS.md, twenty-second round).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SourceMasks([u64; MAX_GROUPS]);

impl SourceMasks {
    /// The sources each group of rows of `[a b]` reads (`a` and `b` of the same length, at most
    /// [`ROWS_MAP_MAX`] rows, `NS + NI` at most 64 sources).
    ///
    /// # Panics
    /// If the map is larger than that (a programming error).
    pub fn of<const NS: usize, const NI: usize>(a: &[[f64; NS]], b: &[[f64; NI]]) -> Self {
        const { assert!(NS + NI <= 64, "SourceMasks: more than 64 sources") };
        assert!(
            a.len() == b.len() && a.len() <= ROWS_MAP_MAX,
            "SourceMasks: {} and {} rows",
            a.len(),
            b.len()
        );
        let mut m = [0u64; MAX_GROUPS];
        for (i, (ai, bi)) in a.iter().zip(b).enumerate() {
            let sources = ai.iter().chain(bi);
            for (j, v) in sources.enumerate() {
                m[i / ROW_GROUP] |= u64::from(*v != 0.0) << j;
            }
        }
        Self(m)
    }

    /// Whether group `g` reads source `s`.
    #[inline(always)]
    fn reads(&self, g: usize, s: usize) -> bool {
        (self.0[g] >> s) & 1 != 0
    }
}

/// The sums of group `g`'s rows of `[a b]` (rows `G g..G g + G`; past the last row the last
/// is repeated, its sum to be dropped) at one vector of columns `xv`, `uv`, skipping the
/// sources the group does not read; each in the order of `a`'s columns, then `b`'s.
#[inline(always)]
fn group_sums<S: Simd, const NS: usize, const NI: usize>(
    simd: S,
    a: &[[f64; NS]],
    b: &[[f64; NI]],
    g: usize,
    masks: &SourceMasks,
    xv: &[S::f64s; NS],
    uv: &[S::f64s; NI],
) -> [S::f64s; ROW_GROUP] {
    let row = |r: usize| (ROW_GROUP * g + r).min(a.len() - 1);
    let mut acc = [simd.splat_f64s(0.0); ROW_GROUP];
    for j in 0..NS {
        if masks.reads(g, j) {
            for (r, acc) in acc.iter_mut().enumerate() {
                let k = a[row(r)][j];
                *acc = simd.mul_add_e_f64s(simd.splat_f64s(k), xv[j], *acc);
            }
        }
    }
    for l in 0..NI {
        if masks.reads(g, NS + l) {
            for (r, acc) in acc.iter_mut().enumerate() {
                let k = b[row(r)][l];
                *acc = simd.mul_add_e_f64s(simd.splat_f64s(k), uv[l], *acc);
            }
        }
    }
    acc
}

/// Most rows [`rows_map`] takes (its per-group masks live in fixed arrays).
pub const ROWS_MAP_MAX: usize = 64;

/// `out_i = sum_j a_ij x_j + sum_l b_il u_l` for `a.len()` (at most [`ROWS_MAP_MAX`]) rows over
/// `n` columns: a rectangular [`state_map`] (the same storage: `x` is `NS n` state-major, `out`
/// is `a.len() n` row-major), for maps that give more or fewer values than they read (a
/// composite of several steps' maps with their outputs). Rows are computed [`ROW_GROUP`] at a
/// time and a group skips the sources none of its rows reads (`masks`, the map's
/// [`SourceMasks::of`]); each row is summed in the order of `a`'s columns, then `b`'s.
///
/// # Panics
/// If `a` and `b` differ in length, there are more than [`ROWS_MAP_MAX`] rows, or a slice is
/// shorter than the dimensions say (programming errors).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub fn rows_map<S: Simd, const NS: usize, const NI: usize>(
    simd: S,
    a: &[[f64; NS]],
    b: &[[f64; NI]],
    masks: &SourceMasks,
    x: &[f64],
    u: [&[f64]; NI],
    n: usize,
    out: &mut [f64],
) {
    const G: usize = ROW_GROUP;
    let rows = a.len();
    assert!(
        b.len() == rows && rows <= ROWS_MAP_MAX,
        "rows_map: {rows} rows"
    );
    if n == 0 || rows == 0 {
        return;
    }
    let (xs, us) = columns::<NS, NI>(x, u, n);
    let out = &mut out[..rows * n];
    let m = S::as_simd_f64s(xs[0]).0.len();
    let tail = n - S::as_simd_f64s(xs[0]).1.len();
    let xh: [&[S::f64s]; NS] = std::array::from_fn(|j| &S::as_simd_f64s(xs[j]).0[..m]);
    let uh: [&[S::f64s]; NI] = std::array::from_fn(|l| &S::as_simd_f64s(us[l]).0[..m]);
    debug_assert_eq!(
        *masks,
        SourceMasks::of(a, b),
        "rows_map: masks of another map"
    );
    let mut it = out.chunks_exact_mut(n);
    let zero = simd.splat_f64s(0.0);
    for g in 0..rows.div_ceil(G) {
        let mut oh: [&mut [S::f64s]; G] = std::array::from_fn(|_| match it.next() {
            Some(o) => S::as_mut_simd_f64s(o).0,
            None => Default::default(),
        });
        for c in 0..m {
            let xv: [S::f64s; NS] = at_column(&xh, c, zero);
            let uv: [S::f64s; NI] = at_column(&uh, c, zero);
            let acc = group_sums(simd, a, b, g, masks, &xv, &uv);
            for (o, acc) in oh.iter_mut().zip(acc) {
                if let Some(o) = o.get_mut(c) {
                    *o = acc;
                }
            }
        }
    }
    // The columns after the last whole vector: one vector loaded with zeros past `n`, summed
    // as the others.
    if tail < n {
        let xv: [S::f64s; NS] = partial_at(simd, &xs, tail);
        let uv: [S::f64s; NI] = partial_at(simd, &us, tail);
        for g in 0..rows.div_ceil(G) {
            let acc = group_sums(simd, a, b, g, masks, &xv, &uv);
            for (r, acc) in acc.into_iter().enumerate() {
                let i = G * g + r;
                if i < rows {
                    simd.partial_store_f64s(&mut out[i * n + tail..(i + 1) * n], acc);
                }
            }
        }
    }
}

/// `out += a x`.
#[inline(always)]
pub fn axpy(out: &mut [f64], a: f64, x: &[f64]) {
    for (o, xi) in out.iter_mut().zip(x) {
        *o += a * xi;
    }
}

// Complex vectors (the dense solves' passes: `lu_solve`, `complex_symmetric`, `extreme`).

/// Rows `from..to` of column `j` of the column-major `m` as a slice (empty if the column is
/// not contiguous: the callers check the storage first, as faer's owned matrices are).
#[inline(always)]
pub fn column_c64(m: faer::MatRef<'_, c64>, j: usize, from: usize, to: usize) -> &[c64] {
    match m.col(j).try_as_col_major() {
        Some(c) => &c.as_slice()[from..to],
        None => &[],
    }
}

/// `y += s a`.
#[inline(always)]
pub fn axpy_c64<S: Simd>(simd: S, s: c64, a: &[c64], y: &mut [c64]) {
    let (ah, at) = S::as_simd_c64s(a);
    let (yh, yt) = S::as_mut_simd_c64s(y);
    let sv = simd.splat_c64s(s);
    for (yv, &av) in yh.iter_mut().zip(ah) {
        *yv = simd.mul_add_c64s(sv, av, *yv);
    }
    for (yv, &av) in yt.iter_mut().zip(at) {
        *yv += s * av;
    }
}

/// `sum_i conj(a_i) w_i`.
#[inline(always)]
pub fn dot_conj_c64<S: Simd>(simd: S, a: &[c64], w: &[c64]) -> c64 {
    let (ah, at) = S::as_simd_c64s(a);
    let (wh, wt) = S::as_simd_c64s(w);
    let zero = simd.splat_c64s(c64::new(0.0, 0.0));
    let fma = |x, y, acc| simd.conj_mul_add_c64s(x, y, acc);
    // Four independent sums: a complex multiply-add is two dependent fused operations.
    let mut acc = [zero; 4];
    let mut chunks = ah.chunks_exact(4).zip(wh.chunks_exact(4));
    for (ac, wc) in &mut chunks {
        for k in 0..4 {
            acc[k] = fma(ac[k], wc[k], acc[k]);
        }
    }
    let done = ah.len() / 4 * 4;
    for (k, (&av, &wv)) in ah[done..].iter().zip(&wh[done..]).enumerate() {
        acc[k] = fma(av, wv, acc[k]);
    }
    let mut s = (simd.reduce_sum_c64s(acc[0]) + simd.reduce_sum_c64s(acc[1]))
        + (simd.reduce_sum_c64s(acc[2]) + simd.reduce_sum_c64s(acc[3]));
    for (&a, &w) in at.iter().zip(wt) {
        s += a.conj() * w;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `state_map` against the plain sums, for column counts around the vector width, with a
    /// dense map and with a sparse one (a zero column, a state that no row of the first group of
    /// rows reads, one that the group's first row does not read but the others do, an input
    /// only the last, partial, group reads).
    #[test]
    fn state_map_equals_the_plain_sums() {
        const {
            assert!(
                !NS.is_multiple_of(ROW_GROUP),
                "the test needs a partial group of rows"
            )
        };
        let dense: [[f64; NS]; NS] = std::array::from_fn(|i| {
            std::array::from_fn(|j| ((i * 7 + j * 3) % 11) as f64 / 5.0 - 1.0)
        });
        let sparse: [[f64; NS]; NS] = std::array::from_fn(|i| {
            std::array::from_fn(|j| {
                if j == 1 || (j == 3 && i < ROW_GROUP) || (i == 0 && j == 2) {
                    0.0
                } else {
                    dense[i][j]
                }
            })
        });
        let b_dense: [[f64; NI]; NS] =
            std::array::from_fn(|i| std::array::from_fn(|l| ((i + 2 * l) % 5) as f64 - 2.0));
        let b_sparse: [[f64; NI]; NS] = std::array::from_fn(|i| {
            std::array::from_fn(|l| {
                if l == 0 && i < ROW_GROUP {
                    0.0
                } else {
                    b_dense[i][l]
                }
            })
        });
        for (a, b) in [(dense, b_dense), (sparse, b_sparse)] {
            state_map_case(&a, &b);
        }
    }

    /// `cols_dot_f32` against the plain double-precision sums (within single precision's
    /// rounding of the sum of the terms' magnitudes), over ranges of rows that start and end
    /// anywhere in a vector and around a block; every row gives the same bits whatever range
    /// computes it; the scalar instruction set gives the same bits as the vector ones.
    #[test]
    fn cols_dot_f32_sums_each_row_whatever_the_range() {
        struct Case<'a> {
            a: &'a [f32],
            lda: usize,
            k: usize,
            rows: std::ops::Range<usize>,
            x: &'a [f32],
            y: &'a mut [f64],
        }
        impl pulp::WithSimd for Case<'_> {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: Simd>(self, simd: S) {
                cols_dot_f32::<S>(simd, self.a, self.lda, self.k, self.rows, self.x, self.y);
            }
        }
        let (k, n, lda) = (61usize, 301usize, 304usize);
        let a: Vec<f32> = (0..k * lda)
            .map(|i| ((i * 7919) % 1013) as f32 / 1013.0 - 0.5)
            .collect();
        let x: Vec<f32> = (0..k).map(|j| (j as f32 * 0.37).sin()).collect();
        let run = |rows: std::ops::Range<usize>, scalar: bool| {
            let mut y = vec![f64::NAN; rows.len()];
            let case = Case {
                a: &a,
                lda,
                k,
                rows,
                x: &x,
                y: &mut y,
            };
            if scalar {
                pulp::WithSimd::with_simd(case, pulp::Scalar);
            } else {
                pulp::Arch::new().dispatch(case);
            }
            y
        };
        let whole = run(0..n, false);
        for i in 0..n {
            let (want, size) = (0..k).fold((0.0f64, 0.0f64), |(s, m), j| {
                let t = f64::from(a[j * lda + i]) * f64::from(x[j]);
                (s + t, m + t.abs())
            });
            assert!(
                (whole[i] - want).abs() <= 1e-6 * size,
                "row {i}: {} vs {want}",
                whole[i]
            );
        }
        for rows in [0..1, 3..20, 17..150, 100..301, 129..130, 250..301] {
            let part = run(rows.clone(), false);
            for (i, v) in rows.clone().zip(&part) {
                assert_eq!(v.to_bits(), whole[i].to_bits(), "row {i} of {rows:?}");
            }
        }
        let scalar = run(0..n, true);
        for (i, (s, v)) in scalar.iter().zip(&whole).enumerate() {
            assert_eq!(s.to_bits(), v.to_bits(), "row {i}: scalar {s}, vector {v}");
        }
    }

    /// A map's masks mark, per group of rows, exactly the sources some row of the group reads
    /// with a non-zero coefficient: a whole zero column, a column zero in one group only, an
    /// input read by one row, the groups past the map's rows empty.
    #[test]
    fn source_masks_mark_the_sources_each_group_reads() {
        let rows = ROW_GROUP + 3;
        let a: Vec<[f64; NS]> = (0..rows)
            .map(|i| {
                std::array::from_fn(|j| match j {
                    1 => 0.0,
                    3 if i < ROW_GROUP => 0.0,
                    _ => 1.0 + (i + j) as f64,
                })
            })
            .collect();
        let b: Vec<[f64; NI]> = (0..rows)
            .map(|i| [if i == ROW_GROUP + 1 { 2.0 } else { 0.0 }, -0.0])
            .collect();
        let m = SourceMasks::of(&a, &b);
        for s in 0..NS + NI {
            let want = [s != 1 && s != 3 && s < NS, s != 1 && s < NS || s == NS];
            assert_eq!(m.reads(0, s), want[0], "group 0, source {s}");
            assert_eq!(m.reads(1, s), want[1], "group 1, source {s}");
            for g in 2..MAX_GROUPS {
                assert!(!m.reads(g, s), "group {g}, source {s}");
            }
        }
    }

    /// `rows_map` against the plain sums: 1, 7 (a partial group) and 9 rows of a sparse map
    /// (a state no row of the first group reads, an input one row does not), over column
    /// counts around the vector widths, on the best instruction set and the scalar ones.
    #[test]
    fn rows_map_equals_the_plain_sums() {
        struct Case(usize);
        impl pulp::WithSimd for Case {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: Simd>(self, simd: S) {
                let rows = self.0;
                let a: Vec<[f64; NS]> = (0..rows)
                    .map(|i| {
                        std::array::from_fn(|j| {
                            if j == 1 || (j == 3 && i < ROW_GROUP) {
                                0.0
                            } else {
                                ((i * 7 + j * 3) % 11) as f64 / 5.0 - 1.0
                            }
                        })
                    })
                    .collect();
                let b: Vec<[f64; NI]> = (0..rows)
                    .map(|i| std::array::from_fn(|l| if i == 2 { 0.0 } else { (i + l) as f64 }))
                    .collect();
                let masks = SourceMasks::of(&a, &b);
                for n in [0usize, 1, 3, 4, 7, 8, 9, 17, 61] {
                    let x: Vec<f64> = (0..NS * n)
                        .map(|k| ((k * 7919) % 1013) as f64 / 1013.0 - 0.5)
                        .collect();
                    let u: Vec<Vec<f64>> = (0..NI)
                        .map(|l| (0..n).map(|c| (c + l) as f64 * 0.25).collect())
                        .collect();
                    let mut out = vec![f64::NAN; rows * n + 3];
                    rows_map::<S, NS, NI>(simd, &a, &b, &masks, &x, [&u[0], &u[1]], n, &mut out);
                    for i in 0..rows {
                        for c in 0..n {
                            let want: f64 = (0..NS).map(|j| a[i][j] * x[j * n + c]).sum::<f64>()
                                + (0..NI).map(|l| b[i][l] * u[l][c]).sum::<f64>();
                            let got = out[i * n + c];
                            assert!(
                                (got - want).abs() <= 1e-13 * (1.0 + want.abs()),
                                "{rows} rows, n {n}, ({i}, {c}): {got} vs {want}"
                            );
                        }
                    }
                    assert!(
                        out[rows * n..].iter().all(|v| v.is_nan()),
                        "wrote past the rows"
                    );
                }
            }
        }
        for rows in [1, 7, 9] {
            pulp::Arch::new().dispatch(Case(rows));
            pulp::WithSimd::with_simd(Case(rows), pulp::Scalar);
            pulp::WithSimd::with_simd(Case(rows), pulp::Scalar256b);
        }
    }

    /// The columns after a row's last whole vector are summed as the others, to the bit: each
    /// column of `n` columns (not a whole number of vectors) against the same column of `64`
    /// (whole vectors for every width), for both kernels, the running sum `d` included.
    #[test]
    fn the_last_columns_are_summed_as_the_others() {
        struct Case;
        impl pulp::WithSimd for Case {
            type Output = ();
            #[inline(always)]
            fn with_simd<S: Simd>(self, simd: S) {
                const WIDE: usize = 64;
                let a: [[f64; NS]; NS] = std::array::from_fn(|i| {
                    std::array::from_fn(|j| ((i * 5 + j * 3) % 7) as f64 / 3.0 - 1.0)
                });
                let b: [[f64; NI]; NS] =
                    std::array::from_fn(|i| std::array::from_fn(|l| (i + l) as f64 * 0.3));
                let w: [f64; NS] = std::array::from_fn(|i| 0.7 - i as f64 * 0.2);
                let masks = SourceMasks::of(&a, &b);
                let value = |k: usize| ((k * 7919) % 1013) as f64 / 1013.0 - 0.5;
                // Column c of state j, and of input l, whatever the width.
                let run = |n: usize| {
                    let x: Vec<f64> = (0..NS * n).map(|k| value((k / n) * WIDE + k % n)).collect();
                    let u: Vec<Vec<f64>> = (0..NI)
                        .map(|l| (0..n).map(|c| value(9000 + l * WIDE + c)).collect())
                        .collect();
                    let mut out = vec![0.0; NS * n];
                    let mut d: Vec<f64> = (0..n).map(|c| c as f64 / 7.0).collect();
                    state_map::<S, NS, NI>(
                        simd,
                        &a,
                        &b,
                        &masks,
                        &x,
                        [&u[0], &u[1]],
                        n,
                        &mut out,
                        Some((&w, &mut d)),
                    );
                    let mut rows = vec![0.0; NS * n];
                    rows_map::<S, NS, NI>(simd, &a, &b, &masks, &x, [&u[0], &u[1]], n, &mut rows);
                    (out, d, rows)
                };
                let (wide, wide_d, wide_rows) = run(WIDE);
                for n in [S::F64_LANES + 1, 2 * S::F64_LANES - 1, 61] {
                    let (out, d, rows) = run(n);
                    for c in 0..n {
                        for i in 0..NS {
                            let (got, want) = (out[i * n + c], wide[i * WIDE + c]);
                            assert_eq!(got.to_bits(), want.to_bits(), "state_map n {n} ({i}, {c})");
                            let (got, want) = (rows[i * n + c], wide_rows[i * WIDE + c]);
                            assert_eq!(got.to_bits(), want.to_bits(), "rows_map n {n} ({i}, {c})");
                        }
                        assert_eq!(d[c].to_bits(), wide_d[c].to_bits(), "d, n {n}, column {c}");
                    }
                }
            }
        }
        pulp::Arch::new().dispatch(Case);
        pulp::WithSimd::with_simd(Case, pulp::Scalar256b);
    }

    /// States and inputs of the `state_map` tests.
    const NS: usize = 5;
    const NI: usize = 2;

    fn state_map_case(a: &[[f64; NS]; NS], b: &[[f64; NI]; NS]) {
        let w: [f64; NS] = std::array::from_fn(|i| i as f64 - 1.5);
        for n in [0usize, 1, 3, 4, 7, 8, 9, 17, 61] {
            let x: Vec<f64> = (0..NS * n)
                .map(|k| ((k * 7919) % 1013) as f64 / 1013.0 - 0.5)
                .collect();
            let u0: Vec<f64> = (0..n).map(|c| c as f64 * 0.25).collect();
            let u1: Vec<f64> = (0..n).map(|c| 1.0 - c as f64 * 0.5).collect();
            let mut out = vec![f64::NAN; NS * n];
            let mut d: Vec<f64> = (0..n).map(|c| c as f64).collect();
            struct Op<'a> {
                a: &'a [[f64; NS]; NS],
                b: &'a [[f64; NI]; NS],
                w: &'a [f64; NS],
                x: &'a [f64],
                u: [&'a [f64]; NI],
                n: usize,
                out: &'a mut [f64],
                d: &'a mut [f64],
            }
            impl pulp::WithSimd for Op<'_> {
                type Output = ();
                fn with_simd<S: Simd>(self, simd: S) {
                    state_map::<S, NS, NI>(
                        simd,
                        self.a,
                        self.b,
                        &SourceMasks::of(self.a, self.b),
                        self.x,
                        self.u,
                        self.n,
                        self.out,
                        Some((self.w, self.d)),
                    );
                }
            }
            pulp::Arch::new().dispatch(Op {
                a,
                b,
                w: &w,
                x: &x,
                u: [&u0, &u1],
                n,
                out: &mut out,
                d: &mut d,
            });
            for c in 0..n {
                let mut dsum = c as f64;
                for i in 0..NS {
                    let mut e = 0.0;
                    for j in 0..NS {
                        e += a[i][j] * x[j * n + c];
                    }
                    e += b[i][0] * u0[c] + b[i][1] * u1[c];
                    assert!((out[i * n + c] - e).abs() <= 1e-12, "n {n} c {c} i {i}");
                    dsum += w[i] * e;
                }
                assert!((d[c] - dsum).abs() <= 1e-11, "n {n} c {c}");
            }
        }
    }

    /// A row-major `m x k` matrix with stride `lda > k`: the padding is NaN and must never be
    /// read.
    fn matrix(m: usize, k: usize, lda: usize) -> Vec<f64> {
        (0..lda * m)
            .map(|i| {
                if i % lda < k {
                    ((i * 7919) % 1013) as f64 / 1013.0 - 0.5
                } else {
                    f64::NAN
                }
            })
            .collect()
    }

    struct Check {
        m: usize,
        k: usize,
    }

    impl pulp::WithSimd for Check {
        type Output = ();

        #[inline(always)]
        fn with_simd<S: Simd>(self, simd: S) {
            let (m, k) = (self.m, self.k);
            let lda = k + 3;
            let a = matrix(m, k, lda);
            let vec = |len: usize, l: usize| -> Vec<f64> {
                (0..len).map(|i| ((i + 3 * l) as f64).sin()).collect()
            };
            let close = |got: f64, want: f64| (got - want).abs() < 1e-12 * (1.0 + want.abs());
            // y += A x, with one and two right-hand sides.
            let x: Vec<Vec<f64>> = (0..3).map(|l| vec(k, l)).collect();
            let want: Vec<Vec<f64>> = x
                .iter()
                .map(|xl| {
                    (0..m)
                        .map(|i| (0..k).map(|j| a[i * lda + j] * xl[j]).sum())
                        .collect()
                })
                .collect();
            let mut y1 = vec![-1.0; m];
            rows_dot::<S>(simd, &a, lda, m, k, &x[1], &mut y1);
            for i in 0..m {
                assert!(
                    close(y1[i], want[1][i] - 1.0),
                    "{m}x{k} one right-hand side"
                );
            }
            let xt: Vec<Vec<f64>> = (0..2).map(|l| vec(m, l)).collect();
            // The single-precision kernels (NaN padding too), against the double-precision sums
            // of the rounded values: within 1e-6 of the sum of the terms' magnitudes.
            let a32: Vec<f32> = a.iter().map(|&v| v as f32).collect();
            let a64: Vec<f64> = a32.iter().map(|&v| f64::from(v)).collect();
            let round = |x: &[f64]| -> (Vec<f32>, Vec<f64>) {
                let r: Vec<f32> = x.iter().map(|&v| v as f32).collect();
                let back = r.iter().map(|&v| f64::from(v)).collect();
                (r, back)
            };
            let near = |got: f64, want: f64, mag: f64| (got - want).abs() <= 1e-6 * mag + 1e-30;
            let xs: Vec<(Vec<f32>, Vec<f64>)> = x.iter().map(|v| round(v)).collect();
            let mut single = vec![0.5; m];
            rows_dot_f32::<S>(simd, &a32, lda, m, k, &xs[2].0, &mut single);
            let mut pair: Vec<Vec<f64>> = (0..2).map(|l| vec![-(l as f64); m]).collect();
            let [p0, p1] = &mut pair[..] else {
                unreachable!()
            };
            rows_dot2_f32::<S>(simd, &a32, lda, m, k, [&xs[1].0, &xs[2].0], [p0, p1]);
            for i in 0..m {
                for l in 0..3 {
                    let terms = (0..k).map(|j| a64[i * lda + j] * xs[l].1[j]);
                    let want: f64 = terms.clone().sum();
                    let mag: f64 = terms.map(f64::abs).sum();
                    if l == 2 {
                        assert!(near(single[i], 0.5 + want, mag), "{m}x{k} f32 dot one");
                    }
                    if l > 0 {
                        let got = pair[l - 1][i] + (l - 1) as f64;
                        assert!(near(got, want, mag), "{m}x{k} f32 dot pair l={l}");
                    }
                }
            }
            let xts: Vec<(Vec<f32>, Vec<f64>)> = xt.iter().map(|v| round(v)).collect();
            let mut t: Vec<Vec<f64>> = (0..2).map(|_| vec![f64::NAN; k]).collect();
            let mut acc: Vec<Vec<f32>> = (0..2).map(|_| vec![f32::NAN; k]).collect();
            let [t0, t1] = &mut t[..] else { unreachable!() };
            let [c0, c1] = &mut acc[..] else {
                unreachable!()
            };
            rows_axpy2_f32::<S>(
                simd,
                &a32,
                lda,
                m,
                k,
                [&xts[0].0, &xts[1].0],
                [t0, t1],
                [c0, c1],
            );
            for l in 0..2 {
                for j in 0..k {
                    let terms = (0..m).map(|i| a64[i * lda + j] * xts[l].1[i]);
                    let want: f64 = terms.clone().sum();
                    let mag: f64 = terms.map(f64::abs).sum();
                    assert!(near(t[l][j], want, mag), "{m}x{k} f32 transposed l={l}");
                }
            }
        }
    }

    /// Every kernel against the textbook sums, for sizes around the row blocks (1, 2, 4) and
    /// the vector widths (2 to 8 lanes), on the best instruction set and on the scalar one.
    #[test]
    fn kernels_equal_the_plain_sums() {
        for (m, k) in [
            (1, 1),
            (2, 3),
            (3, 7),
            (4, 8),
            (5, 9),
            (9, 17),
            (64, 33),
            (301, 300),
        ] {
            pulp::Arch::new().dispatch(Check { m, k });
            pulp::WithSimd::with_simd(Check { m, k }, pulp::Scalar);
            pulp::WithSimd::with_simd(Check { m, k }, pulp::Scalar256b);
        }
    }
}
