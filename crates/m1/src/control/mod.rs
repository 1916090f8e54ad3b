//! The control algorithm: the nominal setup (A, its reconstructor, focus-mode), the sparse
//! reconstructor and its factor, the global controller with its modal gains.

pub mod aps;
pub mod controller;
pub mod nominal;
pub mod reconstructor;
