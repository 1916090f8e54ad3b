//! The run loop and its results: [`run_into`] sets a system up, steps it to its stop time (or
//! until a component ends it, or a stop flag is raised), and hands the chosen signals every
//! `decimation` base steps to a [`Sink`] as it goes: a table in memory allocated once
//! ([`Results`], what [`run`] returns), or a CSV file written as the rows come ([`CsvSink`]), so
//! that a long run needs no more memory than a short one. It reports where the wall time went
//! ([`Timing`]); a run that fails keeps what it recorded until then ([`Failure`]).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use super::definition::System;
use super::simulation::Simulation;
use crate::error::{CosimError, Result};

/// Results of [`run`]: the time column and one row of recorded values per sample, stored
/// flat (row-major), so that recording during the run never allocates.
#[derive(Debug, Clone)]
pub struct Results {
    /// Column names, "time" first.
    pub columns: Vec<String>,
    /// Row-major values: row `k` is `values[k * w..(k + 1) * w]` with `w = columns.len()`.
    values: Vec<f64>,
    /// Values written so far during a run (the rest is preallocated room).
    filled: usize,
    /// Where the time went.
    pub timing: Timing,
    /// The component that ended the simulation before the stop time, and when (None: the run
    /// reached its stop time).
    pub ended: Option<Ended>,
}

/// A simulation a component ended itself: its fmi2DoStep returned fmi2Discard and
/// fmi2GetBooleanStatus(fmi2Terminated) said true. The run ends cleanly at the last
/// communication point reached, with its results.
#[derive(Debug, Clone, PartialEq)]
pub struct Ended {
    /// The component.
    pub component: String,
    /// The time it reached (fmi2LastSuccessfulTime, or the start of the discarded step if it
    /// does not say) (s).
    pub time: f64,
}

/// Where the wall time of a run went.
#[derive(Debug, Clone, Default)]
pub struct Timing {
    /// The step loop, from the first step to the last (s).
    pub loop_seconds: f64,
    /// FMU calls on the critical path (s): the rest of the loop is the master's own work
    /// (moving values, scheduling, recording).
    pub fmu_seconds: f64,
    /// Wall time inside each component's calls (s).
    pub components: Vec<(String, f64)>,
    /// Wall time of each component's set-up, instantiation to the end of initialisation (s).
    pub setup_components: Vec<(String, f64)>,
    /// Components' steps taken on the look-ahead thread (handed over in Gauss-Seidel order, or
    /// of sinks kept there in either order).
    pub lookahead_steps: u64,
    /// Of those, the steps of kept sinks that took inputs from the memo there (values copied
    /// once by the master for two components, [`Simulation::lookahead_memo_steps`]).
    pub lookahead_memo_steps: u64,
    /// The look-ahead thread's timed trials and what each kept
    /// ([`SchedulerParams::lookahead_trial_every`](super::SchedulerParams::lookahead_trial_every)).
    pub lookahead_trials: Vec<super::LookaheadTrial>,
}

impl Timing {
    /// Share of the step loop spent in the master itself (0..1).
    pub fn master_share(&self) -> f64 {
        if self.loop_seconds > 0.0 {
            ((self.loop_seconds - self.fmu_seconds) / self.loop_seconds).max(0.0)
        } else {
            0.0
        }
    }
}

/// A run that stopped on an error, with what it had recorded until then.
#[derive(Debug)]
pub struct Failure {
    /// What stopped it.
    pub error: CosimError,
    /// The results up to the last completed step (None if it failed before the first).
    pub partial: Option<Results>,
}

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.error)
    }
}

impl std::error::Error for Failure {}

impl From<CosimError> for Failure {
    fn from(error: CosimError) -> Self {
        Self {
            error,
            partial: None,
        }
    }
}

impl Results {
    /// No columns, no rows: a [`Sink`] to run into.
    pub fn empty() -> Self {
        Self {
            columns: Vec::new(),
            values: Vec::new(),
            filled: 0,
            timing: Timing::default(),
            ended: None,
        }
    }

