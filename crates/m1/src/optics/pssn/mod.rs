//! The normalised point-source sensitivity (PSSN, Seo et al.) of a segmented mirror seen through
//! atmospheric seeing.
//!
//! # Definition
//!
//! $$\mathrm{PSSN} = \frac{\int |\mathrm{OTF}_{atm}\,\mathrm{OTF}_{tel+err}|^2\,df}
//! {\int |\mathrm{OTF}_{atm}\,\mathrm{OTF}_{tel}|^2\,df},$$
//!
//! where the telescope OTF is the autocorrelation of the pupil field $E = P\,e^{i 4\pi s /
//! \lambda}$ (`P` the segmented pupil, `s` the surface error in m: the wavefront error is twice
//! the surface error), computed as `IFFT |FFT E|^2` on a grid zero-padded by at least 2 so that
//! the autocorrelation does not wrap around. The atmospheric MTF at the pupil lag `r` (m) is
//! $\exp(-D_\phi(r)/2)$, so the weight of every OTF sample is $\exp(-D_\phi(r))$. PSSN is 1
//! without error, insensitive to a global piston and to image motion (a global tip/tilt only
//! shifts the PSF), its deficit `1 - PSSN` is quadratic in small errors, and PSSNs of
//! independent small errors multiply ([`pssn_small_error`]).
//!
//! # Atmosphere
//!
//! Phase structure function (rad^2) for the Fried parameter `r0` at the evaluation wavelength
//! ([`r0_at_wavelength`]: `r0` given at 500 nm, scaled as `lambda^(6/5)`) and the outer scale
//! `L0`:
//!
//! - Kolmogorov (`L0 = inf`): $D(r) = 6.88388\,(r/r_0)^{5/3}$, the coefficient being
//!   $2\,[\tfrac{24}{5}\Gamma(\tfrac65)]^{5/6}$ ([`KOLMOGOROV_COEFFICIENT`]);
//! - von Kármán: $D(r) = C\,(L_0/r_0)^{5/3}\,[1 - \frac{2^{1/6}}{\Gamma(5/6)}\,x^{5/6}
//!   K_{5/6}(x)]$, $x = 2\pi r/L_0$, with $C = 0.1726287$ fixed so that `D` tends to the
//!   Kolmogorov law for `r << L0`; it saturates at $2\sigma^2 = C (L_0/r_0)^{5/3}$
//!   ([`phase_variance`]). For `x <= 1` the bracket is summed from the ascending series of
//!   $I_{\pm 5/6}$ (no cancellation at small `x`); beyond, `K_nu` comes from [`bessel_k`].
//!
//! # Discretisation
//!
//! The pupil is sampled on the [`PupilGrid`] (spacing `dx`), so the OTF comes on the lag grid
//! `(i, j) dx`, and the integrals become weighted sums over it. The weight of a lag sample is
//! not the point value `exp(-D((i, j) dx))` but its integral against the bilinear hat function
//! of the sample (product integration, exact for an OTF bilinear between samples): at the
//! default TMT grid and 500 nm, `dx = 0.118 m` is comparable with `r0 = 0.2 m`, and point
//! weights would put almost all the weight on the zero lag, which no error affects (they
//! underestimate the TMT deficit by 40 % there; the hat weights are within about 15 % of the
//! converged deficit, converging as `dx`). Use more samples where the deficit must be accurate
//! to a few per cent: `dx <= r0 / 4`.
//!
//! # Fast evaluation
//!
//! [`Pssn`] plans the FFTs, allocates every buffer, tabulates the OTF weights and computes the
//! perfect-telescope denominator once. An evaluation then fills the field on the in-aperture
//! samples (for a segment state, from three `sin_cos` per segment: its piston and tilts make the
//! phase linear in a sample's column and row in the segment's box of grid samples, so every
//! sample is the box corner's exponential times a tabulated power of the step along `x` and one
//! along `y`; the PSSN agrees with the per-sample field's to 1e-12, tested), transforms the `N`
//! non-zero rows along `x`, and obtains the OTF's lag rows that carry weight (`exp(-D) >
//! 1e-30`: 12 of them on the default TMT grid at 500 nm) by one of two [`OtfMethod`]s:
//!
//! - [`OtfMethod::Correlation`] (chosen when few lag rows carry weight): lag row `y'`'s
//!   spectrum along `x` is `sum_y F_{y+y'} conj(F_y)` over the row spectra `F_y`, so the
//!   evaluation needs only the row FFTs, `rows x N x P` complex multiply-adds and `rows` inverse
//!   FFTs. Only lags along `x` within the weighted disc are read, so the rows need zero-padding
//!   to `P >= N + rows` points, not `2N` (270 instead of 512 on the default TMT grid; the
//!   wrap-around falls on lags of no weight);
//! - [`OtfMethod::Transforms`]: on the `M x M` padded grid (`M = pad_factor x samples`), a
//!   transpose, FFTs of the `M` columns, `|.|^2`, inverse FFTs of the PSF rows two at a time
//!   (two real rows packed in one complex FFT, the half spectrum kept), a transpose and the
//!   inverse FFTs of the weighted lag rows;
//!
//! then the weighted sum. The two agree to rounding (1e-12 in double precision, tested).
//! BENCHMARKS.md, twenty-third round: TMT in single precision 0.83 ms per evaluation by the
//! transforms, 0.25 ms by the correlation (1.5 and 0.40 ms in double precision).
//!
//! # Files
//!
//! `mod.rs` the evaluator ([`Pssn`]) and its parameters, `atmosphere.rs` the von Karman phase
//! statistics and the lag weights of the OTF, `pupil.rs` the sampled pupil of the segments,
//! `correlate.rs` the correlation's vector kernel.

