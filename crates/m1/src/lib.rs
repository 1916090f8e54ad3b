//! Physics of segmented primary mirrors, free of any FFI. The FMI glue lives in the `fmu` crate;
//! each FMU wires the two together. Units are SI throughout (m, N, kg, s, rad) unless a name says
//! otherwise.
//!
//! The crate, by concern. Dependencies run down this list (a folder uses only those above it;
//! `linalg` serves all):
//!
//! - [`aperture`]: segment layouts, the geometry built on them, Zernike bases on the aperture.
//! - [`sensing`]: interaction matrices and the edge-sensor model.
//! - [`control`]: the nominal setup (A, reconstructor, focus-mode), the sparse reconstructor,
//!   the global controller.
//! - [`optics`]: rms surface metrics, PSSN, random segment states and their statistics.
//! - [`loads`]: wind pressure screens and loads, pier vibration.
//! - [`plant`]: segments and their servos, the structure, the coupled and quasi-static mirror
//!   solvers, the monolithic models.
//! - [`analysis`]: quasi-static analyses (Table 1), control-structure interaction, the
//!   split-coupling study, step-response figures, the studies' default settings.
//! - [`linalg`]: SIMD kernels, Krylov estimates, block and skyline Cholesky, the NPY/NPZ reader,
//!   the on-disk cache of computed arrays.

// The workspace denies unwrap, expect, panic and unreachable (Cargo.toml). The physics crate
// is not an FFI boundary: its kernels assert shape invariants that callers guarantee (a
// violated one is a programming error, reported with a message), and the FMU crates above it
// catch every panic before the C boundary. Here unwrap and expect are warnings, explicit
// panics and unreachable arms allowed; todo and unimplemented stay denied.
#![warn(clippy::unwrap_used, clippy::expect_used)]
#![allow(clippy::panic, clippy::unreachable)]

pub mod analysis;
pub mod aperture;
pub mod control;
pub mod error;
pub mod linalg;
pub mod loads;
pub mod optics;
pub mod plant;
pub mod sensing;

pub use error::M1Error;
