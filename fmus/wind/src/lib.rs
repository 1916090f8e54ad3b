//! The `wind` FMU: wind loads on the segments (see the `wind_model` crate for the model and its
//! variables).
fmu::export_fmi2!(wind_model::Wind);
