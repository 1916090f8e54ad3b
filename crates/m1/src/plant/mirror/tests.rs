//! Tests of the coupled solver: every step's outputs consistent with its state, the static
//! solution reached, the results independent of the communication step.

use super::*;
use crate::aperture::layout::Layout;
use crate::linalg::symmetric_scaled::{Encoding, Fixed8, Fixed24};
use crate::plant::segment::{Channel, N_STATE, SegmentModel, state};
use crate::plant::structure::{CellModel, CellParams};

/// The 24-bit shapes' default as the documentation states it (from FIXED24_SHAPES_MIN_MODES
/// where the processor permutes the bytes, from FIXED24_SHAPES_AVX2_MIN_MODES on the AVX2
/// path, never on the scalar one), written out independently of the constructor's choice.
fn shapes_fixed24_rule(modes: usize) -> bool {
    if Fixed24::permuted() {
        modes >= FIXED24_SHAPES_MIN_MODES
    } else {
        Fixed24::vectorised() && modes >= FIXED24_SHAPES_AVX2_MIN_MODES
    }
}

fn keck(model: SegmentModel, n_modes: usize) -> (CoupledMirror, CellModel) {
    keck_on(model, n_modes, &CellParams::soft_cell())
}

fn keck_on(model: SegmentModel, n_modes: usize, p: &CellParams) -> (CoupledMirror, CellModel) {
    let layout = Layout::keck();
    let cell = CellModel::new(&layout, p).expect("cell");
    let modes = cell.modes().expect("modes");
    let m =
        CoupledMirror::new(layout.n_segments(), model, modes, n_modes, 0.02, 1).expect("mirror");
    (m, cell)
}

/// Each value of `x` is its counterpart in `y` to within `rel` of `y`'s largest magnitude
/// (which is not zero).
fn assert_close(x: &[f64], y: &[f64], rel: f64) {
    let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(scale > 0.0);
    assert_eq!(x.len(), y.len());
    for (p, q) in x.iter().zip(y) {
        assert!((p - q).abs() <= rel * scale, "{p} vs {q}");
    }
}

fn wind(na: usize) -> Vec<f64> {
    (0..na)
        .map(|i| ((i * 7919 % 13) as f64 - 6.0) * 5.0)
        .collect()
}

/// At the end of every step the two sides agree: the force on the cell is the segments'
/// output for the channel states they ended on (free part plus the part carried on the
/// modes) and the cell displacement, and the modal force is that force projected on the
/// modes (the identities the implicit solve enforces).
#[test]
fn every_step_ends_consistent() {
    for model in [
        SegmentModel::voice_coil(),
        SegmentModel::piezo_damped_default(),
    ] {
        let (mut m, _) = keck(model, 1000);
        let na = m.n_actuators();
        let n = m.n_segments();
        let r = m.r;
        let u_cmd: Vec<f64> = (0..na).map(|i| 1e-8 * (i % 5) as f64).collect();
        let fw = wind(na);
        for k in 0..40 {
            let p = 1e-9 * (k as f64 * 0.3).sin();
            m.advance(m.tick_period(), &u_cmd, &fw, p).expect("tick");
            // The free part's states with its pending steps (its inputs are held here).
            m.free.settle();
            // Channel states X = x_free + Phi_c xi; f = c X + d z_cell, channel by channel.
            let v = m.basis;
            let z = m.cell_displacement().to_vec();
            let mut f = vec![0.0; na];
            for seg in 0..n {
                let idx = [(0usize, seg, n, seg), (1, 2 * seg, 2 * n, n + 2 * seg)];
                let idx = [idx[0], idx[1], (1, 2 * seg + 1, 2 * n, n + 2 * seg + 1)];
                let zc = &z[3 * seg..3 * seg + 3];
                let mut fch = [0.0; 3];
                for (j, &(kind, c, cnt, row)) in idx.iter().enumerate() {
                    let zch = v[(0, j)] * zc[0] + v[(1, j)] * zc[1] + v[(2, j)] * zc[2];
                    let x = |s: usize| {
                        m.free.state()[kind][s * cnt + c]
                            + (0..r)
                                .map(|q| m.phic[row * r + q] * m.xi[kind][s * r + q])
                                .sum::<f64>()
                    };
                    fch[j] = (0..N_STATE).map(|s| m.cell_c[kind][s] * x(s)).sum::<f64>()
                        + m.cell_d * zch;
                }
                for a in 0..3 {
                    f[3 * seg + a] = v[(a, 0)] * fch[0] + v[(a, 1)] * fch[1] + v[(a, 2)] * fch[2];
                }
            }
            let scale = f.iter().fold(0.0f64, |a, b| a.max(b.abs()));
            // The outputs come back through the single-precision shapes.
            for (a, b) in f.iter().zip(m.cell_force()) {
                assert!((a - b).abs() <= 1e-6 * scale, "force {a} vs {b}");
            }
            let phi = m.structure.shapes();
            let bp = m.structure.pier_gains();
            let modal: Vec<f64> = (0..r)
                .map(|j| (0..na).map(|i| phi[i * r + j] * f[i]).sum::<f64>() + bp[j] * p)
                .collect();
            let uscale = modal.iter().fold(1e-300, |a: f64, b| a.max(b.abs()));
            for (j, &u) in modal.iter().enumerate() {
                // Within 1e-6 of the largest modal force: the inputs reach the modes through
                // the single-precision shapes.
                assert!(
                    (u - m.u[j]).abs() <= 1e-6 * uscale,
                    "mode {j}: {u} vs {}",
                    m.u[j]
                );
            }
            // The free part's projection, stepped on the modes, matches the free states.
            for kind in 0..2 {
                let (lo, cnt) = if kind == 0 { (0, n) } else { (n, 2 * n) };
                for s in [state::NODE_POS, state::MIRROR_POS, state::DRIVE] {
                    let direct = |j: usize| -> f64 {
                        (0..cnt)
                            .map(|c| m.phic[(lo + c) * r + j] * m.free.state()[kind][s * cnt + c])
                            .sum()
                    };
                    let scale = (0..r).map(|j| direct(j).abs()).fold(1e-300, f64::max);
                    for j in (0..r).step_by(7) {
                        let direct = direct(j);
                        let carried = m.proj[kind][s * r + j];
                        // The inputs reach the modes through the single-precision shapes:
                        // within 1e-6 of the largest projection.
                        assert!(
                            (direct - carried).abs() <= 1e-6 * scale,
                            "proj {direct} vs {carried}"
                        );
                    }
                }
            }
        }
    }
}

