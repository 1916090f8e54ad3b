//! What is controlled: the segments on their actuators and servos, the telescope structure
//! (modal models, presets, import), the coupled and the quasi-static mirror solvers, and the
//! monolithic state-space and frequency models.

pub mod mirror;
pub mod monolithic;
pub mod segment;
pub mod static_mirror;
pub mod structure;
