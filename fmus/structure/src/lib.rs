//! The `structure` FMU (see the `structure_model` crate for the model and its variables).
