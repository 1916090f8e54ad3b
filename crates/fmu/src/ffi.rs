//! The C boundary: one short shim per FMI 2.0 function, generic over the model.
//!
//! Each shim checks its pointers, runs the safe body under `catch_unwind`, maps the `Result` to
//! a status in one place (`finish`) and sends the message through the importer's logger. The
//! [`crate::export_fmi2!`] macro instantiates all 34 for a model with unmangled names.
//!
//! Arguments that are C enums (`fmi2Type`, `fmi2StatusKind`) are received as `c_int` and
//! checked, since a foreign caller may pass any integer.

use std::ffi::{CStr, c_char, c_int, c_void};
use std::panic::{AssertUnwindSafe, catch_unwind};

use fmi_sys::fmi2::*;

use crate::error::FmuError;
use crate::instance::{Instance, MAGIC, Snapshot};
use crate::model::Model;

fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = p.downcast_ref::<&str>() {
        (*s).to_string()
    } else if let Some(s) = p.downcast_ref::<String>() {
        s.clone()
    } else {
        "unknown panic payload".to_string()
    }
}

/// Maps the outcome of a body to a status, logging errors through the instance's logger.
fn finish<M: Model>(
    inst: *mut Instance<M>,
    function: &'static str,
    r: std::thread::Result<Result<fmi2Status, FmuError>>,
) -> fmi2Status {
    // SAFETY: `inst` was checked non-NULL and tagged by the caller, and the body's borrow ended.
    let inst = unsafe { &mut *inst };
    let err = match r {
        Ok(Ok(s)) => return s,
        Ok(Err(e)) => e,
        Err(p) => {
            inst.set_fatal();
            FmuError::Panic(panic_message(p.as_ref()))
        }
    };
    let status = err.status();
    let category = if status == fmi2Status::fmi2Fatal {
        c"logStatusFatal"
    } else {
        c"logStatusError"
    };
    // The logger is foreign code; a panic can't come from it, but formatting could in theory.
    let _ = catch_unwind(AssertUnwindSafe(|| {
        inst.log(status, category, &format!("{function}: {err}"))
    }));
    status
}

/// Resolves an instance pointer: NULL or foreign pointers are refused.
fn instance<M: Model>(c: fmi2Component, function: &str) -> Option<*mut Instance<M>> {
    if c.is_null() {
        eprintln!("{function}: the instance pointer is NULL");
        return None;
    }
    let p = c as *mut Instance<M>;
    // SAFETY: the importer passes back the pointer fmi2Instantiate returned; the tag guards
    // against pointers from elsewhere and against freed instances (best effort).
    if unsafe { (*p).magic } != MAGIC {
        eprintln!("{function}: not an instance of this FMU (or already freed)");
        return None;
    }
    Some(p)
}

/// Runs `body` on the instance with the panic guard and status mapping.
fn with<M: Model>(
    c: fmi2Component,
    function: &'static str,
    body: impl FnOnce(&mut Instance<M>) -> Result<fmi2Status, FmuError>,
) -> fmi2Status {
    let Some(p) = instance::<M>(c, function) else {
        return fmi2Status::fmi2Error;
    };
    let r = catch_unwind(AssertUnwindSafe(|| {
        // SAFETY: checked above; the FMI contract gives the FMU exclusive use during a call.
        let inst = unsafe { &mut *p };
        inst.trace(|| function.to_string());
        // After fmi2Fatal only freeing is allowed.
        if inst.state() == crate::instance::State::Fatal && function != "fmi2FreeFMUstate" {
            return Err(FmuError::IllegalCall {
                function,
                state: "fatal",
            });
        }
        body(inst)
    }));
    finish(p, function, r)
}

fn ok(r: Result<(), FmuError>) -> Result<fmi2Status, FmuError> {
    r.map(|()| fmi2Status::fmi2OK)
}

/// Builds a slice from a C array; NULL is allowed only for an empty array.
///
/// # Safety
/// `p` must point to `n` valid elements when non-NULL.
unsafe fn slice<'a, T>(
    p: *const T,
    n: usize,
    function: &'static str,
    argument: &'static str,
) -> Result<&'a [T], FmuError> {
    if n == 0 {
        Ok(&[])
    } else if p.is_null() {
        Err(FmuError::NullPointer { function, argument })
    } else {
        // SAFETY: the caller guarantees `n` elements.
        Ok(unsafe { std::slice::from_raw_parts(p, n) })
    }
}

