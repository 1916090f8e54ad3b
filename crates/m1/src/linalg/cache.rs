//! An on-disk cache of arrays that take long to compute and little to read: the structure's
//! modes (the retained ones by block Lanczos, 60 ms for TMT's 60, or a dense eigensolve of
//! all, 0.4 s) and the wind's tables (the pressure screen's spectrum and its inverse FFTs,
//! 0.12 s for TMT), so that the first run of a process, and of every FMU instance in an
//! importer, does not pay them again.
//!
//! - **Where.** `M1CS_CACHE_DIR` if set, else `$XDG_CACHE_HOME/m1cs`, else `$HOME/.cache/m1cs`.
//!   `M1CS_CACHE=off` turns the cache off (nothing read or written). `m1cs cache` lists the
//!   entries and `m1cs cache --clear` removes them; deleting the folder is as good.
//! - **Keys.** An entry is named by its kind and a SHA-256 [`Fingerprint`] of everything its
//!   arrays are computed from (for the modes the assembled stiffness and mass themselves, for
//!   the wind the screen's parameters and the segments' positions), together with the build's
//!   own fingerprint (this crate's sources and the workspace's Cargo.lock, hashed by
//!   `build.rs`): a change of inputs, of the code or of a dependency's version gives another
//!   name, so an entry is never stale, only unused.
//! - **Files.** An entry is a NumPy `.npz` archive of float64 arrays (stored, not compressed),
//!   written to a temporary name and renamed into place, so a reader sees a whole entry or
//!   none. A corrupt entry (a CRC or shape that does not check, a missing array) reads as a
//!   miss; it is removed and rebuilt by the caller.
//! - **Size.** After each store the oldest entries (by modification time, refreshed on every
//!   hit) are removed while the folder holds more than `M1CS_CACHE_MAX_MB` (default 2048) MB.
//!
//! The cache only ever saves time: a failure to read or write it is silent and the arrays are
//! computed as without it.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use npyz::WriterBuilder;
use sha2::{Digest, Sha256};

use super::npy::{NpyArray, parse_npy};

/// The fingerprint of this build: this crate's sources and the workspace's Cargo.lock.
const BUILD: &str = env!("M1_BUILD_FINGERPRINT");

/// Default size limit of the cache folder (MB).
const DEFAULT_MAX_MB: u64 = 2048;

/// A SHA-256 of an entry's inputs (and of the build), fed piece by piece.
#[derive(Clone)]
pub struct Fingerprint {
    kind: &'static str,
    hasher: Sha256,
}

impl Fingerprint {
    /// A fingerprint for an entry of kind `kind` (a file-name prefix: `modes`, `wind`).
    pub fn new(kind: &'static str) -> Self {
        let mut hasher = Sha256::new();
        hasher.update(BUILD.as_bytes());
        hasher.update(kind.as_bytes());
        // The kernels the libraries pick at run time (FFT, eigensolver) depend on the CPU: a
        // folder shared between machines keeps their entries apart.
        hasher.update(std::env::consts::ARCH.as_bytes());
        hasher.update(std::env::consts::OS.as_bytes());
        #[cfg(target_arch = "x86_64")]
        for (name, has) in [
            ("avx", std::arch::is_x86_feature_detected!("avx")),
            ("avx2", std::arch::is_x86_feature_detected!("avx2")),
            ("fma", std::arch::is_x86_feature_detected!("fma")),
            ("avx512f", std::arch::is_x86_feature_detected!("avx512f")),
        ] {
            hasher.update(name.as_bytes());
            hasher.update([u8::from(has)]);
        }
        Self { kind, hasher }
    }

