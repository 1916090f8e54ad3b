//! The factors of a complex symmetric $K = L D L^T$ repacked for solves with one right-hand
//! side ([`PackedLdlt`]): the Lanczos iterations of the CSI analysis make two such solves per
//! step with the same factors, and their time is the time to stream $L$ from memory.
//!
//! The layout serves that stream:
//!
//! * real and imaginary parts apart (the right-hand side too, for the solve's duration), so the
//!   complex products are plain fused multiply-adds with no shuffles of interleaved pairs;
//! * the columns in blocks of [`FUSED`]: both triangular passes update or read the rows below
//!   a block for its four columns in one pass over the right-hand side;
//! * each block's rows below it in groups of [`GROUP`] rows, within a group column by column
//!   (real parts, then imaginary ones), the blocks back to back: one contiguous stream, the
//!   forward pass reading it in order, the backward pass block by block from the last;
//! * a software prefetch ahead of each pass: [`AHEAD`] values along the stream in the forward
//!   pass, the previous block's same group in the backward one (whose blocks are visited
//!   against the storage order, which the processor's own prefetchers do not follow).
//!
//! At order 1000 one solve (both passes, 8 MB of $L$) took 0.77-0.92 ms against 1.75 ms by columns
//! of the factor in place (BENCHMARKS.md, thirty-second round).

use faer::{MatRef, c64};
use pulp::Simd;

use super::kernels::prefetch;

/// Columns of a block (the passes' fused width).
pub const FUSED: usize = 4;
/// Rows of a group: a whole number of vectors on every processor (1, 2, 4 or 8 lanes).
pub const GROUP: usize = 8;
/// Prefetch distance of the forward pass, in values (8 kB).
pub const AHEAD: usize = 1024;
/// Values of one group: [`GROUP`] rows of [`FUSED`] columns, real and imaginary.
const CHUNK: usize = 2 * FUSED * GROUP;

/// $L$ (unit lower) and $D$ of $K = L D L^T$, packed for solves with one right-hand side
/// (module documentation).
#[derive(Debug, Clone)]
pub struct PackedLdlt {
    n: usize,
    d: Vec<c64>,
    /// Per block, `L[j0 + r, j0 + c]` at `r * FUSED + c` (zero on and above the diagonal).
    tri: Vec<c64>,
    /// Block `b` from `start[b]` to `start[b + 1]`: its rows `j0 + FUSED..` by groups (zeros
    /// past the last row and in the missing columns of a last, narrower block).
    panel: Vec<f64>,
    start: Vec<usize>,
}

impl PackedLdlt {
    /// The factors from `f`: $D$ on its diagonal, $L$ strictly below it (the storage of
    /// [`super::complex_symmetric::ModalFactor`]); only the lower triangle is read.
    ///
    /// # Panics
    /// If `f` is not square (a programming error).
    pub fn new(f: MatRef<'_, c64>) -> Self {
        assert_eq!(f.nrows(), f.ncols(), "PackedLdlt: a square factor");
        let n = f.nrows();
        let nb = n.div_ceil(FUSED);
        let zero = c64::new(0.0, 0.0);
        let mut tri = vec![zero; nb * FUSED * FUSED];
        let groups = |b: usize| n.saturating_sub(b * FUSED + FUSED).div_ceil(GROUP);
        let mut panel = Vec::with_capacity((0..nb).map(|b| groups(b) * CHUNK).sum());
        let mut start = Vec::with_capacity(nb + 1);
        for b in 0..nb {
            let j0 = b * FUSED;
            let jb = FUSED.min(n - j0);
            for c in 0..jb {
                for r in c + 1..jb {
                    tri[b * FUSED * FUSED + r * FUSED + c] = f[(j0 + r, j0 + c)];
                }
            }
            start.push(panel.len());
            for g in 0..groups(b) {
                let i0 = j0 + FUSED + g * GROUP;
                for c in 0..FUSED {
                    let at = |r: usize| {
                        let i = i0 + r;
                        if i < n && c < jb {
                            f[(i, j0 + c)]
                        } else {
                            zero
                        }
                    };
                    panel.extend((0..GROUP).map(|r| at(r).re));
                    panel.extend((0..GROUP).map(|r| at(r).im));
                }
            }
        }
        start.push(panel.len());
        Self {
            n,
            d: (0..n).map(|j| f[(j, j)]).collect(),
            tri,
            panel,
            start,
        }
    }

    /// The order.
    pub fn order(&self) -> usize {
        self.n
    }