/// Under a constant load the mirror settles on the analytic static solution: the cell (all
/// modes retained) deflects by the exact static compliance under the actuator reactions
/// (f_cell = f_wind),
/// the integral servo of the piezo holds the stroke at zero, and the mirror sits on the
/// whiffletree and the flexures in series, f (1/k_w + 1/k_s) per channel.
#[test]
fn settles_on_the_static_solution() {
    let model = SegmentModel::piezo();
    let (mut m, cell) = keck(model.clone(), 1000);
    let na = m.n_actuators();
    let fw = wind(na);
    let zero = vec![0.0; na];
    // 24 s: the piezo's integral correction (0.25 Hz, time constant 0.64 s) and the slowest
    // mode (the 10 Hz mount, 2 % damping) decay by e^-30 or more.
    for _ in 0..48 {
        m.advance(0.5, &zero, &fw, 0.0).expect("advance");
    }
    let zc = cell.static_deflection(&fw, 0.0).expect("static");
    let scale = zc.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for (a, b) in m.cell_displacement().iter().zip(&zc) {
        assert!((a - b).abs() <= 1e-5 * scale, "z_cell {a} vs {b}");
    }
    // The outputs come back through the single-precision shapes, and the piezo's force is
    // a difference of stiff terms (K_D times displacements): 1e-4 N of 30 N.
    for (a, b) in m.cell_force().iter().zip(&fw) {
        assert!((a - b).abs() <= 1e-4, "f_cell {a} vs {b}");
    }
    let v = m.basis;
    let mut z = vec![0.0; na];
    m.mirror(&mut z);
    for seg in 0..m.n_segments() {
        let f = &fw[3 * seg..3 * seg + 3];
        let c = &zc[3 * seg..3 * seg + 3];
        let mut ch = [0.0; 3];
        for (j, kind) in [Channel::Piston, Channel::Tilt, Channel::Tilt]
            .iter()
            .enumerate()
        {
            let fj = v[(0, j)] * f[0] + v[(1, j)] * f[1] + v[(2, j)] * f[2];
            let cj = v[(0, j)] * c[0] + v[(1, j)] * c[1] + v[(2, j)] * c[2];
            ch[j] = cj + fj * model.support_compliance(*kind);
        }
        for a in 0..3 {
            let want = v[(a, 0)] * ch[0] + v[(a, 1)] * ch[1] + v[(a, 2)] * ch[2];
            let got = z[3 * seg + a];
            assert!((got - want).abs() <= 1e-5 * scale, "z {got} vs {want}");
        }
    }
}

/// The coupled solve gives the same answer (to rounding) for any split of time into
/// communication steps, on both structure presets, with its matrices in double and in single
/// precision, and refuses a step off the servo grid.
#[test]
fn results_do_not_depend_on_the_communication_step() {
    for (p, single) in [CellParams::soft_cell(), CellParams::tmt()]
        .into_iter()
        .flat_map(|p| [(p, false), (p, true)])
    {
        let (mut a, _) = keck_on(SegmentModel::voice_coil(), 50, &p);
        a.set_coupling_single(single);
        let mut b = a.clone();
        let na = a.n_actuators();
        let fw = wind(na);
        let u = vec![2e-8; na];
        for _ in 0..10 {
            a.advance(1e-3, &u, &fw, 1e-9).expect("1 ms");
        }
        let mut c = b.clone();
        for _ in 0..50 {
            b.advance(2e-4, &u, &fw, 1e-9).expect("0.2 ms");
        }
        // 5 ms steps: 25 ticks, in chunks of 10, 10 and 5 with their free part composed.
        for _ in 0..2 {
            c.advance(5e-3, &u, &fw, 1e-9).expect("5 ms");
        }
        // Equal to rounding: the free part takes one 5-tick map against five 1-tick maps.
        let (za, fa) = a.cell_outputs();
        let (zb, fb) = b.cell_outputs();
        let (zc, fc) = c.cell_outputs();
        for (x, y) in [(za, zb), (fa, fb), (zc, zb), (fc, fb)] {
            assert_close(x, y, 1e-12);
        }
        let e = a
            .advance(3e-4, &u, &fw, 0.0)
            .expect_err("off grid")
            .to_string();
        assert!(e.contains("communicationStepSize"), "{e}");
    }
}

