//! Optical figures of a mirror state: the rms surface metrics (with and without focus-mode, per
//! segment) and the PSSN.

pub mod metrics;
pub mod pssn;
