//! Tests of the segments: the basis, the variants' stability, the tick maps' propagation,
//! the support's modes and stiffness, the array's steps against each other.

use super::*;

fn max_abs(a: &[f64]) -> f64 {
    a.iter().fold(0.0, |m, x| m.max(x.abs()))
}

#[test]
fn modal_basis_is_orthonormal() {
    let v = modal_basis();
    let e = v.transpose() * v - SMatrix::<f64, 3, 3>::identity();
    assert!(e.abs().max() < 1e-15);
}

#[test]
fn default_variants_are_stable() {
    for m in [
        SegmentModel::voice_coil(),
        SegmentModel::piezo(),
        SegmentModel {
            segment: SegmentParams::default(),
            actuator: ActuatorParams::piezo_damped(),
        },
    ] {
        assert!(m.validate().is_ok(), "{m:?}");
    }
}

#[test]
fn propagate_equals_repeated_ticks() {
    let m = SegmentModel::voice_coil();
    let (phi, gam) = m.closed_loop(Channel::Tilt);
    let (p7, s7) = propagate(&phi, &gam, 7);
    let mut p = Phi::identity();
    let mut s = Gamma::zeros();
    for _ in 0..7 {
        s = phi * s + gam;
        p = phi * p;
    }
    assert!((p7 - p).abs().max() < 1e-12 * p.abs().max());
    assert!((s7 - s).abs().max() < 1e-12 * s.abs().max());
}

#[test]
fn clamped_support_modes_match_parameters() {
    // Mirror mass on the support spring alone (node clamped): omega^2 = k_s / m.
    let m = SegmentModel::voice_coil();
    for (ch, f) in [(Channel::Piston, 120.0), (Channel::Tilt, 90.0)] {
        let w2 = m.support_stiffness(ch) / m.mirror_mass(ch);
        assert!((w2.sqrt() / TAU - f).abs() < 1e-9);
    }
}

#[test]
fn static_wind_load_is_transmitted_to_the_cell() {
    // At equilibrium the force on the cell equals the force on the mirror, and the mirror
    // moves by f / K_static.
    for model in [SegmentModel::voice_coil(), SegmentModel::piezo()] {
        let mut arr = SegmentArray::new(2, model.clone()).expect("valid");
        let f = [10.0, 10.0, 10.0, 0.0, 0.0, 0.0];
        let zero = [0.0; 6];
        arr.step(5000 * 20, &zero, &zero, &f).expect("step");
        let mut z = [0.0; 6];
        let mut fc = [0.0; 6];
        arr.outputs(&zero, &mut z, &mut fc).expect("outputs");
        let k = model.static_stiffness(Channel::Piston);
        for a in 0..3 {
            assert!((fc[a] - 10.0).abs() < 1e-6, "{fc:?}");
            assert!(
                (z[a] * k / 10.0 - 1.0).abs() < 1e-6,
                "{} vs {}",
                z[a],
                10.0 / k
            );
        }
        assert!(max_abs(&z[3..]) == 0.0);
    }
}

#[test]
fn voice_coil_is_stiff_below_one_hertz() {
    // The published >= 10 N/um is the servoed actuator's: the mirror's compliance less the
    // support's in series with it (quasi-static below 1 Hz, 40 Hz and up).
    let m = SegmentModel::voice_coil();
    for ch in Channel::ALL {
        for f in [0.01, 0.1, 0.5, 1.0] {
            let c = m.mirror_response(ch, f)[2].norm() - m.support_compliance(ch);
            assert!(1.0 / c > 10e6, "{ch:?} {f} Hz: {} N/um", 1e-6 / c);
        }
    }
}

#[test]
fn issue_14_whiffletree_puts_the_lowest_locked_mode_at_40_hz() {
    let m = SegmentModel::voice_coil();
    let t = m.locked_modes(Channel::Tilt);
    assert!((t[0] - 40.0).abs() < 1e-9, "{t:?}");
    let p = m.locked_modes(Channel::Piston);
    // The piston pair lies above, both upper modes above the clamped-whiffletree ones.
    assert!(p[0] > 40.0 && p[0] < 120.0, "{p:?}");
    assert!(t[1] > 90.0 && p[1] > 120.0, "{t:?} {p:?}");
    // The same from the state matrix: the clamped-node chain's eigenvalues.
    let a = m.plant(Channel::Tilt).a;
    let idx = [
        state::WHIFFLE_POS,
        state::WHIFFLE_VEL,
        state::MIRROR_POS,
        state::MIRROR_VEL,
    ];
    let sub = nalgebra::DMatrix::from_fn(4, 4, |i, j| a[(idx[i], idx[j])]);
    let mut f: Vec<f64> = sub
        .complex_eigenvalues()
        .iter()
        .filter(|l| l.im > 0.0)
        .map(|l| l.norm() / TAU)
        .collect();
    f.sort_by(f64::total_cmp);
    assert!((f[0] / 40.0 - 1.0).abs() < 1e-3, "{f:?}");
}

