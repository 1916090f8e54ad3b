//! The dynamic studies: `m1cs coupling` (how large a communication step the segments and the
//! structure tolerate as two co-simulation components).

use clap::Args;
use serde_json::json;

use m1::coupling::{Exchange, Excitation, Mirror, SplitRun, split_vs_coupled};
use m1::segment::SegmentModel;
use m1::structure::{CellModel, CellParams};

use crate::plot;

/// `m1cs coupling`.
#[derive(Args, Debug)]
pub struct CouplingArgs {
    /// Mirror layout (keck, tmt, elt) or a JSON file of segment centres.
    #[arg(long, default_value = "keck")]
    pub layout: String,
    /// Retained structure modes.
    #[arg(long, default_value_t = 30)]
    pub modes: usize,
    /// Modal damping ratio of the structure.
    #[arg(long, default_value_t = 0.02)]
    pub damping: f64,
    /// Communication steps to try (s), comma-separated: multiples of the 0.2 ms servo period.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "0.0002,0.0004,0.0006,0.001"
    )]
    pub steps: Vec<f64>,
    /// Pier tone frequency (Hz).
    #[arg(long, default_value_t = 5.0)]
    pub tone: f64,
    /// Simulated time per run (s).
    #[arg(long, default_value_t = 1.0)]
    pub duration: f64,
    /// Relative rms error under which a stable run counts as accurate.
    #[arg(long, default_value_t = 0.01)]
    pub tolerance: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// PNG of the relative error against the step, per variant and order (unbounded runs are
    /// left out).
    #[arg(long)]
    pub plot: Option<String>,
}

/// Runs `m1cs coupling`.
pub fn coupling(a: &CouplingArgs) -> Result<(), String> {
    let layout = crate::load_layout(&a.layout)?;
    if a.steps.is_empty() {
        return Err("--steps: give at least one communication step (s)".into());
    }
    if !(a.tolerance.is_finite() && a.tolerance > 0.0) {
        return Err(format!(
            "--tolerance {}: must be finite and > 0",
            a.tolerance
        ));
    }
    let cell = CellModel::new(&layout, &CellParams::default())
        .and_then(|c| c.modes())
        .map_err(|e| format!("structure of {}: {e}", layout.name))?;
    let ex = Excitation {
        frequency: a.tone,
        duration: a.duration,
        ..Excitation::default()
    };
    let variants = [
        ("voicecoil", SegmentModel::voice_coil()),
        ("piezo", SegmentModel::piezo()),
        ("piezo-damped", SegmentModel::piezo_damped_default()),
    ];
    let orders = [Exchange::GaussSeidel, Exchange::Jacobi];
    let bar = indicatif::ProgressBar::new((variants.len() * orders.len() * a.steps.len()) as u64);
    let mut runs: Vec<(&str, SplitRun)> = Vec::new();
    for (name, model) in &variants {
        let mirror = Mirror {
            n_segments: layout.n_segments(),
            model,
            cell: &cell,
            n_modes: a.modes,
            damping_ratio: a.damping,
        };
        for &order in &orders {
            for &step in &a.steps {
                let r = split_vs_coupled(&mirror, step, order, &ex)
                    .map_err(|e| format!("{name}, step {step} s: {e}"))?;
                runs.push((name, r));
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    // The largest accurate step per variant and order.
    let largest = |name: &str, order: Exchange| {
        runs.iter()
            .filter(|(n, r)| *n == name && r.order == order)
            .filter(|(_, r)| r.stable && r.relative_error <= a.tolerance)
            .map(|(_, r)| r.step)
            .fold(None, |m: Option<f64>, s| Some(m.map_or(s, |m| m.max(s))))
    };
    if let Some(p) = &a.plot {
        // One line per run of consecutive bounded steps (a diverged step breaks the line), in
        // the colour of its variant and order: the first piece carries the label.
        type Piece = (String, usize, Vec<(f64, f64)>);
        let mut series: Vec<Piece> = Vec::new();
        let mut colour = 0;
        for (name, _) in &variants {
            for &order in &orders {
                colour += 1;
                let mut label = format!("{name}, {order:?}");
                let mut piece: Vec<(f64, f64)> = Vec::new();
                let case = runs.iter().filter(|(n, r)| n == name && r.order == order);
                for (_, r) in case {
                    if r.stable {
                        piece.push((r.step * 1e3, r.relative_error));
                    } else if !piece.is_empty() {
                        series.push((
                            std::mem::take(&mut label),
                            colour - 1,
                            std::mem::take(&mut piece),
                        ));
                    }
                }
                if !piece.is_empty() || !label.is_empty() {
                    series.push((label, colour - 1, piece));
                }
            }
        }
        let refs: Vec<plot::ColouredSeries> = series
            .iter()
            .map(|(l, c, p)| (l.as_str(), *c, p.as_slice()))
            .collect();
        plot::lines_in_colours(
            p,
            &refs,
            &format!(
                "split segments/structure vs coupled, {} ({} modes, {} Hz pier tone)",
                layout.name, a.modes, a.tone
            ),
            "communication step (ms)",
            "relative rms error of the mirror displacement",
            false,
            true,
        )
        .map_err(|e| format!("--plot {p}: {e}"))?;
    }
    if a.json {
        let rows: Vec<_> = runs
            .iter()
            .map(|(n, r)| {
                json!({"variant": n, "step_s": r.step, "order": r.order, "stable": r.stable,
                       "reached_s": r.reached,
                       "relative_error": if r.relative_error.is_finite() { json!(r.relative_error) } else { json!(null) }})
            })
            .collect();
        let best: serde_json::Map<String, serde_json::Value> = variants
            .iter()
            .flat_map(|(name, _)| orders.iter().map(move |o| (*name, *o)))
            .map(|(name, order)| (format!("{name}/{order:?}"), json!(largest(name, order))))
            .collect();
        println!(
            "{}",
            json!({"layout": layout.name, "modes": a.modes, "tone_hz": a.tone,
                   "duration_s": a.duration, "tolerance": a.tolerance, "runs": rows,
                   "largest_accurate_step_s": best})
        );
        return Ok(());
    }
    println!(
        "Segments and structure as two components exchanging every step, against the coupled \
         solver ({}, {} modes, {} Hz pier tone, {} s):",
        layout.name, a.modes, a.tone, a.duration
    );
    println!(
        "{:<14} {:<12} {:>9} {:>10} {:>16}",
        "variant", "order", "step (ms)", "bounded", "rel. rms error"
    );
    for (name, r) in &runs {
        let err = if r.stable {
            format!("{:.2e}", r.relative_error)
        } else {
            format!("diverged at {:.3} s", r.reached)
        };
        println!(
            "{:<14} {:<12} {:>9.2} {:>10} {:>16}",
            name,
            format!("{:?}", r.order),
            r.step * 1e3,
            r.stable,
            err
        );
    }
    for (name, _) in &variants {
        for &order in &orders {
            let s = largest(name, order)
                .map_or_else(|| "none".to_string(), |s| format!("{:.1} ms", s * 1e3));
            println!(
                "largest step within {:.1} %: {name}, {order:?}: {s}",
                100.0 * a.tolerance
            );
        }
    }
    println!(
        "The mirror FMUs (mirror_voicecoil, mirror_piezo) solve the two together at every servo \
         sample: stable for every variant at any multiple of 0.2 ms."
    );
    Ok(())
}