/// With three coupled sub-steps per servo period (the first samples, the others hold), steps
/// of one servo period (three ticks, one chunk) and of 3 ms (45 ticks, in chunks of 10 that
/// start at every phase of the period, then 5) end on the same states.
#[test]
fn substeps_give_the_same_results_for_any_chunk_of_ticks() {
    let layout = Layout::keck();
    let cell = CellModel::new(&layout, &CellParams::default())
        .expect("cell")
        .modes()
        .expect("modes");
    let mut a = CoupledMirror::new(
        layout.n_segments(),
        SegmentModel::piezo(),
        cell,
        40,
        0.02,
        3,
    )
    .expect("mirror");
    let mut b = a.clone();
    let na = a.n_actuators();
    let fw = wind(na);
    let u = vec![2e-8; na];
    for _ in 0..30 {
        a.advance(2e-4, &u, &fw, 1e-9).expect("0.2 ms");
    }
    for _ in 0..2 {
        b.advance(3e-3, &u, &fw, 1e-9).expect("3 ms");
    }
    let (za, fa) = a.cell_outputs();
    let (zb, fb) = b.cell_outputs();
    let (za, fa, zb, fb) = (za.to_vec(), fa.to_vec(), zb.to_vec(), fb.to_vec());
    let (mut ma, mut mb) = (vec![0.0; na], vec![0.0; na]);
    a.mirror(&mut ma);
    b.mirror(&mut mb);
    for (x, y) in [(&za, &zb), (&fa, &fb), (&ma, &mb)] {
        assert_close(x, y, 1e-11);
    }
}

/// The coupled solve's matrix streamed in single precision changes the mirror's response to
/// wind, a command and a pier input over 400 ms, and the cell's force likewise, with the Gram
/// matrices whole and by half, by less than 1e-7 of its largest value for TMT's voice coil at
/// 300 modes and at the default 60 (measured 2.1e-9: the correction `W - I` is about 4e-7 in
/// norm there, so losing it would show) and 1e-6 for Keck's piezo at 60 modes with two coupled
/// sub-steps per servo period (measured 5e-8). Single precision is the default in all three.
#[test]
fn coupling_precision_single_matches_double() {
    let tmt = Layout::tmt();
    let keck = Layout::keck();
    let cases = [
        (&tmt, SegmentModel::voice_coil(), 300, 1, 1e-7),
        (&tmt, SegmentModel::voice_coil(), 60, 1, 1e-7),
        (&keck, SegmentModel::piezo(), 60, 2, 1e-6),
    ];
    for (layout, model, modes, substeps, bound) in cases {
        let cell = CellModel::new(layout, &CellParams::default())
            .expect("cell")
            .modes()
            .expect("modes");
        let build = |single: bool| {
            let mut m = CoupledMirror::new(
                layout.n_segments(),
                model.clone(),
                cell.clone(),
                modes,
                0.02,
                substeps,
            )
            .expect("mirror");
            // Single precision by default at these mode counts.
            assert!(m.coupling_single() && modes >= SINGLE_COUPLING_MIN_MODES);
            m.set_coupling_single(single);
            m
        };
        // Double precision; single precision with the Gram matrices whole and by half.
        let (mut a, mut b, mut c) = (build(false), build(true), build(true));
        b.set_gram_packed(false);
        c.set_gram_packed(true);
        assert!(!a.coupling_single() && b.coupling_single() && c.gram_packed());
        let na = a.n_actuators();
        let fw = wind(na);
        // Per single-precision form: the worst difference from double precision in z and in
        // the cell force; the largest z and force.
        let mut worst = [[0.0f64; 2]; 2];
        let (mut max_z, mut max_f) = (0.0f64, 0.0f64);
        for k in 0..400 {
            let s = (k as f64 * 0.05).sin();
            let u: Vec<f64> = (0..na).map(|i| 1e-8 * s * ((i % 5) as f64 - 2.0)).collect();
            let f: Vec<f64> = fw.iter().map(|x| x * (1.0 + 0.3 * s)).collect();
            for m in [&mut a, &mut b, &mut c] {
                m.advance(1e-3, &u, &f, 1e-9 * s).expect("step");
            }
            let mut za = vec![0.0; na];
            a.mirror(&mut za);
            let fa = a.cell_force().to_vec();
            max_z = za.iter().fold(max_z, |m, x| m.max(x.abs()));
            max_f = fa.iter().fold(max_f, |m, x| m.max(x.abs()));
            for (w, m) in worst.iter_mut().zip([&mut b, &mut c]) {
                let mut z = vec![0.0; na];
                m.mirror(&mut z);
                for (x, y) in za.iter().zip(&z) {
                    w[0] = w[0].max((x - y).abs());
                }
                for (x, y) in fa.iter().zip(m.cell_force()) {
                    w[1] = w[1].max((x - y).abs());
                }
            }
        }
        assert!(max_z > 0.0 && max_f > 0.0);
        for (w, form) in worst
            .iter()
            .zip(["Gram matrices whole", "Gram matrices by half"])
        {
            eprintln!(
                "{} {modes} modes: single ({form}) against double: z {:.2e}, force {:.2e} \
                 (of the largest)",
                layout.name,
                w[0] / max_z,
                w[1] / max_f
            );
            assert!(w[0] <= bound * max_z, "{form}, z: {:e} of {max_z:e}", w[0]);
            assert!(
                w[1] <= bound * max_f,
                "{form}, force: {:e} of {max_f:e}",
                w[1]
            );
        }
    }
}

