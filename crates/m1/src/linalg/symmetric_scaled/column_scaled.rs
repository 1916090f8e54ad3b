//! General matrices stored by rows with each column scaled into `[-1, 1]` and their entries in
//! one of the module's [`Encoding`]s, and their products with single-precision vectors.

use std::ops::Range;

use super::{Encoding, Lanes, Scalar, ScaledPath};
use crate::linalg::kernels::{padded_len, prefetch};

/// An `m x k` matrix `A = A' S` by rows, `S = diag(s)` with `s_j = max_i |A_ij|` (1 for a zero
/// column), so that `A'`'s entries are in `[-1, 1]`, stored in the encoding `E` (each row padded
/// with zeros to [`padded_len`]`(k)` entries). The encoding reads an entry back as
/// `A'_ij F` ([`Encoding::FACTOR`]), so the storage keeps `c_j = s_j / F` per column, applied
/// to the right-hand sides of [`Self::dot`] and to the results of [`Self::tdot2`] by the
/// kernels. Each entry is within the encoding's rounding of its column's largest: for the
/// 24-bit [`Fixed24`](super::Fixed24), `|A_ij - A'_ij s_j| <= s_j / (2 (2^23 - 1))`, about
/// `6e-8 s_j`.
///
/// Why the columns: in the coupled mirror's mode shapes (rows the actuators' channels, columns
/// the modes) a row's largest entry may belong to a mode of small response, so a scale by rows
/// would round the modes that carry the response more coarsely (TMT at 500 modes, a static
/// load: the response 6.4e-7 from double precision scaled by rows, against 1.6e-7 in single
/// precision).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(bound = "")]
pub struct ColumnScaled<E: Encoding> {
    m: usize,
    k: usize,
    ld: usize,
    /// `c_j = s_j / F` per column, zero past the columns (`ld` long).
    scale: Vec<f32>,
    /// `E::UNITS` units per entry, `ld` entries per row, then `E::PAD` units of padding.
    data: Vec<E::Unit>,
    #[serde(skip, default = "E::detect")]
    path: ScaledPath,
}

impl<E: Encoding> ColumnScaled<E> {
    /// The `m x k` matrix whose entry `(i, j)` is `f(i, j)`, scaled by columns and encoded, or
    /// `None` if an entry is not finite.
    pub fn from_fn(m: usize, k: usize, f: impl Fn(usize, usize) -> f64) -> Option<Self> {
        let (ld, u) = (padded_len(k), E::UNITS);
        let mut s = vec![0.0f64; k];
        for i in 0..m {
            for (j, sj) in s.iter_mut().enumerate() {
                let v = f(i, j);
                if !v.is_finite() {
                    return None;
                }
                *sj = sj.max(v.abs());
            }
        }
        for sj in s.iter_mut() {
            if *sj == 0.0 {
                *sj = 1.0;
            }
        }
        let mut data = vec![E::Unit::default(); u * m * ld + E::PAD];
        for i in 0..m {
            let row = &mut data[u * i * ld..][..u * k];
            for ((j, d), sj) in row.chunks_exact_mut(u).enumerate().zip(&s) {
                E::encode(f(i, j) / sj, d);
            }
        }
        let mut scale: Vec<f32> = s.iter().map(|&x| (x / E::FACTOR) as f32).collect();
        scale.resize(ld, 0.0);
        Some(Self {
            m,
            k,
            ld,
            scale,
            data,
            path: E::detect(),
        })
    }

    /// Rows.
    pub fn rows(&self) -> usize {
        self.m
    }

    /// Columns.
    pub fn cols(&self) -> usize {
        self.k
    }

    /// The padded row length: the length the right-hand sides of [`Self::dot`] need (zero
    /// past [`Self::cols`]).
    pub fn padded_cols(&self) -> usize {
        self.ld
    }

    /// The bytes a product streams: the stored entries with their padding.
    pub fn stored_bytes(&self) -> usize {
        std::mem::size_of_val(self.data.as_slice())
    }

    /// The path the products run on.
    pub fn path(&self) -> ScaledPath {
        self.path
    }

    /// Runs the products on `path` instead of the detected one (for tests and comparisons):
    /// `false`, and nothing changed, if this processor cannot run it.
    pub fn set_path(&mut self, path: ScaledPath) -> bool {
        self.path.set::<E>(path)
    }