    /// `x <- K^-1 x`, or `x <- K^-H x = conj(K^-1 conj(x))` with `adjoint`.
    ///
    /// # Panics
    /// If `x`'s length is not the order (a programming error).
    pub fn solve_in_place(&self, x: &mut [c64], adjoint: bool) {
        assert_eq!(x.len(), self.n, "PackedLdlt: wrong right-hand side length");
        // Every group of every block lies within the split vectors.
        let len = self.n.div_ceil(FUSED) * FUSED + GROUP;
        let sign = if adjoint { -1.0 } else { 1.0 };
        let mut xr = vec![0.0; len];
        let mut xi = vec![0.0; len];
        for (i, v) in x.iter().enumerate() {
            xr[i] = v.re;
            xi[i] = sign * v.im;
        }
        pulp::Arch::new().dispatch(Substitute {
            p: self,
            xr: &mut xr,
            xi: &mut xi,
        });
        for (i, v) in x.iter_mut().enumerate() {
            *v = c64::new(xr[i], sign * xi[i]);
        }
    }
}

/// Both passes of one solve on the split right-hand side `(xr, xi)` (zeros past the order).
struct Substitute<'a> {
    p: &'a PackedLdlt,
    xr: &'a mut [f64],
    xi: &'a mut [f64],
}

