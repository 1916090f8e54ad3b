//! The servo bandwidth the structure allows (module documentation, "Servo bandwidth"): the
//! servo's gains scaled together ([`scaled_servo`]), its rigid-base crossover
//! ([`crossover`]), and the search for the highest factor meeting the sensitivity criterion
//! ([`highest_gain`], [`GainLimit`]).

use faer::{Mat, c64};
use rayon::prelude::*;
use serde::Serialize;

use super::actuator_loop::ActuatorLoop;
use super::frequency_sweep::{CsiSweep, argmax, log_grid};
use super::projected::{Kinds, modal_factor, sensitivity_max};
use crate::M1Error;
use crate::plant::monolithic::{open_channel, servo_transfer};
use crate::plant::segment::{Channel, SegmentModel};

/// The servo with its `kp`, `ki`, `kd` scaled by `gain`.
pub fn scaled_servo(model: &SegmentModel, gain: f64) -> SegmentModel {
    let mut m = model.clone();
    let v = &mut m.actuator.servo;
    v.kp *= gain;
    v.ki *= gain;
    v.kd *= gain;
    m
}

/// The rigid-base loop-gain crossover of the piston channel with the servo scaled by `gain`:
/// the first frequency (Hz) from 0.01 Hz up where $|K_s p_{0,p}|$ falls to 1 (`None` if it
/// starts below 1 or never falls below it before half the servo rate).
pub fn crossover(model: &SegmentModel, gain: f64) -> Option<f64> {
    let mag = |f: f64| {
        let (_, k_s) = servo_transfer(model, f);
        (k_s * gain * open_channel(model, Channel::Piston, f).sampled_stroke).norm()
    };
    let nyq = 0.5 / model.servo_period();
    let grid = log_grid(0.01, 0.999 * nyq, 600);
    if mag(grid[0]) < 1.0 {
        return None;
    }
    for w in grid.windows(2) {
        if mag(w[1]) <= 1.0 {
            let (mut lo, mut hi) = (w[0], w[1]);
            for _ in 0..50 {
                let mid = (lo * hi).sqrt();
                if mag(mid) > 1.0 {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            return Some((lo * hi).sqrt());
        }
    }
    None
}

/// Factors scanned by [`highest_gain`] before bisecting.
pub const SCAN: usize = 16;

/// The highest servo gain meeting the sensitivity criterion.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GainLimit {
    /// Factor on the servo's kp, ki, kd (1 is the nominal servo).
    pub gain_factor: f64,
    /// The scaled gains.
    pub kp: f64,
    /// Integral gain.
    pub ki: f64,
    /// Derivative gain.
    pub kd: f64,
    /// Rigid-base servo bandwidth (piston loop-gain crossover) at that factor (Hz).
    pub bandwidth_hz: Option<f64>,
    /// The nominal servo's bandwidth (Hz).
    pub nominal_bandwidth_hz: Option<f64>,
    /// All-segment peak sensitivity below the criterion's frequency at that factor.
    pub peak_sensitivity: f64,
    /// Where (Hz).
    pub peak_frequency_hz: f64,
    /// The criterion: sensitivity below this...
    pub max_sensitivity: f64,
    /// ... at every grid frequency up to this (Hz).
    pub below_hz: f64,
    /// Whether the factor meets the criterion with all segments (if none does, the factor
    /// reported is the nominal 1 when its servo is valid, else the lowest valid one scanned).
    pub meets_criterion: bool,
    /// The highest factor found in the Zernike basis of the largest degree (first stage).
    pub zernike_gain_factor: Option<f64>,
    /// That Zernike degree.
    pub zernike_degree: u32,
    /// When no factor meets the criterion: the scanned factor with the lowest peak in the
    /// Zernike basis, and its all-segment peak (the best this structure allows).
    pub lowest_peak_factor: Option<f64>,
    /// That all-segment peak sensitivity below the criterion's frequency.
    pub lowest_peak_sensitivity: Option<f64>,
    /// What stops a higher factor: "sensitivity", "servo stability" (the rigid-base loop of
    /// the next factor is unstable), "search range" (the top factor passes), "all-segment
    /// check" (the Zernike factor failed with all segments and was lowered), "no factor meets
    /// the criterion" or "servo unstable over the whole range".
    pub limited_by: String,
}

/// The sensitivity test of one basis over a band: `Ok(None)` for an invalid scaled servo,
/// else whether every frequency is below the limit.
type PassFn<'a> = dyn Fn(f64) -> Result<Option<bool>, M1Error> + Sync + 'a;

/// Scan and bisection of [`highest_gain`] with one basis's test: `(factor, passes, why)` for
/// the highest passing factor, `None` if none of the scan passes.
fn search_factor(
    factors: &[f64],
    passes: &PassFn<'_>,
) -> Result<Option<(f64, &'static str)>, M1Error> {
    let scan: Vec<Option<bool>> = factors
        .iter()
        .map(|&a| passes(a))
        .collect::<Result<_, _>>()?;
    let Some(k) = (0..factors.len()).rev().find(|&k| scan[k] == Some(true)) else {
        return Ok(None);
    };
    if k + 1 == factors.len() {
        return Ok(Some((factors[k], "search range")));
    }
    let (mut a, mut b, mut fail) = (factors[k], factors[k + 1], scan[k + 1]);
    while b / a > 1.005 {
        let mid = (a * b).sqrt();
        let e = passes(mid)?;
        if e == Some(true) {
            a = mid;
        } else {
            b = mid;
            fail = e;
        }
    }
    Ok(Some((
        a,
        if fail.is_none() {
            "servo stability"
        } else {
            "sensitivity"
        },
    )))
}

/// Searches the factor on the servo gains in `[lo, hi]` for the largest keeping
/// $\sigma_{max}(S)$ below `max_sensitivity` at the frequencies of `sweep` (made with the
/// nominal servo, whose values it reuses) up to `below_hz`,
/// with the scaled segment model valid; the seed paper's way: in the Zernike basis of the
/// largest degree first (cheap: its plants are kept per frequency), then checked with all
/// segments and lowered until that check passes.
///
/// The search: the window of factors with a valid (stable) servo on 400 log-spaced factors,
/// a log-spaced scan of [`SCAN`] factors over it (plus 1 and the first unstable factor above
/// it), then geometric bisection to 0.5 % between the largest passing scan point and the next.
/// If the all-segment check fails, the factor is lowered by 5 % steps until it passes and then
/// bisected to 0.5 % with all segments. The peak need not be monotonic in the factor: a pass
/// between two failing scan points can be missed.
///
/// # Errors
/// As [`ActuatorLoop::point`]; [`M1Error::InvalidParameter`] for a bad range or no frequency
/// below `below_hz`.
pub fn highest_gain(
    lp: &ActuatorLoop,
    sweep: &CsiSweep,
    below_hz: f64,
    max_sensitivity: f64,
    (lo, hi): (f64, f64),
) -> Result<GainLimit, M1Error> {
    if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && hi > lo) {
        return Err(M1Error::InvalidParameter {
            name: "gain range",
            value: lo,
            reason: "must be finite with 0 < lo < hi",
        });
    }
    let search = GainSearch::new(lp, sweep, below_hz, max_sensitivity)?;
    // The servo alone is stable only on a window of factors (a PID on a lightly damped plant
    // is conditionally stable): find the window on a fine grid (cheap), scan the criterion
    // over it, then bisect above the largest passing scan point.
    let Some((lowest_valid, factors)) = search.scan_factors(lo, hi) else {
        return Ok(search.result(lo, None, false, None, "servo unstable over the whole range"));
    };
    let Some((az, why)) = search_factor(&factors, &|a| search.zernike_pass(a))? else {
        return search.none_meets(&factors, "no factor meets the criterion");
    };
    search.check_all_segments(az, why, lowest_valid)
}

