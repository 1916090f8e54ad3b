//! The `segments_piezo` FMU: every segment on hard piezo actuators with an optional LR shunt
//! (see the `segments` crate for the model and its variables).
fmu::export_fmi2!(segments::Piezo);
