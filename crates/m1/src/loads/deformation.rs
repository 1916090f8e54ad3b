//! Gravity and thermal deformation of the mirror cell as the telescope tracks: the in-plane
//! motion of every segment `w` and the out-of-plane motion of the cell at the actuators
//! `z_cell`, as functions of the zenith angle and the temperature, relative to the baseline at
//! which the mirror was aligned (zenith 30 deg, the seed paper's baseline).
//!
//! # The parametric model (built in)
//!
//! The TMT finite-element results are not public, so the built-in model is parametric. With
//! `c = cos(zeta) - cos(zeta_0)` and `s = sin(zeta) - sin(zeta_0)` the changes of the gravity
//! components along the optical axis and across it (in g; the elevation axis is `x`, so the
//! cross-axis component points along `y`), `dT = T - T_0`, `rho_max` the outermost segment
//! radius and `(x, y)` aperture coordinates:
//!
//! - **thermal expansion** of the cell relative to the glass: an isotropic strain about the
//!   vertex, every support point `p` moving by `d = alpha dT p` (3-D), which opens every gap by
//!   about `alpha dT` times the pitch and moves each attachment along the segment normal by
//!   `alpha dT p . n` (a focus-like change of the cell's curvature, which the loop takes out);
//! - **axial gravity**: an isotropic strain `d = epsilon_a c p` and a sag
//!   `z_cell = sag_a c (rho / rho_max)^2`;
//! - **lateral gravity**: a shear of the cell `d_y = shear_l s (1 - (rho / rho_max)^2)` and a
//!   coma-like motion `z_cell = sag_l s (rho / rho_max)^2 y / rho_max`;
//! - **local compliance**: the truss is not uniform, so each segment also moves by its own
//!   amount, a seeded draw `N(0, local_a)` per g along the axis and `N(0, local_l)` per g across
//!   it, on each in-plane axis (and clocking of the same size over the circumradius).
//!
//! Each segment's `w` is `d` at its centre projected on its radial and azimuthal tangents, plus
//! its local draw; `z_cell` is the normal part of `d` at each actuator attachment plus the sag
//! patterns. The sizes are parameters ([`DeformationParams`]); the defaults are *assumed* or
//! *calibrated* to the zenith and temperature rows of the seed paper's Table 1, as each field's
//! documentation says.
//!
//! # Imported FEA results (`.npz`)
//!
//! [`DeformationTable`] reads a NumPy `.npz` archive with float64 arrays
//!
//! | array | shape | unit |
//! |---|---|---|
//! | `zenith_deg` | `(nz,)` increasing | deg |
//! | `temperature_c` | `(nt,)` increasing | degC |
//! | `w` | `(nz, nt, 3N)` | m, m, rad (radial, azimuthal, clocking of segment `i` at `3i..3i+3`) |
//! | `z_cell` | `(nz, nt, 3N)` | m (actuator `k` of segment `i` at `3i + k`) |
//!
//! and interpolates bilinearly (a single zenith angle or temperature is a constant along that
//! axis); inputs outside the tabulated range are an error, not an extrapolation. For example:
//!
//! ```python
//! import numpy as np
//! zen = np.array([0.0, 30.0, 60.0]); temp = np.array([-5.0, 0.0, 5.0])
//! w = np.zeros((3, 3, 3 * 492)); z_cell = np.zeros((3, 3, 3 * 492))
//! # ... fill from the FEA: w[i, j] and z_cell[i, j] at zen[i], temp[j]
//! np.savez("fea.npz", zenith_deg=zen, temperature_c=temp, w=w, z_cell=z_cell)
//! ```
//!
//! Both models return the deformation relative to the baseline: the mirror is aligned there.

use std::path::Path;

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::linalg::npy::Npz;

/// The default baseline zenith angle (deg): the seed paper's Table 1 baseline.
pub const DEFAULT_BASELINE_ZENITH_DEG: f64 = 30.0;