/// The band of a [`highest_gain`] search and what it reuses across factors: the Zernike plants
/// and the channel scalars per frequency, the nominal servo's all-segment values, the order in
/// which the Zernike test visits the frequencies.
struct GainSearch<'a> {
    lp: &'a ActuatorLoop,
    base: &'a SegmentModel,
    /// The grid frequencies at or below `below_hz` (Hz).
    band: Vec<f64>,
    /// The nominal servo's all-segment values on the band, from the sweep.
    nominal_all: Vec<f64>,
    /// The Zernike plants of the band, gain-independent, with their channel scalars.
    zplants: Vec<(Kinds, Mat<c64>)>,
    kinds: Vec<Kinds>,
    /// The sweep's all-segment top vectors on the band (each point's Lanczos starts there).
    warm: Vec<Option<&'a [c64]>>,
    /// The largest Zernike degree and its number of basis vectors.
    degree: usize,
    nz: usize,
    /// Band indices from the nominal servo's worst Zernike value down.
    zorder: Vec<usize>,
    max_sensitivity: f64,
    below_hz: f64,
}

/// Indices `0..n` from the largest of `vals` down (frequencies visited from the nominal
/// servo's worst down, so failures show early).
fn worst_first(n: usize, vals: Vec<f64>) -> Vec<usize> {
    let mut o: Vec<usize> = (0..n).collect();
    o.sort_by(|&x, &y| vals[y].total_cmp(&vals[x]));
    o
}

