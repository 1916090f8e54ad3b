//! The `global_controller` FMU (see the `global_controller_model` crate for the model and its variables).