    /// Feeds bytes (length-prefixed, so that consecutive pieces cannot run into each other).
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.hasher.update((b.len() as u64).to_le_bytes());
        self.hasher.update(b);
        self
    }

    /// Feeds float64 values by their bits.
    pub fn f64s(&mut self, v: &[f64]) -> &mut Self {
        self.hasher.update((v.len() as u64).to_le_bytes());
        let mut block = [0u8; 8 * 1024];
        for chunk in v.chunks(1024) {
            for (b, x) in block.chunks_exact_mut(8).zip(chunk) {
                b.copy_from_slice(&x.to_bits().to_le_bytes());
            }
            self.hasher.update(&block[..8 * chunk.len()]);
        }
        self
    }

    /// Feeds unsigned integers.
    pub fn usizes(&mut self, v: &[usize]) -> &mut Self {
        self.hasher.update((v.len() as u64).to_le_bytes());
        for x in v {
            self.hasher.update((*x as u64).to_le_bytes());
        }
        self
    }

    /// The entry's file name: `<kind>-<64 hex digits>.npz`.
    pub fn file_name(&self) -> String {
        let digest = self.hasher.clone().finalize();
        let hex: String = digest.iter().map(|b| format!("{b:02x}")).collect();
        format!("{}-{hex}.npz", self.kind)
    }
}

/// A cache folder (or none: every load misses, every store does nothing).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Store {
    dir: Option<PathBuf>,
}

impl Store {
    /// The folder the environment names (module docs): `M1CS_CACHE_DIR`, else
    /// `$XDG_CACHE_HOME/m1cs`, else `$HOME/.cache/m1cs`; none with `M1CS_CACHE=off`.
    pub fn from_env() -> Self {
        if std::env::var("M1CS_CACHE").is_ok_and(|v| v.eq_ignore_ascii_case("off") || v == "0") {
            return Self { dir: None };
        }
        let nonempty = |k: &str| {
            std::env::var_os(k)
                .filter(|v| !v.is_empty())
                .map(PathBuf::from)
        };
        Self {
            dir: nonempty("M1CS_CACHE_DIR")
                .or_else(|| nonempty("XDG_CACHE_HOME").map(|d| d.join("m1cs")))
                .or_else(|| nonempty("HOME").map(|d| d.join(".cache").join("m1cs"))),
        }
    }

    /// The folder `dir`.
    pub fn at(dir: impl Into<PathBuf>) -> Self {
        Self {
            dir: Some(dir.into()),
        }
    }

    /// No cache.
    pub fn off() -> Self {
        Self { dir: None }
    }

    /// The folder, if any.
    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    /// The arrays `names` of the entry `key`, if it is there and whole. A corrupt entry is
    /// removed (and reads as a miss). A hit refreshes the entry's modification time (the size
    /// limit removes the least recently used first).
    pub fn load(&self, key: &Fingerprint, names: &[&str]) -> Option<Vec<NpyArray>> {
        let path = self.dir.as_ref()?.join(key.file_name());
        if !path.is_file() {
            return None;
        }
        match read_entry(&path, names) {
            Some(arrays) => {
                if let Ok(f) = std::fs::File::options().append(true).open(&path) {
                    let _ = f.set_modified(std::time::SystemTime::now());
                }
                Some(arrays)
            }
            None => {
                let _ = std::fs::remove_file(&path);
                None
            }
        }
    }

    /// Stores `arrays` (name, shape, C-order values) as the entry `key`, then trims the folder
    /// to its size limit. Silent on failure (the cache only saves time).
    pub fn store(&self, key: &Fingerprint, arrays: &[(&str, &[usize], &[f64])]) {
        let Some(dir) = self.dir.as_ref() else {
            return;
        };
        if std::fs::create_dir_all(dir).is_err() {
            return;
        }
        let path = dir.join(key.file_name());
        // A random name, created exclusively (write_entry), for each writer.
        let tmp = dir.join(format!(
            ".{}.{}.{:016x}.tmp",
            key.file_name(),
            std::process::id(),
            rand::random::<u64>()
        ));
        if write_entry(&tmp, arrays).is_ok() && std::fs::rename(&tmp, &path).is_ok() {
            trim(dir, max_bytes());
        } else {
            let _ = std::fs::remove_file(&tmp);
        }
    }

