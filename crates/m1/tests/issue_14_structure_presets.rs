//! Issue 14: the structure presets. `tmt` (the default) is a TMT-representative cell on which
//! the segment supports, not the cell's modes, limit the loops; `soft-cell` keeps the first
//! built-in cell, whose figures are its regression. Run in release (`cargo test --release -p m1
//! --test issue_14_structure_presets`): each case is a TMT eigensolve (1477 degrees of freedom)
//! and a servo-loop sweep with all 492 segments.
#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use m1::analysis::csi::{ActuatorLoop, log_grid};
use m1::analysis::global_csi::GlobalCsi;
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::ControllerParams;
use m1::plant::monolithic::FrequencyModel;
use m1::plant::segment::SegmentModel;
use m1::plant::structure::{
    CellModel, CellParams, DEFAULT_STRUCTURE, ModalModel, StructurePreset, StructureSource,
};

fn modes(layout: &Layout, p: &CellParams) -> ModalModel {
    CellModel::new(layout, p).unwrap().modes().unwrap()
}

/// How much of mode `j`'s pattern survives a 60-degree rotation of TMT (segment `i` and
/// segment `i + N/6` are the same place in neighbouring sectors): 1 for an axisymmetric mode,
/// cos(60 m) for a pattern cos(m theta).
fn rotation_correlation(m: &ModalModel, n: usize, j: usize) -> f64 {
    let r = m.frequencies.len();
    let (mut num, mut den) = (0.0, 0.0);
    for i in 0..n - n / 6 {
        let a: f64 = (0..3).map(|k| m.phi_cell[(3 * i + k) * r + j]).sum();
        let b: f64 = (0..3)
            .map(|k| m.phi_cell[(3 * (i + n / 6) + k) * r + j])
            .sum();
        num += a * b;
        den += a * a;
    }
    num / den
}

#[test]
fn presets_by_name_and_the_default() {
    assert_eq!(CellParams::default(), CellParams::tmt());
    assert_eq!(
        StructurePreset::from_name(DEFAULT_STRUCTURE),
        Some(StructurePreset::Tmt)
    );
    for p in StructurePreset::ALL {
        assert_eq!(StructurePreset::from_name(p.name()), Some(p));
        assert_eq!(
            StructureSource::parse(p.name()).unwrap(),
            StructureSource::BuiltIn(p.params())
        );
        p.params().validate().unwrap();
    }
    assert_eq!(
        StructureSource::parse("modes/cell.NPZ").unwrap(),
        StructureSource::File("modes/cell.NPZ".into())
    );
    let e = StructureSource::parse("stiff").unwrap_err().to_string();
    assert!(
        e.contains("stiff") && e.contains("tmt") && e.contains("soft-cell"),
        "{e}"
    );
    // A file that is not there is an error naming it, not a panic.
    let e = StructureSource::parse("/nonexistent/m.npz")
        .unwrap()
        .modes(&Layout::keck())
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/m.npz"), "{e}");
}

#[test]
fn tmt_preset_has_axisymmetric_first_modes_and_no_other_cell_mode_below_14_hz() {
    let layout = Layout::tmt();
    let n = layout.n_segments();
    let p = CellParams::tmt();
    // The cell outweighs the segments 4.5 to 1 (220 kg on the actuators per segment).
    assert!(p.cell_mass / SegmentModel::voice_coil().segment.mass > 4.0);
    let m = modes(&layout, &p);
    let f = &m.frequencies;
    for (j, fj) in f.iter().enumerate().take(2) {
        let c = rotation_correlation(&m, n, j);
        assert!(c > 0.999, "mode {j} at {fj} Hz: correlation {c}");
        assert!((7.0..12.0).contains(fj), "mode {j}: {fj} Hz");
    }
    // The frequencies ascend: the third is the lowest of the others.
    assert!(f[2] >= 14.0, "a third mode below 14 Hz: {} Hz", f[2]);
    // The next modes are the cos(theta) pair: 0.5 after a 60-degree turn, summed over the pair.
    let pair = rotation_correlation(&m, n, 2) + rotation_correlation(&m, n, 3);
    assert!((pair - 1.0).abs() < 0.05, "{pair}");
    assert!((f[2] - f[3]).abs() < 1e-6 * f[2]);
}

