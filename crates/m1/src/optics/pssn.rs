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
//! samples and does, on the `M x M` padded grid (`M = pad_factor x samples`): FFTs of the `N`
//! non-zero rows, a transpose, FFTs of the `M` columns, `|.|^2`, inverse FFTs of the PSF rows
//! two at a time (packing two real rows in one complex FFT and keeping the half spectrum), a
//! transpose, inverse FFTs of only the rows of lags where the weight is non-negligible
//! (`exp(-D) > 1e-30`), and the weighted sum.

use std::f64::consts::PI;
use std::fmt;
use std::sync::{Arc, Mutex, TryLockError};

use rustfft::num_complex::Complex64;
use rustfft::{Fft, FftPlanner};

use crate::M1Error;
use crate::aperture::layout::Layout;

/// Kolmogorov phase structure function coefficient, `2 [24/5 Gamma(6/5)]^(5/6)` (the "6.88").
pub const KOLMOGOROV_COEFFICIENT: f64 = 6.883_877_182_293_812;

/// Wavelength at which the Fried parameter `r0` is given (m): 500 nm.
pub const R0_WAVELENGTH: f64 = 500e-9;

/// Gamma(1/6).
const GAMMA_1_6: f64 = 5.566_316_001_780_235;
/// Gamma(5/6).
const GAMMA_5_6: f64 = 1.128_787_029_908_126;
/// Order of the Bessel function of the von Kármán structure function.
const NU: f64 = 5.0 / 6.0;

/// Relative weight below which an OTF sample is dropped (`exp(-D) < 1e-30`).
const WEIGHT_FLOOR: f64 = 1e-30;

/// Modified Bessel function of the second kind `K_nu(x)` for real `nu` and `x > 0`, from
/// `K_nu(x) = integral_0^inf exp(-x cosh t) cosh(nu t) dt` by the trapezoidal rule (step
/// 0.05), which converges geometrically for this analytic, double-exponentially decaying
/// integrand: relative accuracy about 1e-14. `+inf` at `x = 0`, NaN for `x < 0` or NaN.
pub fn bessel_k(nu: f64, x: f64) -> f64 {
    if x.is_nan() || x < 0.0 || nu.is_nan() {
        return f64::NAN;
    }
    if x == 0.0 {
        return f64::INFINITY;
    }
    if x.is_infinite() {
        return 0.0;
    }
    const H: f64 = 0.05;
    let nu = nu.abs();
    // exp(-x) is factored out: terms exp(-x (cosh t - 1)) cosh(nu t), the first at half weight.
    let mut sum = 0.5;
    for k in 1..200_000_u32 {
        let t = f64::from(k) * H;
        let e = x * (t.cosh() - 1.0);
        sum += (-e).exp() * (nu * t).cosh();
        // Past the peak every further term is below exp(-40) of the sum, and falling fast.
        if e - nu * t > 40.0 {
            break;
        }
    }
    sum * H * (-x).exp()
}

/// Von Kármán constant `C` of [`phase_structure_function`]: `D(r) -> 6.88 (r/r0)^(5/3)` for
/// `r << L0`.
fn von_karman_coefficient() -> f64 {
    // Leading small-x term of the bracket: a1 x^(5/3), a1 = Gamma(1/6) / (nu 2^(2 nu) Gamma(5/6)).
    let a1 = GAMMA_1_6 / (NU * 2.0_f64.powf(2.0 * NU) * GAMMA_5_6);
    KOLMOGOROV_COEFFICIENT / (a1 * (2.0 * PI).powf(5.0 / 3.0))
}

/// The bracket `1 - 2^(1/6) / Gamma(5/6) x^(5/6) K_(5/6)(x)` of the von Kármán structure
/// function, from 0 at `x = 0` to 1 at `x = inf`.
fn von_karman_shape(x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x <= 1.0 {
        // x^nu K_nu(x) from the series of I_-nu and I_nu; its constant term cancels the 1.
        let y = 0.25 * x * x;
        let mut tp = 1.0 / (NU * GAMMA_5_6); // 1 / Gamma(1 + nu)
        let mut tm = 1.0 / GAMMA_1_6; // 1 / Gamma(1 - nu)
        let mut sum_p = tp;
        let mut sum_m = 0.0;
        for k in 1..100 {
            let k = f64::from(k);
            tp *= y / (k * (k + NU));
            tm *= y / (k * (k - NU));
            sum_p += tp;
            sum_m += tm;
            if tp.abs() <= 1e-18 * sum_p.abs() && tm.abs() <= 1e-18 * sum_m.abs() {
                break;
            }
        }
        GAMMA_1_6 * (2.0_f64.powf(-2.0 * NU) * x.powf(2.0 * NU) * sum_p - sum_m)
    } else {
        let c = 2.0_f64.powf(1.0 - NU) / GAMMA_5_6;
        1.0 - c * x.powf(NU) * bessel_k(NU, x)
    }
}

