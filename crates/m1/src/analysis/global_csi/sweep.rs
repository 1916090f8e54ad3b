//! The global loop's sweep against the criteria ([`global_sweep`], [`GlobalSweep`]): every
//! basis's curves ([`GlobalCurve`]) with their peaks labelled, the labelled local maxima of the
//! all-segment curves ([`GlobalPeak`]), and the bandwidth search on the sweep's plants.

use faer::{Mat, c64};
use rayon::prelude::*;
use serde::Serialize;

use super::bandwidth::{GlobalBandwidth, highest_global_bandwidth};
use super::zernike_loop::{GlobalCsi, GlobalPoint};
use super::{GlobalCriteria, GlobalQuantity, MAX_LABELLED_PEAKS, SENSITIVITY_LABEL_FROM};
use crate::M1Error;
use crate::control::controller::{ControllerParams, LoopGains};
use crate::plant::monolithic::PlantOnW;

/// A labelled local maximum of an all-segment curve.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GlobalPeak {
    /// Which curve.
    pub quantity: GlobalQuantity,
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// The maximum singular value there (all segments).
    pub value: f64,
    /// Family of the dominant Zernike mode (largest degree of the analysis).
    pub label: String,
    /// Its Noll index.
    pub noll: usize,
}

/// One basis's curves.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GlobalCurve {
    /// `zernike` or `all_segments`.
    pub basis: String,
    /// Largest radial degree (Zernike bases).
    pub max_radial_degree: Option<u32>,
    /// Basis vectors (actuators for all segments).
    pub n_vectors: usize,
    /// $\sigma_{max}(S)$ on the grid.
    pub sensitivity_max: Vec<f64>,
    /// $\sigma_{max}(L)$ on the grid.
    pub loop_gain_max: Vec<f64>,
    /// Peak sensitivity and where (Hz).
    pub peak_sensitivity: f64,
    /// Where the sensitivity peaks (Hz).
    pub peak_sensitivity_hz: f64,
    /// Largest loop gain at and above the band start, and where (Hz).
    pub high_frequency_loop_gain: f64,
    /// Where (Hz).
    pub high_frequency_loop_gain_hz: f64,
    /// Family of the dominant Zernike mode at the sensitivity peak.
    pub peak_sensitivity_label: Option<String>,
    /// Its Noll index.
    pub peak_sensitivity_noll: Option<usize>,
    /// Family of the dominant Zernike mode at the high-frequency loop-gain peak.
    pub high_frequency_loop_gain_label: Option<String>,
    /// Its Noll index.
    pub high_frequency_loop_gain_noll: Option<usize>,
}

/// The global loop's sweep against the criteria.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GlobalSweep {
    /// The grid (Hz).
    pub frequencies_hz: Vec<f64>,
    /// The controller analysed.
    pub params: ControllerParams,
    /// Retained structural modes.
    pub modes: usize,
    /// Images of the sensors' sampling summed on each side.
    pub aliases: usize,
    /// The criteria.
    pub criteria: GlobalCriteria,
    /// The loop-gain limit with the allowance, `max_loop_gain / allowance`.
    pub loop_gain_limit: f64,
    /// Zernike bases, degree 0 up.
    pub zernike: Vec<GlobalCurve>,
    /// All segments (exact on the coupled subspace).
    pub all_segments: GlobalCurve,
    /// Labelled local maxima of the all-segment curves, by frequency (see the module
    /// documentation).
    pub all_segment_peaks: Vec<GlobalPeak>,
    /// Whether the peak sensitivity (all segments) meets its criterion.
    pub meets_sensitivity: bool,
    /// Whether the high-frequency loop gain (all segments) meets its criterion.
    pub meets_loop_gain: bool,
    /// The highest bandwidth of radial degrees >= 5 meeting both (radial degrees 3-4 and 2 at
    /// the same ratios to it as in `params`, focus-mode as in `params`).
    pub highest_bandwidth: GlobalBandwidth,
}

