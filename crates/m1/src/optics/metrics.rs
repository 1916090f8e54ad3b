//! Optical metrics of a mirror state: rms surface error with the global piston/tip/tilt removed,
//! focus-mode amplitude, and the rms without focus-mode ([`MirrorMetrics`]); the PSSN of the same
//! state comes from [`crate::optics::pssn::Pssn`] fed with [`MirrorMetrics::residual_ptt`].
//!
//! # Surface of a segment state
//!
//! The input is `z` (m, length `na = 3 N`): the displacement of the mirror normal to the segment
//! at each actuator, actuator `k` of segment `i` at index `3 i + k`. Segments are rigid, so the
//! surface error over segment `i` is an affine function of the position `(x, y)` in the
//! aperture plane (the plane of [`crate::aperture::layout`], where every segment is a regular hexagon of
//! circumradius `a` centred on `c_i`):
//!
//! $$s_i(x, y) = p_i + t_{x,i}\,(x - c_{x,i}) + t_{y,i}\,(y - c_{y,i}),$$
//!
//! the `[p, tx, ty]` state of [`crate::aperture::zernike`] and [`crate::optics::pssn`]. It is the plane through
//! the three actuator points projected onto the aperture plane with heights `z`:
//! `[p, tx, ty]_i = M_i^{-1} z_i`, rows of `M_i` = `[1, a_{x,k} - c_{x,i}, a_{y,k} - c_{y,i}]`
//! ([`aperture_ptt_matrix`]). The segment moves rigidly in its tangent plane and the tangent
//! plane projects affinely onto the aperture plane, so this is exact for the normal
//! displacement; the surface error is taken as that normal displacement (the obliquity of the
//! segment normal, `cos` of the surface slope, at most 3 % at the edge of TMT, is neglected).
//!
//! # Metric and global piston/tip/tilt
//!
//! The metric is the area integral over the segmented aperture (gaps excluded). A regular
//! hexagon is centrally symmetric with an isotropic second moment, so for hexagon area
//! $A = \frac{3\sqrt3}{2}a^2$ and second moment $I = \frac{5\sqrt3}{16}a^4$ about any in-plane
//! axis through the centre (exact closed forms),
//!
//! $$\langle s, s' \rangle = \sum_i A\,p_i p'_i + I\,(t_{x,i} t'_{x,i} + t_{y,i} t'_{y,i}).$$
//!
//! The global piston/tip/tilt is the least-squares plane $g(x, y) = P + T_x x + T_y y$ over the
//! aperture (coordinates about the aperture centroid): $G\beta = b$ with $G$ the Gram matrix of
//! $\{1, x, y\}$ in this metric and $b_j = \langle s, g_j \rangle$. The residual is $r = s - g$.
//!
//! - **`rms`** (m, surface): $\sqrt{\|r\|^2 / (N A)}$, the area-weighted rms over the aperture of
//!   the surface with the best-fit global piston/tip/tilt removed. The wavefront error is twice
//!   this (reflection at normal incidence).
//! - **`focus`** (m): the coefficient `c` of the focus-mode vector `f` (actuator space, unit
//!   Euclidean norm over the `na` actuators, [`crate::control::nominal::Nominal::focus`]) in the
//!   least-squares fit of `r` by the residual `F` of `f`: $c = \langle r, F \rangle /
//!   \|F\|^2$. So `z = c f` gives `c`, and `z = c f` plus any global piston/tip/tilt too. As a
//!   surface, `c` units of focus-mode have the rms `c * focus_rms_per_unit()`.
//! - **`focus_rms`** (m, surface): that rms, $c \sqrt{\|F\|^2 / (N A)}$, signed as `c`: the
//!   focus-mode's share of the surface, $\text{rms}^2 = \text{rms\_without\_focus}^2 +
//!   \text{focus\_rms}^2$ (the residual is orthogonal to $F$). This is the figure the seed
//!   paper quotes as "focus-mode amplitude, nm rms"; `focus` is an actuator-space coefficient,
//!   38 times larger on TMT (1476 actuators), 10 times on Keck.
//! - **`rms_without_focus`** (m, surface): $\sqrt{\|r - cF\|^2 / (N A)}$.
//!
//! Every residual is accumulated directly (not as a difference of squares), so a pure global
//! piston/tip/tilt gives 0 to round-off (the plane is refined once on the residual). An evaluation
//! is two passes over vectors of segments (`O(na)`, the processor's widest vectors, each sum
//! taken by lane), after the displacements are laid out actuator by actuator.

use nalgebra::{Matrix3, Vector3};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::control::nominal::Nominal;

/// Area of a regular hexagon of circumradius `a`: `3 sqrt(3) / 2 a^2` (m^2).
pub fn hexagon_area(a: f64) -> f64 {
    1.5 * 3.0_f64.sqrt() * a * a
}

/// Second moment of area of a regular hexagon of circumradius `a` about any in-plane axis
/// through its centre: `5 sqrt(3) / 16 a^4` (m^4).
pub fn hexagon_second_moment(a: f64) -> f64 {
    5.0 * 3.0_f64.sqrt() / 16.0 * a.powi(4)
}