    /// The entries: (file, size in bytes), oldest first.
    pub fn entries(&self) -> Vec<(PathBuf, u64)> {
        self.dir.as_ref().map_or_else(Vec::new, |d| {
            listing(d).into_iter().map(|(p, s, _)| (p, s)).collect()
        })
    }

    /// Removes every entry (and leftover temporary file); returns how many files and bytes.
    ///
    /// # Errors
    /// A file that cannot be removed.
    pub fn clear(&self) -> std::io::Result<(usize, u64)> {
        let Some(dir) = self.dir.as_ref() else {
            return Ok((0, 0));
        };
        let Ok(rd) = std::fs::read_dir(dir) else {
            return Ok((0, 0));
        };
        let (mut n, mut bytes) = (0, 0);
        for e in rd.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.ends_with(".npz") || name.ends_with(".tmp") {
                bytes += e.metadata().map_or(0, |m| m.len());
                std::fs::remove_file(e.path())?;
                n += 1;
            }
        }
        Ok((n, bytes))
    }
}

/// Reads `names` from the `.npz` at `path`: `None` if any is missing or does not check.
fn read_entry(path: &Path, names: &[&str]) -> Option<Vec<NpyArray>> {
    let f = std::fs::File::open(path).ok()?;
    let len = f.metadata().ok()?.len();
    let mut zip = zip::ZipArchive::new(f).ok()?;
    let mut out = Vec::with_capacity(names.len());
    for name in names {
        let mut entry = zip.by_name(&format!("{name}.npy")).ok()?;
        // A stored entry is no larger than its file: a size beyond that is corruption.
        if entry.size() > len {
            return None;
        }
        let mut bytes = Vec::with_capacity(usize::try_from(entry.size()).ok()?);
        // The zip reader checks the entry's CRC-32 once it has read it all.
        entry.read_to_end(&mut bytes).ok()?;
        out.push(parse_npy(&bytes).ok()?);
    }
    Some(out)
}

/// Writes `arrays` as an uncompressed `.npz` at `path`.
fn write_entry(path: &Path, arrays: &[(&str, &[usize], &[f64])]) -> std::io::Result<()> {
    let f = std::fs::File::options()
        .write(true)
        .create_new(true)
        .open(path)?;
    let mut zip = zip::ZipWriter::new(std::io::BufWriter::new(f));
    let large = arrays
        .iter()
        .any(|a| a.2.len() * 8 > (u32::MAX / 2) as usize);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Stored)
        .large_file(large);
    for (name, shape, values) in arrays {
        let mut bytes = Vec::with_capacity(128 + values.len() * 8);
        {
            let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
            let mut w = npyz::WriteOptions::new()
                .default_dtype()
                .shape(&shape)
                .writer(&mut bytes)
                .begin_nd()?;
            for v in *values {
                w.push(v)?;
            }
            w.finish()?;
        }
        zip.start_file(format!("{name}.npy"), opts)
            .map_err(std::io::Error::other)?;
        zip.write_all(&bytes)?;
    }
    let inner = zip.finish().map_err(std::io::Error::other)?;
    let f = inner.into_inner().map_err(|e| e.into_error())?;
    f.sync_all()
}

/// The size limit (bytes): `M1CS_CACHE_MAX_MB`, else [`DEFAULT_MAX_MB`].
fn max_bytes() -> u64 {
    std::env::var("M1CS_CACHE_MAX_MB")
        .ok()
        .and_then(|v| v.trim().parse::<u64>().ok())
        .unwrap_or(DEFAULT_MAX_MB)
        .saturating_mul(1 << 20)
}

