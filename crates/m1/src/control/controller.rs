//! The global edge-sensor control loop: the reconstructor with global piston/tip/tilt projected
//! out, a modal decomposition into four orthogonal mode groups and one discrete integrator per
//! group, sampled at the loop rate (default 20 Hz) with the command held between samples.
//!
//! # Control law
//!
//! With $A$ ($n_s \times n_a$) the interaction matrix, $B_0$ its reconstructor with global
//! piston/tip/tilt (the columns of $N$) projected out ([`crate::control::reconstructor`]:
//! $B_0 A P = P$, $P = I - N N^T$), the readings $y$ and their set-point $y_{ref}$, sample $k$
//! updates the actuator command by
//!
//! $$u_{k+1} = u_k - G\,P\,B_0\,(y_k - y_{ref,k}),$$
//! $$G = g\,(P - \psi_f\psi_f^T - R_2 R_2^T - R_{34} R_{34}^T) + g_{34}\,R_{34} R_{34}^T +
//!   g_2\,R_2 R_2^T + \Gamma g_f\,\psi_f\psi_f^T .$$
//!
//! Sign convention: the reading of a displacement $z$ is $A z$; the loop drives the mirror to
//! the state whose readings equal $y_{ref}$, so with a perfect plant ($z = u + d$, $d$ a static
//! disturbance) the error $e = u + d$ (observable part) obeys $e_{k+1} = (I - G) e_k$ exactly.
//! The mode groups are orthogonal projections that add up to $P$, so on each group the loop is
//! exactly a first-order discrete integrator, decaying by $(1 - g_{group})$ per sample (the seed
//! paper's baseline tuning, its Figure 11, is the default):
//!
//! - **focus-mode** $\psi_f$: the least observable mode of $A$ ([`Nominal::focus`], unit norm,
//!   orthogonal to $N$), gain $\Gamma g_f$ with $\Gamma$ the reconstructor's modal gain on
//!   focus-mode (the seed paper's $\Gamma$, `focus_gain`) and $g_f$ from `bandwidth_focus`
//!   (0.1 Hz);
//! - **radial degree 2** $R_2$ (two orthonormal columns): the span of the Zernike modes
//!   $Z_4, Z_5, Z_6$ projected on the segments' piston/tip/tilt ([`crate::aperture::zernike`]), as
//!   actuator displacements, with $N$ projected out, minus the direction of that span closest to
//!   focus-mode (focus-mode is almost exactly $Z_4$ and has its own group). What remains is
//!   astigmatism, and is exactly orthogonal to $\psi_f$; gain $g_2$ from `bandwidth_radial2`
//!   (0.75 Hz);
//! - **radial degrees 3 and 4** $R_{34}$ (nine orthonormal columns): the span of $Z_7$ to
//!   $Z_{15}$ projected the same way, with $N$, the whole radial-degree-2 span ($Z_4, Z_5, Z_6$)
//!   and focus-mode projected out; gain $g_{34}$ from `bandwidth_radial34` (1 Hz);
//! - **every other observable mode** (radial degrees 5 and up), gain $g$ from `bandwidth`
//!   (1.5 Hz).
//!
//! $u$ never holds global piston/tip/tilt: $P$ is applied to every update (it starts at 0).
//!
//! # Bandwidth and integrator gain
//!
//! A group with closed-loop bandwidth $f_{bw}$ (Hz) at the loop rate $f_s$ gets
//!
//! $$g = 1 - e^{-2\pi f_{bw}/f_s},$$
//!
//! which matches the discrete pole $1 - g$ to the continuous first-order loop
//! $e(t) = e^{-2\pi f_{bw} t}$ (time constant $1/(2\pi f_{bw})$). At 20 Hz: 1.5 Hz gives
//! $g = 0.3758$; 1 Hz: 0.2696; 0.75 Hz: 0.2099; 0.1 Hz: 0.0309. $f_{bw} = 0$ opens the loop on
//! that group; bandwidths must stay below $f_s/2$.
//!
//! # Sampling
//!
//! The loop samples at its own instants $t_k = t_0 + k/f_s$, $k \ge 1$, whatever the
//! communication step ([`SampleClock`]). A communication step $(t, t + h]$ takes every sample
//! instant in it (an instant within $10^{-9}\max(1, |t|)$ s of $t + h$ belongs to this step),
//! each with the readings held over the step (the values set at $t$), so $u$ at a communication
//! point equal to $t_k$ already shows $u_k$, and $u$ never depends directly on $y$: no algebraic
//! loop in a closed loop sensors -> controller -> segments. With a plant that responds to $u$
//! only at sample instants (the perfect plant of the tests) any communication step gives the
//! same $u_k$.

