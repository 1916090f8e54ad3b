//! Running the systems of `m1cs run`: open the FMUs once, record every run, summarise.

use super::figures::{draw_z_plots, mirror_spectrum};
use super::*;

pub(super) fn execute(
    a: &RunCmd,
    runs: Vec<(String, System)>,
    metrics: &[&str],
) -> Result<(), String> {
    // Every FMU opened once for all the runs: they share its unpacked files and loaded library
    // (and so its caches, e.g. the structure's modes), instead of unpacking it per run.
    let _open = open_fmus(&runs)?;
    let recorded = record_runs(a, &runs, metrics)?;
    draw_z_plots(a, &recorded.maps, &recorded.spectra)?;
    let duration = runs.first().map_or(0.0, |r| r.1.stop_time - r.1.start_time);
    let table: Vec<serde_json::Value> = recorded
        .outcomes
        .iter()
        .map(|o| summary_row(o, duration))
        .collect();
    plot_metrics(a, &recorded.outcomes, metrics)?;
    let summary = match &a.ssp {
        // A user's system: what it is comes from its file, not from the standard-system flags.
        Some(path) => json!({
            "ssp": path.display().to_string(),
            "duration_s": duration,
            "runs": table,
            "results": a.out.display().to_string(),
        }),
        None => json!({
            "layout": a.system.layout,
            "actuator": format!("{:?}", a.system.actuator).to_lowercase(),
            "scenario": format!("{:?}", a.system.scenario).to_lowercase(),
            "duration_s": duration,
            "runs": table,
            "results": a.out.display().to_string(),
        }),
    };
    std::fs::write(a.out.join("summary.json"), summary.to_string())
        .map_err(|e| format!("{}: {e}", a.out.display()))?;
    if a.json {
        println!("{summary}");
        return Ok(());
    }
    print_summary(a, &table, duration);
    Ok(())
}

/// Every distinct FMU of `runs`, opened (kept open while the handles live).
pub(super) fn open_fmus(runs: &[(String, System)]) -> Result<Vec<cosim::Fmu>, String> {
    let mut paths: Vec<&std::path::Path> = runs
        .iter()
        .flat_map(|(_, s)| s.components.iter().map(|c| c.fmu.as_path()))
        .collect();
    paths.sort();
    paths.dedup();
    paths
        .into_iter()
        .map(cosim::Fmu::open)
        .collect::<Result<_, _>>()
        .map_err(|e| e.to_string())
}

/// What the runs recorded: the outcomes (their CSV written), and per run with a mirror its
/// displacement time series (for the map) and amplitude spectrum.
pub(super) struct Recorded {
    outcomes: Vec<Outcome>,
    maps: Vec<(String, Vec<Vec<f64>>)>,
    spectra: Vec<(String, Vec<(f64, f64)>)>,
}

/// Runs each system recording `metrics` and the mirror displacement, and writes each run's
/// CSV (without the displacement) into `--out`.
pub(super) fn record_runs(
    a: &RunCmd,
    runs: &[(String, System)],
    metrics: &[&str],
) -> Result<Recorded, String> {
    let mut recorded = Recorded {
        outcomes: Vec::new(),
        maps: Vec::new(),
        spectra: Vec::new(),
    };
    for (label, s) in runs {
        let csv = a.out.join(format!("{}.csv", label.replace(' ', "_")));
        // The mirror displacement is recorded for the map and the spectrum, not written.
        let mirror = ["mirror", "segments"]
            .into_iter()
            .find(|m| s.components.iter().any(|c| c.name == *m));
        let mut record: Vec<String> = metrics.iter().map(|m| m.to_string()).collect();
        if let Some(m) = mirror {
            record.push(format!("{m}.z"));
        }
        let record: Vec<&str> = record.iter().map(String::as_str).collect();
        let mut o = run_one(label, s, a.decimation, &record, Some(&csv))?;
        let dt = s.step * a.decimation.max(1) as f64;
        let z = split_off_z(&mut o.results);
        if !z.is_empty() {
            recorded
                .spectra
                .push((label.clone(), mirror_spectrum(&z, dt)));
            recorded.maps.push((label.clone(), z));
        }
        o.results.write_csv(&csv).map_err(|e| e.to_string())?;
        recorded.outcomes.push(o);
    }
    Ok(recorded)
}

