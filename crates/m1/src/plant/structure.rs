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

use std::f64::consts::TAU;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::{Geometry, GeometryParams};
use crate::aperture::layout::Layout;
use crate::linalg::npy::{NpyArray, Npz};
use crate::linalg::skyline::Skyline;

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

// ------------------------------------------------------------------------------------------
// The finite-element mirror-cell model
// ------------------------------------------------------------------------------------------

/// One actuator attachment: `z = x[dof] + c[1] x[dof + 1] + c[2] x[dof + 2]` (`c[0] = 1`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Attachment {
    /// First degree of freedom (`w`) of the segment's node.
    pub dof: usize,
    /// Coefficients of `(w, theta_x, theta_y)`: `(1, dy, -dx)`.
    pub coef: [f64; 3],
}

/// The assembled finite-element model of the mirror cell on its mount and pier.
#[derive(Debug, Clone, PartialEq)]
pub struct CellModel {
    /// Number of degrees of freedom, `3 N + 1` (the mount's is the last).
    pub ndof: usize,
    /// Stiffness matrix, dense row-major `ndof x ndof` (N/m, N, N.m per unit dof).
    pub stiffness: Vec<f64>,
    /// Diagonal of the (lumped) mass matrix (kg, kg.m2).
    pub mass: Vec<f64>,
    /// The attachment of every actuator, in actuator order.
    pub attachments: Vec<Attachment>,
    /// The mount's degree of freedom (where the pier spring acts).
    pub pier_dof: usize,
    /// Pier spring `k_p` (N/m).
    pub k_pier: f64,
    /// Support spring `k_s` of each support node (N/m).
    pub k_support: f64,
    /// Grillage bending stiffness `EI` (N.m2).
    pub bending_stiffness: f64,
    /// Segment indices of the support nodes.
    pub support_nodes: Vec<usize>,
}

/// Adds the stiffness of a grillage beam between the nodes whose first dofs are `dofs`
/// (length `len`, in-plane direction `e`, section `[EI, GJ]`) to `k` (`n x n`, row-major).
fn add_beam(k: &mut [f64], n: usize, dofs: [usize; 2], len: f64, e: [f64; 2], section: [f64; 2]) {
    let [d1, d2] = dofs;
    let [ei, gj] = section;
    let l = len;
    let b = ei / (l * l * l);
    let kb = [
        [12.0 * b, 6.0 * l * b, -12.0 * b, 6.0 * l * b],
        [6.0 * l * b, 4.0 * l * l * b, -6.0 * l * b, 2.0 * l * l * b],
        [-12.0 * b, -6.0 * l * b, 12.0 * b, -6.0 * l * b],
        [6.0 * l * b, 2.0 * l * l * b, -6.0 * l * b, 4.0 * l * l * b],
    ];
    let t = gj / l;
    // Local (w1, phi1, w2, phi2, t1, t2) from global (w1, tx1, ty1, w2, tx2, ty2).
    let [ex, ey] = e;
    let tr: [[f64; 6]; 6] = [
        [1.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, ey, -ex, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, ey, -ex],
        [0.0, ex, ey, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, ex, ey],
    ];
    let mut kl = [[0.0; 6]; 6];
    for i in 0..4 {
        kl[i][..4].copy_from_slice(&kb[i]);
    }
    kl[4][4] = t;
    kl[4][5] = -t;
    kl[5][4] = -t;
    kl[5][5] = t;
    let dofs = [d1, d1 + 1, d1 + 2, d2, d2 + 1, d2 + 2];
    for a in 0..6 {
        for c in 0..6 {
            let mut s = 0.0;
            for p in 0..6 {
                for q in 0..6 {
                    s += tr[p][a] * kl[p][q] * tr[q][c];
                }
            }
            k[dofs[a] * n + dofs[c]] += s;
        }
    }
}

