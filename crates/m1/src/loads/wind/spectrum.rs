//! The von Karman pressure screen: its discrete spectrum and its synthesis by inverse FFT.

use super::*;

/// The discrete pressure spectrum of a screen (see [`ScreenParams::discrete_psd`]).
#[derive(Debug, Clone, PartialEq)]
pub struct DiscretePsd {
    pub(super) n: usize,
    pub(super) dk: f64,
    /// (outer scale, factor on the unit-variance von Karman spectrum) per component.
    pub(super) weights: Vec<(f64, f64)>,
    /// [`Self::at`] on the grid by `(|signed ix|, |signed iy|)`, row-major with `n / 2 + 1`
    /// columns: the spectrum is even in each wavenumber, so a quarter of the grid holds every
    /// value (each computed exactly as [`Self::at`] computes it).
    pub(super) quadrant: Vec<f64>,
}

impl DiscretePsd {
    /// Variance (Pa^2) carried by the bin `(ix, iy)` of the FFT grid (0 at the mean and Nyquist).
    pub fn bin(&self, ix: usize, iy: usize) -> f64 {
        if bin_wavenumber(ix, iy, self.n, self.dk).is_none() {
            return 0.0;
        }
        let h = self.n / 2 + 1;
        self.quadrant[signed(iy, self.n).unsigned_abs() as usize * h
            + signed(ix, self.n).unsigned_abs() as usize]
    }

    /// Variance density times `dk^2` at wavenumber `(kx, ky)` (cycles/m), as for a grid bin.
    pub fn at(&self, kx: f64, ky: f64) -> f64 {
        let k = kx.hypot(ky);
        self.weights
            .iter()
            .map(|&(l0, w)| w * von_karman_psd(k, 1.0, l0))
            .sum()
    }

    /// Signed wavenumber (cycles/m) of FFT index `i` (`i - N` above `N / 2`).
    pub fn wavenumber(&self, i: usize) -> f64 {
        signed(i, self.n) as f64 * self.dk
    }
}

/// Signed FFT frequency index.
pub(super) fn signed(i: usize, n: usize) -> i64 {
    if i < n / 2 {
        i as i64
    } else {
        i as i64 - n as i64
    }
}

/// Wavenumber of bin `(ix, iy)`, or None at the mean and on the Nyquist row and column.
pub(super) fn bin_wavenumber(ix: usize, iy: usize, n: usize, dk: f64) -> Option<(f64, f64)> {
    if (ix == 0 && iy == 0) || ix == n / 2 || iy == n / 2 {
        return None;
    }
    Some((signed(ix, n) as f64 * dk, signed(iy, n) as f64 * dk))
}

/// The random Fourier coefficients `c_k` of a pressure screen.
#[derive(Debug, Clone)]
pub struct ScreenSpectrum {
    params: ScreenParams,
    /// `c[iy N + ix]`, bin `(kx, ky)` of FFT indices `(ix, iy)`.
    pub(super) coefficients: Vec<Complex64>,
}

impl ScreenSpectrum {
    /// Draws the coefficients (two standard normals per bin, in row-major bin order, from
    /// `StdRng::seed_from_u64(seed)`).
    pub fn new(params: &ScreenParams) -> Result<ScreenSpectrum, M1Error> {
        params.check()?;
        Ok(Self::drawn(params, &params.discrete_psd()))
    }

    /// [`Self::new`] on the screen's discrete spectrum `psd` ([`ScreenParams::discrete_psd`]
    /// of checked `params`), for a caller that needs it too.
    pub(super) fn drawn(params: &ScreenParams, psd: &DiscretePsd) -> ScreenSpectrum {
        Self::scaled(params, psd, Self::normals(params))
    }

    /// The standard normal draws of [`Self::new`], two per bin in row-major bin order, as
    /// `(g1, g2)` per bin: what the coefficients are before the spectrum scales them (so the
    /// draws, which one generator makes in turn, can be made while the spectrum is computed).
    pub(super) fn normals(params: &ScreenParams) -> Vec<Complex64> {
        let n = params.samples;
        let mut rng = StdRng::seed_from_u64(params.seed);
        let mut draws = vec![Complex64::ZERO; n * n];
        for g in &mut draws {
            let g1: f64 = StandardNormal.sample(&mut rng);
            let g2: f64 = StandardNormal.sample(&mut rng);
            *g = Complex64::new(g1, g2);
        }
        draws
    }

