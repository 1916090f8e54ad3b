//! The wind's forces at one instant (`WindLoads::forces`, what the wind FMU computes at every
//! 100 Hz step) alone, vectorised and one segment at a time side by side, with the tables warm in
//! the caches and with a 32 MiB sweep through memory before every call (as the rest of a closed
//! loop leaves the caches between two wind steps, or worse). Used for the figures of
//! BENCHMARKS.md (issue 18, eighteenth round).
//!
//! ```text
//! cargo run --release -p m1 --example wind_forces -- [LAYOUT] [SPEED]
//! ```
//!
//! `LAYOUT` is a preset (`tmt`, the default, `keck` or `elt`) on its default geometry and
//! screen, `SPEED` the wind speed in m/s (default 1). Three rounds of the four cases in turn;
//! each prints the median and the fastest of five blocks of 2000 calls (microseconds per call,
//! the 100 Hz times 0.01 s apart), after a check that both ways give the same forces to the
//! bit. The set-up time printed first reads the tables from the on-disk cache when they are
//! there (`M1CS_CACHE_DIR`; an empty folder gives the synthesis).

use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::loads::wind::{WindLoads, WindParams};
use std::hint::black_box;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let name = args.get(1).map_or("tmt", String::as_str);
    let speed: f64 = match args.get(2) {
        Some(s) => s.parse().map_err(|e| format!("SPEED {s}: {e}"))?,
        None => 1.0,
    };
    let layout = Layout::preset(name)?;
    let geometry = Geometry::new(&layout, GeometryParams::for_layout(&layout))?;
    let params = WindParams {
        speed,
        ..WindParams::default()
    };
    let t0 = Instant::now();
    let loads = WindLoads::new(&geometry, &params)?;
    println!(
        "{name}: {} segments, {:.1} MB of tables and maps, set up in {:.2} s, {speed} m/s",
        loads.n_segments(),
        loads.memory_bytes() as f64 / 1e6,
        t0.elapsed().as_secs_f64()
    );
    let (mut a, mut b) = (
        vec![0.0; loads.n_actuators()],
        vec![0.0; loads.n_actuators()],
    );
    for k in 0..1000 {
        let t = 0.01 * f64::from(k);
        loads.forces(t, &mut a)?;
        loads.forces_by_segment(t, &mut b)?;
        if a.iter().zip(&b).any(|(x, y)| x.to_bits() != y.to_bits()) {
            return Err(format!("the two ways differ at t = {t} s").into());
        }
    }
    let mut sweep = vec![1.0f64; 4 << 20];
    let (blocks, calls) = (5, 2000);
    for round in 1..=3 {
        for (way, evict) in [
            ("vectorised", false),
            ("one segment at a time", false),
            ("vectorised", true),
            ("one segment at a time", true),
        ] {
            let mut times = Vec::with_capacity(blocks);
            for block in 0..blocks {
                let mut total = 0.0;
                for k in 0..calls {
                    if evict {
                        // One write per 64-byte line of 32 MiB.
                        for x in sweep.iter_mut().step_by(8) {
                            *x += 1.0;
                        }
                        black_box(&mut sweep);
                    }
                    let t = 0.01 * (block * calls + k) as f64;
                    let start = Instant::now();
                    if way == "vectorised" {
                        loads.forces(t, &mut a)?;
                    } else {
                        loads.forces_by_segment(t, &mut a)?;
                    }
                    total += start.elapsed().as_secs_f64();
                    black_box(&a);
                }
                times.push(total / calls as f64 * 1e6);
            }
            times.sort_by(f64::total_cmp);
            println!(
                "round {round}: {way:<22} {:<22} {:7.2} us (fastest {:.2})",
                if evict {
                    "after a 32 MiB sweep"
                } else {
                    "warm"
                },
                times[blocks / 2],
                times[0]
            );
        }
    }
    Ok(())
}