/// Matrix `M_i` of segment `i` (rows: actuators; columns: `p`, `tx`, `ty`): the actuator
/// heights of the aperture-plane state `[p, tx, ty]` are `z = M_i [p, tx, ty]`, with the actuator
/// points projected onto the aperture plane. See the [module documentation](self).
///
/// # Panics
/// If `i >= geometry.n_segments()`.
pub fn aperture_ptt_matrix(geometry: &Geometry, i: usize) -> [[f64; 3]; 3] {
    let f = &geometry.segments[i];
    std::array::from_fn(|k| {
        [
            1.0,
            f.actuators[k][0] - f.centre[0],
            f.actuators[k][1] - f.centre[1],
        ]
    })
}

fn inverse(m: &[[f64; 3]; 3], i: usize) -> Result<Matrix3<f64>, M1Error> {
    Matrix3::from_fn(|r, c| m[r][c])
        .try_inverse()
        .ok_or(M1Error::InvalidParameter {
            name: "actuator_radius",
            value: i as f64,
            reason: "the projected actuator triangle of a segment is degenerate",
        })
}

/// The aperture-plane state `[p, tx, ty]` of every segment from the actuator heights `z`
/// (m, length `3 N`).
pub fn actuators_to_ptt(geometry: &Geometry, z: &[f64]) -> Result<Vec<[f64; 3]>, M1Error> {
    check_len(z, geometry.n_actuators())?;
    (0..geometry.n_segments())
        .map(|i| {
            let m = inverse(&aperture_ptt_matrix(geometry, i), i)?;
            let s = m * Vector3::new(z[3 * i], z[3 * i + 1], z[3 * i + 2]);
            Ok([s[0], s[1], s[2]])
        })
        .collect()
}

/// The actuator heights `z` (length `3 N`) of an aperture-plane segment state `ptt`.
pub fn ptt_to_actuators(geometry: &Geometry, ptt: &[[f64; 3]]) -> Result<Vec<f64>, M1Error> {
    if ptt.len() != geometry.n_segments() {
        return Err(M1Error::SizeMismatch {
            what: "segment piston/tip/tilt",
            expected: geometry.n_segments(),
            found: ptt.len(),
        });
    }
    let mut z = Vec::with_capacity(geometry.n_actuators());
    for (i, s) in ptt.iter().enumerate() {
        for row in aperture_ptt_matrix(geometry, i) {
            z.push(row[0] * s[0] + row[1] * s[1] + row[2] * s[2]);
        }
    }
    Ok(z)
}

fn check_len(z: &[f64], na: usize) -> Result<(), M1Error> {
    if z.len() == na {
        Ok(())
    } else {
        Err(M1Error::SizeMismatch {
            what: "actuator displacements z",
            expected: na,
            found: z.len(),
        })
    }
}

/// The metrics of one mirror state (see the [module documentation](self)).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SurfaceMetrics {
    /// Area-weighted rms surface error with the global piston/tip/tilt removed (m).
    pub rms: f64,
    /// Focus-mode coefficient: the amplitude `c` of the unit-norm focus-mode vector over the
    /// actuators in `z` (m of actuator displacement, not a surface figure: one unit is
    /// [`MirrorMetrics::focus_rms_per_unit`] of rms surface).
    pub focus: f64,
    /// Focus-mode as a surface: `c` times the rms surface of the unit vector (m), signed as
    /// `c`. `|focus_rms|` is the rms surface of the focus-mode component, so
    /// `rms^2 = rms_without_focus^2 + focus_rms^2`; the seed paper's "focus-mode amplitude
    /// (nm rms)" is its rms over time.
    pub focus_rms: f64,
    /// Rms surface error with global piston/tip/tilt and focus-mode removed (m).
    pub rms_without_focus: f64,
    /// The removed global plane `[P, Tx, Ty]`: piston at the aperture centroid (m) and slopes
    /// `dz/dx`, `dz/dy` (rad).
    pub global_ptt: [f64; 3],
}

/// Precomputed projections for [`SurfaceMetrics`] of a geometry (see the
/// [module documentation](self)).
#[derive(Debug, Clone)]
pub struct MirrorMetrics {
    /// Segment area `A` (m^2).
    area: f64,
    /// Segment second moment `I` (m^4).
    moment: f64,
    /// Segment centres about the aperture centroid (m).
    centres: Vec<[f64; 2]>,
    /// Aperture centroid (m).
    centroid: [f64; 2],
    /// `M_i^-1` per segment, row-major.
    to_ptt: Vec<[f64; 9]>,
    /// Inverse Gram matrix of the global modes {1, x, y}.
    gram_inv: Matrix3<f64>,
    /// Focus-mode residual state per segment and `||F||^2`.
    focus_ptt: Vec<[f64; 3]>,
    focus_norm2: f64,
    /// The focus-mode vector in actuator space (unit norm).
    focus: Vec<f64>,
    /// The same per-segment values by component, for [`Self::evaluate`]'s passes over
    /// vectors of segments: `M_i^-1` entry by entry, the centres' `x` and `y`, `F` by component.
    by_component: ByComponent,
}

