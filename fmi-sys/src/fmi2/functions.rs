//! Signatures of the functions a Co-Simulation FMU exports (`fmi2FunctionTypes.h`):
//! the functions common to Model Exchange and Co-Simulation, then the Co-Simulation ones.
//!
//! The C header declares these as function types (`...TYPE`); here they are plain
//! `unsafe extern "C" fn` pointer types. An importer that loads them dynamically wraps them
//! in `Option` itself. Array parameters of the C header (`T[]`) become raw pointers.
//!
//! Enum-typed results and out-parameters ([`fmi2Status`]) come from foreign code; an
//! importer that does not trust the FMU can read them as `c_int` and convert with
//! [`fmi2Status::from_raw`].

#![allow(non_camel_case_types, non_snake_case)]

use super::callbacks::fmi2CallbackFunctions;
use super::enums::{fmi2Status, fmi2StatusKind, fmi2Type};
use super::types::{
    fmi2Boolean, fmi2Byte, fmi2Component, fmi2FMUstate, fmi2Integer, fmi2Real, fmi2String,
    fmi2ValueReference,
};

// ---------------------------------------------------------------------------------------
// Common functions: inquire platform and version
// ---------------------------------------------------------------------------------------

/// Returns the types platform the FMU was compiled with (`"default"` for standard headers).
pub type fmi2GetTypesPlatformTYPE = unsafe extern "C" fn() -> fmi2String;

/// Returns the version of the FMI headers the FMU was compiled with (`"2.0"`).
pub type fmi2GetVersionTYPE = unsafe extern "C" fn() -> fmi2String;

/// Enables/disables debug logging; with `nCategories > 0` only for the listed log
/// categories, otherwise for all categories.
pub type fmi2SetDebugLoggingTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    loggingOn: fmi2Boolean,
    nCategories: usize,
    categories: *const fmi2String,
) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Common functions: creation and destruction of FMU instances
// ---------------------------------------------------------------------------------------

/// Creates a new FMU instance of the given type; returns null on failure. `fmuGUID` must
/// match the modelDescription.xml guid, `fmuResourceLocation` is a URI of the resources
/// directory.
pub type fmi2InstantiateTYPE = unsafe extern "C" fn(
    instanceName: fmi2String,
    fmuType: fmi2Type,
    fmuGUID: fmi2String,
    fmuResourceLocation: fmi2String,
    functions: *const fmi2CallbackFunctions,
    visible: fmi2Boolean,
    loggingOn: fmi2Boolean,
) -> fmi2Component;

/// Disposes of the FMU instance and all memory and resources it allocated.
pub type fmi2FreeInstanceTYPE = unsafe extern "C" fn(c: fmi2Component);

// ---------------------------------------------------------------------------------------
// Common functions: initialization, termination, reset
// ---------------------------------------------------------------------------------------

/// Informs the FMU about the experiment setup (tolerance, start time, optional stop time);
/// must be called after instantiation and before entering initialization mode.
pub type fmi2SetupExperimentTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    toleranceDefined: fmi2Boolean,
    tolerance: fmi2Real,
    startTime: fmi2Real,
    stopTimeDefined: fmi2Boolean,
    stopTime: fmi2Real,
) -> fmi2Status;

/// Enters initialization mode (values of initial/calculated variables may now be set).
pub type fmi2EnterInitializationModeTYPE = unsafe extern "C" fn(c: fmi2Component) -> fmi2Status;

/// Leaves initialization mode (Co-Simulation: the slave is ready for `fmi2DoStep`).
pub type fmi2ExitInitializationModeTYPE = unsafe extern "C" fn(c: fmi2Component) -> fmi2Status;

/// Informs the FMU that the simulation run is terminated.
pub type fmi2TerminateTYPE = unsafe extern "C" fn(c: fmi2Component) -> fmi2Status;

/// Resets the FMU to the state directly after `fmi2Instantiate`.
pub type fmi2ResetTYPE = unsafe extern "C" fn(c: fmi2Component) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Common functions: getting and setting variable values
// ---------------------------------------------------------------------------------------

/// Reads the `nvr` Real variables referenced by `vr` into `value`.
pub type fmi2GetRealTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *mut fmi2Real,
) -> fmi2Status;

