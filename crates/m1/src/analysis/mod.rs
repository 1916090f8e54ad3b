//! Studies built on the rest: the quasi-static analyses (SVD, the robustness of Table 1, noise,
//! clocking, calibration), control-structure interaction of both loops, the split-coupling
//! study, the figures of a segment's step response, and the studies' default settings.

pub mod coupling;
pub mod csi;
pub mod defaults;
pub mod global_csi;
pub mod overall;
pub mod quasistatic;
pub mod step_response;
