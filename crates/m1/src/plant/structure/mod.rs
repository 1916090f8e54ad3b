//! The telescope structure seen by M1: a parametric mirror-cell finite-element model, modal
//! models (built in, or imported from a NumPy `.npz` file exported from the user's FE model),
//! and their exact discrete-time simulation with static correction of the truncated modes.
//!
//! # Signals
//!
//! Inputs: `f_cell` (N, length `na = 3 N`), the force of each actuator on the mirror cell,
//! positive along +z (towards the sky); `pier_z` (m), the vertical motion of the pier.
//! Output: `z_cell` (m, length `na`), the cell displacement at each actuator attachment, +z.
//! Actuator `k` of segment `i` has index `3 i + k`.
//!
//! # Built-in mirror-cell model ([`CellModel`])
//!
//! A beam grillage with one node at every segment centre and one Euler-Bernoulli beam (bending
//! stiffness `EI`, torsion stiffness `GJ`) along every shared edge of the layout. Each node has
//! three degrees of freedom: vertical displacement `w` and rotations `theta_x`, `theta_y` about
//! the x and y axes. The three actuator attachment points of a segment are rigid offsets of its
//! node: with `(dx, dy)` the attachment point minus the segment centre in the aperture plane,
//!
//! ```text
//!   z_cell = w + theta_x dy - theta_y dx
//! ```
//!
//! (the rows of the attachment matrix `T`, `z_cell = T x`, and the actuator forces load the
//! model as `T^T f_cell`). A beam from node 1 to node 2 (length `L`, in-plane direction
//! `e = (e_x, e_y)`) has the bending slope `phi = dw/ds = theta_x e_y - theta_y e_x` and the
//! torsion angle `t = theta_x e_x + theta_y e_y` at each end, and the usual stiffness
//!
//! ```text
//!   K_bend = EI/L^3 [[12, 6L, -12, 6L], [6L, 4L^2, -6L, 2L^2], [-12, -6L, 12, -6L],
//!                    [6L, 2L^2, -6L, 4L^2]]   on (w1, phi1, w2, phi2),
//!   K_tors = GJ/L [[1, -1], [-1, 1]]          on (t1, t2),
//! ```
//!
//! so a rigid tilt of the whole grillage strains nothing. Each node carries the lumped cell mass
//! `m_c` ([`CellParams::cell_mass`]) and the rotary inertia `m_c p^2 / 12` of a square patch of
//! side the segment pitch `p` about both in-plane axes. The mirror segments themselves are *not*
//! in this model: the segments FMU carries them and loads the cell through `f_cell`.
//!
//! The cell rests on the mount through vertical support springs `k_s` at the *support nodes*
//! (the ring of nodes within half a pitch of the radius `support_radius x r_max`, `r_max` the
//! largest centre radius). The mount is one vertical degree of freedom `w_m` with mass
//! `M_m = mount_mass_ratio x N m_c`, on the pier through the spring `k_p`. Pier motion is a base
//! excitation through that spring: the pier pushes the mount with `k_p (pier_z - w_m)`, i.e. a
//! force `k_p pier_z` on the mount's degree of freedom of a model whose `k_p` is grounded
//! ("large-spring" base excitation; at DC the whole structure follows the pier rigidly).
//!
//! The stiffnesses are set from three *target* frequencies, so that the same defaults give a
//! realistic structure for every layout size:
//! - `k_p = (2 pi f_mount)^2 (N m_c + M_m)`: the rigid cell and the mount bouncing on the pier;
//! - `k_s = (2 pi f_support)^2 N m_c / n_s`: the rigid cell bouncing on its `n_s` supports;
//! - `EI = (2 pi f_cell)^2 / lambda_1`, with `lambda_1` the lowest eigenvalue of the grillage
//!   with unit `EI` (and `GJ / EI = torsion_ratio`) pinned at its supports (`w = 0` there):
//!   `f_cell` is the first elastic mode of the cell on rigid supports.
//!
//! The coupled modes of the assembly ([`CellModel::modes`], one dense self-adjoint eigensolve of
//! `M^-1/2 K M^-1/2`, `3 N + 1` degrees of freedom: 1477 for TMT) lie below and between these
//! targets; the defaults (10, 30 and 15 Hz) give a first mode of 9.1 Hz for Keck and 6.3 Hz for
//! TMT, and a number of modes per octave that grows with frequency, as in real telescopes.
//! When only the lowest few are retained ([`CellModel::lowest_modes`], the FMUs' `n_modes`),
//! they are found without the others by block Lanczos on the envelope factor of `K`
//! ([`crate::linalg::lanczos`]): TMT's 60 lowest in about 60 ms instead of 0.4 s
//! (`cargo bench -p m1 --bench setup`).
//!
//! # Modal model ([`ModalModel`]) and its simulation ([`ModalSolver`])
//!
//! With mass-normalised modes `Phi` (`Phi^T M Phi = I`, `Phi^T K Phi = Omega^2`), modal
//! coordinates `q` and proportional (modal) damping `zeta_j`:
//!
//! ```text
//!   q_j'' + 2 zeta_j w_j q_j' + w_j^2 q_j = u_j,   u = Phi_a^T f_cell + k_p phi_p pier_z,
//!   z_cell = Phi_a q + R (f_cell, pier_z),
//! ```
//!
//! with `Phi_a = T Phi` (`na x n`, the shapes at the attachments) and `phi_p` the shapes at the
//! pier spring's node. Only the `n_modes` lowest modes are integrated; the static response of
//! the truncated ones is added back (static correction, residual flexibility):
//! `R(f, p) = G f + g_p p - Phi_a Omega^-2 u`, with `G` the static compliance at the
//! attachments and `g_p` the static response to a unit pier motion. With all modes retained `R`
//! vanishes; at DC the output is the exact static deflection `G f + g_p p` for any `n_modes`.
//! For the built-in model `G f + g_p p = T K^-1 (T^T f + k_p e_m p)` is computed by a sparse
//! (envelope) Cholesky solve of the FE stiffness, without forming `G`.
//!
//! Each mode is integrated exactly over a communication step `h` with the inputs held (zero-order
//! hold): `x_{k+1} = A_d x_k + B_d u` with `x = (q, q')`, `A_d = exp(A h)`,
//! `A = [[0, 1], [-w^2, -2 zeta w]]` and `B_d = A^-1 (A_d - I) [0, 1]^T`. All modes are stored
//! in contiguous arrays; a step costs two products with the dense `na x n` shape matrix plus
//! the static correction.
//!
//! **No direct feedthrough.** The segments' `f_cell` depends directly on `z_cell`; to avoid an
//! algebraic loop, `z_cell` does not depend on the *current* inputs: the static correction uses
//! the inputs held over the last completed step (the ones that drove that step). The quasi-static
//! residual of the truncated modes therefore lags the inputs by one communication step; the
//! retained modes are exact.
//!
//! # Importing a modal model: the `.npz` format ([`ModalModel::from_npz`])
//!
//! A NumPy `.npz` archive (`numpy.savez` or `numpy.savez_compressed`) of little-endian float64
//! arrays (`<f8`, C or Fortran order, NPY format 1.0, 2.0 or 3.0), `n` modes, `na` actuators:
//!
//! | array | shape | unit | meaning |
//! |---|---|---|---|
//! | `frequencies` | `(n,)` | Hz | natural frequencies, all > 0 (ground the model) |
//! | `phi_cell` | `(na, n)` | 1/sqrt(kg) | mass-normalised mode shapes, vertical displacement at the actuator attachments |
//! | `phi_pier` | `(n,)` | 1/sqrt(kg) | mode shapes at the node where the pier spring attaches |
//! | `k_pier` | `()` or `(1,)` | N/m | the pier spring (grounded in the FE model used for the modes) |
//! | `damping_ratios` | `(n,)` | 1 | optional: modal damping (default: the `damping_ratio` parameter for every mode) |
//! | `flexibility` | `(na, na)` | m/N | optional: static compliance `K^-1` at the attachments, symmetric; enables the static correction |
//! | `static_pier` | `(na,)` | m/m | optional: static `z_cell` per metre of `pier_z` (all ones if the pier spring is the only ground); static correction of the pier input |
//!
//! Modes are used in increasing frequency. Without `flexibility` (or `static_pier`) the force
//! (or pier) input has no static correction: the truncated modal sum only. With `flexibility`,
//! a step costs `O(na^2)` more (a dense product).