#[test]
fn misaligned_steps_give_the_aligned_trajectory() {
    // Steps of 0.13 ms and 0.07 ms (servo period 0.2 ms) against whole ticks: both land on
    // t = 4 ms, where the states must agree.
    let model = SegmentModel::piezo_damped_default();
    let mut a = SegmentArray::new(2, model.clone()).expect("valid");
    let mut b = SegmentArray::new(2, model).expect("valid");
    let u = [1e-6, 0.0, -2e-7, 0.0, 3e-7, 0.0];
    let zc = [0.0, 1e-7, 0.0, 0.0, 0.0, -1e-7];
    let fw = [5.0, 0.0, 0.0, -3.0, 0.0, 1.0];
    a.step(20, &u, &zc, &fw).expect("step");
    for k in 0..40 {
        let h = if k % 2 == 0 { 0.13e-3 } else { 0.07e-3 };
        b.advance(h, &u, &zc, &fw).expect("advance");
    }
    assert!(b.phase.abs() < 1e-12, "{}", b.phase);
    for k in 0..2 {
        let d: Vec<f64> = a.x[k].iter().zip(&b.x[k]).map(|(x, y)| x - y).collect();
        assert!(max_abs(&d) <= 1e-9 * max_abs(&a.x[k]), "{}", max_abs(&d));
    }
}

#[test]
fn step_size_does_not_change_the_trajectory() {
    let model = SegmentModel::voice_coil();
    let mut a = SegmentArray::new(3, model.clone()).expect("valid");
    let mut b = SegmentArray::new(3, model).expect("valid");
    let u: Vec<f64> = (0..9).map(|i| 1e-6 * (i as f64 - 4.0)).collect();
    let zc: Vec<f64> = (0..9).map(|i| 1e-7 * (i as f64).sin()).collect();
    let fw: Vec<f64> = (0..9).map(|i| (i as f64).cos()).collect();
    for _ in 0..50 {
        a.step(5, &u, &zc, &fw).expect("step");
        for _ in 0..5 {
            b.step(1, &u, &zc, &fw).expect("step");
        }
    }
    for k in 0..2 {
        let d: Vec<f64> = a.x[k].iter().zip(&b.x[k]).map(|(x, y)| x - y).collect();
        assert!(max_abs(&d) <= 1e-9 * max_abs(&a.x[k]));
    }
}

/// Two arrays of `n` segments at rest, the second leaving its steps on unchanged inputs
/// pending.
fn plain_and_deferred(n: usize, model: &SegmentModel) -> (SegmentArray, SegmentArray) {
    let plain = SegmentArray::new(n, model.clone()).expect("valid");
    let mut lazy = SegmentArray::new(n, model.clone()).expect("valid");
    lazy.set_deferred(true);
    (plain, lazy)
}