/// The multiply-adds a step counts (the benchmarks' arithmetic floor): the per-tick parts
/// double with the step's servo periods while the two passes over the shapes do not; the
/// channel maps on the modes count fewer than the dense `12 x 12` maps would (the voice coil's
/// maps have zero columns: what `state_map` skips), but more than half of them; a step that
/// is not a whole number of servo periods is refused.
#[test]
fn multiply_adds_follow_the_step_and_the_maps() {
    let (m, _) = keck(SegmentModel::voice_coil(), 30);
    let ts = m.tick_period();
    let one = m.multiply_adds_per_step(5.0 * ts, 1).expect("5 ticks");
    let two = m.multiply_adds_per_step(10.0 * ts, 1).expect("10 ticks");
    assert_eq!(one.len(), two.len());
    let (r, na) = (m.structure().n_modes() as u64, m.n_actuators() as u64);
    for (a, b) in one.iter().zip(&two) {
        assert_eq!(a.0, b.0);
        if a.0.contains("per coupled tick") || a.0.contains("per servo sample") {
            assert_eq!(2 * a.1, b.1, "{}", a.0);
        } else if a.0.starts_with("inputs") || a.0.starts_with("outputs") {
            assert_eq!(a.1, b.1, "{}", a.0);
        }
    }
    let part = |name: &str| {
        one.iter()
            .find(|p| p.0.starts_with(name))
            .map(|p| p.1)
            .expect(name)
    };
    assert_eq!(part("inputs onto the modes"), 2 * na * r);
    assert_eq!(part("outputs back"), na * r);
    assert_eq!(part("coupled solve"), 5 * 2 * r * r);
    assert_eq!(part("drive jump"), 5 * 2 * r * r);
    // Per tick, mode and kind: the cell-driven map, its ramp input, its force row, the ramp.
    let dense = 5 * 2 * r * (144 + 12 + 12 + 12);
    let maps = part("channel maps on the modes");
    assert!(maps < dense && 2 * maps > dense, "{maps} of {dense}");
    // The free part's five ticks composed: per mode and kind at most 12 + 2 x 5 rows of the
    // 12 states and 2 inputs, and less than the five per-tick maps' dense 5 x 12 x 14.
    let composed = part("the free part on the modes");
    assert!(composed <= 2 * r * 22 * 14, "{composed}");
    assert!(
        composed < 2 * r * 5 * 12 * 14 && composed > 2 * r * 22,
        "{composed}"
    );
    // With the inputs changing every tenth step, the free part's steps between are left
    // pending: per channel and step, the mirror position's row of the pending map (at most
    // 12 + 3), and a tenth of the inputs' 12 terms and of the pass that applies them (at most
    // 12 x (12 + 6)), against the whole map at every step.
    let held = m.multiply_adds_per_step(5.0 * ts, 10).expect("5 ticks");
    let free = |parts: &[(&str, u64, bool)]| {
        parts
            .iter()
            .find(|p| p.0.starts_with("free part"))
            .map(|p| p.1)
            .expect("free part")
    };
    let (every, tenth) = (free(&one), free(&held));
    let channels = na;
    assert!(
        tenth < every / 3 && tenth <= channels * (12 + 15 + 216u64.div_ceil(10)),
        "{tenth} of {every}"
    );
    assert!(tenth > channels * 12, "{tenth}");
    for (a, b) in one.iter().zip(&held) {
        if !a.0.starts_with("free part") {
            assert_eq!(a, b);
        }
    }
    assert!(m.multiply_adds_per_step(2.5 * ts, 1).is_err());
}

/// The held inputs' projection on the modes is kept while the inputs do not change and
/// recomputed when one value of either input does: after every step it is the projection of
/// the inputs of that step (to the single-precision shapes' 1e-6).
#[test]
fn held_inputs_keep_their_projection() {
    let (mut m, _) = keck(SegmentModel::voice_coil(), 40);
    let (na, n, r) = (m.n_actuators(), m.n_segments(), m.r);
    let u: Vec<f64> = (0..na).map(|i| 1e-8 * ((i % 5) as f64 - 2.0)).collect();
    let mut f = wind(na);
    let check = |m: &CoupledMirror| {
        let w = m.free.channel_inputs();
        for (kind, (lo, cnt)) in [(0usize, n), (n, 2 * n)].into_iter().enumerate() {
            for (col, out) in [(0usize, 0usize), (2, 2)] {
                let direct: Vec<f64> = (0..r)
                    .map(|j| {
                        (0..cnt)
                            .map(|c| m.phic[(lo + c) * r + j] * w[kind][col * cnt + c])
                            .sum()
                    })
                    .collect();
                let scale = direct.iter().fold(1e-300, |a: f64, b| a.max(b.abs()));
                for (j, d) in direct.iter().enumerate() {
                    let held = m.w_proj[kind][out * r + j];
                    assert!(
                        (d - held).abs() <= 1e-6 * scale,
                        "kind {kind} column {col} mode {j}: {d} vs {held}"
                    );
                }
            }
        }
    };
    for k in 0..8 {
        if k == 3 {
            // One value of the wind changes (a tilt channel's and a piston channel's share).
            f[4] += 25.0;
        }
        if k == 6 {
            f[4] -= 25.0;
        }
        m.advance(1e-3, &u, &f, 0.0).expect("step");
        check(&m);
    }
}