mod cell;
mod modal;
mod solver;

pub use cell::{Attachment, CellModel, PARTIAL_FRACTION};
pub use modal::{Flexibility, ModalModel, StaticFe};
pub use solver::{ModalSolver, zoh_mode};

use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::layout::Layout;

// ------------------------------------------------------------------------------------------
// Parameters
// ------------------------------------------------------------------------------------------

/// Parameters of the built-in mirror-cell model (all *assumed*; defaults stated per field).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CellParams {
    /// Cell structural mass lumped at each segment node (kg). Default 500 kg.
    pub cell_mass: f64,
    /// Mount mass as a multiple of the total cell mass (1). Default 2.
    pub mount_mass_ratio: f64,
    /// Target bounce frequency of the rigid cell and the mount on the pier spring (Hz).
    /// Default 10 Hz.
    pub mount_frequency: f64,
    /// Target bounce frequency of the rigid cell on its supports, mount held (Hz). Default 30 Hz.
    pub support_frequency: f64,
    /// Target first elastic mode of the cell grillage pinned at its supports (Hz). Default 15 Hz.
    pub cell_frequency: f64,
    /// Torsion to bending stiffness ratio `GJ / EI` of the grillage beams (1). Default 0.5.
    pub torsion_ratio: f64,
    /// Radius of the support ring as a fraction of the largest segment-centre radius (1).
    /// Default 0.65.
    pub support_radius: f64,
}

