//! Enumerations of FMI 2.0 (`fmi2FunctionTypes.h`).
//!
//! All are C enums, i.e. `int` on the target platform. Values coming from foreign code must
//! be converted with the `from_raw` functions instead of being transmuted.

#![allow(non_camel_case_types)]

use std::ffi::c_int;

/// Status returned by all FMI functions that can fail (C enum `fmi2Status`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum fmi2Status {
    /// All well.
    fmi2OK = 0,
    /// Things are not quite right, but the computation can continue.
    fmi2Warning = 1,
    /// The call was not successful; for Co-Simulation, the step was not performed and the
    /// importer may retry, e.g. with a smaller step.
    fmi2Discard = 2,
    /// The call failed; the instance may only be freed (or reset / state-restored).
    fmi2Error = 3,
    /// The model computations are irreparably corrupted for all instances.
    fmi2Fatal = 4,
    /// Co-Simulation only: `fmi2DoStep` runs asynchronously and has not finished yet.
    fmi2Pending = 5,
}

impl fmi2Status {
    /// Converts a raw C `int` into a status, or `None` if it is not a valid `fmi2Status`.
    pub const fn from_raw(raw: i32) -> Option<Self> {
        match raw {
            0 => Some(Self::fmi2OK),
            1 => Some(Self::fmi2Warning),
            2 => Some(Self::fmi2Discard),
            3 => Some(Self::fmi2Error),
            4 => Some(Self::fmi2Fatal),
            5 => Some(Self::fmi2Pending),
            _ => None,
        }
    }

    /// Returns the raw C `int` value of this status.
    pub const fn to_raw(self) -> c_int {
        self as c_int
    }
}

/// Kind of FMU interface requested in `fmi2Instantiate` (C enum `fmi2Type`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum fmi2Type {
    /// Model Exchange: the importer integrates the model's continuous states.
    fmi2ModelExchange = 0,
    /// Co-Simulation: the FMU contains its own solver and is advanced with `fmi2DoStep`.
    fmi2CoSimulation = 1,
}

impl fmi2Type {
    /// Converts a raw C `int` into an FMU type, or `None` if it is not a valid `fmi2Type`.
    pub const fn from_raw(raw: i32) -> Option<Self> {
        match raw {
            0 => Some(Self::fmi2ModelExchange),
            1 => Some(Self::fmi2CoSimulation),
            _ => None,
        }
    }
}

/// Which status is queried with the Co-Simulation `fmi2Get*Status` functions
/// (C enum `fmi2StatusKind`).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum fmi2StatusKind {
    /// Status of an asynchronous `fmi2DoStep` (queried with `fmi2GetStatus`).
    fmi2DoStepStatus = 0,
    /// Description of the pending asynchronous step (queried with `fmi2GetStringStatus`).
    fmi2PendingStatus = 1,
    /// Time of the last successful step after a discard (queried with `fmi2GetRealStatus`).
    fmi2LastSuccessfulTime = 2,
    /// Whether the slave wants to terminate the simulation (queried with
    /// `fmi2GetBooleanStatus`).
    fmi2Terminated = 3,
}

impl fmi2StatusKind {
    /// Converts a raw C `int` into a status kind, or `None` if it is not a valid
    /// `fmi2StatusKind`.
    pub const fn from_raw(raw: i32) -> Option<Self> {
        match raw {
            0 => Some(Self::fmi2DoStepStatus),
            1 => Some(Self::fmi2PendingStatus),
            2 => Some(Self::fmi2LastSuccessfulTime),
            3 => Some(Self::fmi2Terminated),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{align_of, size_of};

    const ALL_STATUS: [fmi2Status; 6] = [
        fmi2Status::fmi2OK,
        fmi2Status::fmi2Warning,
        fmi2Status::fmi2Discard,
        fmi2Status::fmi2Error,
        fmi2Status::fmi2Fatal,
        fmi2Status::fmi2Pending,
    ];

    #[test]
    fn enums_are_c_int_sized() {
        assert_eq!(size_of::<fmi2Status>(), size_of::<c_int>());
        assert_eq!(align_of::<fmi2Status>(), align_of::<c_int>());
        assert_eq!(size_of::<fmi2Type>(), size_of::<c_int>());
        assert_eq!(size_of::<fmi2StatusKind>(), size_of::<c_int>());
    }

    #[test]
    fn status_discriminants() {
        assert_eq!(fmi2Status::fmi2OK as i32, 0);
        assert_eq!(fmi2Status::fmi2Warning as i32, 1);
        assert_eq!(fmi2Status::fmi2Discard as i32, 2);
        assert_eq!(fmi2Status::fmi2Error as i32, 3);
        assert_eq!(fmi2Status::fmi2Fatal as i32, 4);
        assert_eq!(fmi2Status::fmi2Pending as i32, 5);
    }

    #[test]
    fn status_from_raw_round_trip() {
        for s in ALL_STATUS {
            assert_eq!(fmi2Status::from_raw(s.to_raw()), Some(s));
            assert_eq!(fmi2Status::from_raw(s as i32), Some(s));
        }
        for raw in [-1, 6, 7, i32::MIN, i32::MAX] {
            assert_eq!(fmi2Status::from_raw(raw), None);
        }
    }

    #[test]
    fn type_discriminants_and_round_trip() {
        assert_eq!(fmi2Type::fmi2ModelExchange as i32, 0);
        assert_eq!(fmi2Type::fmi2CoSimulation as i32, 1);
        for t in [fmi2Type::fmi2ModelExchange, fmi2Type::fmi2CoSimulation] {
            assert_eq!(fmi2Type::from_raw(t as i32), Some(t));
        }
        assert_eq!(fmi2Type::from_raw(2), None);
        assert_eq!(fmi2Type::from_raw(-1), None);
    }

    #[test]
    fn status_kind_discriminants_and_round_trip() {
        let all = [
            fmi2StatusKind::fmi2DoStepStatus,
            fmi2StatusKind::fmi2PendingStatus,
            fmi2StatusKind::fmi2LastSuccessfulTime,
            fmi2StatusKind::fmi2Terminated,
        ];
        for (i, k) in all.into_iter().enumerate() {
            assert_eq!(k as usize, i);
            assert_eq!(fmi2StatusKind::from_raw(k as i32), Some(k));
        }
        assert_eq!(fmi2StatusKind::from_raw(4), None);
        assert_eq!(fmi2StatusKind::from_raw(-1), None);
    }
}