#[test]
fn soft_cell_preset_keeps_the_first_cells_modes() {
    let m = modes(&Layout::tmt(), &CellParams::soft_cell());
    let f = &m.frequencies;
    // 6.28 Hz (not 2 pi: a measured frequency).
    #[allow(clippy::approx_constant)]
    let first = 6.28;
    assert!((f[0] - first).abs() < 0.01, "{}", f[0]);
    assert!((f[1] - 9.09).abs() < 0.01, "{}", f[1]);
}

/// The all-segment servo sensitivity peak below 15 Hz and the global loop's principal gain
/// from 8 Hz up (1 Hz on every mode but radial degree 2 and focus-mode) on TMT, 60 modes.
fn loops(p: &CellParams, segment: &SegmentModel) -> (f64, f64) {
    let layout = Layout::tmt();
    let n = layout.n_segments();
    let cell = modes(&layout, p);
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
    let fm = FrequencyModel::new(n, segment.clone(), cell.clone(), 60, 0.02).unwrap();
    let lp = ActuatorLoop::new(fm, &layout, &geometry, 2, &[1]).unwrap();
    let servo = log_grid(1.0, 15.0, 400)
        .into_iter()
        .map(|f| lp.all_sensitivity(f, 1.0).unwrap())
        .fold(0.0, f64::max);
    let params = ControllerParams {
        bandwidth: 1.0,
        bandwidth_radial2: 0.75,
        bandwidth_focus: 0.1,
        ..ControllerParams::default()
    };
    let fm = FrequencyModel::new(n, segment.clone(), cell, 60, 0.02).unwrap();
    let gl = GlobalCsi::new(fm, &layout, &geometry, params, 4, 3).unwrap();
    let global = (0..=40)
        .map(|k| 8.0 + 0.05 * f64::from(k))
        .map(|f| gl.point(f).unwrap().0.loop_gain)
        .fold(0.0, f64::max);
    (servo, global)
}

#[test]
fn issue_14_tmt_preset_meets_the_servo_criterion_and_the_global_loop_gain() {
    let (servo, global) = loops(&CellParams::tmt(), &SegmentModel::voice_coil());
    // Seed paper, section 3.2: sigma_max(S) < 2 below 15 Hz with all segments.
    assert!(servo < 2.0, "servo peak {servo}");
    // Principal loop gain under 1/4 near the structural resonances.
    assert!(global < 0.25, "global loop gain {global}");
}

#[test]
fn issue_14_soft_cell_preset_reproduces_its_figures() {
    // The first cell's figures (issue 14): peak sensitivity 3.6 at 10.5 Hz, loop gain 1.63 at
    // 8.95 Hz, within 2 %, with the segment they were measured with.
    let (servo, global) = loops(
        &CellParams::soft_cell(),
        &SegmentModel::voice_coil_without_whiffletree(),
    );
    assert!((servo / 3.6 - 1.0).abs() < 0.02, "servo peak {servo}");
    assert!(
        (global / 1.63 - 1.0).abs() < 0.02,
        "global loop gain {global}"
    );
    // With today's segment (the whiffletree's 40 Hz mode in the servo loop, setpoint weight
    // 0.8) the same cell is worse on both counts: 4.01 and 2.27 (README).
    let (servo, global) = loops(&CellParams::soft_cell(), &SegmentModel::voice_coil());
    assert!((servo / 4.01 - 1.0).abs() < 0.02, "servo peak {servo}");
    assert!(
        (global / 2.27 - 1.0).abs() < 0.02,
        "global loop gain {global}"
    );
}
