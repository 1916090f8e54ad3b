//! The mirror for wind studies, quasi-static (seed paper, section 4.1): the structure without
//! inertia and each segment chain reduced to its low-frequency behaviour, the servo's integrator
//! the only state.
//!
//! # Why
//!
//! Wind loads are at low frequency relative to the structure and to the segment supports, so
//! the response to them depends on the static compliance of the structure and on the segments'
//! low-frequency stiffness: the servo's static stiffness and its integral gain, which sets how
//! fast the compliance grows with frequency. [`QuasiStaticMirror`] keeps exactly that and
//! nothing faster, so a wind run needs no servo-rate stepping and no retained-mode dynamics;
//! the coupled solver ([`crate::plant::mirror::CoupledMirror`]) stays the reference, and the two agree
//! below 1 Hz (tested).
//!
//! # Model
//!
//! Per channel (piston and the two tilts of each segment, as in [`crate::plant::segment`]) the
//! masses are dropped: the chain's static equilibrium `0 = A x + B w` (its continuous plant,
//! `w` = drive `u`, cell displacement `z_c`, wind force `f`) gives the stroke and the glass
//! displacement as linear functions of `w`,
//! `s = σ_u u + σ_z z_c + σ_f f` and `x_g = γ_u u + γ_z z_c + γ_f f`,
//! and the force on the cell is the wind force (the chain carries it through). The encoder
//! servo in its low-frequency form is `u = (k_ff + k_p b) u_cmd − k_p s + k_i I` with the leaky
//! integrator `İ = u_cmd − s − λ I` (`λ = (1 − a_i) / T_s`, the discrete leak), the derivative
//! term vanishing. Eliminating `s` leaves one linear ODE per channel, `İ = a I + b · (u_cmd,
//! z_c, f)`, integrated exactly over each step with the inputs held. The structure is
//! [`ModalSolver::settle`]: its exact static response (built-in FE model or imported
//! compliance; else the retained modes' static sum), to the wind force and the pier.
//!
//! Outputs after a step are those at its end, from the inputs held over it, as for the
//! dynamic mirror: `z` (the glass at each actuator), `z_cell`, `f_cell`.

use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::plant::segment::{Channel, N_CONT, SegmentModel, modal_basis, state};
use crate::plant::structure::{ModalModel, ModalSolver};

/// The low-frequency reduction of one channel kind.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ChannelFit {
    /// Integrator ODE `İ = a I + b_u u_cmd + b_z z_c + b_f f`: `a` (1/s).
    pub a: f64,
    /// `b_u` (dimensionless: the integrator, in m s, grows by the command error in m).
    pub b_u: f64,
    /// `b_z`.
    pub b_z: f64,
    /// `b_f` (m/N).
    pub b_f: f64,
    /// Stroke `s = s_i I + s_u u_cmd + s_z z_c + s_f f`: `s_i` (1/s).
    pub s_i: f64,
    /// `s_u`.
    pub s_u: f64,
    /// `s_z`.
    pub s_z: f64,
    /// `s_f` (m/N).
    pub s_f: f64,
    /// Glass `x_g = g_i I + g_u u_cmd + g_z z_c + g_f f`: `g_i` (1/s).
    pub g_i: f64,
    /// `g_u`.
    pub g_u: f64,
    /// `g_z`.
    pub g_z: f64,
    /// `g_f` (m/N).
    pub g_f: f64,
}