use faer::{Mat, MatRef};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::aperture::zernike::ZernikeBasis;
use crate::control::nominal::Nominal;
use crate::control::reconstructor::orthonormalize;

/// Default loop sample rate (Hz).
pub const DEFAULT_RATE: f64 = 20.0;
/// Default closed-loop bandwidth of the modes of radial degree 5 and up (Hz).
pub const DEFAULT_BANDWIDTH: f64 = 1.5;
/// Default bandwidth of the radial-degree-3-4 group (Hz).
pub const DEFAULT_BANDWIDTH_RADIAL34: f64 = 1.0;
/// Default bandwidth of the radial-degree-2 group (astigmatism) (Hz).
pub const DEFAULT_BANDWIDTH_RADIAL2: f64 = 0.75;
/// Default bandwidth of focus-mode (Hz, *assumed*).
pub const DEFAULT_BANDWIDTH_FOCUS: f64 = 0.1;
/// Default modal gain $\Gamma$ on focus-mode (1: the focus-mode loop is set by its bandwidth
/// alone; the paper's reduction by 4 is `focus_gain = 0.25` with all bandwidths equal).
pub const DEFAULT_FOCUS_GAIN: f64 = 1.0;
/// Relative time tolerance of sample instants (an instant within `TIME_TOLERANCE x max(1, |t|)`
/// seconds of a communication point is at that point).
pub const TIME_TOLERANCE: f64 = 1e-9;

/// Noll indices of the radial-degree-2 Zernike modes (focus, astigmatism x2).
const RADIAL2_NOLL: [usize; 3] = [4, 5, 6];
/// Number of modes of the radial-degree-3-4 group.
pub const N_RADIAL34: usize = 9;
/// Noll indices of the Zernike modes of radial degrees 3 and 4 (coma, trefoil, spherical,
/// secondary astigmatism, quadrafoil): Z7 to Z15.
const RADIAL34_NOLL: std::ops::RangeInclusive<usize> = 7..=6 + N_RADIAL34;
/// A Zernike mode whose part outside global piston/tip/tilt and the lower modes is below this
/// fraction of its norm (as actuator displacements) is taken as degenerate on the aperture.
const DEGENERATE: f64 = 1e-6;

/// Integrator gain of a first-order discrete loop with closed-loop bandwidth `bandwidth` (Hz)
/// sampled at `rate` (Hz): $g = 1 - e^{-2\pi f_{bw}/f_s}$.
pub fn integrator_gain(bandwidth: f64, rate: f64) -> f64 {
    1.0 - (-std::f64::consts::TAU * bandwidth / rate).exp()
}

/// The tunables of the global loop.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ControllerParams {
    /// Loop sample rate (Hz) (default: 20).
    pub rate: f64,
    /// Bandwidth of every mode outside the three groups below, radial degrees 5 and up (Hz)
    /// (default: 1.5).
    pub bandwidth: f64,
    /// Bandwidth of the radial-degree-3-4 group, Z7 to Z15 (Hz) (default: 1).
    pub bandwidth_radial34: f64,
    /// Bandwidth of the radial-degree-2 group, astigmatism (Hz) (default: 0.75).
    pub bandwidth_radial2: f64,
    /// Bandwidth of focus-mode (Hz) (default: 0.1).
    pub bandwidth_focus: f64,
    /// Modal gain $\Gamma$ of the reconstructor on focus-mode, in [0, 1] (default: 1).
    pub focus_gain: f64,
}

impl Default for ControllerParams {
    fn default() -> Self {
        Self {
            rate: DEFAULT_RATE,
            bandwidth: DEFAULT_BANDWIDTH,
            bandwidth_radial34: DEFAULT_BANDWIDTH_RADIAL34,
            bandwidth_radial2: DEFAULT_BANDWIDTH_RADIAL2,
            bandwidth_focus: DEFAULT_BANDWIDTH_FOCUS,
            focus_gain: DEFAULT_FOCUS_GAIN,
        }
    }
}

fn invalid(name: &'static str, value: f64, reason: &'static str) -> M1Error {
    M1Error::InvalidParameter {
        name,
        value,
        reason,
    }
}