mod atmosphere;
mod correlate;
mod pupil;
#[cfg(test)]
mod tests;

pub use atmosphere::{
    KOLMOGOROV_COEFFICIENT, R0_WAVELENGTH, bessel_k, phase_structure_function, phase_variance,
    pssn_small_error, r0_at_wavelength,
};
pub use pupil::PupilGrid;

#[cfg(test)]
use atmosphere::LagWeight;
use atmosphere::otf_weights;
use correlate::Lane;
use pupil::check_ptt;

use std::f64::consts::PI;
use std::fmt;
use std::sync::{Arc, Mutex, TryLockError};

use rustfft::num_complex::{Complex, Complex64};
use rustfft::{Fft, FftNum, FftPlanner};

use crate::M1Error;
use crate::aperture::layout::Layout;

/// Parameters of [`Pssn`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PssnParams {
    /// Samples across the aperture `N` (default 256).
    pub samples: usize,
    /// Evaluation wavelength (m, default 500e-9).
    pub wavelength: f64,
    /// Fried parameter at 500 nm (m, default 0.2), scaled to `wavelength` as `lambda^(6/5)`.
    pub r0: f64,
    /// Outer scale `L0` (m, default 30; `f64::INFINITY` for Kolmogorov).
    pub l0: f64,
    /// Zero-padding factor, at least 2 (default 2): the FFT size is `pad_factor x samples`
    /// (rounded up to even).
    pub pad_factor: usize,
}

impl Default for PssnParams {
    fn default() -> Self {
        PssnParams {
            samples: PupilGrid::DEFAULT_SAMPLES,
            wavelength: 500e-9,
            r0: 0.2,
            l0: 30.0,
            pad_factor: 2,
        }
    }
}

/// An in-aperture sample: where it goes in the field buffer, its grid index, its segment, and
/// its column and row in the segment's bounding box of grid samples.
#[derive(Debug, Clone, Copy)]
struct PupilSample {
    field: usize,
    grid: usize,
    segment: usize,
    col: usize,
    row: usize,
}

/// A run of in-aperture samples of one segment on one grid row, consecutive in the field
/// buffer. A segment's piston and tilts make its phase linear in the sample's column and row in
/// the segment's box, so its field is the box corner's exponential times a power of the step
/// along `x` and one of the step along `y` ([`Pssn::pssn_ptt`]).
#[derive(Debug, Clone, Copy)]
struct Run {
    /// First sample's index in the field buffer.
    field: usize,
    len: usize,
    segment: usize,
    /// First sample's column and row in the segment's box.
    col: usize,
    row: usize,
}

