//! Model wiring of the `global_controller` FMU: the global edge-sensor control loop (reconstructor, modal integral control at 20 Hz).
