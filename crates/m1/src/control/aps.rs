//! The Alignment and Phasing System (APS) and the real-time optical feedback: the optical
//! measurements that set what the edge sensors cannot know by themselves.
//!
//! # APS
//!
//! Every few weeks (2-4 in TMT operation) the APS measures the piston, tip and tilt of every
//! segment optically, with its own error, and the control system resets the desired sensor
//! readings so that the measured error is removed: with `e` the measured error in actuator
//! space (global piston/tip/tilt removed: the APS measures the segments relative to each other)
//! and `A_0` the nominal A-matrix,
//!
//! ```text
//! y_ref <- y_ref - A_0 e.
//! ```
//!
//! The loop then moves the segments by `-e` (to first order in the A-matrix error).
//! [`Aps::measure`] draws the measurement error per segment, `N(0, piston_rms)` in piston and
//! `N(0, tilt_rms)` in each tilt (about the segment's radial and azimuthal axes), from a generator
//! seeded by `(seed, run)`.
//!
//! # Optical feedback
//!
//! Between APS runs an on-instrument wavefront sensor (or the AO system) measures the global
//! low-order modes that the edge sensors cannot see (global piston, tip and tilt) and,
//! optionally, focus-mode, which they see only weakly. [`OpticalFeedback`] integrates the
//! measured modal coefficients at its own bandwidth, `c <- c - g (m + noise)` with
//! `g = 1 - exp(-2 pi bandwidth dt)` per update of length `dt`, and returns the command:
//! global piston/tip/tilt as a direct low-order actuator command `u_lo = N c_ptt` (the edge
//! sensors do not see it, so the controller adds it to its output), focus-mode as an offset of
//! the desired readings `dy_ref = A_0 psi_f c_f` (the edge-sensor loop would otherwise fight a
//! direct command on a mode it sees).

use faer::Mat;
use faer::sparse::SparseColMat;
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::control::nominal::project_out;
use crate::control::reconstructor::{orthonormalize, sparse_mul};
use crate::sensing::interaction::global_ptt;

/// Parameters of the APS.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ApsParams {
    /// Days between APS runs (default 14; TMT plans every 2-4 weeks).
    pub interval_days: f64,
    /// rms error of the measured segment piston (m, default 5e-9, *assumed*).
    pub piston_rms: f64,
    /// rms error of each measured segment tilt (rad, default 2e-9, *assumed*: 1.4 nm of edge
    /// height over the 0.72 m circumradius).
    pub tilt_rms: f64,
    /// Seed of the measurement errors (default 1).
    pub seed: u64,
}

impl Default for ApsParams {
    fn default() -> Self {
        Self {
            interval_days: 14.0,
            piston_rms: 5e-9,
            tilt_rms: 2e-9,
            seed: 1,
        }
    }
}

impl ApsParams {
    /// Checks every field.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming the field out of range.
    pub fn check(&self) -> Result<(), M1Error> {
        if !(self.interval_days.is_finite() && self.interval_days > 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "aps_interval_days",
                value: self.interval_days,
                reason: "must be > 0 days",
            });
        }
        for (name, v) in [
            ("aps_piston_rms", self.piston_rms),
            ("aps_tilt_rms", self.tilt_rms),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be finite and >= 0",
                });
            }
        }
        Ok(())
    }
}

/// The APS of one mirror.
#[derive(Debug, Clone)]
pub struct Aps {
    params: ApsParams,
    geometry: Geometry,
    ptt_modes: Mat<f64>,
}

impl Aps {
    /// The APS of `geometry`.
    ///
    /// # Errors
    /// As [`ApsParams::check`].
    pub fn new(geometry: &Geometry, params: ApsParams) -> Result<Self, M1Error> {
        params.check()?;
        Ok(Self {
            params,
            geometry: geometry.clone(),
            ptt_modes: orthonormalize(global_ptt(geometry).as_ref()),
        })
    }

    /// The parameters.
    pub fn params(&self) -> &ApsParams {
        &self.params
    }

