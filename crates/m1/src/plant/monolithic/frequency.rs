//! The frequency-domain model ([`FrequencyModel`]): the servoed channels of identical segments
//! coupled to the retained modes of the structure by one r x r complex system per frequency,
//! with its inputs ([`Inputs`]) and response ([`Response`]); see the parent module's
//! documentation for the derivation.

use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use nalgebra::SMatrix;
use std::f64::consts::TAU;

use super::{
    ChannelTransfer, channel_transfer, retained_modes, to_actuator_order, to_channel_order,
};
use crate::M1Error;
use crate::plant::segment::{Channel, SegmentModel, modal_basis};
use crate::plant::structure::{ModalModel, ModalSolver};

/// Inputs of a frequency point, actuator order (actuator k of segment i at 3 i + k): complex
/// amplitudes of sinusoids at the frequency.
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    /// Actuator commands, a sequence at the servo rate (m); empty for none.
    pub u_cmd: &'a [c64],
    /// Wind forces at the actuator points (N); empty for none.
    pub f_wind: &'a [c64],
    /// Pier displacement (m).
    pub pier: c64,
}

/// The response at one frequency, actuator order.
#[derive(Debug, Clone, PartialEq)]
pub struct Response {
    /// Frequency (Hz).
    pub frequency: f64,
    /// Mirror displacement at each actuator (m).
    pub mirror: Vec<c64>,
    /// Cell displacement at each attachment (m).
    pub cell: Vec<c64>,
    /// Force of each actuator on the cell (N).
    pub force: Vec<c64>,
    /// Modal coordinates of the structure.
    pub modes: Vec<c64>,
}

/// The mirror (identical segments of one actuator variant on a modal structure) in the
/// frequency domain; see the module documentation.
#[derive(Debug, Clone)]
pub struct FrequencyModel {
    n_segments: usize,
    model: SegmentModel,
    omega: Vec<f64>,
    zeta: Vec<f64>,
    b_pier: Vec<f64>,
    /// Shapes in the channel basis (rows: piston channels, then tilt channels 2 s + m), na x r.
    pub(super) phic: Mat<f64>,
    /// `Phi_p^T Phi_p`, `Phi_t^T Phi_t`.
    gram: [Mat<f64>; 2],
    basis: SMatrix<f64, 3, 3>,
}

impl FrequencyModel {
    /// `n_segments` identical segments of `model` on the `n_modes` lowest modes of `cell`
    /// (damping `damping_ratio` unless the model carries its own). The static correction of
    /// the truncated modes is not used (as in [`crate::plant::mirror::CoupledMirror`]).
    pub fn new(
        n_segments: usize,
        model: SegmentModel,
        cell: ModalModel,
        n_modes: usize,
        damping_ratio: f64,
    ) -> Result<Self, M1Error> {
        let solver = retained_modes(n_segments, cell, n_modes, damping_ratio)?;
        Self::from_solver(n_segments, model, &solver)
    }

    /// The same, from the retained modes of a modal solver.
    pub fn from_solver(
        n_segments: usize,
        model: SegmentModel,
        structure: &ModalSolver,
    ) -> Result<Self, M1Error> {
        model.validate()?;
        let na = 3 * n_segments;
        if structure.n_actuators() != na {
            return Err(M1Error::SizeMismatch {
                what: "structure attachments (3 per segment)",
                expected: na,
                found: structure.n_actuators(),
            });
        }
        let r = structure.n_modes();
        let omega: Vec<f64> = structure.frequencies().iter().map(|f| TAU * f).collect();
        let shapes = structure.shapes();
        let v = modal_basis();
        let n = n_segments;
        let mut phic = Mat::<f64>::zeros(na, r);
        for seg in 0..n {
            for j in 0..r {
                let a = [0, 1, 2].map(|k| shapes[(3 * seg + k) * r + j]);
                let ch = |c: usize| v[(0, c)] * a[0] + v[(1, c)] * a[1] + v[(2, c)] * a[2];
                phic[(seg, j)] = ch(0);
                phic[(n + 2 * seg, j)] = ch(1);
                phic[(n + 2 * seg + 1, j)] = ch(2);
            }
        }
        let pp = phic.subrows(0, n);
        let pt = phic.subrows(n, 2 * n);
        let gram = [pp.transpose() * pp, pt.transpose() * pt];
        Ok(Self {
            n_segments,
            model,
            omega,
            zeta: structure.damping_ratios().to_vec(),
            b_pier: structure.pier_gains().to_vec(),
            phic,
            gram,
            basis: v,
        })
    }

