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
    cosim::Fmu::open_all(&paths).map_err(|e| e.to_string())
}

/// What the runs recorded: the outcomes (their CSV written as they ran), and per run with a
/// mirror its displacement time series (for the map) and amplitude spectrum.
pub(super) struct Recorded {
    outcomes: Vec<RunOutcome>,
    maps: Vec<(String, Vec<Vec<f64>>)>,
    spectra: Vec<(String, Vec<(f64, f64)>)>,
}

/// One run of `m1cs run`.
pub(super) struct RunOutcome {
    label: String,
    /// The columns kept in memory for the figures (none with `--no-plots`).
    memory: cosim::system::Results,
    report: cosim::system::Report,
    /// Per metric, its rms and mean over the settled second half of the run.
    settled: Vec<(String, Settled)>,
    seconds: f64,
    /// The system's start time (s).
    start: f64,
}

/// Running sums of a column over the settled part of a run.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Settled {
    n: usize,
    sum: f64,
    sum_sq: f64,
}

impl Settled {
    fn rms(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.sum_sq / self.n as f64).sqrt()
        }
    }

    fn mean(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            self.sum / self.n as f64
        }
    }
}

/// The sink of one run of `m1cs run`: every column goes to the run's CSV as it comes, except
/// the mirror displacement recorded only for the figures; the metrics' settled statistics
/// accumulate as rows arrive; the metrics stay in memory, and the displacement over the second
/// half of the rows, only when the figures are drawn. So with `--no-plots` a run takes the same
/// memory whatever its length.
struct RunSink<'a> {
    file: Box<dyn cosim::system::Sink>,
    /// User record entries (their columns always go to the CSV).
    asked: &'a [String],
    metrics: &'a [&'a str],
    figures: bool,
    /// From this time on, a row counts as settled (s).
    settled_from: f64,
    to_csv: Vec<usize>,
    to_memory: Vec<usize>,
    stats: Vec<(usize, String, Settled)>,
    memory: cosim::system::Results,
    buf: Vec<f64>,
    /// The figures' displacement: its columns, the rows kept from (the second half of the
    /// rows the run is to give, which is all the figures use), the rows seen so far, and the
    /// values kept, row after row.
    z: FigureZ,
}

/// The mirror displacement kept for the figures (their spectra and maps over the second half of
/// a run), apart from the metrics' table and only over that half: a 5 s TMT run's 29.5 MB
/// instead of 59 MB, each row's displacement copied in one pass. Its room is written once
/// before the run, as `cosim::system::Results` does with its own, so that the step loop takes
/// no page fault on it (0.8-2 us each on the project's VMs), and the runs of one invocation
/// share it. Before, each row's 1476 values were gathered one by one into the whole run's
/// table, and with the figures (the default run) the master's share of the loop was 13 %
/// (twentieth round of issue 18). The half is that of the rows the run is to give: a run
/// stopped before it has no figures of the displacement.
#[derive(Default)]
struct FigureZ {
    /// The displacement's columns in a row.
    columns: Vec<usize>,
    /// The first row kept, and the rows seen so far.
    from_row: usize,
    rows: usize,
    /// The rows kept, one after the other.
    values: Vec<f64>,
    /// How many values of the room have been written (their pages mapped).
    written: usize,
}

impl FigureZ {
    /// Keeps the columns `columns` of the rows from the second half of `rows` on (the room of
    /// an earlier run kept, written now where it has not been).
    fn start(&mut self, columns: Vec<usize>, rows: usize) {
        let n = (rows - rows / 2) * columns.len();
        self.from_row = rows / 2;
        self.rows = 0;
        self.values.clear();
        if self.values.capacity() < n {
            self.values = Vec::with_capacity(n);
            self.written = 0;
        }
        if self.written < n {
            self.values.resize(n, 0.0);
            self.values.clear();
            self.written = n;
        }
        self.columns = columns;
    }

    /// Keeps row `row`'s displacement if the row is one it keeps.
    fn row(&mut self, row: &[f64]) {
        let kept = self.rows >= self.from_row;
        self.rows += 1;
        if !kept {
            return;
        }
        let n = self.columns.len();
        match self.columns.first() {
            // Consecutive columns (a whole array, as recorded for the figures): the slice.
            Some(&k) if self.columns.last() == Some(&(k + n - 1)) => {
                self.values.extend_from_slice(&row[k..k + n]);
            }
            _ => self.values.extend(self.columns.iter().map(|&k| row[k])),
        }
    }

