//! The guard around every body: the instance pointer is resolved (NULL and foreign pointers
//! refused), the body runs under `catch_unwind` so that no panic crosses the C boundary, and
//! its `Result` becomes a status in one place (`finish`), the error sent through the
//! importer's logger. After fmi2Fatal only freeing is allowed.

use std::panic::{AssertUnwindSafe, catch_unwind};

use fmi_sys::fmi2::*;

use crate::error::FmuError;
use crate::instance::{Instance, MAGIC};
use crate::model::Model;

/// The message of a caught panic.
pub(super) fn panic_message(p: &(dyn std::any::Any + Send)) -> String {
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
///
/// Relies on `c` being NULL or a component that fmi2Instantiate of this FMU returned and
/// fmi2FreeInstance has not freed (the FMI 2.0 contract on the importer): the tag is read
/// through the pointer, so it catches foreign pointers and freed instances on a best-effort
/// basis only.
pub(super) fn instance<M: Model>(c: fmi2Component, function: &str) -> Option<*mut Instance<M>> {
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
///
/// Relies on what [`instance`] relies on, and on no other call on the same instance running
/// at the same time (FMI 2.0: calls on one instance are sequential), which makes the `&mut`
/// given to `body` exclusive.
pub(super) fn with<M: Model>(
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

/// A body's `Ok(())` as fmi2OK.
pub(super) fn ok(r: Result<(), FmuError>) -> Result<fmi2Status, FmuError> {
    r.map(|()| fmi2Status::fmi2OK)
}