    /// The segments on a rigid base (no structural mode).
    pub fn rigid(n_segments: usize, model: SegmentModel) -> Result<Self, M1Error> {
        model.validate()?;
        let na = 3 * n_segments;
        Ok(Self {
            n_segments,
            model,
            omega: Vec::new(),
            zeta: Vec::new(),
            b_pier: Vec::new(),
            phic: Mat::zeros(na, 0),
            gram: [Mat::zeros(0, 0), Mat::zeros(0, 0)],
            basis: modal_basis(),
        })
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// Number of actuators.
    pub fn n_actuators(&self) -> usize {
        3 * self.n_segments
    }

    /// Number of retained structural modes.
    pub fn n_modes(&self) -> usize {
        self.omega.len()
    }

    /// The segment model.
    pub fn model(&self) -> &SegmentModel {
        &self.model
    }

    /// Natural frequencies of the retained modes (Hz).
    pub fn mode_frequencies(&self) -> Vec<f64> {
        self.omega.iter().map(|w| w / TAU).collect()
    }

    /// Shapes at the attachments in the channel basis (na x r: piston channels, then the tilt
    /// channels of each segment).
    pub fn channel_shapes(&self) -> &Mat<f64> {
        &self.phic
    }

    /// Both channel kinds' transfers at `f`.
    pub fn channels(&self, f: f64) -> [ChannelTransfer; 2] {
        [
            channel_transfer(&self.model, Channel::Piston, f),
            channel_transfer(&self.model, Channel::Tilt, f),
        ]
    }

    /// The modes' dynamic stiffness with the servoed segments attached, at `f` (Hz):
    /// $D - t_{fz,p} G_p - t_{fz,t} G_t$ (r x r).
    pub fn modal_stiffness(&self, f: f64, ch: &[ChannelTransfer; 2]) -> Mat<c64> {
        self.stiffness(f, ch, false)
    }

    /// [`Self::modal_stiffness`]'s lower triangle (diagonal included), the upper one left
    /// zero: what a symmetric factorisation reads (at 1000 modes built in 3.5 ms against the
    /// whole matrix's 5.1 ms: BENCHMARKS.md, thirty-third round).
    pub fn modal_stiffness_lower(&self, f: f64, ch: &[ChannelTransfer; 2]) -> Mat<c64> {
        self.stiffness(f, ch, true)
    }

    /// The modal stiffness by columns, from row `j` of column `j` on if `lower`.
    fn stiffness(&self, f: f64, ch: &[ChannelTransfer; 2], lower: bool) -> Mat<c64> {
        let w = TAU * f;
        let r = self.n_modes();
        let (tp, tt) = (ch[0].force[1], ch[1].force[1]);
        let mut k = Mat::<c64>::zeros(r, r);
        for j in 0..r {
            let i0 = if lower { j } else { 0 };
            let (g0, g1) = (self.gram[0].col(j), self.gram[1].col(j));
            for (i, x) in k.col_mut(j).iter_mut().enumerate().skip(i0) {
                *x = -(tp * g0[i] + tt * g1[i]);
            }
            let wj = self.omega[j];
            k[(j, j)] += c64::new(wj * wj - w * w, 2.0 * self.zeta[j] * wj * w);
        }
        k
    }

    /// Actuator order to channel order (piston channels, then tilt channels 2 s + m).
    pub fn to_channels(&self, a: &[c64]) -> Vec<c64> {
        to_channel_order(&self.basis, a)
    }

    /// Channel order back to actuator order.
    pub fn to_actuators(&self, c: &[c64]) -> Vec<c64> {
        to_actuator_order(&self.basis, c)
    }

    /// The response at `f` (Hz) to the given inputs.
    ///
    /// # Errors
    /// [`M1Error::SizeMismatch`] for an input of the wrong length, [`M1Error::Unstable`] if
    /// the modal system is singular at `f` (an undamped resonance).
    pub fn response(&self, f: f64, inputs: &Inputs<'_>) -> Result<Response, M1Error> {
        let na = self.n_actuators();
        let n = self.n_segments;
        let zero = c64::new(0.0, 0.0);
        for (what, a) in [("u_cmd", inputs.u_cmd), ("f_wind", inputs.f_wind)] {
            if !(a.is_empty() || a.len() == na) {
                return Err(M1Error::SizeMismatch {
                    what,
                    expected: na,
                    found: a.len(),
                });
            }
        }
        let channel_input = |a: &[c64]| {
            if a.is_empty() {
                vec![zero; na]
            } else {
                self.to_channels(a)
            }
        };
        let rc = channel_input(inputs.u_cmd);
        let wc = channel_input(inputs.f_wind);
        let ch = self.channels(f);
        let kind = |c: usize| usize::from(c >= n);
        // External part of the forces and the mirror (cell at rest).
        let f_ext: Vec<c64> = (0..na)
            .map(|c| {
                let t = &ch[kind(c)];
                t.force[0] * rc[c] + t.force[2] * wc[c]
            })
            .collect();
        let r = self.n_modes();
        let mut q = vec![zero; r];
        if r > 0 {
            let mut rhs = Mat::<c64>::zeros(r, 1);
            for j in 0..r {
                let mut x = inputs.pier * self.b_pier[j];
                for (c, fc) in f_ext.iter().enumerate() {
                    x += fc * self.phic[(c, j)];
                }
                rhs[(j, 0)] = x;
            }
            let k = self.modal_stiffness(f, &ch);
            let sol = k.partial_piv_lu().solve(&rhs);
            for j in 0..r {
                q[j] = sol[(j, 0)];
            }
            if q.iter().any(|x| !(x.re.is_finite() && x.im.is_finite())) {
                return Err(M1Error::Unstable {
                    channel: "coupled segments and structure",
                    spectral_radius: f64::NAN,
                    hint: "the modal system is singular at this frequency (an undamped mode)",
                });
            }
        }
        let zc: Vec<c64> = (0..na)
            .map(|c| (0..r).fold(zero, |s, j| s + q[j] * self.phic[(c, j)]))
            .collect();
        let mut mirror = vec![zero; na];
        let mut force = vec![zero; na];
        for c in 0..na {
            let t = &ch[kind(c)];
            mirror[c] = t.mirror[0] * rc[c] + t.mirror[1] * zc[c] + t.mirror[2] * wc[c];
            force[c] = f_ext[c] + t.force[1] * zc[c];
        }
        Ok(Response {
            frequency: f,
            mirror: self.to_actuators(&mirror),
            cell: self.to_actuators(&zc),
            force: self.to_actuators(&force),
            modes: q,
        })
    }

    /// The response to a unit pier displacement at `f` (Hz).
    pub fn pier_response(&self, f: f64) -> Result<Response, M1Error> {
        self.response(
            f,
            &Inputs {
                u_cmd: &[],
                f_wind: &[],
                pier: c64::new(1.0, 0.0),
            },
        )
    }
}
