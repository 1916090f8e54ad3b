//! Optical metrics of a mirror state (rms surface, focus-mode, PSSN).
