//! The global edge-sensor control loop (reconstructor, modal integral control).
