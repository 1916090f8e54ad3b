//! Three-dimensional geometry of a segmented mirror: the optical prescription, each segment's
//! local frame and actuator points, and the edge-sensor locations and measuring directions.
//!
//! # Conventions
//!
//! Global coordinates are those of [`crate::aperture::layout`]: `x`, `y` in the aperture plane (m), `z`
//! along the optical axis towards the sky, origin at the mirror vertex.
//!
//! - **Prescription.** The parent surface is the conic of revolution (vertex radius of curvature
//!   `R`, conic constant `k`, `rho^2 = x^2 + y^2`)
//!
//!   ```text
//!   z(rho) = rho^2 / (R (1 + sqrt(1 - (1 + k) rho^2 / R^2))),
//!   dz/drho = rho / (R sqrt(1 - (1 + k) rho^2 / R^2)),
//!   ```
//!
//!   concave towards the sky (`z` grows away from the axis); `R = infinity` is the plane
//!   `z = 0`. The unit surface normal `n = (-dz/dx, -dz/dy, 1) / |.|` points towards `+z`
//!   (towards the sky and, for a sphere, exactly at the centre of curvature).
//! - **Segment frame** `(radial, azimuthal, normal)`, right-handed: the segment centre
//!   `c = (x_c, y_c, z(rho_c))` lies on the prescription above the layout centre; `normal` is the
//!   surface normal there; `radial` is the unit tangent in the meridian plane (optical axis and
//!   centre) pointing away from the axis, `(cos phi, sin phi, dz/drho) / |.|` with `phi` the
//!   polar angle of the centre (`x` for a centre on the axis); `azimuthal = normal x radial`
//!   (horizontal, counter-clockwise seen from the sky).
//! - **Vertices**: the layout's 2-D corners lifted vertically onto the prescription (so on a
//!   curved mirror the segments are not exactly regular hexagons).
//! - **Actuators**: actuator `k = 0, 1, 2` of a segment is in its tangent plane at
//!   `a_k = c + r_act (cos phi_k radial + sin phi_k azimuthal)`, `phi_k = 2 pi k / 3`.
//! - **Piston/tip/tilt.** A small rigid out-of-plane motion of segment `i` with piston `p` (along
//!   `normal`) and rotation `theta = alpha radial + beta azimuthal` moves actuator `k` along the
//!   normal by
//!
//!   ```text
//!   z_k = p + (theta x (a_k - c)) . normal = p + r_act (alpha sin phi_k - beta cos phi_k),
//!   ```
//!
//!   i.e. `z = P (p, alpha, beta)` with the rows of `P` given by [`Geometry::ptt_matrix`] and its
//!   inverse by [`Geometry::ptt_inverse`].
//! - **Edge sensors.** Two per shared edge, in layout edge order: sensors `2 e` and `2 e + 1` sit
//!   on edge `e = (i, j)`. In 2-D, take segment `i`'s side facing `j` (the side whose outward
//!   normal is closest to the edge normal), with ends `v_0` (the corner reached first going
//!   counter-clockwise round `i`) and `v_1`; shift it by `gap / 2` along the edge normal onto the
//!   gap centre line and move the sensor offset `e_s` inward from each end:
//!   `s_0 = v_0 + (gap/2) n + e_s t`, `s_1 = v_1 + (gap/2) n - e_s t` (`t` the unit vector from
//!   `v_0` to `v_1`). The points are lifted onto the prescription. At a sensor point:
//!   `height` is the surface normal; `gap` is the unit tangent perpendicular to the edge (whose
//!   surface tangent is `(t, grad z . t)`), pointing from `i` towards `j`;
//!   `shear = height x gap`.
//!
//! # Assumed parameter values
//!
//! [`GeometryParams::for_layout`] gives defaults that are *assumed*, not published: actuator
//! radius `r_act = a / 2` (0.36 m for TMT), sensor offset `e_s = 0.10 m x a / 0.72 m` from each
//! end of the edge, effective dihedral moment arm `L_eff = 0.1 m`.

use nalgebra::Vector3;

use crate::M1Error;
use crate::aperture::layout::Layout;