/// Reads the `nvr` Integer (and Enumeration) variables referenced by `vr` into `value`.
pub type fmi2GetIntegerTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *mut fmi2Integer,
) -> fmi2Status;

/// Reads the `nvr` Boolean variables referenced by `vr` into `value`.
pub type fmi2GetBooleanTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *mut fmi2Boolean,
) -> fmi2Status;

/// Reads the `nvr` String variables referenced by `vr` into `value`; the strings are owned
/// by the FMU and valid only until its next call.
pub type fmi2GetStringTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *mut fmi2String,
) -> fmi2Status;

/// Sets the `nvr` Real variables referenced by `vr` from `value`.
pub type fmi2SetRealTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2Real,
) -> fmi2Status;

/// Sets the `nvr` Integer (and Enumeration) variables referenced by `vr` from `value`.
pub type fmi2SetIntegerTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2Integer,
) -> fmi2Status;

/// Sets the `nvr` Boolean variables referenced by `vr` from `value`.
pub type fmi2SetBooleanTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2Boolean,
) -> fmi2Status;

/// Sets the `nvr` String variables referenced by `vr` from `value`; the FMU copies them.
pub type fmi2SetStringTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2String,
) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Common functions: FMU state (optional, canGetAndSetFMUstate / canSerializeFMUstate)
// ---------------------------------------------------------------------------------------

/// Copies the current FMU state into `*FMUstate`; allocates a new state if `*FMUstate` is
/// null, otherwise overwrites the given one.
pub type fmi2GetFMUstateTYPE =
    unsafe extern "C" fn(c: fmi2Component, FMUstate: *mut fmi2FMUstate) -> fmi2Status;

/// Restores the FMU state from a previously obtained `FMUstate`.
pub type fmi2SetFMUstateTYPE =
    unsafe extern "C" fn(c: fmi2Component, FMUstate: fmi2FMUstate) -> fmi2Status;

/// Frees the state `*FMUstate` and sets it to null (a null `*FMUstate` is ignored).
pub type fmi2FreeFMUstateTYPE =
    unsafe extern "C" fn(c: fmi2Component, FMUstate: *mut fmi2FMUstate) -> fmi2Status;

/// Returns in `*size` the number of bytes needed to serialize `FMUstate`.
pub type fmi2SerializedFMUstateSizeTYPE =
    unsafe extern "C" fn(c: fmi2Component, FMUstate: fmi2FMUstate, size: *mut usize) -> fmi2Status;

/// Serializes `FMUstate` into the importer-provided buffer `serializedState` of `size`
/// bytes.
pub type fmi2SerializeFMUstateTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    FMUstate: fmi2FMUstate,
    serializedState: *mut fmi2Byte,
    size: usize,
) -> fmi2Status;

/// Deserializes `size` bytes of `serializedState` into a new FMU state returned in
/// `*FMUstate`.
pub type fmi2DeSerializeFMUstateTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    serializedState: *const fmi2Byte,
    size: usize,
    FMUstate: *mut fmi2FMUstate,
) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Common functions: partial derivatives (optional, providesDirectionalDerivative)
// ---------------------------------------------------------------------------------------

/// Computes the directional derivative `dvUnknown = J * dvKnown` of the unknowns
/// `vUnknown_ref` with respect to the knowns `vKnown_ref`.
pub type fmi2GetDirectionalDerivativeTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vUnknown_ref: *const fmi2ValueReference,
    nUnknown: usize,
    vKnown_ref: *const fmi2ValueReference,
    nKnown: usize,
    dvKnown: *const fmi2Real,
    dvUnknown: *mut fmi2Real,
) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Co-Simulation functions: transfer of input/output derivatives
// ---------------------------------------------------------------------------------------

/// Sets the `order[i]`-th time derivatives of the Real inputs `vr[i]` to `value[i]`
/// (for input extrapolation/interpolation during the next step).
pub type fmi2SetRealInputDerivativesTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    order: *const fmi2Integer,
    value: *const fmi2Real,
) -> fmi2Status;

