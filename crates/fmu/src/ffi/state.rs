//! The forwards of the FMU-state functions: get, set and free a state, its serialised size,
//! serialisation and deserialisation. States are tagged boxes ([`Snapshot`]) handed to the
//! importer as `fmi2FMUstate`; each forward states the part of the FMI 2.0 contract on the
//! importer it relies on (which slot or buffer must be valid, for how many bytes).

use fmi_sys::fmi2::*;

use super::guard::{ok, with};
use super::pointers::{slice, slice_mut, snapshot};
use crate::error::FmuError;
use crate::instance::{Instance, MAGIC, Snapshot};
use crate::model::Model;

/// fmi2GetFMUstate: allocates a new state, or overwrites the one given.
///
/// # Safety
/// `state` must point to a valid fmi2FMUstate slot: readable and writable for the duration of
/// the call (NULL is refused), holding NULL or a state of this FMU not yet freed (that state is
/// overwritten in place; any other content would be read as one).
/// `c` as for every forward (see [`crate::export_fmi2!`]).
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

/// fmi2SetFMUstate.
///
/// # Safety
/// `state` must be a state from fmi2GetFMUstate of this FMU (or fmi2DeSerializeFMUstate), not
/// yet freed; NULL is refused, and the tag catches other pointers on a best-effort basis only.
/// `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `state` must point to a slot holding NULL or a state of this FMU: NULL itself is allowed
/// (nothing to free); otherwise readable and writable for the duration of the call, set to NULL
/// once the state is freed. `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `state` from this FMU; `size` writable: `state` as for [`set_fmu_state`], `size` NULL (refused)
/// or pointing to one writable `size_t`. `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `state` from this FMU; `bytes` holds `size` writable bytes: `state` as for [`set_fmu_state`];
/// `bytes` NULL (refused unless `size` is 0) or `size` bytes writable for the duration of the call,
/// not overlapping the state. `c` as for every forward (see [`crate::export_fmi2!`]).
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
/// `bytes` holds `size` bytes; `state` is a valid slot: `bytes` NULL (refused unless `size` is 0)
/// or `size` bytes readable for the duration of the call; `state` NULL (refused) or a slot as for
/// [`get_fmu_state`] (NULL, or a state of this FMU to overwrite in place). `c` as for every forward
/// (see [`crate::export_fmi2!`]).
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