    /// Each column's values over the rows kept.
    fn series(&self) -> Vec<Vec<f64>> {
        let n = self.columns.len();
        (0..n)
            .map(|c| self.values.chunks_exact(n).map(|row| row[c]).collect())
            .collect()
    }
}

impl cosim::system::Sink for RunSink<'_> {
    fn columns(&mut self, columns: &[String], rows: usize) -> cosim::Result<()> {
        let is_z = |c: &str| c.starts_with("mirror.z[") || c.starts_with("segments.z[");
        let asked = |c: &str| {
            self.asked
                .iter()
                .any(|e| cosim::system::record_selects(e, c))
        };
        let is_metric = |c: &str| self.metrics.contains(&c);
        self.to_csv = (0..columns.len())
            .filter(|&k| k == 0 || !is_z(&columns[k]) || asked(&columns[k]))
            .collect();
        self.to_memory = (0..columns.len())
            .filter(|&k| self.figures && (k == 0 || is_metric(&columns[k])))
            .collect();
        let z: Vec<usize> = (0..columns.len())
            .filter(|&k| self.figures && is_z(&columns[k]))
            .collect();
        self.z.start(z, rows);
        self.stats = (1..columns.len())
            .filter(|&k| is_metric(&columns[k]))
            .map(|k| (k, columns[k].clone(), Settled::default()))
            .collect();
        let names =
            |keep: &[usize]| -> Vec<String> { keep.iter().map(|&k| columns[k].clone()).collect() };
        self.file.columns(&names(&self.to_csv), rows)?;
        self.memory.columns(&names(&self.to_memory), rows)
    }

    fn row(&mut self, row: &[f64]) -> cosim::Result<()> {
        if row[0] >= self.settled_from {
            for (k, _, s) in &mut self.stats {
                let v = row[*k];
                s.n += 1;
                s.sum += v;
                s.sum_sq += v * v;
            }
        }
        self.buf.clear();
        self.buf.extend(self.to_csv.iter().map(|&k| row[k]));
        self.file.row(&self.buf)?;
        if !self.to_memory.is_empty() {
            self.buf.clear();
            self.buf.extend(self.to_memory.iter().map(|&k| row[k]));
            cosim::system::Sink::row(&mut self.memory, &self.buf)?;
        }
        self.z.row(row);
        Ok(())
    }

    fn finish(&mut self) -> cosim::Result<()> {
        self.file.finish()?;
        self.memory.finish()
    }
}

/// Raised by Ctrl-C (SIGINT) or SIGTERM: the run under way stops after its current step.
static STOP: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Installs the handler that raises [`STOP`] (once per process); a second signal ends the
/// process at once (exit status 130).
fn catch_signals() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        if let Err(e) = ctrlc::set_handler(|| {
            // A second signal while the first is being honoured (a step that does not return):
            // leave at once, as the shell expects.
            if STOP.swap(true, std::sync::atomic::Ordering::Relaxed) {
                std::process::exit(130);
            }
        }) {
            eprintln!("note: Ctrl-C will not stop the run cleanly ({e})");
        }
    });
}