/// Parameters of the built-in parametric deformation model (see the
/// [module documentation](self)).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DeformationParams {
    /// Zenith angle at which the mirror is aligned (deg). Default 30.
    pub baseline_zenith_deg: f64,
    /// Temperature at which the mirror is aligned (degC). Default 0 (temperatures are
    /// relative).
    pub baseline_temperature: f64,
    /// `alpha`: thermal expansion of the cell relative to the glass (1/K). Default 10e-6
    /// (*assumed*: steel, 11e-6, on a near-zero-expansion glass).
    pub thermal_expansion: f64,
    /// `epsilon_a`: radial in-plane strain of the cell per g along the axis (1). Default 15e-6
    /// (*calibrated*: with the local terms it gives Table 1's zenith `rho(Q - I)`).
    pub axial_strain: f64,
    /// `shear_l`: in-plane shear of the cell per g across the axis, centre relative to the rim
    /// (m). Default 30e-6 (*calibrated*: a larger shear raises the zenith-0 `sigma(Q)` above
    /// Table 1's 1.34).
    pub lateral_shear: f64,
    /// `sag_a`: out-of-plane sag of the cell at the rim per g along the axis (m). Default 50e-6
    /// (*assumed*).
    pub axial_sag: f64,
    /// `sag_l`: out-of-plane coma-like motion of the cell at the rim per g across the axis (m).
    /// Default 20e-6 (*assumed*).
    pub lateral_sag: f64,
    /// `local_a`: rms of each segment's own in-plane motion per g along the axis (m). Default
    /// 4.6e-6 (*calibrated* to Table 1's zenith-65 `sigma(Q) = 1.65`).
    pub local_axial_rms: f64,
    /// `local_l`: the same per g across the axis (m). Default 1.9e-6 (*calibrated* to Table 1's
    /// zenith-0 `sigma(Q) = 1.34`).
    pub local_lateral_rms: f64,
    /// Seed of the local draws. Default 1.
    pub seed: u64,
}

impl Default for DeformationParams {
    fn default() -> Self {
        Self {
            baseline_zenith_deg: DEFAULT_BASELINE_ZENITH_DEG,
            baseline_temperature: 0.0,
            thermal_expansion: 10e-6,
            axial_strain: 15e-6,
            lateral_shear: 30e-6,
            axial_sag: 50e-6,
            lateral_sag: 20e-6,
            local_axial_rms: 4.6e-6,
            local_lateral_rms: 1.9e-6,
            seed: 1,
        }
    }
}

/// One deformation state: in-plane segment motion and cell motion at the actuators.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Deformation {
    /// In-plane motion of every segment (length `3 N`: radial m, azimuthal m, clocking rad).
    pub w: Vec<f64>,
    /// Out-of-plane motion of the cell at every actuator (m, length `3 N`).
    pub z_cell: Vec<f64>,
}

/// Checks a zenith angle (deg, in [0, 90]) and a temperature (finite).
fn check_inputs(zenith_deg: f64, temperature: f64) -> Result<(), M1Error> {
    if !(zenith_deg.is_finite() && (0.0..=90.0).contains(&zenith_deg)) {
        return Err(M1Error::InvalidParameter {
            name: "zenith_angle",
            value: zenith_deg,
            reason: "must be in [0, 90] deg",
        });
    }
    if !temperature.is_finite() {
        return Err(M1Error::InvalidParameter {
            name: "temperature",
            value: temperature,
            reason: "must be finite",
        });
    }
    Ok(())
}

/// The parametric model set up for one geometry: its unit fields, evaluated once.
#[derive(Debug, Clone)]
pub struct ParametricDeformation {
    params: DeformationParams,
    /// Unit fields (per g or per K), each `(w, z_cell)`.
    thermal: Deformation,
    axial: Deformation,
    lateral: Deformation,
}

