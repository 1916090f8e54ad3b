//! The `optics` FMU: optical metrics of the mirror state (see the `optics_model` crate for the
//! model and its variables).
fmu::export_fmi2!(optics_model::Optics);