/// # Safety
/// `p` must point to `n` writable elements when non-NULL.
unsafe fn slice_mut<'a, T>(
    p: *mut T,
    n: usize,
    function: &'static str,
    argument: &'static str,
) -> Result<&'a mut [T], FmuError> {
    if n == 0 {
        Ok(&mut [])
    } else if p.is_null() {
        Err(FmuError::NullPointer { function, argument })
    } else {
        // SAFETY: the caller guarantees `n` elements.
        Ok(unsafe { std::slice::from_raw_parts_mut(p, n) })
    }
}

/// # Safety
/// `s` must be NULL or a valid C string.
unsafe fn string<'a>(s: fmi2String) -> Option<&'a str> {
    if s.is_null() {
        None
    } else {
        // SAFETY: non-NULL C string from the importer.
        unsafe { CStr::from_ptr(s) }.to_str().ok()
    }
}

/// fmi2GetTypesPlatform.
pub fn get_types_platform() -> *const c_char {
    FMI2_TYPES_PLATFORM.as_ptr()
}

/// fmi2GetVersion.
pub fn get_version() -> *const c_char {
    FMI2_VERSION.as_ptr()
}

/// fmi2Instantiate.
///
/// # Safety
/// Pointer arguments must be NULL or valid as the standard describes.
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
/// `categories` must hold `n` C strings when non-NULL.
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
pub fn enter_initialization_mode<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2EnterInitializationMode", |i| {
        ok(i.enter_initialization_mode())
    })
}

/// fmi2ExitInitializationMode.
pub fn exit_initialization_mode<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2ExitInitializationMode", |i| {
        ok(i.exit_initialization_mode())
    })
}

/// fmi2Terminate.
pub fn terminate<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2Terminate", |i| ok(i.terminate()))
}

/// fmi2Reset.
pub fn reset<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2Reset", |i| ok(i.reset()))
}

macro_rules! getter {
    ($fname:ident, $cname:literal, $t:ty, $method:ident, $conv:expr) => {
        /// The FMI getter of this type.
        ///
        /// # Safety
        /// `vr` and `value` must hold `nvr` elements when non-NULL.
        pub unsafe fn $fname<M: Model>(
            c: fmi2Component,
            vr: *const fmi2ValueReference,
            nvr: usize,
            value: *mut $t,
        ) -> fmi2Status {
            with::<M>(c, $cname, |inst| {
                // SAFETY: per contract.
                let vrs = unsafe { slice(vr, nvr, $cname, "vr") }?;
                // SAFETY: per contract.
                let out = unsafe { slice_mut(value, nvr, $cname, "value") }?;
                #[allow(clippy::redundant_closure_call)]
                ok(($conv)(inst, vrs, out))
            })
        }
    };
}

getter!(
    get_real,
    "fmi2GetReal",
    fmi2Real,
    get_real,
    |i: &mut Instance<M>, v: &[u32], o: &mut [f64]| i.get_real(v, o)
);
getter!(
    get_integer,
    "fmi2GetInteger",
    fmi2Integer,
    get_integer,
    |i: &mut Instance<M>, v: &[u32], o: &mut [i32]| i.get_integer(v, o)
);
getter!(
    get_boolean,
    "fmi2GetBoolean",
    fmi2Boolean,
    get_boolean,
    |i: &mut Instance<M>, v: &[u32], o: &mut [i32]| {
        let mut b = vec![false; v.len()];
        i.get_boolean(v, &mut b)?;
        for (o, b) in o.iter_mut().zip(b) {
            *o = b as i32;
        }
        Ok(())
    }
);
getter!(
    get_string,
    "fmi2GetString",
    fmi2String,
    get_string,
    |i: &mut Instance<M>, v: &[u32], o: &mut [*const c_char]| i.get_string(v, o)
);

