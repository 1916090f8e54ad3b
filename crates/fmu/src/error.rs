//! The runtime's error type; every variant maps to one FMI status in one place.

use fmi_sys::fmi2::fmi2Status;
use thiserror::Error;

/// Everything that can go wrong inside an FMU call.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum FmuError {
    /// A function called in a state where the standard does not allow it.
    #[error("illegal call sequence: {function} is not allowed in state {state}")]
    IllegalCall {
        /// The FMI function.
        function: &'static str,
        /// The instance's state.
        state: &'static str,
    },
    /// A value rejected by a variable's check.
    #[error("bad value for {variable}: {value} {reason}")]
    BadValue {
        /// Scalar name, e.g. `segment_mass` or `z[3]`.
        variable: String,
        /// The rejected value.
        value: String,
        /// Why.
        reason: String,
    },
    /// A value reference that is not in the model, or of another type.
    #[error("unknown {ty} value reference {vr}")]
    UnknownReference {
        /// The value reference.
        vr: u32,
        /// The expected type.
        ty: &'static str,
    },
    /// A variable that may not be set now (outputs, fixed parameters after initialisation).
    #[error("{variable} ({causality}, {variability}) cannot be set in state {state}")]
    NotSettable {
        /// Scalar name.
        variable: String,
        /// Its causality.
        causality: &'static str,
        /// Its variability.
        variability: &'static str,
        /// The instance's state.
        state: &'static str,
    },
    /// A NULL pointer where the standard requires an array or struct.
    #[error("{function}: {argument} is NULL")]
    NullPointer {
        /// The FMI function.
        function: &'static str,
        /// The argument.
        argument: &'static str,
    },
    /// An optional capability this FMU does not provide.
    #[error("{0} is not supported by this FMU")]
    Unsupported(&'static str),
    /// A doStep whose communication point is not the instance's time.
    #[error("fmi2DoStep: currentCommunicationPoint {given} differs from the FMU's time {expected}")]
    TimeMismatch {
        /// The time passed by the master.
        given: f64,
        /// The instance's time.
        expected: f64,
    },
    /// A model-specific failure (bad parameter combination, step size, ...).
    #[error("{0}")]
    Model(String),
    /// The variable table breaks an FMI rule (a programming error caught by tests).
    #[error("invalid variable table: {0}")]
    Table(String),
    /// A serialized FMU state that cannot be read back.
    #[error("cannot deserialize the FMU state: {0}")]
    State(String),
    /// Instantiation failed (GUID, resources, layout).
    #[error("{0}")]
    Instantiate(String),
    /// A panic caught at the C boundary.
    #[error("internal error (panic caught at the FMI boundary): {0}")]
    Panic(String),
}

impl FmuError {
    /// The FMI status this error is reported with.
    pub fn status(&self) -> fmi2Status {
        match self {
            FmuError::Panic(_) => fmi2Status::fmi2Fatal,
            _ => fmi2Status::fmi2Error,
        }
    }
}
