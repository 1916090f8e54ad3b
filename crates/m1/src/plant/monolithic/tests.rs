//! Tests of the monolithic models: the channels against the exact discrete loop, the two
//! formulations against each other and against the coupled solver, the global loop's projection.

use super::*;
use crate::aperture::layout::Layout;
use crate::plant::mirror::CoupledMirror;
use crate::plant::structure::{CellModel, CellParams};
use faer::Mat;

fn close(a: c64, b: c64, tol: f64) -> bool {
    (a - b).norm() <= tol * b.norm().max(1e-300)
}

/// On a rigid base the model is the sampled-data loop itself: its fundamental, held at the
/// servo rate where the segment model holds an input, agrees with the exact discrete
/// response of the closed-loop tick map (the difference is the images beyond 4.9 kHz that
/// sampling the mirror folds back, a few 1e-4 at most here). Input 1, the base motion, is
/// the vibration response of a segment on a rigid base (issue 6): the model's transfer
/// function equals the analytic one of the discrete loop, for every variant and channel.
#[test]
fn rigid_base_channels_match_the_exact_discrete_loop() {
    for model in [
        SegmentModel::voice_coil(),
        SegmentModel::piezo(),
        SegmentModel::piezo_damped_default(),
    ] {
        for ch in Channel::ALL {
            for f in [0.3, 5.0, 29.6, 120.0] {
                let t = channel_transfer(&model, ch, f);
                let exact = model.mirror_response(ch, f);
                let h = hold(f, model.servo_period());
                // The command is a sequence in both; z_c and f_w are held in the discrete
                // one. A held z_c reaches the plant as h z_k at the fundamental but the
                // servo's samples as z_k itself: that case is assembled from the open
                // channel here.
                let o = open_channel(&model, ch, f);
                let (_, k_s) = servo_transfer(&model, f);
                let stroke_held = (o.stroke[1] + 1.0) * h - 1.0;
                let drive = -k_s * stroke_held / t.return_difference;
                let held_z = o.mirror[0] * h * drive + o.mirror[1] * h;
                let ours = [t.mirror[0], held_z, t.mirror[2] * h];
                for j in 0..3 {
                    // What is left is the images beyond 4.9 kHz folded back by sampling
                    // the mirror.
                    let tol = 1e-3;
                    assert!(
                        close(ours[j], exact[j], tol),
                        "{:?} {} {f} Hz input {j}: {} vs {}",
                        model.actuator.drive,
                        ch.name(),
                        ours[j],
                        exact[j]
                    );
                }
            }
        }
    }
}

/// The servo's sensitivity on a rigid base, 1 / (1 + K_s P_d), is the analytic
/// discrete-loop value: K_r S is the response of the drive state of the closed-loop tick
/// map to the command.
#[test]
fn rigid_base_sensitivity_is_the_closed_loop_maps() {
    use nalgebra::Complex;
    for model in [
        SegmentModel::voice_coil(),
        SegmentModel::piezo_damped_default(),
    ] {
        for ch in Channel::ALL {
            let (phi, gam) = model.closed_loop(ch);
            for f in [0.5, 10.0, 40.0, 300.0] {
                let t = channel_transfer(&model, ch, f);
                let (k_r, _) = servo_transfer(&model, f);
                let z = Complex::from_polar(1.0, TAU * f * model.servo_period());
                let m = SMatrix::<
                    Complex<f64>,
                    { crate::plant::segment::N_STATE },
                    { crate::plant::segment::N_STATE },
                >::identity()
                    * z
                    - phi.map(|x| Complex::new(x, 0.0));
                let x = m
                    .lu()
                    .solve(&gam.column(0).map(|x| Complex::new(x, 0.0)))
                    .expect("solve");
                // DRIVE holds u_{k-1}: x_drive = z^-1 u.
                let u = x[state::DRIVE] * z;
                let s = t.return_difference.inv();
                assert!(close(k_r * s, u, 1e-9), "{f} Hz: {} vs {u}", k_r * s);
            }
        }
    }
}

fn keck_modes() -> ModalModel {
    let layout = Layout::keck();
    CellModel::new(&layout, &CellParams::soft_cell())
        .expect("cell")
        .modes()
        .expect("modes")
}