    /// Writes CSV (a header row, "time" first; full-precision values).
    ///
    /// # Errors
    /// [`CosimError::Io`] naming the file.
    pub fn write_csv(&self, path: &Path) -> Result<()> {
        use std::io::Write;
        let f = std::fs::File::create(path).map_err(crate::error::io(path))?;
        let mut w = std::io::BufWriter::new(f);
        let mut write = || -> std::io::Result<()> {
            writeln!(w, "{}", self.columns.join(","))?;
            for row in self.rows() {
                write_csv_row(&mut w, row)?;
            }
            w.flush()
        };
        write().map_err(crate::error::io(path))
    }

    /// The column called `name`.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let k = self.columns.iter().position(|c| c == name)?;
        Some(self.rows().map(|r| r[k]).collect())
    }

    /// Number of rows (samples).
    pub fn n_rows(&self) -> usize {
        self.values.len() / self.columns.len().max(1)
    }

    /// The rows in order: time then the recorded values.
    pub fn rows(&self) -> std::slice::ChunksExact<'_, f64> {
        self.values.chunks_exact(self.columns.len().max(1))
    }

    /// Row `k`, if there is one.
    pub fn row(&self, k: usize) -> Option<&[f64]> {
        let w = self.columns.len();
        self.values.get(k * w..(k + 1) * w)
    }

    /// The last row, if any.
    pub fn last_row(&self) -> Option<&[f64]> {
        self.n_rows().checked_sub(1).and_then(|k| self.row(k))
    }

    /// All values, row-major.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// Keeps only the columns `keep` (indices, in the order given).
    pub fn keep_columns(&mut self, keep: &[usize]) {
        let w = self.columns.len();
        let n = self.n_rows();
        let mut values = Vec::with_capacity(n * keep.len());
        for row in self.values.chunks_exact(w.max(1)) {
            values.extend(keep.iter().map(|&k| row[k]));
        }
        self.columns = keep.iter().map(|&k| self.columns[k].clone()).collect();
        self.filled = values.len();
        self.values = values;
    }
}

/// Where the recorded rows of a run go, as the run produces them.
pub trait Sink {
    /// The column names ("time" first), once, before the first row; `rows` is the number of
    /// rows the run will give if it reaches its stop time (for preallocation).
    ///
    /// # Errors
    /// The sink cannot take them (e.g. a file that cannot be written).
    fn columns(&mut self, columns: &[String], rows: usize) -> Result<()>;
    /// One row: the time, then the recorded values in column order.
    ///
    /// # Errors
    /// As [`Self::columns`].
    fn row(&mut self, row: &[f64]) -> Result<()>;
    /// After the last row (also after a failure or a stop): flush what is buffered.
    ///
    /// # Errors
    /// As [`Self::columns`].
    fn finish(&mut self) -> Result<()> {
        Ok(())
    }
}

impl Sink for Results {
    fn columns(&mut self, columns: &[String], rows: usize) -> Result<()> {
        self.columns = columns.to_vec();
        // Room for every row up front, written once so that its pages are mapped now: the
        // loop neither allocates nor page-faults on new rows (measured: 2.5 % of the TMT loop).
        // (vec![0.0; n] would take zeroed pages from the kernel, mapped only when first
        // written: in the loop.)
        let mut values = Vec::with_capacity(rows * columns.len());
        values.resize(rows * columns.len(), 0.0);
        self.values = values;
        self.filled = 0;
        Ok(())
    }

    fn row(&mut self, row: &[f64]) -> Result<()> {
        let at = self.filled;
        if self.values.len() < at + row.len() {
            self.values.resize(at + row.len(), 0.0);
        }
        self.values[at..at + row.len()].copy_from_slice(row);
        self.filled += row.len();
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        self.values.truncate(self.filled);
        Ok(())
    }
}

/// A CSV file written row by row as the run goes (a header row, "time" first; full-precision
/// values, as [`Results::write_csv`]).
pub struct CsvSink {
    path: PathBuf,
    /// Opened when the columns are known (a run that fails in its set-up leaves no file).
    out: Option<std::io::BufWriter<std::fs::File>>,
    rows: usize,
}

