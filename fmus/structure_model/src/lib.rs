//! Model wiring of the `structure` FMU: the telescope structure seen by M1 (modal model driven by actuator forces and pier motion).