impl Default for CellParams {
    /// The [`StructurePreset::Tmt`] preset.
    fn default() -> Self {
        Self::tmt()
    }
}

impl CellParams {
    /// The `tmt` preset (the default): a TMT-representative mirror cell (see
    /// [`StructurePreset::Tmt`] for the published statement each value serves).
    pub fn tmt() -> Self {
        Self {
            cell_mass: 1000.0,
            mount_mass_ratio: 2.0,
            mount_frequency: 10.0,
            support_frequency: 30.0,
            cell_frequency: 15.0,
            torsion_ratio: 0.5,
            support_radius: 0.85,
        }
    }

    /// The `soft-cell` preset: the first built-in cell (500 kg per node on a ring at 0.65 of
    /// the radius), whose modes near 6-10 Hz limit both loops: a study of a cell too soft for
    /// a 1 Hz global loop ([`StructurePreset::SoftCell`]).
    pub fn soft_cell() -> Self {
        Self {
            cell_mass: 500.0,
            mount_mass_ratio: 2.0,
            mount_frequency: 10.0,
            support_frequency: 30.0,
            cell_frequency: 15.0,
            torsion_ratio: 0.5,
            support_radius: 0.65,
        }
    }
}

/// Name of the default structure preset (`tmt`).
pub const DEFAULT_STRUCTURE: &str = "tmt";

/// The named parameter sets of the built-in structure (`--structure NAME`, the FMUs'
/// `structure` parameter).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum StructurePreset {
    /// `tmt` (the default): TMT-representative; the segment-support resonances, not the cell's
    /// modes, limit the servo and the global loop.
    Tmt,
    /// `soft-cell`: the first built-in cell, too soft for a 1 Hz global loop.
    SoftCell,
}

impl StructurePreset {
    /// Every preset, the default first.
    pub const ALL: [StructurePreset; 2] = [StructurePreset::Tmt, StructurePreset::SoftCell];

