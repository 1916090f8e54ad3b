//! Every component of the standard wind closed loop (`m1cs run`: wind -> mirror -> edge sensors
//! -> controller, with the optics metrics) next to its arithmetic or memory floor.
//!
//! For each component, in the same process:
//! 1. its real time per communication step, driven in-process through [`fmu::Instance`] exactly
//!    as the master drives it (`set_real` of its connected inputs, `do_step(t, h)`, `get_real`
//!    of its outputs), with inputs that change at every step, after a warm-up;
//! 2. a floor: the arithmetic or memory traffic the component cannot avoid, as a plain kernel
//!    on data of the same sizes;
//! 3. their ratio.
//!
//! | component | step | floor |
//! |---|---|---|
//! | mirror (`mirror_voicecoil`, each `--modes`; its wind forces changing every 10 steps and its command every 50, as in the standard system) | 1 ms | memory: the matrices one step streams ([`m1::plant::mirror::CoupledMirror::streamed_per_step`]: the inputs' pass over the shapes in the steps whose inputs change), as separate single-precision buffers summed with SIMD as often and in the mirror's order (the ticks' matrices in turn, tick by tick), on one core and, for a mirror on two threads, on both at once (each its half of every buffer); arithmetic: the multiply-adds of a step ([`m1::plant::mirror::CoupledMirror::multiply_adds_per_step`]) as independent fused multiply-adds in registers at the peak rate, on one core and, for a mirror on two threads, on both at once (each half of them) |
//! | edge sensors | 1 ms | arithmetic: one multiply-add per non-zero of `y = H z`, `gap = g0 + G z` at the peak rate; memory: the non-zeros and `z` read once (a plain CSR product with the same non-zeros is timed too, for scale, in the JSON) |
//! | optics | 1 ms | metrics: one dot-product pass over `z`; PSSN: the FFTs of one evaluation (`m1::optics::pssn`) in the precision of the FMU's `pssn_single_precision`, and with `OtfMethod::Correlation` (the default's choice) its complex multiply-adds at the peak rate, per step |
//! | wind | 10 ms (100 Hz) | streaming the table entries one sample interpolates and the forces it writes |
//! | master | 1 ms | an estimate of the data work on its thread: the finite check's read of the Real outputs of the steps it takes, a copy of the mirror's displacement per step handed to the look-ahead thread without it (into a buffer the other core read last, the cheaper way: values that must reach the other core), a cache line's round trip between the cores per step handed over (the fractions from the runs below); its own time from `m1cs run` (below) |
//!
//! Each measurement runs in `BLOCKS` blocks of equal length (about 1.5 s in all unless
//! `--steps` fixes the steps per block) and reports the median time per step and the minimum.
//! The optics blocks are whole numbers of PSSN periods, so the PSSN evaluations are averaged
//! over the steps.
//!
//! Run (release profile; `--bench` from cargo and unknown flags are ignored):
//!
//! ```text
//! cargo bench --bench floors -- [--layout tmt|keck] [--modes 60,300] [--steps N] [--json PATH]
//!     [--fmu-dir DIR]
//! ```
//!
//! The master's own time is its wall time outside the FMUs' calls in the standard system,
//! measured in the same run by [`MASTER_RUNS`] invocations of this package's `m1cs run --json
//! --no-plots` (5 s of wind, open and closed loop, the default modes) on the FMUs packaged in
//! `--fmu-dir` (default `target/fmu`, written by `cargo xtask package LAYOUT`): per run
//! `master_share` x the loop time over the steps. Without the packaged FMUs the row says so.
#![allow(clippy::expect_used, clippy::unwrap_used, clippy::panic)]

use std::hint::black_box;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use cosim::system::{CopyWay, copy_for_other_core};
use faer::sparse::SparseColMat;
use fmu::{Instance, Model};
use m1::aperture::layout::Layout;
use m1::loads::wind::WindParams;
use m1::optics::pssn::{OtfMethod, Pssn, PssnParams};
use rustfft::num_complex::Complex;
use serde_json::{Value, json};

/// Blocks per measurement (the median and the minimum are taken over them).
const BLOCKS: usize = 7;
/// Wall time of a measurement's blocks when `--steps` is not given (s).
const TARGET_SECONDS: f64 = 1.5;
/// Warm-up before each measurement (it also estimates the cost of a step).
const WARM_UP: Duration = Duration::from_millis(150);
/// Precomputed input vectors cycled through, so that the inputs change at every step at no
/// cost to the timed loop.
const VARIANTS: usize = 8;
/// The base communication step of the standard system (s).
const STEP: f64 = 1e-3;
/// The wind FMU's step in the standard system (100 Hz) (s).
const WIND_STEP: f64 = 1e-2;

struct Args {
    layout: String,
    modes: Vec<i32>,
    steps: Option<usize>,
    json: Option<PathBuf>,
    fmu_dir: PathBuf,
}

fn parse_args() -> Args {
    let mut a = Args {
        layout: "tmt".into(),
        modes: vec![60, 300],
        steps: None,
        json: None,
        fmu_dir: PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/fmu"),
    };
    let mut it = std::env::args().skip(1);
    while let Some(arg) = it.next() {
        let (flag, inline) = match arg.split_once('=') {
            Some((f, v)) => (f.to_string(), Some(v.to_string())),
            None => (arg.clone(), None),
        };
        let mut value = |name: &str| {
            inline
                .clone()
                .or_else(|| it.next())
                .unwrap_or_else(|| panic!("{name} needs a value"))
        };
        match flag.as_str() {
            "--layout" => a.layout = value("--layout"),
            "--modes" => {
                a.modes = value("--modes")
                    .split(',')
                    .map(|m| {
                        m.trim()
                            .parse()
                            .unwrap_or_else(|e| panic!("--modes {m}: {e}"))
                    })
                    .collect()
            }
            "--steps" => {
                let s = value("--steps");
                a.steps = Some(s.parse().unwrap_or_else(|e| panic!("--steps {s}: {e}")))
            }
            "--json" => a.json = Some(PathBuf::from(value("--json"))),
            "--fmu-dir" => a.fmu_dir = PathBuf::from(value("--fmu-dir")),
            // `cargo bench` passes `--bench`; anything else unknown is ignored too.
            _ => {}
        }
    }
    a
}

/// Time per step of one measurement (s).
#[derive(Debug, Clone, Copy)]
struct Stats {
    median: f64,
    min: f64,
    /// Steps per block.
    steps: usize,
}

impl Stats {
    fn scaled(self, k: f64) -> Stats {
        Stats {
            median: self.median * k,
            min: self.min * k,
            steps: self.steps,
        }
    }

    fn json(self) -> Value {
        json!({
            "median_us": self.median * 1e6,
            "min_us": self.min * 1e6,
            "steps_per_block": self.steps,
            "blocks": BLOCKS,
        })
    }
}