impl ParametricDeformation {
    /// The unit fields of `geometry`.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming a non-finite parameter, a negative rms or a
    /// baseline zenith angle outside [0, 90] deg.
    pub fn new(geometry: &Geometry, params: DeformationParams) -> Result<Self, M1Error> {
        check_inputs(params.baseline_zenith_deg, params.baseline_temperature)?;
        for (name, v) in [
            ("thermal_expansion", params.thermal_expansion),
            ("axial_strain", params.axial_strain),
            ("lateral_shear", params.lateral_shear),
            ("axial_sag", params.axial_sag),
            ("lateral_sag", params.lateral_sag),
        ] {
            if !v.is_finite() {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be finite",
                });
            }
        }
        for (name, v) in [
            ("local_axial_rms", params.local_axial_rms),
            ("local_lateral_rms", params.local_lateral_rms),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(M1Error::InvalidParameter {
                    name,
                    value: v,
                    reason: "must be finite and >= 0",
                });
            }
        }
        let n = geometry.n_segments();
        let rho_max = geometry
            .segments
            .iter()
            .map(|s| s.centre[0].hypot(s.centre[1]))
            .fold(0.0, f64::max)
            .max(f64::MIN_POSITIVE);
        let a = geometry.layout.circumradius;
        // A displacement `d` (3-D) of segment i's support: its components along the segment's
        // radial and azimuthal tangents are the in-plane slide (the normal part is out of plane).
        let project = |i: usize, d: [f64; 3], clock: f64, w: &mut [f64]| {
            let s = &geometry.segments[i];
            let dot = |a: [f64; 3]| d[0] * a[0] + d[1] * a[1] + d[2] * a[2];
            w[3 * i] += dot(s.radial);
            w[3 * i + 1] += dot(s.azimuthal);
            w[3 * i + 2] += clock;
        };
        let mut rng = StdRng::seed_from_u64(params.seed);
        let mut gauss = || -> f64 { StandardNormal.sample(&mut rng) };
        let mut field =
            |strain: f64, shear: f64, local: f64, z_of: &dyn Fn(f64, f64) -> f64| -> Deformation {
                let mut w = vec![0.0; 3 * n];
                let mut z_cell = vec![0.0; 3 * n];
                for i in 0..n {
                    let c = geometry.segments[i].centre;
                    let r2 = (c[0] * c[0] + c[1] * c[1]) / (rho_max * rho_max);
                    // The strain is isotropic (3-D, about the vertex); the shear is lateral.
                    let d = [
                        strain * c[0],
                        strain * c[1] + shear * (1.0 - r2),
                        strain * c[2],
                    ];
                    project(i, d, 0.0, &mut w);
                    let (dx, dy, dc) = (local * gauss(), local * gauss(), local / a * gauss());
                    project(i, [dx, dy, 0.0], dc, &mut w);
                    let nrm = geometry.segments[i].normal;
                    for k in 0..3 {
                        let p = geometry.segments[i].actuators[k];
                        // The strain's normal displacement of the attachment, plus the sag.
                        let along = strain * (p[0] * nrm[0] + p[1] * nrm[1] + p[2] * nrm[2]);
                        z_cell[3 * i + k] = along + z_of(p[0] / rho_max, p[1] / rho_max);
                    }
                }
                Deformation { w, z_cell }
            };
        let thermal = field(1.0, 0.0, 0.0, &|_, _| 0.0);
        let (sag_a, sag_l) = (params.axial_sag, params.lateral_sag);
        let axial = field(params.axial_strain, 0.0, params.local_axial_rms, &|x, y| {
            sag_a * (x * x + y * y)
        });
        let lateral = field(
            0.0,
            params.lateral_shear,
            params.local_lateral_rms,
            &|x, y| sag_l * (x * x + y * y) * y,
        );
        Ok(Self {
            params,
            thermal,
            axial,
            lateral,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &DeformationParams {
        &self.params
    }

    /// The deformation at `zenith_deg` (deg, in [0, 90]) and `temperature` (degC) relative to
    /// the baseline, written into `out` (its vectors must be `3 N` long).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for an input out of range; [`M1Error::SizeMismatch`] for
    /// output vectors of the wrong length.
    pub fn evaluate_into(
        &self,
        zenith_deg: f64,
        temperature: f64,
        out: &mut Deformation,
    ) -> Result<(), M1Error> {
        check_inputs(zenith_deg, temperature)?;
        let n3 = self.thermal.w.len();
        crate::error::check_lengths(n3, &[("w", &out.w), ("z_cell", &out.z_cell)])?;
        let (z, z0) = (
            zenith_deg.to_radians(),
            self.params.baseline_zenith_deg.to_radians(),
        );
        let c = z.cos() - z0.cos();
        let s = z.sin() - z0.sin();
        let dt = (temperature - self.params.baseline_temperature) * self.params.thermal_expansion;
        for k in 0..n3 {
            out.w[k] = dt * self.thermal.w[k] + c * self.axial.w[k] + s * self.lateral.w[k];
            out.z_cell[k] =
                dt * self.thermal.z_cell[k] + c * self.axial.z_cell[k] + s * self.lateral.z_cell[k];
        }
        Ok(())
    }
}

/// FEA results on a grid of zenith angles and temperatures (see the
/// [module documentation](self) for the `.npz` format).
#[derive(Debug, Clone)]
pub struct DeformationTable {
    zenith_deg: Vec<f64>,
    temperature: Vec<f64>,
    /// `(nz, nt, 3N)` C order.
    w: Vec<f64>,
    z_cell: Vec<f64>,
    n3: usize,
    baseline: Deformation,
}

fn check_axis(name: &str, v: &[f64], file: &str) -> Result<(), M1Error> {
    if v.is_empty() || v.iter().any(|x| !x.is_finite()) || v.windows(2).any(|p| p[1] <= p[0]) {
        return Err(M1Error::InvalidInput(format!(
            "{file}: '{name}' must be a non-empty, finite, strictly increasing 1-D array"
        )));
    }
    Ok(())
}

/// Bracketing index and weight of `x` on the increasing axis `v` (None outside the range).
fn bracket(v: &[f64], x: f64) -> Option<(usize, f64)> {
    if v.len() == 1 {
        return Some((0, 0.0));
    }
    if x < v[0] || x > v[v.len() - 1] {
        return None;
    }
    let k = v.partition_point(|&a| a <= x).clamp(1, v.len() - 1) - 1;
    Some((k, (x - v[k]) / (v[k + 1] - v[k])))
}

impl DeformationTable {
    /// A table from its arrays (`w` and `z_cell` of shape `(nz, nt, n_actuators)`, C order),
    /// with the baseline at (`baseline_zenith_deg`, `baseline_temperature`).
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] for axes that are not increasing or arrays of the wrong size;
    /// [`M1Error::InvalidParameter`] for a baseline outside the table.
    pub fn new(
        zenith_deg: Vec<f64>,
        temperature: Vec<f64>,
        w: Vec<f64>,
        z_cell: Vec<f64>,
        n_actuators: usize,
        baseline_zenith_deg: f64,
        baseline_temperature: f64,
    ) -> Result<Self, M1Error> {
        Self::build(
            "deformation table",
            zenith_deg,
            temperature,
            w,
            z_cell,
            n_actuators,
            (baseline_zenith_deg, baseline_temperature),
        )
    }

    fn build(
        file: &str,
        zenith_deg: Vec<f64>,
        temperature: Vec<f64>,
        w: Vec<f64>,
        z_cell: Vec<f64>,
        n3: usize,
        baseline: (f64, f64),
    ) -> Result<Self, M1Error> {
        check_axis("zenith_deg", &zenith_deg, file)?;
        check_axis("temperature_c", &temperature, file)?;
        let expected = zenith_deg.len() * temperature.len() * n3;
        for (name, a) in [("w", &w), ("z_cell", &z_cell)] {
            if a.len() != expected {
                return Err(M1Error::InvalidInput(format!(
                    "{file}: '{name}' has {} values, expected {} x {} x {n3} (zenith angles x \
                     temperatures x 3 per segment)",
                    a.len(),
                    zenith_deg.len(),
                    temperature.len()
                )));
            }
            if a.iter().any(|x| !x.is_finite()) {
                return Err(M1Error::InvalidInput(format!(
                    "{file}: '{name}' has a value that is not finite"
                )));
            }
        }
        let mut t = Self {
            zenith_deg,
            temperature,
            w,
            z_cell,
            n3,
            baseline: Deformation {
                w: vec![0.0; n3],
                z_cell: vec![0.0; n3],
            },
        };
        let mut b = t.baseline.clone();
        t.absolute_into(baseline.0, baseline.1, &mut b)?;
        t.baseline = b;
        Ok(t)
    }

    /// Reads `path` for a mirror of `n_actuators` actuators (3 per segment), the baseline at
    /// (`baseline_zenith_deg`, `baseline_temperature`).
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] naming the file and the array at fault.
    pub fn from_npz(
        path: &Path,
        n_actuators: usize,
        baseline_zenith_deg: f64,
        baseline_temperature: f64,
    ) -> Result<Self, M1Error> {
        let file = path.display().to_string();
        let mut npz = Npz::open(path)?;
        let zen = npz.require("zenith_deg")?;
        let temp = npz.require("temperature_c")?;
        let w = npz.require("w")?;
        let z = npz.require("z_cell")?;
        for (name, a) in [("zenith_deg", &zen), ("temperature_c", &temp)] {
            if a.shape.len() != 1 {
                return Err(M1Error::InvalidInput(format!(
                    "{file}: '{name}' must be 1-D, has shape {:?}",
                    a.shape
                )));
            }
        }
        let want = [zen.data.len(), temp.data.len(), n_actuators];
        for (name, a) in [("w", &w), ("z_cell", &z)] {
            if a.shape != want {
                return Err(M1Error::InvalidInput(format!(
                    "{file}: '{name}' has shape {:?}, expected {want:?} (zenith angles, \
                     temperatures, 3 per segment)",
                    a.shape
                )));
            }
        }
        Self::build(
            &file,
            zen.data,
            temp.data,
            w.data,
            z.data,
            n_actuators,
            (baseline_zenith_deg, baseline_temperature),
        )
    }

    fn absolute_into(&self, zenith: f64, temp: f64, out: &mut Deformation) -> Result<(), M1Error> {
        check_inputs(zenith, temp)?;
        let (Some((iz, fz)), Some((it, ft))) = (
            bracket(&self.zenith_deg, zenith),
            bracket(&self.temperature, temp),
        ) else {
            return Err(M1Error::InvalidInput(format!(
                "zenith angle {zenith} deg and temperature {temp} degC: outside the table \
                 (zenith {}..{} deg, temperature {}..{} degC)",
                self.zenith_deg[0],
                self.zenith_deg[self.zenith_deg.len() - 1],
                self.temperature[0],
                self.temperature[self.temperature.len() - 1]
            )));
        };
        let nt = self.temperature.len();
        let (iz1, it1) = (
            (iz + 1).min(self.zenith_deg.len() - 1),
            (it + 1).min(nt - 1),
        );
        let corners = [
            (iz, it, (1.0 - fz) * (1.0 - ft)),
            (iz1, it, fz * (1.0 - ft)),
            (iz, it1, (1.0 - fz) * ft),
            (iz1, it1, fz * ft),
        ];
        crate::error::check_lengths(self.n3, &[("w", &out.w), ("z_cell", &out.z_cell)])?;
        out.w.fill(0.0);
        out.z_cell.fill(0.0);
        for (a, b, wt) in corners {
            if wt == 0.0 {
                continue;
            }
            let off = (a * nt + b) * self.n3;
            for k in 0..self.n3 {
                out.w[k] += wt * self.w[off + k];
                out.z_cell[k] += wt * self.z_cell[off + k];
            }
        }
        Ok(())
    }

    /// The deformation at `zenith_deg` and `temperature` relative to the baseline, into `out`.
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] outside the table; [`M1Error::SizeMismatch`] for output vectors
    /// of the wrong length.
    pub fn evaluate_into(
        &self,
        zenith_deg: f64,
        temperature: f64,
        out: &mut Deformation,
    ) -> Result<(), M1Error> {
        self.absolute_into(zenith_deg, temperature, out)?;
        for k in 0..self.n3 {
            out.w[k] -= self.baseline.w[k];
            out.z_cell[k] -= self.baseline.z_cell[k];
        }
        Ok(())
    }
}

