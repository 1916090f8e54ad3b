//! The actuator servo loop of a mirror on its structure ([`ActuatorLoop`]): the Zernike,
//! segment and all-segment bases built once, and every basis's largest sensitivity singular
//! value at a frequency ([`CsiPoint`]), with the dense reference and the peak labels.

use faer::{Mat, c64};
use serde::Serialize;

use super::projected::{Kinds, Projected, modal_factor, sensitivity_max};
use super::zernike::ZernikeChannels;
use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::aperture::layout::Layout;
use crate::linalg::trapezoid::UpperTrapezoid;
use crate::plant::monolithic::FrequencyModel;

/// The actuator servo loop of a mirror on its structure, with the bases of the analysis.
#[derive(Debug, Clone)]
pub struct ActuatorLoop {
    pub(super) fm: FrequencyModel,
    pub(super) zernike: ZernikeChannels,
    pub(super) zernike_projected: Projected,
    /// Segment counts of the segment bases, ascending.
    pub(super) segment_counts: Vec<usize>,
    segments_projected: Projected,
    /// The all-segment coupled subspace: `R_k = Q_k^T Phi_k` (rank_k x r, upper trapezoidal)
    /// per kind, with `Q_k` an orthonormal basis of the span of that kind's shapes (the one
    /// that makes `R_k` trapezoidal).
    pub(super) coupled_r: [UpperTrapezoid; 2],
    /// The kept rank of each kind.
    pub(super) coupled_rank: [usize; 2],
    /// `R_k^T R_k` (r x r, symmetric, by its upper part) per kind: the shapes' Gram matrices
    /// on the kept rank.
    pub(super) coupled_gram: [UpperTrapezoid; 2],
    /// Whether each kind has channels outside the span of its shapes.
    pub(super) complement: [bool; 2],
    /// The all-segment Lanczos's step limit ([`super::LANCZOS_STEPS`] by default).
    pub(super) lanczos_steps: usize,
}

/// One evaluated point: the values, the plant projected on the Zernike basis of the largest
/// degree, the all-segment top vector (`None` without a coupled subspace).
pub(super) type Evaluated = (CsiPoint, Mat<c64>, Option<Vec<c64>>);

/// One point of every basis's curve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CsiPoint {
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// Largest singular value of the sensitivity per Zernike degree `0..=max`.
    pub zernike: Vec<f64>,
    /// The same per segment basis.
    pub segments: Vec<f64>,
    /// The same with all segments (exact).
    pub all_segments: f64,
}