/// Runs `run(n)` (n steps) in [`BLOCKS`] blocks of a whole number of `granule` steps, after a
/// warm-up.
fn measure(fixed_steps: Option<usize>, granule: usize, mut run: impl FnMut(usize)) -> Stats {
    let granule = granule.max(1);
    let start = Instant::now();
    let mut done = 0;
    while done == 0 || start.elapsed() < WARM_UP {
        run(granule);
        done += granule;
    }
    let per_step = start.elapsed().as_secs_f64() / done as f64;
    let wanted =
        fixed_steps.unwrap_or_else(|| (TARGET_SECONDS / BLOCKS as f64 / per_step).ceil() as usize);
    let steps = wanted.max(1).div_ceil(granule) * granule;
    let t: Vec<f64> = (0..BLOCKS)
        .map(|_| {
            let s = Instant::now();
            run(steps);
            s.elapsed().as_secs_f64() / steps as f64
        })
        .collect();
    let stats = stats_of(&t).expect("BLOCKS > 0");
    Stats { steps, ..stats }
}

/// One line of the table.
struct Row {
    component: &'static str,
    case: String,
    /// The component's time per step (None: not measured here).
    time: Option<Stats>,
    floor: Stats,
    basis: String,
    details: Value,
}

impl Row {
    fn ratio(&self) -> Option<f64> {
        self.time.map(|t| t.median / self.floor.median)
    }
}

// ---------------------------------------------------------------------------------------------
// Driving an FMU in-process.

/// An initialised instance of model `M` for `variant`, its parameters set by `configure` first.
fn instance<M: Model>(variant: &str, configure: impl FnOnce(&mut Instance<M>)) -> Instance<M> {
    let id = M::INFO.model_identifier;
    let (table, _) = M::new(variant).unwrap_or_else(|e| panic!("{id} {variant}: {e}"));
    let guid = fmu::xml::guid(&M::INFO, &table);
    let mut fmu = Instance::<M>::new("floors", &guid, None, None, false)
        .unwrap_or_else(|e| panic!("{id}: instantiate: {e}"));
    configure(&mut fmu);
    fmu.setup_experiment(0.0, None)
        .unwrap_or_else(|e| panic!("{id}: setup: {e}"));
    fmu.enter_initialization_mode()
        .unwrap_or_else(|e| panic!("{id}: initialisation mode: {e}"));
    fmu.exit_initialization_mode()
        .unwrap_or_else(|e| panic!("{id}: initialise: {e}"));
    fmu
}

/// The value references of every scalar of variable `name`.
fn vrs<M: Model>(fmu: &Instance<M>, name: &str) -> Vec<u32> {
    let v = fmu
        .table()
        .by_name(name)
        .unwrap_or_else(|| panic!("{}: no variable {name}", M::INFO.model_identifier));
    (v.vr..v.vr + v.len as u32).collect()
}

fn set_integer<M: Model>(fmu: &mut Instance<M>, name: &str, x: i32) {
    let vr = vrs(fmu, name);
    fmu.set_integer(&vr, &[x])
        .unwrap_or_else(|e| panic!("set {name}: {e}"));
}

fn set_real<M: Model>(fmu: &mut Instance<M>, name: &str, x: f64) {
    let vr = vrs(fmu, name);
    fmu.set_real(&vr, &[x])
        .unwrap_or_else(|e| panic!("set {name}: {e}"));
}

fn get_scalar<M: Model>(fmu: &mut Instance<M>, name: &str) -> f64 {
    let vr = vrs(fmu, name);
    let mut x = [f64::NAN];
    fmu.get_real(&vr, &mut x)
        .unwrap_or_else(|e| panic!("get {name}: {e}"));
    x[0]
}

/// One step: `set_real` of each input, `do_step(t, h)`, `get_real` of each output.
fn step<M: Model>(
    fmu: &mut Instance<M>,
    h: f64,
    inputs: &[(&[u32], &[f64])],
    outputs: &mut [(&[u32], &mut [f64])],
) {
    for (vr, x) in inputs {
        fmu.set_real(vr, x).expect("set_real of an input");
    }
    let t = fmu.time();
    fmu.do_step(t, h).expect("do_step");
    for (vr, out) in outputs.iter_mut() {
        fmu.get_real(vr, out).expect("get_real of an output");
    }
    black_box(outputs);
}

/// [`VARIANTS`] versions of a vector of length `n`: a fixed pattern of amplitude `scale`, each
/// version perturbed by a different 1 %.
fn variants(n: usize, scale: f64) -> Vec<Vec<f64>> {
    (0..VARIANTS)
        .map(|k| {
            (0..n)
                .map(|i| {
                    let x = i as f64;
                    scale
                        * ((0.731 * x).sin()
                            + 0.3 * (2.17 * x).cos()
                            + 0.01 * (0.37 * x + k as f64).sin())
                })
                .collect()
        })
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Floor kernels.

/// Sum of a single-precision buffer in SIMD, eight independent accumulators: a pure read of
/// the buffer at the bandwidth of wherever it lives.
struct Sum<'a>(&'a [f32]);

impl pulp::WithSimd for Sum<'_> {
    type Output = f32;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) -> f32 {
        let (head, tail) = S::as_simd_f32s(self.0);
        let zero = simd.splat_f32s(0.0);
        let mut acc = [zero; 8];
        let mut chunks = head.chunks_exact(8);
        for c in &mut chunks {
            for (a, &v) in acc.iter_mut().zip(c) {
                *a = simd.add_f32s(*a, v);
            }
        }
        let mut total = zero;
        for a in acc {
            total = simd.add_f32s(total, a);
        }
        for &v in chunks.remainder() {
            total = simd.add_f32s(total, v);
        }
        simd.reduce_sum_f32s(total) + tail.iter().sum::<f32>()
    }
}

/// `n` rounds of fused multiply-adds on `CHAINS` independent vectors of double precision held
/// in registers: the machine's peak rate of multiply-adds, with nothing read from memory.
struct Fmas(usize);

/// Independent chains of [`Fmas`]: enough to cover the latency of a fused multiply-add at two
/// per cycle.
const CHAINS: usize = 10;

impl pulp::WithSimd for Fmas {
    type Output = f64;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) -> f64 {
        let a = simd.splat_f64s(black_box(0.999_999));
        let b = simd.splat_f64s(black_box(1e-9));
        let mut acc: [S::f64s; CHAINS] =
            std::array::from_fn(|i| simd.splat_f64s(black_box(i as f64)));
        for _ in 0..self.0 {
            for v in acc.iter_mut() {
                *v = simd.mul_add_f64s(*v, a, b);
            }
        }
        let mut total = simd.splat_f64s(0.0);
        for v in acc {
            total = simd.add_f64s(total, v);
        }
        simd.reduce_sum_f64s(total)
    }
}

/// Lanes of a double-precision vector on this processor.
struct F64Lanes;

impl pulp::WithSimd for F64Lanes {
    type Output = usize;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> usize {
        std::mem::size_of::<S::f64s>() / std::mem::size_of::<f64>()
    }
}

/// Runs `fmas` double-precision fused multiply-adds (rounded up to whole rounds of vectors) at
/// the peak rate: the arithmetic floor of that much work.
fn multiply_adds(arch: pulp::Arch, fmas: u64) -> f64 {
    let per_round = (CHAINS * arch.dispatch(F64Lanes)) as u64;
    arch.dispatch(Fmas(fmas.div_ceil(per_round) as usize))
}