impl pulp::WithSimd for Substitute<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Substitute { p, xr, xi } = self;
        let n = p.n;
        let nb = n.div_ceil(FUSED);
        let zero = c64::new(0.0, 0.0);
        let get = |xr: &[f64], xi: &[f64], i: usize| c64::new(xr[i], xi[i]);
        let set = |xr: &mut [f64], xi: &mut [f64], i: usize, v: c64| {
            xr[i] = v.re;
            xi[i] = v.im;
        };
        // L y = b: the block's own triangle, then the rows below it for its columns at once.
        for b in 0..nb {
            let j0 = b * FUSED;
            let jb = FUSED.min(n - j0);
            let t = &p.tri[b * FUSED * FUSED..(b + 1) * FUSED * FUSED];
            for c in 0..jb {
                let s = get(xr, xi, j0 + c);
                for r in c + 1..jb {
                    let v = get(xr, xi, j0 + r) - t[r * FUSED + c] * s;
                    set(xr, xi, j0 + r, v);
                }
            }
            let s: [c64; FUSED] =
                std::array::from_fn(|c| if c < jb { -get(xr, xi, j0 + c) } else { zero });
            let sr = s.map(|v| simd.splat_f64s(v.re));
            let si = s.map(|v| simd.splat_f64s(v.im));
            let nsi = s.map(|v| simd.splat_f64s(-v.im));
            let i0 = j0 + FUSED;
            let panel = &p.panel[p.start[b]..p.start[b + 1]];
            for (g, chunk) in panel.chunks_exact(CHUNK).enumerate() {
                for l in (0..CHUNK).step_by(8) {
                    prefetch(chunk.as_ptr().wrapping_add(AHEAD + l));
                }
                let rows = i0 + g * GROUP..i0 + (g + 1) * GROUP;
                let (yr, _) = S::as_mut_simd_f64s(&mut xr[rows.clone()]);
                let (yi, _) = S::as_mut_simd_f64s(&mut xi[rows]);
                for (v, (ur, ui)) in yr.iter_mut().zip(yi.iter_mut()).enumerate() {
                    let (mut ar, mut ai) = (*ur, *ui);
                    for c in 0..FUSED {
                        let (lr, _) = S::as_simd_f64s(&chunk[2 * c * GROUP..(2 * c + 1) * GROUP]);
                        let (li, _) =
                            S::as_simd_f64s(&chunk[(2 * c + 1) * GROUP..(2 * c + 2) * GROUP]);
                        ar = simd.mul_add_f64s(sr[c], lr[v], ar);
                        ar = simd.mul_add_f64s(nsi[c], li[v], ar);
                        ai = simd.mul_add_f64s(sr[c], li[v], ai);
                        ai = simd.mul_add_f64s(si[c], lr[v], ai);
                    }
                    *ur = ar;
                    *ui = ai;
                }
            }
        }
        for (j, d) in p.d.iter().enumerate() {
            let v = get(xr, xi, j) / d;
            set(xr, xi, j, v);
        }
        // L^T x = z from the last block up: the block's dot products with the rows below it at
        // once, then its own triangle.
        let vzero = simd.splat_f64s(0.0);
        for b in (0..nb).rev() {
            let j0 = b * FUSED;
            let jb = FUSED.min(n - j0);
            let i0 = j0 + FUSED;
            let panel = &p.panel[p.start[b]..p.start[b + 1]];
            let mut accr = [vzero; FUSED];
            let mut acci = [vzero; FUSED];
            for (g, chunk) in panel.chunks_exact(CHUNK).enumerate() {
                if b > 0 {
                    let next = p.start[b - 1] + g * CHUNK;
                    for l in (0..CHUNK).step_by(8) {
                        prefetch(p.panel.as_ptr().wrapping_add(next + l));
                    }
                }
                let rows = i0 + g * GROUP..i0 + (g + 1) * GROUP;
                let (wr, _) = S::as_simd_f64s(&xr[rows.clone()]);
                let (wi, _) = S::as_simd_f64s(&xi[rows]);
                for (v, (&ur, &ui)) in wr.iter().zip(wi).enumerate() {
                    let nui = simd.neg_f64s(ui);
                    for c in 0..FUSED {
                        let (lr, _) = S::as_simd_f64s(&chunk[2 * c * GROUP..(2 * c + 1) * GROUP]);
                        let (li, _) =
                            S::as_simd_f64s(&chunk[(2 * c + 1) * GROUP..(2 * c + 2) * GROUP]);
                        accr[c] = simd.mul_add_f64s(lr[v], ur, accr[c]);
                        accr[c] = simd.mul_add_f64s(li[v], nui, accr[c]);
                        acci[c] = simd.mul_add_f64s(lr[v], ui, acci[c]);
                        acci[c] = simd.mul_add_f64s(li[v], ur, acci[c]);
                    }
                }
            }
            let t = &p.tri[b * FUSED * FUSED..(b + 1) * FUSED * FUSED];
            for c in (0..jb).rev() {
                let dot = c64::new(simd.reduce_sum_f64s(accr[c]), simd.reduce_sum_f64s(acci[c]));
                let mut v = get(xr, xi, j0 + c) - dot;
                for r in c + 1..jb {
                    v -= t[r * FUSED + c] * get(xr, xi, j0 + r);
                }
                set(xr, xi, j0 + c, v);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;
    use faer::linalg::solvers::Solve;

    /// A complex symmetric matrix with a dominant diagonal and its factors by the textbook
    /// unpivoted elimination (independent of the blocked factorisation).
    fn factored(n: usize) -> (Mat<c64>, Mat<c64>) {
        let k = Mat::<c64>::from_fn(n, n, |i, j| {
            let (a, b) = (i.min(j) as f64, i.max(j) as f64);
            let off = c64::new((0.37 * a + 0.11 * b).sin(), (0.21 * a - 0.13 * b).cos()) * 0.3;
            if i == j {
                c64::new(2.0 + 0.5 * n as f64, 0.7 - 0.01 * a) + off
            } else {
                off
            }
        });
        let mut f = k.clone();
        for j in 0..n {
            let d = f[(j, j)];
            for i in j + 1..n {
                f[(i, j)] /= d;
            }
            for c in j + 1..n {
                let s = f[(c, j)] * d;
                for i in c..n {
                    let l = f[(i, j)];
                    f[(i, c)] -= l * s;
                }
            }
        }
        (k, f)
    }

    /// Both solves against faer's LU of the matrix, for orders around the block width and the
    /// group height (empty panels, a narrower last block, partial last groups) and one of many
    /// blocks; the factor's upper triangle is never read (filled with NaN).
    #[test]
    fn solves_equal_the_lu_for_every_ragged_order() {
        for n in (1..=19).chain([64, 203]) {
            let (k, mut f) = factored(n);
            for j in 1..n {
                for i in 0..j {
                    f[(i, j)] = c64::new(f64::NAN, f64::NAN);
                }
            }
            let p = PackedLdlt::new(f.as_ref());
            assert_eq!(p.order(), n);
            let lu = k.partial_piv_lu();
            let b: Vec<c64> = (0..n)
                .map(|i| c64::new((0.3 * i as f64).sin() + 1.0, (0.7 * i as f64).cos()))
                .collect();
            let bm = Mat::from_fn(n, 1, |i, _| b[i]);
            for adjoint in [false, true] {
                let want = if adjoint {
                    k.adjoint().to_owned().partial_piv_lu().solve(&bm)
                } else {
                    lu.solve(&bm)
                };
                let mut x = b.clone();
                p.solve_in_place(&mut x, adjoint);
                for i in 0..n {
                    let err = (x[i] - want[(i, 0)]).norm();
                    assert!(
                        err <= 1e-13 * (1.0 + want[(i, 0)].norm()),
                        "order {n}, adjoint {adjoint}, row {i}: {err:e}"
                    );
                }
            }
        }
    }

    /// A zero-order factor solves the empty system.
    #[test]
    fn empty_order() {
        let p = PackedLdlt::new(Mat::<c64>::zeros(0, 0).as_ref());
        let mut x: Vec<c64> = Vec::new();
        p.solve_in_place(&mut x, false);
        assert!(x.is_empty());
    }
}
