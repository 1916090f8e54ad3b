//! Figures of a segment's command response (`m1cs demo`): rise time, overshoot and settling
//! time of a sampled step response, and the -3 dB bandwidth of a segment model's command
//! response.

use crate::plant::segment::{Channel, SegmentModel};

/// A step response is settled once it stays within this fraction of the step (2 %).
pub const SETTLING_BAND: f64 = 0.02;

/// The figures of a step response.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepFigures {
    /// 10-90 % rise time (s): between the first samples at or above 10 % and 90 % of the step
    /// (NaN if the response never reaches one of them).
    pub rise_time: f64,
    /// Overshoot: the peak over the step, less 1 (fraction of the step; -1 if the response
    /// never rises above 0).
    pub overshoot: f64,
    /// Settling time (s): the end of the last sample interval that starts outside
    /// [`SETTLING_BAND`] of the step (0 if every sample is within it).
    pub settling_time: f64,
}

impl StepFigures {
    /// The figures of the response `z` (sample `k` at time `k h`, from `z[0]` at 0) to a step of
    /// `step` (same unit as `z`, > 0).
    pub fn of(z: &[f64], h: f64, step: f64) -> Self {
        let t_at = |k: usize| k as f64 * h;
        let first = |th: f64| {
            z.iter()
                .position(|&x| x >= th * step)
                .map_or(f64::NAN, t_at)
        };
        let peak = z.iter().fold(0.0f64, |m, &x| m.max(x));
        let settling_time = z
            .iter()
            .rposition(|&x| (x / step - 1.0).abs() > SETTLING_BAND)
            .map_or(0.0, |k| t_at(k + 1));
        Self {
            rise_time: first(0.9) - first(0.1),
            overshoot: peak / step - 1.0,
            settling_time,
        }
    }
}

/// The -3 dB bandwidth (Hz) of the command response of channel `ch` of `model`: the first
/// frequency of the geometric scan from 0.1 Hz by 1 % steps where the mirror's response to a
/// command falls below `1 / sqrt(2)`; NaN if it stays above up to 2 kHz.
pub fn command_bandwidth(model: &SegmentModel, ch: Channel) -> f64 {
    let mut f = 0.1;
    while f < 2000.0 {
        if model.mirror_response(ch, f)[0].norm() < std::f64::consts::FRAC_1_SQRT_2 {
            return f;
        }
        f *= 1.01;
    }
    f64::NAN
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn figures_of_a_first_order_step() {
        // 1 - exp(-t / tau), tau = 10 ms, sampled at 1 ms: rise 2.2 tau, settling 3.9 tau.
        let (h, tau) = (1e-3, 1e-2);
        let z: Vec<f64> = (0..200)
            .map(|k| 2.0 * (1.0 - (-(k as f64) * h / tau).exp()))
            .collect();
        let s = StepFigures::of(&z, h, 2.0);
        assert!((s.rise_time - 0.022).abs() < 1.5e-3, "{s:?}");
        assert!(s.overshoot < 0.0 && s.overshoot > -0.01, "{s:?}");
        assert!((s.settling_time - 0.040).abs() < 1.5e-3, "{s:?}");
        let never = StepFigures::of(&[0.0; 5], h, 1.0);
        assert!(never.rise_time.is_nan());
        assert_eq!(never.settling_time, 5e-3);
    }

    #[test]
    fn bandwidths_of_the_variants_are_finite() {
        for model in [SegmentModel::voice_coil(), SegmentModel::piezo()] {
            for ch in Channel::ALL {
                let b = command_bandwidth(&model, ch);
                assert!(b.is_finite() && b > 0.1, "{ch:?}: {b}");
            }
        }
    }
}
