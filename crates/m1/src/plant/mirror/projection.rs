//! The single-precision streaming passes between the channels and the modes, each a SIMD
//! operation for [`pulp::Arch::dispatch`]: the held inputs onto the modes ([`Project`]) and the
//! modal columns back onto the channel rows ([`Reconstruct`]).

use nalgebra::DMatrix;

use crate::linalg::kernels::{cols_dot_f32, rows_axpy2_f32, rows_dot_f32, rows_dot2_f32};
use crate::linalg::symmetric_scaled::{ColumnScaled, Fixed24};

/// The mode shapes by channel rows as the passes read them: in single precision (rows `ld`
/// long, zero-padded), or in 24-bit fixed point with each mode's column scaled
/// ([`super::CoupledMirror::set_shapes_fixed24`]).
#[derive(Clone, Copy)]
pub(super) enum Shapes<'a> {
    Single(&'a [f32]),
    Fixed24(&'a ColumnScaled<Fixed24>),
}

impl<'a> Shapes<'a> {
    /// The 24-bit storage where there is one, else the single-precision one.
    pub(super) fn new(fixed: Option<&'a ColumnScaled<Fixed24>>, single: &'a [f32]) -> Self {
        fixed.map_or(Self::Single(single), Self::Fixed24)
    }
}

/// The two input columns the ticks use (command, wind) of an `r x N_IN` column-major block.
pub(super) fn input_columns(w: &mut [f64], r: usize) -> (&mut [f64], &mut [f64]) {
    let (u, rest) = w.split_at_mut(r);
    (u, &mut rest[r..2 * r])
}

/// `Phi_k^T w_k` (command and wind columns) for both kinds, from the single-precision shapes,
/// over the channel rows `rows` (piston `0..n`, tilt `n..3n`): `out` is (piston command,
/// piston wind, tilt command, tilt wind), each `r` long, set to the sums over those of the
/// kind's rows that `rows` holds (left as they are for a kind it holds none of, or whose
/// inputs are unchanged: `kinds`); `w[kind]` is the kind's command column then its wind column.
/// Two ranges of rows give two parts of a kind's sums, which two threads may compute at once.
pub(super) struct Project<'a> {
    pub(super) phic: Shapes<'a>,
    /// Row stride of `phic` (its rows zero-padded to whole vectors).
    pub(super) ld: usize,
    pub(super) n: usize,
    /// The channel rows to project.
    pub(super) rows: std::ops::Range<usize>,
    /// The kinds to project (the others keep their outputs).
    pub(super) kinds: [bool; 2],
    pub(super) w: [&'a [f32]; 2],
    pub(super) acc: [&'a mut [f32]; 2],
    pub(super) out: [&'a mut [f64]; 4],
}

impl pulp::WithSimd for Project<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (ld, n) = (self.ld, self.n);
        let [pu, pf, tu, tf] = self.out;
        let [a0, a1] = self.acc;
        for (kind, kinds, yu, yf) in [(0usize, 0..n, pu, pf), (1, n..3 * n, tu, tf)] {
            let (lo, hi) = (
                self.rows.start.max(kinds.start),
                self.rows.end.min(kinds.end),
            );
            if !self.kinds[kind] || lo >= hi {
                continue;
            }
            let x = self.w[kind];
            let (i0, i1, count) = (lo - kinds.start, hi - kinds.start, kinds.len());
            let x = [&x[i0..i1], &x[count + i0..count + i1]];
            match self.phic {
                Shapes::Single(a) => rows_axpy2_f32::<S>(
                    simd,
                    &a[lo * ld..],
                    ld,
                    hi - lo,
                    ld,
                    x,
                    [yu, yf],
                    [&mut *a0, &mut *a1],
                ),
                Shapes::Fixed24(a) => a.tdot2(lo..hi, x, [yu, yf], [&mut *a0, &mut *a1]),
            }
        }
    }
}

/// Rows `rows` of `Phi_c [cols_k]` for `C` (1 or 2) columns per kind (channel rows: piston
/// `0..n`, tilt `n..3n`; `cols` holds the `C` columns of each kind in turn, each `ld` long and
/// zero past `r`): `out` is the `C` output columns over `rows`.
pub(super) struct Reconstruct<'a, const C: usize> {
    pub(super) phic: Shapes<'a>,
    /// Row stride of `phic` (its rows zero-padded to whole vectors), and length of each
    /// column of `cols`.
    pub(super) ld: usize,
    pub(super) n: usize,
    pub(super) rows: std::ops::Range<usize>,
    pub(super) cols: &'a [f32],
    pub(super) out: [&'a mut [f64]; C],
}

impl<const C: usize> pulp::WithSimd for Reconstruct<'_, C> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (ld, n) = (self.ld, self.n);
        let mut out = self.out;
        for (kind, kinds) in [(0usize, 0..n), (1, n..3 * n)] {
            let lo = self.rows.start.max(kinds.start);
            let hi = self.rows.end.min(kinds.end);
            if lo >= hi {
                continue;
            }
            let cols = &self.cols[C * ld * kind..C * ld * (kind + 1)];
            let at = lo - self.rows.start..hi - self.rows.start;
            for o in out.iter_mut() {
                o[at.clone()].fill(0.0);
            }
            let a = match self.phic {
                Shapes::Single(a) => &a[lo * ld..],
                Shapes::Fixed24(a) => {
                    let x: [&[f32]; C] = std::array::from_fn(|c| &cols[c * ld..(c + 1) * ld]);
                    a.dot::<C>(lo..hi, x, out.each_mut().map(|o| &mut o[at.clone()]));
                    continue;
                }
            };
            match &mut out[..] {
                [o0] => rows_dot_f32::<S>(simd, a, ld, hi - lo, ld, cols, &mut o0[at]),
                [o0, o1] => rows_dot2_f32::<S>(
                    simd,
                    a,
                    ld,
                    hi - lo,
                    ld,
                    [&cols[..ld], &cols[ld..]],
                    [&mut o0[at.clone()], &mut o1[at]],
                ),
                _ => unreachable!("Reconstruct: 1 or 2 columns per kind"),
            }
        }
    }
}