impl CellModel {
    /// Assembles the model for `layout` (see the module documentation).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for a bad parameter, [`M1Error::InvalidInput`] for a layout
    /// without shared edges or with fewer than three support nodes, [`M1Error::Numerical`] if
    /// the grillage is not connected (singular stiffness).
    pub fn new(layout: &Layout, p: &CellParams) -> Result<Self, M1Error> {
        p.validate()?;
        let nseg = layout.n_segments();
        if layout.edges.is_empty() {
            return Err(M1Error::InvalidInput(
                "the layout has no shared edges: the grillage needs beams between segments".into(),
            ));
        }
        let geo = Geometry::new(layout, GeometryParams::for_layout(layout))?;
        let centre = |i: usize| layout.segments[i].center;
        let pitch = {
            let mut d: Vec<f64> = layout
                .edges
                .iter()
                .map(|e| {
                    let (a, b) = (centre(e.i), centre(e.j));
                    (b[0] - a[0]).hypot(b[1] - a[1])
                })
                .collect();
            d.sort_by(f64::total_cmp);
            d[d.len() / 2]
        };
        // Node order: grid rows (y), then x, for a narrow envelope.
        let mut order: Vec<usize> = (0..nseg).collect();
        let key = |i: usize| ((centre(i)[1] * 1e6).round() as i64, centre(i)[0]);
        order.sort_by(|&a, &b| {
            let (ya, xa) = key(a);
            let (yb, xb) = key(b);
            ya.cmp(&yb).then(xa.total_cmp(&xb))
        });
        let mut node_of = vec![0; nseg];
        for (pos, &i) in order.iter().enumerate() {
            node_of[i] = pos;
        }
        let ndof = 3 * nseg + 1;
        let pier_dof = 3 * nseg;

        // Supports: the nodes within half a pitch of the support ring.
        let rmax = (0..nseg)
            .map(|i| centre(i)[0].hypot(centre(i)[1]))
            .fold(0.0, f64::max);
        let rs = p.support_radius * rmax;
        let mut support_nodes: Vec<usize> = (0..nseg)
            .filter(|&i| (centre(i)[0].hypot(centre(i)[1]) - rs).abs() <= 0.5 * pitch + 1e-9)
            .collect();
        if support_nodes.len() < 3 {
            let mut by_dist: Vec<usize> = (0..nseg).collect();
            by_dist.sort_by(|&a, &b| {
                let da = (centre(a)[0].hypot(centre(a)[1]) - rs).abs();
                let db = (centre(b)[0].hypot(centre(b)[1]) - rs).abs();
                da.total_cmp(&db)
            });
            support_nodes = by_dist.into_iter().take(3.min(nseg)).collect();
            support_nodes.sort_unstable();
        }
        if support_nodes.len() < 3 {
            return Err(M1Error::InvalidInput(
                "the cell needs at least three segments to rest on its supports".into(),
            ));
        }

        // Mass.
        let mc = p.cell_mass;
        let rot = mc * pitch * pitch / 12.0;
        let mut mass = vec![0.0; ndof];
        for pos in 0..nseg {
            mass[3 * pos] = mc;
            mass[3 * pos + 1] = rot;
            mass[3 * pos + 2] = rot;
        }
        let m_cell = mc * nseg as f64;
        mass[pier_dof] = p.mount_mass_ratio * m_cell;

        // Unit-EI grillage, then its lowest pinned mode for the EI scaling.
        let nc = 3 * nseg;
        let mut k1 = vec![0.0; nc * nc];
        for e in &layout.edges {
            let (a, b) = (centre(e.i), centre(e.j));
            let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
            let len = dx.hypot(dy);
            add_beam(
                &mut k1,
                nc,
                [3 * node_of[e.i], 3 * node_of[e.j]],
                len,
                [dx / len, dy / len],
                [1.0, p.torsion_ratio],
            );
        }
        let lambda1 = {
            let pinned: Vec<bool> = {
                let mut v = vec![false; nc];
                for &s in &support_nodes {
                    v[3 * node_of[s]] = true;
                }
                v
            };
            let keep: Vec<usize> = (0..nc).filter(|&d| !pinned[d]).collect();
            let nr = keep.len();
            let mut kr = vec![0.0; nr * nr];
            for (a, &da) in keep.iter().enumerate() {
                for (b, &db) in keep.iter().enumerate() {
                    kr[a * nr + b] = k1[da * nc + db];
                }
            }
            let mr: Vec<f64> = keep.iter().map(|&d| mass[d]).collect();
            lowest_eigenvalue(nr, &kr, &mr)?
        };
        let ei = (TAU * p.cell_frequency).powi(2) / lambda1;
        let k_support = (TAU * p.support_frequency).powi(2) * m_cell / support_nodes.len() as f64;
        let k_pier = (TAU * p.mount_frequency).powi(2) * (m_cell + mass[pier_dof]);

        let mut stiffness = vec![0.0; ndof * ndof];
        for i in 0..nc {
            for j in 0..nc {
                stiffness[i * ndof + j] = ei * k1[i * nc + j];
            }
        }
        for &s in &support_nodes {
            let d = 3 * node_of[s];
            stiffness[d * ndof + d] += k_support;
            stiffness[pier_dof * ndof + pier_dof] += k_support;
            stiffness[d * ndof + pier_dof] -= k_support;
            stiffness[pier_dof * ndof + d] -= k_support;
        }
        stiffness[pier_dof * ndof + pier_dof] += k_pier;

        let mut attachments = Vec::with_capacity(3 * nseg);
        for (i, frame) in geo.segments.iter().enumerate() {
            let c = centre(i);
            for a in &frame.actuators {
                let (dx, dy) = (a[0] - c[0], a[1] - c[1]);
                attachments.push(Attachment {
                    dof: 3 * node_of[i],
                    coef: [1.0, dy, -dx],
                });
            }
        }
        Ok(Self {
            ndof,
            stiffness,
            mass,
            attachments,
            pier_dof,
            k_pier,
            k_support,
            bending_stiffness: ei,
            support_nodes,
        })
    }

    /// Number of actuators `na`.
    pub fn n_actuators(&self) -> usize {
        self.attachments.len()
    }

