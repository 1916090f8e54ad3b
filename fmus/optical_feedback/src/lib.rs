//! The `optical_feedback` FMU: optical feedback of the global low-order modes (see the
//! `optical_feedback_model` crate for the model and its variables).
fmu::export_fmi2!(optical_feedback_model::OpticalFeedbackFmu);