/// A run's row of the summary: timings and the settled optics metrics.
pub(super) fn summary_row(o: &Outcome, duration: f64) -> serde_json::Value {
    let col = |n: &str| o.results.column(n).unwrap_or_else(|| vec![f64::NAN]);
    json!({
        "run": o.label,
        "wall_seconds": o.seconds,
        "real_time_factor": duration / o.seconds.max(1e-9),
        // The step loop alone, without instantiation and initialisation (the FMUs' set-up,
        // e.g. the structure's eigensolve, is paid once per run whatever its length).
        "setup_seconds": (o.seconds - o.results.timing.loop_seconds).max(0.0),
        "loop_real_time_factor": duration / o.results.timing.loop_seconds.max(1e-9),
        "master_share": o.results.timing.master_share(),
        "component_seconds": o.results.timing.components.iter()
            .map(|(n, t)| (n.clone(), json!(t)))
            .collect::<serde_json::Map<_, _>>(),
        "component_setup_seconds": o.results.timing.setup_components.iter()
            .map(|(n, t)| (n.clone(), json!(t)))
            .collect::<serde_json::Map<_, _>>(),
        "rms_surface_m": settled_rms(&col("optics.rms_surface")),
        "focus_mode_m": settled_rms(&col("optics.focus_mode")),
        "rms_surface_without_focus_m": settled_rms(&col("optics.rms_surface_without_focus")),
        "pssn": settled_mean(&col("optics.pssn")),
    })
}

/// One plot per metric over time, all runs overlaid (nm, PSSN as is).
pub(super) fn plot_metrics(
    a: &RunCmd,
    outcomes: &[Outcome],
    metrics: &[&str],
) -> Result<(), String> {
    for m in metrics {
        let data: Vec<(String, Vec<(f64, f64)>)> = outcomes
            .iter()
            .filter_map(|o| {
                let t = o.results.column("time")?;
                let v = o.results.column(m)?;
                Some((o.label.clone(), t.into_iter().zip(v).collect()))
            })
            .collect();
        if data.is_empty() {
            continue;
        }
        let name = m.trim_start_matches("optics.");
        let (unit, scale) = if *m == "optics.pssn" {
            ("1", 1.0)
        } else {
            ("nm", 1e9)
        };
        let scaled: Vec<Vec<(f64, f64)>> = data
            .iter()
            .map(|(_, p)| p.iter().map(|(t, v)| (*t, v * scale)).collect())
            .collect();
        let series: Vec<(&str, &[(f64, f64)])> = data
            .iter()
            .zip(&scaled)
            .map(|((l, _), p)| (l.as_str(), p.as_slice()))
            .collect();
        plot::lines(
            a.out.join(format!("{name}.png")),
            &series,
            &format!("{name} ({})", a.system.layout),
            "time (s)",
            &format!("{name} ({unit})"),
            false,
            false,
        )
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

/// The summary table, and the actuator variants' ratios when all three ran.
pub(super) fn print_summary(a: &RunCmd, table: &[serde_json::Value], duration: f64) {
    match &a.ssp {
        Some(path) => println!(
            "{}: {duration} s simulated (statistics over the second half):",
            path.display()
        ),
        None => println!(
            "{} {:?} actuators, {:?} scenario, {duration} s simulated (statistics over the second half):",
            a.system.layout, a.system.actuator, a.system.scenario
        ),
    }
    println!(
        "{:<12} {:>14} {:>14} {:>18} {:>8} {:>9} {:>11} {:>16} {:>8}",
        "run",
        "rms surf (nm)",
        "focus (nm)",
        "rms w/o focus (nm)",
        "PSSN",
        "wall (s)",
        "set-up (s)",
        "x realtime loop",
        "master"
    );
    for r in table {
        let g = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
        println!(
            "{:<12} {:>14.3} {:>14.3} {:>18.3} {:>8.5} {:>9.2} {:>11.2} {:>16.2} {:>7.1}%",
            r["run"].as_str().unwrap_or(""),
            g("rms_surface_m") * 1e9,
            g("focus_mode_m") * 1e9,
            g("rms_surface_without_focus_m") * 1e9,
            g("pssn"),
            g("wall_seconds"),
            g("setup_seconds"),
            g("loop_real_time_factor"),
            100.0 * g("master_share")
        );
    }
    let rms_of = |label: &str| {
        table
            .iter()
            .find(|r| r["run"] == label)
            .and_then(|r| r["rms_surface_m"].as_f64())
    };
    if let (Some(soft), Some(hard), Some(damped)) =
        (rms_of("voicecoil"), rms_of("piezo"), rms_of("piezo damped"))
    {
        println!(
            "rms surface ratios: hard / soft = {:.2}, undamped / damped = {:.2}",
            hard / soft,
            hard / damped
        );
    }
    println!(
        "CSV, plots and summary.json in {}",
        Path::new(&a.out).display()
    );
}
