//! Edge sensing: the sensor/actuator interaction matrices (A and its in-plane parts) and the
//! edge-sensor model with noise.

pub mod installed;
pub mod interaction;
pub mod sensors;
