//! The observing schedule of the overall simulation: a star's zenith-angle track each night and
//! the temperature through the nights.
//!
//! Each night `d` follows one star of declination `delta_d`, drawn (seeded) uniformly in
//! `[min_declination, max_declination]`, from hour angle `-night/2` to `+night/2`; the zenith
//! angle is `cos(zeta) = sin(phi) sin(delta) + cos(phi) cos(delta) cos(H)` at latitude `phi`.
//! Instants with `zeta > max_zenith` are skipped (the telescope does not observe there). The
//! temperature starts each night at `T_d + drop / 2` and falls linearly by `drop` over the night;
//! `T_d` is a seeded random walk, `N(0, day_rms)` per day, held within `+-limit`.

use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal, Uniform};
use serde::{Deserialize, Serialize};

use crate::M1Error;

/// Parameters of the schedule.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ScheduleParams {
    /// Number of nights (default 30: one month).
    pub days: usize,
    /// Hours observed per night (default 10).
    pub night_hours: f64,
    /// Quasi-static step (minutes, default 10).
    pub step_minutes: f64,
    /// Site latitude (deg, default 19.83: Maunakea).
    pub latitude_deg: f64,
    /// Declination range of the nightly star (deg, default -20 and 50).
    pub min_declination_deg: f64,
    /// Upper end of the declination range (deg).
    pub max_declination_deg: f64,
    /// Largest zenith angle observed (deg, default 65, Table 1's largest).
    pub max_zenith_deg: f64,
    /// Temperature fall over a night (degC, default 2, *assumed*).
    pub nightly_drop: f64,
    /// Day-to-day rms change of the mean night temperature (degC, default 1, *assumed*).
    pub day_rms: f64,
    /// Limit of the mean night temperature about the baseline (degC, default 5: Table 1).
    pub limit: f64,
    /// Seed (default 1).
    pub seed: u64,
}

impl Default for ScheduleParams {
    fn default() -> Self {
        Self {
            days: 30,
            night_hours: 10.0,
            step_minutes: 10.0,
            latitude_deg: 19.83,
            min_declination_deg: -20.0,
            max_declination_deg: 50.0,
            max_zenith_deg: 65.0,
            nightly_drop: 2.0,
            day_rms: 1.0,
            limit: 5.0,
            seed: 1,
        }
    }
}

/// One quasi-static instant.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Instant {
    /// Night index.
    pub night: usize,
    /// Time since the start (days).
    pub time_days: f64,
    /// Zenith angle (deg).
    pub zenith_deg: f64,
    /// Temperature relative to the baseline (degC).
    pub temperature: f64,
    /// First instant of its night.
    pub first_of_night: bool,
}

impl ScheduleParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] naming the field out of range.
    pub fn check(&self) -> Result<(), M1Error> {
        let bad = |name, value, reason| {
            Err(M1Error::InvalidParameter {
                name,
                value,
                reason,
            })
        };
        if self.days == 0 {
            return bad("days", 0.0, "must be at least 1");
        }
        if !(self.night_hours > 0.0 && self.night_hours <= 24.0) {
            return bad("night_hours", self.night_hours, "must be in (0, 24]");
        }
        if !(self.step_minutes > 0.0 && self.step_minutes <= 60.0 * self.night_hours) {
            return bad(
                "step_minutes",
                self.step_minutes,
                "must be > 0 and at most a night",
            );
        }
        if self.latitude_deg.is_nan() || self.latitude_deg.abs() >= 90.0 {
            return bad("latitude_deg", self.latitude_deg, "must be in (-90, 90)");
        }
        if !(self.min_declination_deg <= self.max_declination_deg
            && self.min_declination_deg.abs() <= 90.0
            && self.max_declination_deg.abs() <= 90.0)
        {
            return bad(
                "min_declination_deg",
                self.min_declination_deg,
                "must be <= max_declination_deg, both in [-90, 90]",
            );
        }
        if !(self.max_zenith_deg > 0.0 && self.max_zenith_deg <= 90.0) {
            return bad("max_zenith_deg", self.max_zenith_deg, "must be in (0, 90]");
        }
        for (name, v) in [
            ("nightly_drop", self.nightly_drop),
            ("day_rms", self.day_rms),
            ("limit", self.limit),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(name, v, "must be finite and >= 0");
            }
        }
        Ok(())
    }

    /// The instants of the schedule, in time order.
    ///
    /// # Errors
    /// As [`ScheduleParams::check`].
    pub fn instants(&self) -> Result<Vec<Instant>, M1Error> {
        self.check()?;
        let mut rng = StdRng::seed_from_u64(self.seed);
        let dec = Uniform::new_inclusive(self.min_declination_deg, self.max_declination_deg)
            .map_err(|e| M1Error::InvalidInput(format!("declination range: {e}")))?;
        let phi = self.latitude_deg.to_radians();
        let steps = (self.night_hours * 60.0 / self.step_minutes).floor() as usize + 1;
        let mut mean = 0.0_f64;
        let mut out = Vec::new();
        for night in 0..self.days {
            let delta = dec.sample(&mut rng).to_radians();
            let x: f64 = StandardNormal.sample(&mut rng);
            if night > 0 {
                mean = (mean + self.day_rms * x).clamp(-self.limit, self.limit);
            }
            let mut first = true;
            for k in 0..steps {
                let hours = k as f64 * self.step_minutes / 60.0;
                let h = (hours - self.night_hours / 2.0) * 15f64.to_radians();
                let cz = phi.sin() * delta.sin() + phi.cos() * delta.cos() * h.cos();
                let zenith = cz.clamp(-1.0, 1.0).acos().to_degrees();
                if zenith > self.max_zenith_deg {
                    continue;
                }
                let frac = hours / self.night_hours;
                out.push(Instant {
                    night,
                    // Nights start at 19 h local time.
                    time_days: night as f64 + (19.0 + hours) / 24.0,
                    zenith_deg: zenith,
                    temperature: mean + self.nightly_drop * (0.5 - frac),
                    first_of_night: first,
                });
                first = false;
            }
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_star_on_the_meridian_passes_at_latitude_minus_declination() {
        let p = ScheduleParams {
            days: 3,
            min_declination_deg: 10.0,
            max_declination_deg: 10.0,
            step_minutes: 30.0,
            max_zenith_deg: 90.0,
            ..ScheduleParams::default()
        };
        let s = p.instants().unwrap();
        // 10 h at 30 min: 21 instants a night; the middle one is on the meridian.
        assert_eq!(s.len(), 3 * 21);
        let mid = &s[10];
        assert!((mid.zenith_deg - (19.83 - 10.0)).abs() < 1e-9);
        assert!(s[0].first_of_night && !s[1].first_of_night && s[21].first_of_night);
        // Symmetric about the meridian; the temperature falls by the nightly drop.
        assert!((s[0].zenith_deg - s[20].zenith_deg).abs() < 1e-9);
        assert!((s[0].temperature - s[20].temperature - 2.0).abs() < 1e-12);
        let lim = ScheduleParams {
            max_zenith_deg: 30.0,
            ..p
        };
        assert!(lim.instants().unwrap().iter().all(|i| i.zenith_deg <= 30.0));
        assert!(ScheduleParams { days: 0, ..p }.instants().is_err());
    }
}