impl<'a> GainSearch<'a> {
    /// The band of `sweep` up to `below_hz` and its Zernike plants (in parallel).
    fn new(
        lp: &'a ActuatorLoop,
        sweep: &'a CsiSweep,
        below_hz: f64,
        max_sensitivity: f64,
    ) -> Result<Self, M1Error> {
        let grid = &sweep.frequencies_hz;
        let in_band: Vec<usize> = (0..grid.len()).filter(|&i| grid[i] <= below_hz).collect();
        let band: Vec<f64> = in_band.iter().map(|&i| grid[i]).collect();
        // The nominal servo's values from the sweep.
        let nominal_all: Vec<f64> = in_band
            .iter()
            .map(|&i| sweep.all_segments.sensitivity_max[i])
            .collect();
        if band.is_empty() {
            return Err(M1Error::InvalidParameter {
                name: "below_hz",
                value: below_hz,
                reason: "no grid frequency at or below it",
            });
        }
        let base = lp.fm.model();
        let degree = lp.zernike.prefix.len().saturating_sub(1);
        let nz = lp.zernike.prefix[degree];
        // The Zernike plants of the band, gain-independent: the sweep's (computed again only
        // for a sweep without them).
        let zplants: Vec<(Kinds, Mat<c64>)> = in_band
            .par_iter()
            .map(|&i| {
                let k = Kinds::new(base, grid[i]);
                match sweep.zernike_plants.get(i) {
                    Some(m) if m.nrows() == nz && m.ncols() == nz => Ok((k, m.clone())),
                    _ => {
                        let lu = modal_factor(&lp.fm, &k);
                        Ok((k, lp.zernike_projected.plant(&k, lu.as_ref())?))
                    }
                }
            })
            .collect::<Result<_, M1Error>>()?;
        let kinds: Vec<Kinds> = zplants.iter().map(|(k, _)| *k).collect();
        let warm = in_band
            .iter()
            .map(|&i| sweep.top_vectors.get(i).and_then(|v| v.as_deref()))
            .collect();
        let zorder = match sweep.zernike.get(degree) {
            Some(c) if scaled_servo(base, 1.0).validate().is_ok() => worst_first(
                band.len(),
                in_band.iter().map(|&i| c.sensitivity_max[i]).collect(),
            ),
            _ => (0..band.len()).collect(),
        };
        Ok(Self {
            lp,
            base,
            band,
            nominal_all,
            zplants,
            kinds,
            warm,
            degree,
            nz,
            zorder,
            max_sensitivity,
            below_hz,
        })
    }

