//! The segments and the structure as two co-simulation components (the "split" system),
//! against the coupled solver: how large a communication step the split exchange tolerates.
//!
//! # Why it fails
//!
//! Exchanged every communication step `h`, the actuator forces reach the structure and the cell
//! displacement reaches the segments one step late on at least one side (Gauss-Seidel: the
//! segments see the cell displacement of the previous step; Jacobi: both sides do). The
//! actuators tie each segment stiffly to the cell (a servo-stiffened voice coil up to its
//! bandwidth, a piezo stack outright), so the loop "cell moves -> actuator force -> cell
//! moves" has a high gain at the cell modes, and a delay of `h` in it adds a phase lag of
//! `2 pi f h` at frequency `f`: above some `h` the lag turns that stiff loop unstable. The
//! coupled solver ([`crate::plant::mirror::CoupledMirror`]) has no such delay: it solves the two
//! together at every servo sample, so it is the reference here.
//!
//! # The experiment
//!
//! Both systems start at rest and get the same pier displacement tone `p(t) = a sin(2 pi f t)`
//! (held over each step, as the FMUs see it), no command and no wind. The split system is
//! [`SegmentArray`] + [`ModalSolver`] with the same retained modes, damping and no static
//! correction, exchanging values in the chosen order. Reported per run: whether it stayed
//! bounded, and the rms over the second half of the run of the difference of the mirror
//! displacements at every actuator, relative to the coupled solver's rms.

use serde::Serialize;

use crate::M1Error;
use crate::plant::mirror::CoupledMirror;
use crate::plant::segment::{SegmentArray, SegmentModel};
use crate::plant::structure::{Flexibility, ModalModel, ModalSolver};

/// Order of the exchange between the two components.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Exchange {
    /// The segments step first with the cell displacement of the previous step, then the
    /// structure steps with the forces they just produced.
    GaussSeidel,
    /// Both step on the values of the previous step.
    Jacobi,
}

/// The pier tone and the run length of a comparison.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Excitation {
    /// Tone frequency (Hz).
    pub frequency: f64,
    /// Tone amplitude (m).
    pub amplitude: f64,
    /// Simulated time (s).
    pub duration: f64,
}

impl Default for Excitation {
    /// 5 Hz, 1 um, 1 s.
    fn default() -> Self {
        Self {
            frequency: 5.0,
            amplitude: 1e-6,
            duration: 1.0,
        }
    }
}

/// The mirror both systems model: `n_segments` identical segments of `model` on the `n_modes`
/// lowest modes of `cell` (damping `damping_ratio` unless the cell carries its own).
#[derive(Debug, Clone, Copy)]
pub struct Mirror<'a> {
    /// Number of segments.
    pub n_segments: usize,
    /// The segment and its actuators.
    pub model: &'a SegmentModel,
    /// The cell's modal model.
    pub cell: &'a ModalModel,
    /// Retained modes.
    pub n_modes: usize,
    /// Modal damping ratio.
    pub damping_ratio: f64,
}

/// One split run against the coupled solver.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SplitRun {
    /// Communication step (s).
    pub step: f64,
    /// Exchange order.
    pub order: Exchange,
    /// Whether the split run stayed bounded (finite and below 1e3 times the coupled run's
    /// largest displacement) to the end.
    pub stable: bool,
    /// Simulated time reached (s): the duration, or when the run was stopped as unbounded.
    pub reached: f64,
    /// rms difference of the mirror displacements over the second half, relative to the coupled
    /// solver's rms (infinite when unbounded).
    pub relative_error: f64,
}