/// The floating-point precision of an evaluation's transforms ([`Pssn::with_precision`]).
///
/// The field's phases, the OTF weights and the weighted sum are always computed in double
/// precision; single precision holds the field, its transforms and the OTF (and the
/// correlation's sums). Against double precision it moves the PSSN by up to 4.6e-7 by the
/// correlation and 0.7-2.8e-7 by the transforms (TMT at the default grid, segment states from
/// PSSN 0.9999 to 0.54; a test bounds it at 1e-5), three orders of magnitude below the grid's
/// own discretisation error at the closed loop's PSSN (1 - PSSN about 7 % high at 256 samples,
/// module documentation), and an evaluation takes 0.6 times as long (the FFTs half;
/// BENCHMARKS.md, twenty-second and twenty-third rounds).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PssnPrecision {
    /// Double precision throughout (the default of [`Pssn::new`]).
    #[default]
    Double,
    /// The field, its transforms and the OTF in single precision.
    Single,
}

/// How an evaluation obtains the lag rows of the OTF that carry weight ([`Pssn::with_method`]).
///
/// Both give the same PSSN to rounding (tested); [`OtfMethod::choose`] picks the cheaper.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OtfMethod {
    /// The FFTs of the `N` field rows, then each lag row `y'`'s spectrum along `x` as the sum
    /// over the rows of `F_{y+y'} conj(F_y)` (`rows x N x P` complex multiply-adds, with
    /// [`Pssn::row_fft_size`] `P`) and its inverse FFT. The cheaper where few lag rows carry
    /// weight: 12 on the default TMT grid, where an evaluation takes 0.3 times the transforms'
    /// time (BENCHMARKS.md, twenty-third round).
    Correlation,
    /// The 2-D power spectrum: the `N` row FFTs, a transpose, `M` column FFTs, `|.|^2`, `M / 2`
    /// inverse FFTs of packed PSF rows, a transpose and the inverse FFTs of the lag rows.
    Transforms,
}

impl OtfMethod {
    /// Where [`OtfMethod::choose`] stops correlating: while `rows x N <= this x M log2 M`
    /// (the correlation's `rows N P` multiply-adds against the transforms' `1.5 M` FFTs of
    /// size `M` beyond the row FFTs). Measured on TMT at 256 samples (`M` = 512), the two take
    /// as long at about 80 lag rows in both precisions (4.4 here); 4 keeps the correlation
    /// where it is faster (BENCHMARKS.md, twenty-third round).
    pub const CORRELATION_ROWS_PER_LOG: f64 = 4.0;

    /// The cheaper method for `rows` weighted lag rows, `samples` (`N`) field rows and the FFT
    /// size `size` (`M`).
    pub fn choose(rows: usize, samples: usize, size: usize) -> OtfMethod {
        let live = rows.min(samples) as f64;
        let m = size as f64;
        if live * samples as f64 <= Self::CORRELATION_ROWS_PER_LOG * m * m.log2() {
            OtfMethod::Correlation
        } else {
            OtfMethod::Transforms
        }
    }
}

/// `out[j] = exp(i j angle)`, each a product of two earlier ones (`j / 2` and `j - j / 2`):
/// about `log2 j` roundings, and products that do not wait on each other.
fn unit_powers(out: &mut [Complex64], angle: f64) {
    if let Some(o) = out.first_mut() {
        *o = Complex64::new(1.0, 0.0);
    }
    if let Some(o) = out.get_mut(1) {
        let (s, c) = angle.sin_cos();
        *o = Complex64::new(c, s);
    }
    for j in 2..out.len() {
        out[j] = out[j / 2] * out[j - j / 2];
    }
}

/// The smallest even `2^a 3^b 5^c` (sizes the FFTs handle well) of at least `n + rows`: the
/// period of [`OtfMethod::Correlation`]'s row transforms.
fn correlation_size(n: usize, rows: usize) -> usize {
    let smooth = |mut k: usize| {
        for f in [2, 3, 5] {
            while k.is_multiple_of(f) {
                k /= f;
            }
        }
        k == 1
    };
    let mut p = (n + rows).max(2);
    p += p % 2;
    while !smooth(p) {
        p += 2;
    }
    p
}

/// A floating-point type the transforms run in ([`PssnPrecision`]).
trait Sample: FftNum {
    /// `x` rounded to this type.
    fn of(x: f64) -> Self;
    /// The value in double precision.
    fn wide(self) -> f64;
}

impl Sample for f64 {
    fn of(x: f64) -> Self {
        x
    }
    fn wide(self) -> f64 {
        self
    }
}