/// The loop on `grid` (Hz, ascending) against `criteria`, and the highest bandwidth meeting
/// them (bisected between 0.01 Hz and 0.49 of the loop rate).
///
/// # Errors
/// As [`GlobalCsi::point`]; [`M1Error::InvalidParameter`] for criteria that are not positive
/// and finite, or an empty grid.
pub fn global_sweep(
    g: &GlobalCsi,
    grid: &[f64],
    criteria: &GlobalCriteria,
) -> Result<GlobalSweep, M1Error> {
    check_inputs(grid, criteria)?;
    let pts: Vec<(GlobalPoint, PlantOnW, Mat<c64>)> = grid
        .par_iter()
        .map(|&f| g.point_with_plants(f))
        .collect::<Result<_, _>>()?;
    let limit = criteria.max_loop_gain / criteria.allowance;
    let gains = g.params.gains()?;
    let top = g.prefix.len().saturating_sub(1) as u32;
    let curves = Curves {
        g,
        grid,
        pts: &pts,
        gains,
        top,
        criteria,
    };
    let zernike = g
        .prefix
        .iter()
        .enumerate()
        .map(|(d, &nb)| {
            curves.curve(
                "zernike",
                Some(d as u32),
                nb,
                pts.iter().map(|p| p.0.zernike_sensitivity[d]).collect(),
                pts.iter().map(|p| p.0.zernike_loop_gain[d]).collect(),
            )
        })
        .collect::<Result<Vec<_>, _>>()?;
    let all = curves.curve(
        "all_segments",
        None,
        g.fm.n_actuators(),
        pts.iter().map(|p| p.0.sensitivity).collect(),
        pts.iter().map(|p| p.0.loop_gain).collect(),
    )?;
    let peaks = curves.all_segment_peaks(&all, limit)?;
    let mut plants = Vec::with_capacity(pts.len());
    let mut zplants = Vec::with_capacity(pts.len());
    for (_, p, z) in pts {
        plants.push(p);
        zplants.push(z);
    }
    let nominal: Vec<(f64, f64)> = all
        .loop_gain_max
        .iter()
        .copied()
        .zip(all.sensitivity_max.iter().copied())
        .collect();
    let highest = highest_global_bandwidth(g, grid, &plants, &zplants, &nominal, criteria)?;
    Ok(GlobalSweep {
        frequencies_hz: grid.to_vec(),
        params: g.params,
        modes: g.fm.n_modes(),
        aliases: g.aliases,
        criteria: *criteria,
        loop_gain_limit: limit,
        meets_sensitivity: all.peak_sensitivity < criteria.max_sensitivity,
        meets_loop_gain: all.high_frequency_loop_gain < limit,
        zernike,
        all_segments: all,
        all_segment_peaks: peaks,
        highest_bandwidth: highest,
    })
}

/// The criteria positive and finite, the grid not empty.
fn check_inputs(grid: &[f64], criteria: &GlobalCriteria) -> Result<(), M1Error> {
    for (name, v) in [
        ("max_sensitivity", criteria.max_sensitivity),
        ("max_loop_gain", criteria.max_loop_gain),
        ("allowance", criteria.allowance),
        ("band_start_hz", criteria.band_start_hz),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(M1Error::InvalidParameter {
                name,
                value: v,
                reason: "must be finite and > 0",
            });
        }
    }
    if grid.is_empty() {
        return Err(M1Error::InvalidParameter {
            name: "grid",
            value: 0.0,
            reason: "needs at least one frequency",
        });
    }
    Ok(())
}

/// What a sweep's curves and their labels are built from: the grid, every point with its
/// plants, the analysed controller's gains and the largest Zernike degree.
struct Curves<'a> {
    g: &'a GlobalCsi,
    grid: &'a [f64],
    pts: &'a [(GlobalPoint, PlantOnW, Mat<c64>)],
    gains: LoopGains,
    top: u32,
    criteria: &'a GlobalCriteria,
}

