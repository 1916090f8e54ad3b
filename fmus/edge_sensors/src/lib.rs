//! The `edge_sensors` FMU (see the `edge_sensors_model` crate for the model and its variables).
fmu::export_fmi2!(edge_sensors_model::EdgeSensorsModel);