/// Reads the `order[i]`-th time derivatives of the Real outputs `vr[i]` into `value[i]`.
pub type fmi2GetRealOutputDerivativesTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    order: *const fmi2Integer,
    value: *mut fmi2Real,
) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Co-Simulation functions: computation
// ---------------------------------------------------------------------------------------

/// Advances the slave from `currentCommunicationPoint` by `communicationStepSize`;
/// `noSetFMUStatePriorToCurrentPoint` true means the importer will never restore a state
/// earlier than the current point.
pub type fmi2DoStepTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    currentCommunicationPoint: fmi2Real,
    communicationStepSize: fmi2Real,
    noSetFMUStatePriorToCurrentPoint: fmi2Boolean,
) -> fmi2Status;

/// Cancels a running asynchronous `fmi2DoStep` (one that returned `fmi2Pending`).
pub type fmi2CancelStepTYPE = unsafe extern "C" fn(c: fmi2Component) -> fmi2Status;

// ---------------------------------------------------------------------------------------
// Co-Simulation functions: status inquiry
// ---------------------------------------------------------------------------------------

/// Queries a status of kind `s` (only `fmi2DoStepStatus`) into `*value`.
pub type fmi2GetStatusTYPE =
    unsafe extern "C" fn(c: fmi2Component, s: fmi2StatusKind, value: *mut fmi2Status) -> fmi2Status;

/// Queries a Real status of kind `s` (only `fmi2LastSuccessfulTime`) into `*value`.
pub type fmi2GetRealStatusTYPE =
    unsafe extern "C" fn(c: fmi2Component, s: fmi2StatusKind, value: *mut fmi2Real) -> fmi2Status;

/// Queries an Integer status of kind `s` into `*value` (no kind is defined for it in 2.0).
pub type fmi2GetIntegerStatusTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    s: fmi2StatusKind,
    value: *mut fmi2Integer,
) -> fmi2Status;

/// Queries a Boolean status of kind `s` (only `fmi2Terminated`) into `*value`.
pub type fmi2GetBooleanStatusTYPE = unsafe extern "C" fn(
    c: fmi2Component,
    s: fmi2StatusKind,
    value: *mut fmi2Boolean,
) -> fmi2Status;

/// Queries a String status of kind `s` (only `fmi2PendingStatus`) into `*value`.
pub type fmi2GetStringStatusTYPE =
    unsafe extern "C" fn(c: fmi2Component, s: fmi2StatusKind, value: *mut fmi2String) -> fmi2Status;

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::c_void;
    use std::mem::size_of;

    unsafe extern "C" fn do_step(
        _c: fmi2Component,
        _t: fmi2Real,
        _h: fmi2Real,
        _no_set: fmi2Boolean,
    ) -> fmi2Status {
        fmi2Status::fmi2OK
    }

    unsafe extern "C" fn get_real(
        _c: fmi2Component,
        _vr: *const fmi2ValueReference,
        nvr: usize,
        value: *mut fmi2Real,
    ) -> fmi2Status {
        for i in 0..nvr {
            // SAFETY: the caller provides `nvr` writable values.
            unsafe { value.add(i).write(i as fmi2Real) };
        }
        fmi2Status::fmi2OK
    }

    #[test]
    fn function_types_are_thin_pointers() {
        assert_eq!(size_of::<fmi2DoStepTYPE>(), size_of::<*const c_void>());
        assert_eq!(
            size_of::<Option<fmi2DoStepTYPE>>(),
            size_of::<*const c_void>()
        );
    }

    #[test]
    fn rust_functions_coerce_to_signatures() {
        let step: fmi2DoStepTYPE = do_step;
        let get: fmi2GetRealTYPE = get_real;
        let vr = [0, 1, 2];
        let mut out = [f64::NAN; 3];
        // SAFETY: the test functions ignore the component and respect the array lengths.
        unsafe {
            assert_eq!(step(std::ptr::null_mut(), 0.0, 1e-3, 0), fmi2Status::fmi2OK);
            assert_eq!(
                get(
                    std::ptr::null_mut(),
                    vr.as_ptr(),
                    vr.len(),
                    out.as_mut_ptr()
                ),
                fmi2Status::fmi2OK
            );
        }
        assert_eq!(out, [0.0, 1.0, 2.0]);
    }
}