    /// The preset's name.
    pub fn name(self) -> &'static str {
        match self {
            StructurePreset::Tmt => "tmt",
            StructurePreset::SoftCell => "soft-cell",
        }
    }

    /// The preset called `name`, if any.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// Its parameters.
    pub fn params(self) -> CellParams {
        match self {
            StructurePreset::Tmt => CellParams::tmt(),
            StructurePreset::SoftCell => CellParams::soft_cell(),
        }
    }

    /// The names of every preset, comma-separated (for messages).
    pub fn names() -> String {
        Self::ALL.map(Self::name).join(", ")
    }
}

/// Where a plant's structure comes from: a preset of the built-in cell, or a modal model file.
#[derive(Debug, Clone, PartialEq)]
pub enum StructureSource {
    /// The built-in cell with these parameters.
    BuiltIn(CellParams),
    /// A `.npz` modal model ([`ModalModel::from_npz`]).
    File(std::path::PathBuf),
}

impl StructureSource {
    /// A preset name or the path of a `.npz` file.
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] naming the presets if `name` is neither a preset nor a
    /// `.npz` path.
    pub fn parse(name: &str) -> Result<Self, M1Error> {
        let name = name.trim();
        if let Some(p) = StructurePreset::from_name(name) {
            return Ok(Self::BuiltIn(p.params()));
        }
        if name.to_ascii_lowercase().ends_with(".npz") {
            return Ok(Self::File(name.into()));
        }
        Err(M1Error::InvalidInput(format!(
            "structure \"{name}\": not a preset ({}) nor the path of a .npz modal model",
            StructurePreset::names()
        )))
    }

    /// The `r` lowest modes of the structure for `layout` (a file's modes are all read, the
    /// solver keeps the lowest): [`CellModel::lowest_modes`] for the built-in cell.
    ///
    /// # Errors
    /// As [`Self::modes`].
    pub fn lowest_modes(&self, layout: &Layout, r: usize) -> Result<ModalModel, M1Error> {
        match self {
            Self::BuiltIn(p) => CellModel::new(layout, p)?.lowest_modes(r),
            Self::File(path) => ModalModel::from_npz(path, layout.n_actuators()),
        }
    }

    /// Every mode of the structure for `layout` (`na = 3 N` attachments).
    ///
    /// # Errors
    /// From [`CellModel::new`], [`CellModel::modes`] or [`ModalModel::from_npz`].
    pub fn modes(&self, layout: &Layout) -> Result<ModalModel, M1Error> {
        match self {
            Self::BuiltIn(p) => CellModel::new(layout, p)?.modes(),
            Self::File(path) => ModalModel::from_npz(path, layout.n_actuators()),
        }
    }
}

impl CellParams {
    /// Checks every field (finite and positive; `support_radius` in (0, 1]).
    pub fn validate(&self) -> Result<(), M1Error> {
        for (name, value) in self.named() {
            if name != "support_radius" && !(value.is_finite() && value > 0.0) {
                return Err(M1Error::InvalidParameter {
                    name,
                    value,
                    reason: "must be finite and > 0",
                });
            }
        }
        if !(self.support_radius > 0.0 && self.support_radius <= 1.0) {
            return Err(M1Error::InvalidParameter {
                name: "support_radius",
                value: self.support_radius,
                reason: "must be in (0, 1]",
            });
        }
        Ok(())
    }

    /// Every field with its parameter name (the FMUs' variable names), in declaration order.
    pub fn named(&self) -> [(&'static str, f64); 7] {
        [
            ("cell_mass", self.cell_mass),
            ("mount_mass_ratio", self.mount_mass_ratio),
            ("mount_frequency", self.mount_frequency),
            ("support_frequency", self.support_frequency),
            ("cell_frequency", self.cell_frequency),
            ("torsion_ratio", self.torsion_ratio),
            ("support_radius", self.support_radius),
        ]
    }
}
