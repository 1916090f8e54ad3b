//! Pier vibration sources (tones and band-limited noise).