fn stream(arch: pulp::Arch, x: &[f32]) -> f32 {
    arch.dispatch(Sum(x))
}

/// Streams `n` steps of the mirror's buffers `(buffer, mean reads per step)` in the order its
/// step reads them: a buffer read less than once per step (the inputs' pass over the shapes)
/// whenever a whole read is owed, and those read at every servo tick in turn, tick by tick (the
/// Gram matrices, then the correction, then the Gram matrices again...), so that a buffer
/// stays in a cache only as long as it does in the mirror.
fn stream_steps(arch: pulp::Arch, buffers: &[(&[f32], f64)], n: usize) -> f32 {
    let mut owed = vec![0.0; buffers.len()];
    let mut now = vec![0u32; buffers.len()];
    let mut s = 0.0;
    for _ in 0..n {
        for ((_, reads), (owed, now)) in buffers.iter().zip(owed.iter_mut().zip(now.iter_mut())) {
            *owed += *reads;
            *now = (*owed + 1e-9).floor() as u32;
            *owed -= f64::from(*now);
        }
        while now.iter().any(|&k| k > 0) {
            for ((b, _), k) in buffers.iter().zip(now.iter_mut()) {
                if *k > 0 {
                    s += stream(arch, black_box(b));
                    *k -= 1;
                }
            }
        }
    }
    s
}

/// A buffer of `bytes` bytes of single-precision values (rounded up to whole values).
fn buffer(bytes: usize) -> Vec<f32> {
    (0..bytes.div_ceil(4))
        .map(|i| 1e-3 * (i % 97) as f32)
        .collect()
}

/// A row-major sparse matrix (compressed rows, 32-bit column indices), with `L` values per
/// non-zero (`L` matrices on one pattern).
struct Csr<const L: usize> {
    ptr: Vec<usize>,
    col: Vec<u32>,
    val: Vec<[f64; L]>,
}

impl<const L: usize> Csr<L> {
    /// The matrices `a` (same shape) on the pattern of the first, by rows (the others' values
    /// at the same entries; [`SensorCsr`] checks the patterns agree).
    fn from_csc(a: [&SparseColMat<usize, f64>; L]) -> Self {
        let s = a[0].symbolic();
        let (cp, ri) = (s.col_ptr(), s.row_idx());
        let m = a[0].nrows();
        let mut ptr = vec![0usize; m + 1];
        for j in 0..a[0].ncols() {
            for &r in &ri[cp[j]..cp[j + 1]] {
                ptr[r + 1] += 1;
            }
        }
        for r in 0..m {
            ptr[r + 1] += ptr[r];
        }
        let nnz = ptr[m];
        let (mut col, mut val) = (vec![0u32; nnz], vec![[0.0; L]; nnz]);
        let mut next = ptr.clone();
        for j in 0..a[0].ncols() {
            for k in cp[j]..cp[j + 1] {
                let d = &mut next[ri[k]];
                col[*d] = u32::try_from(j).expect("columns fit in u32");
                val[*d] = std::array::from_fn(|l| a[l].val()[k]);
                *d += 1;
            }
        }
        Csr { ptr, col, val }
    }

    fn nnz(&self) -> usize {
        self.val.len()
    }

    fn bytes(&self) -> usize {
        8 * self.ptr.len() + 4 * self.col.len() + 8 * L * self.val.len()
    }

    /// `y_l = offset_l + A_l x`, one dot per row (the `L` sums of a row together).
    #[inline(always)]
    fn mul(&self, x: &[f64], offset: [f64; L], mut y: [&mut [f64]; L]) {
        let rows = y.iter().map(|yl| yl.len()).min().unwrap_or(0);
        for r in 0..rows {
            let (a, b) = (self.ptr[r], self.ptr[r + 1]);
            let mut s = offset;
            for (v, &c) in self.val[a..b].iter().zip(&self.col[a..b]) {
                let xc = x[c as usize];
                for (sl, vl) in s.iter_mut().zip(v) {
                    *sl += vl * xc;
                }
            }
            for (yl, sl) in y.iter_mut().zip(s) {
                yl[r] = sl;
            }
        }
    }
}

/// The sensors' `z` operators by rows: `H` and `G` fused on one pattern when they share it
/// (one column index and one `x` read for both), otherwise apart.
struct SensorCsr {
    fused: bool,
    both: Csr<2>,
    height: Csr<1>,
    gap: Csr<1>,
    nnz_height: usize,
    nnz_gap: usize,
}

impl SensorCsr {
    fn new(h: &SparseColMat<usize, f64>, g: &SparseColMat<usize, f64>) -> Self {
        let (height, gap) = (Csr::from_csc([h]), Csr::from_csc([g]));
        let fused = height.ptr == gap.ptr && height.col == gap.col;
        let both = if fused {
            Csr::from_csc([h, g])
        } else {
            Csr {
                ptr: vec![0],
                col: Vec::new(),
                val: Vec::new(),
            }
        };
        let (nnz_height, nnz_gap) = (height.nnz(), gap.nnz());
        SensorCsr {
            fused,
            both,
            height,
            gap,
            nnz_height,
            nnz_gap,
        }
    }

    fn bytes(&self) -> usize {
        if self.fused {
            self.both.bytes()
        } else {
            self.height.bytes() + self.gap.bytes()
        }
    }

    /// `y = H x`, `gap = g0 + G x`.
    #[inline(never)]
    fn mul(&self, x: &[f64], g0: f64, y: &mut [f64], gap: &mut [f64]) {
        if self.fused {
            self.both.mul(x, [0.0, g0], [y, gap]);
        } else {
            self.height.mul(x, [0.0], [y]);
            self.gap.mul(x, [g0], [gap]);
        }
    }
}

/// `(sum x w, sum x^2)` in one pass, four accumulators each.
#[inline(never)]
fn dot_pass(x: &[f64], w: &[f64]) -> (f64, f64) {
    let (mut s, mut q) = ([0.0; 4], [0.0; 4]);
    let (xc, wc) = (x.chunks_exact(4), w.chunks_exact(4));
    let (xr, wr) = (xc.remainder(), wc.remainder());
    for (a, b) in xc.zip(wc) {
        for l in 0..4 {
            s[l] += a[l] * b[l];
            q[l] += a[l] * a[l];
        }
    }
    let (mut s, mut q) = (s.iter().sum::<f64>(), q.iter().sum::<f64>());
    for (a, b) in xr.iter().zip(wr) {
        s += a * b;
        q += a * a;
    }
    (s, q)
}

fn mb(bytes: f64) -> String {
    if bytes >= 1e6 {
        format!("{:.2} MB", bytes / 1e6)
    } else {
        format!("{:.1} kB", bytes / 1e3)
    }
}

// ---------------------------------------------------------------------------------------------
// The components.