impl CsvSink {
    /// A sink that writes `path` (created, or truncated, when the run knows its columns).
    ///
    /// # Errors
    /// None yet (kept for the callers' sake; the file's errors come with the columns).
    pub fn create(path: &Path) -> Result<Self> {
        Ok(Self {
            path: path.to_path_buf(),
            out: None,
            rows: 0,
        })
    }

    /// Rows written so far.
    pub fn rows(&self) -> usize {
        self.rows
    }
}

impl Sink for CsvSink {
    fn columns(&mut self, columns: &[String], _rows: usize) -> Result<()> {
        use std::io::Write;
        let f = std::fs::File::create(&self.path).map_err(crate::error::io(&self.path))?;
        let mut out = std::io::BufWriter::with_capacity(1 << 16, f);
        writeln!(out, "{}", columns.join(",")).map_err(crate::error::io(&self.path))?;
        self.out = Some(out);
        Ok(())
    }

    fn row(&mut self, row: &[f64]) -> Result<()> {
        // The path borrowed beside the writer: no copy of it per row.
        let path = &self.path;
        let out = self.out.as_mut().ok_or_else(|| {
            CosimError::Invalid(format!("{}: a row before the columns", path.display()))
        })?;
        // The error's path is made only on an error: no allocation per row.
        write_csv_row(out, row).map_err(|e| crate::error::io(path)(e))?;
        self.rows += 1;
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        use std::io::Write;
        match self.out.as_mut() {
            Some(out) => out.flush().map_err(crate::error::io(&self.path)),
            None => Ok(()),
        }
    }
}

/// One CSV row of numbers in full precision: each the shortest decimal that reads back as
/// the same value (`1e-3` as `0.001`, `1.7e-9` as `1.7e-9`; NaN and infinities as std writes
/// them, `NaN`, `inf`, `-inf`).
fn write_csv_row(w: &mut impl std::io::Write, row: &[f64]) -> std::io::Result<()> {
    let mut buf = zmij::Buffer::new();
    for (k, v) in row.iter().enumerate() {
        if k > 0 {
            w.write_all(b",")?;
        }
        w.write_all(buf.format(*v).as_bytes())?;
    }
    w.write_all(b"\n")
}

/// What a run records and when it stops early.
#[derive(Debug, Clone, Copy, Default)]
pub struct RunOptions<'a> {
    /// The signals to record: `component.signal` or patterns (see [`Simulation::new`]).
    pub record: &'a [String],
    /// Record every `decimation` base steps (and at the start); 0 counts as 1.
    pub decimation: usize,
    /// Raised from elsewhere (a signal handler, another thread): the run stops after the step
    /// under way, with the rows recorded until then ([`Report::interrupted`]).
    pub stop: Option<&'a AtomicBool>,
}

/// What a run reports besides its rows.
#[derive(Debug, Clone, Default)]
pub struct Report {
    /// Where the time went.
    pub timing: Timing,
    /// The component that ended the simulation before the stop time, and when.
    pub ended: Option<Ended>,
    /// The time at which the stop flag ended the run, if it did (s).
    pub interrupted: Option<f64>,
    /// Rows handed to the sink.
    pub rows: usize,
}