/// The large products split between two threads give the same mirror and cell outputs to the
/// bit as on one thread, at every tick kind: TMT's voice coil at 300 modes (a servo sample per
/// tick) with the Gram matrices whole, by half and by half in 24-bit fixed point, at 520 modes (the correction in two parts
/// too, in half precision), Keck's piezo at 60 modes with two sub-steps per servo period
/// (ticks between samples too), all with the coupled solve in single precision (the split
/// products); and a clone taken during the run (with its own helper thread) goes on with the
/// same values. The inputs change at every step, so that every step projects them onto the
/// modes (in two parts of channel rows, at once on two threads).
#[test]
fn two_threads_give_the_same_values_to_the_bit() {
    let tmt = Layout::tmt();
    let keck = Layout::keck();
    for (layout, model, modes, substeps, packed, fixed24) in [
        (&tmt, SegmentModel::voice_coil(), 300, 1, false, false),
        (&tmt, SegmentModel::voice_coil(), 300, 1, true, false),
        (&tmt, SegmentModel::voice_coil(), 300, 1, true, true),
        (&tmt, SegmentModel::voice_coil(), 520, 1, true, false),
        (&keck, SegmentModel::piezo(), 60, 2, true, false),
    ] {
        // The Gram matrices in 24-bit fixed point with the shapes so too (the largest
        // models' defaults); at 520 modes the shapes so by default.
        let cell = CellModel::new(layout, &CellParams::default())
            .expect("cell")
            .modes()
            .expect("modes");
        let mut one = CoupledMirror::new(
            layout.n_segments(),
            model.clone(),
            cell,
            modes,
            0.02,
            substeps,
        )
        .expect("mirror");
        // The default follows the retained modes.
        assert_eq!(one.two_threads(), modes >= TWO_THREADS_MIN_MODES);
        assert_eq!(one.gram_packed(), modes >= PACKED_GRAM_MIN_MODES);
        // From TWO_THREADS_MIN_MODES the correction's product is in two parts.
        assert_eq!(one.corr_split > 0, modes >= TWO_THREADS_MIN_MODES);
        one.set_coupling_single(true);
        one.set_two_threads(false);
        one.set_gram_packed(packed);
        one.set_gram_fixed24(fixed24);
        assert_eq!(one.shapes_fixed24(), shapes_fixed24_rule(modes));
        if fixed24 {
            one.set_shapes_fixed24(true);
        }
        let mut two = one.clone();
        two.set_two_threads(true);
        assert!(two.two_threads() && !one.two_threads());
        let na = one.n_actuators();
        let fw = wind(na);
        let mut third: Option<CoupledMirror> = None;
        for k in 0..120 {
            let s = (k as f64 * 0.05).sin();
            let u: Vec<f64> = (0..na).map(|i| 1e-8 * s * ((i % 5) as f64 - 2.0)).collect();
            let f: Vec<f64> = fw.iter().map(|x| x * (1.0 + 0.3 * s)).collect();
            if k == 60 {
                third = Some(two.clone());
            }
            let mut outs = Vec::new();
            for m in [Some(&mut one), Some(&mut two), third.as_mut()]
                .into_iter()
                .flatten()
            {
                m.advance(1e-3, &u, &f, 1e-9 * s).expect("step");
                let mut z = vec![0.0; na];
                m.mirror(&mut z);
                let (zc, fc) = m.cell_outputs();
                z.extend_from_slice(zc);
                z.extend_from_slice(fc);
                outs.push(z);
            }
            assert!(outs[0].iter().any(|&v| v != 0.0));
            for o in &outs[1..] {
                let same = o
                    .iter()
                    .zip(&outs[0])
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{} modes, step {k}: two threads differ", modes);
            }
        }
        assert!(third.is_some_and(|m| m.two_threads()));
    }
}

