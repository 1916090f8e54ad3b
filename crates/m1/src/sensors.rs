//! Edge-sensor readings with gain errors, noise and installation errors.
