//! Model wiring of the `optics` FMU: optical metrics of the mirror state (rms surface, focus-mode, PSSN).
