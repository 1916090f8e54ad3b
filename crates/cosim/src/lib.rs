//! The co-simulation master: imports any FMI 2.0 Co-Simulation FMU and runs systems of them.
//!
//! - [`Fmu::open`] unpacks a .fmu into a private temporary directory, parses its
//!   modelDescription.xml ([`ModelDescription`]), loads the binary for this platform with dlopen
//!   and resolves all 34 FMI 2.0 Co-Simulation functions; [`Fmu::instantiate`] creates an
//!   [`Instance`] with a working logger (a tiny C shim formats the variadic messages) and the
//!   resource URI. Instances are freed in `Drop`; the library and the unpacked files live as
//!   long as the FMU or any of its instances.
//! - Errors ([`CosimError`]) name the file, component or variable at fault.

pub mod description;
pub mod error;
pub mod fmu;
pub mod instance;
pub mod library;
pub mod logger;
pub mod ssp;
pub mod system;

pub use description::ModelDescription;
pub use error::{CosimError, Result};
pub use fmu::Fmu;
pub use instance::Instance;
pub use system::{Order, SchedulerParams, Simulation, System, Value};