impl ControllerParams {
    /// Checks the values and returns the integrator gains per group.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming the parameter: `rate` must be finite and > 0, each
    /// bandwidth finite, >= 0 and below `rate / 2`, `focus_gain` in [0, 1].
    pub fn gains(&self) -> Result<LoopGains, M1Error> {
        if !(self.rate.is_finite() && self.rate > 0.0) {
            return Err(invalid("rate", self.rate, "must be finite and > 0 Hz"));
        }
        for (name, f) in [
            ("bandwidth", self.bandwidth),
            ("bandwidth_radial34", self.bandwidth_radial34),
            ("bandwidth_radial2", self.bandwidth_radial2),
            ("bandwidth_focus", self.bandwidth_focus),
        ] {
            if !(f.is_finite() && f >= 0.0) {
                return Err(invalid(name, f, "must be finite and >= 0 Hz"));
            }
            if f >= 0.5 * self.rate {
                return Err(invalid(
                    name,
                    f,
                    "must be below half the loop rate (the Nyquist frequency of `rate`)",
                ));
            }
        }
        if !(0.0..=1.0).contains(&self.focus_gain) {
            return Err(invalid("focus_gain", self.focus_gain, "must be in [0, 1]"));
        }
        Ok(LoopGains {
            rest: integrator_gain(self.bandwidth, self.rate),
            radial34: integrator_gain(self.bandwidth_radial34, self.rate),
            radial2: integrator_gain(self.bandwidth_radial2, self.rate),
            focus: self.focus_gain * integrator_gain(self.bandwidth_focus, self.rate),
        })
    }
}

/// Integrator gains per sample of the four mode groups (each in [0, 1)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopGains {
    /// Every mode outside the three groups below (radial degrees 5 and up).
    pub rest: f64,
    /// Radial degrees 3 and 4 (Z7 to Z15).
    pub radial34: f64,
    /// Radial degree 2 without focus-mode (astigmatism).
    pub radial2: f64,
    /// Focus-mode (already multiplied by the modal gain $\Gamma$).
    pub focus: f64,
}

/// Sample instants $t_k = t_0 + k/f_s$ of a sampled subsystem and the latest one taken.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SampleClock {
    start: f64,
    rate: f64,
    last: u64,
}

impl SampleClock {
    /// A clock of `rate` (Hz) started at `start` (s), whose latest sample is instant 0 (`start`).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] unless `rate` is finite and > 0 and `start` finite.
    pub fn new(start: f64, rate: f64) -> Result<Self, M1Error> {
        if !(rate.is_finite() && rate > 0.0) {
            return Err(invalid("rate", rate, "must be finite and > 0 Hz"));
        }
        if !start.is_finite() {
            return Err(invalid("start_time", start, "must be finite"));
        }
        Ok(Self {
            start,
            rate,
            last: 0,
        })
    }

    /// The instant of sample `k` (s).
    pub fn instant(&self, k: u64) -> f64 {
        self.start + k as f64 / self.rate
    }

    /// The sample rate (Hz).
    pub fn rate(&self) -> f64 {
        self.rate
    }

    /// Index of the latest sample taken.
    pub fn last(&self) -> u64 {
        self.last
    }

    fn tolerance(t: f64) -> f64 {
        TIME_TOLERANCE * t.abs().max(1.0)
    }

    /// Whether the instant of sample `k` is `t` (within the time tolerance).
    pub fn is_at(&self, k: u64, t: f64) -> bool {
        (self.instant(k) - t).abs() <= Self::tolerance(t)
    }

    /// Index of the latest sample instant at or before `t` (within the tolerance); 0 before
    /// the start.
    pub fn latest_at(&self, t: f64) -> u64 {
        let tol = Self::tolerance(t);
        let x = ((t - self.start) * self.rate).floor();
        if !(x.is_finite() && x > 0.0) {
            return u64::from(self.instant(1) <= t + tol);
        }
        let mut k = x as u64;
        if self.instant(k + 1) <= t + tol {
            k += 1;
        } else if k > 0 && self.instant(k) > t + tol {
            k -= 1;
        }
        k
    }

    /// Moves on to `t`: returns the indices of the sample instants in `(last instant, t]` (to
    /// the tolerance), now taken; empty if there are none.
    pub fn advance_to(&mut self, t: f64) -> std::ops::Range<u64> {
        let k = self.latest_at(t).max(self.last);
        let new = self.last + 1..k + 1;
        self.last = k;
        new
    }
}

