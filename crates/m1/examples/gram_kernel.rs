//! The mirror's Gram product alone, in each storage the mirror can take: a symmetric matrix
//! of order `ORDER` (default 1000, TMT's largest retained-mode count) by its upper block
//! triangles, times two right-hand sides, repeated. Used for the figures of BENCHMARKS.md
//! (issue 18, twenty-ninth round: which storage pays on which processor).
//!
//! ```text
//! cargo run --release -p m1 --example gram_kernel -- [ORDER] [COLD_MB]
//! ```
//!
//! Storages: 24-bit fixed point, half precision and 8 bits (`SymScaled::scaled_rows`, on the
//! processor's widest path) and single precision (`sym_dot_f32`). `COLD_MB` (default 0)
//! megabytes are read between products (not timed), so that the matrix comes from the L3 or
//! the memory rather than the L2. Three rounds of the storages in turn; each line gives the
//! time per product, the multiply-adds per second (two per stored entry and right-hand side,
//! `2 ORDER^2` in all) and the stored bytes per second.

use m1::linalg::symmetric::{BLOCK, SymPacked32, sym_dot_f32};
use m1::linalg::symmetric_scaled::{Encoding, SymPacked8, SymPacked24, SymPackedHalf, SymScaled};
use std::hint::black_box;
use std::time::Instant;

/// Products timed per storage and round (after as many untimed).
const REPS: usize = 400;

/// A symmetric test matrix with entries of mixed sign and a slowly varying scale.
fn entry(i: usize, j: usize) -> f64 {
    let (a, b) = (i.min(j) as f64, i.max(j) as f64);
    ((0.37 * a + 0.11 * b).sin() + 0.05) * (1.0 + 0.001 * a)
}

/// The single-precision product, dispatched to the processor's widest vectors.
struct Single<'a> {
    a: &'a SymPacked32,
    x: [&'a [f32]; 2],
    y: &'a mut [Vec<f64>; 2],
    t: &'a mut [Vec<f32>; 2],
}

impl pulp::WithSimd for Single<'_> {
    type Output = ();
    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let [y0, y1] = self.y;
        let [t0, t1] = self.t;
        sym_dot_f32::<S, 2>(simd, self.a, self.x, [y0, y1], [t0, t1]);
    }
}

/// Vectors of the products: two right-hand sides, their results and the scratch.
struct Work {
    x: [Vec<f32>; 2],
    y: [Vec<f64>; 2],
    t: [Vec<f32>; 2],
}

impl Work {
    fn scaled<E: Encoding>(&mut self, a: &SymScaled<E>) {
        let [y0, y1] = &mut self.y;
        let [t0, t1] = &mut self.t;
        a.scaled_rows::<2>(
            [&self.x[0], &self.x[1]],
            [y0, y1],
            [t0, t1],
            0..a.padded_order() / BLOCK,
        );
    }
}

/// Times `REPS` calls of `f` (after `REPS / 20` untimed), reading `junk` before each one outside
/// the timing; seconds per call.
fn time(junk: &[f32], mut f: impl FnMut()) -> f64 {
    for _ in 0..REPS / 20 {
        f();
    }
    let mut total = 0.0;
    for _ in 0..REPS {
        // One value per cache line.
        black_box(junk.iter().step_by(16).sum::<f32>());
        let t0 = Instant::now();
        f();
        total += t0.elapsed().as_secs_f64();
    }
    total / REPS as f64
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let order: usize = match args.get(1) {
        Some(s) => s.parse().map_err(|e| format!("ORDER {s:?}: {e}"))?,
        None => 1000,
    };
    let cold_mb: usize = match args.get(2) {
        Some(s) => s.parse().map_err(|e| format!("COLD_MB {s:?}: {e}"))?,
        None => 0,
    };
    if order == 0 {
        return Err("ORDER: expected at least 1".into());
    }
    let a24 = SymPacked24::from_fn(order, entry).ok_or("24-bit matrix: an entry not finite")?;
    let ah = SymPackedHalf::from_fn(order, entry).ok_or("half matrix: an entry not finite")?;
    let a8 = SymPacked8::from_fn(order, entry).ok_or("8-bit matrix: an entry not finite")?;
    let a32 = SymPacked32::from_fn(order, entry);
    let n = a32.padded_order();
    let junk = vec![1.0f32; cold_mb * (1 << 20) / 4];
    let mut w = Work {
        x: std::array::from_fn(|l| {
            (0..n)
                .map(|i| {
                    if i < order {
                        ((i + l) as f32 * 0.01).cos()
                    } else {
                        0.0
                    }
                })
                .collect()
        }),
        y: std::array::from_fn(|_| vec![0.0; n]),
        t: std::array::from_fn(|_| vec![0.0; n]),
    };
    let arch = pulp::Arch::new();
    let fmas = 2.0 * (order * order) as f64;
    println!(
        "order {order}, two right-hand sides, {cold_mb} MB read between products; paths: \
         scaled {:?}, 24-bit {:?}",
        ah.path(),
        a24.path()
    );
    for round in 0..3 {
        let runs: [(&str, usize, f64); 4] = [
            ("24-bit", a24.stored_bytes(), time(&junk, || w.scaled(&a24))),
            ("half", ah.stored_bytes(), time(&junk, || w.scaled(&ah))),
            ("8-bit", a8.stored_bytes(), time(&junk, || w.scaled(&a8))),
            (
                "single",
                4 * a32.as_slice().len(),
                time(&junk, || {
                    arch.dispatch(Single {
                        a: &a32,
                        x: [&w.x[0], &w.x[1]],
                        y: &mut w.y,
                        t: &mut w.t,
                    })
                }),
            ),
        ];
        for (name, bytes, s) in runs {
            println!(
                "round {round}, {name:>6}: {:7.1} us per product, {:5.2} G multiply-adds/s, {:5.1} GB/s",
                s * 1e6,
                fmas / s / 1e9,
                bytes as f64 / s / 1e9
            );
        }
    }
    black_box(&w.y);
    Ok(())
}