/// A deformation source: the built-in parametric model or imported FEA results.
#[derive(Debug, Clone)]
pub enum DeformationModel {
    /// The parametric model.
    Parametric(ParametricDeformation),
    /// Tabulated FEA results.
    Table(DeformationTable),
}

impl DeformationModel {
    /// The parametric model of `geometry` with `params`.
    ///
    /// # Errors
    /// As [`ParametricDeformation::new`].
    pub fn parametric(geometry: &Geometry, params: DeformationParams) -> Result<Self, M1Error> {
        Ok(Self::Parametric(ParametricDeformation::new(
            geometry, params,
        )?))
    }

    /// Number of in-plane coordinates `3 N`.
    pub fn len(&self) -> usize {
        match self {
            Self::Parametric(p) => p.thermal.w.len(),
            Self::Table(t) => t.n3,
        }
    }

    /// True for a mirror without segments.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The deformation at (`zenith_deg`, `temperature`) relative to the baseline, into `out`.
    ///
    /// # Errors
    /// As the model's `evaluate_into`.
    pub fn evaluate_into(
        &self,
        zenith_deg: f64,
        temperature: f64,
        out: &mut Deformation,
    ) -> Result<(), M1Error> {
        match self {
            Self::Parametric(p) => p.evaluate_into(zenith_deg, temperature, out),
            Self::Table(t) => t.evaluate_into(zenith_deg, temperature, out),
        }
    }

