//! Tests of the global loop's CSI: the rigid base against the integrator, the Zernike bases'
//! convergence, the peak labels, the default band, the checked criteria.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use super::zernike_loop::integrator;
use super::*;
use crate::aperture::geometry::{Geometry, GeometryParams};
use crate::aperture::layout::Layout;
use crate::control::controller::ControllerParams;
use crate::plant::monolithic::{FrequencyModel, hold};
use crate::plant::segment::SegmentModel;
use crate::plant::structure::{CellModel, CellParams};

fn keck(modes: usize, aliases: usize) -> GlobalCsi {
    let layout = Layout::keck();
    let n = layout.n_segments();
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
    let fm = if modes == 0 {
        FrequencyModel::rigid(n, SegmentModel::voice_coil()).unwrap()
    } else {
        let cell = CellModel::new(&layout, &CellParams::soft_cell())
            .unwrap()
            .modes()
            .unwrap();
        FrequencyModel::new(n, SegmentModel::voice_coil(), cell, modes, 0.02).unwrap()
    };
    GlobalCsi::new(
        fm,
        &layout,
        &geometry,
        ControllerParams::default(),
        6,
        aliases,
    )
    .unwrap()
}

/// On a rigid base every channel outside the controller's special vectors is the same
/// scalar loop $c\,g\,\tilde H_c t_{0,k}$ per kind, and the special ones have lower gains,
/// so the all-segment principal loop gain is exactly the larger kind's; a Zernike basis
/// mixes the kinds within its vectors and lies between the two.
#[test]
fn rigid_base_loop_is_the_integrator() {
    let g = keck(0, 0);
    let gains = ControllerParams::default().gains().unwrap();
    for f in [0.05, 0.3, 1.0, 4.0] {
        let (p, _) = g.point(f).unwrap();
        let ch = g.model().channels(f);
        let scalar = |k: usize| {
            (integrator(f, 20.0) * gains.rest * hold(f, 1.0 / 20.0) * ch[k].mirror[0]).norm()
        };
        let (hi, lo) = (scalar(0).max(scalar(1)), scalar(0).min(scalar(1)));
        assert!(
            (p.loop_gain - hi).abs() <= 1e-9 * hi,
            "{f} Hz: {} vs {hi}",
            p.loop_gain
        );
        let last = *p.zernike_loop_gain.last().unwrap();
        assert!(
            last <= hi * (1.0 + 1e-9) && last >= lo * (1.0 - 1e-9),
            "{f} Hz: {last} not in [{lo}, {hi}]"
        );
    }
}

/// The Zernike basis of the largest degree against all segments (Keck, 30 modes): the
/// loop gain's peak at high frequency converges (within 10 %), and the curves agree at low
/// frequency where every basis is the integrator.
#[test]
fn zernike_global_loop_converges_to_all_segments() {
    let g = keck(30, 2);
    let grid = crate::analysis::csi::log_grid(0.05, 9.9, 40);
    let sw = global_sweep(&g, &grid, &GlobalCriteria::default()).unwrap();
    let all = sw.all_segments.high_frequency_loop_gain;
    let last = sw.zernike.last().unwrap().high_frequency_loop_gain;
    assert!(all > 0.0 && last > 0.0, "{all} {last}");
    assert!(
        (last - all).abs() < 0.1 * all,
        "Zernike {last} vs all {all}"
    );
    let (z0, a0) = (
        sw.zernike.last().unwrap().loop_gain_max[0],
        sw.all_segments.loop_gain_max[0],
    );
    assert!((z0 - a0).abs() < 1e-2 * a0, "{z0} vs {a0}");
    assert!(sw.highest_bandwidth.bandwidth_hz > 0.0);
}

/// At low frequency the loop is large in every direction but the controller's null space
/// (global piston, tip and tilt, at zero gain), where the sensitivity stays near 1: its
/// peak direction is Z1, Z2 or Z3. The loop gain's top direction is elsewhere.
#[test]
fn low_frequency_sensitivity_is_labelled_by_the_null_space() {
    let g = keck(0, 0);
    for d in [2, 4, 6] {
        let (label, noll) = g.peak_label(0.01, d, GlobalQuantity::Sensitivity).unwrap();
        assert!(noll <= 3, "degree {d}: {label} (Z{noll})");
        assert!(label == "P" || label == "TT", "{label}");
        let (_, nl) = g.peak_label(0.01, d, GlobalQuantity::LoopGain).unwrap();
        assert!(nl > 3, "degree {d}: loop gain's direction Z{nl}");
    }
    let e = g
        .peak_label(0.01, 7, GlobalQuantity::Sensitivity)
        .unwrap_err();
    assert!(e.to_string().contains("degree"), "{e}");
    let grid = crate::analysis::csi::log_grid(0.005, 9.9, 30);
    let sw = global_sweep(&g, &grid, &GlobalCriteria::default()).unwrap();
    for c in sw.zernike.iter().chain(std::iter::once(&sw.all_segments)) {
        assert!(c.peak_sensitivity_label.is_some() && c.high_frequency_loop_gain_noll.is_some());
    }
    for p in &sw.all_segment_peaks {
        let from = match p.quantity {
            GlobalQuantity::Sensitivity => SENSITIVITY_LABEL_FROM,
            GlobalQuantity::LoopGain => 0.5 * sw.loop_gain_limit,
        };
        assert!(p.value > from, "{p:?}");
    }
}

