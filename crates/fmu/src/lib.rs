//! FMI 2.0 co-simulation runtime shared by every FMU of the project.
//!
//! A model implements [`Model`] and declares its variables once in a [`VariableTable`] (built
//! with [`TableBuilder`]). From that one table the runtime derives the value references, the
//! start values, get/set dispatch with value checks, modelDescription.xml ([`xml`]), the
//! documentation page and the archive ([`package`]). [`export_fmi2!`] exports the 34 FMI 2.0
//! functions of a model from a cdylib: each is a short shim with a NULL check, a panic guard
//! and one mapping from `Result` to status ([`ffi`]); the state machine lives in safe Rust
//! ([`Instance`]).
//!
//! No global state: every instance owns its values, model and logger.

pub mod calls;
pub mod declare;
pub mod docs;
pub mod error;
pub mod ffi;
pub mod instance;
pub mod model;
pub mod package;
pub mod units;
pub mod variables;
pub mod xml;

pub use declare::Handle;
pub use error::FmuError;
pub use fmi_sys;
pub use instance::{Instance, State};
pub use model::{Model, ModelInfo, Running};
pub use variables::{
    BoolVar, Check, Decl, Dependencies, IntVar, RealVar, StrVar, TableBuilder, Values,
    VariableTable,
};
