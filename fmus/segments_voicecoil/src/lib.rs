//! The `segments_voicecoil` FMU: every segment on soft voice-coil actuators (see the
//! `segments` crate for the model and its variables).
fmu::export_fmi2!(segments::VoiceCoil);