    /// The coefficients from the draws of [`Self::normals`]: bin `k`'s scaled by
    /// `sqrt(psd_k / 2)` (rows in parallel).
    pub(super) fn scaled(
        params: &ScreenParams,
        psd: &DiscretePsd,
        mut coefficients: Vec<Complex64>,
    ) -> ScreenSpectrum {
        let n = params.samples;
        coefficients
            .par_chunks_mut(n)
            .enumerate()
            .for_each(|(iy, row)| {
                for (ix, c) in row.iter_mut().enumerate() {
                    let a = (psd.bin(ix, iy) / 2.0).sqrt();
                    *c = Complex64::new(a * c.re, a * c.im);
                }
            });
        ScreenSpectrum {
            params: params.clone(),
            coefficients,
        }
    }

    /// The parameters.
    pub fn params(&self) -> &ScreenParams {
        &self.params
    }

    /// The screen at any point `(x, y)` of its plane (Pa): the trigonometric polynomial
    /// evaluated exactly, in `O(N^2)` (for checks; [`ScreenSpectrum::screen`] gives the grid).
    pub fn value_at(&self, x: f64, y: f64) -> f64 {
        let n = self.params.samples;
        let dk = 1.0 / self.params.size;
        let phase = |i: usize, r: f64| {
            Complex64::cis(TAU * signed(i, n) as f64 * dk * r.rem_euclid(self.params.size))
        };
        let ex: Vec<Complex64> = (0..n).map(|i| phase(i, x)).collect();
        let sum: Complex64 = self
            .coefficients
            .chunks_exact(n)
            .enumerate()
            .map(|(iy, row)| {
                let inner: Complex64 = row.iter().zip(&ex).map(|(c, e)| c * e).sum();
                inner * phase(iy, y)
            })
            .sum();
        SQRT_2 * sum.re
    }

    /// The pressure screen on the grid (Pa), row-major: sample `[iy N + ix]` at
    /// `(ix dx, iy dx)`.
    pub fn screen(&self) -> Vec<f64> {
        let n = self.params.samples;
        let mut buf = self.coefficients.clone();
        inverse_fft_2d(&mut buf, n);
        buf.iter().map(|c| SQRT_2 * c.re).collect()
    }
}

/// In-place unnormalised inverse 2-D FFT (`sum_k c_k exp(+2 pi i k.r)`) of a row-major
/// `n x n` grid.
pub(super) fn inverse_fft_2d(buf: &mut [Complex64], n: usize) {
    let fft: std::sync::Arc<dyn Fft<f64>> = FftPlanner::new().plan_fft_inverse(n);
    let mut scratch = vec![Complex64::ZERO; fft.get_inplace_scratch_len()];
    fft.process_with_scratch(buf, &mut scratch);
    transpose(buf, n);
    fft.process_with_scratch(buf, &mut scratch);
    transpose(buf, n);
}

/// The real parts of the unnormalised inverse 2-D FFTs of two row-major `n x n` spectra `a`
/// and `b`, at the grid rows `rows` only: row `i` of the returned `rows.len() x n` values
/// holds `(Re IFFT a)[rows[i]]` in its real parts and `(Re IFFT b)[rows[i]]` in its imaginary
/// parts. One complex transform serves both: `Re IFFT a = IFFT a_h` with the Hermitian part
/// `a_h(k) = (a(k) + conj a(-k)) / 2`, so `IFFT (a_h + i b_h)` ([`packed`]) carries both.
/// With `b = None` `a` is transformed as it is (its real parts are the ones asked; the
/// imaginary parts are meaningless). (The synthesis packs its spectra as it filters them and
/// calls [`inverse_fft_rows`]; this is the reference the tests hold it to.)
#[cfg(test)]
pub(super) fn real_inverse_fft_rows(
    a: &[Complex64],
    b: Option<&[Complex64]>,
    n: usize,
    rows: &[usize],
) -> Vec<Complex64> {
    match b {
        None => inverse_fft_rows(a, n, rows),
        Some(b) => {
            let neg = |i: usize| (n - i) % n;
            let mut buf = vec![Complex64::ZERO; n * n];
            buf.par_chunks_mut(n).enumerate().for_each(|(iy, row)| {
                let my = neg(iy) * n;
                for (ix, z) in row.iter_mut().enumerate() {
                    let j = my + neg(ix);
                    *z = packed(a[iy * n + ix], a[j], b[iy * n + ix], b[j]);
                }
            });
            inverse_fft_rows(&buf, n, rows)
        }
    }
}

