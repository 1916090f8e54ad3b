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
//! samples (for a segment state, run by run along the grid rows: a segment's piston and tilts
//! make the phase an arithmetic progression along a row, so the field is one complex
//! exponential times powers of another, a `sin_cos` per run of up to 32 samples and one per
//! segment instead of one per sample; the PSSN agrees with the per-sample field's to 1e-12,
//! tested) and does, on the `M x M` padded grid (`M = pad_factor x samples`): FFTs of the `N`
//! non-zero rows, a transpose, FFTs of the `M` columns, `|.|^2`, inverse FFTs of the PSF rows
//! two at a time (packing two real rows in one complex FFT and keeping the half spectrum), a
//! transpose, inverse FFTs of only the rows of lags where the weight is non-negligible
//! (`exp(-D) > 1e-30`), and the weighted sum.
//!
//! # Files
//!
//! `mod.rs` the evaluator ([`Pssn`]) and its parameters, `atmosphere.rs` the von Karman phase
//! statistics and the lag weights of the OTF, `pupil.rs` the sampled pupil of the segments.

mod atmosphere;
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

/// An in-aperture sample: where it goes in the field buffer, its grid index, its segment and its
/// offset from the segment centre (m).
#[derive(Debug, Clone, Copy)]
struct PupilSample {
    field: usize,
    grid: usize,
    segment: usize,
    dx: f64,
    dy: f64,
}

/// A run of in-aperture samples of one segment on one grid row, consecutive in the field
/// buffer: the phase of a segment's piston and tilts along it is an arithmetic progression, so
/// its field is one complex exponential times powers of one step ([`Pssn::pssn_ptt`]).
#[derive(Debug, Clone, Copy)]
struct Run {
    /// First sample's index in the field buffer.
    field: usize,
    len: usize,
    segment: usize,
    /// First sample's offset from the segment centre (m).
    dx: f64,
    dy: f64,
}

/// Longest [`Run`]: the field along a run is a running product of complex exponentials, whose
/// rounding grows with its length (about `len` units in the last place); longer rows are split.
const RUN_MAX: usize = 32;

/// The floating-point precision of an evaluation's transforms ([`Pssn::with_precision`]).
///
/// The field's phases, the OTF weights and the weighted sum are always computed in double
/// precision; single precision holds the field, its transforms and the OTF. Against double
/// precision it moves the PSSN by 0.7-2.8e-7 (TMT at the default grid, segment states from
/// PSSN 0.9999 to 0.54; a test bounds it at 1e-5), three orders of magnitude below the grid's
/// own discretisation error at the closed loop's PSSN (1 - PSSN about 7 % high at 256 samples,
/// module documentation), and the FFTs take about half the time (BENCHMARKS.md,
/// twenty-second round).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PssnPrecision {
    /// Double precision throughout (the default of [`Pssn::new`]).
    #[default]
    Double,
    /// The field, its transforms and the OTF in single precision.
    Single,
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
    /// `N x M`: the field rows, then their FFTs.
    field: Vec<Complex<T>>,
    /// `M x M`: the transposed spectrum, then the packed PSF rows and their inverse FFTs.
    spectrum: Vec<Complex<T>>,
    /// `rows x M`: the half OTF over the lags with non-negligible weight.
    otf: Vec<Complex<T>>,
    scratch: Vec<Complex<T>>,
    /// Per segment: the field's factor from one sample to the next along a row.
    steps: Vec<Complex64>,
}