    /// Entry `(i, j)` as stored.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let at = E::UNITS * (i * self.ld + j);
        E::decode(&self.data[at..at + E::UNITS]) * f64::from(self.scale[j])
    }

    /// `y_l[i - rows.start] += (A x_l)_i` for the rows `rows` and `L` (1 or 2) right-hand
    /// sides `x_l` ([`Self::padded_cols`] long, zero past the columns): the right-hand sides
    /// scaled by the columns' scale as they are read, each row's products summed in single
    /// precision by lane, then across the lanes, and added in double precision (as
    /// [`rows_dot_f32`](crate::linalg::kernels::rows_dot_f32) sums).
    /// Calls on disjoint rows may run at once.
    ///
    /// # Panics
    /// If a slice is shorter than that, the rows run past the matrix's, or `L` is not 1 or 2
    /// (programming errors).
    pub fn dot<const L: usize>(&self, rows: Range<usize>, x: [&[f32]; L], y: [&mut [f64]; L]) {
        assert!(L == 1 || L == 2, "one or two right-hand sides");
        assert!(rows.start <= rows.end && rows.end <= self.m);
        for l in 0..L {
            assert!(x[l].len() >= self.ld && y[l].len() >= rows.len());
        }
        assert!(self.data.len() == E::UNITS * self.m * self.ld + E::PAD);
        let a = Stored::<E> {
            ld: self.ld,
            scale: &self.scale,
            data: &self.data,
        };
        // SAFETY: the slices' lengths are checked above (the data with its padding for the
        // paths' over-reads); the path was checked to run on this processor with this
        // encoding (detected at construction, or `set_path`).
        unsafe {
            match self.path {
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx512 if E::VBMI => x86::dot_avx512_vbmi::<E, L>(&a, rows, x, y),
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx512 => x86::dot_avx512::<E, L>(&a, rows, x, y),
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx2 => x86::dot_avx2::<E, L>(&a, rows, x, y),
                _ => dot_impl::<Scalar, E, L>(&a, rows, x, y),
            }
        }
    }

    /// `y_l = sum_i x_l[i - rows.start] A_i` over the rows `rows` for two right-hand sides
    /// (`x_l` as long as `rows`): the transposed product, summed as
    /// [`rows_axpy2_f32`](crate::linalg::kernels::rows_axpy2_f32) sums (the rows combined four
    /// at a time into the single-precision `acc_l`, [`Self::padded_cols`] long, scratch, which
    /// is added, scaled by the columns' scale, into the double-precision `y_l` every 64 rows).
    /// `y_l` may be shorter than the
    /// padded columns: the sums past its length are dropped. Calls with their own `y_l` and
    /// `acc_l` may run at once.
    ///
    /// # Panics
    /// If a slice is shorter than that or the rows run past the matrix's (programming errors).
    pub fn tdot2(
        &self,
        rows: Range<usize>,
        x: [&[f32]; 2],
        y: [&mut [f64]; 2],
        acc: [&mut [f32]; 2],
    ) {
        assert!(rows.start <= rows.end && rows.end <= self.m);
        for l in 0..2 {
            assert!(x[l].len() >= rows.len() && acc[l].len() >= self.ld);
        }
        assert!(self.data.len() == E::UNITS * self.m * self.ld + E::PAD);
        let [y0, y1] = y;
        let [a0, a1] = acc;
        y0.fill(0.0);
        y1.fill(0.0);
        a0[..self.ld].fill(0.0);
        a1[..self.ld].fill(0.0);
        if rows.is_empty() {
            return;
        }
        let a = Stored::<E> {
            ld: self.ld,
            scale: &self.scale,
            data: &self.data,
        };
        let (y, acc) = ([y0, y1], [a0, a1]);
        // SAFETY: as in `dot`.
        unsafe {
            match self.path {
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx512 if E::VBMI => x86::tdot_avx512_vbmi::<E>(&a, rows, x, y, acc),
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx512 => x86::tdot_avx512::<E>(&a, rows, x, y, acc),
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx2 => x86::tdot_avx2::<E>(&a, rows, x, y, acc),
                _ => tdot_impl::<Scalar, E>(&a, rows, x, y, acc),
            }
        }
    }
}

/// A [`ColumnScaled`] matrix's entries as the kernels read them, with its columns' scale.
struct Stored<'a, E: Encoding> {
    ld: usize,
    scale: &'a [f32],
    data: &'a [E::Unit],
}