/// An array that leaves its steps on unchanged inputs pending gives the states and outputs of
/// one that steps every time, to rounding: inputs held for 1, 3, 10 and 40 steps (more than
/// `MAX_PENDING_STEPS`, so pending steps are applied when the table ends as well as with the
/// step that changes the inputs), whole steps of two lengths and a misaligned one (applied at
/// once: no step of another length is left pending), the combinations of the states read
/// between steps (the mirror position and the cell force, with pending steps and without),
/// and the states after `settle`. Steps are pending where they should be, and none after a
/// change of the step.
#[test]
fn pending_steps_give_the_stepped_trajectory() {
    use super::array::MAX_PENDING_STEPS;
    let model = SegmentModel::voice_coil();
    let (n, na) = (4, 12);
    let (mut plain, mut lazy) = plain_and_deferred(n, &model);
    let ts = model.servo_period();
    let mut pos = SMatrix::<f64, 1, N_STATE>::zeros();
    pos[state::MIRROR_POS] = 1.0;
    let (force, _) = model.cell_force_map(Channel::Tilt);
    let mut k = 0usize;
    let mut worst = 0.0f64;
    for (hold, h) in [
        (1, 5.0 * ts),
        (3, 5.0 * ts),
        (10, 5.0 * ts),
        (40, 5.0 * ts),
        (4, 2.0 * ts),
        (1, 0.7 * ts),
        (6, 5.0 * ts),
    ] {
        let u: Vec<f64> = (0..na).map(|i| 1e-6 * ((i + k) as f64).sin()).collect();
        let zc: Vec<f64> = (0..na).map(|i| 1e-7 * ((i * 3 + k) as f64).cos()).collect();
        let fw: Vec<f64> = (0..na).map(|i| ((i + 2 * k) as f64 * 0.3).cos()).collect();
        for step in 0..hold {
            plain.advance(h, &u, &zc, &fw).expect("plain");
            lazy.advance(h, &u, &zc, &fw).expect("lazy");
            k += 1;
            // A whole step from a servo sample is left pending (at most the table's length);
            // the misaligned step and the one after it (from mid-period) are applied.
            let whole = (h / ts - (h / ts).round()).abs() < 1e-9 && plain.phase == 0.0;
            if whole && step > 0 {
                assert!(lazy.pending_steps() >= 1, "step {k}");
            }
            assert!(lazy.pending_steps() <= MAX_PENDING_STEPS);
            if !whole {
                assert_eq!(lazy.pending_steps(), 0, "step {k}");
            }
            for (kind, c) in [(0, pos), (1, pos), (1, force)] {
                let cnt = if kind == 0 { n } else { 2 * n };
                let (mut a, mut b) = (vec![0.0; cnt], vec![0.0; cnt]);
                plain.combination(kind, &c, &mut a);
                lazy.combination(kind, &c, &mut b);
                let scale = max_abs(&a).max(1e-30);
                let d: Vec<f64> = a.iter().zip(&b).map(|(x, y)| x - y).collect();
                worst = worst.max(max_abs(&d) / scale);
            }
        }
    }
    assert!(
        worst <= 1e-12,
        "combinations differ by {worst:e} of their largest"
    );
    assert!(worst > 0.0, "the pending steps were never used");
    lazy.settle();
    assert_eq!(lazy.pending_steps(), 0);
    for kind in 0..2 {
        let d: Vec<f64> = plain.state()[kind]
            .iter()
            .zip(lazy.state()[kind])
            .map(|(x, y)| x - y)
            .collect();
        assert!(
            max_abs(&d) <= 1e-12 * max_abs(plain.state()[kind]),
            "{}",
            max_abs(&d)
        );
    }
    // Its outputs in actuator order agree too (computed from the settled states).
    let zc = vec![0.0; na];
    let (mut za, mut fa, mut zb, mut fb) =
        (vec![0.0; na], vec![0.0; na], vec![0.0; na], vec![0.0; na]);
    plain.outputs(&zc, &mut za, &mut fa).expect("outputs");
    lazy.outputs(&zc, &mut zb, &mut fb).expect("outputs");
    for (a, b) in za.iter().zip(&zb).chain(fa.iter().zip(&fb)) {
        assert!(
            (a - b).abs() <= 1e-12 * max_abs(&za).max(max_abs(&fa)),
            "{a} {b}"
        );
    }
}

/// Inputs that change at every step leave no step pending: the states are those of stepping
/// without it, to the bit.
#[test]
fn inputs_changing_every_step_are_stepped_as_without_pending() {
    let model = SegmentModel::piezo_damped_default();
    let (n, na) = (3, 9);
    let (mut plain, mut lazy) = plain_and_deferred(n, &model);
    let h = 5.0 * model.servo_period();
    for k in 0..30 {
        let u: Vec<f64> = (0..na).map(|i| 1e-6 * ((i + k) as f64).sin()).collect();
        let fw: Vec<f64> = (0..na).map(|i| ((i * 5 + k) as f64).cos()).collect();
        let zc = vec![0.0; na];
        plain.advance(h, &u, &zc, &fw).expect("plain");
        lazy.advance(h, &u, &zc, &fw).expect("lazy");
        assert_eq!(lazy.pending_steps(), 0);
        assert_eq!(plain.state(), lazy.state(), "step {k}");
    }
}