impl<T: Sample> Workspace<T> {
    fn empty() -> Self {
        Self {
            field: Vec::new(),
            spectrum: Vec::new(),
            otf: Vec::new(),
            scratch: Vec::new(),
            steps: Vec::new(),
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
    /// Lag rows `y' = 0..rows` of the half OTF that carry weight.
    rows: usize,
    transforms: Transforms,
    /// `rows x M`: `exp(-D(r))`, doubled for the rows standing for their mirror image too.
    weights: Vec<f64>,
    pupil: Vec<PupilSample>,
    /// The same samples as runs along the rows, for segment states ([`Self::pssn_ptt`]).
    runs: Vec<Run>,
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
            .field("lag_rows", &self.rows)
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
    /// perfect mirror still gives exactly 1).
    pub fn with_precision(
        layout: &Layout,
        params: PssnParams,
        precision: PssnPrecision,
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

        // Pupil samples, in field-buffer order (row iy, column ix of an N x M buffer).
        let pupil: Vec<PupilSample> = grid
            .segment
            .iter()
            .enumerate()
            .filter_map(|(flat, seg)| {
                let seg = (*seg)? as usize;
                let (ix, iy) = (flat % n, flat / n);
                Some(PupilSample {
                    field: iy * size + ix,
                    grid: flat,
                    segment: seg,
                    dx: grid.coordinate(ix) - grid.centers[seg][0],
                    dy: grid.coordinate(iy) - grid.centers[seg][1],
                })
            })
            .collect();

        let mut runs: Vec<Run> = Vec::new();
        for s in &pupil {
            match runs.last_mut() {
                Some(r)
                    if r.segment == s.segment && r.field + r.len == s.field && r.len < RUN_MAX =>
                {
                    r.len += 1;
                }
                _ => runs.push(Run {
                    field: s.field,
                    len: 1,
                    segment: s.segment,
                    dx: s.dx,
                    dy: s.dy,
                }),
            }
        }

        let (weights, rows) = otf_weights(&params, size, grid.spacing);

        let transforms = match precision {
            PssnPrecision::Double => Transforms::Double(Fourier::new(size)),
            PssnPrecision::Single => Transforms::Single(Fourier::new(size)),
        };
        let mut pssn = Pssn {
            params,
            grid,
            size,
            rows,
            transforms,
            weights,
            pupil,
            runs,
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
    fn ptt_power<T: Sample>(&self, f: &Fourier<T>, ptt: &[[f64; 3]]) -> f64 {
        let k = self.phase_per_metre;
        let h = self.grid.spacing;
        self.with_workspace(f, |ws| {
            // Along a run the phase grows by k tx h per sample: the field is its first
            // sample's exponential times powers of the segment's step (a sin_cos per run and
            // one per segment, instead of one per sample), in double precision.
            let mut steps = std::mem::take(&mut ws.steps);
            steps.clear();
            steps.extend(ptt.iter().map(|&[_, tx, _]| {
                let (s, c) = (k * tx * h).sin_cos();
                Complex64::new(c, s)
            }));
            let power = self.weighted_otf_power(f, ws, |field| {
                for r in &self.runs {
                    let [p, tx, ty] = ptt[r.segment];
                    let (s0, c0) = (k * (p + tx * r.dx + ty * r.dy)).sin_cos();
                    let step = steps[r.segment];
                    let mut e = Complex64::new(c0, s0);
                    for f in &mut field[r.field..r.field + r.len] {
                        *f = sample(e);
                        e *= step;
                    }
                }
            });
            ws.steps = steps;
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
    fn surface_power<T: Sample>(&self, f: &Fourier<T>, surface: &[f64]) -> f64 {
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
    fn perfect_power<T: Sample>(&self, f: &Fourier<T>) -> f64 {
        self.with_workspace(f, |ws| {
            self.weighted_otf_power(f, ws, |field| {
                for s in &self.pupil {
                    field[s.field] = Complex::new(T::one(), T::zero());
                }
            })
        })
    }

    fn new_workspace<T: Sample>(&self, f: &Fourier<T>) -> Workspace<T> {
        let (n, m) = (self.grid.samples, self.size);
        let scratch = f
            .fft
            .get_inplace_scratch_len()
            .max(f.ifft.get_inplace_scratch_len());
        let zero = Complex::new(T::zero(), T::zero());
        Workspace {
            field: vec![zero; n * m],
            spectrum: vec![zero; m * m],
            otf: vec![zero; self.rows * m],
            scratch: vec![zero; scratch],
            steps: vec![Complex64::new(0.0, 0.0); self.grid.n_segments()],
        }
    }

    /// Runs `g` on `f`'s buffers (made at the first evaluation), or on fresh ones when
    /// another thread holds them.
    fn with_workspace<T: Sample, R>(
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
    fn weighted_otf_power<T: Sample>(
        &self,
        f: &Fourier<T>,
        ws: &mut Workspace<T>,
        fill: impl FnOnce(&mut [Complex<T>]),
    ) -> f64 {
        let (n, m) = (self.grid.samples, self.size);
        let half = m / 2;
        let zero = Complex::new(T::zero(), T::zero());

        // Field on the N non-zero rows, FFT along x.
        ws.field.fill(zero);
        fill(&mut ws.field);
        f.fft.process_with_scratch(&mut ws.field, &mut ws.scratch);

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
        f.ifft.process_with_scratch(&mut ws.otf, &mut ws.scratch);

        ws.otf
            .iter()
            .zip(&self.weights)
            .map(|(o, w)| w * o.norm_sqr().wide())
            .sum()
    }
}
