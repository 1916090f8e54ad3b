//! Callback function types and the structs exchanged between importer and FMU
//! (`fmi2FunctionTypes.h`).
//!
//! The callback types are `Option<fn>` so that a null pointer (an absent callback) is
//! representable, as the standard allows e.g. for `stepFinished`.

#![allow(non_camel_case_types, non_snake_case)]

use std::ffi::c_void;

use super::enums::fmi2Status;
use super::types::{fmi2Boolean, fmi2ComponentEnvironment, fmi2Real, fmi2String};

/// Logger provided by the importer: prints a printf-style `message` (with the variadic
/// arguments) for instance `instanceName` with the given `status` and log `category`.
pub type fmi2CallbackLogger = Option<
    unsafe extern "C" fn(
        componentEnvironment: fmi2ComponentEnvironment,
        instanceName: fmi2String,
        status: fmi2Status,
        category: fmi2String,
        message: fmi2String,
        ...
    ),
>;

/// Allocator provided by the importer: like C `calloc`, returns zero-initialized memory for
/// `nobj` objects of `size` bytes each, or null on failure.
pub type fmi2CallbackAllocateMemory =
    Option<unsafe extern "C" fn(nobj: usize, size: usize) -> *mut c_void>;

/// Deallocator provided by the importer: like C `free`, releases memory obtained from
/// [`fmi2CallbackAllocateMemory`]; a null `obj` is ignored.
pub type fmi2CallbackFreeMemory = Option<unsafe extern "C" fn(obj: *mut c_void)>;

/// Co-Simulation only: called by the FMU when an asynchronous `fmi2DoStep` has finished
/// with the given `status`; may be null if the importer does not support asynchronous steps.
pub type fmi2StepFinished = Option<
    unsafe extern "C" fn(componentEnvironment: fmi2ComponentEnvironment, status: fmi2Status),
>;

/// Callback functions passed by the importer to `fmi2Instantiate`; the FMU must keep
/// using them (and `componentEnvironment`) for the lifetime of the instance.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct fmi2CallbackFunctions {
    /// Logging callback (must not be null).
    pub logger: fmi2CallbackLogger,
    /// Memory allocation callback (must not be null).
    pub allocateMemory: fmi2CallbackAllocateMemory,
    /// Memory release callback (must not be null).
    pub freeMemory: fmi2CallbackFreeMemory,
    /// Asynchronous step completion callback (Co-Simulation, may be null).
    pub stepFinished: fmi2StepFinished,
    /// Importer pointer passed as first argument to `logger` and `stepFinished`.
    pub componentEnvironment: fmi2ComponentEnvironment,
}

/// Model Exchange only: event information returned by `fmi2NewDiscreteStates`.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct fmi2EventInfo {
    /// The importer must call `fmi2NewDiscreteStates` again (event iteration).
    pub newDiscreteStatesNeeded: fmi2Boolean,
    /// The FMU requests the simulation to be terminated.
    pub terminateSimulation: fmi2Boolean,
    /// The nominal values of the continuous states have changed.
    pub nominalsOfContinuousStatesChanged: fmi2Boolean,
    /// The values of the continuous states have changed.
    pub valuesOfContinuousStatesChanged: fmi2Boolean,
    /// `nextEventTime` holds the time of the next time event.
    pub nextEventTimeDefined: fmi2Boolean,
    /// Time of the next time event (valid if `nextEventTimeDefined` is true).
    pub nextEventTime: fmi2Real,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{align_of, offset_of, size_of};

    const PTR: usize = size_of::<*const c_void>();

    #[test]
    fn callback_functions_is_five_pointers() {
        assert_eq!(size_of::<fmi2CallbackFunctions>(), 5 * PTR);
        assert_eq!(
            align_of::<fmi2CallbackFunctions>(),
            align_of::<*const c_void>()
        );
        #[cfg(target_pointer_width = "64")]
        assert_eq!(size_of::<fmi2CallbackFunctions>(), 40);
        assert_eq!(offset_of!(fmi2CallbackFunctions, logger), 0);
        assert_eq!(offset_of!(fmi2CallbackFunctions, allocateMemory), PTR);
        assert_eq!(offset_of!(fmi2CallbackFunctions, freeMemory), 2 * PTR);
        assert_eq!(offset_of!(fmi2CallbackFunctions, stepFinished), 3 * PTR);
        assert_eq!(
            offset_of!(fmi2CallbackFunctions, componentEnvironment),
            4 * PTR
        );
    }

    #[test]
    fn callbacks_are_nullable_pointers() {
        assert_eq!(size_of::<fmi2CallbackLogger>(), PTR);
        assert_eq!(size_of::<fmi2CallbackAllocateMemory>(), PTR);
        assert_eq!(size_of::<fmi2CallbackFreeMemory>(), PTR);
        assert_eq!(size_of::<fmi2StepFinished>(), PTR);
    }

    #[test]
    fn event_info_layout() {
        assert_eq!(offset_of!(fmi2EventInfo, newDiscreteStatesNeeded), 0);
        assert_eq!(offset_of!(fmi2EventInfo, nextEventTimeDefined), 16);
        assert_eq!(offset_of!(fmi2EventInfo, nextEventTime), 24);
        assert_eq!(size_of::<fmi2EventInfo>(), 32);
        assert_eq!(align_of::<fmi2EventInfo>(), 8);
    }
}