/// Default sensor offset from each end of an edge for a TMT-sized segment (m, *assumed*).
pub const DEFAULT_SENSOR_OFFSET_TMT: f64 = 0.10;
/// Circumradius the default sensor offset refers to (TMT, m).
pub const REFERENCE_CIRCUMRADIUS: f64 = 0.72;
/// Default effective dihedral moment arm of the edge sensors (m, *assumed*).
pub const DEFAULT_LEFF: f64 = 0.1;

/// Distance from the axis below which a segment centre counts as on the axis, as a fraction of
/// the circumradius (its radial direction is then `x`).
const ON_AXIS: f64 = 1e-12;

/// The optical prescription of the parent surface: a conic of revolution, concave towards `+z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prescription {
    /// Vertex radius of curvature `R` (m, > 0); `f64::INFINITY` for a flat mirror.
    pub radius_of_curvature: f64,
    /// Conic constant `k` (0 sphere, -1 paraboloid, < -1 hyperboloid).
    pub conic: f64,
}

impl Prescription {
    /// A flat mirror (`R = infinity`, `k = 0`).
    pub const FLAT: Prescription = Prescription {
        radius_of_curvature: f64::INFINITY,
        conic: 0.0,
    };

    /// True when the surface is the plane `z = 0` (`R` infinite).
    pub fn is_flat(&self) -> bool {
        self.radius_of_curvature.is_infinite()
    }

    /// Vertex curvature `1 / R` (1/m), 0 for a flat mirror.
    pub fn curvature(&self) -> f64 {
        if self.is_flat() {
            0.0
        } else {
            1.0 / self.radius_of_curvature
        }
    }

    /// `1 - (1 + k) rho^2 / R^2`: the surface is defined where this is positive.
    fn discriminant(&self, rho: f64) -> f64 {
        let c = self.curvature();
        1.0 - (1.0 + self.conic) * rho * rho * c * c
    }

    /// True when the conic is defined (and single-valued) at distance `rho` from the axis.
    pub fn is_defined_at(&self, rho: f64) -> bool {
        rho.is_finite() && self.discriminant(rho) > 0.0
    }

    /// Sag `z(rho) = rho^2 / (R (1 + sqrt(1 - (1 + k) rho^2 / R^2)))` (m); 0 when flat, NaN
    /// beyond the conic's rim.
    pub fn sag(&self, rho: f64) -> f64 {
        if self.is_flat() {
            return 0.0;
        }
        rho * rho * self.curvature() / (1.0 + self.discriminant(rho).sqrt())
    }

    /// Slope `dz/drho = rho / (R sqrt(1 - (1 + k) rho^2 / R^2))`; 0 when flat.
    pub fn slope(&self, rho: f64) -> f64 {
        if self.is_flat() {
            return 0.0;
        }
        rho * self.curvature() / self.discriminant(rho).sqrt()
    }

    /// Gradient `(dz/dx, dz/dy)` at `(x, y)`.
    pub fn gradient(&self, x: f64, y: f64) -> [f64; 2] {
        if self.is_flat() {
            return [0.0, 0.0];
        }
        // dz/dx = (dz/drho) x / rho = x / (R sqrt(D)): regular on the axis.
        let rho = x.hypot(y);
        let f = self.curvature() / self.discriminant(rho).sqrt();
        [f * x, f * y]
    }

    /// The point of the surface above `(x, y)`: `[x, y, z(rho)]`.
    pub fn surface_point(&self, x: f64, y: f64) -> [f64; 3] {
        [x, y, self.sag(x.hypot(y))]
    }

    /// Unit surface normal at `(x, y)`, pointing towards `+z` (towards the sky, and towards the
    /// centre of curvature of this concave mirror).
    pub fn normal(&self, x: f64, y: f64) -> [f64; 3] {
        let [gx, gy] = self.gradient(x, y);
        let norm = (1.0 + gx * gx + gy * gy).sqrt();
        [-gx / norm, -gy / norm, 1.0 / norm]
    }
}

/// Assumed geometric parameters of the segment supports and edge sensors.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GeometryParams {
    /// Radius of the actuator circle from the segment centre, in the segment's tangent plane (m).
    /// Default `a / 2` (0.36 m for TMT, *assumed*).
    pub actuator_radius: f64,
    /// Distance of each edge sensor from its end of the shared edge, along the edge (m).
    /// Default 0.10 m scaled by `a / 0.72 m` (*assumed*).
    pub sensor_offset: f64,
    /// Effective moment arm `L_eff` of the sensors' dihedral sensitivity (m). Default 0.1 m
    /// (*assumed*); 0 gives pure height sensors.
    pub leff: f64,
    /// Ignore the layout's radius of curvature and treat the mirror as flat. Default `false`.
    pub flat: bool,
}

