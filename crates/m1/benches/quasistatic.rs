//! Wall time of the quasi-static analyses (issue 3) on the TMT mirror (492 segments, A is
//! 2772 x 1476), plus a few Keck figures for scale.
//!
//! Criterion cases:
//! - `a_build/<layout>`: `Geometry::new` + `a_matrix` (the geometry and the sparse A-matrix);
//!   `a_build/tmt_geometry_only` splits off the geometry.
//! - `svd_tmt/faer_thin_svd`: `thin_svd` of the dense A (U, S, V), faer's default parallelism
//!   (rayon's global pool, one thread per core); `faer_thin_svd_seq` the same on one thread;
//!   `faer_singular_values` the singular values only; `to_dense` the conversion alone.
//! - `reconstructor_<layout>/sparse_apply` and `dense_apply`: one `apply(&y)` per iteration
//!   (`sparse_apply_into`: into preallocated buffers, no allocation)
//!   (`dense_apply_seq`: the dense one with faer on one thread; the sparse one is sequential);
//!   `sparse_setup` (`SparseReconstructor::new`: A^T A, block Cholesky, constraint terms) and
//!   `dense_setup` (`DenseReconstructor::new` on the dense A: projection, SVD, B = V S^-1 U^T).
//!
//! After criterion, unless a filter that does not match `robustness` is given (or under
//! `--test`, `--list` or `--profile-time`), `main` times one run of `quasistatic::robustness`
//! on TMT with the default cases and parameters (100 realizations) with `std::time::Instant`,
//! and prints the total and the time of every case (from the progress callback: a case ends
//! when the running count of finished realizations reaches its cumulative total).
//!
//! Before criterion, `main` writes the dense TMT A (Fortran order) and faer's singular values
//! as NPY v1.0 files to `target/m1-bench/` (or `$M1_BENCH_OUT`) for `benches/numpy_svd.py`,
//! and prints a one-off accuracy check of faer's SVD and of sparse against dense `apply`.
//!
//! Run (from the workspace root):
//! - everything: `cargo bench -p m1 --bench quasistatic` (about 10 min on 2 cores);
//! - one part: `cargo bench -p m1 --bench quasistatic -- reconstructor_tmt` (criterion filter;
//!   the robustness timing is skipped), `... -- robustness` (robustness timing only) or
//!   `... -- 'reconstructor_keck|robustness'` (criterion takes a single regex filter);
//! - then `.venv/bin/python benches/numpy_svd.py`.

#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::hint::black_box;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use criterion::{Criterion, SamplingMode};
use faer::sparse::SparseColMat;
use faer::{Mat, Par};
use m1::analysis::quasistatic::{Case, RobustnessParams, robustness};
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::nominal::Nominal;
use m1::control::reconstructor::{DenseReconstructor, SparseReconstructor};
use m1::sensing::interaction::{a_matrix, global_ptt};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, StandardNormal};

/// Name under which the robustness timing is reported (and matched against filters).
const ROBUSTNESS_NAME: &str = "quasistatic_tmt/robustness_100";

fn geometry(layout: &Layout) -> Geometry {
    Geometry::new(layout, GeometryParams::for_layout(layout)).expect("geometry")
}

// ---------------------------------------------------------------------------------------------
// NPY v1.0 writer
// ---------------------------------------------------------------------------------------------