    /// Whether the servo scaled by `a` is valid (its rigid-base loop stable).
    fn valid_at(&self, a: f64) -> bool {
        scaled_servo(self.base, a).validate().is_ok()
    }

    /// $\sigma_{max}(S)$ in the Zernike basis of the largest degree at band point `i`, servo
    /// scaled by `a`.
    fn zval(&self, i: usize, a: f64) -> Result<f64, M1Error> {
        let (k, m) = &self.zplants[i];
        sensitivity_max(m, k.k_s * a, self.nz)
    }

    /// The all-segment $\sigma_{max}(S)$ at band point `i`, servo scaled by `a`, its Lanczos
    /// started from the sweep's top vector there.
    fn all_at(&self, i: usize, a: f64) -> Result<f64, M1Error> {
        self.lp
            .all_from_kinds_warm(&self.kinds[i], a, self.warm[i])
            .map(|(v, _)| v)
    }

    /// Whether any band point of `o` (visited in parallel) fails the criterion under `val`.
    fn fails_any(
        &self,
        o: &[usize],
        val: &(dyn Fn(usize) -> Result<f64, M1Error> + Sync),
    ) -> Result<bool, M1Error> {
        match o
            .par_iter()
            .map(|&i| val(i).map(|s| s >= self.max_sensitivity))
            .find_any(|r| !matches!(r, Ok(false)))
        {
            None => Ok(false),
            Some(Ok(_)) => Ok(true),
            Some(Err(e)) => Err(e),
        }
    }

    /// The Zernike test of factor `a` (`None` for an invalid servo).
    fn zernike_pass(&self, a: f64) -> Result<Option<bool>, M1Error> {
        if !self.valid_at(a) {
            return Ok(None);
        }
        Ok(Some(!self.fails_any(&self.zorder, &|i| self.zval(i, a))?))
    }

    /// All segments: (peak, where) over the band for factor `a`.
    fn all_peak(&self, a: f64) -> Result<(f64, f64), M1Error> {
        let v: Vec<f64> = if a == 1.0 {
            self.nominal_all.clone()
        } else {
            (0..self.band.len())
                .into_par_iter()
                .map(|i| self.all_at(i, a))
                .collect::<Result<_, _>>()?
        };
        let i = argmax(&v);
        Ok((v[i], self.band[i]))
    }

    /// The all-segment test of factor `a`, visiting the band in the order `aorder`.
    fn all_pass(&self, aorder: &[usize], a: f64) -> Result<Option<bool>, M1Error> {
        if !self.valid_at(a) {
            return Ok(None);
        }
        Ok(Some(!self.fails_any(aorder, &|i| self.all_at(i, a))?))
    }

    /// The report for factor `a` with its all-segment (peak, where) `e`.
    fn result(
        &self,
        a: f64,
        e: Option<(f64, f64)>,
        meets: bool,
        za: Option<f64>,
        why: &str,
    ) -> GainLimit {
        let base = self.base;
        let m = scaled_servo(base, a);
        let v = &m.actuator.servo;
        let (peak, at) = e.unwrap_or((f64::NAN, f64::NAN));
        GainLimit {
            gain_factor: a,
            kp: v.kp,
            ki: v.ki,
            kd: v.kd,
            bandwidth_hz: crossover(base, a),
            nominal_bandwidth_hz: crossover(base, 1.0),
            peak_sensitivity: peak,
            peak_frequency_hz: at,
            max_sensitivity: self.max_sensitivity,
            below_hz: self.below_hz,
            meets_criterion: meets,
            zernike_gain_factor: za,
            zernike_degree: self.degree as u32,
            lowest_peak_factor: None,
            lowest_peak_sensitivity: None,
            limited_by: why.into(),
        }
    }

