//! The `aps` FMU: Alignment and Phasing System runs that reset the desired edge-sensor readings
//! (see the `aps_model` crate for the model and its variables).
fmu::export_fmi2!(aps_model::ApsFmu);
