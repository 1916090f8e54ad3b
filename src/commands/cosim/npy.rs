//! The binary output of `m1cs run --format npy`: each run's rows as one 2-D float64 array in a
//! NumPy `.npy` file (C order, `rows x columns`, memory-mappable: `np.load(f, mmap_mode="r")`),
//! written row by row as the run goes through `npyz`, with the column names in a `.json` file
//! beside it from the first row on (its `rows` is null until the run ends). The header announces
//! the rows of the whole run; a run that stops early (a signal, a component ending it, a
//! failure) has its header's row count rewritten to the rows it wrote.

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
        // The column names from the start: a run killed outright leaves them too.
        self.write_json()
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
        let Some(w) = self.writer.take() else {
            return Ok(());
        };
        if self.written == self.rows {
            w.finish().map_err(|e| self.io(e))?;
        } else {
            // A run that stopped early: the array holds the rows written. Dropping the writer
            // flushes them (npyz refuses to finish short of the shape it announced), then the
            // header's row count is rewritten in place.
            drop(w);
            self.shorten().map_err(|e| self.io(e))?;
        }
        self.write_json()
    }
}

impl NpySink {
    /// The `.json` beside the array: its column names and the rows written so far (`null`
    /// while the run goes on).
    fn write_json(&self) -> cosim::Result<()> {
        let mut json = self.path.clone().into_os_string();
        json.push(".json");
        let json = PathBuf::from(json);
        let done = self.writer.is_none();
        let text = serde_json::json!({
            "columns": self.columns,
            "rows": if done { serde_json::json!(self.written) } else { serde_json::Value::Null },
            "shape": [if done { self.written } else { self.rows }, self.columns.len()],
            "dtype": "float64",
            "order": "C",
        })
        .to_string();
        std::fs::write(&json, text).map_err(|e| CosimError::Io {
            path: json,
            source: e,
        })
    }

    /// Rewrites the shape in the header of the `.npy` to the rows written: the header keeps its
    /// length (the new count has no more digits; spaces pad it, as the format allows).
    fn shorten(&self) -> std::io::Result<()> {
        use std::io::{Read, Seek, SeekFrom};
        let bad = |why: &str| std::io::Error::other(format!("npy header: {why}"));
        let mut f = std::fs::File::options()
            .read(true)
            .write(true)
            .open(&self.path)?;
        let mut head = [0u8; 10];
        f.read_exact(&mut head)?;
        if &head[..6] != b"\x93NUMPY" {
            return Err(bad("no magic"));
        }
        let (start, len) = match head[6] {
            1 => (10usize, usize::from(u16::from_le_bytes([head[8], head[9]]))),
            _ => {
                let mut more = [0u8; 2];
                f.read_exact(&mut more)?;
                (
                    12,
                    u32::from_le_bytes([head[8], head[9], more[0], more[1]]) as usize,
                )
            }
        };
        let mut text = vec![0u8; len];
        f.seek(SeekFrom::Start(start as u64))?;
        f.read_exact(&mut text)?;
        let text = String::from_utf8(text).map_err(|_| bad("not text"))?;
        let at = text.find("'shape': (").ok_or_else(|| bad("no shape"))? + "'shape': (".len();
        let end = at + text[at..].find(')').ok_or_else(|| bad("no shape"))?;
        let mut new = format!(
            "{}{}, {}{}",
            &text[..at],
            self.written,
            self.columns.len(),
            &text[end..]
        );
        let body = new.trim_end_matches(['\n', ' ']).len();
        new.truncate(body);
        if new.len() + 1 > len {
            return Err(bad("no room"));
        }
        new.extend(std::iter::repeat_n(' ', len - 1 - new.len()));
        new.push('\n');
        f.seek(SeekFrom::Start(start as u64))?;
        f.write_all(new.as_bytes())?;
        let data = (self.written * self.columns.len() * 8) as u64;
        f.set_len(start as u64 + len as u64 + data)?;
        Ok(())
    }
}