impl ActuatorLoop {
    /// The loop of `fm`'s mirror (`layout` and `geometry` of its segments), with Zernike bases
    /// up to `max_degree` and segment bases of `segment_counts` segments (sorted, deduplicated,
    /// clamped to the number of segments).
    ///
    /// # Errors
    /// From the Zernike basis (degree too high for the layout), the geometry, or a size
    /// mismatch between the layout and the model.
    pub fn new(
        fm: FrequencyModel,
        layout: &Layout,
        geometry: &Geometry,
        max_degree: u32,
        segment_counts: &[usize],
    ) -> Result<Self, M1Error> {
        let n = fm.n_segments();
        let na = fm.n_actuators();
        if layout.n_segments() != n {
            return Err(M1Error::SizeMismatch {
                what: "layout segments",
                expected: n,
                found: layout.n_segments(),
            });
        }
        let zernike = ZernikeChannels::new(&fm, layout, geometry, max_degree)?;
        let zernike_projected = Projected::new(&fm, &zernike.basis);
        // Segments by distance from the centre.
        let mut order: Vec<usize> = (0..n).collect();
        let dist = |i: usize| layout.segments[i].center[0].hypot(layout.segments[i].center[1]);
        order.sort_by(|&a, &b| dist(a).total_cmp(&dist(b)));
        let mut counts: Vec<usize> = segment_counts
            .iter()
            .map(|&m| m.clamp(1, n.max(1)))
            .collect();
        counts.sort_unstable();
        counts.dedup();
        let m_top = counts.last().copied().unwrap_or(0);
        let mut bs = Mat::<f64>::zeros(na, 3 * m_top);
        for (k, &s) in order.iter().take(m_top).enumerate() {
            bs[(s, 3 * k)] = 1.0;
            bs[(n + 2 * s, 3 * k + 1)] = 1.0;
            bs[(n + 2 * s + 1, 3 * k + 2)] = 1.0;
        }
        let segments_projected = Projected::new(&fm, &bs);
        // All segments: R_k = Q_k^T Phi_k = Sigma_k V_k^T from the thin SVD of each kind's
        // shapes, keeping the numerical rank.
        let phic = fm.channel_shapes();
        let r = fm.n_modes();
        let rows = [(0, n), (n, na - n)];
        let mut complement = [true; 2];
        let mut coupled_r = [Mat::<f64>::zeros(0, r), Mat::<f64>::zeros(0, r)];
        let mut coupled_rank = [0, 0];
        for (kind, &(r0, nr)) in rows.iter().enumerate() {
            if r == 0 || nr == 0 {
                complement[kind] = nr > 0;
                continue;
            }
            let svd = phic
                .subrows(r0, nr)
                .thin_svd()
                .map_err(|_| M1Error::InvalidInput("SVD of the channel shapes failed".into()))?;
            let sv = svd.S().column_vector();
            let smax = (0..sv.nrows()).map(|i| sv[i]).fold(0.0f64, f64::max);
            let keep: Vec<usize> = (0..sv.nrows())
                .filter(|&i| smax > 0.0 && sv[i] > 1e-10 * smax)
                .collect();
            let v = svd.V();
            complement[kind] = keep.len() < nr;
            coupled_rank[kind] = keep.len();
            let rk = Mat::from_fn(keep.len(), r, |i, j| sv[keep[i]] * v[(j, keep[i])]);
            // The same subspace in the coordinates that make R_k upper trapezoidal (R_k = U
            // R'_k, U orthogonal): its products read only the upper part.
            let rt = rk.qr();
            let rt = rt.thin_R();
            coupled_r[kind] =
                Mat::from_fn(rt.nrows(), r, |i, j| if j >= i { rt[(i, j)] } else { 0.0 });
        }
        Ok(Self {
            fm,
            zernike,
            zernike_projected,
            segment_counts: counts,
            segments_projected,
            coupled_gram: [0, 1]
                .map(|k| UpperTrapezoid::new((coupled_r[k].transpose() * &coupled_r[k]).as_ref())),
            coupled_r: [0, 1].map(|k| UpperTrapezoid::new(coupled_r[k].as_ref())),
            coupled_rank,
            complement,
            lanczos_steps: super::LANCZOS_STEPS,
        })
    }

    /// The loop with at most `steps` Lanczos steps per all-segment value (default
    /// [`super::LANCZOS_STEPS`]): where the top singular values cluster the limit ends the
    /// iteration, and more steps bring the value, a lower bound, closer to the exact one.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for a limit outside [`super::LANCZOS_STEPS_RANGE`].
    pub fn with_lanczos_steps(mut self, steps: usize) -> Result<Self, M1Error> {
        if !super::LANCZOS_STEPS_RANGE.contains(&steps) {
            return Err(M1Error::InvalidParameter {
                name: "Lanczos steps",
                value: steps as f64,
                reason: "outside LANCZOS_STEPS_RANGE",
            });
        }
        self.lanczos_steps = steps;
        Ok(self)
    }

    /// The all-segment Lanczos's step limit.
    pub fn lanczos_steps(&self) -> usize {
        self.lanczos_steps
    }

    /// The frequency model.
    pub fn model(&self) -> &FrequencyModel {
        &self.fm
    }

    /// Number of orthonormal Zernike vectors up to each radial degree.
    pub fn zernike_sizes(&self) -> &[usize] {
        &self.zernike.prefix
    }

    /// Segment counts of the segment bases.
    pub fn segment_counts(&self) -> &[usize] {
        &self.segment_counts
    }

    /// Dimension of the all-segment coupled subspace ($r_p + r_t$).
    pub fn coupled_dimension(&self) -> usize {
        self.coupled_rank[0] + self.coupled_rank[1]
    }

    /// Every basis's largest sensitivity singular value at `f` (Hz), servo scaled by `gain`.
    ///
    /// # Errors
    /// [`M1Error::Unstable`] at a singular point, [`M1Error::InvalidInput`] if an SVD fails.
    pub fn point(&self, f: f64, gain: f64) -> Result<CsiPoint, M1Error> {
        self.point_warm(f, gain, None).map(|(p, _, _)| p)
    }

