//! Reading NumPy `.npy` arrays and `.npz` archives (little-endian float64, C or Fortran order):
//! the import format of the structure's modal models.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use crate::M1Error;

/// An array read from a `.npy` file: its shape and its elements in C (row-major) order.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    /// Shape (empty for a 0-d scalar).
    pub shape: Vec<usize>,
    /// Elements, C order.
    pub data: Vec<f64>,
}

fn header_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let pos = header
        .find(&format!("'{key}'"))
        .or_else(|| header.find(&format!("\"{key}\"")))?;
    let rest = &header[pos + key.len() + 2..];
    let colon = rest.find(':')?;
    Some(rest[colon + 1..].trim_start())
}

/// Parses the bytes of one `.npy` file (format 1.0, 2.0 or 3.0; little-endian float64 only).
///
/// # Errors
/// A message saying what is wrong (the caller adds the file and array names).
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not an NPY array (missing the \\x93NUMPY magic)".into());
    }
    let major = bytes[6];
    let (hlen, start) = match major {
        1 => (usize::from(u16::from_le_bytes([bytes[8], bytes[9]])), 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("truncated NPY header".into());
            }
            let l = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
            (l as usize, 12)
        }
        v => return Err(format!("unsupported NPY format version {v}.{}", bytes[7])),
    };
    let end = start + hlen;
    if bytes.len() < end {
        return Err(format!(
            "truncated NPY header ({hlen} bytes announced, {} present)",
            bytes.len() - start
        ));
    }
    let header = std::str::from_utf8(&bytes[start..end])
        .map_err(|_| "the NPY header is not text".to_string())?;
    let descr = header_value(header, "descr").ok_or("the NPY header has no 'descr'")?;
    let quote = descr.chars().next().ok_or("empty 'descr'")?;
    if quote != '\'' && quote != '"' {
        return Err(format!("unsupported dtype description {descr}"));
    }
    let descr = descr[1..]
        .split(quote)
        .next()
        .ok_or("unterminated 'descr'")?;
    if descr != "<f8" {
        return Err(format!(
            "dtype '{descr}', expected little-endian float64 '<f8' (write it with \
             numpy.asarray(a, dtype='<f8'))"
        ));
    }
    let fortran = header_value(header, "fortran_order").ok_or("no 'fortran_order'")?;
    let fortran = if fortran.starts_with("True") {
        true
    } else if fortran.starts_with("False") {
        false
    } else {
        return Err(format!("bad 'fortran_order' {fortran}"));
    };
    let shape_text = header_value(header, "shape").ok_or("no 'shape'")?;
    let close = shape_text.find(')').ok_or("bad 'shape'")?;
    if !shape_text.starts_with('(') {
        return Err(format!("bad 'shape' {shape_text}"));
    }
    let mut shape = Vec::new();
    for part in shape_text[1..close].split(',') {
        let p = part.trim();
        if p.is_empty() {
            continue;
        }
        shape.push(
            p.parse::<usize>()
                .map_err(|_| format!("bad dimension '{p}' in 'shape'"))?,
        );
    }
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or("the shape is too large")?;
    let body = &bytes[end..];
    if body.len() != count * 8 {
        return Err(format!(
            "shape {shape:?} needs {} data bytes, the array has {}",
            count * 8,
            body.len()
        ));
    }
    let raw: Vec<f64> = body
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
        .collect();
    let data = if fortran && shape.len() > 1 {
        // Element (i_0, .., i_{d-1}) is at sum i_k stride_k with Fortran strides.
        let d = shape.len();
        let mut fstride = vec![1usize; d];
        for k in 1..d {
            fstride[k] = fstride[k - 1] * shape[k - 1];
        }
        let mut out = Vec::with_capacity(count);
        let mut idx = vec![0usize; d];
        for _ in 0..count {
            let off: usize = idx.iter().zip(&fstride).map(|(i, s)| i * s).sum();
            out.push(raw[off]);
            for k in (0..d).rev() {
                idx[k] += 1;
                if idx[k] < shape[k] {
                    break;
                }
                idx[k] = 0;
            }
        }
        out
    } else {
        raw
    };
    Ok(NpyArray { shape, data })
}

/// A `.npz` archive open for reading arrays by name.
pub struct Npz {
    file: String,
    archive: zip::ZipArchive<std::fs::File>,
}

impl Npz {
    /// Opens `path`.
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] naming the file if it cannot be opened or is not a zip archive.
    pub fn open(path: &Path) -> Result<Self, M1Error> {
        let file = path.display().to_string();
        let f = std::fs::File::open(path)
            .map_err(|e| M1Error::InvalidInput(format!("cannot open {file}: {e}")))?;
        let archive = zip::ZipArchive::new(f).map_err(|e| {
            M1Error::InvalidInput(format!(
                "{file} is not a NumPy .npz archive (zip) file: {e}"
            ))
        })?;
        Ok(Self { file, archive })
    }

    /// Names of the arrays in the archive.
    pub fn names(&self) -> Vec<String> {
        self.archive
            .file_names()
            .filter_map(|n| n.ok()?.strip_suffix(".npy").map(str::to_string))
            .collect()
    }

    /// Reads array `name` if present.
    ///
    /// # Errors
    /// [`M1Error::InvalidInput`] naming the file and the array if it cannot be read or parsed.
    pub fn optional(&mut self, name: &str) -> Result<Option<NpyArray>, M1Error> {
        let bad =
            |why: String| M1Error::InvalidInput(format!("{}: array '{name}': {why}", self.file));
        let mut bytes = Vec::new();
        match self.archive.by_name(&format!("{name}.npy")) {
            Ok(mut entry) => {
                entry
                    .read_to_end(&mut bytes)
                    .map_err(|e| bad(format!("cannot read: {e}")))?;
            }
            Err(zip::result::ZipError::FileNotFound) => return Ok(None),
            Err(e) => return Err(bad(format!("cannot read: {e}"))),
        }
        parse_npy(&bytes).map(Some).map_err(bad)
    }

    /// Reads array `name`, which must be present.
    ///
    /// # Errors
    /// As [`Npz::optional`], and if the array is missing (listing the arrays present).
    pub fn require(&mut self, name: &str) -> Result<NpyArray, M1Error> {
        match self.optional(name)? {
            Some(a) => Ok(a),
            None => {
                let present: BTreeMap<String, ()> =
                    self.names().into_iter().map(|n| (n, ())).collect();
                Err(M1Error::InvalidInput(format!(
                    "{}: array '{name}' is missing (the file has: {})",
                    self.file,
                    present.keys().cloned().collect::<Vec<_>>().join(", ")
                )))
            }
        }
    }
}
