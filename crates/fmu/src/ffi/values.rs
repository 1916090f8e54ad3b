//! The forwards of the value getters and setters (fmi2Get/SetReal, Integer, Boolean,
//! String): the C arrays become slices (checked for NULL) and the instance does the rest. Each
//! states the part of the FMI 2.0 contract on the importer it relies on: how many elements each
//! pointer must be valid for, and for how long.

use std::ffi::c_char;

use fmi_sys::fmi2::*;

use super::guard::{ok, with};
use super::pointers::{slice, slice_mut, string};
use crate::error::FmuError;
use crate::instance::Instance;
use crate::model::Model;

/// One getter forward per type: `$cname` is the FMI function, `$t` the C element type,
/// `$extra` what the contract adds for this type (a doc line), `$conv` the body.
macro_rules! getter {
    ($fname:ident, $cname:literal, $t:ty, $method:ident, $extra:literal, $conv:expr) => {
        #[doc = concat!("The FMI getter of this type: ", $cname, ".")]
        ///
        /// # Safety
        /// `vr` and `value` must hold `nvr` elements when non-NULL: `vr` `nvr` readable value
        /// references and `value` `nvr` writable elements of this type, not overlapping, both
        /// valid for the duration of the call (NULL with `nvr` > 0 is refused). `c` as for every
        /// forward (see [`crate::export_fmi2!`]).
        #[doc = $extra]
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
    "",
    |i: &mut Instance<M>, v: &[u32], o: &mut [f64]| i.get_real(v, o)
);
getter!(
    get_integer,
    "fmi2GetInteger",
    fmi2Integer,
    get_integer,
    "",
    |i: &mut Instance<M>, v: &[u32], o: &mut [i32]| i.get_integer(v, o)
);
getter!(
    get_boolean,
    "fmi2GetBoolean",
    fmi2Boolean,
    get_boolean,
    "Each value written is fmi2True or fmi2False.",
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
    "The pointers written stay valid until the string is set again or the instance is freed.",
    |i: &mut Instance<M>, v: &[u32], o: &mut [*const c_char]| i.get_string(v, o)
);

/// fmi2SetReal.
///
/// # Safety
/// `vr` and `value` must hold `nvr` elements when non-NULL: `vr` `nvr` readable value
/// references and `value` `nvr` readable elements, both valid for the duration of the call
/// (NULL with `nvr` > 0 is refused). `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `vr` and `value` must hold `nvr` elements when non-NULL: `vr` `nvr` readable value
/// references and `value` `nvr` readable elements, both valid for the duration of the call
/// (NULL with `nvr` > 0 is refused). `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `vr` and `value` must hold `nvr` elements when non-NULL: `vr` `nvr` readable value
/// references and `value` `nvr` readable elements, both valid for the duration of the call
/// (NULL with `nvr` > 0 is refused). `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `vr` and `value` must hold `nvr` elements when non-NULL, each a C string: `vr` `nvr`
/// readable value references and `value` `nvr` readable `fmi2String`s, each NULL (refused) or
/// NUL-terminated, all valid for the duration of the call (the values are copied). `c` as for
/// every forward (see [`crate::export_fmi2!`]).
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