/// Writes an NPY v1.0 file of little-endian f64 values. `shape` is the array's shape and `data`
/// its values in Fortran (column-major) order when `fortran_order`, else in C order.
fn write_npy(path: &Path, shape: &[usize], fortran_order: bool, data: &[f64]) {
    assert_eq!(
        shape.iter().product::<usize>(),
        data.len(),
        "shape and data disagree"
    );
    let shape_str = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let dict = format!(
        "{{'descr': '<f8', 'fortran_order': {}, 'shape': {shape_str}, }}",
        if fortran_order { "True" } else { "False" }
    );
    // magic (6) + version (2) + header length (2) + dict + padding + '\n', a multiple of 64.
    let unpadded = 10 + dict.len() + 1;
    let pad = (64 - unpadded % 64) % 64;
    let header = format!("{dict}{}\n", " ".repeat(pad));
    let header_len = u16::try_from(header.len()).expect("NPY v1.0 header longer than 65535");
    let mut bytes = Vec::with_capacity(10 + header.len() + 8 * data.len());
    bytes.extend_from_slice(b"\x93NUMPY");
    bytes.extend_from_slice(&[1, 0]);
    bytes.extend_from_slice(&header_len.to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in data {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    let mut f = std::fs::File::create(path).expect("create npy file");
    f.write_all(&bytes).expect("write npy file");
}

/// A dense faer matrix as an NPY file (Fortran order: faer stores columns contiguously).
fn write_npy_mat(path: &Path, m: &Mat<f64>) {
    let mut data = Vec::with_capacity(m.nrows() * m.ncols());
    for j in 0..m.ncols() {
        for i in 0..m.nrows() {
            data.push(m[(i, j)]);
        }
    }
    write_npy(path, &[m.nrows(), m.ncols()], true, &data);
}

fn out_dir() -> PathBuf {
    let dir = std::env::var_os("M1_BENCH_OUT").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/m1-bench"),
        PathBuf::from,
    );
    std::fs::create_dir_all(&dir).expect("create the output directory");
    dir.canonicalize().unwrap_or(dir)
}

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

/// A realistic reading: y = A z + noise, z ~ N(0, 1 um) per actuator, noise ~ N(0, 1 nm).
fn reading(a: &SparseColMat<usize, f64>, seed: u64) -> Vec<f64> {
    let mut rng = StdRng::seed_from_u64(seed);
    let z: Vec<f64> = (0..a.ncols())
        .map(|_| {
            let x: f64 = StandardNormal.sample(&mut rng);
            1e-6 * x
        })
        .collect();
    let mut y: Vec<f64> = (0..a.nrows())
        .map(|_| {
            let x: f64 = StandardNormal.sample(&mut rng);
            1e-9 * x
        })
        .collect();
    for t in a.triplet_iter() {
        y[t.row] += t.val * z[t.col];
    }
    y
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// Median wall time of `n` calls of `f` (after one warm-up call).
fn median_time<R>(n: usize, mut f: impl FnMut() -> R) -> Duration {
    black_box(f());
    let mut t: Vec<Duration> = (0..n)
        .map(|_| {
            let t0 = Instant::now();
            black_box(f());
            t0.elapsed()
        })
        .collect();
    t.sort();
    t[n / 2]
}

/// Writes the NPY inputs of `benches/numpy_svd.py` and prints one-off accuracy checks.
fn prepare_and_check() {
    let layout = Layout::tmt();
    let g = geometry(&layout);
    let a = a_matrix(&g);
    let ad = a.to_dense();
    let dir = out_dir();
    let a_path = dir.join("a_tmt.npy");
    write_npy_mat(&a_path, &ad);
    let t0 = Instant::now();
    let svd = ad.thin_svd().expect("svd");
    let t_svd = t0.elapsed();
    let s = svd.S().column_vector();
    let sv: Vec<f64> = (0..s.nrows()).map(|i| s[i]).collect();
    let sv_path = dir.join("sv_faer_tmt.npy");
    write_npy(&sv_path, &[sv.len()], false, &sv);
    // Accuracy of the decomposition: ||A - U S V^T||_F / ||A||_F and ||V^T V - I||_max.
    let mut us = svd.U().to_owned();
    for j in 0..us.ncols() {
        for i in 0..us.nrows() {
            us[(i, j)] *= sv[j];
        }
    }
    let resid = &ad - &us * svd.V().transpose();
    let vtv = svd.V().transpose() * svd.V();
    let mut orth = 0.0f64;
    for j in 0..vtv.ncols() {
        for i in 0..vtv.nrows() {
            let d = if i == j { 1.0 } else { 0.0 };
            orth = orth.max((vtv[(i, j)] - d).abs());
        }
    }
    println!(
        "# TMT A: {} x {}, {} stored entries; wrote {} and {}",
        a.nrows(),
        a.ncols(),
        a.val().len(),
        a_path.display(),
        sv_path.display()
    );
    println!(
        "# faer thin SVD (one cold call, {:?}): {:.3} s; s_max = {:.6e}, s_min = {:.6e}, \
         ||A - U S V^T||_F / ||A||_F = {:.2e}, max |V^T V - I| = {:.2e}",
        faer::get_global_parallelism(),
        t_svd.as_secs_f64(),
        sv[0],
        sv[sv.len() - 1],
        resid.norm_l2() / ad.norm_l2(),
        orth
    );
    // Sparse against dense reconstructor on one reading.
    let null = global_ptt(&g);
    let sp = SparseReconstructor::new(&a, null.as_ref(), vec![]).expect("sparse");
    let de = DenseReconstructor::new(ad.as_ref(), null.as_ref(), 1e-10, &[]).expect("dense");
    let y = reading(&a, 7);
    let (zs, zd) = (sp.apply(&y), de.apply(&y));
    let diff: Vec<f64> = zs.iter().zip(&zd).map(|(p, q)| p - q).collect();
    println!(
        "# TMT reconstructors: dense keeps {} singular values; max |z_sparse - z_dense| / \
         max |z_dense| = {:.2e}",
        de.singular_values.len(),
        max_abs(&diff) / max_abs(&zd)
    );
    let t_sp = median_time(201, || sp.apply(&y));
    let t_de = median_time(51, || de.apply(&y));
    println!(
        "# TMT apply, median of plain timings: sparse {:.1} us, dense {:.1} us, dense/sparse = \
         {:.1}",
        t_sp.as_secs_f64() * 1e6,
        t_de.as_secs_f64() * 1e6,
        t_de.as_secs_f64() / t_sp.as_secs_f64()
    );
}

// ---------------------------------------------------------------------------------------------
// Criterion cases
// ---------------------------------------------------------------------------------------------

fn bench_a_build(c: &mut Criterion) {
    let mut group = c.benchmark_group("a_build");
    group.sample_size(20);
    for (name, layout) in [("tmt", Layout::tmt()), ("keck", Layout::keck())] {
        group.bench_function(name, |b| {
            b.iter(|| {
                let g =
                    Geometry::new(&layout, GeometryParams::for_layout(&layout)).expect("geometry");
                a_matrix(black_box(&g))
            });
        });
    }
    let layout = Layout::tmt();
    group.bench_function("tmt_geometry_only", |b| {
        b.iter(|| Geometry::new(black_box(&layout), GeometryParams::for_layout(&layout)));
    });
    group.finish();
}

fn bench_svd(c: &mut Criterion) {
    let g = geometry(&Layout::tmt());
    let a = a_matrix(&g);
    let ad = a.to_dense();
    let mut group = c.benchmark_group("svd_tmt");
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(2));
    // Flat sampling, 10 s: one call per sample for the 1-3 s SVDs (linear sampling would make
    // 55 calls).
    group.sampling_mode(SamplingMode::Flat);
    group.measurement_time(Duration::from_secs(10));
    group.bench_function("to_dense", |b| b.iter(|| black_box(&a).to_dense()));
    group.bench_function("faer_thin_svd", |b| {
        b.iter(|| black_box(&ad).thin_svd().expect("svd"));
    });
    group.bench_function("faer_singular_values", |b| {
        b.iter(|| black_box(&ad).singular_values().expect("svd"));
    });
    let par = faer::get_global_parallelism();
    faer::set_global_parallelism(Par::Seq);
    group.bench_function("faer_thin_svd_seq", |b| {
        b.iter(|| black_box(&ad).thin_svd().expect("svd"));
    });
    faer::set_global_parallelism(par);
    group.finish();
}

fn bench_reconstructors(c: &mut Criterion) {
    for (name, layout) in [("tmt", Layout::tmt()), ("keck", Layout::keck())] {
        let g = geometry(&layout);
        let a = a_matrix(&g);
        let ad = a.to_dense();
        let null = global_ptt(&g);
        let sp = SparseReconstructor::new(&a, null.as_ref(), vec![]).expect("sparse");
        let de = DenseReconstructor::new(ad.as_ref(), null.as_ref(), 1e-10, &[]).expect("dense");
        let y = reading(&a, 11);
        let mut group = c.benchmark_group(format!("reconstructor_{name}"));
        // 100 samples of the dense apply (~1.3 ms for TMT) need ~7 s.
        group.measurement_time(Duration::from_secs(10));
        group.bench_function("sparse_apply", |b| b.iter(|| sp.apply(black_box(&y))));
        // Into preallocated buffers, as the global controller uses it.
        let (mut z, mut work) = (vec![0.0; a.ncols()], vec![0.0; sp.work_len()]);
        group.bench_function("sparse_apply_into", |b| {
            b.iter(|| sp.apply_into(black_box(&y), &mut z, &mut work))
        });
        group.bench_function("dense_apply", |b| b.iter(|| de.apply(black_box(&y))));
        // The same on one thread (faer's matrix-vector product is parallel by default).
        let par = faer::get_global_parallelism();
        faer::set_global_parallelism(Par::Seq);
        group.bench_function("dense_apply_seq", |b| b.iter(|| de.apply(black_box(&y))));
        faer::set_global_parallelism(par);
        group.sample_size(10);
        group.bench_function("sparse_setup", |b| {
            b.iter(|| SparseReconstructor::new(black_box(&a), null.as_ref(), vec![]))
        });
        group.sampling_mode(SamplingMode::Flat);
        group.measurement_time(Duration::from_secs(10));
        group.bench_function("dense_setup", |b| {
            b.iter(|| DenseReconstructor::new(black_box(ad.as_ref()), null.as_ref(), 1e-10, &[]))
        });
        group.finish();
    }
}

// ---------------------------------------------------------------------------------------------
// Robustness: one plain timed run
// ---------------------------------------------------------------------------------------------

fn time_robustness() {
    let threads = rayon::current_num_threads();
    println!("\n{ROBUSTNESS_NAME}: one run, rayon threads = {threads}");
    let t0 = Instant::now();
    let g = geometry(&Layout::tmt());
    let nominal = Nominal::new(g).expect("nominal");
    let t_nominal = t0.elapsed();
    println!(
        "  Nominal::new (geometry, A, B0, focus-mode): {:.3} s",
        t_nominal.as_secs_f64()
    );
    let params = RobustnessParams::default();
    let t0 = Instant::now();
    let gamma = nominal.with_focus_gain(1.0 / params.focus_gain_factor);
    black_box(gamma.expect("gamma"));
    println!(
        "  with_focus_gain (the Gamma reconstructor, built once inside robustness): {:.3} s",
        t0.elapsed().as_secs_f64()
    );
    let cases = Case::defaults();
    let counts: Vec<usize> = cases
        .iter()
        .map(|c| params.realizations_of(&c.perturbation))
        .collect();
    let cumulative: Vec<usize> = counts
        .iter()
        .scan(0, |s, n| {
            *s += n;
            Some(*s)
        })
        .collect();
    let ends: Mutex<Vec<(usize, Instant)>> = Mutex::new(Vec::new());
    let progress = |k: usize, _total: usize| {
        if cumulative.contains(&k) {
            ends.lock().unwrap().push((k, Instant::now()));
        }
    };
    let start = Instant::now();
    let results = robustness(&nominal, &cases, &params, &progress).expect("robustness");
    let total = start.elapsed();
    let mut ends = ends.into_inner().unwrap();
    ends.sort_by_key(|e| e.0);
    assert_eq!(ends.len(), cases.len());
    println!(
        "  robustness, {} cases, {} realizations in all: {:.2} s (requirement: < 60 s for 100 \
         realizations)",
        cases.len(),
        cumulative.last().copied().unwrap_or(0),
        total.as_secs_f64()
    );
    println!(
        "  {:<18} {:>5} {:>9} {:>12}   {:>10} {:>10} {:>10} {:>9}",
        "case", "n", "time s", "ms/realiz.", "rho worst", "sigma", "sigma_G", "unstable"
    );
    let mut prev = start;
    for ((case, &(_, end)), r) in cases.iter().zip(&ends).zip(&results) {
        let dt = end - prev;
        prev = end;
        println!(
            "  {:<18} {:>5} {:>9.2} {:>12.1}   {:>10.3e} {:>10.4} {:>10.4} {:>9.2}",
            case.name,
            r.realizations,
            dt.as_secs_f64(),
            1e3 * dt.as_secs_f64() / r.realizations as f64,
            r.rho_q_minus_i.worst,
            r.sigma_q.worst,
            r.sigma_gamma_q.worst,
            r.unstable_fraction
        );
    }
    println!("  (the first case includes building the Gamma reconstructor)");
}

// ---------------------------------------------------------------------------------------------
// main
// ---------------------------------------------------------------------------------------------

/// Criterion options that take a value (so the value is not mistaken for a filter).
const VALUE_OPTIONS: &[&str] = &[
    "--save-baseline",
    "-s",
    "--baseline",
    "-b",
    "--baseline-lenient",
    "--load-baseline",
    "--sample-size",
    "--warm-up-time",
    "--measurement-time",
    "--nresamples",
    "--noise-threshold",
    "--confidence-level",
    "--significance-level",
    "--profile-time",
    "--plotting-backend",
    "--output-format",
    "--format",
    "--color",
    "-c",
];

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut filters = Vec::new();
    let mut skip = false;
    for a in &args {
        if skip {
            skip = false;
        } else if VALUE_OPTIONS.contains(&a.as_str()) {
            skip = true;
        } else if !a.starts_with('-') {
            filters.push(a.clone());
        }
    }
    // No extra work when criterion only tests, lists or profiles the cases.
    let quick = args
        .iter()
        .any(|a| a == "--test" || a == "--list" || a == "--profile-time");
    // A part runs when no filter is given or an alternative of the filter (criterion takes one
    // regex; `|` separates alternatives) and its name contain one another.
    let matches = |name: &str| {
        filters.is_empty()
            || filters
                .iter()
                .flat_map(|f| f.split('|'))
                .any(|f| name.contains(f) || f.contains(name))
    };

    if !quick && (matches("svd_tmt") || matches("reconstructor_tmt")) {
        prepare_and_check();
    }
    let mut c = Criterion::default().configure_from_args();
    bench_a_build(&mut c);
    bench_svd(&mut c);
    bench_reconstructors(&mut c);
    c.final_summary();
    if !quick && matches(ROBUSTNESS_NAME) {
        time_robustness();
    }
}
