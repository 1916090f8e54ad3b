//! The `global_controller` FMU (see the `global_controller_model` crate for the model and its variables).
fmu::export_fmi2!(global_controller_model::GlobalControllerModel);
