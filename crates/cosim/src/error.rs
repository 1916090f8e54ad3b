//! The error type of the importer and master: every variant names the file, component or
//! variable at fault.

use std::path::PathBuf;

use thiserror::Error;

/// Errors of the co-simulation crate.
#[derive(Debug, Error)]
pub enum CosimError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// An archive (.fmu, .ssp) that is not a readable zip, or holds an unsafe entry.
    #[error("{path}: not a valid archive: {reason}")]
    Archive {
        /// The archive.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// A file the standard requires is missing from an archive or directory.
    #[error("{archive}: {file} is missing")]
    MissingFile {
        /// The archive or directory.
        archive: PathBuf,
        /// The missing file.
        file: String,
    },
    /// Malformed XML, or XML that violates the schema or the standard's rules.
    #[error("{file}: {reason}")]
    Xml {
        /// The XML file.
        file: PathBuf,
        /// What is wrong, with the element or attribute.
        reason: String,
    },
    /// No binary for this platform in the FMU.
    #[error("{fmu}: no binary for this platform: expected {expected}")]
    MissingBinary {
        /// The FMU.
        fmu: PathBuf,
        /// The path inside the archive that was looked for.
        expected: String,
    },
    /// The shared library could not be loaded.
    #[error("{library}: cannot load: {reason}")]
    Load {
        /// The library.
        library: PathBuf,
        /// dlerror's message.
        reason: String,
    },
    /// A function the FMI 2.0 Co-Simulation interface requires is not exported.
    #[error("{library}: missing symbol {symbol}")]
    MissingSymbol {
        /// The library.
        library: PathBuf,
        /// The function.
        symbol: String,
    },
    /// fmi2Instantiate failed (e.g. a GUID the binary does not recognise).
    #[error("{component}: fmi2Instantiate failed (guid {guid}){log}")]
    Instantiate {
        /// Instance name.
        component: String,
        /// The GUID passed.
        guid: String,
        /// The messages the FMU logged, if any.
        log: String,
    },
    /// An FMI call returned an error status.
    #[error("{component}: {function} returned {status}{at}{log}")]
    Status {
        /// Instance name.
        component: String,
        /// The FMI function.
        function: &'static str,
        /// The status (fmi2Error, fmi2Fatal, ...).
        status: String,
        /// ", at t = ..." when known.
        at: String,
        /// The messages the FMU logged for this call.
        log: String,
    },
    /// An FMI call returned fmi2Discard: the FMU discarded it (for fmi2DoStep, it did not
    /// complete the step). The run fails as on [`Self::Status`], unless the FMU asks to end the
    /// simulation ([`Self::Ended`]).
    #[error(
        "{component}: {function} returned fmi2Discard{at}: the FMU discarded the {}{log}",
        discarded_what(function)
    )]
    Discarded {
        /// Instance name.
        component: String,
        /// The FMI function.
        function: &'static str,
        /// ", at t = ..." when known.
        at: String,
        /// The messages the FMU logged for this call.
        log: String,
    },
    /// A component discarded its step and asked to end the simulation
    /// (fmi2GetBooleanStatus(fmi2Terminated) is true). Not a failure: `system::run` ends the
    /// run there with its results ([`crate::system::Results::ended`]); a caller stepping a
    /// [`crate::Simulation`] itself stops at this error.
    #[error("{component} ended the simulation at t = {time} s")]
    Ended {
        /// Instance name.
        component: String,
        /// Its last successful time (fmi2LastSuccessfulTime, or the start of the discarded
        /// step if it does not say) (s).
        time: f64,
    },
    /// A variable name that the component does not have.
    #[error("{component}: no variable named {name}")]
    UnknownVariable {
        /// Component or FMU.
        component: String,
        /// The name looked up.
        name: String,
    },
    /// A connection or binding between incompatible variables.
    #[error("{what}: {reason}")]
    Mismatch {
        /// The connection or binding (e.g. "a.y -> b.u").
        what: String,
        /// Type, causality, size or unit disagreement.
        reason: String,
    },
    /// A component produced a NaN or infinite output.
    #[error("{component}: output {variable} is {value} after the step to t = {time} s")]
    NonFinite {
        /// Instance name.
        component: String,
        /// The output.
        variable: String,
        /// Its value.
        value: f64,
        /// The end of the step (s).
        time: f64,
    },
    /// Invalid input to the master (a step, a time, a value).
    #[error("{0}")]
    Invalid(String),
}

/// What an FMU discards with fmi2Discard: the step (fmi2DoStep) or the call.
fn discarded_what(function: &str) -> &'static str {
    if function == "fmi2DoStep" {
        "step"
    } else {
        "call"
    }
}

/// Result with [`CosimError`].
pub type Result<T> = std::result::Result<T, CosimError>;

pub(crate) fn io(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> CosimError {
    let path = path.into();
    move |source| CosimError::Io { path, source }
}