    /// As [`DeformationModel::evaluate_into`], allocating.
    ///
    /// # Errors
    /// As [`DeformationModel::evaluate_into`].
    pub fn evaluate(&self, zenith_deg: f64, temperature: f64) -> Result<Deformation, M1Error> {
        let mut d = Deformation {
            w: vec![0.0; self.len()],
            z_cell: vec![0.0; self.len()],
        };
        self.evaluate_into(zenith_deg, temperature, &mut d)?;
        Ok(d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::geometry::GeometryParams;
    use crate::aperture::layout::Layout;
    use crate::sensing::interaction::interaction_matrices;

    fn keck() -> Geometry {
        let l = Layout::preset("keck").unwrap();
        Geometry::new(&l, GeometryParams::for_layout(&l)).unwrap()
    }

    #[test]
    fn baseline_is_zero_and_thermal_expansion_opens_every_gap_by_alpha_dt_pitch() {
        let g = keck();
        let p = DeformationParams::default();
        let m = DeformationModel::parametric(&g, p).unwrap();
        let d0 = m.evaluate(30.0, 0.0).unwrap();
        assert!(d0.w.iter().chain(&d0.z_cell).all(|x| x.abs() < 1e-18));
        let d = m.evaluate(30.0, 5.0).unwrap();
        let im = interaction_matrices(&g);
        let mut gap = vec![0.0; g.n_sensors()];
        crate::control::reconstructor::sparse_mul(&im.a_gw, &d.w, &mut gap);
        let pitch = 3f64.sqrt() * g.layout.circumradius + g.layout.gap;
        let expected = p.thermal_expansion * 5.0 * pitch;
        for x in &gap {
            // The expansion is uniform in the aperture plane; the gap is measured along the
            // curved surface, longer by up to 1 / cos(slope) (Keck's rim: 2 %).
            assert!((x / expected - 1.0).abs() < 3e-2, "{x} vs {expected}");
        }
        // The attachments move along the normal by alpha dT p . n: about -alpha dT x sag.
        assert!(d.z_cell.iter().any(|x| x.abs() > 1e-7));
        // Gravity enters through the changes of cos and sin of the zenith angle: from zenith 0
        // and 90 the axial and lateral fields follow, and they predict zenith 60.
        let (c30, s30) = (30f64.to_radians().cos(), 30f64.to_radians().sin());
        let (a, b) = (
            m.evaluate(0.0, 0.0).unwrap(),
            m.evaluate(90.0, 0.0).unwrap(),
        );
        assert!(a.z_cell.iter().any(|x| x.abs() > 1e-7));
        let m60 = m.evaluate(60.0, 0.0).unwrap();
        // [1 - c30, -s30; -c30, 1 - s30] [axial; lateral] = [a; b].
        let det = (1.0 - c30) * (1.0 - s30) - s30 * c30;
        let (c60, s60) = (
            60f64.to_radians().cos() - c30,
            60f64.to_radians().sin() - s30,
        );
        for (x0, x90, x60) in [(&a.w, &b.w, &m60.w), (&a.z_cell, &b.z_cell, &m60.z_cell)] {
            for k in 0..x0.len() {
                let axial = ((1.0 - s30) * x0[k] + s30 * x90[k]) / det;
                let lateral = (c30 * x0[k] + (1.0 - c30) * x90[k]) / det;
                let predicted = c60 * axial + s60 * lateral;
                assert!(
                    (x60[k] - predicted).abs() < 1e-12 * (1.0 + x0[k].abs() * 1e6),
                    "{k}"
                );
            }
        }
        assert!(m.evaluate(91.0, 0.0).is_err());
        assert!(m.evaluate(10.0, f64::NAN).is_err());
    }

    #[test]
    fn table_interpolates_bilinearly_relative_to_its_baseline() {
        let n3 = 6;
        let zen = vec![0.0, 60.0];
        let temp = vec![-5.0, 5.0];
        // Values linear in zenith and temperature: interpolation is exact.
        let f = |z: f64, t: f64, k: usize| 1e-6 * (z + 10.0 * t) * (k as f64 + 1.0);
        let mut w = Vec::new();
        for &z in &zen {
            for &t in &temp {
                for k in 0..n3 {
                    w.push(f(z, t, k));
                }
            }
        }
        let tab = DeformationTable::new(zen, temp, w.clone(), w, n3, 30.0, 0.0).unwrap();
        let m = DeformationModel::Table(tab);
        let d = m.evaluate(45.0, 2.0).unwrap();
        for k in 0..n3 {
            let want = f(45.0, 2.0, k) - f(30.0, 0.0, k);
            assert!((d.w[k] - want).abs() < 1e-15 && (d.z_cell[k] - want).abs() < 1e-15);
        }
        let e = m.evaluate(70.0, 0.0).unwrap_err().to_string();
        assert!(e.contains("outside the table"), "{e}");
        assert!(
            DeformationTable::new(
                vec![1.0, 0.0],
                vec![0.0],
                vec![0.0; 12],
                vec![0.0; 12],
                6,
                0.5,
                0.0
            )
            .is_err()
        );
    }
}