/// [`MirrorMetrics`]' per-segment values as one array per component (entry `i` segment `i`).
#[derive(Debug, Clone, Default)]
struct ByComponent {
    to_ptt: [Vec<f64>; 9],
    cx: Vec<f64>,
    cy: Vec<f64>,
    focus: [Vec<f64>; 3],
}

/// Sums of the first evaluation pass.
struct Moments {
    b: Vector3<f64>,
    sf: f64,
}

impl MirrorMetrics {
    /// Metrics for `geometry` with the focus-mode of its A-matrix
    /// ([`Nominal::new`], which builds A and its reconstructor: about a second for TMT).
    pub fn new(geometry: &Geometry) -> Result<MirrorMetrics, M1Error> {
        let nominal = Nominal::new(geometry.clone())?;
        MirrorMetrics::with_focus(geometry, &nominal.focus)
    }

    /// Metrics for `geometry` with a given focus-mode vector `focus` (actuator space, length
    /// `na`, non-zero outside the global piston/tip/tilt; it is used as given, normalised to
    /// unit Euclidean norm).
    pub fn with_focus(geometry: &Geometry, focus: &[f64]) -> Result<MirrorMetrics, M1Error> {
        let n = geometry.n_segments();
        check_len(focus, geometry.n_actuators())?;
        if n == 0 {
            return Err(M1Error::InvalidParameter {
                name: "n_segments",
                value: 0.0,
                reason: "the mirror has no segment",
            });
        }
        let a = geometry.layout.circumradius;
        let area = hexagon_area(a);
        let moment = hexagon_second_moment(a);
        let centroid = {
            let (sx, sy) = geometry
                .segments
                .iter()
                .fold((0.0, 0.0), |(x, y), f| (x + f.centre[0], y + f.centre[1]));
            [sx / n as f64, sy / n as f64]
        };
        let centres: Vec<[f64; 2]> = geometry
            .segments
            .iter()
            .map(|f| [f.centre[0] - centroid[0], f.centre[1] - centroid[1]])
            .collect();
        let to_ptt = (0..n)
            .map(|i| {
                let m = inverse(&aperture_ptt_matrix(geometry, i), i)?;
                Ok(std::array::from_fn(|k| m[(k / 3, k % 3)]))
            })
            .collect::<Result<Vec<[f64; 9]>, M1Error>>()?;
        // Gram matrix of {1, x, y}: <1,1> = N A, <1,x> = A sum cx, <x,x> = A sum cx^2 + N I, ...
        let mut gram = Matrix3::zeros();
        for c in &centres {
            let g = [1.0, c[0], c[1]];
            for r in 0..3 {
                for k in 0..3 {
                    gram[(r, k)] += area * g[r] * g[k];
                }
            }
        }
        gram[(1, 1)] += n as f64 * moment;
        gram[(2, 2)] += n as f64 * moment;
        let gram_inv = gram.try_inverse().ok_or(M1Error::InvalidParameter {
            name: "n_segments",
            value: n as f64,
            reason: "the global piston/tip/tilt are not independent on this aperture",
        })?;
        let norm = focus.iter().map(|x| x * x).sum::<f64>().sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return Err(M1Error::InvalidParameter {
                name: "focus",
                value: norm,
                reason: "the focus-mode vector must be finite and non-zero",
            });
        }
        let focus: Vec<f64> = focus.iter().map(|x| x / norm).collect();
        let mut metrics = MirrorMetrics {
            area,
            moment,
            centres,
            centroid,
            to_ptt,
            gram_inv,
            focus_ptt: vec![[0.0; 3]; n],
            focus_norm2: 1.0,
            focus: Vec::new(),
            by_component: ByComponent::default(),
        };
        let mut residual = vec![[0.0; 3]; n];
        metrics.residual_ptt(&focus, &mut residual)?;
        let focus_norm2 = residual.iter().map(|r| metrics.norm2(r)).sum::<f64>();
        let total_norm2 = (0..n)
            .map(|i| metrics.norm2(&metrics.segment_ptt(i, &focus)))
            .sum::<f64>();
        // Relative to the whole mode: round-off leaves ~1e-32 of a pure global plane.
        if focus_norm2.is_nan() || focus_norm2 <= 1e-20 * total_norm2 {
            return Err(M1Error::InvalidParameter {
                name: "focus",
                value: focus_norm2,
                reason: "the focus-mode vector is a global piston/tip/tilt",
            });
        }
        metrics.focus_ptt = residual;
        metrics.focus_norm2 = focus_norm2;
        metrics.focus = focus;
        metrics.by_component = ByComponent {
            to_ptt: std::array::from_fn(|k| metrics.to_ptt.iter().map(|m| m[k]).collect()),
            cx: metrics.centres.iter().map(|c| c[0]).collect(),
            cy: metrics.centres.iter().map(|c| c[1]).collect(),
            focus: std::array::from_fn(|k| metrics.focus_ptt.iter().map(|f| f[k]).collect()),
        };
        Ok(metrics)
    }

    /// Number of segments `N`.
    pub fn n_segments(&self) -> usize {
        self.centres.len()
    }

    /// Number of actuators `na = 3 N`.
    pub fn n_actuators(&self) -> usize {
        3 * self.centres.len()
    }

    /// Segmented aperture area `N A` (m^2).
    pub fn total_area(&self) -> f64 {
        self.n_segments() as f64 * self.area
    }

    /// Aperture centroid `(x, y)` (m), the origin of the global plane.
    pub fn centroid(&self) -> [f64; 2] {
        self.centroid
    }

    /// The focus-mode vector (actuator space, unit Euclidean norm).
    pub fn focus_mode(&self) -> &[f64] {
        &self.focus
    }

    /// Rms surface (m) of one unit of focus-mode amplitude, global piston/tip/tilt removed.
    pub fn focus_rms_per_unit(&self) -> f64 {
        (self.focus_norm2 / self.total_area()).sqrt()
    }

    /// `||s_i||^2` of one segment state.
    fn norm2(&self, s: &[f64; 3]) -> f64 {
        self.area * s[0] * s[0] + self.moment * (s[1] * s[1] + s[2] * s[2])
    }

    fn segment_ptt(&self, i: usize, z: &[f64]) -> [f64; 3] {
        let m = &self.to_ptt[i];
        let (z0, z1, z2) = (z[3 * i], z[3 * i + 1], z[3 * i + 2]);
        [
            m[0] * z0 + m[1] * z1 + m[2] * z2,
            m[3] * z0 + m[4] * z1 + m[5] * z2,
            m[6] * z0 + m[7] * z1 + m[8] * z2,
        ]
    }

    /// Every segment's state `s_i` (piston, tip, tilt about its centre) of `z`, computed once
    /// for the passes below.
    fn segment_states(&self, z: &[f64]) -> Vec<[f64; 3]> {
        (0..self.n_segments())
            .map(|i| self.segment_ptt(i, z))
            .collect()
    }

    /// First pass: `b = <s, {1, x, y}>` and `<s, F>`.
    fn moments(&self, s: &[[f64; 3]]) -> Moments {
        let mut b = Vector3::zeros();
        let mut sf = 0.0;
        for ((s, c), f) in s.iter().zip(&self.centres).zip(&self.focus_ptt) {
            let ap = self.area * s[0];
            b[0] += ap;
            b[1] += ap * c[0] + self.moment * s[1];
            b[2] += ap * c[1] + self.moment * s[2];
            sf += ap * f[0] + self.moment * (s[1] * f[1] + s[2] * f[2]);
        }
        Moments { b, sf }
    }

    /// The global plane `beta` of the segment states `s` and `<s, F>`: the normal equations,
    /// then one step of iterative refinement on the residual (the plane is usually much larger
    /// than the residual, whose round-off this brings from about `10 eps` to `eps` of the
    /// plane).
    fn global_plane(&self, s: &[[f64; 3]]) -> (Vector3<f64>, f64) {
        let m = self.moments(s);
        let mut beta = self.gram_inv * m.b;
        let mut b = Vector3::zeros();
        for (si, c) in s.iter().zip(&self.centres) {
            let r = residual(si, c, &beta);
            let ap = self.area * r[0];
            b[0] += ap;
            b[1] += ap * c[0] + self.moment * r[1];
            b[2] += ap * c[1] + self.moment * r[2];
        }
        beta += self.gram_inv * b;
        (beta, m.sf)
    }

    /// The metrics of the actuator displacements `z` (m, length `na`). After the segment
    /// states and their moments, which give the plane `beta0` of the normal equations, one pass
    /// over the residuals about it gives both the refinement `delta = G^-1 b1` (the step of
    /// iterative refinement [`Self::residual_ptt`] takes too) and their squared norms, which
    /// the refinement changes by `-2 delta.b1 + delta^T G delta = -delta.b1`
    /// (`<r, plane(delta)> = delta.b1`, and the focus mode is orthogonal to every plane).
    pub fn evaluate(&self, z: &[f64]) -> Result<SurfaceMetrics, M1Error> {
        self.evaluate_with(z, &mut MetricsScratch::default())
    }

    /// [`Self::evaluate`] with its working buffers in `scratch` (kept between calls by a caller
    /// that evaluates at every step, such as the optics FMU: no allocation per call). The
    /// same values to the bit.
    pub fn evaluate_with(
        &self,
        z: &[f64],
        scratch: &mut MetricsScratch,
    ) -> Result<SurfaceMetrics, M1Error> {
        check_len(z, self.n_actuators())?;
        let n = self.n_segments();
        scratch.by_actuator.resize(3 * n, 0.0);
        scratch.states.resize(3 * n, 0.0);
        Ok(pulp::Arch::new().dispatch(Evaluate {
            m: self,
            z,
            scratch,
        }))
    }

    /// The segment states `[p, tx, ty]` (about each segment centre, aperture plane) of `z` with
    /// the global piston/tip/tilt removed, written into `out` (length `N`): the input of
    /// [`crate::optics::pssn::Pssn::pssn_ptt`]. Returns the removed plane `[P, Tx, Ty]`.
    pub fn residual_ptt(&self, z: &[f64], out: &mut [[f64; 3]]) -> Result<[f64; 3], M1Error> {
        check_len(z, self.n_actuators())?;
        if out.len() != self.n_segments() {
            return Err(M1Error::SizeMismatch {
                what: "segment piston/tip/tilt",
                expected: self.n_segments(),
                found: out.len(),
            });
        }
        let s = self.segment_states(z);
        let (beta, _) = self.global_plane(&s);
        for ((o, si), c) in out.iter_mut().zip(&s).zip(&self.centres) {
            *o = residual(si, c, &beta);
        }
        Ok([beta[0], beta[1], beta[2]])
    }
}