/// The correction `W - I` in half precision or 8-bit fixed point (from
/// HALF_CORRECTION_MIN_MODES modes the default takes the fewest bits whose rounding bound is
/// within single precision's: 8 bits for the voice coil, half precision for the piezo, whose
/// correction is 200 times larger) moves the mirror's response no more than single precision
/// itself moves it: TMT at that size, both actuators, three cases (wind with a command and a
/// pier input together; a static load; a 159 Hz pier vibration, where the response is a small
/// difference of large terms), each against the double-precision solve. Measured: half
/// precision the same worst difference as single precision's to three digits in every case
/// (the voice coil's largest 1.6e-7 of its largest `z`, under the static load; the piezo's
/// 2.0e-7, under the pier vibration), 8 bits the same for the voice coil; rounding the Gram
/// matrices to half precision instead moved the voice coil's response to the pier vibration by
/// 1.1e-4 of its largest (the reason they stay in single precision). The Gram matrices in 24-bit
/// fixed point ([`CoupledMirror::set_gram_fixed24`]) on top of the default correction move it
/// no more than twice as much as single precision (plus 1e-7), and never more than 5e-7.
/// (Run once at 1000 modes: the voice coil's 8-bit correction, bound 1.2e-6, again the same as
/// single precision to three digits in every case; the piezo's 8 bits, bound 2.4e-4, its pier
/// vibration 4.5e-7 against 2.0e-7.)
#[test]
fn correction_in_fewer_bits_matches_double() {
    let tmt = Layout::tmt();
    let cell = CellModel::new(&tmt, &CellParams::default())
        .expect("cell")
        .modes()
        .expect("modes");
    let modes = HALF_CORRECTION_MIN_MODES;
    let eight = if Fixed8::vectorised() {
        CorrectionStorage::Fixed8
    } else {
        CorrectionStorage::Half
    };
    for (name, model, default) in [
        ("voice coil", SegmentModel::voice_coil(), eight),
        ("piezo", SegmentModel::piezo(), CorrectionStorage::Half),
    ] {
        let mut base =
            CoupledMirror::new(tmt.n_segments(), model, cell.clone(), modes, 0.02, 1).expect("m");
        assert!(base.coupling_single() && !base.gram_fixed24());
        // The shapes in 24-bit fixed point from FIXED24_SHAPES_MIN_MODES (checked below, as a
        // form of their own).
        assert_eq!(base.shapes_fixed24(), shapes_fixed24_rule(modes));
        base.set_shapes_fixed24(false);
        assert_eq!(base.correction_storage(), default, "{name}");
        // The bounds that chose it: 8 bits within FIXED8_CORRECTION_MAX_BOUND for the voice
        // coil (measured 6.6e-7), not for the piezo (1.4e-4), whose half precision has 6.2e-8;
        // single precision's far below (3.6e-14 and 7.5e-12).
        let bound = |s| base.correction_rounding_bound(s);
        let (b32, b16, b8) = (
            bound(CorrectionStorage::Single),
            bound(CorrectionStorage::Half),
            bound(CorrectionStorage::Fixed8),
        );
        eprintln!("{name}: rounding bounds single {b32:.2e}, half {b16:.2e}, 8-bit {b8:.2e}");
        assert!(b32 > 0.0 && b32 < b16 && b16 < b8, "{b32:e} {b16:e} {b8:e}");
        assert_eq!(
            b8 <= FIXED8_CORRECTION_MAX_BOUND,
            name == "voice coil",
            "{name}: {b8:e}"
        );
        let with = |storage| {
            let mut m = base.clone();
            m.set_correction_storage(storage);
            assert_eq!(m.correction_storage(), storage);
            m
        };
        let single = with(CorrectionStorage::Single);
        let mut double = single.clone();
        double.set_coupling_single(false);
        let mut fixed = base.clone();
        fixed.set_gram_fixed24(true);
        assert!(fixed.gram_fixed24() && !fixed.shapes_fixed24());
        let mut shapes = fixed.clone();
        shapes.set_shapes_fixed24(true);
        let m = [
            double,
            single,
            with(CorrectionStorage::Half),
            with(CorrectionStorage::Fixed8),
            base.clone(),
            fixed,
            shapes,
        ];
        let na = base.n_actuators();
        let fw = wind(na);
        let load: Vec<f64> = (0..na).map(|i| (i % 7) as f64).collect();
        for case in ["wind, command and pier", "static load", "pier vibration"] {
            let mut m = m.clone();
            let mut worst = [0.0f64; 6];
            let mut max_z = 0.0f64;
            // Whether each form's response differs from single precision's (half, 8 bits)
            // and from the default correction's (the 24-bit Gram matrices): each was read.
            let mut differs = [false; 4];
            let mut z = vec![vec![0.0; na]; m.len()];
            for k in 0..300 {
                let s = (k as f64 * 0.05).sin();
                let (u, f, p): (Vec<f64>, Vec<f64>, f64) = match case {
                    "static load" => (vec![0.0; na], load.clone(), 0.0),
                    "pier vibration" => (vec![0.0; na], vec![0.0; na], 1e-9 * (k as f64).sin()),
                    _ => (
                        (0..na).map(|i| 1e-8 * s * ((i % 5) as f64 - 2.0)).collect(),
                        fw.iter().map(|x| x * (1.0 + 0.3 * s)).collect(),
                        1e-9 * s,
                    ),
                };
                for (mi, zi) in m.iter_mut().zip(z.iter_mut()) {
                    mi.advance(1e-3, &u, &f, p).expect("step");
                    mi.mirror(zi);
                }
                max_z = z[0].iter().fold(max_z, |a, x| a.max(x.abs()));
                for (w, zi) in worst.iter_mut().zip(&z[1..]) {
                    *w = z[0]
                        .iter()
                        .zip(zi)
                        .fold(*w, |a, (x, y)| a.max((x - y).abs()));
                }
                differs[0] |= z[1] != z[2];
                differs[1] |= z[1] != z[3];
                differs[2] |= z[4] != z[5];
                differs[3] |= z[5] != z[6];
            }
            assert!(max_z > 0.0);
            let [single_err, half_err, fixed8_err, _, fixed_err, shapes_err] =
                worst.map(|w| w / max_z);
            eprintln!(
                "{name}, {case}: worst z against double precision, of its largest: single \
                 {single_err:.2e}, correction in half precision {half_err:.2e}, in 8 bits \
                 {fixed8_err:.2e}, and the Gram matrices in 24-bit fixed point (with the \
                 default correction) {fixed_err:.2e}, with the shapes so too {shapes_err:.2e}"
            );
            assert_eq!(differs, [true; 4], "{name}, {case}: a form not read");
            // The 24-bit Gram matrices move the response about as much as single precision
            // does (measured here: the voice coil's pier vibration 1.95e-7 against 9.8e-8, the
            // piezo's static load 2.1e-7 against 1.4e-7 and pier vibration 2.6e-7 against
            // 2.0e-7, the rest within 3 %; at 700 and 1000 modes the piezo's pier vibration
            // 3.0e-7 and 3.6e-7 against 2.0e-7).
            assert!(
                fixed_err <= 5e-7 && fixed_err <= 2.0 * single_err + 1e-7,
                "{name}, {case}: {fixed_err:e} {single_err:e}"
            );
            // The mode shapes in 24-bit fixed point on top of that, no more than twice single
            // precision either (measured: the voice coil 9.8e-9, 3.0e-7 and 2.3e-7 in the three
            // cases, the piezo 5.5e-8, 3.0e-7 and 3.4e-7; scaled by rows instead of columns,
            // the voice coil's static load 6.4e-7).
            assert!(
                shapes_err <= 5e-7 && shapes_err <= 2.0 * single_err + 1e-7,
                "{name}, {case}: {shapes_err:e} {single_err:e}"
            );
            // The cell's outputs, from the same shapes (two columns per kind), within
            // single precision's rounding of those from the shapes in single precision.
            let [.., fixed, shapes] = &mut m;
            let (zc, fc) = fixed.cell_outputs();
            let (zc, fc) = (zc.to_vec(), fc.to_vec());
            let (zs, fs) = shapes.cell_outputs();
            for (a, b) in [(&zc, zs), (&fc, fs)] {
                let top = a.iter().fold(0.0f64, |t, x| t.max(x.abs()));
                let worst = a
                    .iter()
                    .zip(b)
                    .fold(0.0f64, |w, (x, y)| w.max((x - y).abs()));
                assert!(
                    top > 0.0 && worst <= 1e-6 * top,
                    "{name}, {case}: {worst:e} of {top:e}"
                );
            }
            // The correction in fewer bits, where its bound allows them, no more than single
            // precision.
            let mut checked = vec![("half precision", half_err)];
            if b8 <= FIXED8_CORRECTION_MAX_BOUND {
                checked.push(("8 bits", fixed8_err));
            }
            for (form, err) in checked {
                assert!(
                    err <= 5e-7 && err <= 2.0 * single_err + 1e-8,
                    "{name}, {case}, {form}: {err:e} {single_err:e}"
                );
            }
        }
    }
}

