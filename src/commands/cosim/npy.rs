//! The binary output of `m1cs run --format npy`: each run's rows as one 2-D float64 array in a
//! NumPy `.npy` file (C order, `rows x columns`, memory-mappable: `np.load(f, mmap_mode="r")`),
//! written row by row as the run goes through `npyz`, with the column names and the number of
//! rows written in a `.json` file beside it. The array's shape is the rows of the whole run; a
//! run that stops early (a signal, a component ending it, a failure) fills the rows it did not
//! reach with NaN, and the JSON says how many it wrote.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use cosim::CosimError;
use npyz::WriterBuilder;

/// A `.npy` file and its `.json` column list, written as the rows come.
pub(super) struct NpySink {
    path: PathBuf,
    writer: Option<npyz::NpyWriter<f64, BufWriter<std::fs::File>>>,
    columns: Vec<String>,
    rows: usize,
    written: usize,
}

impl NpySink {
    /// A sink writing `path` (and `path` with `.json` appended).
    pub(super) fn new(path: &Path) -> Self {
        Self {
            path: path.to_path_buf(),
            writer: None,
            columns: Vec::new(),
            rows: 0,
            written: 0,
        }
    }

    fn io(&self, e: std::io::Error) -> CosimError {
        CosimError::Io {
            path: self.path.clone(),
            source: e,
        }
    }
}

impl cosim::system::Sink for NpySink {
    fn columns(&mut self, columns: &[String], rows: usize) -> cosim::Result<()> {
        let f = std::fs::File::create(&self.path).map_err(|e| self.io(e))?;
        let writer = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[rows as u64, columns.len() as u64])
            .writer(BufWriter::with_capacity(1 << 16, f))
            .begin_nd()
            .map_err(|e| self.io(e))?;
        self.writer = Some(writer);
        self.columns = columns.to_vec();
        self.rows = rows;
        Ok(())
    }

    fn row(&mut self, row: &[f64]) -> cosim::Result<()> {
        if self.written >= self.rows {
            return Err(CosimError::Invalid(format!(
                "{}: more rows than the {} announced",
                self.path.display(),
                self.rows
            )));
        }
        let Some(w) = self.writer.as_mut() else {
            return Err(CosimError::Invalid(format!(
                "{}: a row before the columns",
                self.path.display()
            )));
        };
        let r = row.iter().try_for_each(|v| w.push(v));
        r.map_err(|e| self.io(e))?;
        self.written += 1;
        Ok(())
    }

    fn finish(&mut self) -> cosim::Result<()> {
        let Some(mut w) = self.writer.take() else {
            return Ok(());
        };
        // The rows a run that stopped early did not reach.
        let missing = (self.rows - self.written) * self.columns.len();
        let r = (0..missing).try_for_each(|_| w.push(&f64::NAN));
        r.map_err(|e| self.io(e))?;
        w.finish().map_err(|e| self.io(e))?;
        let mut json = self.path.clone().into_os_string();
        json.push(".json");
        let json = PathBuf::from(json);
        let text = serde_json::json!({
            "columns": self.columns,
            "rows": self.written,
            "shape": [self.rows, self.columns.len()],
            "dtype": "float64",
            "order": "C",
        })
        .to_string();
        let mut f = std::fs::File::create(&json).map_err(|e| CosimError::Io {
            path: json.clone(),
            source: e,
        })?;
        f.write_all(text.as_bytes()).map_err(|e| CosimError::Io {
            path: json,
            source: e,
        })
    }
}
