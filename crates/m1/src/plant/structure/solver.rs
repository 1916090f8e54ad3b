//! Exact discrete-time simulation of a modal model: every retained mode under a zero-order
//! hold, the static correction of the truncated ones, and the quasi-static settle.

use std::f64::consts::TAU;

use serde::{Deserialize, Serialize};

use super::{Flexibility, ModalModel};
use crate::M1Error;

/// The zero-order-hold discretisation of one mode over `h`: `(A_d, B_d)` with
/// `A_d = exp(A h)` row-major and `B_d = A^-1 (A_d - I) [0, 1]^T`,
/// `A = [[0, 1], [-w^2, -2 zeta w]]`.
pub fn zoh_mode(w: f64, zeta: f64, h: f64) -> ([f64; 4], [f64; 2]) {
    // exp(A t) = e^{-s t} (C I + S (A + s I)), (A + s I)^2 = (s^2 - w^2) I, s = zeta w.
    let s = zeta * w;
    let disc = w * w * (zeta * zeta - 1.0);
    let (c, sn) = if disc < -1e-12 * w * w {
        let wd = (-disc).sqrt();
        ((wd * h).cos(), (wd * h).sin() / wd)
    } else if disc > 1e-12 * w * w {
        let mu = disc.sqrt();
        ((mu * h).cosh(), (mu * h).sinh() / mu)
    } else {
        (1.0, h)
    };
    let e = (-s * h).exp();
    let ad = [e * (c + s * sn), e * sn, -e * w * w * sn, e * (c - s * sn)];
    let bd = [(1.0 - ad[3]) / (w * w) - 2.0 * zeta * ad[1] / w, ad[1]];
    (ad, bd)
}

/// The modal model in state-space form, stepped exactly with the inputs held over each step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModalSolver {
    na: usize,
    n: usize,
    omega: Vec<f64>,
    zeta: Vec<f64>,
    inv_w2: Vec<f64>,
    /// Retained shapes at the attachments, `na x n` row-major.
    phi: Vec<f64>,
    /// Modal gain of the pier input, `k_p phi_p`.
    b_pier: Vec<f64>,
    flex: Flexibility,
    q: Vec<f64>,
    v: Vec<f64>,
    h: f64,
    ad: Vec<[f64; 4]>,
    bd: Vec<[f64; 2]>,
    u: Vec<f64>,
    z: Vec<f64>,
    zs: Vec<f64>,
    work: Vec<f64>,
}

