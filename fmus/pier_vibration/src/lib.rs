//! The `pier_vibration` FMU (see the `pier_vibration_model` crate for the model and its variables).
