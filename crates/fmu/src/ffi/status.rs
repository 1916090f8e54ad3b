//! The forwards of the status queries (fmi2GetStatus, fmi2GetRealStatus,
//! fmi2GetBooleanStatus) and of the functions this FMU does not support. Steps complete
//! synchronously, so the only statuses worth asking are the last step's (always fmi2OK when it
//! returned), the last successful time, and whether the FMU asked to terminate (never).

use std::ffi::c_int;

use fmi_sys::fmi2::*;

use super::guard::with;
use crate::error::FmuError;
use crate::model::Model;

/// A call this FMU does not support: fmi2Error with a message naming it.
///
/// Relies on `c` being NULL or a live instance of this FMU that no other call is using (the
/// contract of [`crate::export_fmi2!`]); the unsupported function's other arguments are never
/// read.
pub fn unsupported<M: Model>(c: fmi2Component, function: &'static str) -> fmi2Status {
    with::<M>(c, function, |_| Err(FmuError::Unsupported(function)))
}

/// fmi2GetStatus.
///
/// # Safety
/// `value` writable: NULL (refused) or pointing to one writable element, valid for the duration of
/// the call. `kind` may be any integer (checked). `c` as for every forward (see
/// [`crate::export_fmi2!`]).
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
/// `value` writable: NULL (refused) or pointing to one writable element, valid for the duration of
/// the call. `kind` may be any integer (checked). `c` as for every forward (see
/// [`crate::export_fmi2!`]).
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
/// `value` writable: NULL (refused) or pointing to one writable element, valid for the duration of
/// the call. `kind` may be any integer (checked). `c` as for every forward (see
/// [`crate::export_fmi2!`]).
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
