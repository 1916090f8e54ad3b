//! The telescope structure seen by M1 (mirror-cell finite-element model, modal models, NPZ import).
