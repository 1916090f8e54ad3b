//! Platform-dependent definitions of FMI 2.0 (`fmi2TypesPlatform.h`, `"default"` platform).
//!
//! The standard uses these aliases instead of plain C types in all function interfaces.

#![allow(non_camel_case_types, non_upper_case_globals)]

use std::ffi::{CStr, c_char, c_double, c_int, c_uint, c_void};

/// Value of the `fmi2TypesPlatform` macro: the types platform the FMU was compiled for.
pub const FMI2_TYPES_PLATFORM: &CStr = c"default";

/// Value of the `fmi2Version` macro: the FMI version of the headers.
pub const FMI2_VERSION: &CStr = c"2.0";

/// Pointer to an FMU instance (opaque, owned by the FMU).
pub type fmi2Component = *mut c_void;

/// Pointer to the importer's environment, passed back unchanged in callbacks.
pub type fmi2ComponentEnvironment = *mut c_void;

/// Pointer to an internal FMU state snapshot (opaque, owned by the FMU).
pub type fmi2FMUstate = *mut c_void;

/// Handle identifying a variable value (`valueReference` in modelDescription.xml).
pub type fmi2ValueReference = c_uint;

/// Real (floating point) variable value.
pub type fmi2Real = c_double;

/// Integer variable value.
pub type fmi2Integer = c_int;

/// Boolean variable value; [`fmi2True`] or [`fmi2False`].
pub type fmi2Boolean = c_int;

/// Single character of an FMI string.
pub type fmi2Char = c_char;

/// Zero-terminated string (`const fmi2Char*`), UTF-8 encoded.
pub type fmi2String = *const fmi2Char;

/// Smallest addressable unit; used for serialized FMU states.
pub type fmi2Byte = c_char;

/// Value of an [`fmi2Boolean`] meaning true.
pub const fmi2True: fmi2Boolean = 1;

/// Value of an [`fmi2Boolean`] meaning false.
pub const fmi2False: fmi2Boolean = 0;

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::size_of;

    #[test]
    fn platform_strings() {
        assert_eq!(FMI2_TYPES_PLATFORM.to_bytes(), b"default");
        assert_eq!(FMI2_VERSION.to_bytes(), b"2.0");
    }

    #[test]
    fn booleans() {
        assert_eq!(fmi2True, 1);
        assert_eq!(fmi2False, 0);
    }

    #[test]
    fn sizes_on_x86_64_linux() {
        assert_eq!(size_of::<fmi2ValueReference>(), 4);
        assert_eq!(size_of::<fmi2Real>(), 8);
        assert_eq!(size_of::<fmi2Integer>(), 4);
        assert_eq!(size_of::<fmi2Boolean>(), 4);
        assert_eq!(size_of::<fmi2Char>(), 1);
        assert_eq!(size_of::<fmi2Byte>(), 1);
        assert_eq!(size_of::<fmi2String>(), size_of::<*const c_void>());
        assert_eq!(size_of::<fmi2Component>(), size_of::<*const c_void>());
    }
}