/// Runs `system` to its stop time, handing the recorded rows to `sink` as they come.
/// `progress` is called after every step with (time, stop time).
///
/// # Errors
/// As [`Simulation::new`] and [`Simulation::step`] (and the sink's errors); the rows until an
/// error are in the sink (finished), and [`Failure::partial`] is `None`.
pub fn run_into(
    system: &System,
    options: &RunOptions,
    sink: &mut dyn Sink,
    progress: &mut dyn FnMut(f64, f64),
) -> std::result::Result<Report, Box<Failure>> {
    let decimation = options.decimation.max(1);
    let mut sim =
        Simulation::new(system, options.record).map_err(|e| Box::new(Failure::from(e)))?;
    let mut columns = vec!["time".to_string()];
    columns.extend(sim.recorded_columns().iter().cloned());
    let steps = ((system.stop_time - system.start_time) / system.step - 1e-6)
        .ceil()
        .max(0.0) as usize;
    sink.columns(&columns, steps / decimation + 1)
        .map_err(|e| Box::new(Failure::from(e)))?;
    let width = columns.len();
    // Rows taken after the oldest step now on the look-ahead thread began wait here (with their
    // base step) until it is back: if that step fails or ends the run, the sequential order
    // would have stopped before them, and they are dropped (so the look-ahead changes no row
    // and no outcome); a recorded component's step there patches the rows that missed its
    // outputs.
    let mut held = HeldRows::new(width);
    let sample = |sim: &Simulation, row: &mut [f64]| {
        row[0] = sim.time();
        sim.recorded_values(&mut row[1..]);
    };
    sim.set_late_rows(true);
    let patch = |sim: &mut Simulation, held: &mut HeldRows| {
        sim.take_late(|due, upto, values| held.patch(due, upto, values));
    };
    sample(&sim, held.push(0));
    let mut stopped = held.flush(sink, 0).err();
    let mut k = 0usize;
    let t0 = Instant::now();
    let mut interrupted = None;
    while stopped.is_none() && !sim.finished() {
        if options.stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            interrupted = Some(sim.time());
            break;
        }
        if let Err(e) = sim.step() {
            stopped = Some(e);
            break;
        }
        k += 1;
        if k.is_multiple_of(decimation) {
            sample(&sim, held.push(k as u64));
        }
        patch(&mut sim, &mut held);
        // Rows before the oldest step in flight began are final.
        let upto = sim.in_flight_since().unwrap_or(u64::MAX);
        if let Err(e) = held.flush(sink, upto) {
            stopped = Some(e);
        }
        progress(sim.time(), sim.stop_time());
    }
    // The component still on the look-ahead thread comes back. Its step began before any step
    // that failed since, so in the sequential order its error comes first; an error that came
    // from it (now or inside a step) keeps only the rows up to the base step where it began.
    let settled = sim.settle();
    patch(&mut sim, &mut held);
    let stopped = match settled {
        Err(e) => Some(e),
        Ok(()) => stopped,
    };
    let upto = sim.lookahead_failed_at().unwrap_or(u64::MAX);
    if let Err(e) = held.flush(sink, upto)
        && stopped.is_none()
    {
        return Err(Box::new(Failure::from(e)));
    }
    let (mut failed, mut ended) = (None, None);
    match stopped {
        Some(CosimError::Ended { component, time }) => ended = Some(Ended { component, time }),
        Some(e) => failed = Some(e),
        None => {}
    }
    if let Err(e) = sink.finish()
        && failed.is_none()
    {
        failed = Some(e);
    }
    if let Some(error) = failed {
        return Err(Box::new(Failure {
            error,
            partial: None,
        }));
    }
    let timing = Timing {
        loop_seconds: t0.elapsed().as_secs_f64(),
        fmu_seconds: sim.fmu_critical_seconds(),
        components: sim.component_seconds(),
        setup_components: sim.component_setup_seconds(),
        lookahead_steps: sim.lookahead_steps(),
        lookahead_memo_steps: sim.lookahead_memo_steps(),
        lookahead_trials: sim.lookahead_trials().to_vec(),
    };
    sim.terminate().map_err(|e| Box::new(Failure::from(e)))?;
    Ok(Report {
        timing,
        ended,
        interrupted,
        rows: held.written,
    })
}

/// The rows of [`run_into`] not yet handed to the sink, oldest first: rows of `width` values
/// from row `start` on, with their base steps. Flushed rows are skipped, not moved; the buffer
/// is compacted once [`Self::COMPACT`] of them have gone (a row is a mirror's 1476
/// displacements when they are recorded, and the rows after the oldest step on the look-ahead
/// thread are held every step).
struct HeldRows {
    width: usize,
    values: Vec<f64>,
    at: Vec<u64>,
    start: usize,
    /// Rows handed to the sink so far.
    written: usize,
}

impl HeldRows {
    const COMPACT: usize = 64;

    fn new(width: usize) -> Self {
        // Room for the rows a run usually holds at once, reserved before the loop.
        let rows = 2 * Self::COMPACT;
        Self {
            width,
            values: Vec::with_capacity(rows * width),
            at: Vec::with_capacity(rows),
            start: 0,
            written: 0,
        }
    }