/// The two monolithic formulations agree: the exact discrete state-space model's steady
/// state (pier held over 1 ms steps, sampled at their ends) and the frequency model's
/// fundamental with that hold applied, for pier tones from 2 to 60 Hz (Keck, 30 modes).
/// The difference is the images of the 1 ms hold folded back by sampling, far above every
/// retained mode.
#[test]
fn state_space_and_frequency_models_agree() {
    let modes = keck_modes();
    let n = 36;
    for model in [
        SegmentModel::voice_coil(),
        SegmentModel::piezo(),
        SegmentModel::piezo_damped_default(),
    ] {
        let fm = FrequencyModel::new(n, model.clone(), modes.clone(), 30, 0.02)
            .expect("frequency model");
        let ss =
            StateSpaceMirror::new(n, model.clone(), modes.clone(), 30, 0.02).expect("state space");
        let h = 1e-3;
        for f in [2.0, 5.0, 9.5, 30.0, 60.0] {
            let a = ss.pier_response_sampled(f, h).expect("state space");
            let b = fm.pier_response(f).expect("frequency model");
            let hp = hold(f, h);
            let (mut e2, mut r2) = (0.0, 0.0);
            for (x, y) in a.iter().zip(&b.mirror) {
                e2 += (*x - *y * hp).norm_sqr();
                r2 += x.norm_sqr();
            }
            let rel = (e2 / r2).sqrt();
            assert!(rel < 1e-5, "{:?} {f} Hz: {rel}", model.actuator.drive);
        }
    }
}

/// The co-simulation's coupled solver against the exact state-space model, in time, from
/// rest under a pier tone at 5 and 30 Hz held over 1 ms steps (Keck, 30 modes): rms
/// difference of the mirror displacement over 3 s, relative to the response's rms. Its
/// interpolation of the continuous part of the actuator force within a coupled sub-step is
/// the difference, second order in the sub-step: the voice coil is within 2e-5 with one
/// sub-step per servo period; the piezo with the first, 150 N/um stacks (ringing at 1.4 kHz)
/// was 1.0 and 1.5 % off with one, 0.24 and 0.36 % with two (the mirror FMU's default for
/// it), the bounds kept here; today's 4.3 N/um stacks are well inside them.
#[test]
fn coupled_solver_follows_the_state_space_model() {
    let modes = keck_modes();
    let n = 36;
    let na = 3 * n;
    for (model, substeps, tol) in [
        (SegmentModel::voice_coil(), 1, [1e-4, 1e-4]),
        (SegmentModel::piezo_damped_default(), 1, [0.012, 0.018]),
        (SegmentModel::piezo_damped_default(), 2, [0.003, 0.0045]),
    ] {
        let mut ss0 =
            StateSpaceMirror::new(n, model.clone(), modes.clone(), 30, 0.02).expect("state space");
        for (f, tol) in [5.0, 30.0].into_iter().zip(tol) {
            let mut m = CoupledMirror::new(n, model.clone(), modes.clone(), 30, 0.02, substeps)
                .expect("mirror");
            let ss = &mut ss0;
            ss.reset();
            let zero = vec![0.0; na];
            let (mut za, mut zb) = (vec![0.0; na], vec![0.0; na]);
            let (mut e2, mut r2) = (0.0, 0.0);
            let h = 1e-3;
            for k in 0..3000 {
                let p = 1e-6 * (TAU * f * k as f64 * h).sin();
                m.advance(h, &zero, &zero, p).expect("coupled");
                ss.advance(h, &zero, &zero, p).expect("state space");
                m.mirror(&mut za);
                ss.mirror(&mut zb);
                for (a, b) in za.iter().zip(&zb) {
                    e2 += (a - b).powi(2);
                    r2 += b * b;
                }
            }
            let rel = (e2 / r2).sqrt();
            assert!(
                rel < tol,
                "{:?} with {substeps} sub-steps, {f} Hz: {rel}",
                model.actuator.drive
            );
        }
    }
}

