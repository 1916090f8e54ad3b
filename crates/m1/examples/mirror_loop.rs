//! The coupled mirror's 1 ms step alone, in variants run side by side: TMT's voice coil on the
//! built-in cell with `MODES` retained modes, the wind forces changing every tenth step (as the
//! 100 Hz wind does in the standard system) and the mirror's displacement read after every
//! step. Used for the figures of BENCHMARKS.md (issue 18, eleventh round).
//!
//! ```text
//! cargo run --release -p m1 --example mirror_loop -- [MODES] [VARIANTS] [LAYOUT]
//! ```
//!
//! `LAYOUT` is a preset (`tmt`, the default, `keck` or `elt`), on its built-in cell.
//! `VARIANTS` is a comma-separated list (default `1,2`): `1` or `2` threads
//! (`CoupledMirror::set_two_threads`) or `a` for the automatic choice, with a `p` suffix for
//! the Gram matrices stored by half (`CoupledMirror::set_gram_packed`), without it whole; `h`:
//! so with the correction in half precision (`CoupledMirror::set_correction_storage`), `s`: in single
//! precision (`p` and `s` alike, but `p` keeps the mirror's default precisions); `x`: as `h` with
//! the Gram matrices in 24-bit fixed point (`CoupledMirror::set_gram_fixed24`); `e`: as `x` with
//! the correction in 8-bit fixed point (`CoupledMirror::set_correction_storage`); `d`: the
//! mirror's defaults for its size; `o`: those defaults with the correction in half precision
//! (the defaults before the correction's 8-bit storage); `f`: the defaults with the mode shapes
//! in single precision (`CoupledMirror::set_shapes_fixed24`; before the twenty-eighth round).
//! The variants other than `d`, `o` and `f` keep the default storage of the mode shapes.
//! Three rounds of the variants in turn; each prints the median and the fastest of five
//! blocks (microseconds per step) and the sum of the last step's |z|, which must agree between
//! thread counts to every digit.
//!
//! Each line also gives the round trip of a cache line between two threads measured just
//! before the variant ran: on the project's 2-core VM it is about 60 ns when the two virtual
//! cores share an L3 cache and about 300 ns when the host has put them on two (BENCHMARKS.md,
//! twelfth round), which changes the two-thread figures at 1000 modes.

use m1::aperture::layout::Layout;
use m1::plant::mirror::{CorrectionStorage, CoupledMirror};
use m1::plant::segment::SegmentModel;
use m1::plant::structure::{CellModel, CellParams};
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let modes: usize = match args.get(1) {
        Some(s) => s.parse().map_err(|e| format!("MODES {s:?}: {e}"))?,
        None => 1000,
    };
    let variants: Vec<&str> = args
        .get(2)
        .map_or(vec!["1", "2"], |s| s.split(',').collect());
    for v in &variants {
        if !matches!(
            *v,
            "1" | "2"
                | "a"
                | "1p"
                | "2p"
                | "ap"
                | "1h"
                | "2h"
                | "ah"
                | "1s"
                | "2s"
                | "as"
                | "1x"
                | "2x"
                | "ax"
                | "1e"
                | "2e"
                | "ae"
                | "1d"
                | "2d"
                | "ad"
                | "1o"
                | "2o"
                | "ao"
                | "1f"
                | "2f"
                | "af"
        ) {
            return Err(format!(
                "variant {v:?}: expected 1, 2 or a, each alone or followed by p, h, s, x, e, d, o or f"
            )
            .into());
        }
    }
    let layout = Layout::preset(args.get(3).map_or("tmt", String::as_str))?;
    let cell = CellModel::new(&layout, &CellParams::default())?.modes()?;
    let na = layout.n_actuators();
    let base = CoupledMirror::new(
        layout.n_segments(),
        SegmentModel::voice_coil(),
        cell,
        modes,
        0.02,
        1,
    )?;
    let steps_per_block = if modes >= 800 { 200 } else { 800 };
    let mut pair = m1::linalg::pair::Pair::start().ok_or("no helper thread")?;
    println!(
        "cores' round trip: {:.0} ns, the mirror's hand-over: {:.0} ns",
        m1::linalg::pair::round_trip_ns(),
        pair.handoff_ns(31)
    );
    for round in 0..3 {
        for v in &variants {
            let trip = m1::linalg::pair::round_trip_ns();
            let handoff = pair.handoff_ns(31);
            let mut m = base.clone();
            if !v.starts_with('a') {
                m.set_two_threads(v.starts_with('2'));
            }
            let suffix = v.chars().nth(1);
            if suffix == Some('f') {
                m.set_shapes_fixed24(false);
            }
            if !matches!(suffix, Some('d' | 'o' | 'f')) {
                m.set_gram_packed(v.len() > 1);
                m.set_gram_fixed24(v.ends_with('x') || v.ends_with('e'));
            }
            let correction = match suffix {
                None | Some('s') => Some(CorrectionStorage::Single),
                Some('h' | 'x' | 'o') => Some(CorrectionStorage::Half),
                Some('e') => Some(CorrectionStorage::Fixed8),
                _ => None,
            };
            if let Some(c) = correction {
                m.set_correction_storage(c);
            }
            let u = vec![0.0; na];
            let mut f: Vec<f64> = (0..na).map(|i| (i % 7) as f64).collect();
            let mut z = vec![0.0; na];
            let mut blocks = Vec::new();
            for b in 0..5 {
                let t = Instant::now();
                for k in b * steps_per_block..(b + 1) * steps_per_block {
                    if k % 10 == 0 {
                        f[k % na] += 0.1;
                    }
                    m.advance(1e-3, &u, &f, 1e-9 * (k as f64).sin())?;
                    m.mirror(&mut z);
                }
                blocks.push(t.elapsed().as_secs_f64() * 1e6 / steps_per_block as f64);
            }
            blocks.sort_by(f64::total_cmp);
            let zsum: f64 = z.iter().map(|x| x.abs()).sum();
            println!(
                "round {round}, {modes} modes, {v}: median {:.1} us, fastest {:.1} us per step, \
                 sum |z| = {zsum:e} (cores' round trip {trip:.0} ns, hand-over {handoff:.0} ns)",
                blocks[2], blocks[0]
            );
        }
    }
    Ok(())
}
