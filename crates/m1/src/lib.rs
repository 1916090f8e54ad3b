//! Physics of segmented primary mirrors, free of any FFI: mirror layouts, segment assemblies with
//! their actuators and encoder servos, and (as the project grows) geometry, interaction matrices,
//! control and optics. The FMI glue lives in the `fmu` crate; each FMU wires the two together.
//!
//! Units are SI throughout (m, N, kg, s, rad) unless a name says otherwise.

pub mod blockchol;
pub mod controller;
pub mod coupling;
pub mod csi;
pub mod error;
pub mod geometry;
pub mod global_csi;
pub mod interaction;
pub mod kernels;
pub mod krylov;
pub mod layout;
pub mod metrics;
pub mod mirror;
pub mod monolithic;
pub mod pssn;
pub mod quasistatic;
pub mod reconstructor;
pub mod segment;
pub mod sensors;
pub mod static_mirror;
pub mod structure;
pub mod vibration;
pub mod wind;
pub mod zernike;

pub use error::M1Error;
