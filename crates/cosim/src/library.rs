//! The FMU's shared library, loaded with dlopen, and the functions the master calls.
//!
//! Every one of the 34 FMI 2.0 Co-Simulation functions must be exported (as fmpy demands); the
//! ones the master calls are kept as function pointers. Their status results are read as
//! `c_int` and converted with [`fmi2Status::from_raw`](fmi_sys::fmi2::enums::fmi2Status::from_raw), so a foreign FMU returning an
//! out-of-range status cannot produce an invalid Rust enum.

use std::ffi::{CStr, CString, c_int, c_void};
use std::path::{Path, PathBuf};

use fmi_sys::fmi2::callbacks::fmi2CallbackFunctions;
use fmi_sys::fmi2::enums::fmi2Type;
use fmi_sys::fmi2::names::FMI2_CS_FUNCTIONS;
use fmi_sys::fmi2::types::{
    fmi2Boolean, fmi2Component, fmi2Integer, fmi2Real, fmi2String, fmi2ValueReference,
};

use crate::error::{CosimError, Result};

type Status = c_int;
pub(crate) type InstantiateFn = unsafe extern "C" fn(
    fmi2String,
    fmi2Type,
    fmi2String,
    fmi2String,
    *const fmi2CallbackFunctions,
    fmi2Boolean,
    fmi2Boolean,
) -> fmi2Component;
pub(crate) type FreeInstanceFn = unsafe extern "C" fn(fmi2Component);
pub(crate) type SetupExperimentFn = unsafe extern "C" fn(
    fmi2Component,
    fmi2Boolean,
    fmi2Real,
    fmi2Real,
    fmi2Boolean,
    fmi2Real,
) -> Status;
pub(crate) type ComponentFn = unsafe extern "C" fn(fmi2Component) -> Status;
pub(crate) type GetRealFn =
    unsafe extern "C" fn(fmi2Component, *const fmi2ValueReference, usize, *mut fmi2Real) -> Status;
pub(crate) type SetRealFn = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Real,
) -> Status;
pub(crate) type GetIntegerFn = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *mut fmi2Integer,
) -> Status;
pub(crate) type SetIntegerFn = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2Integer,
) -> Status;
pub(crate) type GetStringFn = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *mut fmi2String,
) -> Status;
pub(crate) type SetStringFn = unsafe extern "C" fn(
    fmi2Component,
    *const fmi2ValueReference,
    usize,
    *const fmi2String,
) -> Status;
pub(crate) type DoStepFn =
    unsafe extern "C" fn(fmi2Component, fmi2Real, fmi2Real, fmi2Boolean) -> Status;
/// fmi2GetBooleanStatus (the status kind as its C int).
pub(crate) type GetBooleanStatusFn =
    unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2Boolean) -> Status;
/// fmi2GetRealStatus (the status kind as its C int).
pub(crate) type GetRealStatusFn =
    unsafe extern "C" fn(fmi2Component, c_int, *mut fmi2Real) -> Status;

/// The function pointers the master uses.
#[derive(Clone, Copy)]
pub(crate) struct Functions {
    pub instantiate: InstantiateFn,
    pub free_instance: FreeInstanceFn,
    pub setup_experiment: SetupExperimentFn,
    pub enter_initialization_mode: ComponentFn,
    pub exit_initialization_mode: ComponentFn,
    pub terminate: ComponentFn,
    pub reset: ComponentFn,
    pub get_real: GetRealFn,
    pub set_real: SetRealFn,
    pub get_integer: GetIntegerFn,
    pub set_integer: SetIntegerFn,
    pub get_boolean: GetIntegerFn,
    pub set_boolean: SetIntegerFn,
    pub get_string: GetStringFn,
    pub set_string: SetStringFn,
    pub do_step: DoStepFn,
    pub get_boolean_status: GetBooleanStatusFn,
    pub get_real_status: GetRealStatusFn,
}

/// A loaded FMU library; unloaded (dlclose) when the last owner drops it.
pub struct Library {
    handle: *mut c_void,
    pub(crate) fns: Functions,
    path: PathBuf,
}

// SAFETY: the handle is only used for dlclose in Drop; FMI functions are callable from any thread
// (FMI 2.0 requires no thread affinity; instances are not shared between threads concurrently).
unsafe impl Send for Library {}
// SAFETY: as above; the function table is immutable.
unsafe impl Sync for Library {}

fn dlerror_text() -> String {
    // SAFETY: dlerror returns a thread-local string or null.
    let e = unsafe { libc::dlerror() };
    if e.is_null() {
        "unknown error".into()
    } else {
        // SAFETY: non-null, NUL-terminated.
        unsafe { CStr::from_ptr(e) }.to_string_lossy().into_owned()
    }
}

