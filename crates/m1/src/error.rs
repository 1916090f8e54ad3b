//! The error type of the physics crate.

use thiserror::Error;

/// Errors raised by the physics models: each names the parameter or quantity at fault.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum M1Error {
    /// A parameter value is outside its physical range.
    #[error("parameter {name} = {value} is invalid: {reason}")]
    InvalidParameter {
        /// The parameter's name (as the FMU variable or the CLI flag names it).
        name: &'static str,
        /// The value given.
        value: f64,
        /// What it must be.
        reason: &'static str,
    },
    /// A set of parameters gives an unstable closed loop.
    #[error(
        "the {channel} channel's closed loop is unstable (spectral radius {spectral_radius:.6} >= 1): {hint}"
    )]
    Unstable {
        /// The channel (piston, tilt).
        channel: &'static str,
        /// Spectral radius of the discrete closed loop (>= 1).
        spectral_radius: f64,
        /// Which parameter to change.
        hint: &'static str,
    },
    /// Array arguments whose length disagrees with the model size.
    #[error("{what} has length {found}, expected {expected}")]
    SizeMismatch {
        /// The argument.
        what: &'static str,
        /// The length the model needs.
        expected: usize,
        /// The length given.
        found: usize,
    },
    /// Input data that is malformed (an index out of range, a structure violated).
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// A numerical method that failed (factorisation, SVD convergence).
    #[error("numerical failure: {0}")]
    Numerical(String),
}

/// `Ok` when every named slice has length `expected`, else the first mismatch.
pub(crate) fn check_lengths(
    expected: usize,
    slices: &[(&'static str, &[f64])],
) -> Result<(), M1Error> {
    match slices.iter().find(|(_, a)| a.len() != expected) {
        Some((what, a)) => Err(M1Error::SizeMismatch {
            what,
            expected,
            found: a.len(),
        }),
        None => Ok(()),
    }
}