fn mirror(layout: &str, modes: i32, steps: Option<usize>, arch: pulp::Arch, rows: &mut Vec<Row>) {
    let t0 = Instant::now();
    let mut fmu = instance::<mirror::VoiceCoil>(layout, |f| set_integer(f, "n_modes", modes));
    let setup = t0.elapsed().as_secs_f64();
    let solver = fmu
        .running()
        .and_then(|r| r.solver())
        .expect("the mirror FMU runs the coupled solver");
    let retained = solver.structure().n_modes();
    // Whether the mirror splits its products between two threads now (its default from 500
    // modes; between 150 and 500 its timed trial decides while it runs).
    let two_threads = solver.two_threads();
    let streamed = solver
        .streamed_per_step(STEP, WIND_EVERY as u64)
        .expect("the mirror's streamed matrices");
    let arithmetic = solver
        .multiply_adds_per_step(STEP, WIND_EVERY as u64)
        .expect("the mirror's multiply-adds");
    eprintln!("mirror, {modes} modes ({retained} retained): set up in {setup:.2} s");
    let (u, f, p, z) = (
        vrs(&fmu, "u_cmd"),
        vrs(&fmu, "f_wind"),
        vrs(&fmu, "pier_z"),
        vrs(&fmu, "z"),
    );
    let na = u.len();
    let (us, fs) = (variants(na, 1e-7), variants(na, 0.5));
    let ps: Vec<[f64; 1]> = (0..VARIANTS).map(|k| [1e-9 * (k as f64 - 3.5)]).collect();
    let mut out = vec![0.0; na];
    let mut k = 0;
    // The inputs at the standard wind system's rates: the wind forces from the 100 Hz wind,
    // the command from the 20 Hz controller, the pier changing at every step (it reaches the
    // modes only).
    let time = measure(steps, 1, |n| {
        for _ in 0..n {
            let (jw, ju, jp) = (
                (k / WIND_EVERY as usize) % VARIANTS,
                (k / CONTROLLER_EVERY as usize) % VARIANTS,
                k % VARIANTS,
            );
            k += 1;
            step(
                &mut fmu,
                STEP,
                &[(&u, &us[ju]), (&f, &fs[jw]), (&p, &ps[jp])],
                &mut [(&z, &mut out)],
            );
        }
    });
    drop(fmu);

    let buffers: Vec<(Vec<f32>, f64)> = streamed
        .iter()
        .map(|&(_, bytes, reads)| (buffer(bytes), reads))
        .collect();
    let bytes: f64 = streamed.iter().map(|&(_, b, r)| b as f64 * r).sum();
    let footprint: usize = streamed.iter().map(|&(_, b, _)| b).sum();
    let whole: Vec<(&[f32], f64)> = buffers.iter().map(|(b, r)| (b.as_slice(), *r)).collect();
    let floor = measure(steps, 1, |n| {
        black_box(stream_steps(arch, &whole, n));
    });
    // The same traffic on both cores at once: each thread streams its half of every buffer as
    // often, with no hand-over between them (what two cores' caches and memory deliver
    // together; the mirror on two threads cannot stream faster).
    let halves: [Vec<(&[f32], f64)>; 2] = std::array::from_fn(|h| {
        buffers
            .iter()
            .map(|(b, reads)| {
                let (lo, hi) = b.split_at(b.len() / 2);
                (if h == 0 { lo } else { hi }, *reads)
            })
            .collect()
    });
    let floor2 = two_threads.then(|| {
        measure(steps, 1, |n| {
            std::thread::scope(|scope| {
                scope.spawn(|| black_box(stream_steps(arch, &halves[1], n)));
                black_box(stream_steps(arch, &halves[0], n));
            });
        })
    });
    // Single-precision multiply-adds count half: a vector holds twice as many.
    let fmas: u64 = arithmetic
        .iter()
        .map(|&(_, n, single)| if single { n.div_ceil(2) } else { n })
        .sum();
    let compute = measure(steps, 1, |n| {
        for _ in 0..n {
            black_box(multiply_adds(arch, black_box(fmas)));
        }
    });
    // The same multiply-adds on both cores at once, each half of them (the mirror on two
    // threads cannot compute faster).
    let compute2 = two_threads.then(|| {
        let half = fmas.div_ceil(2);
        measure(steps, 1, |n| {
            std::thread::scope(|scope| {
                scope.spawn(|| {
                    for _ in 0..n {
                        black_box(multiply_adds(arch, black_box(half)));
                    }
                });
                for _ in 0..n {
                    black_box(multiply_adds(arch, black_box(half)));
                }
            });
        })
    });
    let (floor_gbs, component_gbs) = (bytes / floor.median / 1e9, bytes / time.median / 1e9);
    rows.push(Row {
        component: "mirror",
        case: format!("voice coil, {modes} modes ({retained} retained), 1 ms step"),
        time: Some(time),
        floor,
        basis: format!(
            "{} streamed per step ({} of buffers) at {floor_gbs:.1} GB/s; component {component_gbs:.1} GB/s",
            mb(bytes),
            mb(footprint as f64),
        ),
        details: json!({
            "modes": modes,
            "retained_modes": retained,
            "setup_s": setup,
            "bytes_per_step": bytes,
            "buffer_bytes": footprint,
            "floor_gb_per_s": floor_gbs,
            "component_gb_per_s": component_gbs,
            "streamed": streamed
                .iter()
                .map(|&(name, b, r)| json!({"matrix": name, "bytes": b, "reads_per_step": r}))
                .collect::<Vec<_>>(),
        }),
    });
    if let Some(floor2) = floor2 {
        let gbs = bytes / floor2.median / 1e9;
        rows.push(Row {
            component: "mirror",
            case: format!(
                "voice coil, {modes} modes ({retained} retained), 1 ms step, on its two threads"
            ),
            time: Some(time),
            floor: floor2,
            basis: format!(
                "{} streamed per step by two cores at once, each half of every buffer, at {gbs:.1} GB/s together",
                mb(bytes),
            ),
            details: json!({
                "modes": modes,
                "bytes_per_step": bytes,
                "floor_gb_per_s": gbs,
                "threads": 2,
            }),
        });
    }
    rows.push(Row {
        component: "mirror",
        case: format!("voice coil, {modes} modes ({retained} retained), 1 ms step"),
        time: Some(time),
        floor: compute,
        basis: format!(
            "arithmetic: {:.2} M double-precision multiply-adds per step (single precision at half) at the peak rate ({:.1} G/s)",
            fmas as f64 / 1e6,
            fmas as f64 / compute.median / 1e9,
        ),
        details: json!({
            "modes": modes,
            "multiply_adds_per_step": fmas,
            "peak_multiply_adds_per_s": fmas as f64 / compute.median,
            "parts": arithmetic
                .iter()
                .map(|&(name, n, single)| json!({"part": name, "multiply_adds": n, "single_precision": single}))
                .collect::<Vec<_>>(),
        }),
    });
    if let Some(compute2) = compute2 {
        rows.push(Row {
            component: "mirror",
            case: format!(
                "voice coil, {modes} modes ({retained} retained), 1 ms step, on its two threads"
            ),
            time: Some(time),
            floor: compute2,
            basis: format!(
                "arithmetic: the same {:.2} M multiply-adds by two cores at once, each half, at {:.1} G/s together",
                fmas as f64 / 1e6,
                fmas as f64 / compute2.median / 1e9,
            ),
            details: json!({
                "modes": modes,
                "multiply_adds_per_step": fmas,
                "peak_multiply_adds_per_s": fmas as f64 / compute2.median,
                "threads": 2,
            }),
        });
    }
}