impl Library {
    /// dlopen `path` and resolve every FMI 2.0 Co-Simulation function.
    ///
    /// # Errors
    /// [`CosimError::Load`] if dlopen fails, [`CosimError::MissingSymbol`] naming the first
    /// function that is not exported.
    pub fn load(path: &Path) -> Result<Self> {
        let c_path =
            CString::new(path.as_os_str().as_encoded_bytes()).map_err(|_| CosimError::Load {
                library: path.to_path_buf(),
                reason: "path contains a NUL byte".into(),
            })?;
        // SAFETY: valid C string; RTLD_LOCAL keeps each FMU's fmi2* symbols apart.
        let handle = unsafe { libc::dlopen(c_path.as_ptr(), libc::RTLD_NOW | libc::RTLD_LOCAL) };
        if handle.is_null() {
            return Err(CosimError::Load {
                library: path.to_path_buf(),
                reason: dlerror_text(),
            });
        }
        let fns = Self::resolve(handle, path).inspect_err(|_| {
            // SAFETY: handle from dlopen above, closed once on this error path.
            unsafe { libc::dlclose(handle) };
        })?;
        Ok(Self {
            handle,
            fns,
            path: path.to_path_buf(),
        })
    }

    fn resolve(handle: *mut c_void, path: &Path) -> Result<Functions> {
        let sym = |name: &str| -> Result<*mut c_void> {
            let c = CString::new(name).map_err(|_| CosimError::MissingSymbol {
                library: path.to_path_buf(),
                symbol: name.into(),
            })?;
            // SAFETY: valid handle and C string.
            let p = unsafe { libc::dlsym(handle, c.as_ptr()) };
            if p.is_null() {
                Err(CosimError::MissingSymbol {
                    library: path.to_path_buf(),
                    symbol: name.into(),
                })
            } else {
                Ok(p)
            }
        };
        for name in FMI2_CS_FUNCTIONS {
            sym(name)?;
        }
        // SAFETY (all transmutes below): the symbols are the FMI 2.0 functions of these names,
        // whose C signatures the types above reproduce (enum results read as int).
        unsafe {
            Ok(Functions {
                instantiate: std::mem::transmute::<*mut c_void, InstantiateFn>(sym(
                    "fmi2Instantiate",
                )?),
                free_instance: std::mem::transmute::<*mut c_void, FreeInstanceFn>(sym(
                    "fmi2FreeInstance",
                )?),
                setup_experiment: std::mem::transmute::<*mut c_void, SetupExperimentFn>(sym(
                    "fmi2SetupExperiment",
                )?),
                enter_initialization_mode: std::mem::transmute::<*mut c_void, ComponentFn>(sym(
                    "fmi2EnterInitializationMode",
                )?),
                exit_initialization_mode: std::mem::transmute::<*mut c_void, ComponentFn>(sym(
                    "fmi2ExitInitializationMode",
                )?),
                terminate: std::mem::transmute::<*mut c_void, ComponentFn>(sym("fmi2Terminate")?),
                reset: std::mem::transmute::<*mut c_void, ComponentFn>(sym("fmi2Reset")?),
                get_real: std::mem::transmute::<*mut c_void, GetRealFn>(sym("fmi2GetReal")?),
                set_real: std::mem::transmute::<*mut c_void, SetRealFn>(sym("fmi2SetReal")?),
                get_integer: std::mem::transmute::<*mut c_void, GetIntegerFn>(sym(
                    "fmi2GetInteger",
                )?),
                set_integer: std::mem::transmute::<*mut c_void, SetIntegerFn>(sym(
                    "fmi2SetInteger",
                )?),
                get_boolean: std::mem::transmute::<*mut c_void, GetIntegerFn>(sym(
                    "fmi2GetBoolean",
                )?),
                set_boolean: std::mem::transmute::<*mut c_void, SetIntegerFn>(sym(
                    "fmi2SetBoolean",
                )?),
                get_string: std::mem::transmute::<*mut c_void, GetStringFn>(sym("fmi2GetString")?),
                set_string: std::mem::transmute::<*mut c_void, SetStringFn>(sym("fmi2SetString")?),
                do_step: std::mem::transmute::<*mut c_void, DoStepFn>(sym("fmi2DoStep")?),
                get_boolean_status: std::mem::transmute::<*mut c_void, GetBooleanStatusFn>(sym(
                    "fmi2GetBooleanStatus",
                )?),
                get_real_status: std::mem::transmute::<*mut c_void, GetRealStatusFn>(sym(
                    "fmi2GetRealStatus",
                )?),
            })
        }
    }

    /// The file it was loaded from.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Library {
    fn drop(&mut self) {
        // SAFETY: handle from dlopen, closed exactly once; no instance outlives the library
        // (instances hold an Arc of it).
        unsafe { libc::dlclose(self.handle) };
    }
}