/// [`MirrorMetrics::evaluate`] over vectors of segments (the processor's widest, `pulp`'s
/// runtime dispatch): the segment states and their moments, which give the plane `beta0` of the
/// normal equations; then one pass over the residuals about it, which gives both the refinement
/// `delta = G^-1 b1` (the step of iterative refinement [`MirrorMetrics::residual_ptt`] takes
/// too) and their squared norms, which the refinement changes by `-2 delta.b1 + delta^T G delta
/// = -delta.b1` (`<r, plane(delta)> = delta.b1`, and the focus mode is orthogonal to every
/// plane). Each sum is taken by lane, then across the lanes; the segments after the last whole
/// vector one by one. The first pass stores the states of the whole vectors for the second.
///
/// The vector operations here are written out, in `#[inline(always)]` functions, without
/// closures or `array::map` around them: those are compiled as functions of their own, without
/// the processor's vector features, where every `pulp` operation becomes a call (a version with
/// them took 18 us per TMT evaluation instead of 1.7).
struct Evaluate<'a> {
    m: &'a MirrorMetrics,
    z: &'a [f64],
    scratch: &'a mut MetricsScratch,
}

/// The working buffers of [`MirrorMetrics::evaluate_with`]: the displacements by actuator of a
/// segment and the segments' states, `3 N` values each.
#[derive(Debug, Clone, Default)]
pub struct MetricsScratch {
    by_actuator: Vec<f64>,
    states: Vec<f64>,
}