impl Sample for f32 {
    fn of(x: f64) -> Self {
        x as f32
    }
    fn wide(self) -> f64 {
        f64::from(self)
    }
}

/// `z` rounded to the type of the transforms.
fn sample<T: Sample>(z: Complex64) -> Complex<T> {
    Complex::new(T::of(z.re), T::of(z.im))
}

/// Buffers of one evaluation.
struct Workspace<T> {
    /// `N x P`: the field rows, then their FFTs.
    field: Vec<Complex<T>>,
    /// `M x M` ([`OtfMethod::Transforms`] only): the transposed spectrum, then the packed PSF
    /// rows and their inverse FFTs.
    spectrum: Vec<Complex<T>>,
    /// [`OtfMethod::Correlation`]'s panels of columns.
    panel: Vec<T>,
    /// `rows x P`: the half OTF over the lags with non-negligible weight.
    otf: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
    /// Per segment ([`Pssn::pssn_ptt`]): the powers of the field's factor from one sample to
    /// the next along a row (as many as the widest box has columns), those along a column (as
    /// many as the tallest box has rows), and the field at the box's corner.
    powers: Vec<Complex64>,
}

impl<T: Sample> Workspace<T> {
    fn empty() -> Self {
        Self {
            field: Vec::new(),
            spectrum: Vec::new(),
            panel: Vec::new(),
            otf: Vec::new(),
            scratch: Vec::new(),
            powers: Vec::new(),
        }
    }
}

/// The FFT plans and the buffers of one precision.
struct Fourier<T> {
    fft: Arc<dyn Fft<T>>,
    ifft: Arc<dyn Fft<T>>,
    workspace: Mutex<Workspace<T>>,
}

impl<T: Sample> Fourier<T> {
    fn new(size: usize) -> Self {
        let mut planner = FftPlanner::<T>::new();
        Self {
            fft: planner.plan_fft_forward(size),
            ifft: planner.plan_fft_inverse(size),
            workspace: Mutex::new(Workspace::empty()),
        }
    }
}

/// The transforms in the evaluator's precision.
enum Transforms {
    Double(Fourier<f64>),
    Single(Fourier<f32>),
}

/// PSSN evaluator for one layout and one set of [`PssnParams`] (see the
/// [module documentation](self)). Evaluations take `&self`: the buffers sit behind a mutex, and
/// a concurrent caller that finds it busy gets fresh buffers.
pub struct Pssn {
    params: PssnParams,
    grid: PupilGrid,
    /// Padded FFT size `M`.
    size: usize,
    /// The size `P` of the row FFTs (and the field buffer's row stride): `M` for
    /// [`OtfMethod::Transforms`], at least `N + rows` for [`OtfMethod::Correlation`].
    row_size: usize,
    /// Lag rows `y' = 0..rows` of the half OTF that carry weight.
    rows: usize,
    method: OtfMethod,
    transforms: Transforms,
    /// `rows x P`: `exp(-D(r))`, doubled for the rows standing for their mirror image too.
    weights: Vec<f64>,
    pupil: Vec<PupilSample>,
    /// The same samples as runs along the rows, for segment states ([`Self::pssn_ptt`]).
    runs: Vec<Run>,
    /// Per segment, the offset (m) of its box's corner sample from its centre.
    corners: Vec<[f64; 2]>,
    /// Columns of the widest segment box and rows of the tallest.
    box_size: [usize; 2],
    phase_per_metre: f64,
    denominator: f64,
}

impl fmt::Debug for Pssn {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Pssn")
            .field("params", &self.params)
            .field("samples", &self.grid.samples)
            .field("spacing", &self.grid.spacing)
            .field("fft_size", &self.size)
            .field("row_fft_size", &self.row_size)
            .field("lag_rows", &self.rows)
            .field("method", &self.method)
            .field("denominator", &self.denominator)
            .field("precision", &self.precision())
            .finish_non_exhaustive()
    }
}

impl Pssn {
    /// Builds the evaluator: pupil grid, FFT plans, buffers, OTF weights and the
    /// perfect-telescope denominator, in double precision.
    pub fn new(layout: &Layout, params: PssnParams) -> Result<Pssn, M1Error> {
        Self::with_precision(layout, params, PssnPrecision::Double)
    }

