//! The mirror's shape: segment layouts (TMT, Keck, ELT), the geometry built on one (segment
//! frames, actuators, edges, sensors) and Zernike bases on the segmented aperture.

pub mod geometry;
pub mod layout;
pub mod zernike;