impl ChannelFit {
    /// The reduction of `model`'s channel `ch`.
    ///
    /// # Errors
    /// A chain without a static equilibrium (singular stiffness).
    pub fn new(model: &SegmentModel, ch: Channel) -> Result<Self, M1Error> {
        let p = model.plant(ch);
        // States that nothing drives (an open shunt) stay at zero: identity rows.
        let mut a = p.a;
        for i in 0..N_CONT {
            if (0..N_CONT).all(|j| a[(i, j)] == 0.0) {
                a[(i, i)] = 1.0;
            }
        }
        let inv = a.try_inverse().ok_or(M1Error::InvalidParameter {
            name: "segment",
            value: f64::NAN,
            reason: "the actuator chain has no static equilibrium",
        })?;
        let x: SMatrix<f64, N_CONT, 3> = -(inv * p.b);
        let (node, glass) = (state::NODE_POS, state::MIRROR_POS);
        let (su, sz, sf) = (x[(node, 0)], x[(node, 1)] - 1.0, x[(node, 2)]);
        let (gu, gz, gf) = (x[(glass, 0)], x[(glass, 1)], x[(glass, 2)]);
        let v = &model.actuator.servo;
        let ts = 1.0 / v.rate;
        let ai = (-std::f64::consts::TAU * v.integrator_leak * ts).exp();
        let lambda = (1.0 - ai) / ts;
        let cu = v.feedforward + v.kp * v.setpoint_weight;
        let d = 1.0 + su * v.kp;
        // s = (su (cu u_cmd + ki I) + sz z_c + sf f) / d
        let (s_i, s_u, s_z, s_f) = (su * v.ki / d, su * cu / d, sz / d, sf / d);
        // drive = cu u_cmd - kp s + ki I; glass = gu drive + gz z_c + gf f
        let (g_i, g_u, g_z, g_f) = (
            gu * (v.ki - v.kp * s_i),
            gu * (cu - v.kp * s_u),
            gz - gu * v.kp * s_z,
            gf - gu * v.kp * s_f,
        );
        Ok(Self {
            a: -s_i - lambda,
            b_u: 1.0 - s_u,
            b_z: -s_z,
            b_f: -s_f,
            s_i,
            s_u,
            s_z,
            s_f,
            g_i,
            g_u,
            g_z,
            g_f,
        })
    }

    /// The glass's static compliance to the wind force relative to the cell (m/N), with the
    /// integrator settled: `1 / static stiffness` of the chain for this load pattern.
    pub fn static_compliance(&self) -> f64 {
        if self.a == 0.0 {
            return f64::NAN;
        }
        // I = -(b_f / a) f at rest, then the glass relative to the cell (g_z = 1).
        self.g_f - self.g_i * self.b_f / self.a
    }
}

/// Segments and structure for wind studies, quasi-static (see the module documentation).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct QuasiStaticMirror {
    n_segments: usize,
    model: SegmentModel,
    fits: [ChannelFit; 2],
    basis: SMatrix<f64, 3, 3>,
    structure: ModalSolver,
    /// Integrator of each channel, segment-major: `3 i + k` (k = 0 piston, 1-2 tilts).
    integrator: Vec<f64>,
    z_mirror: Vec<f64>,
    f_cell: Vec<f64>,
    /// The pier displacement of the last static solve.
    pier: f64,
}

