//! An FMU opened for import: the archive unpacked into a private temporary directory (removed
//! when the FMU and all its instances are gone), its model description parsed, its binary for
//! this platform loaded.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crate::description::ModelDescription;
use crate::error::{CosimError, Result, io};
use crate::instance::Instance;
use crate::library::Library;

/// The platform folder of FMI 2.0 binaries on this machine.
pub const PLATFORM: &str = if cfg!(all(target_os = "linux", target_pointer_width = "64")) {
    "linux64"
} else if cfg!(all(target_os = "macos", target_pointer_width = "64")) {
    "darwin64"
} else if cfg!(all(target_os = "windows", target_pointer_width = "64")) {
    "win64"
} else {
    "unsupported"
};

/// Shared library extension of this platform.
const EXTENSION: &str = if cfg!(target_os = "macos") {
    "dylib"
} else if cfg!(target_os = "windows") {
    "dll"
} else {
    "so"
};

/// A directory removed when dropped.
#[derive(Debug)]
pub(crate) struct TempDir(PathBuf);

impl TempDir {
    /// Its path.
    pub(crate) fn path(&self) -> &Path {
        &self.0
    }

    pub(crate) fn new(stem: &str) -> Result<Self> {
        static COUNT: AtomicU64 = AtomicU64::new(0);
        let n = COUNT.fetch_add(1, Ordering::Relaxed);
        let safe: String = stem
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .take(40)
            .collect();
        let dir = std::env::temp_dir().join(format!("m1cs-{}-{n}-{safe}", std::process::id()));
        std::fs::create_dir_all(&dir).map_err(io(&dir))?;
        Ok(Self(dir))
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// Unpacks the zip archive `path` into `dir`, refusing entries that would escape it.
pub(crate) fn unzip(path: &Path, dir: &Path) -> Result<()> {
    let bad = |reason: String| CosimError::Archive {
        path: path.to_path_buf(),
        reason,
    };
    let file = std::fs::File::open(path).map_err(io(path))?;
    let mut zip = zip::ZipArchive::new(file).map_err(|e| bad(e.to_string()))?;
    for i in 0..zip.len() {
        let mut entry = zip.by_index(i).map_err(|e| bad(e.to_string()))?;
        let Some(rel) = entry.enclosed_name() else {
            return Err(bad(format!(
                "entry {:?} escapes the archive",
                entry.name_raw()
            )));
        };
        let out = dir.join(&rel);
        if entry.is_dir() {
            std::fs::create_dir_all(&out).map_err(io(&out))?;
            continue;
        }
        if let Some(parent) = out.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        let mut bytes = Vec::with_capacity(usize::try_from(entry.size()).unwrap_or(0));
        entry
            .read_to_end(&mut bytes)
            .map_err(|e| bad(format!("{}: {e}", rel.display())))?;
        std::fs::write(&out, &bytes).map_err(io(&out))?;
    }
    Ok(())
}

/// A file URI of `path` (absolute), percent-encoding what is not unreserved.
pub(crate) fn file_uri(path: &Path) -> String {
    let mut s = String::from("file://");
    for b in path.as_os_str().as_encoded_bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' | b'/' => {
                s.push(char::from(*b));
            }
            _ => s.push_str(&format!("%{b:02X}")),
        }
    }
    s
}

/// What instances share with their FMU: the loaded library and the unpacked files.
pub(crate) struct Shared {
    pub(crate) library: Library,
    /// Kept alive while instances live (resources/ may be read at any time).
    pub(crate) _dir: TempDir,
}

/// Identity of an archive on disk: canonical path, size and modification time.
type ArchiveKey = (PathBuf, u64, Option<std::time::SystemTime>);

fn archive_key(path: &Path) -> Option<ArchiveKey> {
    let meta = std::fs::metadata(path).ok()?;
    Some((
        std::fs::canonicalize(path).ok()?,
        meta.len(),
        meta.modified().ok(),
    ))
}

/// An FMU open somewhere in the process (weakly: it closes when its last user drops it).
struct OpenFmu {
    key: ArchiveKey,
    description: ModelDescription,
    root: PathBuf,
    shared: std::sync::Weak<Shared>,
}

/// The FMUs open in this process, so that opening an unchanged archive again while it is open
/// shares its unpacked files and loaded library (e.g. the runs of one `m1cs run`): the library's
/// own caches survive from one run to the next, and nothing is unpacked twice.
static OPEN: std::sync::Mutex<Vec<OpenFmu>> = std::sync::Mutex::new(Vec::new());

