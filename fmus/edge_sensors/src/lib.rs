//! The `edge_sensors` FMU (see the `edge_sensors_model` crate for the model and its variables).