/// Phase structure function `D(r)` (rad^2) of the atmosphere at the separation `r` (m) for the
/// Fried parameter `r0` (m, at the wavelength of interest) and outer scale `l0` (m;
/// `f64::INFINITY` gives Kolmogorov). See the [module documentation](self).
pub fn phase_structure_function(r: f64, r0: f64, l0: f64) -> f64 {
    let r = r.abs();
    if r == 0.0 {
        return 0.0;
    }
    if l0.is_infinite() {
        return KOLMOGOROV_COEFFICIENT * (r / r0).powf(5.0 / 3.0);
    }
    von_karman_coefficient() * (l0 / r0).powf(5.0 / 3.0) * von_karman_shape(2.0 * PI * r / l0)
}

/// Von Kármán phase variance `sigma^2 = C/2 (L0/r0)^(5/3)` (rad^2, about
/// `0.0863 (L0/r0)^(5/3)`): `D(r) -> 2 sigma^2` for `r >> L0`. Infinite for `l0 = inf`.
pub fn phase_variance(r0: f64, l0: f64) -> f64 {
    0.5 * von_karman_coefficient() * (l0 / r0).powf(5.0 / 3.0)
}

/// Fried parameter at `wavelength` (m) from its value `r0_500` at 500 nm: `r0 ∝ lambda^(6/5)`.
pub fn r0_at_wavelength(r0_500: f64, wavelength: f64) -> f64 {
    r0_500 * (wavelength / R0_WAVELENGTH).powf(1.2)
}

/// Combined PSSN of several independent small errors: the product of their PSSNs (the
/// small-error property of PSSN, accurate while each deficit is small).
pub fn pssn_small_error(pssn: &[f64]) -> f64 {
    pssn.iter().product()
}

/// The segmented pupil sampled on a square grid of `N x N` points.
///
/// The grid spans the bounding square of the hexagon corners, `[-h, h]^2` with
/// `h = max(|x|, |y|)` over all corners, cut into `N x N` cells of side `dx = 2 h / N`; sample
/// `(ix, iy)` sits at the cell centre `(x0 + ix dx, x0 + iy dx)`, `x0 = -h + dx / 2`, and has
/// the flat index `iy N + ix` (rows along `x`). A sample belongs to segment `i` when it lies in
/// the hexagon's 6 half-planes (circumradius `a`; samples in the gaps belong to none; on a
/// shared boundary, the lower segment index wins).
#[derive(Debug, Clone, PartialEq)]
pub struct PupilGrid {
    samples: usize,
    spacing: f64,
    origin: f64,
    centers: Vec<[f64; 2]>,
    segment: Vec<Option<u32>>,
    n_inside: usize,
}

impl PupilGrid {
    /// Default number of samples across the aperture.
    pub const DEFAULT_SAMPLES: usize = 256;