fn edge_sensors(layout: &str, steps: Option<usize>, arch: pulp::Arch, rows: &mut Vec<Row>) {
    let t0 = Instant::now();
    let mut fmu = instance::<edge_sensors_model::EdgeSensorsModel>(layout, |_| {});
    let setup = t0.elapsed().as_secs_f64();
    eprintln!("edge sensors: set up in {setup:.2} s");
    let (z, y, gap) = (vrs(&fmu, "z"), vrs(&fmu, "y"), vrs(&fmu, "gap"));
    let (na, ns) = (z.len(), y.len());
    let zs = variants(na, 1e-7);
    let sensors = fmu.running().expect("initialised").edge_sensors();
    let a = SensorCsr::new(sensors.height_matrix(), sensors.gap_matrices().0);
    let g0 = sensors.nominal_gap();
    let (mut yo, mut go) = (vec![0.0; ns], vec![0.0; ns]);
    let mut k = 0;
    let time = measure(steps, 1, |n| {
        for _ in 0..n {
            let j = k % VARIANTS;
            k += 1;
            step(
                &mut fmu,
                STEP,
                &[(&z, &zs[j])],
                &mut [(&y, &mut yo), (&gap, &mut go)],
            );
        }
    });
    let mut k = 0;
    let csr = measure(steps, 1, |n| {
        for _ in 0..n {
            let x = black_box(&zs[k % VARIANTS]);
            k += 1;
            a.mul(x, g0, &mut yo, &mut go);
            black_box((&yo, &go));
        }
    });
    // The arithmetic: one multiply-add per non-zero, at the peak rate.
    let fmas = (a.nnz_height + a.nnz_gap) as u64;
    let arithmetic = measure(steps, 1, |n| {
        for _ in 0..n {
            black_box(multiply_adds(arch, fmas));
        }
    });
    // The traffic no kernel avoids: the non-zero coefficients read once, z read, y and gap
    // written.
    let coefficients = 8 * (a.nnz_height + a.nnz_gap);
    let values = buffer(coefficients + 8 * na);
    let memory = measure(steps, 1, |n| {
        for _ in 0..n {
            let s = f64::from(stream(arch, black_box(&values)));
            yo.fill(s);
            go.fill(s);
            black_box((&yo, &go));
        }
    });
    let case = format!("{ns} sensors (y and gap) from z, 1 ms step");
    let details = json!({
        "setup_s": setup,
        "n_sensors": ns,
        "nnz_height": a.nnz_height,
        "nnz_gap": a.nnz_gap,
        "same_pattern": a.fused,
        "csr_bytes": a.bytes(),
        // For scale only: a plain CSR product with the same non-zeros, one dot per row (the
        // component's row kernel is faster, so it is no floor).
        "csr_reference": csr.json(),
        "arithmetic_floor": arithmetic.json(),
        "memory_floor": memory.json(),
    });
    rows.push(Row {
        component: "edge sensors",
        case: case.clone(),
        time: Some(time),
        floor: arithmetic,
        basis: format!(
            "arithmetic: y = H z, gap = g0 + G z, one multiply-add per non-zero ({} + {}{}) at \
             the peak rate",
            a.nnz_height,
            a.nnz_gap,
            if a.fused {
                ", H and G on one pattern"
            } else {
                ""
            },
        ),
        details: details.clone(),
    });
    rows.push(Row {
        component: "edge sensors",
        case,
        time: Some(time),
        floor: memory,
        basis: format!(
            "memory: the {} non-zero coefficients and z read once ({}), y and gap written",
            a.nnz_height + a.nnz_gap,
            mb((coefficients + 8 * na) as f64)
        ),
        details,
    });
}

