//! Model wiring of the `edge_sensors` FMU: edge-sensor readings (height + Leff x dihedral, gap) from segment motion.
