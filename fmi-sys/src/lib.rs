//! Raw C ABI of the Functional Mock-up Interface (FMI), written by hand from the standard.
//!
//! This crate contains **no logic**: only type aliases, `#[repr(C)]` enums and structs,
//! function-pointer signatures and exported symbol names that mirror the C headers of the
//! FMI standard (for FMI 2.0: `fmi2TypesPlatform.h`, `fmi2FunctionTypes.h` and
//! `fmi2Functions.h`). It is meant to be shared by FMU exporters (which implement the
//! functions) and importers (which load them from a shared library).
//!
//! The only non-declarative items are tiny checked conversions from raw C integers into the
//! Rust enums (`from_raw`), because a raw integer received from foreign code must never be
//! transmuted into an enum unchecked, and the XML spellings of the variable attributes
//! ([`fmi2::attributes`]: causality, variability, initial), which exporters write and importers
//! read, so that both use one vocabulary.
//!
//! Each FMI major version lives in its own module ([`fmi2`]; an `fmi3` module can be added
//! beside it later). The target platform is Linux x86_64 with the standard's
//! `"default"` types platform.

pub mod fmi2;
