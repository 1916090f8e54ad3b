//! [`BackgroundSink`]: a [`Sink`] whose rows are written by a thread of its own, so that
//! formatting them (a CSV row of the TMT run's 20 columns takes about 0.2 us) is off the
//! master's thread.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use super::run::Sink;
use crate::error::{CosimError, Result};

/// Values per batch of rows handed to the writer (128 KB).
const BATCH_VALUES: usize = 1 << 14;

/// Batches in flight to the writer at most: a writer slower than the run (a slow disk) holds
/// the run back instead of filling the memory.
const BATCHES_IN_FLIGHT: usize = 8;

/// A [`Sink`] that hands its rows to `inner` on a writer thread, in batches, as the run goes.
///
/// The columns are given to `inner` on the calling thread (so that a file that cannot be
/// created fails the run before its first step); each row is then copied into a batch, and a
/// full batch goes to the writer. Its errors come back at the next row, or at
/// [`Sink::finish`], which waits for everything to be written. Dropped without `finish`, it
/// still writes every row it took before it returns.
pub struct BackgroundSink {
    /// The sink, until the writer takes it.
    inner: Option<Box<dyn Sink + Send>>,
    width: usize,
    batch: Vec<f64>,
    /// Full batches to the writer.
    to_writer: Option<SyncSender<Vec<f64>>>,
    /// Written batches back, for reuse.
    back: Option<Receiver<Vec<f64>>>,
    /// Raised by the writer when `inner` failed (it then writes nothing more).
    failed: Arc<AtomicBool>,
    writer: Option<JoinHandle<Result<()>>>,
}

impl BackgroundSink {
    /// Rows for `inner`, written on a thread of their own.
    pub fn new(inner: Box<dyn Sink + Send>) -> Self {
        Self {
            inner: Some(inner),
            width: 0,
            batch: Vec::new(),
            to_writer: None,
            back: None,
            failed: Arc::new(AtomicBool::new(false)),
            writer: None,
        }
    }

    /// Hands the batch under way to the writer (if it has rows).
    fn send_batch(&mut self) -> Result<()> {
        if self.batch.is_empty() {
            return Ok(());
        }
        let next = self
            .back
            .as_ref()
            .and_then(|b| b.try_recv().ok())
            .unwrap_or_else(|| Vec::with_capacity(BATCH_VALUES.max(self.width)));
        let full = std::mem::replace(&mut self.batch, next);
        self.batch.clear();
        match self.to_writer.as_ref().map(|tx| tx.send(full)) {
            Some(Ok(())) => Ok(()),
            // The writer is gone: its own error says why.
            _ => self.stop(),
        }
    }

    /// Stops the writer after what it was given, and gives its outcome.
    fn stop(&mut self) -> Result<()> {
        self.to_writer = None;
        self.back = None;
        match self.writer.take().map(JoinHandle::join) {
            None | Some(Ok(Ok(()))) => Ok(()),
            Some(Ok(Err(e))) => Err(e),
            Some(Err(_)) => Err(CosimError::Invalid(
                "the results' writer thread stopped unexpectedly".into(),
            )),
        }
    }
}

impl Sink for BackgroundSink {
    fn columns(&mut self, columns: &[String], rows: usize) -> Result<()> {
        let mut inner = self.inner.take().ok_or_else(|| {
            CosimError::Invalid("a background sink takes its columns once".into())
        })?;
        inner.columns(columns, rows)?;
        self.width = columns.len().max(1);
        self.batch = Vec::with_capacity(BATCH_VALUES.max(self.width));
        let (tx, rx) = sync_channel::<Vec<f64>>(BATCHES_IN_FLIGHT);
        let (back_tx, back_rx) = sync_channel::<Vec<f64>>(BATCHES_IN_FLIGHT + 1);
        let (width, failed) = (self.width, Arc::clone(&self.failed));
        let writer = std::thread::Builder::new()
            .name("cosim-writer".into())
            .spawn(move || write_batches(inner, width, &rx, &back_tx, &failed))
            .map_err(|e| CosimError::Invalid(format!("cannot start the results' writer: {e}")))?;
        self.to_writer = Some(tx);
        self.back = Some(back_rx);
        self.writer = Some(writer);
        Ok(())
    }

    fn row(&mut self, row: &[f64]) -> Result<()> {
        if self.failed.load(Ordering::Relaxed) {
            return self.stop().and(Err(CosimError::Invalid(
                "the results' writer failed".into(),
            )));
        }
        if self.writer.is_none() {
            return Err(CosimError::Invalid(
                "a row before the columns, or after the writer stopped".into(),
            ));
        }
        if row.len() != self.width {
            return Err(CosimError::Invalid(format!(
                "a row of {} values for {} columns",
                row.len(),
                self.width
            )));
        }
        self.batch.extend_from_slice(row);
        if self.batch.len() + self.width > BATCH_VALUES.max(self.width) {
            self.send_batch()?;
        }
        Ok(())
    }

    fn finish(&mut self) -> Result<()> {
        let sent = self.send_batch();
        let stopped = self.stop();
        sent.and(stopped)
    }
}

impl Drop for BackgroundSink {
    fn drop(&mut self) {
        // Every row taken is written (errors go unseen here: `finish` reports them).
        let _ = self.send_batch();
        let _ = self.stop();
    }
}

