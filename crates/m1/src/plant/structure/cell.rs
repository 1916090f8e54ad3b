//! The built-in finite-element mirror cell: a beam grillage with one node per segment centre,
//! rigid offsets to the actuator attachments, support springs on a mount mass and the pier
//! spring; its assembly, its modes and its static solves.

use std::f64::consts::TAU;

use serde::{Deserialize, Serialize};

use super::{CellParams, Flexibility, ModalModel, StaticFe};
use crate::M1Error;
use crate::aperture::geometry::{Geometry, GeometryParams};
use crate::aperture::layout::Layout;
use crate::linalg::cache::{Fingerprint, Store};
use crate::linalg::lanczos;
use crate::linalg::skyline::Skyline;

/// [`CellModel::lowest_modes`] solves for the lowest `r` modes alone when `r` is at most
/// `ndof / PARTIAL_FRACTION`; above, the dense eigensolve of every mode costs about as much
/// (TMT, 1477 degrees of freedom: 0.47 s for the 300 lowest against 0.79-0.91 s for all,
/// `cargo bench -p m1 --bench setup`; 0.63-0.71 s for 369 or 450).
pub const PARTIAL_FRACTION: usize = 4;

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
    /// exact static correction of the FE model attached. The frequencies and shapes come from
    /// the on-disk cache when an earlier run computed them for the same stiffness, masses and
    /// attachments ([`crate::linalg::cache`]; `M1CS_CACHE=off` turns it off).
    ///
    /// # Errors
    /// A mode with a non-positive eigenvalue, or a failed eigensolve.
    pub fn modes(&self) -> Result<ModalModel, M1Error> {
        self.modes_in(&Store::from_env())
    }

    /// [`Self::modes`] with the cache `store`.
    ///
    /// # Errors
    /// As [`Self::modes`].
    pub fn modes_in(&self, store: &Store) -> Result<ModalModel, M1Error> {
        let (n, na) = (self.ndof, self.n_actuators());
        let key = self.fingerprint("modes");
        if let Some(m) = self.cached(store, &key, n) {
            return m;
        }
        let m = self.solve_modes()?;
        store.store(
            &key,
            &[
                ("frequencies", &[n], &m.frequencies),
                ("phi_cell", &[na, n], &m.phi_cell),
                ("phi_pier", &[n], &m.phi_pier),
            ],
        );
        Ok(m)
    }

    /// The `r` lowest modes of the model (all of them if `r >= ndof`), with the exact static
    /// correction attached, as [`Self::modes`] but without the dense eigensolve of every mode
    /// when `r` is at most a quarter of the degrees of freedom ([`PARTIAL_FRACTION`]; the two
    /// cost about the same from a third): block Lanczos on the envelope factor of `K`
    /// ([`crate::linalg::lanczos`]; `cargo bench -p m1 --bench setup` measures TMT's 30, 60,
    /// 147 and 300 lowest of 1477 modes against all of them). The modes are cached as
    /// [`Self::modes`]'s are, keyed by `r` too.
    ///
    /// The retained modes are the same as [`Self::modes`]'s lowest `r` up to the solvers'
    /// round-off, except that within a repeated frequency (the hexagonal cells' degenerate
    /// pairs) either solver picks its own basis: a cut at `r` between the two modes of a pair
    /// keeps a different, equally valid, mode of it.
    ///
    /// # Errors
    /// As [`Self::modes`], and [`M1Error::InvalidParameter`] for `r = 0`.
    pub fn lowest_modes(&self, r: usize) -> Result<ModalModel, M1Error> {
        self.lowest_modes_in(r, &Store::from_env())
    }

    /// [`Self::lowest_modes`] with the cache `store`.
    ///
    /// # Errors
    /// As [`Self::lowest_modes`].
    pub fn lowest_modes_in(&self, r: usize, store: &Store) -> Result<ModalModel, M1Error> {
        if r == 0 {
            return Err(M1Error::InvalidParameter {
                name: "n_modes",
                value: 0.0,
                reason: "must be >= 1",
            });
        }
        let n = self.ndof;
        if r.saturating_mul(PARTIAL_FRACTION) > n {
            return self.modes_in(store);
        }
        let mut key = self.fingerprint("modes-lowest");
        key.usizes(&[r]);
        if let Some(m) = self.cached(store, &key, r) {
            return m;
        }
        let chol = Skyline::factor(n, &self.stiffness)?;
        let Some(pairs) = lanczos::lowest_eigenpairs(&chol, &self.mass, r)? else {
            // Not converged within its space (not seen on the built-in cells): every mode.
            return self.modes_in(store);
        };
        let frequencies: Vec<f64> = pairs.values.iter().map(|l| l.sqrt() / TAU).collect();
        let x = |row: usize, j: usize| pairs.vectors[j * n + row];
        let (phi_cell, phi_pier) = self.shapes(r, x);
        store.store(
            &key,
            &[
                ("frequencies", &[r], &frequencies),
                ("phi_cell", &[self.n_actuators(), r], &phi_cell),
                ("phi_pier", &[r], &phi_pier),
            ],
        );
        Ok(self.modal_model_on(frequencies, phi_cell, phi_pier, chol))
    }

    /// The cache key of this model's modes of kind `kind`: the stiffness by its non-zero
    /// entries (row by row, with their columns: 1 % of TMT's dense matrix), the masses, the
    /// pier spring and the attachments.
    fn fingerprint(&self, kind: &'static str) -> Fingerprint {
        let n = self.ndof;
        let mut key = Fingerprint::new(kind);
        key.usizes(&[n, self.n_actuators(), self.pier_dof]);
        let (mut cols, mut vals) = (Vec::new(), Vec::new());
        for row in self.stiffness.chunks_exact(n) {
            cols.clear();
            vals.clear();
            for (j, &v) in row.iter().enumerate() {
                if v != 0.0 {
                    cols.push(j);
                    vals.push(v);
                }
            }
            key.usizes(&cols).f64s(&vals);
        }
        key.f64s(&self.mass).f64s(&[self.k_pier]);
        for a in &self.attachments {
            key.usizes(&[a.dof]).f64s(&a.coef);
        }
        key
    }

    /// The cached modal model of `r` modes under `key`, if any.
    fn cached(
        &self,
        store: &Store,
        key: &Fingerprint,
        r: usize,
    ) -> Option<Result<ModalModel, M1Error>> {
        let na = self.n_actuators();
        let mut arrays = store.load(key, &["frequencies", "phi_cell", "phi_pier"])?;
        if !(arrays[0].shape == [r] && arrays[1].shape == [na, r] && arrays[2].shape == [r]) {
            return None;
        }
        let phi_pier = arrays.pop().map(|a| a.data).unwrap_or_default();
        let phi_cell = arrays.pop().map(|a| a.data).unwrap_or_default();
        let frequencies = arrays.pop().map(|a| a.data).unwrap_or_default();
        Some(self.modal_model(frequencies, phi_cell, phi_pier))
    }

    /// The shapes at the attachments (`na x r` row-major) and at the pier of the `r`
    /// mass-normalised vectors `x(dof, mode)`.
    fn shapes(&self, r: usize, x: impl Fn(usize, usize) -> f64) -> (Vec<f64>, Vec<f64>) {
        let mut phi_cell = vec![0.0; self.n_actuators() * r];
        for (row, a) in phi_cell.chunks_exact_mut(r).zip(&self.attachments) {
            for (j, v) in row.iter_mut().enumerate() {
                *v = (0..3).map(|k| a.coef[k] * x(a.dof + k, j)).sum();
            }
        }
        let phi_pier = (0..r).map(|j| x(self.pier_dof, j)).collect();
        (phi_cell, phi_pier)
    }

    /// [`Self::modes`] computed (the dense eigensolve).
    fn solve_modes(&self) -> Result<ModalModel, M1Error> {
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
        let (phi_cell, phi_pier) = self.shapes(n, |row, j| d[row] * u[(row, j)]);
        self.modal_model(frequencies, phi_cell, phi_pier)
    }

    /// The modal model of these modes, with the FE model's exact static correction.
    fn modal_model(
        &self,
        frequencies: Vec<f64>,
        phi_cell: Vec<f64>,
        phi_pier: Vec<f64>,
    ) -> Result<ModalModel, M1Error> {
        let chol = Skyline::factor(self.ndof, &self.stiffness)?;
        Ok(self.modal_model_on(frequencies, phi_cell, phi_pier, chol))
    }

    /// [`Self::modal_model`] with the stiffness factor `chol` already computed.
    fn modal_model_on(
        &self,
        frequencies: Vec<f64>,
        phi_cell: Vec<f64>,
        phi_pier: Vec<f64>,
        chol: Skyline,
    ) -> ModalModel {
        ModalModel {
            na: self.n_actuators(),
            frequencies,
            damping_ratios: None,
            phi_cell,
            phi_pier,
            k_pier: self.k_pier,
            flexibility: Flexibility::FiniteElement(StaticFe::from_factor(self, chol)),
        }
    }
}

pub(super) fn attach(att: &[Attachment], x: &[f64], z: &mut [f64]) {
    for (zi, a) in z.iter_mut().zip(att) {
        *zi = a.coef[0] * x[a.dof] + a.coef[1] * x[a.dof + 1] + a.coef[2] * x[a.dof + 2];
    }
}

/// Lowest eigenvalue of `K x = lambda M x` (`M` diagonal) by block Lanczos on the envelope
/// Cholesky of `K` ([`lanczos::lowest_eigenpairs`]; inverse iteration with the Rayleigh
/// quotient if that has not converged, not seen).
fn lowest_eigenvalue(n: usize, k: &[f64], m: &[f64]) -> Result<f64, M1Error> {
    let chol = Skyline::factor(n, k).map_err(|_| {
        M1Error::Numerical(
            "the grillage pinned at its supports is singular (a segment not connected by shared \
             edges?)"
                .into(),
        )
    })?;
    if let Some(pairs) = lanczos::lowest_eigenpairs(&chol, m, 1)? {
        return Ok(pairs.values[0]);
    }
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