/// The kernel: [`ColumnScaled::dot`] on the path `T`.
///
/// # Safety
/// The processor runs `T`'s instructions; the slices have the lengths [`ColumnScaled::dot`]
/// checks.
#[inline(always)]
unsafe fn dot_impl<T: Lanes, E: Encoding, const L: usize>(
    a: &Stored<'_, E>,
    rows: Range<usize>,
    x: [&[f32]; L],
    y: [&mut [f64]; L],
) {
    // Four rows at a time: four (eight) independent chains of multiply-adds.
    const R: usize = 4;
    let ld = a.ld;
    let xp: [*const f32; L] = std::array::from_fn(|l| x[l].as_ptr());
    let sp = a.scale.as_ptr();
    let data = a.data.as_ptr();
    let row = |i: usize| data.wrapping_add(E::UNITS * i * ld);
    let mut i = rows.start;
    // SAFETY (every access below): row `i < m` is stored at `UNITS i ld .. UNITS (i + 1) ld`
    // within `data` (followed by `E::PAD` units at the end), `x_l` and the scale are `ld` long,
    // `y_l` covers the rows.
    unsafe {
        while i < rows.end {
            let g = (rows.end - i).min(R);
            let rp: [*const E::Unit; R] = std::array::from_fn(|k| row(i + k.min(g - 1)));
            let mut acc = [[T::zero(); L]; R];
            // The next group of rows, a group ahead.
            let next = row(i + R);
            let mut c = 0;
            while c < ld {
                if c.is_multiple_of(E::PREFETCH_EVERY) {
                    for k in 0..R {
                        prefetch(next.wrapping_add(E::UNITS * (k * ld + c)));
                    }
                }
                let v: [T::V; R] = std::array::from_fn(|k| E::load::<T>(rp[k].add(E::UNITS * c)));
                let sv = T::load(sp.add(c));
                for l in 0..L {
                    let xv = T::fma(T::load(xp[l].add(c)), sv, T::zero());
                    for k in 0..R {
                        acc[k][l] = T::fma(v[k], xv, acc[k][l]);
                    }
                }
                c += T::N;
            }
            for (k, acck) in acc.iter().enumerate().take(g) {
                for l in 0..L {
                    y[l][i + k - rows.start] += f64::from(T::sum(acck[l]));
                }
            }
            i += g;
        }
    }
}

/// Rows the transposed kernel sums in single precision before adding them in double.
const FLUSH: usize = 64;

