//! The `wind` FMU (see the `wind_model` crate for the model and its variables).
