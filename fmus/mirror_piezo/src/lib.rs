//! The `mirror_piezo` FMU: every segment on hard piezo actuators (LR shunt optional), coupled
//! to the structure (see the `mirror` crate for the model and its variables).
fmu::export_fmi2!(mirror::Piezo);
