//! Reading NumPy `.npy` arrays and `.npz` archives (little-endian float64, C or Fortran order):
//! the import format of the structure's modal models. The `.npy` format is read by the `npyz`
//! crate; an `.npz` is a zip archive of them, opened with the `zip` crate. What is ours: the
//! checks and messages that name the array at fault, and the reordering of a Fortran-order
//! array into C order.

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

/// Parses the bytes of one `.npy` file (any format version; little-endian float64 only) with
/// the `npyz` crate.
///
/// # Errors
/// A message saying what is wrong (the caller adds the file and array names).
pub fn parse_npy(bytes: &[u8]) -> Result<NpyArray, String> {
    let mut rest = bytes;
    let file =
        npyz::NpyFile::new(&mut rest).map_err(|e| format!("not a readable NPY array: {e}"))?;
    match file.dtype() {
        npyz::DType::Plain(ty) if ty.to_string() == "<f8" => {}
        other => {
            return Err(format!(
                "dtype {}, expected little-endian float64 '<f8' (write it with \
                 numpy.asarray(a, dtype='<f8'))",
                other.descr()
            ));
        }
    }
    let shape = file
        .shape()
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| format!("dimension {d} is too large")))
        .collect::<Result<Vec<usize>, String>>()?;
    let bytes_needed = shape
        .iter()
        .try_fold(8usize, |a, &d| a.checked_mul(d))
        .ok_or("the shape is too large")?;
    let fortran = file.order() == npyz::Order::Fortran;
    let raw: Vec<f64> = file.into_vec().map_err(|e| {
        format!("shape {shape:?} needs {bytes_needed} data bytes, the array has fewer ({e})")
    })?;
    if !rest.is_empty() {
        return Err(format!(
            "shape {shape:?} needs {bytes_needed} data bytes, the array has {}",
            bytes_needed + rest.len()
        ));
    }
    let data = if fortran && shape.len() > 1 {
        c_order_from_fortran(&raw, &shape)
    } else {
        raw
    };
    Ok(NpyArray { shape, data })
}

/// The elements of a Fortran-order array of `shape` in C order: element `(i_0, .., i_{d-1})`
/// sits at `sum i_k s_k` with the Fortran strides `s_0 = 1`, `s_k = s_{k-1} n_{k-1}`.
fn c_order_from_fortran(raw: &[f64], shape: &[usize]) -> Vec<f64> {
    let d = shape.len();
    let mut stride = vec![1usize; d];
    for k in 1..d {
        stride[k] = stride[k - 1] * shape[k - 1];
    }
    let mut out = Vec::with_capacity(raw.len());
    let mut idx = vec![0usize; d];
    for _ in 0..raw.len() {
        out.push(raw[idx.iter().zip(&stride).map(|(i, s)| i * s).sum::<usize>()]);
        for k in (0..d).rev() {
            idx[k] += 1;
            if idx[k] < shape[k] {
                break;
            }
            idx[k] = 0;
        }
    }
    out
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
