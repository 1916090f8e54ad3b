//! The export macro: [`crate::export_fmi2!`] defines the 34 `extern "C"` FMI 2.0 functions of
//! a model with unmangled names, each a one-line call of its forward in [`crate::ffi`]; its
//! `# Safety` section states the contract the FMI 2.0 standard places on the importer.

/// Exports the 34 FMI 2.0 co-simulation functions for a model type, with unmangled names.
///
/// Use once per cdylib: `fmu::export_fmi2!(my_crate::MyModel);`
///
/// # Safety
///
/// The exported functions are called by a foreign importer, and the FMI 2.0 standard places
/// this contract on it, which every forward in [`crate::ffi`] relies on (each names its own
/// part): every `fmi2Component` passed is one that this FMU's `fmi2Instantiate` returned and
/// `fmi2FreeInstance` has not yet freed, never used after it is freed (NULL and foreign
/// pointers are refused by a tag check, but only on a best-effort basis: a dangling pointer
/// cannot be detected soundly); the functions of one instance are never called concurrently
/// (different instances may be used from different threads), so each call has its instance to
/// itself; every array argument points to at least as many elements as its length argument
/// says (`vr` and `value` `nvr` each, a serialised state `size` bytes, the debug categories
/// `n`), readable where the FMU reads and writable where it writes, valid for the duration of
/// the call; every string argument is NUL-terminated and valid for the duration of the call
/// (strings are copied, never kept); every `fmi2FMUstate` is one this FMU's
/// `fmi2GetFMUstate` or `fmi2DeSerializeFMUstate` returned and `fmi2FreeFMUstate` has not
/// freed, and every `fmi2FMUstate*`, `size_t*` or status out-pointer is valid for reads and
/// writes of one element; and the callback functions given to `fmi2Instantiate` stay callable
/// with their `componentEnvironment` until the instance is freed (the struct itself is copied).
/// In return the FMU assumes nothing else: the calling sequence is checked by the state
/// machine ([`crate::Instance`]) and refused out of order, enum arguments (`fmi2Type`,
/// `fmi2StatusKind`) arrive as `c_int` and are checked, NULL where a pointer is needed is
/// refused with a message, every body runs under `catch_unwind` so that no panic unwinds into
/// the importer, and the strings the FMU returns stay valid until the string is set again or
/// the instance is freed (the version strings for as long as the library is loaded).
#[macro_export]
macro_rules! export_fmi2 {
    ($model:ty) => {
        mod fmi2_exports {
            #![allow(non_snake_case, clippy::missing_safety_doc)]
            use super::*;
            use std::ffi::{c_char, c_int};
            use $crate::ffi;
            use $crate::fmi_sys::fmi2::*;
            type M = $model;

            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2GetTypesPlatform() -> *const c_char {
                ffi::get_types_platform()
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2GetVersion() -> *const c_char {
                ffi::get_version()
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SetDebugLogging(
                c: fmi2Component,
                on: fmi2Boolean,
                n: usize,
                cats: *const fmi2String,
            ) -> fmi2Status {
                unsafe { ffi::set_debug_logging::<M>(c, on, n, cats) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2Instantiate(
                name: fmi2String,
                ty: c_int,
                guid: fmi2String,
                res: fmi2String,
                f: *const fmi2CallbackFunctions,
                visible: fmi2Boolean,
                logging: fmi2Boolean,
            ) -> fmi2Component {
                unsafe { ffi::instantiate::<M>(name, ty, guid, res, f, visible, logging) }
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2FreeInstance(c: fmi2Component) {
                ffi::free_instance::<M>(c)
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2SetupExperiment(
                c: fmi2Component,
                td: fmi2Boolean,
                tol: fmi2Real,
                start: fmi2Real,
                sd: fmi2Boolean,
                stop: fmi2Real,
            ) -> fmi2Status {
                ffi::setup_experiment::<M>(c, td, tol, start, sd, stop)
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2EnterInitializationMode(c: fmi2Component) -> fmi2Status {
                ffi::enter_initialization_mode::<M>(c)
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2ExitInitializationMode(c: fmi2Component) -> fmi2Status {
                ffi::exit_initialization_mode::<M>(c)
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2Terminate(c: fmi2Component) -> fmi2Status {
                ffi::terminate::<M>(c)
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2Reset(c: fmi2Component) -> fmi2Status {
                ffi::reset::<M>(c)
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetReal(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *mut fmi2Real,
            ) -> fmi2Status {
                unsafe { ffi::get_real::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetInteger(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *mut fmi2Integer,
            ) -> fmi2Status {
                unsafe { ffi::get_integer::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetBoolean(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *mut fmi2Boolean,
            ) -> fmi2Status {
                unsafe { ffi::get_boolean::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetString(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *mut fmi2String,
            ) -> fmi2Status {
                unsafe { ffi::get_string::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SetReal(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *const fmi2Real,
            ) -> fmi2Status {
                unsafe { ffi::set_real::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SetInteger(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *const fmi2Integer,
            ) -> fmi2Status {
                unsafe { ffi::set_integer::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SetBoolean(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *const fmi2Boolean,
            ) -> fmi2Status {
                unsafe { ffi::set_boolean::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SetString(
                c: fmi2Component,
                vr: *const fmi2ValueReference,
                n: usize,
                v: *const fmi2String,
            ) -> fmi2Status {
                unsafe { ffi::set_string::<M>(c, vr, n, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetFMUstate(
                c: fmi2Component,
                s: *mut fmi2FMUstate,
            ) -> fmi2Status {
                unsafe { ffi::get_fmu_state::<M>(c, s) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SetFMUstate(
                c: fmi2Component,
                s: fmi2FMUstate,
            ) -> fmi2Status {
                unsafe { ffi::set_fmu_state::<M>(c, s) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2FreeFMUstate(
                c: fmi2Component,
                s: *mut fmi2FMUstate,
            ) -> fmi2Status {
                unsafe { ffi::free_fmu_state::<M>(c, s) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SerializedFMUstateSize(
                c: fmi2Component,
                s: fmi2FMUstate,
                n: *mut usize,
            ) -> fmi2Status {
                unsafe { ffi::serialized_size::<M>(c, s, n) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2SerializeFMUstate(
                c: fmi2Component,
                s: fmi2FMUstate,
                b: *mut fmi2Byte,
                n: usize,
            ) -> fmi2Status {
                unsafe { ffi::serialize::<M>(c, s, b, n) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2DeSerializeFMUstate(
                c: fmi2Component,
                b: *const fmi2Byte,
                n: usize,
                s: *mut fmi2FMUstate,
            ) -> fmi2Status {
                unsafe { ffi::deserialize::<M>(c, b, n, s) }
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2GetDirectionalDerivative(
                c: fmi2Component,
                _u: *const fmi2ValueReference,
                _nu: usize,
                _k: *const fmi2ValueReference,
                _nk: usize,
                _dk: *const fmi2Real,
                _du: *mut fmi2Real,
            ) -> fmi2Status {
                ffi::unsupported::<M>(c, "fmi2GetDirectionalDerivative")
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2SetRealInputDerivatives(
                c: fmi2Component,
                _vr: *const fmi2ValueReference,
                _n: usize,
                _o: *const fmi2Integer,
                _v: *const fmi2Real,
            ) -> fmi2Status {
                ffi::unsupported::<M>(c, "fmi2SetRealInputDerivatives")
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2GetRealOutputDerivatives(
                c: fmi2Component,
                _vr: *const fmi2ValueReference,
                _n: usize,
                _o: *const fmi2Integer,
                _v: *mut fmi2Real,
            ) -> fmi2Status {
                ffi::unsupported::<M>(c, "fmi2GetRealOutputDerivatives")
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2DoStep(
                c: fmi2Component,
                t: fmi2Real,
                h: fmi2Real,
                no_prior: fmi2Boolean,
            ) -> fmi2Status {
                ffi::do_step::<M>(c, t, h, no_prior)
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2CancelStep(c: fmi2Component) -> fmi2Status {
                ffi::cancel_step::<M>(c)
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetStatus(
                c: fmi2Component,
                k: c_int,
                v: *mut fmi2Status,
            ) -> fmi2Status {
                unsafe { ffi::get_status::<M>(c, k, v) }
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetRealStatus(
                c: fmi2Component,
                k: c_int,
                v: *mut fmi2Real,
            ) -> fmi2Status {
                unsafe { ffi::get_real_status::<M>(c, k, v) }
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2GetIntegerStatus(
                c: fmi2Component,
                _k: c_int,
                _v: *mut fmi2Integer,
            ) -> fmi2Status {
                ffi::unsupported::<M>(
                    c,
                    "fmi2GetIntegerStatus (no integer status kinds exist in FMI 2.0)",
                )
            }
            #[unsafe(no_mangle)]
            pub unsafe extern "C" fn fmi2GetBooleanStatus(
                c: fmi2Component,
                k: c_int,
                v: *mut fmi2Boolean,
            ) -> fmi2Status {
                unsafe { ffi::get_boolean_status::<M>(c, k, v) }
            }
            #[unsafe(no_mangle)]
            pub extern "C" fn fmi2GetStringStatus(
                c: fmi2Component,
                _k: c_int,
                _v: *mut fmi2String,
            ) -> fmi2Status {
                ffi::unsupported::<M>(c, "fmi2GetStringStatus (pending status is never used)")
            }
        }
    };
}