fn optics(layout: &str, steps: Option<usize>, arch: pulp::Arch, rows: &mut Vec<Row>) {
    let t0 = Instant::now();
    let mut fmu = instance::<optics_model::Optics>(layout, |_| {});
    let setup = t0.elapsed().as_secs_f64();
    let mut metrics_only = instance::<optics_model::Optics>(layout, |f| {
        set_real(f, "pssn_rate", 0.0);
    });
    eprintln!("optics: set up in {setup:.2} s");
    let pssn_rate = get_scalar(&mut fmu, "pssn_rate");
    let metrics_rate = get_scalar(&mut fmu, "metrics_rate");
    let single = {
        let mut b = [false];
        fmu.get_boolean(&vrs(&fmu, "pssn_single_precision"), &mut b)
            .unwrap_or_else(|e| panic!("get pssn_single_precision: {e}"));
        b[0]
    };
    let per_pssn = ((1.0 / pssn_rate) / STEP).round().max(1.0) as usize;
    let z = vrs(&fmu, "z");
    let na = z.len();
    let names = [
        "rms_surface",
        "focus_mode",
        "rms_surface_without_focus",
        "pssn",
        "focus_mode_coefficient",
    ];
    let outs: Vec<Vec<u32>> = names.iter().map(|n| vrs(&fmu, n)).collect();
    let zs = variants(na, 1e-7);
    let mut values = vec![[0.0f64; 1]; outs.len()];
    let mut run = |fmu: &mut Instance<optics_model::Optics>, granule: usize| {
        let mut k = 0;
        measure(steps, granule, |n| {
            let mut o: Vec<(&[u32], &mut [f64])> = outs
                .iter()
                .zip(values.iter_mut())
                .map(|(v, x)| (v.as_slice(), x.as_mut_slice()))
                .collect();
            for _ in 0..n {
                let j = k % VARIANTS;
                k += 1;
                step(fmu, STEP, &[(&z, &zs[j])], &mut o);
            }
        })
    };
    let with_pssn = run(&mut fmu, per_pssn);
    let metrics = run(&mut metrics_only, 1);
    drop((fmu, metrics_only));

    // Metrics floor: one pass over z with its arithmetic.
    let w = variants(na, 1.0).swap_remove(0);
    let mut k = 0;
    let metrics_floor = measure(steps, 1, |n| {
        for _ in 0..n {
            let x = black_box(&zs[k % VARIANTS]);
            k += 1;
            black_box(dot_pass(x, &w));
        }
    });

    // PSSN floor: the FFTs of one evaluation in the precision of its transforms, and for the
    // correlation its multiply-adds at the peak rate.
    let params = PssnParams::default();
    let pssn = Pssn::new(&Layout::preset(layout).expect("layout"), params).expect("PSSN");
    let (n, m, p) = (pssn.grid().samples(), pssn.fft_size(), pssn.row_fft_size());
    let (lag_rows, method) = (pssn.otf_lag_rows(), pssn.otf_method());
    drop(pssn);
    let half = m / 2;
    let evals = steps.map(|s| s.div_ceil(per_pssn));
    let plan: Vec<(usize, usize)> = match method {
        OtfMethod::Correlation => vec![(p, n), (p, lag_rows)],
        OtfMethod::Transforms => vec![(m, n), (m, m), (m, half), (m, lag_rows)],
    };
    let ffts = if single {
        fft_floor::<f32>(&plan, evals)
    } else {
        fft_floor::<f64>(&plan, evals)
    };
    let transforms: usize = plan.iter().map(|&(_, count)| count).sum();
    let precision = if single { "single" } else { "double" };
    // The correlation: 4 real multiply-adds per complex one, for every pair of rows y, y + y'
    // and column; in single precision a vector holds twice the lanes (counted at half).
    let complex_macs: usize = match method {
        OtfMethod::Correlation => (0..lag_rows.min(n)).map(|lag| (n - lag) * p).sum(),
        OtfMethod::Transforms => 0,
    };
    let fmas = 4 * complex_macs as u64 / if single { 2 } else { 1 };
    let arithmetic = if fmas > 0 {
        measure(evals, 1, |reps| {
            for _ in 0..reps {
                black_box(multiply_adds(arch, black_box(fmas)));
            }
        })
    } else {
        Stats {
            median: 0.0,
            min: 0.0,
            steps: 1,
        }
    };
    let fft_per_eval = Stats {
        median: ffts.median + arithmetic.median,
        min: ffts.min + arithmetic.min,
        steps: ffts.steps,
    };
    let fft_basis = match method {
        OtfMethod::Correlation => format!(
            "{transforms} complex FFTs of {p} in {precision} precision ({n} field rows, {lag_rows} \
             OTF lag rows) and the correlation's {:.2} M complex multiply-adds at the peak rate \
             per evaluation",
            complex_macs as f64 / 1e6
        ),
        OtfMethod::Transforms => format!(
            "{transforms} complex FFTs of {m} in {precision} precision ({n} field rows, {m} \
             columns, {half} packed PSF rows, {lag_rows} OTF lag rows) per evaluation"
        ),
    };
    let pssn_floor = fft_per_eval.scaled(1.0 / per_pssn as f64);
    let combined = Stats {
        median: metrics_floor.median + pssn_floor.median,
        min: metrics_floor.min + pssn_floor.min,
        steps: metrics_floor.steps,
    };
    let details = json!({
        "setup_s": setup,
        "metrics_rate_hz": metrics_rate,
        "pssn_rate_hz": pssn_rate,
        "steps_per_pssn": per_pssn,
        "pssn_samples": n,
        "fft_size": m,
        "row_fft_size": p,
        "otf_method": format!("{method:?}"),
        "lag_rows": lag_rows,
        "ffts_per_evaluation": transforms,
        "correlation_complex_multiply_adds": complex_macs,
        "ffts_alone_per_evaluation": ffts.json(),
        "correlation_at_peak": arithmetic.json(),
        "pssn_single_precision": single,
        "metrics_floor": metrics_floor.json(),
        "fft_per_evaluation": fft_per_eval.json(),
    });
    rows.push(Row {
        component: "optics",
        case: format!(
            "metrics at {metrics_rate} Hz + PSSN at {pssn_rate} Hz, 1 ms step (averaged over \
             {} PSSN periods per block)",
            with_pssn.steps / per_pssn
        ),
        time: Some(with_pssn),
        floor: combined,
        basis: format!("one pass over z ({na} values) + FFTs / {per_pssn} steps: {fft_basis}"),
        details: details.clone(),
    });
    rows.push(Row {
        component: "optics",
        case: "metrics only (pssn_rate 0), 1 ms step".into(),
        time: Some(metrics),
        floor: metrics_floor,
        basis: format!("one dot-product pass over z ({na} values)"),
        details: details.clone(),
    });
    // One PSSN evaluation, from the difference of the two runs.
    let eval = Stats {
        median: (with_pssn.median - metrics.median) * per_pssn as f64,
        min: (with_pssn.min - metrics.min).max(0.0) * per_pssn as f64,
        steps: with_pssn.steps,
    };
    rows.push(Row {
        component: "optics",
        case: "one PSSN evaluation (difference of the two rows above x steps per PSSN)".into(),
        time: Some(eval),
        floor: fft_per_eval,
        basis: fft_basis,
        details,
    });
}

/// The FFTs of one PSSN evaluation in the precision `T` of its transforms, `plan` listing
/// (size, count) (for the correlation: the field rows and the OTF's lag rows), planned once, on
/// buffers of the evaluation's sizes: `evals` evaluations (or as many as the measurement takes).
fn fft_floor<T: rustfft::FftNum>(plan: &[(usize, usize)], evals: Option<usize>) -> Stats {
    let mut planner = rustfft::FftPlanner::<T>::new();
    let zero = Complex::new(T::zero(), T::zero());
    // Per (size, count): the plan and `count` rows of zeros (the cost of a transform does not
    // depend on the values: zeros keep the repeated in-place transforms finite).
    let mut work: Vec<_> = plan
        .iter()
        .map(|&(size, count)| {
            let fft = planner.plan_fft_forward(size);
            let scratch = vec![zero; fft.get_inplace_scratch_len()];
            (fft, vec![zero; size * count], scratch)
        })
        .collect();
    measure(evals, 1, |reps| {
        for _ in 0..reps {
            for (fft, rows, scratch) in work.iter_mut() {
                fft.process_with_scratch(rows, scratch);
                black_box(&rows);
            }
        }
    })
}

fn wind(layout: &str, steps: Option<usize>, arch: pulp::Arch, rows: &mut Vec<Row>) {
    let t0 = Instant::now();
    let mut fmu = instance::<wind_model::Wind>(layout, |f| {
        set_real(f, "wind_speed", WindParams::default().speed);
    });
    let setup = t0.elapsed().as_secs_f64();
    eprintln!("wind: set up in {setup:.2} s");
    let f = vrs(&fmu, "f_wind");
    let na = f.len();
    let nseg = na / 3;
    let mut out = vec![0.0; na];
    let time = measure(steps, 1, |n| {
        for _ in 0..n {
            step(&mut fmu, WIND_STEP, &[], &mut [(&f, &mut out)]);
        }
    });
    // Per segment a sample reads 4 entries of each of its 3 tables (cubic interpolation), its
    // 3 x 3 map to the actuator forces and its position along the flow; it writes 3 forces,
    // which get_real reads back.
    let read = nseg * (3 * 4 * 8 + 9 * 8 + 8);
    let tables = buffer(read);
    let mut forces = vec![0.0f64; na];
    let mut copy = vec![0.0f64; na];
    let floor = measure(steps, 1, |n| {
        for _ in 0..n {
            let s = f64::from(stream(arch, black_box(&tables)));
            forces.fill(s);
            copy.copy_from_slice(black_box(&forces));
            black_box(&copy);
        }
    });
    let basis = format!(
        "{} read (table entries, maps) + {} of forces written and read back",
        mb(read as f64),
        mb((8 * na) as f64)
    );
    let details = json!({
        "setup_s": setup,
        "step_s": WIND_STEP,
        "bytes_read": read,
        "bytes_forces": 8 * na,
    });
    rows.push(Row {
        component: "wind",
        case: "100 Hz: per 10 ms step".into(),
        time: Some(time),
        floor,
        basis: basis.clone(),
        details: details.clone(),
    });
    let per_second = 1.0 / WIND_STEP;
    rows.push(Row {
        component: "wind",
        case: format!("100 Hz: per simulated second ({per_second} steps)"),
        time: Some(time.scaled(per_second)),
        floor: floor.scaled(per_second),
        basis,
        details,
    });
}