/// fmi2SetReal.
///
/// # Safety
/// `vr` and `value` must hold `nvr` elements when non-NULL.
pub unsafe fn set_real<M: Model>(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2Real,
) -> fmi2Status {
    with::<M>(c, "fmi2SetReal", |inst| {
        // SAFETY: per contract.
        let (vrs, vals) = unsafe {
            (
                slice(vr, nvr, "fmi2SetReal", "vr")?,
                slice(value, nvr, "fmi2SetReal", "value")?,
            )
        };
        ok(inst.set_real(vrs, vals))
    })
}

/// fmi2SetInteger.
///
/// # Safety
/// `vr` and `value` must hold `nvr` elements when non-NULL.
pub unsafe fn set_integer<M: Model>(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2Integer,
) -> fmi2Status {
    with::<M>(c, "fmi2SetInteger", |inst| {
        // SAFETY: per contract.
        let (vrs, vals) = unsafe {
            (
                slice(vr, nvr, "fmi2SetInteger", "vr")?,
                slice(value, nvr, "fmi2SetInteger", "value")?,
            )
        };
        ok(inst.set_integer(vrs, vals))
    })
}

/// fmi2SetBoolean.
///
/// # Safety
/// `vr` and `value` must hold `nvr` elements when non-NULL.
pub unsafe fn set_boolean<M: Model>(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2Boolean,
) -> fmi2Status {
    with::<M>(c, "fmi2SetBoolean", |inst| {
        // SAFETY: per contract.
        let (vrs, vals) = unsafe {
            (
                slice(vr, nvr, "fmi2SetBoolean", "vr")?,
                slice(value, nvr, "fmi2SetBoolean", "value")?,
            )
        };
        let b: Vec<bool> = vals.iter().map(|&x| x != 0).collect();
        ok(inst.set_boolean(vrs, &b))
    })
}

/// fmi2SetString.
///
/// # Safety
/// `vr` and `value` must hold `nvr` elements when non-NULL, each a C string.
pub unsafe fn set_string<M: Model>(
    c: fmi2Component,
    vr: *const fmi2ValueReference,
    nvr: usize,
    value: *const fmi2String,
) -> fmi2Status {
    with::<M>(c, "fmi2SetString", |inst| {
        // SAFETY: per contract.
        let (vrs, vals) = unsafe {
            (
                slice(vr, nvr, "fmi2SetString", "vr")?,
                slice(value, nvr, "fmi2SetString", "value")?,
            )
        };
        let mut strs = Vec::with_capacity(nvr);
        for &s in vals {
            // SAFETY: each entry NULL or a C string.
            strs.push(unsafe { string(s) }.ok_or(FmuError::NullPointer {
                function: "fmi2SetString",
                argument: "value[i]",
            })?);
        }
        ok(inst.set_string(vrs, &strs))
    })
}

/// fmi2DoStep.
pub fn do_step<M: Model>(
    c: fmi2Component,
    t: f64,
    h: f64,
    _no_set_prior: fmi2Boolean,
) -> fmi2Status {
    with::<M>(c, "fmi2DoStep", |i| ok(i.do_step(t, h)))
}

/// fmi2CancelStep: steps complete synchronously, so there is never a step to cancel.
pub fn cancel_step<M: Model>(c: fmi2Component) -> fmi2Status {
    with::<M>(c, "fmi2CancelStep", |_| {
        Err(FmuError::Unsupported(
            "fmi2CancelStep (steps are never asynchronous)",
        ))
    })
}

