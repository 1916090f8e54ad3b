//! The `pier_vibration` FMU: vertical pier vibration (see the `pier_vibration_model` crate for the
//! model and its variables).
fmu::export_fmi2!(pier_vibration_model::PierVibrationFmu);
