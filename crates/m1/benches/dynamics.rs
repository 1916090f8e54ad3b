//! The frequency-domain studies of issue 6 on the TMT mirror and its built-in cell, per
//! frequency point: the monolithic model's response to the pier (`FrequencyModel::pier_response`,
//! one r x r complex LU), the exact all-segment servo-loop sensitivity (`ActuatorLoop`:
//! closed-loop modal stiffness and Lanczos) at a separated peak (10.49 Hz) and in the band where
//! the top singular values cluster (40 Hz), and one global-loop point (`GlobalCsi::point`:
//! Zernike bases to degree 8 and all segments, 3 images each side). And the factorisation of
//! the closed-loop modal stiffness (complex symmetric, 300 and 1000 modes, at 10.49 Hz):
//! `ModalFactor` ($L D L^T$ without pivoting, its growth test) against faer's pivoted LU of the
//! same matrix, one thread each; and a Lanczos step's pair of solves with each (`solve_pair`:
//! the packed $L D L^T$, the LU's factors by columns).
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]
use criterion::{Criterion, criterion_group, criterion_main};
use faer::c64;
use m1::analysis::csi::ActuatorLoop;
use m1::analysis::global_csi::GlobalCsi;
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::ControllerParams;
use m1::linalg::complex_symmetric::ModalFactor;
use m1::plant::monolithic::FrequencyModel;
use m1::plant::segment::SegmentModel;
use m1::plant::structure::{CellModel, CellParams};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let layout = Layout::tmt();
    let n = layout.n_segments();
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
    let cell = CellModel::new(&layout, &CellParams::default())
        .and_then(|c| c.modes())
        .unwrap();
    let mut g = c.benchmark_group("tmt_frequency_point");
    g.sample_size(10);
    for r in [60usize, 500] {
        let fm = FrequencyModel::new(n, SegmentModel::voice_coil(), cell.clone(), r, 0.02).unwrap();
        g.bench_function(format!("pier_response/{r}_modes"), |b| {
            b.iter(|| black_box(fm.pier_response(black_box(29.6)).unwrap().mirror[0]))
        });
        let lp = ActuatorLoop::new(fm.clone(), &layout, &geometry, 8, &[1]).unwrap();
        for f in [10.49, 40.0] {
            g.bench_function(format!("servo_all_segments/{r}_modes/{f}_hz"), |b| {
                b.iter(|| black_box(lp.all_sensitivity(black_box(f), 1.0).unwrap()))
            });
        }
        if r <= 100 {
            let gl =
                GlobalCsi::new(fm, &layout, &geometry, ControllerParams::default(), 8, 3).unwrap();
            g.bench_function(format!("global_point/{r}_modes"), |b| {
                b.iter(|| black_box(gl.point(black_box(8.95)).unwrap().0.loop_gain))
            });
        }
    }
    g.finish();
    // One thread each: faer's LU would otherwise split its products over the pool.
    let par = faer::get_global_parallelism();
    faer::set_global_parallelism(faer::Par::Seq);
    let mut g = c.benchmark_group("tmt_modal_factor");
    g.sample_size(10);
    for r in [300usize, 1000] {
        let fm = FrequencyModel::new(n, SegmentModel::voice_coil(), cell.clone(), r, 0.02).unwrap();
        let ch = fm.channels(10.49);
        // The stiffness whole (faer's LU reads it) and by its lower triangle (the L D L^T's).
        g.bench_function(format!("stiffness/full/{r}_modes"), |b| {
            b.iter(|| black_box(fm.modal_stiffness(black_box(10.49), &ch)))
        });
        g.bench_function(format!("stiffness/lower/{r}_modes"), |b| {
            b.iter(|| black_box(fm.modal_stiffness_lower(black_box(10.49), &ch)))
        });
        let k = fm.modal_stiffness(10.49, &ch);
        assert!(ModalFactor::new(|| k.clone()).is_ldlt());
        g.bench_function(format!("ldlt/{r}_modes"), |b| {
            b.iter(|| black_box(ModalFactor::new(|| k.clone())))
        });
        g.bench_function(format!("faer_lu/{r}_modes"), |b| {
            b.iter(|| black_box(k.partial_piv_lu()))
        });
        // One Lanczos step's two solves (K^-1 x, then K^-H x): the packed L D L^T against
        // faer's LU factors solved by columns (`lu_solve`, as the LU fallback does).
        let rhs: Vec<c64> = (0..r)
            .map(|i| c64::new((0.3 * i as f64).sin(), (0.7 * i as f64).cos()))
            .collect();
        let mut work = Vec::new();
        let ldlt = ModalFactor::new(|| k.clone());
        let lu = ModalFactor::Lu(k.partial_piv_lu());
        for (name, f) in [("ldlt_packed", &ldlt), ("lu", &lu)] {
            g.bench_function(format!("solve_pair/{name}/{r}_modes"), |b| {
                let mut x = rhs.clone();
                b.iter(|| {
                    f.solve_in_place(&mut x, &mut work);
                    f.solve_adjoint_in_place(&mut x, &mut work);
                    black_box(x[0])
                })
            });
        }
    }
    g.finish();
    faer::set_global_parallelism(par);
}

criterion_group!(benches, bench);
criterion_main!(benches);