    /// Samples the pupil of `layout` with `samples` points across (at least 2).
    pub fn new(layout: &Layout, samples: usize) -> Result<PupilGrid, M1Error> {
        if samples < 2 {
            return Err(M1Error::InvalidParameter {
                name: "samples",
                value: samples as f64,
                reason: "need at least 2 samples across the pupil",
            });
        }
        if layout.n_segments() >= u32::MAX as usize {
            return Err(M1Error::InvalidParameter {
                name: "n_segments",
                value: layout.n_segments() as f64,
                reason: "too many segments",
            });
        }
        let a = layout.circumradius;
        let half = (0..layout.n_segments())
            .filter_map(|i| layout.vertices(i))
            .flatten()
            .map(|v| v[0].abs().max(v[1].abs()))
            .fold(0.0, f64::max);
        let dx = 2.0 * half / samples as f64;
        let origin = -half + 0.5 * dx;
        let apothem = 0.5 * 3.0_f64.sqrt() * a;
        let normals: [[f64; 2]; 3] = std::array::from_fn(|k| {
            let t = (60.0 * k as f64).to_radians();
            [t.cos(), t.sin()]
        });
        let index_range = |c: f64| {
            let lo = ((c - a - origin) / dx).ceil().max(0.0) as usize;
            let hi = (((c + a - origin) / dx).floor().max(-1.0) + 1.0) as usize;
            lo..hi.min(samples)
        };
        let mut segment = vec![None; samples * samples];
        let mut n_inside = 0;
        for (i, s) in layout.segments.iter().enumerate() {
            let [cx, cy] = s.center;
            for iy in index_range(cy) {
                let ry = origin + iy as f64 * dx - cy;
                for ix in index_range(cx) {
                    let rx = origin + ix as f64 * dx - cx;
                    let inside = normals
                        .iter()
                        .all(|n| (rx * n[0] + ry * n[1]).abs() <= apothem);
                    let slot = &mut segment[iy * samples + ix];
                    if inside && slot.is_none() {
                        *slot = Some(i as u32);
                        n_inside += 1;
                    }
                }
            }
        }
        Ok(PupilGrid {
            samples,
            spacing: dx,
            origin,
            centers: layout.segments.iter().map(|s| s.center).collect(),
            segment,
            n_inside,
        })
    }

    /// Samples across, `N`.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// Sample spacing `dx` (m).
    pub fn spacing(&self) -> f64 {
        self.spacing
    }

    /// Coordinate (m) of sample column (or row) `k`: `x0 + k dx`.
    pub fn coordinate(&self, k: usize) -> f64 {
        self.origin + k as f64 * self.spacing
    }

    /// Number of segments of the layout.
    pub fn n_segments(&self) -> usize {
        self.centers.len()
    }

    /// Number of samples inside the segments.
    pub fn n_inside(&self) -> usize {
        self.n_inside
    }

    /// Segment of every sample (flat index `iy N + ix`), `None` outside the segments.
    pub fn segment_map(&self) -> &[Option<u32>] {
        &self.segment
    }

    /// Segment of sample `(ix, iy)`, if any.
    pub fn segment_at(&self, ix: usize, iy: usize) -> Option<usize> {
        if ix >= self.samples || iy >= self.samples {
            return None;
        }
        self.segment[iy * self.samples + ix].map(|i| i as usize)
    }

    /// Pupil mask (flat index `iy N + ix`).
    pub fn mask(&self) -> Vec<bool> {
        self.segment.iter().map(Option::is_some).collect()
    }

    /// Surface (m) on the grid of the segment state `ptt` (`[p, tx, ty]` per segment, see
    /// [`crate::aperture::zernike`]), zero outside the segments.
    pub fn surface_from_ptt(&self, ptt: &[[f64; 3]]) -> Result<Vec<f64>, M1Error> {
        check_ptt(ptt, self.n_segments())?;
        let n = self.samples;
        Ok(self
            .segment
            .iter()
            .enumerate()
            .map(|(flat, seg)| match seg {
                Some(i) => {
                    let i = *i as usize;
                    let [p, tx, ty] = ptt[i];
                    let x = self.coordinate(flat % n) - self.centers[i][0];
                    let y = self.coordinate(flat / n) - self.centers[i][1];
                    p + tx * x + ty * y
                }
                None => 0.0,
            })
            .collect())
    }
}

fn check_ptt(ptt: &[[f64; 3]], n: usize) -> Result<(), M1Error> {
    if ptt.len() == n {
        Ok(())
    } else {
        Err(M1Error::SizeMismatch {
            what: "segment piston/tip/tilt",
            expected: n,
            found: ptt.len(),
        })
    }
}

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

/// Buffers of one evaluation.
struct Workspace {
    /// `N x M`: the field rows, then their FFTs.
    field: Vec<Complex64>,
    /// `M x M`: the transposed spectrum, then the packed PSF rows and their inverse FFTs.
    spectrum: Vec<Complex64>,
    /// `rows x M`: the half OTF over the lags with non-negligible weight.
    otf: Vec<Complex64>,
    scratch: Vec<Complex64>,
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
    fft: Arc<dyn Fft<f64>>,
    ifft: Arc<dyn Fft<f64>>,
    /// `rows x M`: `exp(-D(r))`, doubled for the rows standing for their mirror image too.
    weights: Vec<f64>,
    pupil: Vec<PupilSample>,
    phase_per_metre: f64,
    denominator: f64,
    workspace: Mutex<Workspace>,
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
            .finish_non_exhaustive()
    }
}

