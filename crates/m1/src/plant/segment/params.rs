//! The parameters of a segment and its actuators: the segment and its support
//! ([`SegmentParams`]), the encoder servo ([`ServoParams`]), the drive variants ([`Drive`]:
//! voice coil, or piezo stack with an optional LR shunt [`Shunt`]) and the actuator presets
//! ([`ActuatorParams`]).

use serde::{Deserialize, Serialize};

use super::{PIEZO_INTEGRAL_GAIN, PIEZO_STIFFNESS, SHUNT_FREQUENCY};

/// The segment and its support, identical for every segment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentParams {
    /// Mass carried by the three actuators, glass and support module (kg) (default: 220).
    pub mass: f64,
    /// Moment of inertia of the carried mass about an in-plane diameter through the centre
    /// (kg m^2) (default: 23.76, a uniform hexagon of 0.72 m circumradius: 5/24 m a^2).
    pub inertia: f64,
    /// Radius of the actuator circle (m) (default: 0.36).
    pub actuator_radius: f64,
    /// The support module's moving part (moving frame and whiffletrees) between the actuators
    /// and the glass's flexures, part of `mass`, taken as concentrated at the actuator points
    /// (kg) (default: 65, the published support module without the subcell). 0 removes the
    /// whiffletree from the chain (node -k_s- glass, the model before issue 14; then
    /// `whiffletree_frequency` is unused).
    pub support_mass: f64,
    /// Mode of the glass on its flexures, piston, with the whiffletree clamped (Hz)
    /// (default: 120).
    pub support_piston_frequency: f64,
    /// Mode of the glass on its flexures, tip/tilt, with the whiffletree clamped (Hz)
    /// (default: 90).
    pub support_tilt_frequency: f64,
    /// Lowest mode of the whole assembly with the actuators locked: glass and whiffletree
    /// rocking on the whiffletree's stiffness (tip/tilt) (Hz) (default: 40). Less than
    /// `support_tilt_frequency`.
    pub whiffletree_frequency: f64,
    /// Damping ratio of the support modes (default: 0.02).
    pub support_damping_ratio: f64,
}

impl Default for SegmentParams {
    fn default() -> Self {
        Self {
            mass: 220.0,
            inertia: 23.76,
            actuator_radius: 0.36,
            support_mass: 65.0,
            support_piston_frequency: 120.0,
            support_tilt_frequency: 90.0,
            whiffletree_frequency: 40.0,
            support_damping_ratio: 0.02,
        }
    }
}

/// The discrete encoder servo of each actuator. Gains are in the drive's units: N/m for a
/// voice coil (force per metre of error), dimensionless for a piezo (extension per metre).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ServoParams {
    /// Servo sample rate (Hz) (default: 5000).
    pub rate: f64,
    /// Proportional gain (drive unit per m).
    pub kp: f64,
    /// Integral gain (drive unit per m s).
    pub ki: f64,
    /// Derivative gain (drive unit s per m).
    pub kd: f64,
    /// Corner of the derivative's first-order filter (Hz).
    pub derivative_cutoff: f64,
    /// Leak corner of the integrator (Hz); 0 makes it a pure integrator.
    pub integrator_leak: f64,
    /// Weight b of the command in the proportional term, kp (b u_cmd - s): 1 is a plain PID,
    /// less tames the command overshoot without changing stiffness or disturbance rejection.
    pub setpoint_weight: f64,
    /// Command feedforward k_ff: drive added per metre of command (drive unit per m; 1 for a
    /// piezo makes the free extension follow the command, 0 for the voice coil).
    pub feedforward: f64,
}

/// Resonant LR shunt of a piezo stack.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Shunt {
    /// Generalised electromechanical coupling factor kappa (default: 0.3).
    pub coupling: f64,
    /// Electrical resonance 1/(2 pi sqrt(L C)) (Hz) (default: [`SHUNT_FREQUENCY`], tuned to
    /// the segment's piston mode on the stacks).
    pub frequency: f64,
    /// Electrical damping ratio R/(2 L omega_e) (default: 0.2).
    pub damping_ratio: f64,
}

impl Default for Shunt {
    fn default() -> Self {
        Self {
            coupling: 0.3,
            frequency: SHUNT_FREQUENCY,
            damping_ratio: 0.2,
        }
    }
}

/// What drives the actuator node.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Drive {
    /// Soft voice coil with an offload spring: the servo commands a force.
    VoiceCoil {
        /// Offload spring stiffness (N/m) (default: 2e4, i.e. 0.02 N/um).
        spring_stiffness: f64,
        /// Damping of the spring and coil (N s/m) (default: 50).
        spring_damping: f64,
    },
    /// Hard piezo stack: the servo commands a free extension.
    Piezo {
        /// Open-circuit stiffness of the stack K_D (N/m) (default: [`PIEZO_STIFFNESS`]).
        stiffness: f64,
        /// Structural damping ratio of the stack, on the segment's piston mode: the damper is
        /// c = 2 zeta sqrt(K_D (m_a + m / 3)) (default: 0.01).
        damping_ratio: f64,
        /// The LR shunt, if connected.
        shunt: Option<Shunt>,
    },
}

/// One actuator with its servo.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ActuatorParams {
    /// Moving mass of the actuator output node (kg) (default: 2).
    pub moving_mass: f64,
    /// The drive.
    pub drive: Drive,
    /// The encoder servo.
    pub servo: ServoParams,
}

impl ActuatorParams {
    /// The baseline soft actuator: voice coil, offload spring, 5 kHz PID with a leaky
    /// integrator (closed-loop stiffness above 10 N/um below 1 Hz, bandwidth 25-30 Hz).
    pub fn voice_coil() -> Self {
        Self {
            moving_mass: 2.0,
            drive: Drive::VoiceCoil {
                spring_stiffness: 2.0e4,
                spring_damping: 50.0,
            },
            servo: ServoParams {
                rate: 5000.0,
                kp: 1.5e6,
                ki: 7.0e7,
                kd: 1.5e4,
                derivative_cutoff: 800.0,
                integrator_leak: 0.05,
                setpoint_weight: 0.8,
                feedforward: 0.0,
            },
        }
    }

    /// The hard actuator: piezo stack driven by the command (feedforward 1) with a slow
    /// integral correction of the stroke, shunt open.
    pub fn piezo() -> Self {
        Self {
            moving_mass: 2.0,
            drive: Drive::Piezo {
                stiffness: PIEZO_STIFFNESS,
                damping_ratio: 0.01,
                shunt: None,
            },
            servo: ServoParams {
                rate: 5000.0,
                kp: 0.0,
                ki: PIEZO_INTEGRAL_GAIN,
                kd: 0.0,
                derivative_cutoff: 800.0,
                integrator_leak: 0.0,
                setpoint_weight: 1.0,
                feedforward: 1.0,
            },
        }
    }

    /// The hard actuator with its LR shunt connected.
    pub fn piezo_damped() -> Self {
        let mut a = Self::piezo();
        if let Drive::Piezo { shunt, .. } = &mut a.drive {
            *shunt = Some(Shunt::default());
        }
        a
    }
}