impl pulp::WithSimd for Evaluate<'_> {
    type Output = SurfaceMetrics;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) -> SurfaceMetrics {
        let (m, z) = (self.m, self.z);
        let MetricsScratch {
            by_actuator,
            states,
        } = self.scratch;
        let bc = &m.by_component;
        let n = m.n_segments();
        let lanes = S::F64_LANES;
        let whole = n - n % lanes;
        // The displacements by actuator of a segment, so that a vector holds one actuator of
        // `lanes` segments.
        {
            let (z0, rest) = by_actuator.split_at_mut(n);
            let (z1, z2) = rest.split_at_mut(n);
            let pieces = z0.iter_mut().zip(z1.iter_mut()).zip(z2.iter_mut());
            for (((a, b), c), zi) in pieces.zip(z.chunks_exact(3)) {
                (*a, *b, *c) = (zi[0], zi[1], zi[2]);
            }
        }
        let zk: [&[f64]; 3] = [
            &by_actuator[..n],
            &by_actuator[n..2 * n],
            &by_actuator[2 * n..],
        ];
        let (s0s, rest) = states.split_at_mut(n);
        let (s1s, s2s) = rest.split_at_mut(n);
        let (area, moment) = (m.area, m.moment);
        let zero = simd.splat_f64s(0.0);
        // First pass: sum s0, s0 cx, s0 cy, s1, s2 and <s, F>.
        let mut acc = [zero; 6];
        let (va, vi) = (simd.splat_f64s(area), simd.splat_f64s(moment));
        for i in (0..whole).step_by(lanes) {
            let [s0, s1, s2] = seg_states(simd, bc, &zk, i);
            for (out, s) in [(&mut *s0s, s0), (&mut *s1s, s1), (&mut *s2s, s2)] {
                simd.partial_store_f64s(&mut out[i..i + lanes], s);
            }
            let (cx, cy) = (vec_at::<S>(&bc.cx, i), vec_at::<S>(&bc.cy, i));
            let f = [
                vec_at::<S>(&bc.focus[0], i),
                vec_at::<S>(&bc.focus[1], i),
                vec_at::<S>(&bc.focus[2], i),
            ];
            acc[0] = simd.add_f64s(acc[0], s0);
            acc[1] = simd.mul_add_e_f64s(s0, cx, acc[1]);
            acc[2] = simd.mul_add_e_f64s(s0, cy, acc[2]);
            acc[3] = simd.add_f64s(acc[3], s1);
            acc[4] = simd.add_f64s(acc[4], s2);
            let sf = simd.mul_add_e_f64s(s1, f[1], simd.mul_f64s(s2, f[2]));
            acc[5] = simd.mul_add_e_f64s(
                va,
                simd.mul_f64s(s0, f[0]),
                simd.mul_add_e_f64s(vi, sf, acc[5]),
            );
        }
        let mut sums = [0.0; 6];
        for (s, v) in sums.iter_mut().zip(acc) {
            *s = simd.reduce_sum_f64s(v);
        }
        for i in whole..n {
            let s = m.segment_ptt(i, z);
            let (c, f) = (&m.centres[i], &m.focus_ptt[i]);
            sums[0] += s[0];
            sums[1] += s[0] * c[0];
            sums[2] += s[0] * c[1];
            sums[3] += s[1];
            sums[4] += s[2];
            sums[5] += area * s[0] * f[0] + moment * (s[1] * f[1] + s[2] * f[2]);
        }
        let b = Vector3::new(
            area * sums[0],
            area * sums[1] + moment * sums[3],
            area * sums[2] + moment * sums[4],
        );
        let beta0 = m.gram_inv * b;
        // F is orthogonal to {1, x, y}, so <r, F> = <s, F>.
        let c = sums[5] / m.focus_norm2;
        // Second pass: the residuals' moments and squared norms, with and without focus-mode.
        let mut acc = [zero; 7];
        let (b0, b1, b2) = (
            simd.splat_f64s(beta0[0]),
            simd.splat_f64s(beta0[1]),
            simd.splat_f64s(beta0[2]),
        );
        let vc = simd.splat_f64s(c);
        for i in (0..whole).step_by(lanes) {
            let (s0, s1, s2) = (
                vec_at::<S>(s0s, i),
                vec_at::<S>(s1s, i),
                vec_at::<S>(s2s, i),
            );
            let (cx, cy) = (vec_at::<S>(&bc.cx, i), vec_at::<S>(&bc.cy, i));
            let plane = simd.mul_add_e_f64s(b2, cy, simd.mul_add_e_f64s(b1, cx, b0));
            let (r0, r1, r2) = (
                simd.sub_f64s(s0, plane),
                simd.sub_f64s(s1, b1),
                simd.sub_f64s(s2, b2),
            );
            acc[0] = simd.add_f64s(acc[0], r0);
            acc[1] = simd.mul_add_e_f64s(r0, cx, acc[1]);
            acc[2] = simd.mul_add_e_f64s(r0, cy, acc[2]);
            acc[3] = simd.add_f64s(acc[3], r1);
            acc[4] = simd.add_f64s(acc[4], r2);
            acc[5] = simd.add_f64s(acc[5], norm2_vec(simd, va, vi, [r0, r1, r2]));
            let f = [
                vec_at::<S>(&bc.focus[0], i),
                vec_at::<S>(&bc.focus[1], i),
                vec_at::<S>(&bc.focus[2], i),
            ];
            let q = [
                simd.sub_f64s(r0, simd.mul_f64s(vc, f[0])),
                simd.sub_f64s(r1, simd.mul_f64s(vc, f[1])),
                simd.sub_f64s(r2, simd.mul_f64s(vc, f[2])),
            ];
            acc[6] = simd.add_f64s(acc[6], norm2_vec(simd, va, vi, q));
        }
        let mut sums = [0.0; 7];
        for (s, v) in sums.iter_mut().zip(acc) {
            *s = simd.reduce_sum_f64s(v);
        }
        for i in whole..n {
            let (ci, f) = (&m.centres[i], &m.focus_ptt[i]);
            let r = residual(&m.segment_ptt(i, z), ci, &beta0);
            sums[0] += r[0];
            sums[1] += r[0] * ci[0];
            sums[2] += r[0] * ci[1];
            sums[3] += r[1];
            sums[4] += r[2];
            sums[5] += m.norm2(&r);
            sums[6] += m.norm2(&[r[0] - c * f[0], r[1] - c * f[1], r[2] - c * f[2]]);
        }
        let b1 = Vector3::new(
            area * sums[0],
            area * sums[1] + moment * sums[3],
            area * sums[2] + moment * sums[4],
        );
        let delta = m.gram_inv * b1;
        let beta = beta0 + delta;
        let refined = delta.dot(&b1);
        let (rr, qq) = ((sums[5] - refined).max(0.0), (sums[6] - refined).max(0.0));
        let total = m.total_area();
        SurfaceMetrics {
            rms: (rr / total).sqrt(),
            focus: c,
            focus_rms: c * m.focus_rms_per_unit(),
            rms_without_focus: (qq / total).sqrt(),
            global_ptt: [beta[0], beta[1], beta[2]],
        }
    }
}