impl Pssn {
    /// Builds the evaluator: pupil grid, FFT plans, buffers, OTF weights and the
    /// perfect-telescope denominator.
    pub fn new(layout: &Layout, params: PssnParams) -> Result<Pssn, M1Error> {
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

        let (weights, rows) = otf_weights(&params, size, grid.spacing);

        let mut planner = FftPlanner::<f64>::new();
        let fft = planner.plan_fft_forward(size);
        let ifft = planner.plan_fft_inverse(size);
        let mut pssn = Pssn {
            params,
            grid,
            size,
            rows,
            fft,
            ifft,
            weights,
            pupil,
            phase_per_metre: 4.0 * PI / params.wavelength,
            denominator: 1.0,
            workspace: Mutex::new(Workspace {
                field: Vec::new(),
                spectrum: Vec::new(),
                otf: Vec::new(),
                scratch: Vec::new(),
            }),
        };
        let mut ws = pssn.new_workspace();
        let denominator = pssn.weighted_otf_power(&mut ws, |_| 0.0);
        if !(denominator > 0.0 && denominator.is_finite()) {
            return Err(M1Error::InvalidParameter {
                name: "samples",
                value: n as f64,
                reason: "the perfect-telescope OTF has no weight",
            });
        }
        pssn.denominator = denominator;
        pssn.workspace = Mutex::new(ws);
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
        let k = self.phase_per_metre;
        Ok(self.with_workspace(|ws| {
            self.weighted_otf_power(ws, |s| {
                let [p, tx, ty] = ptt[s.segment];
                k * (p + tx * s.dx + ty * s.dy)
            })
        }) / self.denominator)
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
        let k = self.phase_per_metre;
        Ok(
            self.with_workspace(|ws| self.weighted_otf_power(ws, |s| k * surface[s.grid]))
                / self.denominator,
        )
    }

    fn new_workspace(&self) -> Workspace {
        let (n, m) = (self.grid.samples, self.size);
        let scratch = self
            .fft
            .get_inplace_scratch_len()
            .max(self.ifft.get_inplace_scratch_len());
        let zero = Complex64::new(0.0, 0.0);
        Workspace {
            field: vec![zero; n * m],
            spectrum: vec![zero; m * m],
            otf: vec![zero; self.rows * m],
            scratch: vec![zero; scratch],
        }
    }

    fn with_workspace<R>(&self, f: impl FnOnce(&mut Workspace) -> R) -> R {
        match self.workspace.try_lock() {
            Ok(mut guard) => f(&mut guard),
            Err(TryLockError::Poisoned(poisoned)) => f(&mut poisoned.into_inner()),
            Err(TryLockError::WouldBlock) => f(&mut self.new_workspace()),
        }
    }