impl Curves<'_> {
    /// The dominant Zernike mode of `q` at grid point `i` in the basis of radial degree
    /// `degree`.
    fn label(&self, i: usize, degree: u32, q: GlobalQuantity) -> Result<(String, usize), M1Error> {
        self.g
            .label_from_plant(self.grid[i], &self.pts[i].2, &self.gains, degree, q)
    }

    /// One basis's curve from its sensitivity `s` and loop gain `l` on the grid, with its
    /// peaks labelled (in its own basis, or the largest degree's for all segments).
    fn curve(
        &self,
        basis: &str,
        degree: Option<u32>,
        nv: usize,
        s: Vec<f64>,
        l: Vec<f64>,
    ) -> Result<GlobalCurve, M1Error> {
        let (grid, criteria, top) = (self.grid, self.criteria, self.top);
        let label = |i: usize, degree: u32, q: GlobalQuantity| self.label(i, degree, q);
        let (mut ps, mut psf, mut pl, mut plf) = (0.0f64, f64::NAN, 0.0f64, f64::NAN);
        let (mut psi, mut pli) = (None, None);
        for (i, &f) in grid.iter().enumerate() {
            if s[i] > ps {
                ps = s[i];
                psf = f;
                psi = Some(i);
            }
            if f >= criteria.band_start_hz && l[i] > pl {
                pl = l[i];
                plf = f;
                pli = Some(i);
            }
        }
        let d = degree.unwrap_or(top);
        let at = |i: Option<usize>, q| i.map(|i| label(i, d, q)).transpose();
        let sl = at(psi, GlobalQuantity::Sensitivity)?;
        let ll = at(pli, GlobalQuantity::LoopGain)?;
        Ok::<_, M1Error>(GlobalCurve {
            basis: basis.into(),
            max_radial_degree: degree,
            n_vectors: nv,
            sensitivity_max: s,
            loop_gain_max: l,
            peak_sensitivity: ps,
            peak_sensitivity_hz: psf,
            high_frequency_loop_gain: pl,
            high_frequency_loop_gain_hz: plf,
            peak_sensitivity_noll: sl.as_ref().map(|x| x.1),
            peak_sensitivity_label: sl.map(|x| x.0),
            high_frequency_loop_gain_noll: ll.as_ref().map(|x| x.1),
            high_frequency_loop_gain_label: ll.map(|x| x.0),
        })
    }

    /// The labelled local maxima of the all-segment curves `all` (module documentation,
    /// "Peak labels"), by frequency; `limit` is the loop-gain limit with the allowance.
    fn all_segment_peaks(&self, all: &GlobalCurve, limit: f64) -> Result<Vec<GlobalPeak>, M1Error> {
        let (grid, criteria, top) = (self.grid, self.criteria, self.top);
        let label = |i: usize, degree: u32, q: GlobalQuantity| self.label(i, degree, q);
        let mut peaks = Vec::new();
        for (q, v, from, in_band) in [
            (
                GlobalQuantity::Sensitivity,
                &all.sensitivity_max,
                SENSITIVITY_LABEL_FROM,
                false,
            ),
            (
                GlobalQuantity::LoopGain,
                &all.loop_gain_max,
                0.5 * limit,
                true,
            ),
        ] {
            let mut found: Vec<usize> = crate::analysis::csi::local_maxima(v)
                .filter(|&i| v[i] > from && (!in_band || grid[i] >= criteria.band_start_hz))
                .collect();
            found.sort_by(|&x, &y| v[y].total_cmp(&v[x]));
            found.truncate(MAX_LABELLED_PEAKS);
            for i in found {
                let (label, noll) = label(i, top, q)?;
                peaks.push(GlobalPeak {
                    quantity: q,
                    frequency_hz: grid[i],
                    value: v[i],
                    label,
                    noll,
                });
            }
        }
        peaks.sort_by(|x, y| x.frequency_hz.total_cmp(&y.frequency_hz));
        Ok(peaks)
    }
}
