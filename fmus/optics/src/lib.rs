//! The `optics` FMU (see the `optics_model` crate for the model and its variables).
