//! The first run's set-up without the on-disk cache (issue 18 item 3), piece by piece on TMT:
//! the built-in cell's assembly, its modes (the retained 30, 60, 147 and 300 alone by block
//! Lanczos, against the dense solve of all 1477; `CellModel::lowest_modes` solves up to 369
//! alone on TMT), and the wind screen's tables (TMT's default 1024 x 1024 screen, wind at 37
//! degrees). The cache is off throughout.
//!
//! `cargo bench -p m1 --bench setup`
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::linalg::cache::Store;
use m1::loads::wind::{WindLoads, WindParams};
use m1::plant::structure::{CellModel, CellParams};

fn bench(c: &mut Criterion) {
    let layout = Layout::tmt();
    let params = CellParams::tmt();
    let mut g = c.benchmark_group("tmt_setup");
    g.sample_size(10);
    g.bench_function("cell_assembly", |b| {
        b.iter(|| black_box(CellModel::new(&layout, &params).unwrap().ndof))
    });
    let cell = CellModel::new(&layout, &params).unwrap();
    for r in [30usize, 60, 147, 300] {
        g.bench_function(format!("lowest_modes/{r}"), |b| {
            b.iter(|| black_box(cell.lowest_modes_in(r, &Store::off()).unwrap().n_modes()))
        });
    }
    g.bench_function("every_mode_dense", |b| {
        b.iter(|| black_box(cell.modes_in(&Store::off()).unwrap().n_modes()))
    });
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout)).unwrap();
    let wind = WindParams {
        direction: 37.0,
        ..WindParams::default()
    };
    g.bench_function("wind_tables", |b| {
        b.iter(|| {
            black_box(
                WindLoads::new_in(&geometry, &wind, &Store::off())
                    .unwrap()
                    .expected_force_rms(),
            )
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