/// The traffic a step counts (the benchmarks' memory floor) follows the Gram matrices' storage:
/// by half they stream a little over half of the whole matrices (the diagonal blocks whole,
/// the kinds' padding gone), in 24-bit fixed point three quarters of that, and only the
/// single-precision solve reads them so; the correction
/// in half precision, half of its bytes in single; the inputs' pass over the shapes only as
/// often as the inputs change.
#[test]
fn streamed_bytes_follow_the_gram_storage() {
    let (mut m, _) = keck(SegmentModel::voice_coil(), 96);
    m.set_coupling_single(true);
    let gram = |m: &CoupledMirror| {
        let s = m.streamed_per_step(m.tick_period(), 1).expect("one tick");
        let &(_, bytes, reads) = s
            .iter()
            .find(|(name, ..)| name.starts_with("Gram matrices"))
            .expect("the Gram matrices counted");
        assert_eq!(reads, 1.0);
        bytes as f64
    };
    m.set_gram_packed(false);
    let whole = gram(&m);
    m.set_gram_packed(true);
    let half = gram(&m);
    assert!(
        half > 0.45 * whole && half < 0.65 * whole,
        "{half} of {whole}"
    );
    // In 24-bit fixed point three quarters of that (and the padding the kernels read past
    // the last entry).
    m.set_gram_fixed24(true);
    let fixed = gram(&m);
    assert_eq!(fixed, 0.75 * half + 2.0 * Fixed24::PAD as f64);
    m.set_gram_fixed24(false);
    assert_eq!(gram(&m), half);
    m.set_coupling_single(false);
    assert_eq!(gram(&m), whole);
    // The correction in half precision streams half the bytes of single precision's.
    m.set_coupling_single(true);
    let correction = |m: &CoupledMirror| {
        let s = m.streamed_per_step(m.tick_period(), 1).expect("one tick");
        let &(name, bytes, reads) = s
            .iter()
            .find(|(name, ..)| name.starts_with("the solve's correction"))
            .expect("the correction counted");
        assert_eq!(reads, 1.0);
        (name, bytes)
    };
    assert_eq!(m.correction_storage(), CorrectionStorage::Single);
    let (name, single) = correction(&m);
    assert!(name.ends_with("(single precision)"));
    m.set_correction_storage(CorrectionStorage::Half);
    let (name, half) = correction(&m);
    assert!(
        name.ends_with("(half precision)") && 2 * half == single,
        "{half} {single}"
    );
    // In 8 bits a quarter.
    m.set_correction_storage(CorrectionStorage::Fixed8);
    let (name, fixed8) = correction(&m);
    assert!(
        name.ends_with("(8-bit fixed point)") && 4 * fixed8 == single,
        "{fixed8} {single}"
    );
    m.set_correction_storage(CorrectionStorage::Half);
    // The inputs' pass over the shapes counts only in the steps whose inputs change (every
    // tenth here), the displacement's pass back in every step; the ticks' matrices as before.
    let s = m.streamed_per_step(m.tick_period(), 10).expect("one tick");
    let reads = |prefix: &str| -> Vec<f64> {
        s.iter()
            .filter(|(name, ..)| name.starts_with(prefix))
            .map(|&(_, _, r)| r)
            .collect()
    };
    assert_eq!(reads("mode shapes by rows"), [0.1]);
    assert_eq!(reads("mode shapes by columns"), [1.0]);
    assert_eq!(reads("Gram matrices"), [1.0]);
    // The shapes by rows in 24-bit fixed point: three quarters of their bytes in single
    // precision (and the padding the kernels read past the last entry); the columns' copy the
    // pass back reads up to COLUMN_PASS_MAX_MODES modes stays in single precision.
    let rows_bytes = |m: &CoupledMirror| {
        let s = m.streamed_per_step(m.tick_period(), 10).expect("one tick");
        let rows: Vec<_> = s
            .iter()
            .filter(|(name, ..)| name.starts_with("mode shapes by rows"))
            .map(|&(name, bytes, _)| (name, bytes))
            .collect();
        assert_eq!(rows.len(), 1);
        rows[0]
    };
    let (name, single) = rows_bytes(&m);
    assert!(name.ends_with("(single precision)") && !m.shapes_fixed24());
    m.set_shapes_fixed24(true);
    let (name, fixed) = rows_bytes(&m);
    assert!(name.ends_with("24-bit fixed point") && m.shapes_fixed24());
    assert_eq!(4 * (fixed - Fixed24::PAD), 3 * single);
}

