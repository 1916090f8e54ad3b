//! The `deformation` FMU: gravity and thermal deformation of the mirror cell (see the
//! `deformation_model` crate for the model and its variables).
fmu::export_fmi2!(deformation_model::DeformationFmu);
