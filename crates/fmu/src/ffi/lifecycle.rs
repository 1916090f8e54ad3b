//! The forwards of the life-cycle functions: version queries, instantiation and freeing,
//! debug logging, the experiment set-up, initialisation, stepping, termination and reset. Each
//! states the part of the FMI 2.0 contract on the importer it relies on (the whole contract is
//! on [`crate::export_fmi2!`]).

use std::ffi::{c_char, c_int};
use std::panic::{AssertUnwindSafe, catch_unwind};

use fmi_sys::fmi2::*;

use super::guard::{instance, ok, panic_message, with};
use super::pointers::{slice, string};
use crate::error::FmuError;
use crate::instance::Instance;
use crate::model::Model;

/// fmi2GetTypesPlatform.
///
/// Relies on nothing: the string returned is static (valid as long as the library is loaded).
pub fn get_types_platform() -> *const c_char {
    FMI2_TYPES_PLATFORM.as_ptr()
}

/// fmi2GetVersion.
///
/// Relies on nothing: the string returned is static (valid as long as the library is loaded).
pub fn get_version() -> *const c_char {
    FMI2_VERSION.as_ptr()
}

/// fmi2Instantiate.
///
/// # Safety
/// Pointer arguments must be NULL or valid as the standard describes: `name`, `guid` and
/// `resources` each NULL or a NUL-terminated string readable for the duration of the call
/// (NULL `name` or `guid` is refused with a message); `functions` NULL or pointing to an
/// `fmi2CallbackFunctions` readable during the call (it is copied, not kept); its `logger`, if
/// set, callable with its `componentEnvironment` (and `name`) from the thread of every later
/// call on the instance until fmi2FreeInstance. `fmu_type` may be any integer (checked).
pub unsafe fn instantiate<M: Model>(
    name: fmi2String,
    fmu_type: c_int,
    guid: fmi2String,
    resources: fmi2String,
    functions: *const fmi2CallbackFunctions,
    _visible: fmi2Boolean,
    logging_on: fmi2Boolean,
) -> fmi2Component {
    let r = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: per the function's contract.
        let callbacks = unsafe { functions.as_ref() }.copied();
        let log_failure = |msg: &str| {
            let text = format!("fmi2Instantiate: {msg}");
            match callbacks.and_then(|c| c.logger.map(|l| (l, c.componentEnvironment))) {
                Some((logger, env)) => {
                    let m = std::ffi::CString::new(text.replace('\0', " ")).unwrap_or_default();
                    let n = if name.is_null() { c"".as_ptr() } else { name };
                    // SAFETY: importer's logger with "%s" and valid C strings.
                    unsafe {
                        logger(
                            env,
                            n,
                            fmi2Status::fmi2Error,
                            c"logStatusError".as_ptr(),
                            c"%s".as_ptr(),
                            m.as_ptr(),
                        )
                    };
                }
                None => eprintln!("{text}"),
            }
        };
        // SAFETY: NULL or valid C strings per the contract.
        let (name_s, guid_s, res_s) = unsafe { (string(name), string(guid), string(resources)) };
        let Some(name_s) = name_s else {
            log_failure("instanceName is NULL or not UTF-8");
            return std::ptr::null_mut();
        };
        if fmi2Type::from_raw(fmu_type) != Some(fmi2Type::fmi2CoSimulation) {
            log_failure(&format!(
                "fmuType {fmu_type} requested; {} is a co-simulation FMU only",
                M::INFO.model_identifier
            ));
            return std::ptr::null_mut();
        }
        let Some(guid_s) = guid_s else {
            log_failure("fmuGUID is NULL");
            return std::ptr::null_mut();
        };
        match Instance::<M>::new(name_s, guid_s, res_s, callbacks, logging_on != 0) {
            Ok(inst) => Box::into_raw(Box::new(inst)) as fmi2Component,
            Err(e) => {
                log_failure(&e.to_string());
                std::ptr::null_mut()
            }
        }
    }));
    match r {
        Ok(p) => p,
        Err(p) => {
            eprintln!(
                "fmi2Instantiate: internal error: {}",
                panic_message(p.as_ref())
            );
            std::ptr::null_mut()
        }
    }
}

/// fmi2FreeInstance.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using, and
/// on no call on it after this one (FMI 2.0: the component is invalid once freed; a second
/// free is caught by the cleared tag only while its memory is not reused).
pub fn free_instance<M: Model>(c: fmi2Component) {
    if let Some(p) = instance::<M>(c, "fmi2FreeInstance") {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            // SAFETY: a live instance created by Box::into_raw in `instantiate`; untag it first
            // so a second free is detected (best effort).
            unsafe {
                (*p).magic = 0;
                drop(Box::from_raw(p));
            }
        }));
    }
}

/// fmi2SetDebugLogging.
///
/// # Safety
/// `categories` must hold `n` C strings when non-NULL: `n` readable `fmi2String`s, each NULL
/// (refused) or NUL-terminated, valid for the duration of the call (NULL with `n` > 0 is
/// refused). `c` as for every forward (see [`crate::export_fmi2!`]).
pub unsafe fn set_debug_logging<M: Model>(
    c: fmi2Component,
    on: fmi2Boolean,
    n: usize,
    categories: *const fmi2String,
) -> fmi2Status {
    with::<M>(c, "fmi2SetDebugLogging", |inst| {
        // SAFETY: per contract.
        let cats = unsafe { slice(categories, n, "fmi2SetDebugLogging", "categories") }?;
        let mut names = Vec::with_capacity(n);
        for &s in cats {
            // SAFETY: each entry is a C string or NULL.
            match unsafe { string(s) } {
                Some(s) => names.push(s.to_string()),
                None => {
                    return Err(FmuError::NullPointer {
                        function: "fmi2SetDebugLogging",
                        argument: "categories[i]",
                    });
                }
            }
        }
        ok(inst.set_debug_logging(on != 0, &names))
    })
}

/// fmi2SetupExperiment.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn setup_experiment<M: Model>(
    c: fmi2Component,
    _tol_defined: fmi2Boolean,
    _tol: f64,
    start: f64,
    stop_defined: fmi2Boolean,
    stop: f64,
) -> fmi2Status {
    with::<M>(c, "fmi2SetupExperiment", |inst| {
        ok(inst.setup_experiment(start, (stop_defined != 0).then_some(stop)))
    })
}

/// fmi2EnterInitializationMode.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn enter_initialization_mode<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2EnterInitializationMode", |i| {
        ok(i.enter_initialization_mode())
    })
}

/// fmi2ExitInitializationMode.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn exit_initialization_mode<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2ExitInitializationMode", |i| {
        ok(i.exit_initialization_mode())
    })
}

/// fmi2Terminate.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn terminate<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2Terminate", |i| ok(i.terminate()))
}

/// fmi2Reset.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn reset<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2Reset", |i| ok(i.reset()))
}

/// fmi2DoStep.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn do_step<M: Model>(
    c: fmi2Component,
    t: f64,
    h: f64,
    _no_set_prior: fmi2Boolean,
) -> fmi2Status {
    with::<M>(c, "fmi2DoStep", |i| ok(i.do_step(t, h)))
}

/// fmi2CancelStep: steps complete synchronously, so there is never a step to cancel.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using
/// (the contract of [`crate::export_fmi2!`]); it takes no other pointer.
pub fn cancel_step<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2CancelStep", |_| {
        Err(FmuError::Unsupported(
            "fmi2CancelStep (steps are never asynchronous)",
        ))
    })
}