/// The kernel: [`ColumnScaled::tdot2`] on the path `T`.
///
/// # Safety
/// The processor runs `T`'s instructions; the slices have the lengths [`ColumnScaled::tdot2`]
/// checks, the rows are not empty and `acc_l` is zero.
#[inline(always)]
unsafe fn tdot_impl<T: Lanes, E: Encoding>(
    a: &Stored<'_, E>,
    rows: Range<usize>,
    x: [&[f32]; 2],
    y: [&mut [f64]; 2],
    acc: [&mut [f32]; 2],
) {
    // Four rows at a time (the last group repeats the last row with a zero weight).
    const R: usize = 4;
    let ld = a.ld;
    let data = a.data.as_ptr();
    let row = |i: usize| data.wrapping_add(E::UNITS * i * ld);
    let [y0, y1] = y;
    let [a0, a1] = acc;
    let (mut i, mut since) = (rows.start, 0);
    while i < rows.end {
        let rp: [*const E::Unit; R] = std::array::from_fn(|k| row((i + k).min(rows.end - 1)));
        let weight = |l: usize, k: usize| -> f32 {
            if i + k < rows.end {
                x[l][i + k - rows.start]
            } else {
                0.0
            }
        };
        let next = row(i + R);
        let ap = [a0.as_mut_ptr(), a1.as_mut_ptr()];
        // SAFETY: rows below `m` are stored at `UNITS i ld .. UNITS (i + 1) ld` within `data`
        // (followed by `E::PAD` units at the end); `acc_l` is `ld` long.
        unsafe {
            let w: [[T::V; R]; 2] =
                std::array::from_fn(|l| std::array::from_fn(|k| T::splat(weight(l, k))));
            let mut c = 0;
            while c < ld {
                if c.is_multiple_of(E::PREFETCH_EVERY) {
                    for k in 0..R {
                        prefetch(next.wrapping_add(E::UNITS * (k * ld + c)));
                    }
                }
                let (mut u, mut v) = (T::load(ap[0].add(c)), T::load(ap[1].add(c)));
                for k in 0..R {
                    let e = E::load::<T>(rp[k].add(E::UNITS * c));
                    u = T::fma(e, w[0][k], u);
                    v = T::fma(e, w[1][k], v);
                }
                T::store(ap[0].add(c), u);
                T::store(ap[1].add(c), v);
                c += T::N;
            }
        }
        i += R;
        since += R;
        if since >= FLUSH || i >= rows.end {
            for (yl, al) in [(&mut *y0, &mut *a0), (&mut *y1, &mut *a1)] {
                for ((yv, av), s) in yl.iter_mut().zip(al.iter_mut()).zip(a.scale) {
                    *yv += f64::from(*av) * f64::from(*s);
                    *av = 0.0;
                }
            }
            since = 0;
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use super::super::x86::{Avx2, Avx512};
    use super::{Encoding, Range, Stored, dot_impl, tdot_impl};

    /// # Safety
    /// As [`dot_impl`], on a processor with AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn dot_avx512<E: Encoding, const L: usize>(
        a: &Stored<'_, E>,
        rows: Range<usize>,
        x: [&[f32]; L],
        y: [&mut [f64]; L],
    ) {
        unsafe { dot_impl::<Avx512, E, L>(a, rows, x, y) }
    }

    /// # Safety
    /// As [`dot_impl`], on a processor with AVX-512F, BW and VBMI.
    #[target_feature(enable = "avx512f,avx512bw,avx512vbmi")]
    pub(super) unsafe fn dot_avx512_vbmi<E: Encoding, const L: usize>(
        a: &Stored<'_, E>,
        rows: Range<usize>,
        x: [&[f32]; L],
        y: [&mut [f64]; L],
    ) {
        unsafe { dot_impl::<Avx512, E, L>(a, rows, x, y) }
    }

    /// # Safety
    /// As [`dot_impl`], on a processor with AVX2, FMA and F16C.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub(super) unsafe fn dot_avx2<E: Encoding, const L: usize>(
        a: &Stored<'_, E>,
        rows: Range<usize>,
        x: [&[f32]; L],
        y: [&mut [f64]; L],
    ) {
        unsafe { dot_impl::<Avx2, E, L>(a, rows, x, y) }
    }

    /// # Safety
    /// As [`tdot_impl`], on a processor with AVX-512F.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn tdot_avx512<E: Encoding>(
        a: &Stored<'_, E>,
        rows: Range<usize>,
        x: [&[f32]; 2],
        y: [&mut [f64]; 2],
        acc: [&mut [f32]; 2],
    ) {
        unsafe { tdot_impl::<Avx512, E>(a, rows, x, y, acc) }
    }

    /// # Safety
    /// As [`tdot_impl`], on a processor with AVX-512F, BW and VBMI.
    #[target_feature(enable = "avx512f,avx512bw,avx512vbmi")]
    pub(super) unsafe fn tdot_avx512_vbmi<E: Encoding>(
        a: &Stored<'_, E>,
        rows: Range<usize>,
        x: [&[f32]; 2],
        y: [&mut [f64]; 2],
        acc: [&mut [f32]; 2],
    ) {
        unsafe { tdot_impl::<Avx512, E>(a, rows, x, y, acc) }
    }

    /// # Safety
    /// As [`tdot_impl`], on a processor with AVX2, FMA and F16C.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub(super) unsafe fn tdot_avx2<E: Encoding>(
        a: &Stored<'_, E>,
        rows: Range<usize>,
        x: [&[f32]; 2],
        y: [&mut [f64]; 2],
        acc: [&mut [f32]; 2],
    ) {
        unsafe { tdot_impl::<Avx2, E>(a, rows, x, y, acc) }
    }
}

#[cfg(test)]
mod tests {
    use super::super::{Fixed8, Fixed24, Half};
    use super::*;

    /// Columns whose magnitudes span six decades (so that the scale matters), with a zero
    /// column.
    fn entry(i: usize, j: usize) -> f64 {
        if j == 5 {
            return 0.0;
        }
        10f64.powi(-((j % 7) as i32)) * ((0.37 * i as f64 + 0.11 * j as f64).sin() + 0.05)
    }

    /// Each encoding's stored matrix against the exact one (within its rounding of the
    /// column's largest entry), and every path's products, whole and in parts of rows, against
    /// the double-precision products with the matrix as stored (within single-precision sums).
    #[test]
    fn products_match_the_stored_matrix_on_every_path() {
        // Half precision: within 2^-11 of the entry (2^-25 of the column's largest below the
        // normal range); 24 bits: 2^-24 of the column's largest; 8 bits: 1 / 254 of it (and the
        // scale's single-precision rounding, 2^-24 of the entry).
        let f32_scale = |e: f64| 2f64.powi(-23) * e.abs();
        check::<Half>(|e, s| 2f64.powi(-11) * e.abs() + 2f64.powi(-25) * s + f32_scale(e));
        check::<Fixed24>(|e, s| 0.5 / 8_388_607.0 * s + f32_scale(e));
        check::<Fixed8>(|e, s| 0.5 / 127.0 * s + f32_scale(e));
    }

