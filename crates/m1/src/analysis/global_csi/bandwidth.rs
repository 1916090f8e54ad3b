//! The highest global-loop bandwidth meeting the criteria ([`GlobalBandwidth`]): bisection in
//! the Zernike basis of the largest degree on the sweep's plants, then the all-segment check,
//! lowered until it passes.

use faer::{Mat, c64};
use rayon::prelude::*;
use serde::Serialize;

use super::GlobalCriteria;
use super::zernike_loop::{GlobalCsi, extremes};
use crate::M1Error;
use crate::control::controller::{ControllerParams, LoopGains};
use crate::plant::monolithic::PlantOnW;

/// The highest global-loop bandwidth meeting the criteria: searched in the Zernike basis of the
/// largest degree, then checked with all segments (and lowered until that check passes).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GlobalBandwidth {
    /// Bandwidth of radial degrees >= 5 (Hz); radial degrees 3-4 and 2 at the ratios of the
    /// analysed controller.
    pub bandwidth_hz: f64,
    /// The bandwidth found in the Zernike basis (first stage).
    pub zernike_bandwidth_hz: f64,
    /// Whether `bandwidth_hz` meets both criteria with all segments.
    pub meets_criteria: bool,
    /// Peak sensitivity there (all segments).
    pub peak_sensitivity: f64,
    /// Largest loop gain at and above the band start there, and where (Hz).
    pub high_frequency_loop_gain: f64,
    /// Where (Hz).
    pub high_frequency_loop_gain_hz: f64,
    /// What stops a higher one: "sensitivity", "loop gain", "search range" (the top passes),
    /// "all-segment check" or "no bandwidth meets the criteria".
    pub limited_by: String,
}

/// The bandwidth search of [`global_sweep`](super::global_sweep): geometric bisection between
/// 0.01 Hz and 0.49 of the loop rate to 0.5 % on the Zernike basis of the largest degree (its
/// plants kept per frequency), then the all-segment check of the result, lowered in growing
/// steps (1 %, 3 %, 7 %, ...) and bisected again to 1 % with all segments if it fails. Assumes
/// the criteria hold below some bandwidth and fail above it (a pass above a failing bisection
/// point can be missed).
pub(super) fn highest_global_bandwidth(
    g: &GlobalCsi,
    grid: &[f64],
    plants: &[PlantOnW],
    zplants: &[Mat<c64>],
    nominal: &[(f64, f64)],
    criteria: &GlobalCriteria,
) -> Result<GlobalBandwidth, M1Error> {
    let s = BandwidthSearch::new(g, grid, plants, zplants, nominal, criteria);
    let (lo0, hi0) = (0.01, 0.49 * g.params.rate);
    // The Zernike stage.
    let top = s.zeval(hi0)?;
    let (bz, zwhy) = if s.ok(top) {
        (hi0, "search range")
    } else if !s.ok(s.zeval(lo0)?) {
        let e = s.aeval(lo0)?;
        return Ok(result(
            lo0,
            lo0,
            e,
            s.ok(e),
            "no bandwidth meets the criteria",
        ));
    } else {
        s.bisect(lo0, hi0, &|b| s.zeval(b))?
    };
    s.check_all_segments(bz, zwhy, lo0)
}

/// The report of a bandwidth `b` (`bz` found in the Zernike basis) with its summary `e`.
fn result(b: f64, bz: f64, e: (f64, f64, f64), meets: bool, by: &str) -> GlobalBandwidth {
    GlobalBandwidth {
        bandwidth_hz: b,
        zernike_bandwidth_hz: bz,
        meets_criteria: meets,
        peak_sensitivity: e.0,
        high_frequency_loop_gain: e.1,
        high_frequency_loop_gain_hz: e.2,
        limited_by: by.into(),
    }
}

/// What the bandwidth search evaluates the loop with: the plants of both stages per grid
/// frequency, the criteria, and the order in which the all-segment test visits the grid.
struct BandwidthSearch<'a> {
    g: &'a GlobalCsi,
    grid: &'a [f64],
    plants: &'a [PlantOnW],
    zplants: &'a [Mat<c64>],
    criteria: &'a GlobalCriteria,
    /// The loop-gain limit with the allowance.
    limit: f64,
    /// The ratios of the bandwidths of radial degrees 3-4 and 2 to that of radial degrees >= 5.
    ratio34: f64,
    ratio2: f64,
    /// Vectors of the Zernike basis of the largest degree.
    nz: usize,
    /// Grid indices from the nominal loop's worst down.
    order: Vec<usize>,
}