/// `lanes` entries of `v` from `i`, as a vector.
#[inline(always)]
fn vec_at<S: pulp::Simd>(v: &[f64], i: usize) -> S::f64s {
    S::as_simd_f64s(&v[i..i + S::F64_LANES]).0[0]
}

/// The states `[p, tx, ty]` of the `lanes` segments from `i`, as vectors, from the actuators'
/// displacements by actuator of the segment (`zk[k][i]`: actuator `k` of segment `i`).
#[inline(always)]
fn seg_states<S: pulp::Simd>(
    simd: S,
    bc: &ByComponent,
    zk: &[&[f64]; 3],
    i: usize,
) -> [S::f64s; 3] {
    let z0 = vec_at::<S>(zk[0], i);
    let z1 = vec_at::<S>(zk[1], i);
    let z2 = vec_at::<S>(zk[2], i);
    let t = &bc.to_ptt;
    let mut out = [simd.splat_f64s(0.0); 3];
    for (r, o) in out.iter_mut().enumerate() {
        let k = 3 * r;
        let a = simd.mul_f64s(vec_at::<S>(&t[k], i), z0);
        let a = simd.mul_add_e_f64s(vec_at::<S>(&t[k + 1], i), z1, a);
        *o = simd.mul_add_e_f64s(vec_at::<S>(&t[k + 2], i), z2, a);
    }
    out
}