    /// Room for the row of base step `at`, to be filled.
    fn push(&mut self, at: u64) -> &mut [f64] {
        debug_assert!(
            self.at.last().is_none_or(|&last| last < at),
            "rows out of order"
        );
        let end = self.values.len();
        self.values.resize(end + self.width, 0.0);
        self.at.push(at);
        &mut self.values[end..]
    }

    /// Writes `values` (`(column, value)`, columns counted without time) into the held rows
    /// of base steps `due..=upto`. The held rows' base steps ascend: only those rows are
    /// visited (a kept sink's steps catching up after a long one patch a few rows each among
    /// the many held meanwhile).
    fn patch(&mut self, due: u64, upto: u64, values: &[(usize, f64)]) {
        let w = self.width;
        let at = &self.at[self.start..];
        let first = self.start + at.partition_point(|&a| a < due);
        let end = self.start + at.partition_point(|&a| a <= upto);
        if first >= end {
            return;
        }
        for row in self.values[first * w..end * w].chunks_exact_mut(w.max(1)) {
            for &(c, v) in values {
                row[1 + c] = v;
            }
        }
    }

    /// Hands the held rows of base steps up to `upto` to `sink`.
    fn flush(&mut self, sink: &mut dyn Sink, upto: u64) -> Result<()> {
        let w = self.width;
        while self.start < self.at.len() && self.at[self.start] <= upto {
            sink.row(&self.values[self.start * w..(self.start + 1) * w])?;
            self.start += 1;
            self.written += 1;
        }
        if self.start == self.at.len() {
            self.values.clear();
            self.at.clear();
            self.start = 0;
        } else if self.start >= Self::COMPACT {
            self.values.drain(..self.start * w);
            self.at.drain(..self.start);
            self.start = 0;
        }
        Ok(())
    }
}

/// Runs `system` to its stop time, recording `record` every `decimation` base steps (and at
/// the start) into memory ([`run_into`] with [`Results`] as the sink). `progress` is called
/// after every step with (time, stop time).
///
/// # Errors
/// As [`Simulation::new`] and [`Simulation::step`]; an error during the steps comes with the
/// results recorded until then ([`Failure::partial`]).
pub fn run(
    system: &System,
    record: &[String],
    decimation: usize,
    progress: &mut dyn FnMut(f64, f64),
) -> std::result::Result<Results, Box<Failure>> {
    let mut results = Results::empty();
    let options = RunOptions {
        record,
        decimation,
        stop: None,
    };
    match run_into(system, &options, &mut results, progress) {
        Ok(report) => {
            results.timing = report.timing;
            results.ended = report.ended;
            Ok(results)
        }
        Err(mut f) => {
            // Failed before the first row: nothing to keep.
            if !results.columns.is_empty() {
                f.partial = Some(results);
            }
            Err(f)
        }
    }
}

#[cfg(test)]
mod tests {
    /// A CSV row reads back the same values to the bit, the special ones included, and a
    /// round number is written as a decimal.
    #[test]
    fn csv_rows_read_back_the_same_values() {
        let row = [
            0.0,
            -0.0,
            1e-3,
            1.7119416889180317e-9,
            -2.5,
            1e300,
            f64::MAX,
            f64::MIN_POSITIVE,
            5e-324,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        let mut out = Vec::new();
        super::write_csv_row(&mut out, &row).unwrap();
        let text = String::from_utf8(out).unwrap();
        assert!(text.starts_with("0.0,-0.0,0.001,"), "{text}");
        assert!(text.ends_with(",NaN,inf,-inf\n"), "{text}");
        let back: Vec<f64> = text
            .trim_end()
            .split(',')
            .map(|s| s.parse().unwrap())
            .collect();
        assert_eq!(back.len(), row.len());
        for (a, b) in row.iter().zip(&back) {
            if a.is_nan() {
                assert!(b.is_nan());
            } else {
                assert_eq!(a.to_bits(), b.to_bits(), "{a:e} read back as {b:e}");
            }
        }
    }
}
