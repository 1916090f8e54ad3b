//! Issue 14 item 4: the quasi-static mirror for wind (seed paper section 4.1) against the
//! coupled dynamic solver below 1 Hz, on Keck with the default `tmt` cell.
#![allow(clippy::expect_used, clippy::unwrap_used)] // tests panic on failure by design

use m1::aperture::layout::Layout;
use m1::plant::mirror::CoupledMirror;
use m1::plant::segment::SegmentModel;
use m1::plant::static_mirror::QuasiStaticMirror;
use m1::plant::structure::{CellModel, CellParams};

fn keck_tmt_cell() -> m1::plant::structure::ModalModel {
    CellModel::new(&Layout::keck(), &CellParams::tmt())
        .unwrap()
        .modes()
        .unwrap()
}

/// Relative rms difference over the second half of a run of `seconds` at 1 ms, the inputs
/// given per time by `inputs` (command, wind force, pier).
fn compare(
    model: &SegmentModel,
    seconds: f64,
    inputs: impl Fn(f64) -> (Vec<f64>, Vec<f64>, f64),
) -> (f64, f64) {
    let n = Layout::keck().n_segments();
    let cell = keck_tmt_cell();
    let mut dynamic = CoupledMirror::new(n, model.clone(), cell.clone(), 30, 0.02, 1).unwrap();
    let mut quasi = QuasiStaticMirror::new(n, model.clone(), cell, 30).unwrap();
    let h = 1e-3;
    let steps = (seconds / h).round() as usize;
    let (mut zd, mut zq) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
    let (mut d2, mut r2, mut c2, mut cr2) = (0.0, 0.0, 0.0, 0.0);
    for k in 0..steps {
        let (u, f, p) = inputs(k as f64 * h);
        dynamic.advance(h, &u, &f, p).unwrap();
        quasi.advance(h, &u, &f, p).unwrap();
        dynamic.mirror(&mut zd);
        quasi.mirror(&mut zq);
        if 2 * k >= steps {
            for (a, b) in zq.iter().zip(&zd) {
                d2 += (a - b) * (a - b);
                r2 += b * b;
            }
            for (a, b) in quasi
                .cell_displacement()
                .iter()
                .zip(dynamic.cell_displacement())
            {
                c2 += (a - b) * (a - b);
                cr2 += b * b;
            }
        }
    }
    ((d2 / r2).sqrt(), (c2 / cr2).sqrt())
}

/// A wind-like load: a smooth pattern over the actuators (N), a tone at `f` Hz.
fn wind(n: usize, f: f64) -> impl Fn(f64) -> (Vec<f64>, Vec<f64>, f64) {
    move |t| {
        let s = (std::f64::consts::TAU * f * t).sin();
        let force = (0..3 * n)
            .map(|j| 0.05 * (1.0 + (0.37 * j as f64).sin()) * s)
            .collect();
        (vec![0.0; 3 * n], force, 0.0)
    }
}

#[test]
fn issue_14_quasi_static_mirror_follows_the_dynamic_one_below_1_hz() {
    let n = Layout::keck().n_segments();
    // Measured: 0.2 Hz 1.8e-3 (voice coil) and 1.1e-3 (damped piezo), 1 Hz 1.9e-2 and 1.1e-2,
    // the command 5.8e-4 and 5.0e-4.
    for (name, model) in [
        ("voice coil", SegmentModel::voice_coil()),
        ("piezo-damped", SegmentModel::piezo_damped_default()),
    ] {
        // Wind tones: 0.2 Hz within 0.5 %, 1 Hz within 3 % (the cell's 7.5 Hz bounce and the
        // segments' servo resonance are what the reduction leaves out).
        let (z, c) = compare(&model, 6.0, wind(n, 0.2));
        eprintln!("{name} 0.2 Hz: mirror {z:.2e}, cell {c:.2e}");
        assert!(z < 5e-3 && c < 5e-3, "0.2 Hz: mirror {z:.2e}, cell {c:.2e}");
        let (z, c) = compare(&model, 4.0, wind(n, 1.0));
        eprintln!("1 Hz: mirror {z:.2e}, cell {c:.2e}");
        assert!(z < 3e-2 && c < 3e-2, "1 Hz: mirror {z:.2e}, cell {c:.2e}");
        // A slow command ramp-and-hold pattern is tracked alike.
        let (z, _) = compare(&model, 4.0, move |t| {
            let a = 1e-7 * (t / 2.0).min(1.0);
            (
                (0..3 * n).map(|j| a * ((j % 3) as f64 - 1.0)).collect(),
                vec![0.0; 3 * n],
                0.0,
            )
        });
        eprintln!("command: {z:.2e}");
        assert!(z < 5e-3, "command: {z:.2e}");
    }
}

#[test]
fn bad_inputs_are_errors() {
    let n = Layout::keck().n_segments();
    let cell = keck_tmt_cell();
    let mut m = QuasiStaticMirror::new(n, SegmentModel::voice_coil(), cell.clone(), 10).unwrap();
    let e = m
        .advance(1e-3, &[0.0; 3], &vec![0.0; 3 * n], 0.0)
        .unwrap_err();
    assert!(e.to_string().contains("u_cmd"), "{e}");
    let e = m
        .advance(f64::NAN, &vec![0.0; 3 * n], &vec![0.0; 3 * n], 0.0)
        .unwrap_err();
    assert!(e.to_string().contains("step"), "{e}");
    assert!(QuasiStaticMirror::new(n + 1, SegmentModel::voice_coil(), cell, 10).is_err());
}