impl<'a> BandwidthSearch<'a> {
    /// The search of [`highest_global_bandwidth`]'s arguments.
    fn new(
        g: &'a GlobalCsi,
        grid: &'a [f64],
        plants: &'a [PlantOnW],
        zplants: &'a [Mat<c64>],
        nominal: &[(f64, f64)],
        criteria: &'a GlobalCriteria,
    ) -> Self {
        let limit = criteria.max_loop_gain / criteria.allowance;
        // Radial degrees 3-4 and 2 keep their ratios to the bandwidth of radial degrees >= 5.
        let ratio = |x: f64| {
            if g.params.bandwidth > 0.0 {
                x / g.params.bandwidth
            } else {
                1.0
            }
        };
        let (ratio34, ratio2) = (
            ratio(g.params.bandwidth_radial34),
            ratio(g.params.bandwidth_radial2),
        );
        let nz = g.prefix.last().copied().unwrap_or(0);
        let band = |i: usize| grid[i] >= criteria.band_start_hz;
        // Pass/fail with all segments, stopping at the first failing frequency (visited from
        // the nominal loop's worst down, from the sweep); the full summary only for a pass.
        let worst: Vec<f64> = (0..grid.len())
            .map(|i| {
                let l = if band(i) { nominal[i].0 / limit } else { 0.0 };
                l.max(nominal[i].1 / criteria.max_sensitivity)
            })
            .collect();
        let mut order: Vec<usize> = (0..plants.len()).collect();
        order.sort_by(|&x, &y| worst[y].total_cmp(&worst[x]));
        Self {
            g,
            grid,
            plants,
            zplants,
            criteria,
            limit,
            ratio34,
            ratio2,
            nz,
            order,
        }
    }

    /// The controller's gains at bandwidth `b` of radial degrees >= 5.
    fn gains_at(&self, b: f64) -> Result<LoopGains, M1Error> {
        ControllerParams {
            bandwidth: b,
            bandwidth_radial34: self.ratio34 * b,
            bandwidth_radial2: self.ratio2 * b,
            ..self.g.params
        }
        .gains()
    }

    /// Whether grid point `i` is in the loop-gain criterion's band.
    fn band(&self, i: usize) -> bool {
        self.grid[i] >= self.criteria.band_start_hz
    }

    /// (peak sensitivity, high-frequency loop gain, where) in the Zernike basis at bandwidth
    /// `b`.
    fn zeval(&self, b: f64) -> Result<(f64, f64, f64), M1Error> {
        let (g, grid, zplants, nz) = (self.g, self.grid, self.zplants, self.nz);
        let gains = self.gains_at(b)?;
        let v: Vec<(f64, f64)> = (0..grid.len())
            .into_par_iter()
            .map(|i| extremes(&g.zernike_loop(grid[i], &zplants[i], &gains), nz, grid[i]))
            .collect::<Result<_, _>>()?;
        Ok(summary(&v, grid, &|i| self.band(i)))
    }

    /// The same with all segments.
    fn aeval(&self, b: f64) -> Result<(f64, f64, f64), M1Error> {
        let g = self.g;
        let gains = self.gains_at(b)?;
        let v: Vec<(f64, f64)> = self
            .plants
            .par_iter()
            .map(|p| {
                g.gl.point(p, &gains)
                    .map(|q| (q.loop_gain_max, q.sensitivity_max))
            })
            .collect::<Result<_, _>>()?;
        Ok(summary(&v, self.grid, &|i| self.band(i)))
    }

    /// Whether a summary meets both criteria.
    fn ok(&self, e: (f64, f64, f64)) -> bool {
        e.0 < self.criteria.max_sensitivity && e.1 < self.limit
    }

