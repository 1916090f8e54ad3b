//! Which FMI 2.0 function may be called in which state: the co-simulation calling sequence of
//! the standard (FMI 2.0, section 4.2.4, the state machine of a co-simulation slave) as one
//! table, [`Call::allowed`]. The instance checks every call against it before anything else
//! ([`crate::Instance`]); a call out of sequence is refused with
//! [`FmuError::IllegalCall`](crate::FmuError::IllegalCall) naming the function and the state.
//!
//! The asynchronous states (stepInProgress, stepCanceled) never occur: fmi2DoStep completes
//! before it returns. fmi2Instantiate, fmi2FreeInstance and the status queries are not in the
//! table: the first makes an instance, the second is allowed in every state, the queries
//! answer in every state but fatal.

use crate::instance::State::{self, *};

/// An FMI 2.0 function whose calling sequence the instance checks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Call {
    /// fmi2SetDebugLogging.
    SetDebugLogging,
    /// fmi2SetupExperiment.
    SetupExperiment,
    /// fmi2EnterInitializationMode.
    EnterInitializationMode,
    /// fmi2ExitInitializationMode.
    ExitInitializationMode,
    /// fmi2Terminate.
    Terminate,
    /// fmi2Reset.
    Reset,
    /// fmi2GetReal.
    GetReal,
    /// fmi2GetInteger.
    GetInteger,
    /// fmi2GetBoolean.
    GetBoolean,
    /// fmi2GetString.
    GetString,
    /// fmi2SetReal (which variables, by causality and variability, is checked per variable).
    SetReal,
    /// fmi2SetInteger.
    SetInteger,
    /// fmi2SetBoolean.
    SetBoolean,
    /// fmi2SetString.
    SetString,
    /// fmi2DoStep.
    DoStep,
    /// fmi2GetFMUstate.
    GetFmuState,
    /// fmi2SetFMUstate.
    SetFmuState,
}

/// Every state but fatal (and the asynchronous ones, which never occur).
const ALL_BUT_FATAL: &[State] = &[
    Instantiated,
    InitializationMode,
    StepComplete,
    StepFailed,
    Terminated,
    Error,
];

/// Where values can be read: from initialisation mode on.
const READABLE: &[State] = &[
    InitializationMode,
    StepComplete,
    StepFailed,
    Terminated,
    Error,
];

/// Where values can be set (the variable's causality and variability decide which).
const SETTABLE: &[State] = &[Instantiated, InitializationMode, StepComplete];

impl Call {
    /// The states in which the standard allows this call: the table.
    pub const fn allowed(self) -> &'static [State] {
        match self {
            Call::SetDebugLogging | Call::Reset | Call::GetFmuState | Call::SetFmuState => {
                ALL_BUT_FATAL
            }
            Call::SetupExperiment | Call::EnterInitializationMode => &[Instantiated],
            Call::ExitInitializationMode => &[InitializationMode],
            Call::Terminate => &[StepComplete, StepFailed, Error],
            Call::GetReal | Call::GetInteger | Call::GetBoolean | Call::GetString => READABLE,
            Call::SetReal | Call::SetInteger | Call::SetBoolean | Call::SetString => SETTABLE,
            Call::DoStep => &[StepComplete],
        }
    }

    /// The C function's name.
    pub const fn name(self) -> &'static str {
        match self {
            Call::SetDebugLogging => "fmi2SetDebugLogging",
            Call::SetupExperiment => "fmi2SetupExperiment",
            Call::EnterInitializationMode => "fmi2EnterInitializationMode",
            Call::ExitInitializationMode => "fmi2ExitInitializationMode",
            Call::Terminate => "fmi2Terminate",
            Call::Reset => "fmi2Reset",
            Call::GetReal => "fmi2GetReal",
            Call::GetInteger => "fmi2GetInteger",
            Call::GetBoolean => "fmi2GetBoolean",
            Call::GetString => "fmi2GetString",
            Call::SetReal => "fmi2SetReal",
            Call::SetInteger => "fmi2SetInteger",
            Call::SetBoolean => "fmi2SetBoolean",
            Call::SetString => "fmi2SetString",
            Call::DoStep => "fmi2DoStep",
            Call::GetFmuState => "fmi2GetFMUstate",
            Call::SetFmuState => "fmi2SetFMUstate",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Spot checks of the standard's table: the calls that start and end a simulation, the
    /// step, and that nothing but what the table lists is allowed in the fatal state.
    #[test]
    fn the_table_follows_the_standard() {
        assert_eq!(Call::SetupExperiment.allowed(), &[Instantiated]);
        assert_eq!(Call::DoStep.allowed(), &[StepComplete]);
        assert!(!Call::GetReal.allowed().contains(&Instantiated));
        assert!(Call::SetReal.allowed().contains(&Instantiated));
        assert!(!Call::SetReal.allowed().contains(&StepFailed));
        assert!(!Call::Terminate.allowed().contains(&Terminated));
        for call in [
            Call::SetDebugLogging,
            Call::Reset,
            Call::GetReal,
            Call::SetReal,
            Call::DoStep,
            Call::GetFmuState,
        ] {
            assert!(!call.allowed().contains(&Fatal), "{}", call.name());
            assert!(call.name().starts_with("fmi2"));
        }
    }
}