/// The automatic choice of threads: only between SHARED_CACHE_MIN_MODES and
/// TWO_THREADS_MIN_MODES modes does it try both, whatever it chooses the values are those of
/// one thread to the bit (over a trial and a re-check of the choice), and `set_two_threads`
/// ends it.
#[test]
fn the_automatic_choice_of_threads_changes_no_value() {
    let tmt = Layout::tmt();
    let cell = CellModel::new(&tmt, &CellParams::default())
        .expect("cell")
        .modes()
        .expect("modes");
    let new = |modes: usize| {
        CoupledMirror::new(
            tmt.n_segments(),
            SegmentModel::voice_coil(),
            cell.clone(),
            modes,
            0.02,
            1,
        )
        .expect("mirror")
    };
    let na = tmt.n_actuators();
    let (u, f) = (vec![1e-9; na], wind(na));
    // Outside the range the choice is the fixed one, before and after a check.
    for (modes, two) in [
        (SHARED_CACHE_MIN_MODES - 10, false),
        (TWO_THREADS_MIN_MODES, true),
    ] {
        let mut m = new(modes);
        assert!(m.threads_auto);
        for _ in 0..2 {
            m.advance(1e-3, &u, &f, 0.0).expect("step");
            assert_eq!(m.two_threads(), two, "{modes} modes");
        }
    }
    let mut auto = new(SHARED_CACHE_MIN_MODES);
    let mut one = auto.clone();
    one.set_two_threads(false);
    assert!(auto.threads_auto && !one.threads_auto);
    let (mut za, mut zo) = (vec![0.0; na], vec![0.0; na]);
    let mut used = [false; 2];
    for k in 0..=THREADS_CHECK_STEPS as usize {
        let s = (k as f64 * 0.05).sin();
        let fk: Vec<f64> = f.iter().map(|x| x * (1.0 + 0.3 * s)).collect();
        auto.advance(1e-3, &u, &fk, 0.0).expect("step");
        used[usize::from(auto.two_threads())] = true;
        one.advance(1e-3, &u, &fk, 0.0).expect("step");
        auto.mirror(&mut za);
        one.mirror(&mut zo);
        assert!(
            za.iter().zip(&zo).all(|(a, b)| a.to_bits() == b.to_bits()),
            "step {k}: the automatic choice ({} threads) moved a value",
            if auto.two_threads() { 2 } else { 1 }
        );
        assert!(!one.two_threads());
    }
    // The trial stepped on both.
    assert_eq!(used, [true, true]);
    // The hand-over itself is measured: positive, and bounded by the caller's patience.
    let h = auto.pair.get().expect("a helper").handoff_ns(5);
    assert!(h > 0.0 && h < 1e6, "hand-over {h} ns");
}

/// A mirror with the large models' forms (two threads, the Gram matrices by half and the mode
/// shapes in 24-bit fixed point, the correction in 8-bit fixed point) goes on after a round trip through its
/// serialised state (as an FMU's state is saved and restored, by `postcard`) with the outputs of
/// the original, to the bit, its inputs changing at every step.
#[test]
fn a_restored_mirror_goes_on_with_the_large_forms() {
    let (mut m, _) = keck(SegmentModel::voice_coil(), 96);
    m.set_coupling_single(true);
    m.set_two_threads(true);
    m.set_gram_packed(true);
    m.set_gram_fixed24(true);
    m.set_shapes_fixed24(true);
    m.set_correction_storage(CorrectionStorage::Fixed8);
    let na = m.n_actuators();
    let f = wind(na);
    let u = vec![0.0; na];
    m.advance(1e-3, &u, &f, 1e-9).expect("step");
    let bytes = postcard::to_stdvec(&m).expect("serialised");
    let mut restored: CoupledMirror = postcard::from_bytes(&bytes).expect("deserialised");
    assert!(restored.gram_fixed24() && restored.shapes_fixed24() && restored.two_threads());
    assert_eq!(restored.correction_storage(), CorrectionStorage::Fixed8);
    for k in 0..5 {
        let p = 1e-9 * (k as f64).cos();
        // The wind changes at every step: each step projects it onto the modes too.
        let f: Vec<f64> = f.iter().map(|x| x * (1.0 + 0.1 * k as f64)).collect();
        let (mut z0, mut z1) = (vec![0.0; na], vec![0.0; na]);
        m.advance(1e-3, &u, &f, p).expect("step");
        restored
            .advance(1e-3, &u, &f, p)
            .expect("step of the restored mirror");
        m.mirror(&mut z0);
        restored.mirror(&mut z1);
        assert!(z0.iter().any(|&v| v != 0.0));
        assert_eq!(z1, z0, "step {k}");
    }
}
