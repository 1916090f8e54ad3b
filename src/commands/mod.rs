//! The analysis subcommands of `m1cs`, one module per family.

pub mod cosim;
pub mod csi;
pub mod dynamics;
pub mod optics;
pub mod quasistatic;
pub mod report;
pub mod wind;