/// The packed spectrum of [`real_inverse_fft_rows`] at one bin `k`, from `a(k)`, `a(-k)`,
/// `b(k)` and `b(-k)`: `a_h(k) + i b_h(k)`.
#[inline]
pub(super) fn packed(a: Complex64, a_neg: Complex64, b: Complex64, b_neg: Complex64) -> Complex64 {
    let ah = (a + a_neg.conj()) * 0.5;
    let bh = (b + b_neg.conj()) * 0.5;
    ah + Complex64::new(-bh.im, bh.re)
}

/// Columns per task of the transform along `y` in [`inverse_fft_rows`]: eight complex values
/// of a grid row are two cache lines.
const COLUMNS_PER_TASK: usize = 8;

/// The unnormalised inverse 2-D FFT of the row-major `n x n` `spectrum` at the grid rows `rows`
/// only (row `i` of the returned `rows.len() x n` values is grid row `rows[i]`). The transform
/// along `y` runs over every column (each gathered into a row of a transposed copy, the
/// columns split between the threads), the one along `x` over the asked rows only, gathered
/// from that copy (a quarter of the grid for TMT's mirror on the default 128 m screen): no
/// serial transpose of the whole grid.
pub(super) fn inverse_fft_rows(spectrum: &[Complex64], n: usize, rows: &[usize]) -> Vec<Complex64> {
    let fft: std::sync::Arc<dyn Fft<f64>> = FftPlanner::new().plan_fft_inverse(n);
    let len = fft.get_inplace_scratch_len();
    // Along y: column c into row c of the transposed copy, transformed there.
    let mut columns = vec![Complex64::ZERO; n * n];
    columns
        .par_chunks_mut(COLUMNS_PER_TASK * n)
        .enumerate()
        .for_each_init(
            || vec![Complex64::ZERO; len],
            |scratch, (task, block)| {
                let c0 = task * COLUMNS_PER_TASK;
                let width = block.len() / n;
                for (iy, row) in spectrum.chunks_exact(n).enumerate() {
                    for (j, &v) in row[c0..c0 + width].iter().enumerate() {
                        block[j * n + iy] = v;
                    }
                }
                for column in block.chunks_exact_mut(n) {
                    fft.process_with_scratch(column, scratch);
                }
            },
        );
    // Along x on the asked rows: row r gathered from every column's element r.
    let mut out = vec![Complex64::ZERO; rows.len() * n];
    out.par_chunks_mut(n).zip(rows.par_iter()).for_each_init(
        || vec![Complex64::ZERO; len],
        |scratch, (row, &r)| {
            for (v, column) in row.iter_mut().zip(columns.chunks_exact(n)) {
                *v = column[r];
            }
            fft.process_with_scratch(row, scratch);
        },
    );
    out
}

/// In-place transpose of a square row-major matrix, by blocks.
pub(super) fn transpose(buf: &mut [Complex64], n: usize) {
    const B: usize = 32;
    for bi in (0..n).step_by(B) {
        for bj in (bi..n).step_by(B) {
            for i in bi..(bi + B).min(n) {
                let j0 = if bi == bj { i + 1 } else { bj };
                for j in j0..(bj + B).min(n) {
                    buf.swap(i * n + j, j * n + i);
                }
            }
        }
    }
}