/// The master's copy of `n` values into a buffer that a thread on the other core has just
/// read, its stores drained (a full fence), the way `way` says (as the master hands a step's
/// inputs to its look-ahead thread: into the buffer of the previous hand-over, which that
/// thread read): [`CROSS_CORE_COPIES`] copies, each after the other thread read the buffer;
/// their median and minimum (s per copy).
fn cross_core_copy(n: usize, way: CopyWay) -> Stats {
    use std::sync::Mutex;
    use std::sync::atomic::{AtomicU64, Ordering, fence};
    let buf = Mutex::new(vec![0.0f64; n]);
    // Odd: the reader's turn to read the buffer; even: the writer's to copy into it.
    let turn = AtomicU64::new(0);
    let src: Vec<f64> = (0..n).map(|i| i as f64).collect();
    let mut t = Vec::with_capacity(CROSS_CORE_COPIES);
    std::thread::scope(|s| {
        s.spawn(|| {
            for r in 0..CROSS_CORE_COPIES as u64 {
                while turn.load(Ordering::Acquire) != 2 * r + 1 {
                    std::hint::spin_loop();
                }
                let sum: f64 = buf.lock().unwrap().iter().sum();
                black_box(sum);
                turn.store(2 * r + 2, Ordering::Release);
            }
        });
        for r in 0..CROSS_CORE_COPIES as u64 {
            turn.store(2 * r + 1, Ordering::Release);
            while turn.load(Ordering::Acquire) != 2 * r + 2 {
                std::hint::spin_loop();
            }
            let mut b = buf.lock().unwrap();
            let t0 = Instant::now();
            copy_for_other_core(&mut b, black_box(&src), way);
            fence(Ordering::SeqCst);
            t.push(t0.elapsed().as_secs_f64());
        }
    });
    stats_of(&t).expect("copies")
}

/// Copies timed by [`cross_core_copy`].
const CROSS_CORE_COPIES: usize = 4000;

/// [`cross_core_copy`]'s times for the JSON (one sample per copy, not blocks of steps).
fn copies_json(s: Stats) -> Value {
    json!({
        "median_us": s.median * 1e6,
        "min_us": s.min * 1e6,
        "copies": s.steps,
    })
}

/// The standard system's rates in base steps (`m1cs run`): the wind at 100 Hz, the controller
/// at 20 Hz, the mirror, the edge sensors and the optics at every 1 ms step.
const WIND_EVERY: f64 = 10.0;
const CONTROLLER_EVERY: f64 = 50.0;

/// The master's own time in the standard system next to the data work its thread does there
/// (an estimate of its floor: what it would take if its scheduling cost nothing), per step:
/// - the finite check's read of the Real outputs of the steps taken on its thread: `mirror.z`
///   at every step, `sensors.y` at the steps not handed to the look-ahead thread, `wind.f_wind`
///   at 100 Hz and `controller.u_cmd` at 20 Hz (the optics always step on the look-ahead
///   thread, and a check runs on the thread that steps the component);
/// - a copy of `mirror.z` for each step it hands over whose inputs the look-ahead thread does
///   not already hold (every sensors step handed over, and every optics step not taken from the
///   memo), into a buffer the other core read last, the cheaper of the two ways the master
///   chooses between ([`cross_core_copy`]): the values must reach the other core, and the
///   lines they go into are that core's;
/// - a cache line's round trip between the cores per step handed over (its message and the
///   reply; the master does not always wait for it, so this term is the estimate's loosest).
///
/// The fractions of steps handed over and taken from the memo come from the runs.
fn master(
    layout: &str,
    steps: Option<usize>,
    arch: pulp::Arch,
    fmu_dir: &std::path::Path,
    rows: &mut Vec<Row>,
) {
    let l = Layout::preset(layout).expect("layout");
    let (na, ns) = (l.n_actuators(), l.n_sensors());
    // Each value read once with the processor's widest vectors, from a buffer just written on
    // this core (as the outputs are: the FMU wrote them in the call before the check).
    let read = |n: usize| {
        let values = buffer(8 * n);
        measure(steps, 1, |k| {
            for _ in 0..k {
                black_box(stream(arch, black_box(&values)));
            }
        })
    };
    let (read_na, read_ns) = (read(na), read(ns));
    let plain = cross_core_copy(na, CopyWay::Plain);
    let past = cross_core_copy(na, CopyWay::PastCache);
    // The master copies the way its trial finds cheaper.
    let copy_na = if plain.median <= past.median {
        plain
    } else {
        past
    };
    let trip = m1::linalg::pair::round_trip_ns() * 1e-9;
    let mut failure = None;
    let (time, runs) = match master_runs(layout, fmu_dir) {
        Ok(runs) => (
            stats_of(&runs.iter().map(|r| r.per_step).collect::<Vec<_>>()),
            runs,
        ),
        Err(why) => {
            eprintln!("master: not measured: {why}");
            failure = Some(why);
            (None, Vec::new())
        }
    };
    // The runs' medians (without runs: every sensors step on the master's thread, no memo).
    let median = |f: fn(&MasterRun) -> f64, none: f64| {
        stats_of(&runs.iter().map(f).collect::<Vec<_>>()).map_or(none, |s| s.median)
    };
    let handed = median(|r| r.handed, 1.0);
    let memo = median(|r| r.memo, 0.0);
    let sensors_handed = (handed - 1.0).clamp(0.0, 1.0);
    let reads_na = 1.0 + 1.0 / WIND_EVERY + 1.0 / CONTROLLER_EVERY;
    let reads_ns = 1.0 - sensors_handed;
    let copies_na = sensors_handed + (1.0 - memo);
    let work = |pick: fn(&Stats) -> f64| {
        reads_na * pick(&read_na)
            + reads_ns * pick(&read_ns)
            + copies_na * pick(&copy_na)
            + handed * trip
    };
    let floor = Stats {
        median: work(|s| s.median),
        min: work(|s| s.min),
        steps: read_na.steps,
    };
    let outputs = reads_na * na as f64 + reads_ns * ns as f64;
    rows.push(Row {
        component: "master",
        case: "its own time per 1 ms step in the standard system (open and closed loop)".into(),
        time,
        floor,
        basis: format!(
            "estimate: the data work on its thread, the finite check's read of {outputs:.0} \
             outputs ({:.2} of the sensors' steps handed over), {copies_na:.2} copies of z for \
             the look-ahead thread into lines its core read last ({:.2} us each, the cheaper \
             way; {:.2} of the optics' steps from its memo) and \
             {handed:.2} hand-overs at a {:.0} ns round trip; the time: master_share x loop \
             time / steps of `m1cs run --json --no-plots` ({}){}",
            sensors_handed,
            copy_na.median * 1e6,
            memo,
            trip * 1e9,
            match runs.len() {
                0 => "not run".to_string(),
                k => format!("{k} runs, open and closed loop, the upper median"),
            },
            failure
                .as_ref()
                .map_or(String::new(), |why| format!("; not measured: {why}"))
        ),
        details: json!({
            "not_measured": failure,
            "outputs_checked_per_step": outputs,
            "copies_of_z_per_step": copies_na,
            "handed_over_per_step": handed,
            "sensors_steps_handed_over": sensors_handed,
            "optics_steps_from_memo": memo,
            "read_na": read_na.json(),
            "read_ns": read_ns.json(),
            "copy_na_to_the_other_core": copies_json(copy_na),
            "copy_na_plain": copies_json(plain),
            "copy_na_past_the_cache": copies_json(past),
            "round_trip_ns": trip * 1e9,
            "na": na,
            "ns": ns,
            "runs": runs.iter().map(|r| json!({
                "run": r.run,
                "master_share": r.share,
                "loop_real_time_factor": r.real_time,
                "master_us_per_step": r.per_step * 1e6,
                "handed_over_per_step": r.handed,
                "memo_per_step": r.memo,
            })).collect::<Vec<_>>(),
        }),
    });
}