    /// The measured segment error of run `run` for the true actuator displacements `z` (m):
    /// `z` plus the measurement error, global piston/tip/tilt removed (actuator space).
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for a `z` of the wrong length.
    pub fn measure(&self, z: &[f64], run: u64) -> Result<Vec<f64>, M1Error> {
        crate::error::check_lengths(self.geometry.n_actuators(), &[("z", z)])?;
        let mut rng = StdRng::seed_from_u64(
            self.params
                .seed
                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                .wrapping_add(run),
        );
        let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
        let err: Vec<[f64; 3]> = (0..self.geometry.n_segments())
            .map(|_| {
                [
                    self.params.piston_rms * g(),
                    self.params.tilt_rms * g(),
                    self.params.tilt_rms * g(),
                ]
            })
            .collect();
        // Each segment's error in its own frame: z = P (p, alpha, beta).
        let mut e = z.to_vec();
        for (i, d) in err.iter().enumerate() {
            let p = self.geometry.ptt_matrix(i);
            for (k, row) in p.iter().enumerate() {
                e[3 * i + k] += row[0] * d[0] + row[1] * d[1] + row[2] * d[2];
            }
        }
        project_out(self.ptt_modes.as_ref(), &mut e);
        Ok(e)
    }

    /// `y_ref <- y_ref - A_0 e` for the measured error `e`.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for slices of the wrong length.
    pub fn reset_reference(
        a0: &SparseColMat<usize, f64>,
        y_ref: &mut [f64],
        e: &[f64],
    ) -> Result<(), M1Error> {
        crate::error::check_lengths(a0.nrows(), &[("y_ref", y_ref)])?;
        crate::error::check_lengths(a0.ncols(), &[("measured error", e)])?;
        let mut dy = vec![0.0; a0.nrows()];
        sparse_mul(a0, e, &mut dy);
        for (y, d) in y_ref.iter_mut().zip(&dy) {
            *y -= d;
        }
        Ok(())
    }
}

/// Parameters of the optical feedback.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OpticalFeedbackParams {
    /// Closed-loop bandwidth (Hz, default 0.01: an on-instrument wavefront sensor read every
    /// ~15 s, *assumed*).
    pub bandwidth: f64,
    /// rms noise of each measured modal coefficient (m of actuator-space amplitude, default
    /// 2e-9, *assumed*).
    pub noise_rms: f64,
    /// Also close focus-mode (default true).
    pub focus: bool,
    /// Seed of the measurement noise (default 1).
    pub seed: u64,
}

impl Default for OpticalFeedbackParams {
    fn default() -> Self {
        Self {
            bandwidth: 0.01,
            noise_rms: 2e-9,
            focus: true,
            seed: 1,
        }
    }
}

/// The optical feedback's integrator state and its modes (see the
/// [module documentation](self)).
#[derive(Debug, Clone)]
pub struct OpticalFeedback {
    params: OpticalFeedbackParams,
    /// Orthonormal global piston/tip/tilt (`na x 3`).
    ptt: Mat<f64>,
    /// Unit focus-mode (`na`), orthogonal to `ptt`.
    focus: Vec<f64>,
    /// `A_0 psi_f` (`ns`).
    a_focus: Vec<f64>,
    /// Integrated coefficients: 3 global PTT, then focus-mode.
    c: [f64; 4],
    updates: u64,
}

