//! FMI 2.0 C ABI (FMI 2.0.x standard, `"default"` types platform).
//!
//! * [`types`]: platform-dependent type aliases and constants (`fmi2TypesPlatform.h`).
//! * [`enums`]: enumerations of `fmi2FunctionTypes.h` (status, FMU type, status kind).
//! * [`callbacks`]: callback function types and the structs exchanged at instantiation.
//! * [`functions`]: signatures of the common and Co-Simulation functions an FMU exports.
//! * [`names`]: exact symbol names of those exported functions.
//! * [`attributes`]: the modelDescription.xml attribute values of a variable (causality,
//!   variability, initial), shared by exporters and importers.
//!
//! All items are re-exported at this level, so `fmi_sys::fmi2::fmi2Status` works.

pub mod attributes;
pub mod callbacks;
pub mod enums;
pub mod functions;
pub mod names;
pub mod types;

pub use attributes::*;
pub use callbacks::*;
pub use enums::*;
pub use functions::*;
pub use names::*;
pub use types::*;