    /// The factors to scan in `[lo, hi]`: the window of valid servos on 400 log-spaced
    /// factors, [`SCAN`] log-spaced factors over it, plus 1 inside it and the first unstable
    /// factor above it; with the lowest valid factor. `None` if no factor is valid.
    fn scan_factors(&self, lo: f64, hi: f64) -> Option<(f64, Vec<f64>)> {
        let fine = log_grid(lo, hi, 400);
        let valid: Vec<bool> = fine.iter().map(|&a| self.valid_at(a)).collect();
        let (Some(first), Some(last)) = (
            valid.iter().position(|&v| v),
            valid.iter().rposition(|&v| v),
        ) else {
            return None;
        };
        let mut factors = log_grid(fine[first], fine[last], SCAN);
        if fine[first] < 1.0 && fine[last] > 1.0 {
            factors.push(1.0);
            factors.sort_by(f64::total_cmp);
        }
        if last + 1 < fine.len() {
            // The first unstable factor above the window.
            factors.push(fine[last + 1]);
        }
        Some((fine[first], factors))
    }

    /// The report when no scanned factor meets the criterion: the nominal factor (or the
    /// lowest scanned), with the valid scanned factor of the lowest Zernike peak.
    fn none_meets(&self, factors: &[f64], why: &str) -> Result<GainLimit, M1Error> {
        let a = if self.valid_at(1.0) { 1.0 } else { factors[0] };
        let mut r = self.result(a, Some(self.all_peak(a)?), false, None, why);
        // The valid scanned factor with the lowest Zernike peak, checked with all segments.
        let mut best: Option<(f64, f64)> = None;
        for &f in factors.iter().filter(|&&f| self.valid_at(f)) {
            let v: Vec<f64> = (0..self.band.len())
                .into_par_iter()
                .map(|i| self.zval(i, f))
                .collect::<Result<_, _>>()?;
            let peak = v.iter().copied().fold(0.0f64, f64::max);
            if best.is_none_or(|(_, p)| peak < p) {
                best = Some((f, peak));
            }
        }
        if let Some((f, _)) = best {
            r.lowest_peak_factor = Some(f);
            r.lowest_peak_sensitivity = Some(self.all_peak(f)?.0);
        }
        Ok(r)
    }

    /// The all-segment check of the Zernike factor `az` (found for the reason `why`), and the
    /// descent if it fails: 5 % steps down (not below `lowest_valid`) until a factor passes,
    /// then bisection to 0.5 %.
    fn check_all_segments(
        &self,
        az: f64,
        why: &str,
        lowest_valid: f64,
    ) -> Result<GainLimit, M1Error> {
        let top = self.all_peak(az)?;
        if top.0 < self.max_sensitivity {
            return Ok(self.result(az, Some(top), true, Some(az), why));
        }
        let aorder = worst_first(
            self.band.len(),
            (0..self.band.len())
                .into_par_iter()
                .map(|i| self.all_at(i, az))
                .collect::<Result<_, _>>()?,
        );
        let (mut good, mut bad) = (None, az);
        let mut a = az;
        while a * 0.95 >= lowest_valid {
            a *= 0.95;
            match self.all_pass(&aorder, a)? {
                Some(true) => {
                    good = Some(a);
                    break;
                }
                Some(false) => bad = a,
                None => break,
            }
        }
        let Some(mut g) = good else {
            return Ok(self.result(
                az,
                Some(top),
                false,
                Some(az),
                "no factor meets the criterion with all segments",
            ));
        };
        while bad / g > 1.005 {
            let mid = (g * bad).sqrt();
            if self.all_pass(&aorder, mid)? == Some(true) {
                g = mid;
            } else {
                bad = mid;
            }
        }
        Ok(self.result(
            g,
            Some(self.all_peak(g)?),
            true,
            Some(az),
            "all-segment check",
        ))
    }
}
