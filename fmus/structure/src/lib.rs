//! The `structure` FMU (see the `structure_model` crate for the model and its variables).

fmu::export_fmi2!(structure_model::Structure);
