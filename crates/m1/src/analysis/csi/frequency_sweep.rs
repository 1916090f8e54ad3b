//! The sweep of every basis over a log grid ([`sweep`], [`CsiSweep`]): the refinement around
//! each curve's peak, the curves ([`BasisCurve`]) and the labelled local maxima of the
//! all-segment curve ([`LabelledPeak`]); with the grid helpers.

use faer::{Mat, c64};
use rayon::prelude::*;
use serde::Serialize;

use super::actuator_loop::{ActuatorLoop, CsiPoint, Evaluated};
use crate::M1Error;

/// `n` log-spaced frequencies from `fmin` to `fmax` (Hz).
pub fn log_grid(fmin: f64, fmax: f64, n: usize) -> Vec<f64> {
    if n < 2 {
        return vec![fmin];
    }
    let (a, b) = (fmin.ln(), fmax.ln());
    (0..n)
        .map(|i| (a + (b - a) * i as f64 / (n - 1) as f64).exp())
        .collect()
}

/// One basis's curve and its peak.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BasisCurve {
    /// `zernike`, `segments` or `all_segments`.
    pub basis: String,
    /// Largest radial degree (Zernike bases).
    pub max_radial_degree: Option<u32>,
    /// Segments (segment bases and all segments).
    pub n_segments: Option<usize>,
    /// Number of orthonormal basis vectors (actuators for all segments).
    pub n_vectors: usize,
    /// $\sigma_{max}(S)$ on the grid.
    pub sensitivity_max: Vec<f64>,
    /// Peak over the grid, $\|S\|_\infty$.
    pub peak_sensitivity: f64,
    /// Where it peaks (Hz).
    pub peak_frequency_hz: f64,
    /// Family of the dominant Zernike mode at the peak (Zernike bases and all segments).
    pub peak_label: Option<String>,
    /// Noll index of that mode.
    pub peak_noll: Option<usize>,
}

/// A local maximum of the all-segment curve, labelled with the largest Zernike degree.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LabelledPeak {
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// $\sigma_{max}(S)$ there, all segments.
    pub sensitivity_max: f64,
    /// Family of the dominant Zernike mode.
    pub label: String,
    /// Its Noll index.
    pub noll: usize,
}

/// The sweep of every basis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CsiSweep {
    /// The grid (Hz), with the refinement around the peaks.
    pub frequencies_hz: Vec<f64>,
    /// Zernike bases, degree 0 up.
    pub zernike: Vec<BasisCurve>,
    /// Segment bases.
    pub segments: Vec<BasisCurve>,
    /// All segments (exact).
    pub all_segments: BasisCurve,
    /// Local maxima of the all-segment curve above the label threshold.
    pub all_segment_peaks: Vec<LabelledPeak>,
    /// The plant projected on the Zernike basis of the largest degree at each frequency
    /// (gain-independent: [`super::highest_gain`] reuses them).
    #[serde(skip)]
    pub(super) zernike_plants: Vec<Mat<c64>>,
    /// The all-segment top vector at each frequency (the servo-gain search starts its
    /// Lanczos from them).
    #[serde(skip)]
    pub(super) top_vectors: Vec<Option<Vec<c64>>>,
}

/// Consecutive grid frequencies evaluated in one thread, each point's all-segment Lanczos
/// started from its predecessor's top vector (the runs in parallel; a fixed split, so the
/// values do not depend on the number of threads).
const WARM_RUN: usize = 8;

/// Indices of the local maxima of `v` (a plateau counts at its last point; the ends count).
pub(crate) fn local_maxima(v: &[f64]) -> impl Iterator<Item = usize> + '_ {
    (0..v.len()).filter(move |&i| {
        let left = i == 0 || v[i] >= v[i - 1];
        let right = i + 1 == v.len() || v[i] > v[i + 1];
        left && right
    })
}

pub(super) fn argmax(v: &[f64]) -> usize {
    (0..v.len())
        .max_by(|&a, &b| v[a].total_cmp(&v[b]))
        .unwrap_or(0)
}