    /// `sum_f exp(-D(f)) |OTF(f)|^2` for the pupil phase `phase(sample)` (rad), unnormalised.
    fn weighted_otf_power(&self, ws: &mut Workspace, phase: impl Fn(&PupilSample) -> f64) -> f64 {
        let (n, m) = (self.grid.samples, self.size);
        let half = m / 2;
        let zero = Complex64::new(0.0, 0.0);

        // Field on the N non-zero rows, FFT along x.
        ws.field.fill(zero);
        for s in &self.pupil {
            let (sin, cos) = phase(s).sin_cos();
            ws.field[s.field] = Complex64::new(cos, sin);
        }
        self.fft
            .process_with_scratch(&mut ws.field, &mut ws.scratch);

        // Transpose into the M x M spectrum (rows N..M of the field are zero), FFT along y.
        const BLOCK: usize = 32;
        for c0 in (0..m).step_by(BLOCK) {
            for r0 in (0..n).step_by(BLOCK) {
                for c in c0..(c0 + BLOCK).min(m) {
                    let r1 = (r0 + BLOCK).min(n);
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
        self.fft
            .process_with_scratch(&mut ws.spectrum, &mut ws.scratch);

        // PSF rows 2t and 2t+1 packed as the real and imaginary parts of row t.
        for k in 0..m {
            let (a, b) = (ws.spectrum[k].norm_sqr(), ws.spectrum[m + k].norm_sqr());
            ws.spectrum[k] = Complex64::new(a, b);
        }
        for t in 1..half {
            let (lo, hi) = ws.spectrum.split_at_mut(2 * t * m);
            let dst = &mut lo[t * m..(t + 1) * m];
            let (ra, rb) = hi[..2 * m].split_at(m);
            for ((d, a), b) in dst.iter_mut().zip(ra).zip(rb) {
                *d = Complex64::new(a.norm_sqr(), b.norm_sqr());
            }
        }
        self.ifft
            .process_with_scratch(&mut ws.spectrum[..half * m], &mut ws.scratch);

        // Unpack the two real rows' (Hermitian) transforms and transpose: otf[y'][kx].
        const PAIRS: usize = 8;
        for t0 in (0..half).step_by(PAIRS) {
            let t1 = (t0 + PAIRS).min(half);
            for y in 0..self.rows {
                let ym = (m - y) % m;
                let out = &mut ws.otf[y * m..(y + 1) * m];
                for t in t0..t1 {
                    let z = ws.spectrum[t * m + y];
                    let zc = ws.spectrum[t * m + ym].conj();
                    let (s, d) = (z + zc, z - zc);
                    out[2 * t] = Complex64::new(0.5 * s.re, 0.5 * s.im);
                    out[2 * t + 1] = Complex64::new(0.5 * d.im, -0.5 * d.re);
                }
            }
        }
        self.ifft.process_with_scratch(&mut ws.otf, &mut ws.scratch);

        ws.otf
            .iter()
            .zip(&self.weights)
            .map(|(o, w)| w * o.norm_sqr())
            .sum()
    }
}

/// Weight of the OTF sample at the lag `(i, j) dx`: the integral of `exp(-D(r))` against the
/// bilinear hat function of that sample, `int exp(-D(dx (i + s, j + t))) (1 - |s|)(1 - |t|)
/// ds dt` over `[-1, 1]^2` (8 x 8 Gauss–Legendre points per quadrant), within
/// `3 r0 + 2 dx` of the origin, where `exp(-D)` changes on the scale of a sample; the point value
/// `exp(-D(r))` beyond. This product integration makes the weighted sum exact for an OTF that
/// is bilinear between samples instead of constant around each, so the PSSN deficit stays
/// accurate when `dx` approaches `r0` (the point-sampled weight puts nearly all the weight on
/// the error-blind zero lag then).
#[derive(Debug, Clone)]
struct LagWeight {
    dx: f64,
    r0: f64,
    l0: f64,
    r_smooth: f64,
    /// Gauss–Legendre nodes on [0, 1] and their weights times the hat `1 - s`.
    rule: Vec<(f64, f64)>,
}

impl LagWeight {
    fn new(dx: f64, r0: f64, l0: f64) -> LagWeight {
        let (x, w) = crate::aperture::zernike::gauss_legendre(8);
        let rule = x
            .iter()
            .zip(&w)
            .map(|(&x, &w)| {
                let s = 0.5 * (1.0 + x);
                (s, 0.5 * w * (1.0 - s))
            })
            .collect();
        LagWeight {
            dx,
            r0,
            l0,
            r_smooth: 3.0 * r0 + 2.0 * dx,
            rule,
        }
    }

    fn point(&self, r: f64) -> f64 {
        (-phase_structure_function(r, self.r0, self.l0)).exp()
    }

    /// Weight of the lag `(i, j)` samples, relative to `dx^2` (1 for `D = 0`).
    fn at(&self, i: f64, j: f64) -> f64 {
        let r = self.dx * i.hypot(j);
        if r >= self.r_smooth {
            return self.point(r);
        }
        let mut sum = 0.0;
        for &(s, ws) in &self.rule {
            for &(t, wt) in &self.rule {
                for (si, tj) in [(s, t), (-s, t), (s, -t), (-s, -t)] {
                    sum += ws * wt * self.point(self.dx * (i + si).hypot(j + tj));
                }
            }
        }
        sum
    }
}

/// OTF weights ([`LagWeight`]) on the half lag plane `y' = 0..=M/2` (rows) x `x' = 0..M`, lag
/// `(wrap(x'), y') dx`, doubled for `0 < y' < M/2` (the rows standing for their mirror image);
/// weights below [`WEIGHT_FLOOR`] set to zero and the trailing zero rows dropped.
/// Returns `(weights, rows)`.
fn otf_weights(params: &PssnParams, m: usize, dx: f64) -> (Vec<f64>, usize) {
    let r0 = r0_at_wavelength(params.r0, params.wavelength);
    let l0 = params.l0;
    let d = |r: f64| phase_structure_function(r, r0, l0);
    let threshold = -WEIGHT_FLOOR.ln();
    // D is increasing in r: find the lag beyond which exp(-D) < WEIGHT_FLOOR; the hat weights
    // reach one sample further.
    let r_max = dx * m as f64;
    let r_cut = if d(r_max) <= threshold {
        f64::INFINITY
    } else {
        let (mut lo, mut hi) = (0.0, r_max);
        for _ in 0..80 {
            let mid = 0.5 * (lo + hi);
            if d(mid) > threshold {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        hi + 1.5 * dx
    };
    let half = m / 2;
    let rows = if r_cut.is_finite() {
        ((r_cut / dx).floor() as usize + 1).min(half + 1)
    } else {
        half + 1
    };
    let lag = LagWeight::new(dx, r0, l0);
    let mut weights = vec![0.0; rows * m];
    for y in 0..rows {
        let factor = if y == 0 || y == half { 1.0 } else { 2.0 };
        for x in 0..m {
            let xw = if x > half { m - x } else { x };
            let r = dx * ((xw * xw + y * y) as f64).sqrt();
            if r <= r_cut {
                let w = lag.at(xw as f64, y as f64);
                if w >= WEIGHT_FLOOR {
                    weights[y * m + x] = factor * w;
                }
            }
        }
    }
    (weights, rows)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;
    use rustfft::FftPlanner;

    /// Direct computation (full complex 2-D FFTs, all lags) of the weighted OTF power, to check
    /// the packed fast path.
    fn reference(pssn: &Pssn, surface: &[f64]) -> f64 {
        let (n, m) = (pssn.grid.samples, pssn.size);
        let mut planner = FftPlanner::<f64>::new();
        let fwd = planner.plan_fft_forward(m);
        let inv = planner.plan_fft_inverse(m);
        let fft2 = |buf: &mut Vec<Complex64>, f: &Arc<dyn Fft<f64>>| {
            f.process(buf);
            let mut t = vec![Complex64::new(0.0, 0.0); m * m];
            for r in 0..m {
                for c in 0..m {
                    t[c * m + r] = buf[r * m + c];
                }
            }
            f.process(&mut t);
            *buf = t; // transposed: fine for isotropic weights
        };
        let mut e = vec![Complex64::new(0.0, 0.0); m * m];
        let k = pssn.phase_per_metre;
        for iy in 0..n {
            for ix in 0..n {
                if pssn.grid.segment[iy * n + ix].is_some() {
                    let (s, c) = (k * surface[iy * n + ix]).sin_cos();
                    e[iy * m + ix] = Complex64::new(c, s);
                }
            }
        }
        fft2(&mut e, &fwd);
        let mut p: Vec<Complex64> = e
            .iter()
            .map(|z| Complex64::new(z.norm_sqr(), 0.0))
            .collect();
        fft2(&mut p, &inv);
        let lag = LagWeight::new(pssn.grid.spacing, pssn.r0(), pssn.params.l0);
        let mut sum = 0.0;
        for y in 0..m {
            for x in 0..m {
                let xw = x.min(m - x) as f64;
                let yw = y.min(m - y) as f64;
                sum += lag.at(xw, yw) * p[y * m + x].norm_sqr();
            }
        }
        sum
    }

    #[test]
    fn fast_path_matches_direct_computation() {
        let layout = Layout::keck();
        let params = PssnParams {
            samples: 48,
            wavelength: 1.0e-6,
            r0: 0.2,
            l0: 30.0,
            pad_factor: 2,
        };
        let pssn = Pssn::new(&layout, params).unwrap();
        let n = pssn.grid.samples;
        let surface: Vec<f64> = (0..n * n)
            .map(|i| 40e-9 * ((i as f64 * 0.37).sin() + (i as f64 * 0.011).cos()))
            .collect();
        let fast = pssn.with_workspace(|ws| {
            let k = pssn.phase_per_metre;
            pssn.weighted_otf_power(ws, |s| k * surface[s.grid])
        });
        let direct = reference(&pssn, &surface);
        assert!(
            ((fast - direct) / direct).abs() < 1e-10,
            "fast {fast} direct {direct}"
        );
    }
}