    /// [`Self::point`] with the plant projected on the Zernike basis of the largest degree
    /// (gain-independent; the servo-gain search reuses it) and the all-segment top vector,
    /// that point's Lanczos started from `warm` (a nearby point's top vector) when given.
    pub(super) fn point_warm(
        &self,
        f: f64,
        gain: f64,
        warm: Option<&[c64]>,
    ) -> Result<Evaluated, M1Error> {
        let k = Kinds::new(self.fm.model(), f);
        let lu = modal_factor(&self.fm, &k);
        let s = k.k_s * gain;
        let mz = self.zernike_projected.plant(&k, lu.as_ref())?;
        let zernike = self
            .zernike
            .prefix
            .iter()
            .map(|&nb| sensitivity_max(&mz, s, nb))
            .collect::<Result<Vec<_>, _>>()?;
        let ms = self.segments_projected.plant(&k, lu.as_ref())?;
        let segments = self
            .segment_counts
            .iter()
            .map(|&m| sensitivity_max(&ms, s, 3 * m))
            .collect::<Result<Vec<_>, _>>()?;
        let (all_segments, top) = self.all_from_kinds_warm(&k, gain, warm)?;
        let point = CsiPoint {
            frequency_hz: f,
            zernike,
            segments,
            all_segments,
        };
        Ok((point, mz, top))
    }

    /// The exact all-segment $\sigma_{max}(S)$ at `f` (Hz) with the servo scaled by `gain`
    /// (module documentation, "All segments").
    ///
    /// # Errors
    /// As [`Self::point`].
    pub fn all_sensitivity(&self, f: f64, gain: f64) -> Result<f64, M1Error> {
        self.all_from_kinds(&Kinds::new(self.fm.model(), f), gain)
    }

    /// The dense reference: $\sigma_{max}((I + K_s P)^{-1})$ from the full $n_a \times n_a$
    /// channel-space plant (for tests; $O(n_a^3)$).
    ///
    /// # Errors
    /// As [`Self::point`].
    pub fn dense_sensitivity(&self, f: f64) -> Result<f64, M1Error> {
        let na = self.fm.n_actuators();
        let ident = Mat::<f64>::identity(na, na);
        let p = Projected::new(&self.fm, &ident);
        let k = Kinds::new(self.fm.model(), f);
        let m = p.plant(&k, modal_factor(&self.fm, &k).as_ref())?;
        sensitivity_max(&m, k.k_s, na)
    }

    /// The dominant Zernike mode of the top left singular vector of $S_B$ for the Zernike basis
    /// of radial degree `degree` at `f` (Hz), servo scaled by `gain`: `(label, Noll index)`.
    ///
    /// # Errors
    /// As [`Self::point`]; [`M1Error::InvalidParameter`] for a degree beyond the basis.
    pub fn peak_label(&self, f: f64, degree: u32, gain: f64) -> Result<(String, usize), M1Error> {
        let nb = *self
            .zernike
            .prefix
            .get(degree as usize)
            .ok_or(M1Error::InvalidParameter {
                name: "degree",
                value: f64::from(degree),
                reason: "beyond the largest Zernike degree of the analysis",
            })?;
        let k = Kinds::new(self.fm.model(), f);
        let lu = modal_factor(&self.fm, &k);
        let mz = self.zernike_projected.plant(&k, lu.as_ref())?;
        self.label_from_plant(&mz, f, nb, degree, gain)
    }

    /// [`Self::peak_label`] from the plant `mz` projected on the Zernike basis of the largest
    /// degree at `f` (Hz), as the sweep keeps it, for the leading `nb` vectors (degree
    /// `degree`).
    pub(super) fn label_from_plant(
        &self,
        mz: &Mat<c64>,
        f: f64,
        nb: usize,
        degree: u32,
        gain: f64,
    ) -> Result<(String, usize), M1Error> {
        let k = Kinds::new(self.fm.model(), f);
        let s = k.k_s * gain;
        let a = Mat::from_fn(nb, nb, |i, j| {
            let d = if i == j { 1.0 } else { 0.0 };
            c64::new(d, 0.0) + s * mz[(i, j)]
        });
        // a = U Sigma V^H, S_B = V Sigma^-1 U^H: the top left singular vector of S_B is the
        // right singular vector of `a` with its smallest singular value.
        let svd = a
            .svd()
            .map_err(|_| M1Error::InvalidInput("SVD of the return difference failed".into()))?;
        let sv = svd.S().column_vector();
        let imin = (0..nb)
            .min_by(|&i, &j| sv[i].re.total_cmp(&sv[j].re))
            .unwrap_or(0);
        let v = svd.V();
        let u: Vec<c64> = (0..nb).map(|i| v[(i, imin)]).collect();
        Ok(self.zernike.dominant(&u, degree))
    }
}