/// The modal basis and reconstructor of the global loop for one geometry (see the
/// [module documentation](self)). Built once; shared by instances.
pub struct ControlModes {
    nominal: Nominal,
    radial2: [Vec<f64>; 2],
    radial34: Vec<Vec<f64>>,
    focus_z4_correlation: f64,
}

/// Buffers for one controller sample, allocated once ([`ControlModes::scratch`]).
#[derive(Debug, Clone, Default)]
pub struct Scratch {
    error: Vec<f64>,
    estimate: Vec<f64>,
    work: Vec<f64>,
}

/// The dynamic state of the loop: the held command and the sample clock.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ControllerState {
    /// The actuator command held since the latest sample (m, length n_a).
    pub u: Vec<f64>,
    /// The loop's sample instants.
    pub clock: SampleClock,
}

impl ControllerState {
    /// Zero command, clock started at `start` (s) at `rate` (Hz).
    ///
    /// # Errors
    /// As [`SampleClock::new`].
    pub fn new(na: usize, start: f64, rate: f64) -> Result<Self, M1Error> {
        Ok(Self {
            u: vec![0.0; na],
            clock: SampleClock::new(start, rate)?,
        })
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn axpy(alpha: f64, x: &[f64], y: &mut [f64]) {
    for (yi, xi) in y.iter_mut().zip(x) {
        *yi += alpha * xi;
    }
}

/// Actuator displacements (length 3N) of a segment state `[p, tx, ty]` per segment (surface
/// slopes in the aperture plane): $z_k = p + t_x (a_{k,x} - c_x) + t_y (a_{k,y} - c_y)$.
fn actuator_displacements(geometry: &Geometry, ptt: &[[f64; 3]]) -> Vec<f64> {
    let mut z = vec![0.0; geometry.n_actuators()];
    for (i, (f, s)) in geometry.segments.iter().zip(ptt).enumerate() {
        for (k, a) in f.actuators.iter().enumerate() {
            z[3 * i + k] = s[0] + s[1] * (a[0] - f.centre[0]) + s[2] * (a[1] - f.centre[1]);
        }
    }
    z
}

impl ControlModes {
    /// Builds A, the reconstructor, focus-mode and the radial-degree-2 and 3-4 groups of
    /// `geometry`.
    ///
    /// # Errors
    /// From [`Nominal::new`] and [`ZernikeBasis::new`] (Z1 to Z15 must be independent on the
    /// segments' piston/tip/tilt); [`M1Error::Numerical`] if a Zernike mode of radial degree 2
    /// to 4 is degenerate with global piston/tip/tilt and the lower modes on this aperture.
    pub fn new(geometry: Geometry) -> Result<Self, M1Error> {
        let last = *RADIAL34_NOLL.end();
        let zern = ZernikeBasis::new(&geometry.layout, last)?;
        let nominal = Nominal::new(geometry)?;
        let g = &nominal.geometry;
        let na = g.n_actuators();
        let null = nominal.b0.null_space();
        let k = null.ncols();
        // [N | Z4 Z5 Z6 | Z7 .. Z15], orthonormalised (Gram-Schmidt, column by column): columns
        // k..k+3 are the radial-2 span with global piston/tip/tilt removed, the last nine the
        // radial-3-4 span with N and the whole radial-2 span removed.
        let noll: Vec<usize> = RADIAL2_NOLL.iter().copied().chain(RADIAL34_NOLL).collect();
        let mut m = Mat::<f64>::zeros(na, k + noll.len());
        for c in 0..k {
            for r in 0..na {
                m[(r, c)] = null[(r, c)];
            }
        }
        for (c, &j) in noll.iter().enumerate() {
            let mode = zern
                .mode(j)
                .ok_or_else(|| M1Error::Numerical(format!("Zernike mode {j} missing")))?;
            let z = actuator_displacements(g, &mode);
            for r in 0..na {
                m[(r, k + c)] = z[r];
            }
        }
        let q = orthonormalize(m.as_ref());
        let col = |c: usize| -> Vec<f64> { (0..na).map(|r| q[(r, c)]).collect() };
        // Gram-Schmidt leaves each column's part outside the previous ones as q_c . m_c.
        for (c, &j) in noll.iter().enumerate() {
            let mc: Vec<f64> = (0..na).map(|r| m[(r, k + c)]).collect();
            let qc = col(k + c);
            let residual = dot(&qc, &mc).abs();
            let n = dot(&mc, &mc).sqrt();
            if !(residual > DEGENERATE * n && (dot(&qc, &qc).sqrt() - 1.0).abs() < 1e-6) {
                return Err(M1Error::Numerical(format!(
                    "the Zernike mode Z{j} is degenerate with global piston/tip/tilt and the \
                     lower modes on this aperture"
                )));
            }
        }
        let span: Vec<Vec<f64>> = (0..3).map(|c| col(k + c)).collect();
        // Coordinates of focus-mode in the span; the 2-D complement of that direction in R^3
        // (Gram-Schmidt on the two unit vectors least aligned with it) maps to two orthonormal
        // modes of the span, exactly orthogonal to focus-mode.
        let focus = &nominal.focus;
        let c: [f64; 3] = std::array::from_fn(|i| dot(&span[i], focus));
        let cn = dot(&c, &c).sqrt();
        if cn == 0.0 {
            return Err(M1Error::Numerical(
                "focus-mode is orthogonal to the radial-degree-2 Zernike modes".into(),
            ));
        }
        let c = c.map(|x| x / cn);
        let closest = (0..3)
            .max_by(|&a, &b| c[a].abs().total_cmp(&c[b].abs()))
            .unwrap_or(0);
        let mut basis: Vec<[f64; 3]> = Vec::with_capacity(2);
        for i in (0..3).filter(|&i| i != closest) {
            let mut e = [0.0; 3];
            e[i] = 1.0;
            for _ in 0..2 {
                let d = dot(&e, &c);
                e.iter_mut().zip(&c).for_each(|(x, y)| *x -= d * y);
                for b in &basis {
                    let d = dot(&e, b);
                    e.iter_mut().zip(b).for_each(|(x, y)| *x -= d * y);
                }
            }
            let n = dot(&e, &e).sqrt();
            basis.push(e.map(|x| x / n));
        }
        let radial2: [Vec<f64>; 2] = std::array::from_fn(|b| {
            let mut r = vec![0.0; na];
            for (i, s) in span.iter().enumerate() {
                axpy(basis[b][i], s, &mut r);
            }
            r
        });
        // Radial degrees 3-4: the radial-3-4 span with focus-mode projected out too (focus-mode
        // is orthogonal to N only to round-off, so N, astigmatism, focus-mode and the previous
        // columns are projected out twice, sequentially), orthonormalised.
        let mut radial34: Vec<Vec<f64>> = Vec::with_capacity(N_RADIAL34);
        for c in 0..N_RADIAL34 {
            let mut v = col(k + 3 + c);
            for _ in 0..2 {
                for i in 0..k {
                    let d: f64 = (0..na).map(|r| null[(r, i)] * v[r]).sum();
                    v.iter_mut()
                        .enumerate()
                        .for_each(|(r, x)| *x -= d * null[(r, i)]);
                }
                for b in radial2
                    .iter()
                    .chain(std::iter::once(focus))
                    .chain(&radial34)
                {
                    let d = dot(&v, b);
                    axpy(-d, b, &mut v);
                }
            }
            let n = dot(&v, &v).sqrt();
            if n.is_nan() || n <= DEGENERATE {
                return Err(M1Error::Numerical(
                    "focus-mode lies in the span of the radial-degree-3-4 Zernike modes".into(),
                ));
            }
            v.iter_mut().for_each(|x| *x /= n);
            radial34.push(v);
        }
        // span[0] is Z4 with global piston/tip/tilt removed, unit norm.
        let focus_z4_correlation = dot(&span[0], focus).abs();
        Ok(Self {
            nominal,
            radial2,
            radial34,
            focus_z4_correlation,
        })
    }

    /// A, the reconstructor $B_0$, focus-mode and the geometry.
    pub fn nominal(&self) -> &Nominal {
        &self.nominal
    }

    /// Focus-mode (unit norm, orthogonal to global piston/tip/tilt).
    pub fn focus(&self) -> &[f64] {
        &self.nominal.focus
    }

    /// The two orthonormal modes of the radial-degree-2 group (astigmatism), orthogonal to
    /// focus-mode and to global piston/tip/tilt.
    pub fn radial2(&self) -> &[Vec<f64>; 2] {
        &self.radial2
    }

    /// The nine orthonormal modes of the radial-degree-3-4 group (the span of Z7 to Z15),
    /// orthogonal to global piston/tip/tilt, to the whole radial-degree-2 span (astigmatism
    /// included) and to focus-mode.
    pub fn radial34(&self) -> &[Vec<f64>] {
        &self.radial34
    }

    /// Global piston/tip/tilt (orthonormal columns), never commanded.
    pub fn null_space(&self) -> MatRef<'_, f64> {
        self.nominal.b0.null_space()
    }

    /// |cos| of the angle between $Z_4$ (global piston/tip/tilt removed) and focus-mode.
    pub fn focus_z4_correlation(&self) -> f64 {
        self.focus_z4_correlation
    }

    /// Number of actuators and sensors `(n_a, n_s)`.
    pub fn shape(&self) -> (usize, usize) {
        self.nominal.b0.shape()
    }

    /// Buffers for [`Self::sample`] and [`Self::advance`].
    pub fn scratch(&self) -> Scratch {
        let (na, ns) = self.shape();
        Scratch {
            error: vec![0.0; ns],
            estimate: vec![0.0; na],
            work: vec![0.0; self.nominal.b0.work_len()],
        }
    }

    fn check_lengths(&self, u: usize, y: usize, y_ref: usize, s: &Scratch) -> Result<(), M1Error> {
        let (na, ns) = self.shape();
        for (what, expected, found) in [
            ("command u", na, u),
            ("readings y", ns, y),
            ("set-point y_ref", ns, y_ref),
            ("scratch error", ns, s.error.len()),
            ("scratch estimate", na, s.estimate.len()),
            ("scratch work", self.nominal.b0.work_len(), s.work.len()),
        ] {
            if expected != found {
                return Err(M1Error::SizeMismatch {
                    what,
                    expected,
                    found,
                });
            }
        }
        Ok(())
    }

    /// One sample of the loop: $u \leftarrow u - G P B_0 (y - y_{ref})$, without allocating.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] if a slice or the scratch has the wrong length.
    pub fn sample(
        &self,
        gains: &LoopGains,
        u: &mut [f64],
        y: &[f64],
        y_ref: &[f64],
        s: &mut Scratch,
    ) -> Result<(), M1Error> {
        self.check_lengths(u.len(), y.len(), y_ref.len(), s)?;
        for ((e, a), b) in s.error.iter_mut().zip(y).zip(y_ref) {
            *e = a - b;
        }
        self.nominal
            .b0
            .apply_into(&s.error, &mut s.estimate, &mut s.work);
        let x = &mut s.estimate;
        let null = self.null_space();
        for c in 0..null.ncols() {
            let col = null.col(c);
            let d: f64 = x.iter().enumerate().map(|(i, v)| col[i] * v).sum();
            x.iter_mut().enumerate().for_each(|(i, v)| *v -= d * col[i]);
        }
        // G x = g x + sum over the groups of (g_group - g)(v . x) v, v the group's orthonormal
        // modes (x is not changed, so each coefficient is taken just before its update).
        let rest = gains.rest;
        axpy(-rest, x, u);
        let groups = std::iter::once((gains.focus, &self.nominal.focus))
            .chain(self.radial2.iter().map(|v| (gains.radial2, v)))
            .chain(self.radial34.iter().map(|v| (gains.radial34, v)));
        for (g, v) in groups {
            let c = (g - rest) * dot(v, x);
            axpy(-c, v, u);
        }
        Ok(())
    }

    /// Advances the loop to `t_end` (s): one [`Self::sample`] per sample instant in
    /// `(latest sample, t_end]`, each with the readings `y`, `y_ref` held; with `enabled` false
    /// the instants pass and `u` is held. Returns the number of sample instants passed.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] if a slice or the scratch has the wrong length (nothing is
    /// changed then).
    #[allow(clippy::too_many_arguments)]
    pub fn advance(
        &self,
        gains: &LoopGains,
        state: &mut ControllerState,
        enabled: bool,
        t_end: f64,
        y: &[f64],
        y_ref: &[f64],
        s: &mut Scratch,
    ) -> Result<u64, M1Error> {
        self.check_lengths(state.u.len(), y.len(), y_ref.len(), s)?;
        let new = state.clock.advance_to(t_end);
        let n = new.end - new.start;
        if enabled {
            for _ in new {
                self.sample(gains, &mut state.u, y, y_ref, s)?;
            }
        }
        Ok(n)
    }
}