    fn check<E: Encoding>(bound: impl Fn(f64, f64) -> f64) {
        let (m, k) = (23, 37);
        let a = ColumnScaled::<E>::from_fn(m, k, entry).expect("finite");
        assert_eq!((a.rows(), a.cols(), a.padded_cols()), (m, k, 48));
        for j in 0..k {
            let s = (0..m).map(|i| entry(i, j).abs()).fold(0.0, f64::max);
            for i in 0..m {
                let (exact, stored) = (entry(i, j), a.get(i, j));
                assert!((exact - stored).abs() <= bound(exact, s), "({i}, {j})");
            }
        }
        let x: [Vec<f32>; 2] = std::array::from_fn(|l| {
            (0..48)
                .map(|j| {
                    if j < k {
                        ((j * (l + 2)) as f32 * 0.7).cos()
                    } else {
                        0.0
                    }
                })
                .collect()
        });
        let w: [Vec<f32>; 2] =
            std::array::from_fn(|l| (0..m).map(|i| ((i + l) as f32 * 0.3).sin()).collect());
        let mut paths = 0;
        for path in [ScaledPath::Avx512, ScaledPath::Avx2, ScaledPath::Scalar] {
            let mut a = a.clone();
            if !a.set_path(path) {
                continue;
            }
            paths += 1;
            // Rows by parts (a part shorter than four rows, one not a multiple of four).
            for l in 0..2 {
                let mut y = [vec![0.5; m], vec![0.0; m]];
                let [y0, y1] = &mut y;
                for rows in [0..2, 2..9, 9..m] {
                    let at = rows.clone();
                    a.dot::<2>(rows, [&x[l], &x[1 - l]], [&mut y0[at.clone()], &mut y1[at]]);
                }
                let mut one = vec![0.0; m];
                a.dot::<1>(0..m, [&x[l]], [&mut one]);
                for i in 0..m {
                    let terms: Vec<f64> =
                        (0..k).map(|j| a.get(i, j) * f64::from(x[l][j])).collect();
                    let (sum, mag) = (
                        terms.iter().sum::<f64>(),
                        terms.iter().map(|t| t.abs()).sum::<f64>(),
                    );
                    let tol = 1e-6 * mag + 1e-300;
                    assert!((y[0][i] - 0.5 - sum).abs() <= tol, "{path:?} row {i}");
                    assert!((one[i] - sum).abs() <= tol, "{path:?} row {i}");
                }
            }
            // The transposed product over two parts of rows, and its output cut short.
            for rows in [0..m, 3..17] {
                let (mut y0, mut y1) = (vec![f64::NAN; k], vec![f64::NAN; k - 5]);
                let (mut a0, mut a1) = (vec![f32::NAN; 48], vec![f32::NAN; 48]);
                let at = rows.clone();
                a.tdot2(
                    rows,
                    [&w[0][at.clone()], &w[1][at.clone()]],
                    [&mut y0, &mut y1],
                    [&mut a0, &mut a1],
                );
                for (l, y) in [&y0, &y1].into_iter().enumerate() {
                    for (j, yj) in y.iter().enumerate() {
                        let terms: Vec<f64> = at
                            .clone()
                            .map(|i| a.get(i, j) * f64::from(w[l][i]))
                            .collect();
                        let sum = terms.iter().sum::<f64>();
                        let mag = terms.iter().map(|t| t.abs()).sum::<f64>();
                        assert!((yj - sum).abs() <= 1e-6 * mag + 1e-300, "{path:?} {l} {j}");
                    }
                }
            }
        }
        assert!(paths >= 1 && E::available(E::detect()));
    }

    #[test]
    fn entries_that_are_not_finite_are_refused_and_bytes_counted() {
        assert!(
            ColumnScaled::<Fixed24>::from_fn(4, 5, |i, j| if i == j { f64::NAN } else { 1.0 })
                .is_none()
        );
        let a = ColumnScaled::<Fixed24>::from_fn(7, 20, entry).expect("finite");
        assert_eq!(a.stored_bytes(), 3 * 7 * 32 + Fixed24::PAD);
        assert_eq!(a.get(3, 5), 0.0);
    }
}
