//! Symmetric matrices stored by their upper block triangle with their entries scaled
//! symmetrically into `[-1, 1]` and kept in fewer bits than single precision (half precision,
//! 24-bit or 8-bit fixed point), and their product with one or two single-precision vectors,
//! summed in single precision as [`sym_dot_rows_f32`](super::symmetric::sym_dot_rows_f32) sums.
//!
//! Why: the coupled mirror's servo tick multiplies by the Gram matrices of its mode shapes and
//! by the symmetric form of its correction `W - I` five times per 1 ms step, and at a thousand
//! retained modes those passes are bound by the memory traffic. Each matrix is stored in the
//! fewest bits its product's accuracy allows:
//! - [`SymPacked24`] (three bytes an entry, within `2^-24 s_i s_j` of the exact one) for the
//!   Gram matrices, whose products are not small corrections
//!   ([`CoupledMirror::set_gram_fixed24`](crate::plant::mirror::CoupledMirror::set_gram_fixed24));
//! - [`SymPackedHalf`] (IEEE 754 binary16, within `2^-11` of each entry) and [`SymPacked8`]
//!   (one byte, within `2^-8 s_i s_j`) for the correction, a small term of the solve (about 4e-7
//!   in norm for the voice coil, 8e-5 for the piezo):
//!   [`CoupledMirror::set_correction_storage`](crate::plant::mirror::CoupledMirror::set_correction_storage)
//!   takes the fewest bits whose rounding bound stays below single precision's.
//!
//! One storage, [`SymScaled`], serves all three: only the entries' [`Encoding`] differs (how a
//! value in `[-1, 1]` is stored and read back into single-precision lanes). The same encodings
//! store general matrices by rows with each column scaled ([`ColumnScaled`]): the mirror's mode
//! shapes in 24-bit fixed point, for its passes between the channels and the modes
//! ([`CoupledMirror::set_shapes_fixed24`](crate::plant::mirror::CoupledMirror::set_shapes_fixed24)).
//!
//! **Scaling.** With `s_i = sqrt(max_j |A_ij|)` (1 for a zero row), `A = S A' S`,
//! `S = diag(s)`, and `|A'_ij| <= |A_ij| / sqrt(|A_ij| |A_ji|) = 1`: the stored entries use
//! the encoding's range without overflow. An encoding reads an entry back as `A'_ij F` (its
//! [`Encoding::FACTOR`]: 1 for half precision, `256 (2^23 - 1)` for 24 bits, 127 for 8), so
//! the storage keeps the scale `c_i = s_i / sqrt(F)` and `A = C A'' C`. The caller scales the
//! vector by `c` before the product and the result by `c` after it ([`SymScaled::scale`]), or
//! folds the scale into its own per-entry factors.
//!
//! **Kernels.** The entries are converted to single precision in registers, sixteen or eight
//! lanes at a time (half precision: `vcvtph2ps`, AVX-512F or F16C; 24 bits: a masked byte
//! permutation with AVX-512 VBMI, a byte shuffle of two overlapping loads with AVX2, each entry
//! into the upper three bytes of its lane; 8 bits: a sign extension), and multiplied as the
//! single-precision kernel does (four rows at a time, each stored entry applied to its row's
//! dot product and, past the diagonal block, to its column's); a portable scalar path serves
//! other processors. The path is chosen once, at construction, by the processor's features.

use std::marker::PhantomData;

use half::f16;

use super::kernels::{LINE_F32, prefetch};
use super::symmetric::{BLOCK, packed_offset, padded_order};

mod column_scaled;
pub use column_scaled::ColumnScaled;

/// The instructions a [`SymScaled`] product runs on (the widest one an encoding runs on here:
/// [`Encoding::detect`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScaledPath {
    /// AVX-512F (for 24 bits also BW and VBMI): sixteen lanes.
    Avx512,
    /// AVX2, FMA and F16C: eight lanes.
    Avx2,
    /// Portable scalar code (one lane, the conversion in software).
    Scalar,
}

impl ScaledPath {
    /// `path` instead of this one where the encoding `E` runs on it here (`true`), else
    /// unchanged (`false`).
    fn set<E: Encoding>(&mut self, path: ScaledPath) -> bool {
        let ok = E::available(path);
        if ok {
            *self = path;
        }
        ok
    }