/// `A p^2 + I (tx^2 + ty^2)` by lane.
#[inline(always)]
fn norm2_vec<S: pulp::Simd>(simd: S, a: S::f64s, i: S::f64s, s: [S::f64s; 3]) -> S::f64s {
    let [p, tx, ty] = s;
    simd.mul_add_e_f64s(
        a,
        simd.mul_f64s(p, p),
        simd.mul_f64s(i, simd.mul_add_e_f64s(tx, tx, simd.mul_f64s(ty, ty))),
    )
}

/// A segment's state `s` (centre `c`) after removing the global plane `beta`.
fn residual(s: &[f64; 3], c: &[f64; 2], beta: &Vector3<f64>) -> [f64; 3] {
    [
        s[0] - (beta[0] + beta[1] * c[0] + beta[2] * c[1]),
        s[1] - beta[1],
        s[2] - beta[2],
    ]
}

/// Single-sided amplitude spectrum of equally sampled signals (sample period `dt` s), averaged
/// in power over the signals: `A(f_k) = sqrt(mean_i |X_i(k)|^2)` with `X_i` the Hann-windowed
/// DFT of signal `i` (its mean removed) scaled so that a sine of amplitude `A` centred on a bin
/// reads `A`. Returns `(f_k, A(f_k))` for `k = 1 .. n/2` (`n` the common length; Hz, signal
/// units). Empty if there are fewer than 4 samples or no signal.
pub fn amplitude_spectrum(signals: &[&[f64]], dt: f64) -> Vec<(f64, f64)> {
    use rustfft::FftPlanner;
    use rustfft::num_complex::Complex64;
    let Some(n) = signals.iter().map(|s| s.len()).min() else {
        return Vec::new();
    };
    if n < 4 || dt.is_nan() || dt <= 0.0 {
        return Vec::new();
    }
    let fft = FftPlanner::<f64>::new().plan_fft_forward(n);
    let w: Vec<f64> = (0..n)
        .map(|k| 0.5 - 0.5 * (std::f64::consts::TAU * k as f64 / n as f64).cos())
        .collect();
    let gain: f64 = w.iter().sum();
    let mut power = vec![0.0; n / 2 + 1];
    let mut buf = vec![Complex64::new(0.0, 0.0); n];
    for s in signals {
        let s = &s[..n];
        let mean = s.iter().sum::<f64>() / n as f64;
        for ((b, x), w) in buf.iter_mut().zip(s).zip(&w) {
            *b = Complex64::new((x - mean) * w, 0.0);
        }
        fft.process(&mut buf);
        for (p, b) in power.iter_mut().zip(&buf) {
            *p += b.norm_sqr();
        }
    }
    let m = signals.len() as f64;
    (1..=n / 2)
        .map(|k| {
            let a = 2.0 * (power[k] / m).sqrt() / gain;
            (k as f64 / (n as f64 * dt), a)
        })
        .collect()
}

#[cfg(test)]
mod spectrum_tests {
    use super::amplitude_spectrum;

    /// Two sines centred on bins read their amplitudes; the power mean over signals of equal
    /// spectra is that spectrum.
    #[test]
    fn a_centred_sine_reads_its_amplitude() {
        let (n, dt) = (1000usize, 1e-3);
        let f0 = 50.0; // bin 50 of 1 Hz resolution
        let x: Vec<f64> = (0..n)
            .map(|k| 3.0 * (std::f64::consts::TAU * f0 * k as f64 * dt).sin() + 7.0)
            .collect();
        let y: Vec<f64> = (0..n)
            .map(|k| 3.0 * (std::f64::consts::TAU * f0 * k as f64 * dt).cos())
            .collect();
        let s = amplitude_spectrum(&[&x, &y], dt);
        assert_eq!(s.len(), n / 2);
        let (f, a) = s[49];
        assert!((f - 50.0).abs() < 1e-9 && (a - 3.0).abs() < 1e-9, "{f} {a}");
        // Far from the tone: leakage of the Hann window only.
        assert!(s[200].1 < 1e-9, "{}", s[200].1);
        assert!(amplitude_spectrum(&[&x[..3]], dt).is_empty());
    }
}

#[cfg(test)]
mod evaluate_tests {
    use super::*;
    use crate::aperture::geometry::GeometryParams;
    use crate::aperture::layout::Layout;