/// Runs each system recording `metrics`, the user's `--record` entries and (for the figures)
/// the mirror displacement, writing each run's CSV into `--out` as it goes. A signal stops the
/// run under way after its current step (the rows until then are in its CSV) and the runs after
/// it.
pub(super) fn record_runs(
    a: &RunCmd,
    runs: &[(String, System)],
    metrics: &[&str],
) -> Result<Recorded, String> {
    catch_signals();
    let mut recorded = Recorded {
        outcomes: Vec::new(),
        maps: Vec::new(),
        spectra: Vec::new(),
    };
    // The figures' displacement: its room kept from one run to the next.
    let mut figure_z = FigureZ::default();
    for (label, s) in runs {
        let stem = label.replace(' ', "_");
        // Last time's results go first, so that what is there after a failure is this run's.
        for old in [
            format!("{stem}.csv"),
            format!("{stem}.npy"),
            format!("{stem}.npy.json"),
        ] {
            let _ = std::fs::remove_file(a.out.join(old));
        }
        let (csv, file) = match a.format {
            Format::Csv => {
                let p = a.out.join(format!("{stem}.csv"));
                let sink = cosim::system::CsvSink::create(&p).map_err(|e| e.to_string())?;
                // Formatted and written on a thread of its own, off the master's thread (a
                // binary row costs next to nothing: the npy sink stays in place).
                let sink = cosim::system::BackgroundSink::new(Box::new(sink));
                (p, Box::new(sink) as Box<dyn cosim::system::Sink>)
            }
            Format::Npy => {
                let p = a.out.join(format!("{stem}.npy"));
                (p.clone(), Box::new(super::npy::NpySink::new(&p)) as _)
            }
        };
        let mirror = ["mirror", "segments"]
            .into_iter()
            .find(|m| s.components.iter().any(|c| c.name == *m));
        let mut record: Vec<String> = metrics.iter().map(|m| m.to_string()).collect();
        record.extend(a.record.iter().cloned());
        if let Some(m) = mirror
            && !a.no_plots
        {
            record.push(format!("{m}.z"));
        }
        let mut sink = RunSink {
            file,
            asked: &a.record,
            metrics,
            figures: !a.no_plots,
            settled_from: s.start_time + 0.5 * (s.stop_time - s.start_time) - 1e-9 * s.step,
            to_csv: Vec::new(),
            to_memory: Vec::new(),
            stats: Vec::new(),
            memory: cosim::system::Results::empty(),
            buf: Vec::new(),
            z: std::mem::take(&mut figure_z),
        };
        let t0 = Instant::now();
        let options = cosim::system::RunOptions {
            record: &record,
            decimation: a.decimation,
            stop: Some(&STOP),
        };
        let mut progress = Progress::start(label);
        let outcome = cosim::system::run_into(s, &options, &mut sink, &mut |t, stop| {
            progress.show(t, stop);
        });
        progress.finish();
        // The run's own wall time (set-up and loop), before the figures' post-processing.
        let seconds = t0.elapsed().as_secs_f64();
        let report = outcome.map_err(|f| {
            // The file exists only if the run got as far as its first row (the old one was
            // removed before the run).
            let kept = if csv.exists() {
                format!(" (results up to the failure in {})", csv.display())
            } else {
                String::new()
            };
            format!("{label}: {}{kept}", f.error)
        })?;
        if let Some(e) = &report.ended {
            eprintln!(
                "note: {label}: {} ended the simulation at t = {} s; results up to then in {}",
                e.component,
                e.time,
                csv.display()
            );
        }
        let memory = std::mem::replace(&mut sink.memory, cosim::system::Results::empty());
        let dt = s.step * a.decimation.max(1) as f64;
        let z = sink.z.series();
        figure_z = std::mem::take(&mut sink.z);
        if !z.is_empty() && z.iter().all(|c| !c.is_empty()) {
            recorded
                .spectra
                .push((label.clone(), mirror_spectrum(&z, dt)));
            recorded.maps.push((label.clone(), z));
        }
        let interrupted = report.interrupted;
        recorded.outcomes.push(RunOutcome {
            label: label.clone(),
            memory,
            settled: sink.stats.iter().map(|(_, n, s)| (n.clone(), *s)).collect(),
            report,
            seconds,
            start: s.start_time,
        });
        if let Some(t) = interrupted {
            eprintln!(
                "note: {label}: stopped by a signal at t = {t} s; results up to then in {}",
                csv.display()
            );
            break;
        }
    }
    Ok(recorded)
}

/// Whether a signal stopped the runs.
pub(crate) fn interrupted() -> bool {
    STOP.load(std::sync::atomic::Ordering::Relaxed)
}