impl ModalSolver {
    /// Keeps the `n_modes` lowest modes of `model` (all if it has fewer), with the model's
    /// damping ratios or else `damping_ratio` for every mode. Starts at rest, undeformed.
    pub fn new(model: ModalModel, n_modes: usize, damping_ratio: f64) -> Result<Self, M1Error> {
        let total = model.n_modes();
        let na = model.na;
        if model.phi_cell.len() != na * total {
            return Err(M1Error::SizeMismatch {
                what: "phi_cell",
                expected: na * total,
                found: model.phi_cell.len(),
            });
        }
        if model.phi_pier.len() != total {
            return Err(M1Error::SizeMismatch {
                what: "phi_pier",
                expected: total,
                found: model.phi_pier.len(),
            });
        }
        if n_modes == 0 {
            return Err(M1Error::InvalidParameter {
                name: "n_modes",
                value: 0.0,
                reason: "must be >= 1",
            });
        }
        if !(damping_ratio.is_finite() && damping_ratio >= 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "damping_ratio",
                value: damping_ratio,
                reason: "must be finite and >= 0",
            });
        }
        let mut idx: Vec<usize> = (0..total).collect();
        idx.sort_by(|&a, &b| model.frequencies[a].total_cmp(&model.frequencies[b]));
        idx.truncate(n_modes.min(total));
        let n = idx.len();
        let omega: Vec<f64> = idx.iter().map(|&j| TAU * model.frequencies[j]).collect();
        let zeta: Vec<f64> = idx
            .iter()
            .map(|&j| {
                model
                    .damping_ratios
                    .as_ref()
                    .map_or(damping_ratio, |d| d[j])
            })
            .collect();
        let mut phi = vec![0.0; na * n];
        for r in 0..na {
            for (c, &j) in idx.iter().enumerate() {
                phi[r * n + c] = model.phi_cell[r * total + j];
            }
        }
        let b_pier = idx
            .iter()
            .map(|&j| model.k_pier * model.phi_pier[j])
            .collect();
        let work = match &model.flexibility {
            Flexibility::FiniteElement(s) => vec![0.0; s.ndof()],
            _ => Vec::new(),
        };
        Ok(Self {
            na,
            n,
            inv_w2: omega.iter().map(|w| 1.0 / (w * w)).collect(),
            omega,
            zeta,
            phi,
            b_pier,
            flex: model.flexibility,
            q: vec![0.0; n],
            v: vec![0.0; n],
            h: f64::NAN,
            ad: Vec::new(),
            bd: Vec::new(),
            u: vec![0.0; n],
            z: vec![0.0; na],
            zs: vec![0.0; na],
            work,
        })
    }

    /// Number of retained modes.
    pub fn n_modes(&self) -> usize {
        self.n
    }

    /// Number of actuators.
    pub fn n_actuators(&self) -> usize {
        self.na
    }

    /// Retained natural frequencies (Hz), increasing.
    pub fn frequencies(&self) -> Vec<f64> {
        self.omega.iter().map(|w| w / TAU).collect()
    }

    /// Retained damping ratios.
    pub fn damping_ratios(&self) -> &[f64] {
        &self.zeta
    }

    /// The modal state `(q, q')`.
    pub fn state(&self) -> (&[f64], &[f64]) {
        (&self.q, &self.v)
    }

    /// Retained mode shapes at the attachments, `na x n` row-major (1/sqrt(kg)).
    pub fn shapes(&self) -> &[f64] {
        &self.phi
    }

    /// Modal gain of the pier input of each retained mode, `k_p phi_p` (N/(m sqrt(kg))).
    pub fn pier_gains(&self) -> &[f64] {
        &self.b_pier
    }

    /// Whether a static correction is applied.
    pub fn has_static_correction(&self) -> bool {
        !matches!(self.flex, Flexibility::None)
    }

    /// `z_cell` at the current time.
    pub fn output(&self) -> &[f64] {
        &self.z
    }

    /// Advances by `h` with `f_cell` and `pier_z` held, then updates the output: the retained
    /// modes at `t + h` plus the static correction with these (the step's) inputs.
    pub fn step(&mut self, h: f64, f_cell: &[f64], pier_z: f64) -> Result<(), M1Error> {
        if f_cell.len() != self.na {
            return Err(M1Error::SizeMismatch {
                what: "f_cell",
                expected: self.na,
                found: f_cell.len(),
            });
        }
        if !(h.is_finite() && h > 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "communication step",
                value: h,
                reason: "must be finite and > 0",
            });
        }
        if h != self.h {
            let (ad, bd): (Vec<_>, Vec<_>) = self
                .omega
                .iter()
                .zip(&self.zeta)
                .map(|(&w, &z)| zoh_mode(w, z, h))
                .unzip();
            self.ad = ad;
            self.bd = bd;
            self.h = h;
        }
        let n = self.n;
        self.modal_force(f_cell);
        for j in 0..n {
            let (a, b) = (&self.ad[j], &self.bd[j]);
            let (q, v) = (self.q[j], self.v[j]);
            let u = self.u[j] + self.b_pier[j] * pier_z;
            self.q[j] = a[0] * q + a[1] * v + b[0] * u;
            self.v[j] = a[2] * q + a[3] * v + b[1] * u;
        }
        self.write_output(f_cell, pier_z);
        Ok(())
    }

    /// The quasi-static structure: every retained mode at its static deflection under `f_cell`
    /// and `pier_z` (no inertia), the output written as after a step. With a static
    /// correction (the built-in FE model's exact solve, or an imported compliance) the output
    /// is the exact static response; without one, the retained modes' static sum.
    ///
    /// # Errors
    /// A wrong length of `f_cell`.
    pub fn settle(&mut self, f_cell: &[f64], pier_z: f64) -> Result<(), M1Error> {
        if f_cell.len() != self.na {
            return Err(M1Error::SizeMismatch {
                what: "f_cell",
                expected: self.na,
                found: f_cell.len(),
            });
        }
        self.modal_force(f_cell);
        for j in 0..self.n {
            self.q[j] = self.inv_w2[j] * (self.u[j] + self.b_pier[j] * pier_z);
            self.v[j] = 0.0;
        }
        self.write_output(f_cell, pier_z);
        Ok(())
    }

    /// The modal force of `f_cell` into `u`: `u = Phi^T f` (rows of Phi are contiguous; the
    /// pier's part is added by the callers).
    fn modal_force(&mut self, f_cell: &[f64]) {
        self.u.fill(0.0);
        for (row, &f) in self.phi.chunks_exact(self.n).zip(f_cell) {
            if f != 0.0 {
                for (u, p) in self.u.iter_mut().zip(row) {
                    *u += p * f;
                }
            }
        }
    }

    /// `z = Phi (q - Omega^-2 u) + G f + g_p p` (or `Phi q` without static correction), with
    /// `u` the modal force of `f`, `p` (of each input that has a static correction).
    fn write_output(&mut self, f: &[f64], p: f64) {
        let n = self.n;
        // Which inputs have a static correction: their quasi-static modal part is replaced by
        // the exact static response.
        let (cf, cp) = match &self.flex {
            Flexibility::None => (0.0, 0.0),
            Flexibility::Dense { cell, pier } => (
                if cell.is_some() { 1.0 } else { 0.0 },
                if pier.is_some() { 1.0 } else { 0.0 },
            ),
            Flexibility::FiniteElement(_) => (1.0, 1.0),
        };
        // Reuse u (the modal force of f) as the effective modal coordinate.
        for j in 0..n {
            let quasi_static = cf * self.u[j] + cp * self.b_pier[j] * p;
            self.u[j] = self.q[j] - self.inv_w2[j] * quasi_static;
        }
        for (z, row) in self.z.iter_mut().zip(self.phi.chunks_exact(n)) {
            *z = row.iter().zip(&self.u).map(|(a, b)| a * b).sum();
        }
        match &self.flex {
            Flexibility::None => {}
            Flexibility::Dense { cell, pier } => {
                if let Some(g) = cell {
                    for (z, row) in self.z.iter_mut().zip(g.chunks_exact(self.na)) {
                        *z += row.iter().zip(f).map(|(a, b)| a * b).sum::<f64>();
                    }
                }
                if let Some(g) = pier {
                    for (z, gp) in self.z.iter_mut().zip(g) {
                        *z += gp * p;
                    }
                }
            }
            Flexibility::FiniteElement(s) => {
                s.apply(f, p, &mut self.work, &mut self.zs);
                for (z, o) in self.z.iter_mut().zip(&self.zs) {
                    *z += o;
                }
            }
        }
    }
}
