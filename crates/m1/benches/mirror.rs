//! The coupled mirror (`m1::plant::mirror::CoupledMirror`): one 1 ms communication step (5 servo
//! periods, each with its coupled solve) of the TMT and Keck mirrors on the built-in cell, for
//! several numbers of retained modes and both actuator kinds; and the quasi-static mirror
//! (`m1::plant::static_mirror`) on TMT, with the wind changing every step and every tenth step.
//! Wind forces change every step unless said. The coupled mirror's step is read as the standard
//! system reads it, the mirror's displacement only (the cell's displacement and force are
//! computed when read: a two-column pass over the shapes more). `voicecoil`: the coupled solve's
//! matrices in double precision; `voicecoil_single`: in single precision
//! (`CoupledMirror::set_coupling_single`); `piezo`: the default for the retained modes (single
//! precision from `SINGLE_COUPLING_MIN_MODES`).
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
use criterion::{Criterion, criterion_group, criterion_main};
use m1::aperture::layout::Layout;
use m1::plant::mirror::CoupledMirror;
use m1::plant::segment::SegmentModel;
use m1::plant::static_mirror::QuasiStaticMirror;
use m1::plant::structure::{CellModel, CellParams};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let mut g = c.benchmark_group("mirror_1ms");
    for (name, layout, modes) in [
        ("keck", Layout::keck(), vec![60usize]),
        ("tmt", Layout::tmt(), vec![60, 150, 300, 1000]),
    ] {
        let cell = CellModel::new(&layout, &CellParams::default())
            .and_then(|c| c.modes())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let n = layout.n_segments();
        let na = 3 * n;
        for &r in &modes {
            for (variant, model, single) in [
                ("voicecoil", SegmentModel::voice_coil(), Some(false)),
                ("voicecoil_single", SegmentModel::voice_coil(), Some(true)),
                ("piezo", SegmentModel::piezo(), None),
            ] {
                let mut m = CoupledMirror::new(n, model, cell.clone(), r, 0.02, 1)
                    .unwrap_or_else(|e| panic!("{name}: {e}"));
                if let Some(single) = single {
                    m.set_coupling_single(single);
                }
                let u = vec![0.0; na];
                let mut f: Vec<f64> = (0..na).map(|i| (i % 7) as f64).collect();
                let mut z = vec![0.0; na];
                let mut k = 0u64;
                g.bench_function(format!("{name}/{r}_modes/{variant}"), |b| {
                    b.iter(|| {
                        k += 1;
                        f[(k as usize) % na] += 0.1;
                        m.advance(1e-3, &u, &f, 1e-9 * (k as f64).sin())
                            .unwrap_or_else(|e| panic!("{e}"));
                        m.mirror(&mut z);
                        black_box(z[0])
                    })
                });
            }
        }
    }
    let layout = Layout::tmt();
    let cell = CellModel::new(&layout, &CellParams::default())
        .and_then(|c| c.modes())
        .unwrap_or_else(|e| panic!("tmt: {e}"));
    let na = layout.n_actuators();
    let mut m = QuasiStaticMirror::new(layout.n_segments(), SegmentModel::voice_coil(), cell, 60)
        .unwrap_or_else(|e| panic!("{e}"));
    let u = vec![0.0; na];
    let mut f: Vec<f64> = (0..na).map(|i| (i % 7) as f64).collect();
    for every in [1u64, 10] {
        let mut k = 0u64;
        g.bench_function(format!("tmt/quasi_static/wind_every_{every}"), |b| {
            b.iter(|| {
                k += 1;
                if k.is_multiple_of(every) {
                    f[(k as usize) % na] += 0.1;
                }
                m.advance(1e-3, &u, &f, 0.0)
                    .unwrap_or_else(|e| panic!("{e}"));
                black_box(m.cell_displacement()[0])
            })
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