    /// Whether this processor has the path's base features (AVX-512F; AVX2, FMA and F16C).
    fn base_available(self) -> bool {
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

mod sealed {
    /// Implemented by this module's encodings only.
    pub trait Sealed {}

    /// The vector operations a kernel path needs.
    pub trait Lanes {
        type V: Copy;
        const N: usize;
        unsafe fn zero() -> Self::V;
        unsafe fn splat(v: f32) -> Self::V;
        unsafe fn load(p: *const f32) -> Self::V;
        unsafe fn store(p: *mut f32, v: Self::V);
        unsafe fn load_half(p: *const u16) -> Self::V;
        /// `N` 24-bit entries ([`super::Fixed24`]) from `p`, reading at most
        /// [`super::Fixed24::PAD`] bytes past them.
        unsafe fn load_fixed24(p: *const u8) -> Self::V;
        /// `N` 8-bit entries ([`super::Fixed8`]) from `p`.
        unsafe fn load_fixed8(p: *const u8) -> Self::V;
        unsafe fn fma(a: Self::V, b: Self::V, c: Self::V) -> Self::V;
        unsafe fn sum(v: Self::V) -> f32;
    }
}

use sealed::Lanes;

/// How a [`SymScaled`] matrix stores its scaled entries `A'_ij` (in `[-1, 1]`), and reads them
/// into single-precision lanes as `A'_ij F` ([`Self::FACTOR`], to the encoding's rounding).
pub trait Encoding:
    sealed::Sealed + Clone + Copy + std::fmt::Debug + Send + Sync + 'static
{
    /// The storage unit.
    type Unit: Copy
        + Default
        + std::fmt::Debug
        + Send
        + Sync
        + serde::Serialize
        + serde::de::DeserializeOwned;
    /// Units per entry.
    const UNITS: usize;
    /// Units of padding after the last entry (read, not used, by the vector paths).
    const PAD: usize;
    /// The value an entry `A'_ij = 1` reads as.
    const FACTOR: f64;
    /// The kernels prefetch a row's next stretch every this many entries (a cache line).
    #[doc(hidden)]
    const PREFETCH_EVERY: usize;
    /// Whether the 512-bit path needs AVX-512 BW and VBMI besides AVX-512F.
    #[doc(hidden)]
    const VBMI: bool;
    /// `v` (in `[-1, 1]`) into `out` (`UNITS` long), rounded to nearest.
    fn encode(v: f64, out: &mut [Self::Unit]);
    /// An entry as the kernels read it (`A'_ij F`), from `UNITS` units.
    fn decode(units: &[Self::Unit]) -> f64;
    /// `T::N` entries from `p`, in single precision.
    ///
    /// # Safety
    /// `p` points at `T::N` stored entries, followed by at least [`Self::PAD`] units.
    #[doc(hidden)]
    unsafe fn load<T: Lanes>(p: *const Self::Unit) -> T::V;

    /// Whether a product of this encoding can run on `path` on this processor.
    fn available(path: ScaledPath) -> bool {
        match path {
            #[cfg(target_arch = "x86_64")]
            ScaledPath::Avx512 if Self::VBMI => {
                std::arch::is_x86_feature_detected!("avx512f")
                    && std::arch::is_x86_feature_detected!("avx512bw")
                    && std::arch::is_x86_feature_detected!("avx512vbmi")
            }
            _ => path.base_available(),
        }
    }

    /// The widest path a product of this encoding runs on here.
    fn detect() -> ScaledPath {
        [ScaledPath::Avx512, ScaledPath::Avx2]
            .into_iter()
            .find(|&p| Self::available(p))
            .unwrap_or(ScaledPath::Scalar)
    }

    /// Whether products of this encoding run on vector instructions here.
    fn vectorised() -> bool {
        Self::detect() != ScaledPath::Scalar
    }
}

/// Half precision: one `u16` (IEEE 754 binary16 bits) per entry, `F = 1`: each entry within
/// `2^-11` of itself (or `2^-25` absolute below half precision's normal range, `2^-14`), so
/// that `|A_ij - s_i A'_ij s_j| <= 2^-11 |A_ij| + 2^-25 s_i s_j`.
#[derive(Debug, Clone, Copy)]
pub struct Half;

impl sealed::Sealed for Half {}

impl Encoding for Half {
    type Unit = u16;
    const UNITS: usize = 1;
    const PAD: usize = 0;
    const FACTOR: f64 = 1.0;
    const PREFETCH_EVERY: usize = 2 * LINE_F32;
    const VBMI: bool = false;
    fn encode(v: f64, out: &mut [u16]) {
        out[0] = f16::from_f64(v).to_bits();
    }
    fn decode(units: &[u16]) -> f64 {
        f16::from_bits(units[0]).to_f64()
    }
    #[inline(always)]
    unsafe fn load<T: Lanes>(p: *const u16) -> T::V {
        unsafe { T::load_half(p) }
    }
}

/// The largest stored 24-bit integer: `A'`'s entries in `[-1, 1]` are stored as
/// `round(A'_ij Q)`.
const Q24: f64 = 8_388_607.0;

/// 24-bit fixed point: `q_ij = round(A'_ij Q)` (`Q = 2^23 - 1`) in three bytes, a two's
/// complement integer with its least significant byte first, read as the single-precision
/// value `256 q_ij` (exactly; `F = 256 Q`): `|A_ij - c_i A''_ij c_j| <= s_i s_j / (2 Q)`, about
/// `6e-8 s_i s_j`. Three quarters of single precision's traffic, and for the largest entries of
/// each row and column single precision's rounding. The vector paths read up to 16 bytes past
/// an entry ([`Encoding::PAD`]).
#[derive(Debug, Clone, Copy)]
pub struct Fixed24;

impl sealed::Sealed for Fixed24 {}

impl Encoding for Fixed24 {
    type Unit = u8;
    const UNITS: usize = 3;
    const PAD: usize = 16;
    const FACTOR: f64 = 256.0 * Q24;
    const PREFETCH_EVERY: usize = 16;
    const VBMI: bool = true;
    fn encode(v: f64, out: &mut [u8]) {
        let q = (v * Q24).round().clamp(-Q24, Q24) as i32;
        out.copy_from_slice(&q.to_le_bytes()[..3]);
    }
    fn decode(units: &[u8]) -> f64 {
        f64::from(i32::from_le_bytes([0, units[0], units[1], units[2]]))
    }
    #[inline(always)]
    unsafe fn load<T: Lanes>(p: *const u8) -> T::V {
        unsafe { T::load_fixed24(p) }
    }
}

impl Fixed24 {
    /// Whether this processor decodes 24-bit entries with one byte permutation per vector
    /// (the 512-bit path, with AVX-512 VBMI). The AVX2 path takes two loads, an insert, a byte
    /// shuffle and a conversion per eight entries: on an AMD EPYC (Zen 1, two 128-bit
    /// multiply-add pipes) TMT's Gram product at 1000 modes with two right-hand sides took
    /// 158-180 us in 24 bits against 119-125 us in single precision (BENCHMARKS.md,
    /// twenty-ninth round of issue 18).
    pub fn permuted() -> bool {
        Self::detect() == ScaledPath::Avx512
    }
}

/// The largest stored 8-bit integer.
const Q8: f64 = 127.0;

/// 8-bit fixed point: `q_ij = round(A'_ij 127)` in one byte (two's complement), read as `q_ij`
/// (`F = 127`): `|A_ij - c_i A''_ij c_j| <= s_i s_j / 254`. A quarter of single precision's
/// traffic, for a product that is a small correction whose rounding bound is checked by its
/// user.
#[derive(Debug, Clone, Copy)]
pub struct Fixed8;

impl sealed::Sealed for Fixed8 {}

impl Encoding for Fixed8 {
    type Unit = u8;
    const UNITS: usize = 1;
    const PAD: usize = 0;
    const FACTOR: f64 = Q8;
    const PREFETCH_EVERY: usize = 4 * LINE_F32;
    const VBMI: bool = false;
    fn encode(v: f64, out: &mut [u8]) {
        out[0] = ((v * Q8).round().clamp(-Q8, Q8) as i8).to_le_bytes()[0];
    }
    fn decode(units: &[u8]) -> f64 {
        f64::from(i8::from_le_bytes([units[0]]))
    }
    #[inline(always)]
    unsafe fn load<T: Lanes>(p: *const u8) -> T::V {
        unsafe { T::load_fixed8(p) }
    }
}

/// A symmetric `m x m` matrix `A = C A'' C` with the scaled entries `A''` in the encoding `E`,
/// stored as [`SymPacked32`](super::symmetric::SymPacked32) stores (padded with zeros to
/// `n = m` rounded up to [`BLOCK`], by block rows from each diagonal block on), and the
/// diagonal scale `C` in single precision (the module's documentation).
#[derive(Debug, Clone, serde::Serialize, serde::Deserialize)]
#[serde(bound = "")]
pub struct SymScaled<E: Encoding> {
    m: usize,
    n: usize,
    /// `c_i`, zero past the order.
    scale: Vec<f32>,
    /// `E::UNITS` units per stored entry, then `E::PAD` units of padding.
    data: Vec<E::Unit>,
    #[serde(skip, default = "E::detect")]
    path: ScaledPath,
    #[serde(skip)]
    encoding: PhantomData<E>,
}

/// Scaled entries in half precision ([`Half`]).
pub type SymPackedHalf = SymScaled<Half>;
/// Scaled entries in 24-bit fixed point ([`Fixed24`]).
pub type SymPacked24 = SymScaled<Fixed24>;
/// Scaled entries in 8-bit fixed point ([`Fixed8`]).
pub type SymPacked8 = SymScaled<Fixed8>;

impl<E: Encoding> SymScaled<E> {
    /// The matrix whose entry `(i, j)` is `f(i, j)` (`f` symmetric, which this does not check;
    /// every entry is read, to find the scale), scaled and encoded, or `None` if an entry is not
    /// finite.
    pub fn from_fn(m: usize, f: impl Fn(usize, usize) -> f64) -> Option<Self> {
        let n = padded_order(m);
        let s = symmetric_scale(m, &f)?;
        let u = E::UNITS;
        let mut data = vec![E::Unit::default(); u * packed_offset(n, n) + E::PAD];
        for i in 0..m {
            let start = BLOCK * (i / BLOCK);
            let row = &mut data[u * packed_offset(n, i)..][..u * (n - start)];
            for (j, d) in (start..m).zip(row.chunks_exact_mut(u)) {
                E::encode(f(i, j) / (s[i] * s[j]), d);
            }
        }
        let root = E::FACTOR.sqrt();
        let mut scale: Vec<f32> = s.iter().map(|&x| (x / root) as f32).collect();
        scale.resize(n, 0.0);
        Some(Self {
            m,
            n,
            scale,
            data,
            path: E::detect(),
            encoding: PhantomData,
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

    /// The diagonal scale `c` (the padded order's length, zero past the order): `A = C A'' C`.
    pub fn scale(&self) -> &[f32] {
        &self.scale
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

    /// Entry `(i, j)` of `A` as stored (either triangle).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let (i, j) = if j / BLOCK < i / BLOCK {
            (j, i)
        } else {
            (i, j)
        };
        let at = E::UNITS * (packed_offset(self.n, i) + j - BLOCK * (i / BLOCK));
        let v = E::decode(&self.data[at..at + E::UNITS]);
        f64::from(self.scale[i]) * v * f64::from(self.scale[j])
    }

    /// Block rows `blocks` of the product with the *scaled* matrix `A''`, for `L` (1 or 2)
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
        check_rows(self.m, self.n, &xs, &y, &t, &blocks);
        assert!(self.data.len() == E::UNITS * packed_offset(self.n, self.n) + E::PAD);
        let mut t = t;
        for tl in t.iter_mut() {
            tl[..self.n].fill(0.0);
        }
        let a = Stored::<E> {
            m: self.m,
            n: self.n,
            data: &self.data,
        };
        // SAFETY: the slices' lengths are checked above (the data with its padding for the
        // paths' over-reads); the path was checked to run on this processor with this
        // encoding (detected at construction, or `set_path`), the 512-bit one with VBMI where
        // the encoding needs it.
        unsafe {
            match self.path {
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx512 if E::VBMI => {
                    x86::rows_avx512_vbmi::<E, L>(&a, xs, y, t, blocks);
                }
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx512 => x86::rows_avx512::<E, L>(&a, xs, y, t, blocks),
                #[cfg(target_arch = "x86_64")]
                ScaledPath::Avx2 => x86::rows_avx2::<E, L>(&a, xs, y, t, blocks),
                _ => rows_impl::<Scalar, E, L>(&a, xs, y, t, blocks),
            }
        }
    }
}

/// The symmetric scale of the module's documentation, `s_i = sqrt(max_j |f(i, j)|)` (1 for a
/// zero row), or `None` if an entry is not finite.
pub(crate) fn symmetric_scale(m: usize, f: &impl Fn(usize, usize) -> f64) -> Option<Vec<f64>> {
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
    Some(
        row_max
            .iter()
            .map(|&x| if x > 0.0 { x.sqrt() } else { 1.0 })
            .collect(),
    )
}

/// The checks of `scaled_rows` (order `m`, padded order `n`): panics on a programming error.
fn check_rows<const L: usize>(
    m: usize,
    n: usize,
    xs: &[&[f32]; L],
    y: &[&mut [f64]; L],
    t: &[&mut [f32]; L],
    blocks: &std::ops::Range<usize>,
) {
    assert!(L == 1 || L == 2, "one or two right-hand sides");
    assert!(blocks.start <= blocks.end && blocks.end <= n / BLOCK);
    let rows = (BLOCK * blocks.end)
        .min(m)
        .saturating_sub(BLOCK * blocks.start);
    for l in 0..L {
        assert!(xs[l].len() >= n && t[l].len() >= n && y[l].len() >= rows);
    }
}

/// A scaled symmetric matrix's stored entries as the kernels read them: order `m`, padded
/// order `n`, the entries by block rows ([`packed_offset`]), `E::UNITS` units each.
struct Stored<'a, E: Encoding> {
    m: usize,
    n: usize,
    data: &'a [E::Unit],
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
    unsafe fn load_fixed24(p: *const u8) -> f32 {
        // SAFETY: the caller's: three bytes at `p`.
        let b = unsafe { [*p, *p.add(1), *p.add(2)] };
        i32::from_le_bytes([0, b[0], b[1], b[2]]) as f32
    }
    #[inline(always)]
    unsafe fn load_fixed8(p: *const u8) -> f32 {
        // SAFETY: the caller's: one byte at `p`.
        f32::from(i8::from_le_bytes([unsafe { *p }]))
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

/// The kernel: [`SymScaled::scaled_rows`] on the path `T`.
///
/// # Safety
/// The processor runs `T`'s instructions; the slices have the lengths
/// [`SymScaled::scaled_rows`] checks, `t_l` is zero.
#[inline(always)]
unsafe fn rows_impl<T: Lanes, E: Encoding, const L: usize>(
    a: &Stored<'_, E>,
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
                let rp: [*const E::Unit; R] =
                    std::array::from_fn(|k| data.add((off + k * len) * E::UNITS));
                let mut acc = [[T::zero(); L]; R];
                // The diagonal block, stored whole: dot products only.
                let mut c = 0;
                while c < BLOCK {
                    let v: [T::V; R] =
                        std::array::from_fn(|k| E::load::<T>(rp[k].add(c * E::UNITS)));
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
                let next = data.wrapping_add((off + R * len) * E::UNITS);
                while c < len {
                    // About once per cache line.
                    if c.is_multiple_of(E::PREFETCH_EVERY) {
                        for k in 0..R {
                            prefetch(next.wrapping_add((k * len + c) * E::UNITS));
                        }
                    }
                    let v: [T::V; R] =
                        std::array::from_fn(|k| E::load::<T>(rp[k].add(c * E::UNITS)));
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
    use super::{Encoding, Lanes, Stored, rows_impl};
    use core::arch::x86_64::*;

    /// Byte `4 l + 1 + b` of the result from byte `3 l + b` (lane `l`, `b < 3`), byte `4 l`
    /// zero: a 24-bit entry in the upper three bytes of its lane, `256 q`.
    const SPREAD24: [u8; 64] = {
        let mut t = [0u8; 64];
        let mut l = 0;
        while l < 16 {
            t[4 * l + 1] = (3 * l) as u8;
            t[4 * l + 2] = (3 * l + 1) as u8;
            t[4 * l + 3] = (3 * l + 2) as u8;
            l += 1;
        }
        t
    };

    /// The same within each 128-bit half (four lanes from twelve bytes), `0x80` for a zero.
    const SPREAD24_HALF: [u8; 32] = {
        let mut t = [0x80u8; 32];
        let mut l = 0;
        while l < 8 {
            let b = 3 * (l % 4);
            t[4 * l + 1] = b as u8;
            t[4 * l + 2] = (b + 1) as u8;
            t[4 * l + 3] = (b + 2) as u8;
            l += 1;
        }
        t
    };

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
        /// Needs AVX-512 VBMI (`rows_avx512_vbmi`): 64 bytes read for 48.
        #[inline(always)]
        unsafe fn load_fixed24(p: *const u8) -> __m512 {
            unsafe {
                let raw = _mm512_loadu_si512(p.cast());
                let idx = _mm512_loadu_si512(SPREAD24.as_ptr().cast());
                // Byte 0 of every lane zero (mask 0b1110 per lane).
                let q = _mm512_maskz_permutexvar_epi8(0xEEEE_EEEE_EEEE_EEEE, idx, raw);
                _mm512_cvtepi32_ps(q)
            }
        }
        #[inline(always)]
        unsafe fn load_fixed8(p: *const u8) -> __m512 {
            unsafe { _mm512_cvtepi32_ps(_mm512_cvtepi8_epi32(_mm_loadu_si128(p.cast()))) }
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
        /// Bytes 0-15 and 12-27 read for 0-23.
        #[inline(always)]
        unsafe fn load_fixed24(p: *const u8) -> __m256 {
            unsafe {
                let lo = _mm_loadu_si128(p.cast());
                let hi = _mm_loadu_si128(p.add(12).cast());
                let v = _mm256_set_m128i(hi, lo);
                let ctrl = _mm256_loadu_si256(SPREAD24_HALF.as_ptr().cast());
                _mm256_cvtepi32_ps(_mm256_shuffle_epi8(v, ctrl))
            }
        }
        #[inline(always)]
        unsafe fn load_fixed8(p: *const u8) -> __m256 {
            unsafe { _mm256_cvtepi32_ps(_mm256_cvtepi8_epi32(_mm_loadl_epi64(p.cast()))) }
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
    pub(super) unsafe fn rows_avx512<E: Encoding, const L: usize>(
        a: &Stored<'_, E>,
        xs: [&[f32]; L],
        y: [&mut [f64]; L],
        t: [&mut [f32]; L],
        blocks: std::ops::Range<usize>,
    ) {
        unsafe { rows_impl::<Avx512, E, L>(a, xs, y, t, blocks) }
    }

    /// # Safety
    /// As [`rows_impl`], on a processor with AVX-512F, BW and VBMI (the 24-bit entries'
    /// byte permutation).
    #[target_feature(enable = "avx512f,avx512bw,avx512vbmi")]
    pub(super) unsafe fn rows_avx512_vbmi<E: Encoding, const L: usize>(
        a: &Stored<'_, E>,
        xs: [&[f32]; L],
        y: [&mut [f64]; L],
        t: [&mut [f32]; L],
        blocks: std::ops::Range<usize>,
    ) {
        unsafe { rows_impl::<Avx512, E, L>(a, xs, y, t, blocks) }
    }

    /// # Safety
    /// As [`rows_impl`], on a processor with AVX2, FMA and F16C.
    #[target_feature(enable = "avx2,fma,f16c")]
    pub(super) unsafe fn rows_avx2<E: Encoding, const L: usize>(
        a: &Stored<'_, E>,
        xs: [&[f32]; L],
        y: [&mut [f64]; L],
        t: [&mut [f32]; L],
        blocks: std::ops::Range<usize>,
    ) {
        unsafe { rows_impl::<Avx2, E, L>(a, xs, y, t, blocks) }
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
    /// single-precision summation), and the stored matrix against the exact one (within each
    /// encoding's bound of its documentation).
    #[test]
    fn products_match_the_stored_matrix_on_every_path() {
        // Half precision: each entry within 2^-11 of itself, or 2^-24 of s_i s_j (c = s).
        let half = SymPackedHalf::from_fn(83, entry).expect("finite");
        products_match_on_every_path(&half, |exact, cc| {
            2f64.powi(-11) * exact.abs() + 2f64.powi(-24) * cc
        });
        // 24-bit fixed point: each entry within 2^-24 of s_i s_j (the scale's single-precision
        // rounding adds 2^-23 of the entry); s_i s_j is 256 (2^23 - 1) c_i c_j.
        let fixed = SymPacked24::from_fn(83, entry).expect("finite");
        products_match_on_every_path(&fixed, |exact, cc| {
            2f64.powi(-22) * exact.abs() + 0.5 * 256.0 * cc
        });
        // 8-bit fixed point: each entry within s_i s_j / 254 = c_i c_j / 2.
        let fixed8 = SymPacked8::from_fn(83, entry).expect("finite");
        products_match_on_every_path(&fixed8, |exact, cc| 2f64.powi(-22) * exact.abs() + 0.5 * cc);
    }

    /// The stored matrix against the exact one (within `bound(exact, c_i c_j)`), and every
    /// path's products as the first test's documentation says.
    fn products_match_on_every_path<E: Encoding>(
        a: &SymScaled<E>,
        bound: impl Fn(f64, f64) -> f64,
    ) {
        let m = a.order();
        let n = a.padded_order();
        assert_eq!(n, 96);
        for i in 0..m {
            for j in 0..m {
                let (exact, stored) = (entry(i, j), a.get(i, j));
                let bound = bound(exact, f64::from(a.scale()[i]) * f64::from(a.scale()[j]));
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
        for path in [ScaledPath::Avx512, ScaledPath::Avx2, ScaledPath::Scalar] {
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
        assert!(paths >= 1 && E::available(ScaledPath::Scalar));
        assert!(E::available(E::detect()));
    }

    /// Each encoding's round trip at the ends of its range and at zero, and its rounding to
    /// nearest (so that the bounds of the documentation hold with equality at worst).
    #[test]
    fn encodings_round_trip_their_range() {
        fn trip<E: Encoding>(v: f64) -> f64 {
            let mut u = vec![E::Unit::default(); E::UNITS];
            E::encode(v, &mut u);
            E::decode(&u) / E::FACTOR
        }
        for v in [-1.0, -0.5, 0.0, 0.25, 1.0] {
            assert_eq!(trip::<Half>(v), v);
            assert!((trip::<Fixed24>(v) - v).abs() <= 0.5 / Q24);
            assert!((trip::<Fixed8>(v) - v).abs() <= 0.5 / Q8);
        }
        assert_eq!(trip::<Fixed8>(1.0), 1.0);
        assert_eq!(trip::<Fixed8>(-1.0), -1.0);
        // 0.3 * 127 = 38.1 rounds to 38; -0.3 to -38.
        assert_eq!(trip::<Fixed8>(0.3) * Q8, 38.0);
        assert_eq!(trip::<Fixed8>(-0.3) * Q8, -38.0);
        assert_eq!(trip::<Fixed24>(-1.0), -1.0);
    }

    #[test]
    fn entries_that_are_not_finite_are_refused() {
        assert!(SymPackedHalf::from_fn(20, |i, j| if i == j { f64::NAN } else { 1.0 }).is_none());
        assert!(SymPacked8::from_fn(20, |i, j| if i == j { f64::INFINITY } else { 1.0 }).is_none());
        // A zero matrix keeps a unit scale and zero entries.
        let z = SymPackedHalf::from_fn(20, |_, _| 0.0).expect("finite");
        assert!(z.scale()[..20].iter().all(|&s| s == 1.0) && z.get(3, 7) == 0.0);
    }

    /// The bytes a product streams: the entries by block rows, each encoding's units, and its
    /// padding.
    #[test]
    fn stored_bytes_are_the_encodings_size() {
        let (m, n) = (83, 96);
        let entries = packed_offset(n, n);
        assert_eq!(
            SymPackedHalf::from_fn(m, entry)
                .expect("finite")
                .stored_bytes(),
            2 * entries
        );
        assert_eq!(
            SymPacked24::from_fn(m, entry)
                .expect("finite")
                .stored_bytes(),
            3 * entries + Fixed24::PAD
        );
        assert_eq!(
            SymPacked8::from_fn(m, entry)
                .expect("finite")
                .stored_bytes(),
            entries
        );
    }
}