impl QuasiStaticMirror {
    /// `n_segments` segments of `model` on `cell`, of which the static response uses the
    /// `n_modes` lowest modes (damping is irrelevant here) where the model has no exact
    /// static correction. At rest.
    ///
    /// # Errors
    /// Invalid segment model, a cell of the wrong size, or a reduction that fails.
    pub fn new(
        n_segments: usize,
        model: SegmentModel,
        cell: ModalModel,
        n_modes: usize,
    ) -> Result<Self, M1Error> {
        model.validate()?;
        let na = 3 * n_segments;
        if cell.na != na {
            return Err(M1Error::SizeMismatch {
                what: "cell attachments",
                expected: na,
                found: cell.na,
            });
        }
        let fits = [
            ChannelFit::new(&model, Channel::Piston)?,
            ChannelFit::new(&model, Channel::Tilt)?,
        ];
        let structure = ModalSolver::new(cell, n_modes, 0.0)?;
        let mut m = Self {
            n_segments,
            model,
            fits,
            basis: modal_basis(),
            structure,
            integrator: vec![0.0; na],
            z_mirror: vec![0.0; na],
            f_cell: vec![0.0; na],
            pier: 0.0,
        };
        m.reset();
        Ok(m)
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// The segment model.
    pub fn model(&self) -> &SegmentModel {
        &self.model
    }

    /// The structure's solver (used for its static response only).
    pub fn structure(&self) -> &ModalSolver {
        &self.structure
    }

    /// The reductions of the piston and the tilt channels.
    pub fn fits(&self) -> &[ChannelFit; 2] {
        &self.fits
    }

    /// Advances `h` seconds (any positive step) with the command, the wind forces (actuator
    /// order, length 3N) and the pier displacement held.
    ///
    /// # Errors
    /// Wrong lengths, a non-positive or non-finite step.
    pub fn advance(
        &mut self,
        h: f64,
        u_cmd: &[f64],
        f_wind: &[f64],
        pier_z: f64,
    ) -> Result<(), M1Error> {
        let na = 3 * self.n_segments;
        crate::error::check_lengths(na, &[("u_cmd", u_cmd), ("f_wind", f_wind)])?;
        if !(h.is_finite() && h > 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "communication step",
                value: h,
                reason: "must be finite and > 0",
            });
        }
        // The chain carries the wind force to the cell; the static solve is redone only when
        // the loads change (a wind source updates more slowly than the mirror steps).
        if self.f_cell != f_wind || self.pier != pier_z {
            self.f_cell.copy_from_slice(f_wind);
            self.pier = pier_z;
            self.structure.settle(&self.f_cell, pier_z)?;
        }
        let decay = self.fits.map(|c| {
            let e = (c.a * h).exp();
            (e, if c.a == 0.0 { h } else { (e - 1.0) / c.a })
        });
        let v = self.basis;
        let z_cell = self.structure.output();
        for i in 0..self.n_segments {
            let r = 3 * i..3 * i + 3;
            let to = |x: &[f64]| v.transpose() * SVector::<f64, 3>::from_column_slice(x);
            let (u, f, z) = (
                to(&u_cmd[r.clone()]),
                to(&f_wind[r.clone()]),
                to(&z_cell[r]),
            );
            let mut g = SVector::<f64, 3>::zeros();
            for k in 0..3 {
                let (c, (e, w)) = (&self.fits[usize::from(k > 0)], decay[usize::from(k > 0)]);
                let j = 3 * i + k;
                let drive = c.b_u * u[k] + c.b_z * z[k] + c.b_f * f[k];
                self.integrator[j] = e * self.integrator[j] + w * drive;
                g[k] = c.g_i * self.integrator[j] + c.g_u * u[k] + c.g_z * z[k] + c.g_f * f[k];
            }
            let x = v * g;
            self.z_mirror[3 * i..3 * i + 3].copy_from_slice(x.as_slice());
        }
        Ok(())
    }

    /// Mirror displacement `z` at each actuator (length 3N).
    pub fn mirror(&self, z: &mut [f64]) {
        z.copy_from_slice(&self.z_mirror);
    }

    /// Cell displacement at each attachment (length 3N).
    pub fn cell_displacement(&self) -> &[f64] {
        self.structure.output()
    }

    /// Force of each actuator on the cell (length 3N).
    pub fn cell_force(&self) -> &[f64] {
        &self.f_cell
    }

    /// Back to rest, undeformed.
    pub fn reset(&mut self) {
        self.integrator.fill(0.0);
        self.z_mirror.fill(0.0);
        self.f_cell.fill(0.0);
        self.pier = 0.0;
        let zeros = vec![0.0; self.f_cell.len()];
        // Cannot fail: the length is the structure's.
        let _ = self.structure.settle(&zeros, 0.0);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    #[test]
    fn the_reduction_keeps_the_static_stiffness_and_passes_the_force() {
        for model in [
            SegmentModel::voice_coil(),
            SegmentModel::piezo(),
            SegmentModel::piezo_damped_default(),
            SegmentModel::voice_coil_without_whiffletree(),
        ] {
            for ch in Channel::ALL {
                let fit = ChannelFit::new(&model, ch).unwrap();
                assert!(fit.a < 0.0, "{ch:?}: {fit:?}");
                // The glass moves with the cell, and settles on the analytic stiffness.
                assert!((fit.g_z - 1.0).abs() < 1e-9, "{fit:?}");
                let k = model.static_stiffness(ch);
                let c = fit.static_compliance();
                assert!((c * k - 1.0).abs() < 1e-6, "{ch:?}: {} vs {}", 1.0 / c, k);
                // Against the full sampled closed loop (masses, servo, derivative) near DC, at
                // 0.1 and 1 Hz: the reduction's response is g + g_i b / (j w - a).
                for f in [1e-4, 0.1, 1.0] {
                    let full = model.mirror_response(ch, f);
                    let jw = nalgebra::Complex::new(0.0, std::f64::consts::TAU * f);
                    let red = |b: f64, g: f64| g + fit.g_i * b / (jw - fit.a);
                    let pairs = [
                        (red(fit.b_u, fit.g_u), full[0]),
                        (red(fit.b_f, fit.g_f), full[2]),
                    ];
                    for (k, (r, want)) in pairs.into_iter().enumerate() {
                        // Measured at most 1.4e-7, 1.6e-4 and 9.0e-3.
                        let tol = if f < 0.01 {
                            1e-6
                        } else if f < 0.5 {
                            5e-4
                        } else {
                            2e-2
                        };
                        assert!(
                            (r - want).norm() <= tol * want.norm(),
                            "{ch:?} input {k} at {f} Hz: {r} vs {want}"
                        );
                    }
                }
            }
        }
    }
}