/// Rows `rows` of `Phi_c [cols_k]`, one column per kind, from the shapes stored by columns
/// (`phit`, `r x ldt`: row `j` mode `j` at every channel row): [`Reconstruct`]`::<1>` by
/// [`cols_dot_f32`], each output summed over the modes in order whatever `rows` is.
pub(super) struct ReconstructCols<'a> {
    pub(super) phit: &'a [f32],
    pub(super) ldt: usize,
    pub(super) r: usize,
    pub(super) n: usize,
    pub(super) rows: std::ops::Range<usize>,
    /// The column of each kind in turn, `ld` long.
    pub(super) cols: &'a [f32],
    pub(super) ld: usize,
    pub(super) out: &'a mut [f64],
}

impl pulp::WithSimd for ReconstructCols<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (ld, n) = (self.ld, self.n);
        for (kind, kinds) in [(0usize, 0..n), (1, n..3 * n)] {
            let lo = self.rows.start.max(kinds.start);
            let hi = self.rows.end.min(kinds.end);
            if lo >= hi {
                continue;
            }
            let at = lo - self.rows.start..hi - self.rows.start;
            cols_dot_f32::<S>(
                simd,
                self.phit,
                self.ldt,
                self.r,
                lo..hi,
                &self.cols[ld * kind..ld * kind + self.r],
                &mut self.out[at],
            );
        }
    }
}

/// The entries of `m` row by row.
pub(super) fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    m.transpose().as_slice().to_vec()
}

/// The entries of `m` row by row in single precision, each row zero-padded to `ld` entries.
pub(super) fn padded_rows_f32(m: &DMatrix<f64>, ld: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; m.nrows() * ld];
    for (i, row) in out.chunks_exact_mut(ld).enumerate() {
        for (j, v) in row.iter_mut().take(m.ncols()).enumerate() {
            *v = m[(i, j)] as f32;
        }
    }
    out
}
