//! The C boundary: one short shim per FMI 2.0 function, generic over the model.
//!
//! Each shim checks its pointers, runs the safe body under `catch_unwind`, maps the `Result` to
//! a status in one place (`finish`) and sends the message through the importer's logger. The
//! [`crate::export_fmi2!`] macro instantiates all 34 for a model with unmangled names.
//!
//! Arguments that are C enums (`fmi2Type`, `fmi2StatusKind`) are received as `c_int` and
//! checked, since a foreign caller may pass any integer.
//!
//! The forwards are grouped by concern: `lifecycle.rs` (instantiation to termination and
//! stepping), `values.rs` (the getters and setters), `state.rs` (FMU states), `status.rs` (the
//! status queries and the unsupported functions); `guard.rs` holds the guard every body runs
//! in, `pointers.rs` the string and pointer helpers, `export.rs` the macro. Each forward
//! documents the part of the importer's FMI 2.0 contract it relies on; the whole contract is
//! the `# Safety` section of [`crate::export_fmi2!`].

use std::ffi::c_void;

mod export;
mod guard;
mod lifecycle;
mod pointers;
mod state;
mod status;
mod values;

pub use lifecycle::{
    cancel_step, do_step, enter_initialization_mode, exit_initialization_mode, free_instance,
    get_types_platform, get_version, instantiate, reset, set_debug_logging, setup_experiment,
    terminate,
};
pub use state::{
    deserialize, free_fmu_state, get_fmu_state, serialize, serialized_size, set_fmu_state,
};
pub use status::{get_boolean_status, get_real_status, get_status, unsupported};
pub use values::{
    get_boolean, get_integer, get_real, get_string, set_boolean, set_integer, set_real, set_string,
};

/// The pointer type of the opaque environment, re-exported for the macro.
pub type Env = *mut c_void;
