//! Modal models of the structure seen by M1: modes at the actuator attachments and the pier,
//! with their optional static correction (dense compliance, or the FE model's exact solve), and
//! the `.npz` import.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::cell::attach;
use super::{Attachment, CellModel};
use crate::M1Error;
use crate::linalg::npy::{NpyArray, Npz};
use crate::linalg::skyline::Skyline;

/// The exact static response of the built-in FE model, `T K^-1 (T^T f + k_p e_m p)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StaticFe {
    chol: Skyline,
    attachments: Vec<Attachment>,
    pier_dof: usize,
    k_pier: f64,
}

impl StaticFe {
    /// Factorises the model's stiffness.
    pub fn new(m: &CellModel) -> Result<Self, M1Error> {
        Ok(Self {
            chol: Skyline::factor(m.ndof, &m.stiffness)?,
            attachments: m.attachments.clone(),
            pier_dof: m.pier_dof,
            k_pier: m.k_pier,
        })
    }

    /// The static response of `m` on its stiffness factor `chol` (of `m.stiffness`).
    pub fn from_factor(m: &CellModel, chol: Skyline) -> Self {
        Self {
            chol,
            attachments: m.attachments.clone(),
            pier_dof: m.pier_dof,
            k_pier: m.k_pier,
        }
    }

    /// `z = T K^-1 (T^T f + k_p e_m p)`, `work` of length `ndof`.
    pub fn apply(&self, f: &[f64], p: f64, work: &mut [f64], z: &mut [f64]) {
        work.fill(0.0);
        for (a, fi) in self.attachments.iter().zip(f) {
            for (k, c) in a.coef.iter().enumerate() {
                work[a.dof + k] += c * fi;
            }
        }
        work[self.pier_dof] += self.k_pier * p;
        self.chol.solve_in_place(work);
        attach(&self.attachments, work, z);
    }

    /// Degrees of freedom.
    pub fn ndof(&self) -> usize {
        self.chol.dim()
    }
}

/// The static response used for the static correction.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Flexibility {
    /// None: the truncated modal sum only.
    None,
    /// Dense compliance at the attachments `G` (`na x na`, row-major, m/N) and optionally the
    /// static response to the pier `g_p` (m/m).
    Dense {
        /// `G`.
        cell: Option<Vec<f64>>,
        /// `g_p`.
        pier: Option<Vec<f64>>,
    },
    /// The built-in FE model's exact static solve.
    FiniteElement(StaticFe),
}

/// A modal model of the structure: `n` modes seen at the `na` attachments and at the pier.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModalModel {
    /// Number of actuators.
    pub na: usize,
    /// Natural frequencies (Hz), > 0.
    pub frequencies: Vec<f64>,
    /// Modal damping ratios, if the model carries its own.
    pub damping_ratios: Option<Vec<f64>>,
    /// Mass-normalised shapes at the attachments, `na x n` row-major (1/sqrt(kg)).
    pub phi_cell: Vec<f64>,
    /// Mass-normalised shapes at the pier spring's node (1/sqrt(kg)).
    pub phi_pier: Vec<f64>,
    /// Pier spring (N/m).
    pub k_pier: f64,
    /// Static response for the static correction.
    pub flexibility: Flexibility,
}

impl ModalModel {
    /// Number of modes.
    pub fn n_modes(&self) -> usize {
        self.frequencies.len()
    }

    /// Reads a modal model from a NumPy `.npz` file (format in the module documentation) and
    /// checks it against the number of actuators `na`.
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] naming the file and the array at fault.
    pub fn from_npz(path: &Path, na: usize) -> Result<Self, M1Error> {
        let mut npz = Npz::open(path)?;
        let file = path.display().to_string();
        let bad = |array: &str, why: String| {
            M1Error::InvalidInput(format!("{file}: array '{array}': {why}"))
        };
        let freq = npz.require("frequencies")?;
        if freq.shape.len() != 1 || freq.shape[0] == 0 {
            return Err(bad(
                "frequencies",
                format!("shape {:?}, expected (n,) with n >= 1", freq.shape),
            ));
        }
        let n = freq.shape[0];
        for (j, f) in freq.data.iter().enumerate() {
            if !(f.is_finite() && *f > 0.0) {
                return Err(bad(
                    "frequencies",
                    format!(
                        "element {j} is {f}: every frequency must be finite and > 0 (rigid-body \
                         modes are not supported: ground the model through the pier spring)"
                    ),
                ));
            }
        }
        let expect = |a: &NpyArray, name: &str, shape: &[usize]| -> Result<(), M1Error> {
            let scalar_ok = shape.is_empty() && a.data.len() == 1 && a.shape.len() <= 1;
            if a.shape != shape && !scalar_ok {
                return Err(bad(
                    name,
                    format!("shape {:?}, expected {:?}", a.shape, shape),
                ));
            }
            if let Some(i) = a.data.iter().position(|x| !x.is_finite()) {
                return Err(bad(name, format!("element {i} is not finite")));
            }
            Ok(())
        };
        let phi_cell = npz.require("phi_cell")?;
        expect(&phi_cell, "phi_cell", &[na, n])?;
        let phi_pier = npz.require("phi_pier")?;
        expect(&phi_pier, "phi_pier", &[n])?;
        let k_pier = npz.require("k_pier")?;
        expect(&k_pier, "k_pier", &[])?;
        let k_pier = k_pier.data[0];
        if k_pier <= 0.0 {
            return Err(bad("k_pier", format!("{k_pier} must be > 0")));
        }
        let damping_ratios = match npz.optional("damping_ratios")? {
            Some(d) => {
                expect(&d, "damping_ratios", &[n])?;
                if let Some(i) = d.data.iter().position(|z| *z < 0.0) {
                    return Err(bad("damping_ratios", format!("element {i} is negative")));
                }
                Some(d.data)
            }
            None => None,
        };
        let cell = match npz.optional("flexibility")? {
            Some(g) => {
                expect(&g, "flexibility", &[na, na])?;
                let scale = g.data.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
                for i in 0..na {
                    for j in 0..i {
                        let (a, b) = (g.data[i * na + j], g.data[j * na + i]);
                        if (a - b).abs() > 1e-9 * scale {
                            return Err(bad(
                                "flexibility",
                                format!("not symmetric: [{i}, {j}] = {a:e}, [{j}, {i}] = {b:e}"),
                            ));
                        }
                    }
                }
                Some(g.data)
            }
            None => None,
        };
        let pier = match npz.optional("static_pier")? {
            Some(g) => {
                expect(&g, "static_pier", &[na])?;
                Some(g.data)
            }
            None => None,
        };
        let flexibility = if cell.is_none() && pier.is_none() {
            Flexibility::None
        } else {
            Flexibility::Dense { cell, pier }
        };
        Ok(Self {
            na,
            frequencies: freq.data,
            damping_ratios,
            phi_cell: phi_cell.data,
            phi_pier: phi_pier.data,
            k_pier,
            flexibility,
        })
    }
}