    /// [`Self::new`] with the transforms in `precision` (the denominator too, so that a
    /// perfect mirror still gives exactly 1), the OTF by the cheaper [`OtfMethod`].
    pub fn with_precision(
        layout: &Layout,
        params: PssnParams,
        precision: PssnPrecision,
    ) -> Result<Pssn, M1Error> {
        Self::with_method(layout, params, precision, None)
    }

    /// [`Self::with_precision`] with the OTF by `method` (`None`: [`OtfMethod::choose`]).
    pub fn with_method(
        layout: &Layout,
        params: PssnParams,
        precision: PssnPrecision,
        method: Option<OtfMethod>,
    ) -> Result<Pssn, M1Error> {
        let positive = |name: &'static str, value: f64, allow_inf: bool| {
            if value > 0.0 && (value.is_finite() || allow_inf) {
                Ok(())
            } else {
                Err(M1Error::InvalidParameter {
                    name,
                    value,
                    reason: "must be > 0 (and finite unless an outer scale)",
                })
            }
        };
        positive("wavelength", params.wavelength, false)?;
        positive("r0", params.r0, false)?;
        positive("l0", params.l0, true)?;
        if params.pad_factor < 2 {
            return Err(M1Error::InvalidParameter {
                name: "pad_factor",
                value: params.pad_factor as f64,
                reason: "zero padding of at least 2 is needed to avoid wrap-around",
            });
        }
        let grid = PupilGrid::new(layout, params.samples)?;
        let n = grid.samples;
        let size = n.checked_mul(params.pad_factor).map(|m| m + m % 2).ok_or(
            M1Error::InvalidParameter {
                name: "pad_factor",
                value: params.pad_factor as f64,
                reason: "FFT size overflows",
            },
        )?;
        if grid.n_inside == 0 {
            return Err(M1Error::InvalidParameter {
                name: "samples",
                value: n as f64,
                reason: "no sample falls inside a segment: use more samples",
            });
        }

        let (weights, rows) = otf_weights(&params, size, grid.spacing);
        let method = method.unwrap_or_else(|| OtfMethod::choose(rows, n, size));
        // The correlation's row transforms need no more than N + rows points (below).
        let (row_size, weights) = match method {
            OtfMethod::Correlation => {
                let p = correlation_size(n, rows);
                match otf_weights(&params, p, grid.spacing) {
                    (w, r) if p < size && r == rows => (p, w),
                    _ => (size, weights),
                }
            }
            OtfMethod::Transforms => (size, weights),
        };

        // Every segment's box of grid samples: its first column and row, and its size.
        let n_seg = grid.n_segments();
        let mut first = vec![[usize::MAX; 2]; n_seg];
        let mut box_size = [1, 1];
        let inside = || {
            grid.segment
                .iter()
                .enumerate()
                .filter_map(|(flat, seg)| Some(((*seg)? as usize, flat % n, flat / n)))
        };
        for (seg, ix, iy) in inside() {
            first[seg] = [first[seg][0].min(ix), first[seg][1].min(iy)];
        }
        for (seg, ix, iy) in inside() {
            box_size = [
                box_size[0].max(ix - first[seg][0] + 1),
                box_size[1].max(iy - first[seg][1] + 1),
            ];
        }
        let corners: Vec<[f64; 2]> = first
            .iter()
            .zip(&grid.centers)
            .map(|(&[ix, iy], c)| {
                if ix == usize::MAX {
                    [0.0, 0.0]
                } else {
                    [grid.coordinate(ix) - c[0], grid.coordinate(iy) - c[1]]
                }
            })
            .collect();

        // Pupil samples, in field-buffer order (row iy, column ix of an N x P buffer).
        let pupil: Vec<PupilSample> = inside()
            .map(|(seg, ix, iy)| PupilSample {
                field: iy * row_size + ix,
                grid: iy * n + ix,
                segment: seg,
                col: ix - first[seg][0],
                row: iy - first[seg][1],
            })
            .collect();

        let mut runs: Vec<Run> = Vec::new();
        for s in &pupil {
            match runs.last_mut() {
                Some(r) if r.segment == s.segment && r.field + r.len == s.field => r.len += 1,
                _ => runs.push(Run {
                    field: s.field,
                    len: 1,
                    segment: s.segment,
                    col: s.col,
                    row: s.row,
                }),
            }
        }

