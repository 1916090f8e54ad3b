//! The string and pointer helpers of the C boundary: C arrays as slices (NULL only for an
//! empty array), C strings as `&str`, and FMU state pointers resolved and checked by their tag.
//! Each is `unsafe` with the contract its caller must establish, usually by passing on the
//! importer's part of the FMI 2.0 contract (see [`crate::export_fmi2!`]).

use std::ffi::CStr;

use fmi_sys::fmi2::*;

use crate::error::FmuError;
use crate::instance::{MAGIC, Snapshot};
use crate::model::Model;

/// Builds a slice from a C array; NULL is allowed only for an empty array.
///
/// # Safety
/// `p` must point to `n` valid elements when non-NULL.
pub(super) unsafe fn slice<'a, T>(
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

/// Builds a mutable slice from a C array; NULL is allowed only for an empty array.
///
/// # Safety
/// `p` must point to `n` writable elements when non-NULL.
pub(super) unsafe fn slice_mut<'a, T>(
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

/// Borrows a C string as UTF-8 (`None` if NULL or not UTF-8).
///
/// # Safety
/// `s` must be NULL or a valid C string.
pub(super) unsafe fn string<'a>(s: fmi2String) -> Option<&'a str> {
    if s.is_null() {
        None
    } else {
        // SAFETY: non-NULL C string from the importer.
        unsafe { CStr::from_ptr(s) }.to_str().ok()
    }
}

/// Resolves an FMU state pointer: NULL and untagged states are refused.
///
/// # Safety
/// `s` must be NULL or a state allocated by this FMU.
pub(super) unsafe fn snapshot<'a, M: Model>(
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
