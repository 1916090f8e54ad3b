//! Model wiring of the `pier_vibration` FMU: vertical pier vibration (tones plus band-limited noise).