/// Runs the split system at `step` in `order` and the coupled solver (at the same step) on the
/// same pier tone, both modelling `mirror`.
///
/// # Errors
/// Invalid models (as [`CoupledMirror::new`]), a step that is not a positive multiple of the
/// servo period, a non-positive or non-finite duration, frequency or amplitude.
pub fn split_vs_coupled(
    mirror: &Mirror<'_>,
    step: f64,
    order: Exchange,
    excitation: &Excitation,
) -> Result<SplitRun, M1Error> {
    let Mirror {
        n_segments,
        model,
        cell,
        n_modes,
        damping_ratio,
    } = *mirror;
    for (name, value) in [
        ("duration", excitation.duration),
        ("frequency", excitation.frequency),
        ("amplitude", excitation.amplitude),
    ] {
        if !(value.is_finite() && value > 0.0) {
            return Err(M1Error::InvalidParameter {
                name,
                value,
                reason: "must be finite and > 0",
            });
        }
    }
    let mut coupled = CoupledMirror::new(
        n_segments,
        model.clone(),
        cell.clone(),
        n_modes,
        damping_ratio,
        1,
    )?;
    coupled.ticks_in(step)?;
    let mut rigid = cell.clone();
    rigid.flexibility = Flexibility::None;
    let mut structure = ModalSolver::new(rigid, n_modes, damping_ratio)?;
    let mut segments = SegmentArray::new(n_segments, model.clone())?;
    let na = 3 * n_segments;
    let zeros = vec![0.0; na];
    let (mut z_cell, mut f_cell) = (vec![0.0; na], vec![0.0; na]);
    let (mut z_split, mut z_ref) = (vec![0.0; na], vec![0.0; na]);
    let n_steps = (excitation.duration / step).round().max(1.0) as usize;
    let w = std::f64::consts::TAU * excitation.frequency;
    let (mut diff2, mut ref2, mut ref_max) = (0.0, 0.0, 0.0f64);
    for k in 0..n_steps {
        let t = k as f64 * step;
        let p = excitation.amplitude * (w * t).sin();
        coupled.advance(step, &zeros, &zeros, p)?;
        coupled.mirror(&mut z_ref);
        match order {
            Exchange::GaussSeidel => {
                segments.advance(step, &zeros, &z_cell, &zeros)?;
                segments.outputs(&z_cell, &mut z_split, &mut f_cell)?;
                structure.step(step, &f_cell, p)?;
                z_cell.copy_from_slice(structure.output());
            }
            Exchange::Jacobi => {
                let f_old = f_cell.clone();
                let z_old = z_cell.clone();
                segments.advance(step, &zeros, &z_old, &zeros)?;
                structure.step(step, &f_old, p)?;
                z_cell.copy_from_slice(structure.output());
                segments.outputs(&z_old, &mut z_split, &mut f_cell)?;
            }
        }
        ref_max = z_ref.iter().fold(ref_max, |m, v| m.max(v.abs()));
        let bounded = z_split
            .iter()
            .all(|v| v.is_finite() && v.abs() <= 1e3 * ref_max.max(excitation.amplitude));
        if !bounded {
            return Ok(SplitRun {
                step,
                order,
                stable: false,
                reached: t + step,
                relative_error: f64::INFINITY,
            });
        }
        if 2 * k >= n_steps {
            for (a, b) in z_split.iter().zip(&z_ref) {
                diff2 += (a - b) * (a - b);
                ref2 += b * b;
            }
        }
    }
    Ok(SplitRun {
        step,
        order,
        stable: true,
        reached: n_steps as f64 * step,
        relative_error: if ref2 > 0.0 {
            (diff2 / ref2).sqrt()
        } else {
            f64::NAN
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::layout::Layout;
    use crate::plant::structure::{CellModel, CellParams};

    fn keck_cell() -> ModalModel {
        CellModel::new(&Layout::keck(), &CellParams::soft_cell())
            .and_then(|c| c.modes())
            .unwrap_or_else(|e| panic!("{e}"))
    }

    /// Measured on Keck with 30 modes (the same with all 109): the split voice-coil system stays
    /// bounded at the servo period, where Gauss-Seidel holds each actuator force over the
    /// servo period exactly as the coupled solver does (0.1 % apart) and Jacobi's lagged cell
    /// displacement shows (2.1 %); it diverges at two servo periods in either order. The split
    /// piezo system (4.3 N/um stacks) stays bounded at one and two servo periods but is far off:
    /// 24 % (Gauss-Seidel) and 21 % (Jacobi) after 1 s at the servo period, 62 % and 53 % at two,
    /// a transient of its lightly damped stack modes that takes tens of seconds to fade (3 %
    /// after 30 s).
    #[test]
    fn the_split_exchange_needs_the_servo_period_or_diverges() {
        let cell = keck_cell();
        let n = Layout::keck().n_segments();
        let ex = Excitation::default();
        let run = |model: &SegmentModel, step: f64, order: Exchange| {
            let m = Mirror {
                n_segments: n,
                model,
                cell: &cell,
                n_modes: 30,
                damping_ratio: 0.02,
            };
            split_vs_coupled(&m, step, order, &ex).unwrap_or_else(|e| panic!("{e}"))
        };
        let vc = SegmentModel::voice_coil();
        for order in [Exchange::GaussSeidel, Exchange::Jacobi] {
            let fine = run(&vc, 2e-4, order);
            assert!(fine.stable && fine.reached > 0.999, "{fine:?}");
            let e = fine.relative_error;
            match order {
                Exchange::GaussSeidel => assert!(e < 5e-3, "{fine:?}"),
                // Close, but the lagged cell displacement shows.
                Exchange::Jacobi => assert!(e > 5e-3 && e < 0.03, "{fine:?}"),
            }
            let coarse = run(&vc, 4e-4, order);
            assert!(!coarse.stable && coarse.reached < 0.9, "{coarse:?}");
            let piezo = SegmentModel::piezo();
            let fine = run(&piezo, 2e-4, order);
            assert!(fine.stable && fine.relative_error > 0.15, "{fine:?}");
            let coarse = run(&piezo, 4e-4, order);
            assert!(
                coarse.stable && coarse.relative_error > 2.0 * fine.relative_error,
                "{coarse:?}"
            );
        }
    }

    #[test]
    fn bad_steps_and_excitations_are_errors() {
        let cell = keck_cell();
        let n = Layout::keck().n_segments();
        let vc = SegmentModel::voice_coil();
        let m = Mirror {
            n_segments: n,
            model: &vc,
            cell: &cell,
            n_modes: 10,
            damping_ratio: 0.02,
        };
        let e = split_vs_coupled(&m, 3e-4, Exchange::Jacobi, &Excitation::default()).unwrap_err();
        assert!(e.to_string().contains("communicationStepSize"), "{e}");
        let bad = Excitation {
            frequency: f64::NAN,
            ..Excitation::default()
        };
        let e = split_vs_coupled(&m, 2e-4, Exchange::Jacobi, &bad).unwrap_err();
        assert!(e.to_string().contains("frequency"), "{e}");
    }
}