impl GeometryParams {
    /// The default (*assumed*) parameters for `layout` (circumradius `a`):
    /// `actuator_radius = a / 2`, `sensor_offset = 0.10 m x a / 0.72 m`, `leff = 0.1 m`,
    /// `flat = false`. For TMT (`a = 0.72 m`): 0.36 m, 0.10 m, 0.1 m.
    pub fn for_layout(layout: &Layout) -> GeometryParams {
        let a = layout.circumradius;
        GeometryParams {
            actuator_radius: a / 2.0,
            sensor_offset: DEFAULT_SENSOR_OFFSET_TMT * (a / REFERENCE_CIRCUMRADIUS),
            leff: DEFAULT_LEFF,
            flat: false,
        }
    }
}

/// A segment's local frame on the prescription, its lifted corners and its actuator points.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentFrame {
    /// Centre on the prescription (m).
    pub centre: [f64; 3],
    /// Unit surface normal at the centre (towards `+z`).
    pub normal: [f64; 3],
    /// Unit tangent in the meridian plane, pointing away from the optical axis.
    pub radial: [f64; 3],
    /// `normal x radial`: (radial, azimuthal, normal) is right-handed.
    pub azimuthal: [f64; 3],
    /// The layout's corners lifted onto the prescription, in layout order.
    pub vertices: [[f64; 3]; 6],
    /// Actuator points `c + r_act (cos phi_k radial + sin phi_k azimuthal)`, `phi_k = 2 pi k / 3`.
    pub actuators: [[f64; 3]; 3],
}

/// One edge sensor: where it is, which segments it compares and its measuring directions.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    /// Index of the shared edge in [`Layout::edges`].
    pub edge: usize,
    /// First segment of the edge (`i < j`).
    pub i: usize,
    /// Second segment of the edge.
    pub j: usize,
    /// Sensor point on the gap centre line, on the prescription (m).
    pub point: [f64; 3],
    /// Unit surface normal at the point (height direction).
    pub height: [f64; 3],
    /// Unit tangent perpendicular to the edge, from `i` towards `j` (gap direction).
    pub gap: [f64; 3],
    /// `height x gap`, along the edge (shear direction).
    pub shear: [f64; 3],
}

/// The full 3-D geometry of a segmented mirror: prescription, segment frames and sensors.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    /// The layout the geometry was built from.
    pub layout: Layout,
    /// The (validated) geometric parameters.
    pub params: GeometryParams,
    /// The prescription in use (flat if `params.flat` or the layout is flat).
    pub prescription: Prescription,
    /// One frame per segment, in layout order.
    pub segments: Vec<SegmentFrame>,
    /// Two sensors per shared edge: sensors `2 e` and `2 e + 1` are on edge `e`.
    pub sensors: Vec<Sensor>,
}

fn v3(a: [f64; 3]) -> Vector3<f64> {
    Vector3::new(a[0], a[1], a[2])
}

