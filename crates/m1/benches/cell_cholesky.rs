//! The FE mirror cell's static solves (issue 15 item 6): the envelope (skyline) Cholesky of
//! `m1::linalg::skyline` against faer's sparse Cholesky, on the TMT cell's stiffness matrix
//! (`CellParams::tmt()`, 1477 degrees of freedom). Factorisation (from the dense matrix the cell
//! assembles, as the model does; faer also from its sparse matrix alone) and one solve.
//!
//! `cargo bench -p m1 --bench cell_cholesky`
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use faer::{Mat, Side};

use m1::aperture::layout::Layout;
use m1::linalg::skyline::Skyline;
use m1::plant::structure::{CellModel, CellParams};

/// The lower triangle of the dense row-major `k` as a sparse matrix.
fn sparse_lower(n: usize, k: &[f64]) -> SparseColMat<usize, f64> {
    let mut t = Vec::new();
    for i in 0..n {
        for j in 0..=i {
            let v = k[i * n + j];
            if v != 0.0 {
                t.push(Triplet::new(i, j, v));
            }
        }
    }
    SparseColMat::try_new_from_triplets(n, n, &t).expect("sparse")
}

fn bench(c: &mut Criterion) {
    let cell = CellModel::new(&Layout::tmt(), &CellParams::tmt()).expect("cell");
    let (n, k) = (cell.ndof, cell.stiffness.as_slice());
    let b: Vec<f64> = (0..n).map(|i| (0.37 * i as f64).sin()).collect();
    let sparse = sparse_lower(n, k);
    let skyline = Skyline::factor(n, k).expect("skyline");
    let llt = sparse.sp_cholesky(Side::Lower).expect("faer");
    // The two agree before either is timed.
    let mut x = b.clone();
    skyline.solve_in_place(&mut x);
    let mut y = Mat::from_fn(n, 1, |i, _| b[i]);
    llt.solve_in_place(y.as_mut());
    let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let diff = (0..n).fold(0.0f64, |m, i| m.max((x[i] - y[(i, 0)]).abs()));
    assert!(
        diff <= 1e-9 * scale,
        "skyline and faer disagree: {diff:e} of {scale:e}"
    );
    eprintln!(
        "TMT cell: n = {n}, non-zeros in the lower triangle {}, skyline envelope {}",
        sparse.compute_nnz(),
        skyline.stored()
    );

    let mut g = c.benchmark_group("cell_cholesky/tmt");
    g.sample_size(20);
    g.bench_function("skyline/factor_from_dense", |bn| {
        bn.iter(|| Skyline::factor(n, black_box(k)).expect("factor"))
    });
    g.bench_function("faer_sparse/factor_from_dense", |bn| {
        bn.iter(|| {
            sparse_lower(n, black_box(k))
                .sp_cholesky(Side::Lower)
                .expect("factor")
        })
    });
    g.bench_function("faer_sparse/factor_from_sparse", |bn| {
        bn.iter(|| black_box(&sparse).sp_cholesky(Side::Lower).expect("factor"))
    });
    let mut x = b.clone();
    g.bench_function("skyline/solve", |bn| {
        bn.iter(|| {
            x.copy_from_slice(&b);
            skyline.solve_in_place(black_box(&mut x));
        })
    });
    let mut y = Mat::from_fn(n, 1, |i, _| b[i]);
    g.bench_function("faer_sparse/solve", |bn| {
        bn.iter(|| {
            for i in 0..n {
                y[(i, 0)] = b[i];
            }
            llt.solve_in_place(black_box(y.as_mut()));
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
