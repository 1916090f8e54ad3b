//! Optical figures of a mirror state: the rms surface metrics (with and without focus-mode, per
//! segment), the PSSN, and the random segment states of the PSSN studies with their statistics.

pub mod metrics;
pub mod pssn;
pub mod statistics;