fn arr(v: Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn invalid(name: &'static str, value: f64, reason: &'static str) -> M1Error {
    M1Error::InvalidParameter {
        name,
        value,
        reason,
    }
}

/// Checks the parameters against the segment size `a`.
fn check_params(params: &GeometryParams, a: f64) -> Result<(), M1Error> {
    let r = params.actuator_radius;
    if !r.is_finite() || r <= 0.0 {
        return Err(invalid(
            "actuator_radius",
            r,
            "must be finite and > 0 (the actuator triangle must not degenerate)",
        ));
    }
    if r >= a {
        return Err(invalid(
            "actuator_radius",
            r,
            "must be smaller than the segment circumradius",
        ));
    }
    let e = params.sensor_offset;
    if !e.is_finite() || e < 0.0 {
        return Err(invalid("sensor_offset", e, "must be finite and >= 0"));
    }
    // The side length of a regular hexagon equals its circumradius.
    if e >= a / 2.0 {
        return Err(invalid(
            "sensor_offset",
            e,
            "must be less than half the side length (a / 2) so the two sensors stay apart",
        ));
    }
    if !params.leff.is_finite() || params.leff < 0.0 {
        return Err(invalid("leff", params.leff, "must be finite and >= 0"));
    }
    Ok(())
}

/// Lifts a 2-D point onto the prescription, failing beyond the conic's rim.
fn lift(p: &Prescription, xy: [f64; 2]) -> Result<[f64; 3], M1Error> {
    let rho = xy[0].hypot(xy[1]);
    if !p.is_defined_at(rho) {
        return Err(invalid(
            "radius_of_curvature",
            p.radius_of_curvature,
            "the conic surface is not defined over the whole mirror (1 - (1 + k) rho^2 / R^2 <= 0)",
        ));
    }
    Ok(p.surface_point(xy[0], xy[1]))
}

/// Inverse of a 3 x 3 matrix by the adjugate; `None` if singular.
fn inverse3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let cof =
        |r0: usize, r1: usize, c0: usize, c1: usize| m[r0][c0] * m[r1][c1] - m[r0][c1] * m[r1][c0];
    // Cofactors C[r][c]; inverse = C^T / det.
    let c = [
        [cof(1, 2, 1, 2), -cof(1, 2, 0, 2), cof(1, 2, 0, 1)],
        [-cof(0, 2, 1, 2), cof(0, 2, 0, 2), -cof(0, 2, 0, 1)],
        [cof(0, 1, 1, 2), -cof(0, 1, 0, 2), cof(0, 1, 0, 1)],
    ];
    let det = m[0][0] * c[0][0] + m[0][1] * c[0][1] + m[0][2] * c[0][2];
    if det == 0.0 || !det.is_finite() {
        return None;
    }
    Some(std::array::from_fn(|r| {
        std::array::from_fn(|col| c[col][r] / det)
    }))
}

impl Geometry {
    /// Builds the geometry of `layout` with `params`.
    ///
    /// Fails with [`M1Error::InvalidParameter`] unless `actuator_radius` is finite and in
    /// `(0, a)`, `sensor_offset` finite and in `[0, a / 2)`, `leff` finite and `>= 0`, and the
    /// conic is defined over every corner and sensor point. With `params.flat` the layout's
    /// radius of curvature and conic are ignored.
    pub fn new(layout: &Layout, params: GeometryParams) -> Result<Geometry, M1Error> {
        let a = layout.circumradius;
        check_params(&params, a)?;
        let prescription = if params.flat || layout.radius_of_curvature.is_infinite() {
            Prescription::FLAT
        } else {
            Prescription {
                radius_of_curvature: layout.radius_of_curvature,
                conic: layout.conic,
            }
        };
        let p = &prescription;
        let mut segments = Vec::with_capacity(layout.n_segments());
        for (i, seg) in layout.segments.iter().enumerate() {
            let [x, y] = seg.center;
            let centre = lift(p, seg.center)?;
            let normal = v3(p.normal(x, y));
            let rho = x.hypot(y);
            let radial = if rho <= ON_AXIS * a {
                Vector3::x()
            } else {
                Vector3::new(x / rho, y / rho, p.slope(rho)).normalize()
            };
            let azimuthal = normal.cross(&radial);
            let corners = layout.vertices(i).ok_or(M1Error::SizeMismatch {
                what: "layout segments",
                expected: layout.n_segments(),
                found: i,
            })?;
            let mut vertices = [[0.0; 3]; 6];
            for (v, c) in vertices.iter_mut().zip(corners) {
                *v = lift(p, c)?;
            }
            let c = v3(centre);
            let actuators = std::array::from_fn(|k| {
                let phi = 2.0 * std::f64::consts::PI * k as f64 / 3.0;
                arr(c + params.actuator_radius * (phi.cos() * radial + phi.sin() * azimuthal))
            });
            segments.push(SegmentFrame {
                centre,
                normal: arr(normal),
                radial: arr(radial),
                azimuthal: arr(azimuthal),
                vertices,
                actuators,
            });
        }

        let mut sensors = Vec::with_capacity(layout.n_sensors());
        for (index, edge) in layout.edges.iter().enumerate() {
            let n = edge.normal;
            // Side k of a pointy-topped hexagon faces 60 k degrees and joins corners k-1 and k.
            let facing = (0..6)
                .map(|k| {
                    let angle = (60.0 * k as f64).to_radians();
                    (k, angle.cos() * n[0] + angle.sin() * n[1])
                })
                .fold((0, f64::NEG_INFINITY), |best, cand| {
                    if cand.1 > best.1 { cand } else { best }
                })
                .0;
            let corners = layout.vertices(edge.i).ok_or(M1Error::SizeMismatch {
                what: "edge segment index",
                expected: layout.n_segments(),
                found: edge.i,
            })?;
            let v0 = corners[(facing + 5) % 6];
            let v1 = corners[facing];
            let len = (v1[0] - v0[0]).hypot(v1[1] - v0[1]);
            let t = [(v1[0] - v0[0]) / len, (v1[1] - v0[1]) / len];
            let half_gap = layout.gap / 2.0;
            let e = params.sensor_offset;
            let ends = [(v0, e), (v1, -e)];
            for (v, along) in ends {
                let xy = [
                    v[0] + half_gap * n[0] + along * t[0],
                    v[1] + half_gap * n[1] + along * t[1],
                ];
                let point = lift(p, xy)?;
                let height = v3(p.normal(xy[0], xy[1]));
                let [gx, gy] = p.gradient(xy[0], xy[1]);
                let tangent = Vector3::new(t[0], t[1], gx * t[0] + gy * t[1]).normalize();
                let mut gap = height.cross(&tangent);
                if gap.x * n[0] + gap.y * n[1] < 0.0 {
                    gap = -gap;
                }
                let shear = height.cross(&gap);
                sensors.push(Sensor {
                    edge: index,
                    i: edge.i,
                    j: edge.j,
                    point,
                    height: arr(height),
                    gap: arr(gap),
                    shear: arr(shear),
                });
            }
        }

        let geometry = Geometry {
            layout: layout.clone(),
            params,
            prescription,
            segments,
            sensors,
        };
        // The actuator triangle is non-degenerate for r_act > 0; check anyway so that
        // `ptt_inverse` can rely on it.
        for i in 0..geometry.n_segments() {
            if inverse3(&geometry.ptt_matrix(i)).is_none() {
                return Err(invalid(
                    "actuator_radius",
                    params.actuator_radius,
                    "gives a singular piston/tip/tilt matrix",
                ));
            }
        }
        Ok(geometry)
    }