/// The entries in `dir` (path, size in bytes, modification time), oldest first.
fn listing(dir: &Path) -> Vec<(PathBuf, u64, std::time::SystemTime)> {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut out: Vec<_> = rd
        .flatten()
        .filter(|e| {
            let n = e.file_name();
            let n = n.to_string_lossy();
            n.ends_with(".npz") && !n.starts_with('.')
        })
        .filter_map(|e| {
            let m = e.metadata().ok()?;
            Some((e.path(), m.len(), m.modified().ok()?))
        })
        .collect();
    out.sort_by_key(|e| e.2);
    out
}

/// Removes the oldest entries of `dir` while it holds more than `limit` bytes.
fn trim(dir: &Path, limit: u64) {
    let entries = listing(dir);
    let mut total: u64 = entries.iter().map(|e| e.1).sum();
    for (path, size, _) in entries {
        if total <= limit {
            break;
        }
        if std::fs::remove_file(&path).is_ok() {
            total -= size;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("m1-cache-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    /// Stored arrays come back bit for bit; another key misses; a corrupt entry misses and is
    /// removed; the size limit removes the oldest entries first; clear empties the folder.
    #[test]
    fn entries_round_trip_and_corruption_is_a_miss() {
        let dir = scratch("round-trip");
        let store = Store::at(&dir);
        let mut key = Fingerprint::new("test");
        key.f64s(&[1.0, 2.0]);
        let a: Vec<f64> = (0..12).map(|k| f64::from(k).sin()).collect();
        let b = [std::f64::consts::PI];
        assert!(store.load(&key, &["a", "b"]).is_none());
        store.store(&key, &[("a", &[3, 4], &a), ("b", &[], &b)]);
        let got = store.load(&key, &["a", "b"]).unwrap();
        assert_eq!(got[0].shape, vec![3, 4]);
        assert_eq!(
            got[0].data.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
            a.iter().map(|x| x.to_bits()).collect::<Vec<_>>()
        );
        assert_eq!(got[1].data, b.to_vec());
        // A missing array is a miss (and the entry goes).
        assert!(store.load(&key, &["a", "c"]).is_none());
        assert!(store.entries().is_empty());
        // Another input, another entry.
        store.store(&key, &[("a", &[3, 4], &a), ("b", &[], &b)]);
        let mut other = Fingerprint::new("test");
        other.f64s(&[1.0, 2.000_000_000_000_001]);
        assert_ne!(other.file_name(), key.file_name());
        assert!(store.load(&other, &["a"]).is_none());
        // Corrupt one bit of the values: the CRC says so; the entry is removed.
        let path = dir.join(key.file_name());
        let mut bytes = std::fs::read(&path).unwrap();
        let value = a[5].to_le_bytes();
        let at = bytes.windows(8).position(|w| w == value).unwrap();
        bytes[at + 3] ^= 0x40;
        std::fs::write(&path, &bytes).unwrap();
        assert!(store.load(&key, &["a", "b"]).is_none());
        assert!(!path.exists());
        // A truncated entry too.
        store.store(&key, &[("a", &[3, 4], &a)]);
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 10]).unwrap();
        assert!(store.load(&key, &["a"]).is_none());
        // The size limit: the oldest goes first.
        let big = vec![0.5; 1 << 15];
        for k in 0..3 {
            let mut key = Fingerprint::new("test");
            key.usizes(&[k]);
            store.store(&key, &[("a", &[big.len()], &big)]);
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let sizes: Vec<u64> = store.entries().iter().map(|e| e.1).collect();
        assert_eq!(sizes.len(), 3);
        trim(&dir, sizes[1] + sizes[2]);
        let left: Vec<String> = store
            .entries()
            .iter()
            .map(|e| e.0.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        let name = |k: usize| {
            let mut key = Fingerprint::new("test");
            key.usizes(&[k]);
            key.file_name()
        };
        assert_eq!(left, vec![name(1), name(2)]);
        assert_eq!(store.clear().unwrap().0, 2);
        assert!(store.entries().is_empty());
        // Off: nothing is written.
        Store::off().store(&key, &[("a", &[3, 4], &a)]);
        assert!(Store::off().load(&key, &["a"]).is_none());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