/// The writer's loop: each batch's rows into `inner`, until the sink is finished (the sender
/// gone); then `inner`'s own finish.
fn write_batches(
    mut inner: Box<dyn Sink + Send>,
    width: usize,
    batches: &Receiver<Vec<f64>>,
    back: &SyncSender<Vec<f64>>,
    failed: &AtomicBool,
) -> Result<()> {
    let mut outcome = Ok(());
    while let Ok(batch) = batches.recv() {
        if outcome.is_ok() {
            for row in batch.chunks_exact(width) {
                if let Err(e) = inner.row(row) {
                    failed.store(true, Ordering::Relaxed);
                    outcome = Err(e);
                    break;
                }
            }
        }
        // For reuse; none wanted once the run has enough.
        let _ = back.try_send(batch);
    }
    let finished = inner.finish();
    outcome.and(finished)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::system::Results;
    use std::sync::Mutex;

    /// A sink into a shared table, failing at a given row if asked.
    struct Shared {
        rows: Arc<Mutex<Vec<Vec<f64>>>>,
        fail_at: Option<usize>,
        finished: Arc<AtomicBool>,
    }

    impl Sink for Shared {
        fn columns(&mut self, _columns: &[String], _rows: usize) -> Result<()> {
            Ok(())
        }
        fn row(&mut self, row: &[f64]) -> Result<()> {
            let mut rows = self.rows.lock().unwrap();
            if Some(rows.len()) == self.fail_at {
                return Err(CosimError::Invalid("disk full".into()));
            }
            rows.push(row.to_vec());
            Ok(())
        }
        fn finish(&mut self) -> Result<()> {
            self.finished.store(true, Ordering::SeqCst);
            Ok(())
        }
    }

    fn columns(n: usize) -> Vec<String> {
        (0..n).map(|k| format!("c{k}")).collect()
    }

    #[test]
    fn every_row_arrives_in_order_and_finish_waits_for_them() {
        let rows = Arc::new(Mutex::new(Vec::new()));
        let finished = Arc::new(AtomicBool::new(false));
        let mut sink = BackgroundSink::new(Box::new(Shared {
            rows: Arc::clone(&rows),
            fail_at: None,
            finished: Arc::clone(&finished),
        }));
        sink.columns(&columns(3), 0).unwrap();
        // Several batches and a partial one.
        let n = BATCH_VALUES + 17;
        for k in 0..n {
            let k = k as f64;
            sink.row(&[k, 2.0 * k, -k]).unwrap();
        }
        sink.finish().unwrap();
        assert!(
            finished.load(Ordering::SeqCst),
            "the inner sink was finished"
        );
        let rows = rows.lock().unwrap();
        assert_eq!(rows.len(), n);
        for (k, r) in rows.iter().enumerate() {
            let k = k as f64;
            assert_eq!(r, &[k, 2.0 * k, -k]);
        }
    }

    #[test]
    fn the_writers_error_comes_back() {
        let rows = Arc::new(Mutex::new(Vec::new()));
        let mut sink = BackgroundSink::new(Box::new(Shared {
            rows: Arc::clone(&rows),
            fail_at: Some(5),
            finished: Arc::new(AtomicBool::new(false)),
        }));
        sink.columns(&columns(2), 0).unwrap();
        // One full batch goes to the writer (with its last row), which fails at its sixth row.
        // (One row more could find the writer failed already: a race, not the test's point.)
        for k in 0..BATCH_VALUES / 2 {
            sink.row(&[k as f64, 0.0]).unwrap();
        }
        let t0 = std::time::Instant::now();
        while !sink.failed.load(Ordering::Relaxed) {
            assert!(t0.elapsed().as_secs() < 10, "the writer never failed");
            std::thread::yield_now();
        }
        let e = sink.row(&[0.0, 0.0]).expect_err("the next row reports it");
        assert!(e.to_string().contains("disk full"), "{e}");
        assert_eq!(
            rows.lock().unwrap().len(),
            5,
            "nothing written after the failure"
        );
        assert!(sink.row(&[0.0, 0.0]).is_err(), "nor taken");
    }

    #[test]
    fn a_failure_in_the_last_batch_comes_with_finish() {
        let mut sink = BackgroundSink::new(Box::new(Shared {
            rows: Arc::new(Mutex::new(Vec::new())),
            fail_at: Some(1),
            finished: Arc::new(AtomicBool::new(false)),
        }));
        sink.columns(&columns(1), 0).unwrap();
        sink.row(&[1.0]).unwrap();
        sink.row(&[2.0]).unwrap();
        let e = sink.finish().expect_err("the second row failed");
        assert!(e.to_string().contains("disk full"), "{e}");
    }

    #[test]
    fn rows_of_the_wrong_width_and_rows_before_the_columns_are_refused() {
        let mut sink = BackgroundSink::new(Box::new(Results::empty()));
        assert!(sink.row(&[1.0]).is_err(), "before the columns");
        sink.columns(&columns(2), 4).unwrap();
        let e = sink.row(&[1.0]).expect_err("one value for two columns");
        assert!(e.to_string().contains("2 columns"), "{e}");
        sink.row(&[1.0, 2.0]).unwrap();
        sink.finish().unwrap();
    }

    #[test]
    fn a_csv_file_is_the_same_as_written_in_place() {
        let dir = std::env::temp_dir().join(format!("cosim-bg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (a, b) = (dir.join("a.csv"), dir.join("b.csv"));
        let mut direct = super::super::run::CsvSink::create(&a).unwrap();
        let mut bg = BackgroundSink::new(Box::new(super::super::run::CsvSink::create(&b).unwrap()));
        let cols = columns(4);
        direct.columns(&cols, 0).unwrap();
        bg.columns(&cols, 0).unwrap();
        for k in 0..10_000 {
            let x = k as f64;
            let row = [x * 1e-3, x.sin(), 1.0 / (x + 1.0), -x * 1.7e-9];
            direct.row(&row).unwrap();
            bg.row(&row).unwrap();
        }
        direct.finish().unwrap();
        bg.finish().unwrap();
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
