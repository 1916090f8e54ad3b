//! Disturbances: the wind's pressure screens and segment loads, pier vibration sources.

pub mod deformation;
pub mod vibration;
pub mod wind;