/// The loop-gain band starts at 8 Hz by default: on a rigid base the bare 1.5 Hz
/// integrator (the default bandwidth of radial degrees >= 5, with the hold and the servo)
/// is above the limit of 1/4 at 5 Hz (0.273), and under it from 8 Hz (0.210) to the
/// Nyquist frequency (0.203), so the criterion measures the structure. (The segment as
/// first built, setpoint weight 0.4: 0.245 and 0.166.)
#[test]
fn the_default_band_starts_above_the_bare_integrator() {
    let c = GlobalCriteria::default();
    assert_eq!(c.band_start_hz, DEFAULT_BAND_START_HZ);
    assert_eq!(c.band_start_hz, 8.0);
    let limit = c.max_loop_gain / c.allowance;
    let g = keck(0, 0);
    let at = |f: f64| g.point(f).unwrap().0.loop_gain;
    assert!(at(5.0) > limit, "{}", at(5.0));
    for f in [8.0, 8.5, 9.0, 9.5, 9.99] {
        assert!(at(f) < 0.9 * limit, "{f} Hz: {}", at(f));
    }
    let sw = global_sweep(&g, &crate::analysis::csi::log_grid(0.05, 9.99, 40), &c).unwrap();
    assert!(
        sw.meets_loop_gain,
        "{}",
        sw.all_segments.high_frequency_loop_gain
    );
}

/// The criteria are checked.
#[test]
fn bad_criteria_are_named() {
    let g = keck(0, 0);
    let bad = GlobalCriteria {
        allowance: 0.0,
        ..GlobalCriteria::default()
    };
    let e = global_sweep(&g, &[1.0], &bad).unwrap_err();
    assert!(e.to_string().contains("allowance"), "{e}");
}

/// The extreme singular values by Lanczos ([`crate::linalg::extreme`]) against faer's full
/// singular values on the TMT global loop of `m1cs csi`'s defaults (100 modes: W of
/// dimension 230; 3 images each side), from the integrator-dominated low frequencies to the
/// Nyquist frequency: the loop gain's largest and the return difference's smallest.
#[test]
fn tmt_global_loop_extremes_match_the_full_singular_values() {
    use crate::linalg::extreme;
    let layout = Layout::tmt();
    let n = layout.n_segments();
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
    let cell = CellModel::new(&layout, &CellParams::default())
        .unwrap()
        .modes()
        .unwrap();
    let fm = FrequencyModel::new(n, SegmentModel::voice_coil(), cell, 100, 0.02).unwrap();
    let controls = crate::control::controller::ControlModes::new(geometry).unwrap();
    let params = ControllerParams::default();
    let gl = crate::plant::monolithic::GlobalLoop::new(&fm, &controls, &params).unwrap();
    // Values not bit for bit faer's come from Lanczos (its fallback returns faer's).
    let (mut by_lanczos, mut values) = (0, 0);
    for f in [0.02, 0.1, 0.5, 1.3, 3.0, 6.0, 8.9, 9.6, 12.0, 17.5, 9.99] {
        let (l, _) = gl.loop_matrix(&fm, f, 3);
        assert!(l.nrows() >= extreme::LANCZOS_FROM, "{}", l.nrows());
        let sl = l.singular_values().unwrap();
        let lmax = sl.iter().copied().fold(0.0f64, f64::max);
        let got = extreme::largest_singular_value(l.as_ref()).unwrap();
        by_lanczos += usize::from(got != lmax);
        assert!(
            (got - lmax).abs() <= 1e-9 * lmax,
            "{f} Hz: sigma_max(L) {got} vs {lmax}"
        );
        let s = faer::Mat::<faer::c64>::identity(l.nrows(), l.nrows()) + &l;
        let ss = s.singular_values().unwrap();
        let smin = ss.iter().copied().fold(f64::INFINITY, f64::min);
        let got = extreme::smallest_singular_value(s.as_ref()).unwrap();
        by_lanczos += usize::from(got != smin);
        values += 2;
        assert!(
            (got - smin).abs() <= 1e-9 * smin,
            "{f} Hz: sigma_min(I + L) {got} vs {smin}"
        );
    }
    assert!(
        2 * by_lanczos > values,
        "{by_lanczos} of {values} by Lanczos"
    );
}