    /// Number of segments `N`.
    pub fn n_segments(&self) -> usize {
        self.segments.len()
    }

    /// Number of actuators `na = 3 N`.
    pub fn n_actuators(&self) -> usize {
        3 * self.segments.len()
    }

    /// Number of edge sensors `ns` (two per shared edge).
    pub fn n_sensors(&self) -> usize {
        self.sensors.len()
    }

    /// Vertex curvature `1 / R` in use (0 for a flat mirror).
    pub fn curvature(&self) -> f64 {
        self.prescription.curvature()
    }

    /// Matrix `P` (rows: actuators `k`; columns: piston `p`, tilt `alpha` about `radial`, tilt
    /// `beta` about `azimuthal`) of segment `i`: the actuator displacements along the normal are
    /// `z_k = p + ((alpha radial + beta azimuthal) x (a_k - c)) . normal`, i.e. row
    /// `k = [1, r_act sin phi_k, -r_act cos phi_k]`.
    ///
    /// # Panics
    /// If `i >= n_segments()`.
    pub fn ptt_matrix(&self, i: usize) -> [[f64; 3]; 3] {
        let s = &self.segments[i];
        let (c, n, r, az) = (v3(s.centre), v3(s.normal), v3(s.radial), v3(s.azimuthal));
        std::array::from_fn(|k| {
            let d = v3(s.actuators[k]) - c;
            [1.0, r.cross(&d).dot(&n), az.cross(&d).dot(&n)]
        })
    }

    /// `P^-1` of segment `i`: `(p, alpha, beta) = P^-1 z`.
    ///
    /// # Panics
    /// If `i >= n_segments()` (`P` itself is checked to be invertible by [`Geometry::new`]).
    pub fn ptt_inverse(&self, i: usize) -> [[f64; 3]; 3] {
        // Non-singular: checked in `new` (a zero matrix is never returned in practice).
        inverse3(&self.ptt_matrix(i)).unwrap_or([[0.0; 3]; 3])
    }
}