impl OpticalFeedback {
    /// The optical feedback of `geometry` with the nominal `a0` and its `focus` mode.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for a negative bandwidth or noise,
    /// [`M1Error::SizeMismatch`] for a focus vector of the wrong length.
    pub fn new(
        geometry: &Geometry,
        a0: &SparseColMat<usize, f64>,
        focus: &[f64],
        params: OpticalFeedbackParams,
    ) -> Result<Self, M1Error> {
        for (name, v) in [
            ("of_bandwidth", params.bandwidth),
            ("of_noise_rms", params.noise_rms),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be finite and >= 0",
                });
            }
        }
        crate::error::check_lengths(geometry.n_actuators(), &[("focus-mode", focus)])?;
        let ptt = orthonormalize(global_ptt(geometry).as_ref());
        let mut f = focus.to_vec();
        project_out(ptt.as_ref(), &mut f);
        let n = f.iter().map(|x| x * x).sum::<f64>().sqrt();
        if n.is_nan() || n <= 0.0 {
            return Err(M1Error::InvalidInput(
                "focus-mode lies in the global piston/tip/tilt".into(),
            ));
        }
        f.iter_mut().for_each(|x| *x /= n);
        let mut a_focus = vec![0.0; a0.nrows()];
        sparse_mul(a0, &f, &mut a_focus);
        Ok(Self {
            params,
            ptt,
            focus: f,
            a_focus,
            c: [0.0; 4],
            updates: 0,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &OpticalFeedbackParams {
        &self.params
    }

    /// The modal coefficients of `z`: global piston/tip/tilt (orthonormal basis) and focus-mode.
    pub fn modes_of(&self, z: &[f64]) -> [f64; 4] {
        let mut m = [0.0; 4];
        for (c, v) in m.iter_mut().take(3).enumerate() {
            *v = (0..z.len()).map(|i| self.ptt[(i, c)] * z[i]).sum();
        }
        m[3] = self.focus.iter().zip(z).map(|(a, b)| a * b).sum();
        m
    }

    /// One update over `dt` seconds from the true surface `z` (m, actuator space).
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for a `z` of the wrong length; [`M1Error::InvalidParameter`]
    /// for a negative or non-finite `dt`.
    pub fn update(&mut self, z: &[f64], dt: f64) -> Result<(), M1Error> {
        crate::error::check_lengths(self.focus.len(), &[("z", z)])?;
        if !(dt.is_finite() && dt >= 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "dt",
                value: dt,
                reason: "must be finite and >= 0",
            });
        }
        let g = 1.0 - (-2.0 * std::f64::consts::PI * self.params.bandwidth * dt).exp();
        let m = self.modes_of(z);
        let mut rng = StdRng::seed_from_u64(
            self.params
                .seed
                .wrapping_mul(0xD134_2543_DE82_EF95)
                .wrapping_add(self.updates),
        );
        self.updates += 1;
        let k = if self.params.focus { 4 } else { 3 };
        for (c, mi) in self.c.iter_mut().zip(m).take(k) {
            let noise: f64 = StandardNormal.sample(&mut rng);
            *c -= g * (mi + self.params.noise_rms * noise);
        }
        Ok(())
    }

    /// The integrated coefficients (3 global piston/tip/tilt, focus-mode).
    pub fn coefficients(&self) -> [f64; 4] {
        self.c
    }

    /// Resets the integrator (e.g. at the start of a night).
    pub fn reset(&mut self) {
        self.c = [0.0; 4];
    }

    /// The integrator state: the coefficients and the number of updates taken (which seeds the
    /// next update's noise), for saving.
    pub fn state(&self) -> ([f64; 4], u64) {
        (self.c, self.updates)
    }

    /// Restores a state read by [`OpticalFeedback::state`], exactly.
    pub fn set_state(&mut self, coefficients: [f64; 4], updates: u64) {
        self.c = coefficients;
        self.updates = updates;
    }

    /// The low-order actuator command `u_lo = N c_ptt` into `u` (length `na`).
    pub fn low_order_command_into(&self, u: &mut [f64]) {
        for (i, v) in u.iter_mut().enumerate() {
            *v = (0..3).map(|c| self.ptt[(i, c)] * self.c[c]).sum();
        }
    }

    /// Adds the focus-mode offset of the desired readings, `A_0 psi_f c_f`, to `y_ref`.
    pub fn add_reference_offset(&self, y_ref: &mut [f64]) {
        for (y, a) in y_ref.iter_mut().zip(&self.a_focus) {
            *y += a * self.c[3];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::geometry::GeometryParams;
    use crate::aperture::layout::Layout;
    use crate::control::nominal::Nominal;

    #[test]
    fn aps_measures_the_relative_segment_error_and_resets_the_reference() {
        let l = Layout::preset("keck").unwrap();
        let g = Geometry::new(&l, GeometryParams::for_layout(&l)).unwrap();
        let nominal = Nominal::new(g.clone()).unwrap();
        let exact = Aps::new(
            &g,
            ApsParams {
                piston_rms: 0.0,
                tilt_rms: 0.0,
                ..ApsParams::default()
            },
        )
        .unwrap();
        // A segment error plus a global plane: the APS sees the error without the plane.
        let mut z: Vec<f64> = (0..g.n_actuators())
            .map(|k| 1e-8 * (k as f64).cos())
            .collect();
        project_out(exact.ptt_modes.as_ref(), &mut z);
        let plane = exact.ptt_modes.col(1);
        let zp: Vec<f64> = (0..z.len()).map(|i| z[i] + 3e-7 * plane[i]).collect();
        let e = exact.measure(&zp, 0).unwrap();
        for (a, b) in e.iter().zip(&z) {
            assert!((a - b).abs() < 1e-20, "{a} {b}");
        }
        // After the reset the reference readings are those of the corrected mirror.
        let mut y_ref = vec![0.0; nominal.a.nrows()];
        sparse_mul(&nominal.a, &zp, &mut y_ref);
        Aps::reset_reference(&nominal.a, &mut y_ref, &e).unwrap();
        let fixed: Vec<f64> = (0..z.len()).map(|i| 3e-7 * plane[i]).collect();
        let mut y_fixed = vec![0.0; y_ref.len()];
        sparse_mul(&nominal.a, &fixed, &mut y_fixed);
        for (a, b) in y_ref.iter().zip(&y_fixed) {
            assert!((a - b).abs() < 1e-18);
        }
        // With errors, the same run gives the same draw; the rms matches the parameters.
        let noisy = Aps::new(&g, ApsParams::default()).unwrap();
        let zero = vec![0.0; z.len()];
        assert_eq!(
            noisy.measure(&zero, 3).unwrap(),
            noisy.measure(&zero, 3).unwrap()
        );
        assert_ne!(
            noisy.measure(&zero, 3).unwrap(),
            noisy.measure(&zero, 4).unwrap()
        );
    }

    #[test]
    fn optical_feedback_converges_at_its_bandwidth() {
        let l = Layout::preset("keck").unwrap();
        let g = Geometry::new(&l, GeometryParams::for_layout(&l)).unwrap();
        let nominal = Nominal::new(g.clone()).unwrap();
        let p = OpticalFeedbackParams {
            noise_rms: 0.0,
            bandwidth: 0.1,
            ..OpticalFeedbackParams::default()
        };
        let mut of = OpticalFeedback::new(&g, &nominal.a, &nominal.focus, p).unwrap();
        // A fixed global tilt offset: with u_lo added, the residual decays as (1 - g)^k.
        let tilt = of.ptt.col(2).iter().map(|x| 1e-6 * x).collect::<Vec<f64>>();
        let mut u = vec![0.0; tilt.len()];
        let dt = 1.0;
        let gain = 1.0 - (-2.0 * std::f64::consts::PI * 0.1 * dt).exp();
        for k in 1..=5 {
            let z: Vec<f64> = tilt.iter().zip(&u).map(|(a, b)| a + b).collect();
            of.update(&z, dt).unwrap();
            of.low_order_command_into(&mut u);
            let resid = of.modes_of(&tilt.iter().zip(&u).map(|(a, b)| a + b).collect::<Vec<_>>());
            let expected = 1e-6 * (1.0 - gain).powi(k);
            assert!(
                (resid[2] - expected).abs() < 1e-15,
                "{} {}",
                resid[2],
                expected
            );
        }
        assert!(of.update(&tilt[1..], dt).is_err());
    }
}