/// An imported FMI 2.0 Co-Simulation FMU.
pub struct Fmu {
    /// The .fmu file.
    pub path: PathBuf,
    /// The parsed model description.
    pub description: ModelDescription,
    /// Where it was unpacked.
    root: PathBuf,
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Fmu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Fmu")
            .field("path", &self.path)
            .field("model", &self.description.model_name)
            .finish()
    }
}

impl Fmu {
    /// Unpacks `path` (a .fmu archive) into a temporary directory, parses its model
    /// description and loads its binary for this platform. If the same unchanged archive is
    /// already open in this process, the new handle shares its unpacked files and library
    /// instead.
    ///
    /// # Errors
    /// Naming the file: unreadable or invalid archive, missing modelDescription.xml, malformed
    /// or rule-violating XML, no binary for this platform, a library that does not load or
    /// lacks a symbol.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        if !path.is_file() {
            return Err(CosimError::Io {
                path: path.to_path_buf(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such FMU file"),
            });
        }
        // The same unchanged archive, still open elsewhere in this process: share it.
        let key = archive_key(path);
        if let Some(key) = &key {
            let mut open = OPEN
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            open.retain(|e| e.shared.strong_count() > 0);
            let alive = open.iter().find(|e| e.key == *key).and_then(|e| {
                let shared = e.shared.upgrade()?;
                Some((e.description.clone(), e.root.clone(), shared))
            });
            if let Some((description, root, shared)) = alive {
                return Ok(Self {
                    path: path.to_path_buf(),
                    description,
                    root,
                    shared,
                });
            }
        }
        let fmu = Self::unpack(path)?;
        if let Some(key) = key {
            let mut open = OPEN
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner);
            open.push(OpenFmu {
                key,
                description: fmu.description.clone(),
                root: fmu.root.clone(),
                shared: Arc::downgrade(&fmu.shared),
            });
        }
        Ok(fmu)
    }

    /// [`Self::open`] for every archive of `paths`, in parallel (unpacking a TMT archive and
    /// parsing its description take tens of milliseconds each); the result in the order of
    /// `paths`, or the first error in that order.
    ///
    /// # Errors
    /// As [`Self::open`].
    pub fn open_all<P: AsRef<Path> + Sync>(paths: &[P]) -> Result<Vec<Self>> {
        use rayon::prelude::*;
        let opened: Vec<Result<Self>> = paths.par_iter().map(Self::open).collect();
        opened.into_iter().collect()
    }

    fn unpack(path: &Path) -> Result<Self> {
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or("fmu");
        let dir = TempDir::new(stem)?;
        unzip(path, &dir.0)?;
        let md_path = dir.0.join("modelDescription.xml");
        if !md_path.is_file() {
            return Err(CosimError::MissingFile {
                archive: path.to_path_buf(),
                file: "modelDescription.xml".into(),
            });
        }
        let xml = std::fs::read_to_string(&md_path).map_err(io(&md_path))?;
        let description = ModelDescription::parse(&xml, &path.join("modelDescription.xml"))?;
        let rel = format!(
            "binaries/{PLATFORM}/{}.{EXTENSION}",
            description.co_simulation.model_identifier
        );
        let bin = dir.0.join(&rel);
        if !bin.is_file() {
            return Err(CosimError::MissingBinary {
                fmu: path.to_path_buf(),
                expected: rel,
            });
        }
        let library = Library::load(&bin)?;
        let root = dir.0.clone();
        Ok(Self {
            path: path.to_path_buf(),
            description,
            root,
            shared: Arc::new(Shared { library, _dir: dir }),
        })
    }

    /// The directory the archive was unpacked into.
    pub fn unpacked_dir(&self) -> &Path {
        &self.root
    }

    /// The resource location URI passed to fmi2Instantiate (file URI, no trailing slash).
    pub fn resource_uri(&self) -> String {
        file_uri(&self.root.join("resources"))
    }

    /// Instantiates it as a Co-Simulation slave called `name`; `verbose` prints every logged
    /// message (warnings and errors are always printed).
    ///
    /// # Errors
    /// [`CosimError::Instantiate`] with what the FMU logged (e.g. a GUID it does not know).
    pub fn instantiate(&self, name: &str, verbose: bool) -> Result<Instance> {
        Instance::new(
            self,
            self.shared.clone(),
            name,
            &self.description.guid,
            verbose,
        )
    }

    /// As [`Self::instantiate`] but passing `guid` instead of the description's (for tests of
    /// the GUID check).
    ///
    /// # Errors
    /// As [`Self::instantiate`].
    pub fn instantiate_with_guid(&self, name: &str, guid: &str) -> Result<Instance> {
        Instance::new(self, self.shared.clone(), name, guid, false)
    }
}
