//! The default settings of the studies: the one source the command line (`m1cs`, and so
//! `m1cs report`) takes them from. Grouped by study: the structure the dynamic studies retain,
//! the servo and global loops' control-structure interaction ([`csi`], [`global_csi`]), the
//! pier vibration ([`vibration`]), the split-coupling study ([`coupling`]), the wind sweep of
//! the seed paper's Figure 12 ([`wind`]) and the Monte Carlo check of the calibration
//! ([`calibration`]).
//!
//! Defaults an analysis' parameters already carry are not restated here: take them from there
//! ([`RobustnessParams::default`](super::quasistatic::RobustnessParams),
//! [`GlobalCriteria::default`](super::global_csi::GlobalCriteria) for the allowance,
//! [`Excitation::default`](super::coupling::Excitation) for the pier tone and run length,
//! [`ControllerParams::default`](crate::control::controller::ControllerParams) and its
//! constants for the global loop, [`PssnParams::default`](crate::optics::pssn::PssnParams),
//! [`WindParams::default`](crate::loads::wind::WindParams) for the wind speed).

/// Structure modes the dynamic studies retain (the lowest; the mirror FMU's `n_modes` starts
/// at the same 60).
pub const STRUCTURE_MODES: usize = 60;

/// Modal damping ratio of the structure (*assumed*; the structure FMU's `damping_ratio` starts
/// at the same 0.02).
pub const DAMPING_RATIO: f64 = 0.02;

/// The actuator servo loop on the flexible structure ([`crate::analysis::csi`]).
pub mod csi {
    /// Largest radial degree of the Zernike bases the sensitivity is evaluated in.
    pub const MAX_DEGREE: u32 = 8;
    /// Log-spaced points of the frequency grid (a refinement around each peak is added).
    pub const FREQUENCIES: usize = 200;
    /// Lowest frequency of the grid (Hz).
    pub const FMIN_HZ: f64 = 1.0;
    /// Highest frequency of the grid (Hz).
    pub const FMAX_HZ: f64 = 300.0;
    /// The sensitivity criterion: sigma_max(S) below this...
    pub const MAX_SENSITIVITY: f64 = 2.0;
    /// ... at every grid frequency up to this (Hz).
    pub const BELOW_HZ: f64 = 15.0;
    /// Range `[lo, hi]` of the factor on the servo gains searched for the highest gain.
    pub const GAIN_RANGE: [f64; 2] = [0.05, 20.0];
}

/// The global edge-sensor loop on the flexible structure ([`crate::analysis::global_csi`]).
pub mod global_csi {
    /// Structure modes of the global loop's model (the lowest, at most the servo study's): the
    /// loop's band with its sampling images ends at 3.5 loop rates.
    pub const MODES: usize = 100;
    /// Log-spaced grid points from [`FMIN_HZ`] to the start of the loop-gain band.
    pub const FREQUENCIES: usize = 80;
    /// Grid step (Hz) from the start of the loop-gain band to the loop's Nyquist frequency,
    /// fine enough for the structure's lightly damped modes (half-power width `2 zeta f` =
    /// 0.36 Hz at 9 Hz).
    pub const BAND_STEP_HZ: f64 = 0.05;
    /// Lowest frequency of the grid (Hz).
    pub const FMIN_HZ: f64 = 0.01;
    /// Images of the sensors' sampling summed on each side.
    pub const ALIASES: usize = 3;
    /// Realizations of 0.1 % sensor-gain errors whose worst sigma_max(Gamma Psi Q Psi^T) is
    /// set against the allowance.
    pub const Q_REALIZATIONS: usize = 20;
}

/// M1 under a vertical pier tone, from the monolithic frequency model (the seed paper's
/// Figure 13).
pub mod vibration {
    /// Lowest pier frequency (Hz).
    pub const FMIN_HZ: f64 = 1.0;
    /// Highest pier frequency (Hz).
    pub const FMAX_HZ: f64 = 60.0;
    /// Frequency step (Hz); [`MOTOR_TONE_HZ`] is always added.
    pub const STEP_HZ: f64 = 0.25;
    /// Rms vertical pier motion the PSSN is evaluated for (m; *assumed*: 10 nm).
    pub const PIER_RMS: f64 = 10e-9;
    /// The PSSN is evaluated every this many frequency points (and at [`MOTOR_TONE_HZ`]): each
    /// costs two pupil FFTs.
    pub const PSSN_EVERY: usize = 4;
    /// The tone of the induction motors the seed paper singles out (Hz; the pier-vibration
    /// FMU's first tone is the same 29.6 Hz).
    pub const MOTOR_TONE_HZ: f64 = 29.6;
}

/// Segments and structure as two co-simulation components against the coupled solver
/// ([`crate::analysis::coupling`]).
pub mod coupling {
    /// The layout of the study: Keck, small enough to run every step and order in seconds.
    pub const LAYOUT: &str = "keck";
    /// Structure modes retained.
    pub const MODES: usize = 30;
    /// Communication steps tried (s): multiples of the 0.2 ms servo period.
    pub const STEPS: [f64; 4] = [0.0002, 0.0004, 0.0006, 0.001];
    /// Relative rms error under which a stable run counts as accurate.
    pub const TOLERANCE: f64 = 0.01;
}

/// M1 under wind versus wind speed and global-loop bandwidth (the seed paper's Figure 12).
pub mod wind {
    /// Mean wind speeds of the sweep (m/s).
    pub const SPEEDS: [f64; 3] = [0.5, 1.0, 2.0];
    /// Global-loop bandwidths of the sweep on the modes of radial degrees >= 5 (Hz); the other
    /// groups keep the baseline's ratios to it.
    pub const BANDWIDTHS: [f64; 3] = [0.25, 0.5, 1.0];
}

/// The Monte Carlo check of the calibration's exact figures
/// ([`crate::analysis::quasistatic::calibration`]).
pub mod calibration {
    /// Samples.
    pub const SAMPLES: usize = 50;
    /// Seed.
    pub const SEED: u64 = 1;
}