/// Invocations of `m1cs run` that time the master ([`master`]).
const MASTER_RUNS: usize = 3;

/// One run's master: its share of the loop, the loop's real-time factor, its own time per
/// step (s).
struct MasterRun {
    run: String,
    share: f64,
    real_time: f64,
    per_step: f64,
    /// Steps handed to the look-ahead thread per base step.
    handed: f64,
    /// Steps of kept sinks that took their inputs from the memo, per base step.
    memo: f64,
}

/// The master's own time in [`MASTER_RUNS`] invocations of this package's `m1cs run` on the
/// standard system of `layout` (each: open and closed loop), or why it could not be run.
fn master_runs(layout: &str, fmu_dir: &std::path::Path) -> Result<Vec<MasterRun>, String> {
    if !fmu_dir.join(layout).is_dir() {
        return Err(format!(
            "no FMUs in {} (`cargo xtask package {layout}` first)",
            fmu_dir.join(layout).display()
        ));
    }
    let out = std::env::temp_dir().join(format!("m1cs-floors-master-{}", std::process::id()));
    let runs = (0..MASTER_RUNS).try_fold(Vec::new(), |mut runs, _| {
        runs.extend(master_run(layout, fmu_dir, &out)?);
        Ok::<_, String>(runs)
    });
    let _ = std::fs::remove_dir_all(&out);
    runs
}

/// One invocation of `m1cs run` for [`master_runs`] (its results in `out`): both of its runs.
fn master_run(
    layout: &str,
    fmu_dir: &std::path::Path,
    out: &std::path::Path,
) -> Result<Vec<MasterRun>, String> {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_m1cs"))
        .args([
            "run",
            "--layout",
            layout,
            "--json",
            "--no-plots",
            "--fmu-dir",
        ])
        .arg(fmu_dir)
        .arg("--out")
        .arg(out)
        .output()
        .map_err(|e| format!("m1cs run: {e}"))?;
    if !o.status.success() {
        return Err(format!(
            "m1cs run failed: {}",
            String::from_utf8_lossy(&o.stderr).trim()
        ));
    }
    let doc: Value =
        serde_json::from_slice(&o.stdout).map_err(|e| format!("m1cs run --json: {e}"))?;
    let duration = doc["duration_s"].as_f64().ok_or("no duration_s")?;
    let mut runs = Vec::new();
    for r in doc["runs"].as_array().ok_or("no runs")? {
        let name = r["run"].as_str().unwrap_or("?").to_string();
        // A run that stopped early simulated less than `duration`: not a figure of the loop.
        if !(r["ended_by"].is_null() && r["interrupted_at_s"].is_null()) {
            return Err(format!("m1cs run: the {name} run stopped before its end"));
        }
        let (share, real_time) = (
            r["master_share"].as_f64().ok_or("no master_share")?,
            r["loop_real_time_factor"]
                .as_f64()
                .ok_or("no loop_real_time_factor")?,
        );
        let steps = r["rows"].as_f64().ok_or("no rows")? - 1.0;
        let handed = r["lookahead_steps"].as_f64().ok_or("no lookahead_steps")?;
        let memo = r["lookahead_memo_steps"]
            .as_f64()
            .ok_or("no lookahead_memo_steps")?;
        runs.push(MasterRun {
            run: name,
            share,
            real_time,
            per_step: share * duration / real_time / steps,
            handed: handed / steps,
            memo: memo / steps,
        });
    }
    Ok(runs)
}

/// Median (the upper one of an even count) and minimum of per-step times; `steps` is their
/// number (None: no time).
fn stats_of(t: &[f64]) -> Option<Stats> {
    let mut t = t.to_vec();
    t.sort_by(f64::total_cmp);
    Some(Stats {
        median: *t.get(t.len() / 2)?,
        min: *t.first()?,
        steps: t.len(),
    })
}

fn main() {
    let a = parse_args();
    let layout = Layout::preset(&a.layout)
        .unwrap_or_else(|e| panic!("--layout {}: {e}", a.layout))
        .name
        .clone();
    let arch = pulp::Arch::new();
    let start = Instant::now();
    eprintln!(
        "floors: layout {layout}, modes {:?}, {} blocks of {} per measurement",
        a.modes,
        BLOCKS,
        a.steps
            .map_or(format!("about {TARGET_SECONDS} s in all"), |s| format!(
                "{s} steps"
            ))
    );
    let mut rows = Vec::new();
    for &modes in &a.modes {
        mirror(&layout, modes, a.steps, arch, &mut rows);
    }
    edge_sensors(&layout, a.steps, arch, &mut rows);
    optics(&layout, a.steps, arch, &mut rows);
    wind(&layout, a.steps, arch, &mut rows);
    master(&layout, a.steps, arch, &a.fmu_dir, &mut rows);

    println!("\n## Floors: {layout}, medians of {BLOCKS} blocks per step (minimum in brackets)\n");
    println!("| component | case | time per step (us) | floor (us) | ratio | floor basis |");
    println!("|---|---|---|---|---|---|");
    let us = |s: Stats| format!("{:.2} ({:.2})", s.median * 1e6, s.min * 1e6);
    for r in &rows {
        println!(
            "| {} | {} | {} | {} | {} | {} |",
            r.component,
            r.case,
            r.time.map_or("not measured".into(), us),
            us(r.floor),
            r.ratio().map_or("-".into(), |x| format!("{x:.2}")),
            r.basis
        );
    }
    println!(
        "\nThe master's own time is its wall time outside the FMUs' calls in `m1cs run` (its \
         share of the loop times the loop, per step), against an estimate of the data work its \
         thread does: the finite check of the outputs of the steps it takes, the copies of z \
         it hands to the look-ahead thread, a round trip between the cores per step handed \
         over.\nTotal bench time {:.1} s.",
        start.elapsed().as_secs_f64()
    );
    if let Some(path) = &a.json {
        let doc = json!({
            "layout": layout,
            "modes": a.modes,
            "blocks": BLOCKS,
            "rows": rows
                .iter()
                .map(|r| json!({
                    "component": r.component,
                    "case": r.case,
                    "time": r.time.map(Stats::json),
                    "floor": r.floor.json(),
                    "ratio": r.ratio(),
                    "floor_basis": r.basis,
                    "details": r.details,
                }))
                .collect::<Vec<_>>(),
        });
        let text = serde_json::to_string_pretty(&doc).expect("JSON");
        std::fs::write(path, text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        eprintln!("wrote {}", path.display());
    }
}