    /// The generalised load `T^T f_cell + k_p e_m pier_z` (length `ndof`).
    pub fn load(&self, f_cell: &[f64], pier_z: f64, out: &mut [f64]) {
        out.fill(0.0);
        for (a, f) in self.attachments.iter().zip(f_cell) {
            for (k, c) in a.coef.iter().enumerate() {
                out[a.dof + k] += c * f;
            }
        }
        out[self.pier_dof] += self.k_pier * pier_z;
    }

    /// The displacements at the attachments, `T x`.
    pub fn attach(&self, x: &[f64], z: &mut [f64]) {
        attach(&self.attachments, x, z);
    }

    /// The static deflection `z_cell = T K^-1 (T^T f + k_p e_m pier_z)` (dense-free: envelope
    /// Cholesky of `K`).
    pub fn static_deflection(&self, f_cell: &[f64], pier_z: f64) -> Result<Vec<f64>, M1Error> {
        let s = StaticFe::new(self)?;
        let mut z = vec![0.0; self.n_actuators()];
        let mut work = vec![0.0; self.ndof];
        s.apply(f_cell, pier_z, &mut work, &mut z);
        Ok(z)
    }

    /// Every mode of the model (dense self-adjoint eigensolve of `M^-1/2 K M^-1/2`), with the
    /// exact static correction of the FE model attached.
    pub fn modes(&self) -> Result<ModalModel, M1Error> {
        let n = self.ndof;
        let d: Vec<f64> = self.mass.iter().map(|m| 1.0 / m.sqrt()).collect();
        let kt = faer::Mat::<f64>::from_fn(n, n, |i, j| {
            // Symmetrise exactly (the lower triangle is what the solver reads).
            0.5 * (self.stiffness[i * n + j] + self.stiffness[j * n + i]) * d[i] * d[j]
        });
        let evd = kt
            .self_adjoint_eigen(faer::Side::Lower)
            .map_err(|e| M1Error::Numerical(format!("eigensolve of the cell model: {e:?}")))?;
        let u = evd.U();
        let s = evd.S().column_vector();
        let mut frequencies = Vec::with_capacity(n);
        for j in 0..n {
            let lam = s[j];
            if lam.is_nan() || lam <= 0.0 {
                return Err(M1Error::Numerical(format!(
                    "mode {j} of the cell model has eigenvalue {lam:e} <= 0"
                )));
            }
            frequencies.push(lam.sqrt() / TAU);
        }
        let na = self.n_actuators();
        let mut phi_cell = vec![0.0; na * n];
        for (r, a) in self.attachments.iter().enumerate() {
            let row = &mut phi_cell[r * n..(r + 1) * n];
            for (j, v) in row.iter_mut().enumerate() {
                *v = (0..3)
                    .map(|k| a.coef[k] * d[a.dof + k] * u[(a.dof + k, j)])
                    .sum();
            }
        }
        let phi_pier = (0..n)
            .map(|j| d[self.pier_dof] * u[(self.pier_dof, j)])
            .collect();
        Ok(ModalModel {
            na,
            frequencies,
            damping_ratios: None,
            phi_cell,
            phi_pier,
            k_pier: self.k_pier,
            flexibility: Flexibility::FiniteElement(StaticFe::new(self)?),
        })
    }
}

fn attach(att: &[Attachment], x: &[f64], z: &mut [f64]) {
    for (zi, a) in z.iter_mut().zip(att) {
        *zi = a.coef[0] * x[a.dof] + a.coef[1] * x[a.dof + 1] + a.coef[2] * x[a.dof + 2];
    }
}

/// Lowest eigenvalue of `K x = lambda M x` (`M` diagonal) by inverse iteration with the
/// Rayleigh quotient (envelope Cholesky of `K`).
fn lowest_eigenvalue(n: usize, k: &[f64], m: &[f64]) -> Result<f64, M1Error> {
    let chol = Skyline::factor(n, k).map_err(|_| {
        M1Error::Numerical(
            "the grillage pinned at its supports is singular (a segment not connected by shared \
             edges?)"
                .into(),
        )
    })?;
    // A deterministic start with components along every mode.
    let mut x: Vec<f64> = (0..n).map(|i| 1.0 + 0.5 * (1.7 * i as f64).sin()).collect();
    let mut rho = f64::INFINITY;
    let mut y = vec![0.0; n];
    for _ in 0..500 {
        for i in 0..n {
            y[i] = m[i] * x[i];
        }
        let mx = y.clone();
        chol.solve_in_place(&mut y);
        let ymx: f64 = y.iter().zip(&mx).map(|(a, b)| a * b).sum();
        let ymy: f64 = y.iter().zip(m).map(|(a, b)| a * a * b).sum();
        let new = ymx / ymy;
        let norm = ymy.sqrt();
        for (xi, yi) in x.iter_mut().zip(&y) {
            *xi = yi / norm;
        }
        let done = (rho - new).abs() <= 1e-13 * new;
        rho = new;
        if done {
            break;
        }
    }
    Ok(rho)
}

// ------------------------------------------------------------------------------------------
// Modal models
// ------------------------------------------------------------------------------------------

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

// ------------------------------------------------------------------------------------------
// Exact discrete-time simulation
// ------------------------------------------------------------------------------------------

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