        let transforms = match precision {
            PssnPrecision::Double => Transforms::Double(Fourier::new(row_size)),
            PssnPrecision::Single => Transforms::Single(Fourier::new(row_size)),
        };
        let mut pssn = Pssn {
            params,
            grid,
            size,
            row_size,
            rows,
            method,
            transforms,
            weights,
            pupil,
            runs,
            corners,
            box_size,
            phase_per_metre: 4.0 * PI / params.wavelength,
            denominator: 1.0,
        };
        let denominator = match &pssn.transforms {
            Transforms::Double(f) => pssn.perfect_power(f),
            Transforms::Single(f) => pssn.perfect_power(f),
        };
        if !(denominator > 0.0 && denominator.is_finite()) {
            return Err(M1Error::InvalidParameter {
                name: "samples",
                value: n as f64,
                reason: "the perfect-telescope OTF has no weight",
            });
        }
        pssn.denominator = denominator;
        Ok(pssn)
    }

    /// The parameters.
    pub fn params(&self) -> &PssnParams {
        &self.params
    }

    /// The pupil grid.
    pub fn grid(&self) -> &PupilGrid {
        &self.grid
    }

    /// Lag rows of the half OTF an evaluation transforms (those where the atmosphere's weight
    /// is non-negligible; at most `M / 2 + 1`): with the grid's and `M`, the sizes of its FFTs.
    pub fn otf_lag_rows(&self) -> usize {
        self.rows
    }

    /// How an evaluation obtains the OTF's weighted lag rows.
    pub fn otf_method(&self) -> OtfMethod {
        self.method
    }

    /// The precision of the transforms.
    pub fn precision(&self) -> PssnPrecision {
        match self.transforms {
            Transforms::Double(_) => PssnPrecision::Double,
            Transforms::Single(_) => PssnPrecision::Single,
        }
    }

    /// FFT size `M` of the padded grid.
    pub fn fft_size(&self) -> usize {
        self.size
    }

    /// Size `P` of the field rows' FFTs: [`Self::fft_size`] for [`OtfMethod::Transforms`];
    /// for [`OtfMethod::Correlation`] the smallest even `2^a 3^b 5^c >= N + rows` (at most
    /// `M`): the OTF's weighted lags along `x` are fewer than `rows`, and a period of `N +
    /// rows` keeps them clear of the wrap-around (TMT's default grid: 270 instead of 512).
    pub fn row_fft_size(&self) -> usize {
        self.row_size
    }

    /// Fried parameter at the evaluation wavelength (m).
    pub fn r0(&self) -> f64 {
        r0_at_wavelength(self.params.r0, self.params.wavelength)
    }

    /// The perfect-telescope denominator `sum |OTF_atm OTF_tel|^2` (arbitrary units).
    pub fn denominator(&self) -> f64 {
        self.denominator
    }

    /// PSSN of the segment state `ptt` (`[p, tx, ty]` per segment, m and rad, see
    /// [`crate::aperture::zernike`]).
    pub fn pssn_ptt(&self, ptt: &[[f64; 3]]) -> Result<f64, M1Error> {
        check_ptt(ptt, self.grid.n_segments())?;
        let power = match &self.transforms {
            Transforms::Double(f) => self.ptt_power(f, ptt),
            Transforms::Single(f) => self.ptt_power(f, ptt),
        };
        Ok(power / self.denominator)
    }

    /// The weighted OTF power of the segment state `ptt` ([`Self::pssn_ptt`]).
    fn ptt_power<T: Lane>(&self, f: &Fourier<T>, ptt: &[[f64; 3]]) -> f64 {
        let k = self.phase_per_metre;
        let h = self.grid.spacing;
        self.with_workspace(f, |ws| {
            // Per segment: the powers of the steps along x and y, and the field at the box's
            // corner (three sin_cos per segment); every sample is then two products away.
            let [w, hgt] = self.box_size;
            let per = w + hgt + 1;
            let mut powers = std::mem::take(&mut ws.powers);
            powers.resize(ptt.len() * per, Complex64::new(0.0, 0.0));
            for ((t, &[p, tx, ty]), &[x0, y0]) in
                powers.chunks_exact_mut(per).zip(ptt).zip(&self.corners)
            {
                let (along_x, rest) = t.split_at_mut(w);
                let (along_y, corner) = rest.split_at_mut(hgt);
                unit_powers(along_x, k * tx * h);
                unit_powers(along_y, k * ty * h);
                let (s, c) = (k * (p + tx * x0 + ty * y0)).sin_cos();
                corner[0] = Complex64::new(c, s);
            }
            let power = self.weighted_otf_power(f, ws, |field| {
                for r in &self.runs {
                    let t = &powers[r.segment * per..][..per];
                    let e = t[per - 1] * t[w + r.row];
                    for (f, q) in field[r.field..r.field + r.len].iter_mut().zip(&t[r.col..]) {
                        *f = sample(e * q);
                    }
                }
            });
            ws.powers = powers;
            power
        })
    }

    /// PSSN of a surface error sampled on the [grid](Self::grid) (m, `N x N`, flat index
    /// `iy N + ix`; values outside the segments are ignored).
    pub fn pssn_surface(&self, surface: &[f64]) -> Result<f64, M1Error> {
        let n = self.grid.samples;
        if surface.len() != n * n {
            return Err(M1Error::SizeMismatch {
                what: "surface samples",
                expected: n * n,
                found: surface.len(),
            });
        }
        let power = match &self.transforms {
            Transforms::Double(f) => self.surface_power(f, surface),
            Transforms::Single(f) => self.surface_power(f, surface),
        };
        Ok(power / self.denominator)
    }

    /// The weighted OTF power of the sampled surface `surface` ([`Self::pssn_surface`]).
    fn surface_power<T: Lane>(&self, f: &Fourier<T>, surface: &[f64]) -> f64 {
        let k = self.phase_per_metre;
        self.with_workspace(f, |ws| {
            self.weighted_otf_power(f, ws, |field| {
                for s in &self.pupil {
                    let (sin, cos) = (k * surface[s.grid]).sin_cos();
                    field[s.field] = sample(Complex64::new(cos, sin));
                }
            })
        })
    }

    /// The weighted OTF power of the perfect mirror: the denominator.
    fn perfect_power<T: Lane>(&self, f: &Fourier<T>) -> f64 {
        self.with_workspace(f, |ws| {
            self.weighted_otf_power(f, ws, |field| {
                for s in &self.pupil {
                    field[s.field] = Complex::new(T::one(), T::zero());
                }
            })
        })
    }

    fn new_workspace<T: Lane>(&self, f: &Fourier<T>) -> Workspace<T> {
        let (n, m, p) = (self.grid.samples, self.size, self.row_size);
        let scratch = f
            .fft
            .get_inplace_scratch_len()
            .max(f.ifft.get_inplace_scratch_len());
        let zero = Complex::new(T::zero(), T::zero());
        Workspace {
            field: vec![zero; n * p],
            spectrum: match self.method {
                OtfMethod::Transforms => vec![zero; m * m],
                OtfMethod::Correlation => Vec::new(),
            },
            panel: Vec::new(),
            otf: vec![zero; self.rows * p],
            scratch: vec![zero; scratch],
            powers: Vec::new(),
        }
    }

    /// Runs `g` on `f`'s buffers (made at the first evaluation), or on fresh ones when
    /// another thread holds them.
    fn with_workspace<T: Lane, R>(
        &self,
        f: &Fourier<T>,
        g: impl FnOnce(&mut Workspace<T>) -> R,
    ) -> R {
        let run = |ws: &mut Workspace<T>| {
            if ws.field.is_empty() {
                *ws = self.new_workspace(f);
            }
            g(ws)
        };
        match f.workspace.try_lock() {
            Ok(mut guard) => run(&mut guard),
            Err(TryLockError::Poisoned(poisoned)) => run(&mut poisoned.into_inner()),
            Err(TryLockError::WouldBlock) => run(&mut self.new_workspace(f)),
        }
    }

    /// `sum_f exp(-D(f)) |OTF(f)|^2` for the pupil field that `fill` writes into the zeroed
    /// `N x M` field buffer (`exp(i phase)` at each in-aperture sample), unnormalised.
    fn weighted_otf_power<T: Lane>(
        &self,
        f: &Fourier<T>,
        ws: &mut Workspace<T>,
        fill: impl FnOnce(&mut [Complex<T>]),
    ) -> f64 {
        let (n, m, p) = (self.grid.samples, self.size, self.row_size);
        let zero = Complex::new(T::zero(), T::zero());

        // Field on the N non-zero rows, FFT along x.
        ws.field.fill(zero);
        fill(&mut ws.field);
        f.fft.process_with_scratch(&mut ws.field, &mut ws.scratch);

        // The lag rows' spectra along x, then their inverse FFTs.
        let scale = match self.method {
            OtfMethod::Correlation => {
                correlate::lag_rows(&ws.field, n, p, self.rows, &mut ws.otf, &mut ws.panel);
                // The transforms' OTF carries a factor M^2 / P (their FFTs' sizes): the same
                // power, so that the denominator does not depend on the method.
                let gain = (m * m) as f64 / p as f64;
                gain * gain
            }
            OtfMethod::Transforms => {
                self.transformed_lag_rows(f, ws);
                1.0
            }
        };
        f.ifft.process_with_scratch(&mut ws.otf, &mut ws.scratch);

        scale
            * ws.otf
                .iter()
                .zip(&self.weights)
                .map(|(o, w)| w * o.norm_sqr().wide())
                .sum::<f64>()
    }

    /// [`OtfMethod::Transforms`]: the lag rows' spectra along x into `ws.otf` from the row
    /// FFTs in `ws.field`, by the 2-D power spectrum.
    fn transformed_lag_rows<T: Lane>(&self, f: &Fourier<T>, ws: &mut Workspace<T>) {
        let (n, m) = (self.grid.samples, self.size);
        let half = m / 2;
        let zero = Complex::new(T::zero(), T::zero());

        // Transpose into the M x M spectrum (rows N..M of the field are zero), FFT along y.
        // Blocks of ROWS field rows: their stride (M complex values, a power of two) puts them
        // in one set of the L1 cache, so a block must not outnumber its ways.
        const ROWS: usize = 8;
        const COLS: usize = 64;
        for r0 in (0..n).step_by(ROWS) {
            let r1 = (r0 + ROWS).min(n);
            for c0 in (0..m).step_by(COLS) {
                for c in c0..(c0 + COLS).min(m) {
                    let row = &mut ws.spectrum[c * m + r0..c * m + r1];
                    for (r, value) in (r0..r1).zip(row.iter_mut()) {
                        *value = ws.field[r * m + c];
                    }
                }
            }
        }
        for c in 0..m {
            ws.spectrum[c * m + n..(c + 1) * m].fill(zero);
        }
        f.fft
            .process_with_scratch(&mut ws.spectrum, &mut ws.scratch);

        // PSF rows 2t and 2t+1 packed as the real and imaginary parts of row t.
        for k in 0..m {
            let (a, b) = (ws.spectrum[k].norm_sqr(), ws.spectrum[m + k].norm_sqr());
            ws.spectrum[k] = Complex::new(a, b);
        }
        for t in 1..half {
            let (lo, hi) = ws.spectrum.split_at_mut(2 * t * m);
            let dst = &mut lo[t * m..(t + 1) * m];
            let (ra, rb) = hi[..2 * m].split_at(m);
            for ((d, a), b) in dst.iter_mut().zip(ra).zip(rb) {
                *d = Complex::new(a.norm_sqr(), b.norm_sqr());
            }
        }
        f.ifft
            .process_with_scratch(&mut ws.spectrum[..half * m], &mut ws.scratch);

        // Unpack the two real rows' (Hermitian) transforms and transpose: otf[y'][kx].
        const PAIRS: usize = 8;
        let half_of = T::of(0.5);
        for t0 in (0..half).step_by(PAIRS) {
            let t1 = (t0 + PAIRS).min(half);
            for y in 0..self.rows {
                let ym = (m - y) % m;
                let out = &mut ws.otf[y * m..(y + 1) * m];
                for t in t0..t1 {
                    let z = ws.spectrum[t * m + y];
                    let zc = ws.spectrum[t * m + ym].conj();
                    let (s, d) = (z + zc, z - zc);
                    out[2 * t] = Complex::new(half_of * s.re, half_of * s.im);
                    out[2 * t + 1] = Complex::new(half_of * d.im, -half_of * d.re);
                }
            }
        }
    }
}