    /// The evaluation as three scalar passes over the segments, in the order of the formulas:
    /// the reference for [`Evaluate`].
    fn scalar_reference(m: &MirrorMetrics, z: &[f64]) -> SurfaceMetrics {
        let s = m.segment_states(z);
        let mo = m.moments(&s);
        let beta0 = m.gram_inv * mo.b;
        let c = mo.sf / m.focus_norm2;
        let (mut b1, mut rr, mut qq) = (Vector3::zeros(), 0.0, 0.0);
        for ((si, ci), f) in s.iter().zip(&m.centres).zip(&m.focus_ptt) {
            let r = residual(si, ci, &beta0);
            b1[0] += m.area * r[0];
            b1[1] += m.area * r[0] * ci[0] + m.moment * r[1];
            b1[2] += m.area * r[0] * ci[1] + m.moment * r[2];
            rr += m.norm2(&r);
            qq += m.norm2(&[r[0] - c * f[0], r[1] - c * f[1], r[2] - c * f[2]]);
        }
        let delta = m.gram_inv * b1;
        let refined = delta.dot(&b1);
        let total = m.total_area();
        SurfaceMetrics {
            rms: ((rr - refined).max(0.0) / total).sqrt(),
            focus: c,
            focus_rms: c * m.focus_rms_per_unit(),
            rms_without_focus: ((qq - refined).max(0.0) / total).sqrt(),
            global_ptt: [
                beta0[0] + delta[0],
                beta0[1] + delta[1],
                beta0[2] + delta[2],
            ],
        }
    }

    /// Working buffers of the right size, every value NaN.
    fn poisoned(m: &MirrorMetrics) -> MetricsScratch {
        MetricsScratch {
            by_actuator: vec![f64::NAN; 3 * m.n_segments()],
            states: vec![f64::NAN; 3 * m.n_segments()],
        }
    }

    /// Buffers kept from one evaluation to the next (the optics FMU's way) give the values of
    /// fresh ones, to the bit, whatever the earlier state was.
    #[test]
    fn kept_buffers_give_the_fresh_values() {
        let l = Layout::keck();
        let g = Geometry::new(&l, GeometryParams::for_layout(&l)).expect("geometry");
        let focus: Vec<f64> = (0..g.n_actuators()).map(|k| (k % 7) as f64).collect();
        let m = MirrorMetrics::with_focus(&g, &focus).expect("metrics");
        let state = |phase: f64| -> Vec<f64> {
            (0..g.n_actuators())
                .map(|k| 1e-8 * (0.37 * k as f64 + phase).sin() + 1e-9 * phase)
                .collect()
        };
        let mut kept = poisoned(&m);
        for phase in [0.0, 1.3, -2.1, 0.0] {
            let z = state(phase);
            let fresh = m.evaluate(&z).expect("fresh");
            let again = m.evaluate_with(&z, &mut kept).expect("kept");
            assert_eq!(format!("{fresh:?}"), format!("{again:?}"), "phase {phase}");
            assert!(fresh.rms > 0.0 && fresh.rms.is_finite());
        }
    }

    /// On ELT's 798 segments (not a whole number of vectors of 2, 4 or 8 lanes: every width has
    /// segments after its last whole vector), the evaluation on the processor's widest vectors,
    /// on four lanes and on one agrees with the scalar passes, every output, for a state with a
    /// large global plane (the refinement's case) and one without.
    #[test]
    fn every_instruction_set_matches_the_scalar_passes() {
        let l = Layout::elt();
        assert!(!l.n_segments().is_multiple_of(8) && !l.n_segments().is_multiple_of(4));
        let g = Geometry::new(&l, GeometryParams::for_layout(&l)).expect("geometry");
        let focus: Vec<f64> = (0..g.n_actuators())
            .map(|k| {
                let a = g.segments[k / 3].actuators[k % 3];
                a[0] * a[0] + a[1] * a[1]
            })
            .collect();
        let m = MirrorMetrics::with_focus(&g, &focus).expect("metrics");
        let wavy: Vec<f64> = (0..g.n_actuators())
            .map(|k| 3e-8 * ((k * 7919) % 1013) as f64 / 1013.0 - 1.5e-8)
            .collect();
        let tilted: Vec<f64> = wavy
            .iter()
            .enumerate()
            .map(|(k, w)| {
                let a = g.segments[k / 3].actuators[k % 3];
                w + 1e-5 + 2e-6 * a[0] - 3e-6 * a[1]
            })
            .collect();
        for z in [&wavy, &tilted] {
            let want = scalar_reference(&m, z);
            // Buffers of NaN: a value read before it is written spoils every output.
            let (mut s1, mut s2, mut s3) = (poisoned(&m), poisoned(&m), poisoned(&m));
            let runs = [
                pulp::Arch::new().dispatch(Evaluate {
                    m: &m,
                    z,
                    scratch: &mut s1,
                }),
                pulp::WithSimd::with_simd(
                    Evaluate {
                        m: &m,
                        z,
                        scratch: &mut s2,
                    },
                    pulp::Scalar256b,
                ),
                pulp::WithSimd::with_simd(
                    Evaluate {
                        m: &m,
                        z,
                        scratch: &mut s3,
                    },
                    pulp::Scalar,
                ),
            ];
            let near = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-11 * scale;
            for got in runs {
                assert!(near(got.rms, want.rms, want.rms), "{got:?} vs {want:?}");
                assert!(near(
                    got.rms_without_focus,
                    want.rms_without_focus,
                    want.rms
                ));
                assert!(near(got.focus_rms, want.focus_rms, want.rms), "{got:?}");
                for k in 0..3 {
                    let scale = want.global_ptt[k].abs().max(1e-12);
                    assert!(
                        near(got.global_ptt[k], want.global_ptt[k], scale),
                        "{got:?}"
                    );
                }
            }
        }
    }
}