/// fmi2GetFMUstate: allocates a new state, or overwrites the one given.
///
/// # Safety
/// `state` must point to a valid fmi2FMUstate slot.
pub unsafe fn get_fmu_state<M: Model>(c: fmi2Component, state: *mut fmi2FMUstate) -> fmi2Status {
    with::<M>(c, "fmi2GetFMUstate", |inst| {
        if state.is_null() {
            return Err(FmuError::NullPointer {
                function: "fmi2GetFMUstate",
                argument: "FMUstate",
            });
        }
        let snap = inst.get_state()?;
        // SAFETY: `state` is a valid slot; a non-NULL content is a state this FMU allocated.
        unsafe {
            let old = *state as *mut Snapshot<M>;
            if !old.is_null() && (*old).magic == MAGIC {
                *old = snap;
            } else {
                *state = Box::into_raw(Box::new(snap)) as fmi2FMUstate;
            }
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// # Safety
/// `s` must be NULL or a state allocated by this FMU.
unsafe fn snapshot<'a, M: Model>(
    s: fmi2FMUstate,
    function: &'static str,
) -> Result<&'a Snapshot<M>, FmuError> {
    let p = s as *const Snapshot<M>;
    // SAFETY: per contract; the tag catches foreign pointers (best effort).
    match unsafe { p.as_ref() } {
        None => Err(FmuError::NullPointer {
            function,
            argument: "FMUstate",
        }),
        Some(s) if s.magic == MAGIC => Ok(s),
        Some(_) => Err(FmuError::State(
            "not an FMU state of this FMU (or already freed)".into(),
        )),
    }
}

/// fmi2SetFMUstate.
///
/// # Safety
/// `state` must be a state from fmi2GetFMUstate of this FMU.
pub unsafe fn set_fmu_state<M: Model>(c: fmi2Component, state: fmi2FMUstate) -> fmi2Status {
    with::<M>(c, "fmi2SetFMUstate", |inst| {
        // SAFETY: per contract.
        let s = unsafe { snapshot::<M>(state, "fmi2SetFMUstate") }?;
        ok(inst.set_state(s))
    })
}

/// fmi2FreeFMUstate.
///
/// # Safety
/// `state` must point to a slot holding NULL or a state of this FMU.
pub unsafe fn free_fmu_state<M: Model>(c: fmi2Component, state: *mut fmi2FMUstate) -> fmi2Status {
    with::<M>(c, "fmi2FreeFMUstate", |_| {
        if state.is_null() {
            return Ok(fmi2Status::fmi2OK);
        }
        // SAFETY: per contract.
        unsafe {
            let p = *state as *mut Snapshot<M>;
            if !p.is_null() {
                snapshot::<M>(p as fmi2FMUstate, "fmi2FreeFMUstate")?;
                (*p).magic = 0;
                drop(Box::from_raw(p));
            }
            *state = std::ptr::null_mut();
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// fmi2SerializedFMUstateSize.
///
/// # Safety
/// `state` from this FMU; `size` writable.
pub unsafe fn serialized_size<M: Model>(
    c: fmi2Component,
    state: fmi2FMUstate,
    size: *mut usize,
) -> fmi2Status {
    with::<M>(c, "fmi2SerializedFMUstateSize", |_| {
        // SAFETY: per contract.
        let s = unsafe { snapshot::<M>(state, "fmi2SerializedFMUstateSize") }?;
        let n = Instance::<M>::serialize(s)?.len();
        // SAFETY: per contract.
        match unsafe { size.as_mut() } {
            Some(out) => *out = n,
            None => {
                return Err(FmuError::NullPointer {
                    function: "fmi2SerializedFMUstateSize",
                    argument: "size",
                });
            }
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// fmi2SerializeFMUstate.
///
/// # Safety
/// `state` from this FMU; `bytes` holds `size` writable bytes.
pub unsafe fn serialize<M: Model>(
    c: fmi2Component,
    state: fmi2FMUstate,
    bytes: *mut fmi2Byte,
    size: usize,
) -> fmi2Status {
    with::<M>(c, "fmi2SerializeFMUstate", |_| {
        // SAFETY: per contract.
        let s = unsafe { snapshot::<M>(state, "fmi2SerializeFMUstate") }?;
        let data = Instance::<M>::serialize(s)?;
        if data.len() != size {
            return Err(FmuError::State(format!(
                "buffer of {size} bytes given, the state takes {} (ask fmi2SerializedFMUstateSize)",
                data.len()
            )));
        }
        // SAFETY: per contract.
        let out = unsafe {
            slice_mut(
                bytes as *mut u8,
                size,
                "fmi2SerializeFMUstate",
                "serializedState",
            )
        }?;
        out.copy_from_slice(&data);
        Ok(fmi2Status::fmi2OK)
    })
}

/// fmi2DeSerializeFMUstate.
///
/// # Safety
/// `bytes` holds `size` bytes; `state` is a valid slot.
pub unsafe fn deserialize<M: Model>(
    c: fmi2Component,
    bytes: *const fmi2Byte,
    size: usize,
    state: *mut fmi2FMUstate,
) -> fmi2Status {
    with::<M>(c, "fmi2DeSerializeFMUstate", |inst| {
        // SAFETY: per contract.
        let data = unsafe {
            slice(
                bytes as *const u8,
                size,
                "fmi2DeSerializeFMUstate",
                "serializedState",
            )
        }?;
        if state.is_null() {
            return Err(FmuError::NullPointer {
                function: "fmi2DeSerializeFMUstate",
                argument: "FMUstate",
            });
        }
        let snap = inst.deserialize(data)?;
        // SAFETY: valid slot; non-NULL content is a state of this FMU.
        unsafe {
            let old = *state as *mut Snapshot<M>;
            if !old.is_null() && (*old).magic == MAGIC {
                *old = snap;
            } else {
                *state = Box::into_raw(Box::new(snap)) as fmi2FMUstate;
            }
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// A call this FMU does not support: fmi2Error with a message naming it.
pub fn unsupported<M: Model>(c: fmi2Component, function: &'static str) -> fmi2Status {
    with::<M>(c, function, |_| Err(FmuError::Unsupported(function)))
}

/// fmi2GetStatus.
///
/// # Safety
/// `value` writable.
pub unsafe fn get_status<M: Model>(
    c: fmi2Component,
    kind: c_int,
    value: *mut fmi2Status,
) -> fmi2Status {
    with::<M>(c, "fmi2GetStatus", |_| {
        if fmi2StatusKind::from_raw(kind) != Some(fmi2StatusKind::fmi2DoStepStatus) {
            return Err(FmuError::Unsupported(
                "fmi2GetStatus for a kind other than fmi2DoStepStatus",
            ));
        }
        // SAFETY: per contract.
        match unsafe { value.as_mut() } {
            Some(v) => *v = fmi2Status::fmi2OK,
            None => {
                return Err(FmuError::NullPointer {
                    function: "fmi2GetStatus",
                    argument: "value",
                });
            }
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// fmi2GetRealStatus: fmi2LastSuccessfulTime.
///
/// # Safety
/// `value` writable.
pub unsafe fn get_real_status<M: Model>(
    c: fmi2Component,
    kind: c_int,
    value: *mut fmi2Real,
) -> fmi2Status {
    with::<M>(c, "fmi2GetRealStatus", |inst| {
        if fmi2StatusKind::from_raw(kind) != Some(fmi2StatusKind::fmi2LastSuccessfulTime) {
            return Err(FmuError::Unsupported(
                "fmi2GetRealStatus for a kind other than fmi2LastSuccessfulTime",
            ));
        }
        // SAFETY: per contract.
        match unsafe { value.as_mut() } {
            Some(v) => *v = inst.last_successful_time(),
            None => {
                return Err(FmuError::NullPointer {
                    function: "fmi2GetRealStatus",
                    argument: "value",
                });
            }
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// fmi2GetBooleanStatus: fmi2Terminated (never requested by this FMU).
///
/// # Safety
/// `value` writable.
pub unsafe fn get_boolean_status<M: Model>(
    c: fmi2Component,
    kind: c_int,
    value: *mut fmi2Boolean,
) -> fmi2Status {
    with::<M>(c, "fmi2GetBooleanStatus", |_| {
        if fmi2StatusKind::from_raw(kind) != Some(fmi2StatusKind::fmi2Terminated) {
            return Err(FmuError::Unsupported(
                "fmi2GetBooleanStatus for a kind other than fmi2Terminated",
            ));
        }
        // SAFETY: per contract.
        match unsafe { value.as_mut() } {
            Some(v) => *v = fmi2False,
            None => {
                return Err(FmuError::NullPointer {
                    function: "fmi2GetBooleanStatus",
                    argument: "value",
                });
            }
        }
        Ok(fmi2Status::fmi2OK)
    })
}

/// The pointer type of the opaque environment, re-exported for the macro.
pub type Env = *mut c_void;

/// Exports the 34 FMI 2.0 co-simulation functions for a model type, with unmangled names.
///
/// Use once per cdylib: `fmu::export_fmi2!(my_crate::MyModel);`
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