    /// The all-segment test at bandwidth `b`: its summary for a pass, `None` at the first
    /// failing frequency.
    fn apass(&self, b: f64) -> Result<Option<(f64, f64, f64)>, M1Error> {
        let (g, grid, plants, criteria, limit, order) = (
            self.g,
            self.grid,
            self.plants,
            self.criteria,
            self.limit,
            &self.order,
        );
        let band = |i: usize| self.band(i);
        let gains = self.gains_at(b)?;
        let failed = std::sync::atomic::AtomicBool::new(false);
        let vals: Vec<Option<(f64, f64)>> = order
            .par_iter()
            .map(|&i| -> Result<Option<(f64, f64)>, M1Error> {
                if failed.load(std::sync::atomic::Ordering::Relaxed) {
                    return Ok(None);
                }
                let q = g.gl.point(&plants[i], &gains)?;
                if q.sensitivity_max >= criteria.max_sensitivity
                    || (band(i) && q.loop_gain_max >= limit)
                {
                    failed.store(true, std::sync::atomic::Ordering::Relaxed);
                }
                Ok(Some((q.loop_gain_max, q.sensitivity_max)))
            })
            .collect::<Result<_, _>>()?;
        if failed.load(std::sync::atomic::Ordering::Relaxed) {
            return Ok(None);
        }
        // Every point was computed: back to grid order.
        let mut v = vec![(0.0, 0.0); plants.len()];
        for (k, &i) in order.iter().enumerate() {
            v[i] = vals[k].unwrap_or((f64::NAN, f64::NAN));
        }
        Ok(Some(summary(&v, grid, &band)))
    }

    /// Which criterion a failing summary breaks.
    fn why(&self, e: (f64, f64, f64)) -> &'static str {
        if e.0 >= self.criteria.max_sensitivity {
            "sensitivity"
        } else {
            "loop gain"
        }
    }

    /// Geometric bisection to 0.5 % between a passing `lo` and a failing `hi` under `eval`:
    /// the highest passing bandwidth and what failed above it.
    fn bisect(
        &self,
        mut lo: f64,
        mut hi: f64,
        eval: &dyn Fn(f64) -> Result<(f64, f64, f64), M1Error>,
    ) -> Result<(f64, &'static str), M1Error> {
        let mut reason = "loop gain";
        while hi / lo > 1.005 {
            let mid = (lo * hi).sqrt();
            let e = eval(mid)?;
            if self.ok(e) {
                lo = mid;
            } else {
                hi = mid;
                reason = self.why(e);
            }
        }
        Ok((lo, reason))
    }

    /// The all-segment check of the Zernike bandwidth `bz` (found for the reason `zwhy`), then
    /// lower in growing steps (not below `lo0`) and bisect to 1 %.
    fn check_all_segments(
        &self,
        bz: f64,
        zwhy: &str,
        lo0: f64,
    ) -> Result<GlobalBandwidth, M1Error> {
        if let Some(e) = self.apass(bz)? {
            return Ok(result(bz, bz, e, true, zwhy));
        }
        let mut bad = bz;
        let mut good = None;
        for f in [0.99, 0.97, 0.93, 0.85, 0.7, 0.5, 0.25, 0.1] {
            let b = (bz * f).max(lo0);
            if let Some(e) = self.apass(b)? {
                good = Some((b, e));
                break;
            }
            bad = b;
            if b <= lo0 {
                break;
            }
        }
        let Some((mut gd, mut ge)) = good else {
            return Ok(result(
                bz,
                bz,
                self.aeval(bz)?,
                false,
                "no bandwidth meets the criteria",
            ));
        };
        while bad / gd > 1.01 {
            let mid = (gd * bad).sqrt();
            match self.apass(mid)? {
                Some(e) => {
                    gd = mid;
                    ge = e;
                }
                None => bad = mid,
            }
        }
        Ok(result(gd, bz, ge, true, "all-segment check"))
    }
}

/// `(peak sensitivity, largest loop gain in the band, where)` of `(loop gain, sensitivity)`
/// pairs on `grid`.
fn summary(v: &[(f64, f64)], grid: &[f64], band: &dyn Fn(usize) -> bool) -> (f64, f64, f64) {
    let (mut s, mut l, mut at) = (0.0f64, 0.0f64, f64::NAN);
    for (i, &(li, si)) in v.iter().enumerate() {
        s = s.max(si);
        if band(i) && li > l {
            l = li;
            at = grid[i];
        }
    }
    (s, l, at)
}