/// The global loop's projection on W is exact: on Keck (30 modes) its largest singular
/// values of the loop gain and of the sensitivity equal those of the dense 108 x 108
/// loop, built from the frequency model's response to every actuator's command and the
/// controller's gain matrix.
#[test]
fn global_loop_projection_equals_the_dense_loop() {
    use crate::aperture::geometry::{Geometry, GeometryParams};
    use crate::control::controller::{ControlModes, ControllerParams};
    let layout = Layout::keck();
    let n = layout.n_segments();
    let na = 3 * n;
    let fm = FrequencyModel::new(n, SegmentModel::voice_coil(), keck_modes(), 30, 0.02)
        .expect("frequency model");
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).expect("geometry");
    let controls = ControlModes::new(geometry).expect("controls");
    // Four distinct gains: 2 Hz on radial degrees >= 5, 1 Hz on 3-4, 0.75 Hz on 2, 0.1 Hz
    // on focus-mode.
    let params = ControllerParams {
        bandwidth: 2.0,
        ..ControllerParams::default()
    };
    let gl = GlobalLoop::new(&fm, &controls, &params).expect("loop");
    let gains = params.gains().expect("gains");
    assert!(gains.rest > gains.radial34 && gains.radial34 > gains.radial2);
    // Dense G in actuator space: g P plus (g_group - g) V V^T per group.
    let nsp = controls.null_space();
    let mut g = Mat::<f64>::identity(na, na) * faer::Scale(gains.rest);
    let mut add = |v: &[f64], coef: f64| {
        for i in 0..na {
            for j in 0..na {
                g[(i, j)] += coef * v[i] * v[j];
            }
        }
    };
    for j in 0..nsp.ncols() {
        let v: Vec<f64> = (0..na).map(|i| nsp[(i, j)]).collect();
        add(&v, -gains.rest);
    }
    for v in controls.radial2() {
        add(v, gains.radial2 - gains.rest);
    }
    for v in controls.radial34() {
        add(v, gains.radial34 - gains.rest);
    }
    add(controls.focus(), gains.focus - gains.rest);
    for f in [0.3, 2.0, 9.1, 25.0] {
        let mut t = Mat::<c64>::zeros(na, na);
        for j in 0..na {
            let mut u = vec![c64::new(0.0, 0.0); na];
            u[j] = c64::new(1.0, 0.0);
            let resp = fm
                .response(
                    f,
                    &Inputs {
                        u_cmd: &u,
                        f_wind: &[],
                        pier: c64::new(0.0, 0.0),
                    },
                )
                .expect("response");
            for i in 0..na {
                t[(i, j)] = resp.mirror[i];
            }
        }
        let gc = Mat::from_fn(na, na, |i, j| c64::new(g[(i, j)], 0.0));
        let z = cis(TAU * f / params.rate);
        let c = hold(f, 1.0 / params.rate) / (z - c64::new(1.0, 0.0));
        let l = faer::Scale(c) * (gc * t);
        let lmax = l
            .singular_values()
            .expect("svd")
            .iter()
            .copied()
            .fold(0.0, f64::max);
        let s = Mat::<c64>::identity(na, na) + &l;
        let smin = s
            .singular_values()
            .expect("svd")
            .iter()
            .copied()
            .fold(f64::INFINITY, f64::min);
        let p = gl.at(&fm, f).expect("loop point");
        assert!(
            (p.loop_gain_max - lmax).abs() <= 1e-9 * lmax,
            "{f} Hz: loop gain {} vs dense {lmax}",
            p.loop_gain_max
        );
        assert!(
            (p.sensitivity_max - 1.0 / smin).abs() <= 1e-9 / smin,
            "{f} Hz: sensitivity {} vs dense {}",
            p.sensitivity_max,
            1.0 / smin
        );
    }
}

/// Why the TMT closed loop at 1 Hz grows on the `soft-cell` preset (README): its principal
/// loop gain reaches 1.6 at 8.95 Hz, next to the 9.09 Hz cell modes, where the seed
/// paper's criterion asks for under 1/2; sampling at 20 Hz adds a second peak at 9.55 Hz
/// (the modes near 10.45 Hz folded), which a continuous-time reading misses. The highest
/// bandwidth meeting the criteria over that band is well below 1 Hz. Measured with the
/// segment as first built ([`SegmentModel::voice_coil_without_whiffletree`]); today's
/// segment moves the peaks a little (to 8.9 and 9.6 Hz) and raises them (2.3).
#[test]
fn tmt_global_loop_exceeds_the_loop_gain_criterion_at_1_hz() {
    use crate::aperture::geometry::{Geometry, GeometryParams};
    use crate::control::controller::{ControlModes, ControllerParams};
    let layout = Layout::tmt();
    let n = layout.n_segments();
    let cell = CellModel::new(&layout, &CellParams::soft_cell())
        .expect("cell")
        .modes()
        .expect("modes");
    // The segment these figures were measured with (before the whiffletree).
    let segment = SegmentModel::voice_coil_without_whiffletree();
    let fm = FrequencyModel::new(n, segment, cell, 60, 0.02).expect("frequency model");
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).expect("geometry");
    let controls = ControlModes::new(geometry).expect("controls");
    // The loop this documents (README): 1 Hz on every mode outside radial degree 2 and
    // focus-mode, astigmatism at 0.75 Hz, focus-mode at 0.1 Hz.
    let params = ControllerParams {
        bandwidth: 1.0,
        bandwidth_radial34: 1.0,
        ..ControllerParams::default()
    };
    let gl = GlobalLoop::new(&fm, &controls, &params).expect("loop");
    let at_mode = gl.at(&fm, 8.95).expect("8.95 Hz");
    assert!(at_mode.loop_gain_max > 1.4, "{at_mode:?}");
    let folded = gl.at_with_aliases(&fm, 9.55, 3).expect("folded");
    let plain = gl.at(&fm, 9.55).expect("plain");
    assert!(folded.loop_gain_max > 1.2, "{folded:?}");
    assert!(plain.loop_gain_max < 0.3, "{plain:?}");
    // The search over a grid of the band of those modes.
    let plants: Vec<PlantOnW> = (0..40)
        .map(|k| gl.plant(&fm, 5.0 + 0.125 * f64::from(k), 3))
        .collect();
    let limit =
        highest_bandwidth(&gl, &plants, &params, 1.0, 0.75, 5.0, 2.0, 0.25, 2.0).expect("search");
    assert!(
        limit.bandwidth_hz > 0.05 && limit.bandwidth_hz < 1.0,
        "{limit:?}"
    );
    assert!(limit.high_frequency_loop_gain <= 0.25, "{limit:?}");
}