/// Every basis on the log grid `grid` (Hz, ascending), with `refine` extra points between the
/// neighbours of each curve's peak; local maxima of the all-segment curve above
/// `label_threshold` are labelled.
///
/// # Errors
/// As [`ActuatorLoop::point`].
pub fn sweep(
    lp: &ActuatorLoop,
    grid: &[f64],
    refine: usize,
    label_threshold: f64,
) -> Result<CsiSweep, M1Error> {
    // The grid in runs of neighbouring frequencies, each warm-started along the run.
    let runs: Vec<&[f64]> = grid.chunks(WARM_RUN).collect();
    let mut evaluated: Vec<Evaluated> = runs
        .par_iter()
        .map(|run| {
            let mut out: Vec<Evaluated> = Vec::with_capacity(run.len());
            for &f in *run {
                let warm = out.last().and_then(|e| e.2.as_deref());
                let e = lp.point_warm(f, 1.0, warm)?;
                out.push(e);
            }
            Ok(out)
        })
        .collect::<Result<Vec<_>, M1Error>>()?
        .into_iter()
        .flatten()
        .collect();
    let pts: Vec<&CsiPoint> = evaluated.iter().map(|(p, _, _)| p).collect();
    if refine > 0 && pts.len() > 2 {
        let mut idx: Vec<usize> = Vec::new();
        let nz = pts[0].zernike.len();
        let ns = pts[0].segments.len();
        for c in 0..nz + ns + 1 {
            let v: Vec<f64> = pts
                .iter()
                .map(|p| {
                    if c < nz {
                        p.zernike[c]
                    } else if c < nz + ns {
                        p.segments[c - nz]
                    } else {
                        p.all_segments
                    }
                })
                .collect();
            idx.push(argmax(&v));
        }
        idx.sort_unstable();
        idx.dedup();
        let mut extra = Vec::new();
        for i in idx {
            let lo = grid[i.saturating_sub(1)];
            let hi = grid[(i + 1).min(grid.len() - 1)];
            for k in 1..=refine {
                let f = (lo.ln() + (hi.ln() - lo.ln()) * k as f64 / (refine + 1) as f64).exp();
                if !grid.iter().any(|&g| (g - f).abs() <= 1e-12 * f) {
                    extra.push(f);
                }
            }
        }
        extra.sort_by(f64::total_cmp);
        extra.dedup();
        // Each refinement point starts from the nearest grid point's top vector.
        let nearest = |f: f64| {
            (0..grid.len())
                .min_by(|&a, &b| {
                    (grid[a] / f)
                        .ln()
                        .abs()
                        .total_cmp(&(grid[b] / f).ln().abs())
                })
                .unwrap_or(0)
        };
        let more = extra
            .par_iter()
            .map(|&f| lp.point_warm(f, 1.0, evaluated[nearest(f)].2.as_deref()))
            .collect::<Result<Vec<_>, M1Error>>()?;
        evaluated.extend(more);
        evaluated.sort_by(|a, b| a.0.frequency_hz.total_cmp(&b.0.frequency_hz));
    }
    let mut pts = Vec::with_capacity(evaluated.len());
    let mut zernike_plants = Vec::with_capacity(evaluated.len());
    let mut top_vectors = Vec::with_capacity(evaluated.len());
    for (p, m, v) in evaluated {
        pts.push(p);
        zernike_plants.push(m);
        top_vectors.push(v);
    }
    let freqs: Vec<f64> = pts.iter().map(|p| p.frequency_hz).collect();
    let max_degree = pts.first().map_or(0, |p| p.zernike.len().saturating_sub(1)) as u32;
    // Labels from the kept Zernike plants (the values peak_label would factorise again); every
    // degree here is one of the bases' (at most `max_degree`).
    let label = |i: usize, d: u32| {
        let nb = lp.zernike.prefix[d as usize];
        lp.label_from_plant(&zernike_plants[i], freqs[i], nb, d, 1.0)
    };
    let curve = |basis: &str,
                 degree: Option<u32>,
                 segs: Option<usize>,
                 nv: usize,
                 v: Vec<f64>|
     -> Result<BasisCurve, M1Error> {
        let i = argmax(&v);
        let (label, noll) = match (basis, degree) {
            ("segments", _) => (None, None),
            (_, Some(d)) => {
                let (l, j) = label(i, d)?;
                (Some(l), Some(j))
            }
            _ => {
                let (l, j) = label(i, max_degree)?;
                (Some(l), Some(j))
            }
        };
        Ok(BasisCurve {
            basis: basis.into(),
            max_radial_degree: degree,
            n_segments: segs,
            n_vectors: nv,
            peak_sensitivity: v[i],
            peak_frequency_hz: freqs[i],
            sensitivity_max: v,
            peak_label: label,
            peak_noll: noll,
        })
    };
    let zernike = (0..lp.zernike.prefix.len())
        .map(|d| {
            let v = pts.iter().map(|p| p.zernike[d]).collect();
            curve("zernike", Some(d as u32), None, lp.zernike.prefix[d], v)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let segments = lp
        .segment_counts
        .iter()
        .enumerate()
        .map(|(c, &m)| {
            let v = pts.iter().map(|p| p.segments[c]).collect();
            curve("segments", None, Some(m), 3 * m, v)
        })
        .collect::<Result<Vec<_>, _>>()?;
    let va: Vec<f64> = pts.iter().map(|p| p.all_segments).collect();
    let n = lp.fm.n_segments();
    let mut peaks = Vec::new();
    for i in local_maxima(&va).filter(|&i| va[i] > label_threshold) {
        let (label, noll) = label(i, max_degree)?;
        peaks.push(LabelledPeak {
            frequency_hz: freqs[i],
            sensitivity_max: va[i],
            label,
            noll,
        });
    }
    let all_segments = curve("all_segments", None, Some(n), 3 * n, va)?;
    Ok(CsiSweep {
        frequencies_hz: freqs,
        zernike,
        segments,
        all_segments,
        all_segment_peaks: peaks,
        zernike_plants,
        top_vectors,
    })
}
