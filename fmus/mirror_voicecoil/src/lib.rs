//! The `mirror_voicecoil` FMU: every segment on soft voice-coil actuators, coupled to the
//! structure (see the `mirror` crate for the model and its variables).
fmu::export_fmi2!(mirror::VoiceCoil);
