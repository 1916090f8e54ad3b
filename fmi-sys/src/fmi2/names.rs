//! Exact symbol names a Co-Simulation FMU exports (`fmi2Functions.h` with no
//! `FMI2_FUNCTION_PREFIX`), in the order the standard lists them.

/// Number of functions a Co-Simulation FMU exports (25 common + 9 Co-Simulation).
pub const FMI2_CS_FUNCTION_COUNT: usize = 34;

/// Symbol names of all functions a Co-Simulation FMU exports: first the functions common to
/// Model Exchange and Co-Simulation, then the Co-Simulation-specific ones.
pub const FMI2_CS_FUNCTIONS: [&str; FMI2_CS_FUNCTION_COUNT] = [
    // Common: inquire platform and version
    "fmi2GetTypesPlatform",
    "fmi2GetVersion",
    "fmi2SetDebugLogging",
    // Common: creation and destruction
    "fmi2Instantiate",
    "fmi2FreeInstance",
    // Common: initialization, termination, reset
    "fmi2SetupExperiment",
    "fmi2EnterInitializationMode",
    "fmi2ExitInitializationMode",
    "fmi2Terminate",
    "fmi2Reset",
    // Common: getting and setting variable values
    "fmi2GetReal",
    "fmi2GetInteger",
    "fmi2GetBoolean",
    "fmi2GetString",
    "fmi2SetReal",
    "fmi2SetInteger",
    "fmi2SetBoolean",
    "fmi2SetString",
    // Common: FMU state
    "fmi2GetFMUstate",
    "fmi2SetFMUstate",
    "fmi2FreeFMUstate",
    "fmi2SerializedFMUstateSize",
    "fmi2SerializeFMUstate",
    "fmi2DeSerializeFMUstate",
    // Common: partial derivatives
    "fmi2GetDirectionalDerivative",
    // Co-Simulation: input/output derivatives
    "fmi2SetRealInputDerivatives",
    "fmi2GetRealOutputDerivatives",
    // Co-Simulation: computation
    "fmi2DoStep",
    "fmi2CancelStep",
    // Co-Simulation: status inquiry
    "fmi2GetStatus",
    "fmi2GetRealStatus",
    "fmi2GetIntegerStatus",
    "fmi2GetBooleanStatus",
    "fmi2GetStringStatus",
];

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashSet;

    #[test]
    fn thirty_four_distinct_names() {
        assert_eq!(FMI2_CS_FUNCTIONS.len(), 34);
        let set: HashSet<&str> = FMI2_CS_FUNCTIONS.iter().copied().collect();
        assert_eq!(set.len(), 34);
    }

    #[test]
    fn names_are_valid_c_identifiers_with_prefix() {
        for name in FMI2_CS_FUNCTIONS {
            assert!(name.starts_with("fmi2"), "{name}");
            assert!(name.bytes().all(|b| b.is_ascii_alphanumeric()), "{name}");
        }
        assert_eq!(FMI2_CS_FUNCTIONS[0], "fmi2GetTypesPlatform");
        assert_eq!(FMI2_CS_FUNCTIONS[33], "fmi2GetStringStatus");
    }
}