/// A run's row of the summary: timings and the settled optics metrics.
pub(super) fn summary_row(o: &RunOutcome, duration: f64) -> serde_json::Value {
    let stat = |n: &str| o.settled.iter().find(|(m, _)| m == n).map(|(_, s)| *s);
    let rms = |n: &str| stat(n).map_or(f64::NAN, |s| s.rms());
    let timing = &o.report.timing;
    // What was simulated: to the stop time, or to where a signal or a component ended it.
    let reached = o
        .report
        .interrupted
        .or(o.report.ended.as_ref().map(|e| e.time))
        .map_or(duration, |t| (t - o.start).clamp(0.0, duration));
    let simulated = reached.max(1e-12);
    json!({
        "run": o.label,
        "wall_seconds": o.seconds,
        "real_time_factor": simulated / o.seconds.max(1e-9),
        // The step loop alone, without instantiation and initialisation (the FMUs' set-up,
        // e.g. the structure's eigensolve, is paid once per run whatever its length).
        "setup_seconds": (o.seconds - timing.loop_seconds).max(0.0),
        "loop_real_time_factor": simulated / timing.loop_seconds.max(1e-9),
        "master_share": timing.master_share(),
        // Components' steps the master's second thread took (Gauss-Seidel's look-ahead).
        "lookahead_steps": timing.lookahead_steps,
        "lookahead_memo_steps": timing.lookahead_memo_steps,
        // The master's timed trials of that thread: per trial, the base step it began at, the
        // mean loop time per base step with and without the thread (s), and whether it was kept.
        "lookahead_trials": timing.lookahead_trials.iter()
            .map(|t| json!({
                "step": t.step,
                "with_seconds_per_step": t.with_seconds,
                "without_seconds_per_step": t.without_seconds,
                "kept": t.kept,
            }))
            .collect::<Vec<_>>(),
        "component_seconds": timing.components.iter()
            .map(|(n, t)| (n.clone(), json!(t)))
            .collect::<serde_json::Map<_, _>>(),
        "component_setup_seconds": timing.setup_components.iter()
            .map(|(n, t)| (n.clone(), json!(t)))
            .collect::<serde_json::Map<_, _>>(),
        "rows": o.report.rows,
        "interrupted_at_s": o.report.interrupted,
        "ended_by": o.report.ended.as_ref()
            .map(|e| json!({"component": e.component, "time_s": e.time})),
        "rms_surface_m": rms("optics.rms_surface"),
        "focus_mode_m": rms("optics.focus_mode"),
        "rms_surface_without_focus_m": rms("optics.rms_surface_without_focus"),
        "pssn": stat("optics.pssn").map_or(f64::NAN, |s| s.mean()),
    })
}

/// One plot per metric over time, all runs overlaid (nm, PSSN as is).
pub(super) fn plot_metrics(
    a: &RunCmd,
    outcomes: &[RunOutcome],
    metrics: &[&str],
) -> Result<(), String> {
    if a.no_plots {
        return Ok(());
    }
    for m in metrics {
        let data: Vec<(String, Vec<(f64, f64)>)> = outcomes
            .iter()
            .filter_map(|o| {
                let t = o.memory.column("time")?;
                let v = o.memory.column(m)?;
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
    // The master's timed trials of its look-ahead thread: say where one turned it off.
    for r in table {
        let trials = r["lookahead_trials"]
            .as_array()
            .map_or(&[][..], Vec::as_slice);
        let dropped: Vec<_> = trials.iter().filter(|t| t["kept"] == false).collect();
        if let Some(last) = dropped.last() {
            let us = |k: &str| last[k].as_f64().unwrap_or(f64::NAN) * 1e6;
            println!(
                "{}: the master's second thread was slower in {} of {} timed trials and was \
                 turned off after them (the last: {:.0} us per base step with it, {:.0} us \
                 without)",
                r["run"].as_str().unwrap_or(""),
                dropped.len(),
                trials.len(),
                us("with_seconds_per_step"),
                us("without_seconds_per_step")
            );
        }
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

#[cfg(test)]
mod tests {
    use super::FigureZ;

    /// The figures' displacement is the second half of the rows the run is to give, column by
    /// column, as `split_off_z` takes it from a whole table, for consecutive columns and others;
    /// its room serves the next run, which keeps only its own rows.
    #[test]
    fn the_figures_keep_the_second_half_of_the_displacement() {
        let width = 7;
        let row = |r: usize| -> Vec<f64> { (0..width).map(|c| (100 * r + c) as f64).collect() };
        let mut z = FigureZ::default();
        for (columns, rows) in [(vec![2, 3, 4], 11), (vec![1, 5], 6), (vec![6], 1)] {
            z.start(columns.clone(), rows);
            for r in 0..rows {
                z.row(&row(r));
            }
            let half = rows / 2;
            let expected: Vec<Vec<f64>> = columns
                .iter()
                .map(|&c| (half..rows).map(|r| row(r)[c]).collect())
                .collect();
            assert_eq!(z.series(), expected, "{columns:?} over {rows} rows");
        }
        // A run stopped before its second half keeps nothing.
        z.start(vec![0, 1], 10);
        for r in 0..4 {
            z.row(&row(r));
        }
        assert!(z.series().iter().all(Vec::is_empty));
    }
}
