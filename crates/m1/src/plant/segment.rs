//! Segment assemblies on their three position actuators, with the local encoder servo.
//!
//! # Model
//!
//! Each segment is a rigid mirror carried by three identical actuators at radius $r_a$, 120
//! degrees apart, through the segment support module: a moving frame with its whiffletrees
//! (mass $m_w$ in total, taken as concentrated at the three actuator points) on which the glass
//! rests through its support flexures. The carried mass $m$ (inertia $I$ about any in-plane
//! diameter) is the glass and the support module together; the glass alone has $m - m_w$ and
//! $I - m_w r_a^2 / 2$. Only out-of-plane motion is modelled. Each actuator chain, from the
//! mirror cell to the mirror, is
//!
//! ```text
//!   cell z_c ──[actuator: drive]── node x_a (m_a) ──[k_w, c_w]── whiffletree x_w (m_w/3) ──[k_s, c_s]── mirror x_g
//! ```
//!
//! where `x_g` is the mirror's displacement normal to the segment at the actuator point (the
//! output `z`). Because the actuators are identical and the mass matrix of a rigid segment is
//! diagonalised by the orthonormal actuator-space basis
//! $V = [\mathbf 1/\sqrt3,\ \cos\theta_k/\sqrt{3/2},\ \sin\theta_k/\sqrt{3/2}]$,
//! every segment splits **exactly** into three independent single-input channels: one *piston*
//! channel with effective glass mass $m_p = (m - m_w)/3$ and two identical *tilt* channels with
//! $m_t = (I - m_w r_a^2/2)/(1.5\,r_a^2)$, each with the whiffletree mass $m_w/3$. All 3N
//! channels of a mirror are then stepped together as a structure of arrays with one shared pair
//! of matrices per channel kind.
//!
//! The glass's support stiffness of each channel is set from its mode with the whiffletree
//! clamped, $k_{s} = m_{p,t}(2\pi f_{p,t})^2$ (90 Hz tilt, 120 Hz piston), damping
//! $c_s = 2\zeta_s\sqrt{k_s m_{p,t}}$. The whiffletree's stiffness $k_w$ (the same element in
//! every channel) is solved so that the lowest mode of the tilt channel with the actuator node
//! clamped (the whole assembly rocking on the whiffletrees) is `whiffletree_frequency` (40 Hz)
//! exactly; $c_w = 2\zeta_s\sqrt{k_w (m_w/3 + m_t)}$. The modes of the whole locked assembly
//! are [`SegmentModel::locked_modes`].
//!
//! Actuator variants (force $F$ on the node, positive along +z; $s = x_a - z_c$ is the stroke
//! the encoder measures):
//! - **voice coil** (soft): $F = -k_{off}\,s - c_{off}\,\dot x_a + u$, with $u$ the coil force
//!   commanded by the servo; $k_{off}$ is the soft offload spring.
//! - **piezo** (hard): $F = -K_D\,(s - \delta - e) - c_{pz}\,\dot x_a$ with $\delta = u$ the
//!   commanded free extension and $e$ the electrical coordinate of an optional resonant LR shunt:
//!   $\ddot e + 2\zeta_e\omega_e\dot e + \omega_e^2 e = \kappa^2\omega_e^2 (s - \delta)$. With the
//!   shunt open $e \equiv 0$ and the stiffness is the open-circuit $K_D$; at DC a shunted stack
//!   has the short-circuit stiffness $K_D(1-\kappa^2)$.
//!
//! The reaction on the cell (output `f_cell`, force of the actuator on the cell) is $-F$.
//! Dampers act on the node's velocity: within a communication step the cell displacement is held
//! (zero-order hold), so its velocity is zero there.
//!
//! # Servo
//!
//! A discrete PID on the encoder stroke at rate $f_s$ (default 5 kHz, period $T_s$):
//! error $\epsilon_k = u_{cmd} - s_k$, leaky integrator $I_{k+1} = a_i I_k + T_s\epsilon_k$
//! ($a_i = e^{-2\pi f_{leak} T_s}$; $f_{leak} = 0$ is a pure integrator), derivative on the
//! measurement through a first-order filter $D_{k} = a_d D_{k-1} - (1-a_d)(s_k - s_{k-1})/T_s$,
//! output $u_k = k_{ff} u_{cmd} + k_p(b\,u_{cmd} - s_k) + k_i I_{k+1} + k_d D_k$ (setpoint weight
//! $b$, command feedforward $k_{ff}$: 1 for the piezo, whose free extension is the command, so
//! the slow integrator only corrects the load's compression), applied by zero-order hold over
//! $[t_k, t_{k+1})$. The leak gives the servo a finite static gain
//! $C_0 = k_p + k_i T_s / (1 - a_i)$ and so a finite, analytic static stiffness.
//!
//! # Exact discretisation
//!
//! The continuous part is discretised by the matrix exponential (zero-order hold); together with
//! the servo it forms one linear map per servo tick $X_{k+1} = \Phi X_k + \Gamma w$ with the held
//! inputs $w = (u_{cmd}, z_c, f_{wind})$. A communication step of $M$ ticks applies
//! $X_M = \Phi^M X_0 + (\sum_{i<M}\Phi^i)\Gamma w$, computed once per step size: the result is
//! the 5 kHz sub-stepped trajectory, independent of the communication step. A communication
//! point between two servo samples splits the period: the plant runs on with the drive held
//! (exact partial-period maps), and the servo samples at its own instants, so any sequence of
//! steps gives the trajectory of one long step with the same held inputs.

use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};
use std::f64::consts::{PI, TAU};

use crate::M1Error;
use crate::linalg::kernels::axpy;

/// Continuous states per channel: node position and velocity, mirror position and velocity,
/// shunt coordinate and its rate, whiffletree position and velocity.
pub const N_CONT: usize = 8;
/// States per channel of the sampled closed loop: the continuous states, then the integrator,
/// the previous stroke, the derivative filter and the last servo output.
pub const N_STATE: usize = 12;
/// Held inputs per channel: commanded position, cell displacement, wind force.
pub const N_IN: usize = 3;

/// Open-circuit stiffness of the hard actuator's piezo stack (N/m): 4.3 N/um, which puts the
/// segment's piston mode on its stacks (rigid base, in series with the whiffletree and the
/// flexures) at 30.9 Hz and, on the `tmt` cell, the coupled piston modes of the 492 segments
/// at 29.2-29.8 Hz, on the 29.6 Hz motor tones (tip/tilt: 23.8 Hz rigid base).
/// *Calibrated* to the seed paper's Figure 13 (the hard actuator responds more than 2.5x the
/// soft one near 29.5 Hz); the published actuators are not specified further. "Hard" is
/// relative to the support: the stack is a third of the whiffletree's stiffness and 200 times
/// the voice coil's offload spring.
pub const PIEZO_STIFFNESS: f64 = 4.3e6;
/// Integral gain of the hard actuator's stroke servo (1/s): a 0.25 Hz correction of the
/// stacks' compression under load, slow enough for the lightly damped 30 Hz mode (the drive
/// follows the command by feedforward).
pub const PIEZO_INTEGRAL_GAIN: f64 = TAU * 0.25;
/// Electrical resonance of the hard actuator's LR shunt (Hz), tuned to the segments' coupled
/// piston modes on the stacks (*calibrated*: the largest undamped/damped ratio in
/// 29.4-29.8 Hz on the `tmt` cell).
pub const SHUNT_FREQUENCY: f64 = 29.4;

/// Index of each state in a channel's state vector.
pub mod state {
    /// Actuator node position (m).
    pub const NODE_POS: usize = 0;
    /// Actuator node velocity (m/s).
    pub const NODE_VEL: usize = 1;
    /// Mirror displacement at the actuator point (m).
    pub const MIRROR_POS: usize = 2;
    /// Mirror velocity at the actuator point (m/s).
    pub const MIRROR_VEL: usize = 3;
    /// Shunt electrical coordinate (m).
    pub const SHUNT: usize = 4;
    /// Shunt electrical coordinate rate (m/s).
    pub const SHUNT_RATE: usize = 5;
    /// Whiffletree (moving frame) position at the actuator point (m).
    pub const WHIFFLE_POS: usize = 6;
    /// Whiffletree velocity (m/s).
    pub const WHIFFLE_VEL: usize = 7;
    /// Servo integrator (m s).
    pub const INTEGRATOR: usize = 8;
    /// Stroke at the previous servo sample (m).
    pub const PREV_STROKE: usize = 9;
    /// Filtered derivative of the stroke (m/s).
    pub const DERIVATIVE: usize = 10;
    /// Servo output applied over the last servo period (N or m).
    pub const DRIVE: usize = 11;
}

/// The closed-loop map of one servo tick.
pub type Phi = SMatrix<f64, N_STATE, N_STATE>;
/// The input map of one servo tick.
pub type Gamma = SMatrix<f64, N_STATE, N_IN>;

/// The two kinds of independent channel of a segment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Channel {
    /// Uniform motion of the three actuators (effective mirror mass m/3).
    Piston,
    /// Either of the two tilt patterns (effective mirror mass I / (1.5 r_a^2)).
    Tilt,
}

impl Channel {
    /// Both channel kinds.
    pub const ALL: [Channel; 2] = [Channel::Piston, Channel::Tilt];
    /// Lower-case name.
    pub fn name(self) -> &'static str {
        match self {
            Channel::Piston => "piston",
            Channel::Tilt => "tilt",
        }
    }
}

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

/// A segment with its actuators: everything needed to build the channel dynamics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentModel {
    /// The segment and support.
    pub segment: SegmentParams,
    /// The actuator and servo.
    pub actuator: ActuatorParams,
}

/// Continuous-time state-space model of one channel: $\dot x = A x + B [u, z_c, f_w]$,
/// $f_{cell} = C_f x + D_f [u, z_c, f_w]$.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelPlant {
    /// State matrix.
    pub a: SMatrix<f64, N_CONT, N_CONT>,
    /// Input matrix for (drive u, cell displacement z_c, wind force f_w).
    pub b: SMatrix<f64, N_CONT, N_IN>,
    /// Output row of the force on the cell.
    pub cf: SMatrix<f64, 1, N_CONT>,
    /// Feedthrough of (u, z_c, f_w) into the force on the cell.
    pub df: SMatrix<f64, 1, N_IN>,
}

fn check(name: &'static str, value: f64, ok: bool, reason: &'static str) -> Result<(), M1Error> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(M1Error::InvalidParameter {
            name,
            value,
            reason,
        })
    }
}

impl SegmentModel {
    /// The baseline: default segment on voice-coil actuators.
    pub fn voice_coil() -> Self {
        Self {
            segment: SegmentParams::default(),
            actuator: ActuatorParams::voice_coil(),
        }
    }

    /// The voice-coil segment as first built, before issue 14: no whiffletree in the chain
    /// (`support_mass` 0) and a setpoint weight of 0.4. The `soft-cell` preset's regression
    /// figures (peak servo sensitivity 3.6, global loop gain 1.63) are this model's; kept for
    /// that comparison, not as a design.
    pub fn voice_coil_without_whiffletree() -> Self {
        let mut m = Self::voice_coil();
        m.segment.support_mass = 0.0;
        m.actuator.servo.setpoint_weight = 0.4;
        m
    }

    /// Default segment on hard piezo actuators with the LR shunt connected.
    pub fn piezo_damped_default() -> Self {
        Self {
            segment: SegmentParams::default(),
            actuator: ActuatorParams::piezo_damped(),
        }
    }

    /// Default segment on hard piezo actuators (shunt open).
    pub fn piezo() -> Self {
        Self {
            segment: SegmentParams::default(),
            actuator: ActuatorParams::piezo(),
        }
    }

    /// Checks every parameter's range; the error names the first one at fault.
    pub fn validate(&self) -> Result<(), M1Error> {
        let s = &self.segment;
        check("segment_mass", s.mass, s.mass > 0.0, "must be > 0")?;
        check("segment_inertia", s.inertia, s.inertia > 0.0, "must be > 0")?;
        check(
            "actuator_radius",
            s.actuator_radius,
            s.actuator_radius > 0.0,
            "must be > 0",
        )?;
        check(
            "support_mass",
            s.support_mass,
            s.support_mass >= 0.0 && s.support_mass < s.mass,
            "must be >= 0 and less than segment_mass",
        )?;
        check(
            "support_mass",
            s.support_mass,
            s.support_mass * s.actuator_radius * s.actuator_radius / 2.0 < s.inertia,
            "its inertia at the actuator radius, support_mass actuator_radius^2 / 2, must be \
             less than segment_inertia",
        )?;
        check(
            "whiffletree_frequency",
            s.whiffletree_frequency,
            s.support_mass == 0.0
                || (s.whiffletree_frequency > 0.0
                    && s.whiffletree_frequency < s.support_tilt_frequency),
            "must be > 0 and less than support_tilt_frequency",
        )?;
        check(
            "support_piston_frequency",
            s.support_piston_frequency,
            s.support_piston_frequency > 0.0,
            "must be > 0",
        )?;
        check(
            "support_tilt_frequency",
            s.support_tilt_frequency,
            s.support_tilt_frequency > 0.0,
            "must be > 0",
        )?;
        check(
            "support_damping_ratio",
            s.support_damping_ratio,
            s.support_damping_ratio >= 0.0,
            "must be >= 0",
        )?;
        let a = &self.actuator;
        check(
            "actuator_mass",
            a.moving_mass,
            a.moving_mass > 0.0,
            "must be > 0",
        )?;
        match &a.drive {
            Drive::VoiceCoil {
                spring_stiffness,
                spring_damping,
            } => {
                check(
                    "spring_stiffness",
                    *spring_stiffness,
                    *spring_stiffness >= 0.0,
                    "must be >= 0",
                )?;
                check(
                    "spring_damping",
                    *spring_damping,
                    *spring_damping >= 0.0,
                    "must be >= 0",
                )?;
            }
            Drive::Piezo {
                stiffness,
                damping_ratio,
                shunt,
            } => {
                check(
                    "piezo_stiffness",
                    *stiffness,
                    *stiffness > 0.0,
                    "must be > 0",
                )?;
                check(
                    "piezo_damping_ratio",
                    *damping_ratio,
                    *damping_ratio >= 0.0,
                    "must be >= 0",
                )?;
                if let Some(sh) = shunt {
                    check(
                        "shunt_coupling",
                        sh.coupling,
                        (0.0..1.0).contains(&sh.coupling),
                        "must be in [0, 1)",
                    )?;
                    check(
                        "shunt_frequency",
                        sh.frequency,
                        sh.frequency > 0.0,
                        "must be > 0",
                    )?;
                    check(
                        "shunt_damping_ratio",
                        sh.damping_ratio,
                        sh.damping_ratio >= 0.0,
                        "must be >= 0",
                    )?;
                }
            }
        }
        let v = &a.servo;
        check("servo_rate", v.rate, v.rate > 0.0, "must be > 0")?;
        check("servo_kp", v.kp, v.kp >= 0.0, "must be >= 0")?;
        check("servo_ki", v.ki, v.ki >= 0.0, "must be >= 0")?;
        check("servo_kd", v.kd, v.kd >= 0.0, "must be >= 0")?;
        check(
            "derivative_cutoff",
            v.derivative_cutoff,
            v.derivative_cutoff > 0.0,
            "must be > 0",
        )?;
        check(
            "setpoint_weight",
            v.setpoint_weight,
            (0.0..=1.0).contains(&v.setpoint_weight),
            "must be in [0, 1]",
        )?;
        check(
            "servo_feedforward",
            v.feedforward,
            v.feedforward >= 0.0,
            "must be >= 0",
        )?;
        check(
            "integrator_leak",
            v.integrator_leak,
            v.integrator_leak >= 0.0,
            "must be >= 0",
        )?;
        for ch in Channel::ALL {
            let rho = self.spectral_radius(ch);
            if rho.is_nan() || rho >= 1.0 {
                return Err(M1Error::Unstable {
                    channel: ch.name(),
                    spectral_radius: rho,
                    hint: "reduce the servo gains or raise the servo rate",
                });
            }
        }
        Ok(())
    }

    /// Effective glass mass of a channel (kg): (m - m_w)/3 for piston,
    /// (I - m_w r_a^2 / 2)/(1.5 r_a^2) for tilt.
    pub fn mirror_mass(&self, ch: Channel) -> f64 {
        let s = &self.segment;
        let r2 = s.actuator_radius * s.actuator_radius;
        match ch {
            Channel::Piston => (s.mass - s.support_mass) / 3.0,
            Channel::Tilt => (s.inertia - s.support_mass * r2 / 2.0) / (1.5 * r2),
        }
    }

    /// Whether the chain has a whiffletree (`support_mass` > 0).
    pub fn has_whiffletree(&self) -> bool {
        self.segment.support_mass > 0.0
    }

    /// Effective whiffletree mass of a channel (kg): m_w / 3 in every channel (concentrated
    /// at the actuator points).
    pub fn whiffletree_mass(&self) -> f64 {
        self.segment.support_mass / 3.0
    }

    /// Stiffness of the glass's flexures in a channel (N/m), from its mode with the whiffletree
    /// clamped.
    pub fn support_stiffness(&self, ch: Channel) -> f64 {
        let f = match ch {
            Channel::Piston => self.segment.support_piston_frequency,
            Channel::Tilt => self.segment.support_tilt_frequency,
        };
        self.mirror_mass(ch) * (TAU * f).powi(2)
    }

    /// Stiffness of the whiffletree between actuator node and moving frame, per actuator
    /// (N/m): the value that puts the lowest mode of the tilt channel with the node clamped at
    /// `whiffletree_frequency`. For the chain clamp -k1- m1 -k2- m2 an eigenvalue
    /// lambda < k2/m2 needs k1 = lambda m1 + k2 lambda m2 / (k2 - lambda m2).
    /// Infinite without a whiffletree (`support_mass` 0).
    pub fn whiffletree_stiffness(&self) -> f64 {
        if !self.has_whiffletree() {
            return f64::INFINITY;
        }
        let lam = (TAU * self.segment.whiffletree_frequency).powi(2);
        let (m1, m2) = (self.whiffletree_mass(), self.mirror_mass(Channel::Tilt));
        let k2 = self.support_stiffness(Channel::Tilt);
        lam * m1 + k2 * lam * m2 / (k2 - lam * m2)
    }

    /// Compliance of the support between actuator node and glass in a channel (m/N): the
    /// whiffletree and the flexures in series.
    pub fn support_compliance(&self, ch: Channel) -> f64 {
        1.0 / self.whiffletree_stiffness() + 1.0 / self.support_stiffness(ch)
    }

    /// The two modes of a channel's support with the actuator node clamped (Hz), lower first:
    /// the undamped eigenfrequencies of node -k_w- m_w -k_s- glass. Without a whiffletree the
    /// one mode is the glass on its flexures, and the second is infinite.
    pub fn locked_modes(&self, ch: Channel) -> [f64; 2] {
        if !self.has_whiffletree() {
            let f = (self.support_stiffness(ch) / self.mirror_mass(ch)).sqrt() / TAU;
            return [f, f64::INFINITY];
        }
        let (k1, k2) = (self.whiffletree_stiffness(), self.support_stiffness(ch));
        let (m1, m2) = (self.whiffletree_mass(), self.mirror_mass(ch));
        let sum = (k1 + k2) / m1 + k2 / m2;
        let prod = k1 * k2 / (m1 * m2);
        let d = (sum * sum - 4.0 * prod).max(0.0).sqrt();
        [(sum - d) / 2.0, (sum + d) / 2.0].map(|l| l.sqrt() / TAU)
    }

    /// Static gain of the discrete servo, u / error at DC (infinite for a pure integrator with
    /// nonzero integral gain).
    pub fn servo_dc_gain(&self) -> f64 {
        let v = &self.actuator.servo;
        let ts = 1.0 / v.rate;
        let ai = (-TAU * v.integrator_leak * ts).exp();
        if v.ki == 0.0 {
            v.kp
        } else if ai >= 1.0 {
            f64::INFINITY
        } else {
            v.kp + v.ki * ts / (1.0 - ai)
        }
    }

    /// Static stiffness of the servoed actuator between cell and node (N/m).
    pub fn actuator_static_stiffness(&self) -> f64 {
        let c0 = self.servo_dc_gain();
        match &self.actuator.drive {
            Drive::VoiceCoil {
                spring_stiffness, ..
            } => spring_stiffness + c0,
            Drive::Piezo {
                stiffness, shunt, ..
            } => {
                let k2 = shunt.as_ref().map_or(0.0, |s| s.coupling * s.coupling);
                stiffness * (1.0 - k2) * (1.0 + c0)
            }
        }
    }

    /// Static stiffness at the mirror, per actuator, for a channel's load pattern (N/m): the
    /// servoed actuator in series with the whiffletree and the flexures.
    pub fn static_stiffness(&self, ch: Channel) -> f64 {
        let ka = self.actuator_static_stiffness();
        1.0 / (self.support_compliance(ch) + 1.0 / ka)
    }

    /// The continuous-time model of one channel.
    pub fn plant(&self, ch: Channel) -> ChannelPlant {
        use state::*;
        let ma = self.actuator.moving_mass;
        let mg = self.mirror_mass(ch);
        let mw = self.whiffletree_mass();
        let ks = self.support_stiffness(ch);
        let zeta = self.segment.support_damping_ratio;
        let cs = 2.0 * zeta * (ks * mg).sqrt();
        let kw = self.whiffletree_stiffness();
        let cw = 2.0 * zeta * (kw * (mw + self.mirror_mass(Channel::Tilt))).sqrt();
        let mut a = SMatrix::<f64, N_CONT, N_CONT>::zeros();
        let mut b = SMatrix::<f64, N_CONT, N_IN>::zeros();
        let mut cf = SMatrix::<f64, 1, N_CONT>::zeros();
        let mut df = SMatrix::<f64, 1, N_IN>::zeros();
        let masses = |i: usize| match i {
            NODE_POS => ma,
            WHIFFLE_POS => mw,
            _ => mg,
        };
        // A spring-damper (k, c) between the positions i and j (velocities at i + 1, j + 1).
        let mut link = |i: usize, j: usize, k: f64, c: f64| {
            for (p, q) in [(i, j), (j, i)] {
                let m = masses(p);
                a[(p + 1, p)] -= k / m;
                a[(p + 1, q)] += k / m;
                a[(p + 1, p + 1)] -= c / m;
                a[(p + 1, q + 1)] += c / m;
            }
        };
        if self.has_whiffletree() {
            link(NODE_POS, WHIFFLE_POS, kw, cw);
            link(WHIFFLE_POS, MIRROR_POS, ks, cs);
            a[(WHIFFLE_POS, WHIFFLE_VEL)] = 1.0;
        } else {
            // The whiffletree states stay at rest, outside the chain (a decay of 1 ms keeps
            // them out of the closed loop's unit circle).
            link(NODE_POS, MIRROR_POS, ks, cs);
            a[(WHIFFLE_POS, WHIFFLE_POS)] = -1e3;
            a[(WHIFFLE_VEL, WHIFFLE_VEL)] = -1e3;
        }
        a[(NODE_POS, NODE_VEL)] = 1.0;
        a[(MIRROR_POS, MIRROR_VEL)] = 1.0;
        b[(MIRROR_VEL, 2)] = 1.0 / mg;
        // Actuator force on the node, F = fx . x + fw . w; the cell receives -F.
        let mut fx = SMatrix::<f64, 1, N_CONT>::zeros();
        let mut fw = SMatrix::<f64, 1, N_IN>::zeros();
        match &self.actuator.drive {
            Drive::VoiceCoil {
                spring_stiffness: k,
                spring_damping: c,
            } => {
                fx[NODE_POS] = -k;
                fx[NODE_VEL] = -c;
                fw[0] = 1.0;
                fw[1] = *k;
            }
            Drive::Piezo {
                stiffness: kd,
                damping_ratio,
                shunt,
            } => {
                // F = -K_D (x_a - z_c - u - e) - c x_a'
                fx[NODE_POS] = -kd;
                // Damping defined on the segment's piston mode on the stack (the carried
                // mass per actuator), not on the light node.
                let carried = ma + self.segment.mass / 3.0;
                fx[NODE_VEL] = -2.0 * damping_ratio * (kd * carried).sqrt();
                fw[0] = *kd;
                fw[1] = *kd;
                if let Some(sh) = shunt {
                    a[(SHUNT, SHUNT_RATE)] = 1.0;
                    fx[SHUNT] = *kd;
                    let we = TAU * sh.frequency;
                    let g = sh.coupling * sh.coupling * we * we;
                    a[(SHUNT_RATE, SHUNT)] = -we * we;
                    a[(SHUNT_RATE, SHUNT_RATE)] = -2.0 * sh.damping_ratio * we;
                    a[(SHUNT_RATE, NODE_POS)] = g;
                    b[(SHUNT_RATE, 0)] = -g;
                    b[(SHUNT_RATE, 1)] = -g;
                }
            }
        }
        for j in 0..N_CONT {
            a[(NODE_VEL, j)] += fx[j] / ma;
            cf[j] = -fx[j];
        }
        for j in 0..N_IN {
            b[(NODE_VEL, j)] += fw[j] / ma;
            df[j] = -fw[j];
        }
        ChannelPlant { a, b, cf, df }
    }

    /// The servo period (s).
    pub fn servo_period(&self) -> f64 {
        1.0 / self.actuator.servo.rate
    }

    /// Zero-order-hold discretisation of a channel's continuous part over `d` seconds:
    /// $\exp\left(\begin{bmatrix}A & B\\ 0 & 0\end{bmatrix} d\right) =
    /// \begin{bmatrix}A_d & B_d\\ 0 & I\end{bmatrix}$.
    pub fn zoh(
        &self,
        ch: Channel,
        d: f64,
    ) -> (SMatrix<f64, N_CONT, N_CONT>, SMatrix<f64, N_CONT, N_IN>) {
        let p = self.plant(ch);
        let mut m = SMatrix::<f64, { N_CONT + N_IN }, { N_CONT + N_IN }>::zeros();
        m.fixed_view_mut::<N_CONT, N_CONT>(0, 0)
            .copy_from(&(p.a * d));
        m.fixed_view_mut::<N_CONT, N_IN>(0, N_CONT)
            .copy_from(&(p.b * d));
        let e = m.exp();
        (
            e.fixed_view::<N_CONT, N_CONT>(0, 0).into_owned(),
            e.fixed_view::<N_CONT, N_IN>(0, N_CONT).into_owned(),
        )
    }

    /// The plant alone over `d` seconds with the drive held (no servo sample): used to finish
    /// or start a servo period cut by a communication point.
    pub fn plant_only(&self, ch: Channel, d: f64) -> (Phi, Gamma) {
        let (ad, bd) = self.zoh(ch, d);
        let mut phi = Phi::identity();
        let mut gam = Gamma::zeros();
        for i in 0..N_CONT {
            for j in 0..N_CONT {
                phi[(i, j)] = ad[(i, j)];
            }
            phi[(i, state::DRIVE)] = bd[(i, 0)];
            gam[(i, 1)] = bd[(i, 1)];
            gam[(i, 2)] = bd[(i, 2)];
        }
        (phi, gam)
    }

    /// One servo tick of the sampled closed loop of a channel: $X_{k+1} = \Phi X_k + \Gamma w$.
    pub fn closed_loop(&self, ch: Channel) -> (Phi, Gamma) {
        self.closed_loop_over(ch, self.servo_period())
    }

    /// A servo sample followed by `d` seconds of the plant with the new drive held
    /// (`d` = the servo period for a whole tick).
    pub fn closed_loop_over(&self, ch: Channel, d: f64) -> (Phi, Gamma) {
        use state::*;
        let v = &self.actuator.servo;
        let ts = self.servo_period();
        let (ad, bd) = self.zoh(ch, d);

        let ai = (-TAU * v.integrator_leak * ts).exp();
        let a_d = (-TAU * v.derivative_cutoff * ts).exp();
        let c1 = (1.0 - a_d) / ts;
        let mut phi = Phi::zeros();
        let mut gam = Gamma::zeros();
        // Integrator: I' = a_i I + Ts (u_cmd - x_a + z_c).
        phi[(INTEGRATOR, INTEGRATOR)] = ai;
        phi[(INTEGRATOR, NODE_POS)] = -ts;
        gam[(INTEGRATOR, 0)] = ts;
        gam[(INTEGRATOR, 1)] = ts;
        // Previous stroke: s' = x_a - z_c.
        phi[(PREV_STROKE, NODE_POS)] = 1.0;
        gam[(PREV_STROKE, 1)] = -1.0;
        // Derivative on the measurement: D' = a_d D - c1 (x_a - z_c - s_prev).
        phi[(DERIVATIVE, DERIVATIVE)] = a_d;
        phi[(DERIVATIVE, NODE_POS)] = -c1;
        phi[(DERIVATIVE, PREV_STROKE)] = c1;
        gam[(DERIVATIVE, 1)] = c1;
        // Output u = kp (u_cmd - x_a + z_c) + ki I' + kd D'.
        let mut ux = SMatrix::<f64, 1, N_STATE>::zeros();
        let mut uw = SMatrix::<f64, 1, N_IN>::zeros();
        for j in 0..N_STATE {
            ux[j] = v.ki * phi[(INTEGRATOR, j)] + v.kd * phi[(DERIVATIVE, j)];
        }
        for j in 0..N_IN {
            uw[j] = v.ki * gam[(INTEGRATOR, j)] + v.kd * gam[(DERIVATIVE, j)];
        }
        ux[NODE_POS] -= v.kp;
        uw[0] += v.setpoint_weight * v.kp + v.feedforward;
        uw[1] += v.kp;
        for j in 0..N_STATE {
            phi[(DRIVE, j)] = ux[j];
        }
        for j in 0..N_IN {
            gam[(DRIVE, j)] = uw[j];
        }
        // Plant over the tick with u held: x' = Ad x + Bd0 u + Bd1 z_c + Bd2 f_w.
        for i in 0..N_CONT {
            for j in 0..N_CONT {
                phi[(i, j)] += ad[(i, j)];
            }
            for j in 0..N_STATE {
                phi[(i, j)] += bd[(i, 0)] * ux[j];
            }
            for j in 0..N_IN {
                gam[(i, j)] += bd[(i, 0)] * uw[j];
            }
            gam[(i, 1)] += bd[(i, 1)];
            gam[(i, 2)] += bd[(i, 2)];
        }
        (phi, gam)
    }

    /// Whether the shunt states take part in the dynamics (they stay zero otherwise).
    pub fn has_shunt(&self) -> bool {
        matches!(self.actuator.drive, Drive::Piezo { shunt: Some(_), .. })
    }

    /// Largest eigenvalue modulus of a channel's one-tick closed-loop map, over the states that
    /// take part in the dynamics (without a shunt its two states are inert zeros).
    pub fn spectral_radius(&self, ch: Channel) -> f64 {
        let (phi, _) = self.closed_loop(ch);
        let active: Vec<usize> = (0..N_STATE)
            .filter(|&i| self.has_shunt() || !(i == state::SHUNT || i == state::SHUNT_RATE))
            .collect();
        let sub = nalgebra::DMatrix::from_fn(active.len(), active.len(), |i, j| {
            phi[(active[i], active[j])]
        });
        sub.complex_eigenvalues()
            .iter()
            .map(|l| l.norm())
            .fold(0.0, f64::max)
    }

    /// Output row of the force on the cell from the tick state and held inputs:
    /// $f_{cell} = C X + D w$ (the drive is the one applied over the last servo period).
    pub fn cell_force_map(&self, ch: Channel) -> (SMatrix<f64, 1, N_STATE>, SMatrix<f64, 1, N_IN>) {
        let p = self.plant(ch);
        let mut c = SMatrix::<f64, 1, N_STATE>::zeros();
        for j in 0..N_CONT {
            c[j] = p.cf[j];
        }
        c[state::DRIVE] = p.df[0];
        let mut d = SMatrix::<f64, 1, N_IN>::zeros();
        d[1] = p.df[1];
        d[2] = p.df[2];
        (c, d)
    }

    /// Frequency response of a channel's sampled closed loop from the held inputs
    /// (u_cmd, z_c, f_w) to the mirror displacement, at frequency `f` (Hz):
    /// $H(z) = e_{mirror}^T (zI - \Phi)^{-1}\Gamma$, $z = e^{j 2\pi f T_s}$.
    pub fn mirror_response(&self, ch: Channel, f: f64) -> [nalgebra::Complex<f64>; N_IN] {
        use nalgebra::Complex;
        let (phi, gam) = self.closed_loop(ch);
        let z = Complex::from_polar(1.0, TAU * f * self.servo_period());
        let m: SMatrix<Complex<f64>, N_STATE, N_STATE> =
            SMatrix::<Complex<f64>, N_STATE, N_STATE>::identity() * z
                - phi.map(|x| Complex::new(x, 0.0));
        let g = gam.map(|x| Complex::new(x, 0.0));
        let mut out = [Complex::new(0.0, 0.0); N_IN];
        if let Some(sol) = m.lu().solve(&g) {
            for (j, o) in out.iter_mut().enumerate() {
                *o = sol[(state::MIRROR_POS, j)];
            }
        }
        out
    }
}

/// $(\Phi^M, \sum_{i<M}\Phi^i\Gamma)$: the exact map of M servo ticks with held inputs, by binary
/// powering (no heap allocation).
pub fn propagate(phi: &Phi, gam: &Gamma, ticks: u64) -> (Phi, Gamma) {
    // (P, S) represents X -> P X + S w. Composition "b then a": (Pa Pb, Pa Sb + Sa).
    let mut acc_p = Phi::identity();
    let mut acc_s = Gamma::zeros();
    let mut base_p = *phi;
    let mut base_s = *gam;
    let mut n = ticks;
    while n > 0 {
        if n & 1 == 1 {
            acc_s = base_p * acc_s + base_s;
            acc_p = base_p * acc_p;
        }
        n >>= 1;
        if n > 0 {
            base_s = base_p * base_s + base_s;
            base_p = base_p * base_p;
        }
    }
    (acc_p, acc_s)
}

/// Orthonormal actuator-space basis of a segment: columns piston, tilt 1, tilt 2.
pub fn modal_basis() -> SMatrix<f64, 3, 3> {
    let c = (2.0f64 / 3.0).sqrt();
    let p = 1.0 / 3.0f64.sqrt();
    let mut v = SMatrix::<f64, 3, 3>::zeros();
    for k in 0..3 {
        let th = 2.0 * PI * k as f64 / 3.0;
        v[(k, 0)] = p;
        v[(k, 1)] = c * th.cos();
        v[(k, 2)] = c * th.sin();
    }
    v
}

/// Propagators of both channel kinds for one step size.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct StepMaps {
    ticks: u64,
    p: [Phi; 2],
    s: [Gamma; 2],
}

/// All segments of a mirror, stepped together.
///
/// Arrays in and out are in actuator order, segment-major: actuator k of segment i at 3 i + k.
/// Internally the 3N channels are stored by state (structure of arrays): piston channels of all
/// segments, then tilt channels (two per segment).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SegmentArray {
    n_segments: usize,
    model: SegmentModel,
    tick: [Phi; 2],
    tick_in: [Gamma; 2],
    cell_c: [SMatrix<f64, 1, N_STATE>; 2],
    cell_d: [SMatrix<f64, 1, N_IN>; 2],
    basis: SMatrix<f64, 3, 3>,
    maps: StepMaps,
    /// Time since the last servo sample (s), in [0, servo period).
    phase: f64,
    /// State by kind: `x[kind][s * n + c]` for state s of channel c.
    x: [Vec<f64>; 2],
    /// Scratch for the next state.
    next: [Vec<f64>; 2],
    /// Modal inputs by kind: `w[kind][l * n + c]`.
    w: [Vec<f64>; 2],
}

impl SegmentArray {
    /// A mirror of `n_segments` identical segments, at rest.
    pub fn new(n_segments: usize, model: SegmentModel) -> Result<Self, M1Error> {
        model.validate()?;
        let (pp, gp) = model.closed_loop(Channel::Piston);
        let (pt, gt) = model.closed_loop(Channel::Tilt);
        let (cp, dp) = model.cell_force_map(Channel::Piston);
        let (ct, dt) = model.cell_force_map(Channel::Tilt);
        let counts = [n_segments, 2 * n_segments];
        Ok(Self {
            n_segments,
            tick: [pp, pt],
            tick_in: [gp, gt],
            cell_c: [cp, ct],
            cell_d: [dp, dt],
            basis: modal_basis(),
            maps: StepMaps {
                ticks: 1,
                p: [pp, pt],
                s: [gp, gt],
            },
            phase: 0.0,
            x: counts.map(|n| vec![0.0; N_STATE * n]),
            next: counts.map(|n| vec![0.0; N_STATE * n]),
            w: counts.map(|n| vec![0.0; N_IN * n]),
            model,
        })
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// Number of actuators (3 per segment).
    pub fn n_actuators(&self) -> usize {
        3 * self.n_segments
    }

    /// The model parameters.
    pub fn model(&self) -> &SegmentModel {
        &self.model
    }

    /// Back to rest.
    pub fn reset(&mut self) {
        for x in &mut self.x {
            x.fill(0.0);
        }
        self.phase = 0.0;
    }

    fn check_len(what: &'static str, v: &[f64], n: usize) -> Result<(), M1Error> {
        if v.len() == n {
            Ok(())
        } else {
            Err(M1Error::SizeMismatch {
                what,
                expected: n,
                found: v.len(),
            })
        }
    }

    /// Advances `ticks` servo periods with the inputs held (actuator order, lengths 3N).
    pub fn step(
        &mut self,
        ticks: u64,
        u_cmd: &[f64],
        z_cell: &[f64],
        f_wind: &[f64],
    ) -> Result<(), M1Error> {
        let h = ticks as f64 * self.model.servo_period();
        self.advance(h, u_cmd, z_cell, f_wind)
    }

    /// Advances `h` seconds with the inputs held (actuator order, lengths 3N). The servo samples
    /// at its own instants, multiples of its period from the start: a step that ends between two
    /// samples carries the drive over into the next step, so any sequence of steps gives the
    /// trajectory of one long step with the same held inputs.
    pub fn advance(
        &mut self,
        h: f64,
        u_cmd: &[f64],
        z_cell: &[f64],
        f_wind: &[f64],
    ) -> Result<(), M1Error> {
        let na = self.n_actuators();
        Self::check_len("u_cmd", u_cmd, na)?;
        Self::check_len("z_cell", z_cell, na)?;
        Self::check_len("f_wind", f_wind, na)?;
        if !(h.is_finite() && h >= 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "communicationStepSize",
                value: h,
                reason: "must be finite and >= 0",
            });
        }
        self.load_inputs(u_cmd, z_cell, f_wind);
        let ts = self.model.servo_period();
        // Sample instants closer than this are the same instant (rounding of step sums).
        let eps = 1e-9 * ts;
        let mut rest = h;
        if self.phase > 0.0 {
            // Finish the servo period under way: plant only, drive held.
            let d = (ts - self.phase).min(rest);
            if d > eps {
                let maps = Channel::ALL.map(|ch| self.model.plant_only(ch, d));
                self.apply(&maps);
            }
            self.phase += d;
            rest -= d;
            if ts - self.phase > eps {
                return Ok(());
            }
            self.phase = 0.0;
        }
        let ticks = ((rest + eps) / ts).floor();
        if ticks >= 1.0 {
            let ticks = ticks as u64;
            if self.maps.ticks != ticks {
                let (p0, s0) = propagate(&self.tick[0], &self.tick_in[0], ticks);
                let (p1, s1) = propagate(&self.tick[1], &self.tick_in[1], ticks);
                self.maps = StepMaps {
                    ticks,
                    p: [p0, p1],
                    s: [s0, s1],
                };
            }
            let maps = [
                (self.maps.p[0], self.maps.s[0]),
                (self.maps.p[1], self.maps.s[1]),
            ];
            self.apply(&maps);
            rest -= ticks as f64 * ts;
        }
        if rest > eps {
            // A servo sample, then part of its period.
            let maps = Channel::ALL.map(|ch| self.model.closed_loop_over(ch, rest));
            self.apply(&maps);
            self.phase = rest;
        }
        Ok(())
    }

    /// Applies one linear map per channel kind to every channel: X <- P X + S w.
    fn apply(&mut self, maps: &[(Phi, Gamma); 2]) {
        for (k, (p, s)) in maps.iter().enumerate() {
            let n = self.x[k].len() / N_STATE;
            let x = &self.x[k];
            let w = &self.w[k];
            let next = &mut self.next[k];
            for i in 0..N_STATE {
                let out = &mut next[i * n..(i + 1) * n];
                out.fill(0.0);
                for j in 0..N_STATE {
                    let a = p[(i, j)];
                    if a != 0.0 {
                        axpy(out, a, &x[j * n..(j + 1) * n]);
                    }
                }
                for l in 0..N_IN {
                    let a = s[(i, l)];
                    if a != 0.0 {
                        axpy(out, a, &w[l * n..(l + 1) * n]);
                    }
                }
            }
            std::mem::swap(&mut self.x[k], &mut self.next[k]);
        }
    }

    /// Projects actuator-space inputs onto the channels: q = V^T a per segment.
    fn load_inputs(&mut self, u_cmd: &[f64], z_cell: &[f64], f_wind: &[f64]) {
        let n = self.n_segments;
        let v = self.basis;
        let [wp, wt] = &mut self.w;
        for (l, input) in [u_cmd, z_cell, f_wind].into_iter().enumerate() {
            for (seg, a) in input.chunks_exact(3).enumerate() {
                wp[l * n + seg] = v[(0, 0)] * a[0] + v[(1, 0)] * a[1] + v[(2, 0)] * a[2];
                wt[l * 2 * n + 2 * seg] = v[(0, 1)] * a[0] + v[(1, 1)] * a[1] + v[(2, 1)] * a[2];
                wt[l * 2 * n + 2 * seg + 1] =
                    v[(0, 2)] * a[0] + v[(1, 2)] * a[1] + v[(2, 2)] * a[2];
            }
        }
    }

    /// The outputs at the current time: mirror displacement `z` and force on the cell `f_cell`
    /// at each actuator (lengths 3N), with the current cell displacement `z_cell`.
    pub fn outputs(
        &self,
        z_cell: &[f64],
        z: &mut [f64],
        f_cell: &mut [f64],
    ) -> Result<(), M1Error> {
        let na = self.n_actuators();
        Self::check_len("z_cell", z_cell, na)?;
        Self::check_len("z", z, na)?;
        Self::check_len("f_cell", f_cell, na)?;
        let n = self.n_segments;
        let v = self.basis;
        let mp = state::MIRROR_POS;
        for seg in 0..n {
            // Modal mirror displacement and cell force of the three channels of this segment.
            let idx = [
                (0usize, seg, n),
                (1, 2 * seg, 2 * n),
                (1, 2 * seg + 1, 2 * n),
            ];
            let zc = &z_cell[3 * seg..3 * seg + 3];
            let mut qz = [0.0; 3];
            let mut qf = [0.0; 3];
            for (m, &(k, c, nk)) in idx.iter().enumerate() {
                let x = &self.x[k];
                qz[m] = x[mp * nk + c];
                let cc = &self.cell_c[k];
                let mut f = 0.0;
                for s in 0..N_STATE {
                    f += cc[s] * x[s * nk + c];
                }
                qf[m] = f;
            }
            for a in 0..3 {
                z[3 * seg + a] = v[(a, 0)] * qz[0] + v[(a, 1)] * qz[1] + v[(a, 2)] * qz[2];
                f_cell[3 * seg + a] = v[(a, 0)] * qf[0] + v[(a, 1)] * qf[1] + v[(a, 2)] * qf[2];
            }
            // The cell-displacement feedthrough is the same for both kinds (actuator spring),
            // so it maps actuator by actuator.
            let d = self.cell_d[0][1];
            for a in 0..3 {
                f_cell[3 * seg + a] += d * zc[a];
            }
        }
        Ok(())
    }

    /// The inputs held over the last step in the piston/tilt channel basis, by kind: column-major
    /// `count x 3` (`u_cmd`, `z_cell`, `f_wind`; count = N piston or 2N tilt channels).
    pub(crate) fn channel_inputs(&self) -> [&[f64]; 2] {
        [&self.w[0], &self.w[1]]
    }

    /// The full state, by kind (piston, tilt), for checkpoints.
    pub fn state(&self) -> [&[f64]; 2] {
        [&self.x[0], &self.x[1]]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn max_abs(a: &[f64]) -> f64 {
        a.iter().fold(0.0, |m, x| m.max(x.abs()))
    }

    #[test]
    fn modal_basis_is_orthonormal() {
        let v = modal_basis();
        let e = v.transpose() * v - SMatrix::<f64, 3, 3>::identity();
        assert!(e.abs().max() < 1e-15);
    }

    #[test]
    fn default_variants_are_stable() {
        for m in [
            SegmentModel::voice_coil(),
            SegmentModel::piezo(),
            SegmentModel {
                segment: SegmentParams::default(),
                actuator: ActuatorParams::piezo_damped(),
            },
        ] {
            assert!(m.validate().is_ok(), "{m:?}");
        }
    }

    #[test]
    fn propagate_equals_repeated_ticks() {
        let m = SegmentModel::voice_coil();
        let (phi, gam) = m.closed_loop(Channel::Tilt);
        let (p7, s7) = propagate(&phi, &gam, 7);
        let mut p = Phi::identity();
        let mut s = Gamma::zeros();
        for _ in 0..7 {
            s = phi * s + gam;
            p = phi * p;
        }
        assert!((p7 - p).abs().max() < 1e-12 * p.abs().max());
        assert!((s7 - s).abs().max() < 1e-12 * s.abs().max());
    }

    #[test]
    fn clamped_support_modes_match_parameters() {
        // Mirror mass on the support spring alone (node clamped): omega^2 = k_s / m.
        let m = SegmentModel::voice_coil();
        for (ch, f) in [(Channel::Piston, 120.0), (Channel::Tilt, 90.0)] {
            let w2 = m.support_stiffness(ch) / m.mirror_mass(ch);
            assert!((w2.sqrt() / TAU - f).abs() < 1e-9);
        }
    }

    #[test]
    fn static_wind_load_is_transmitted_to_the_cell() {
        // At equilibrium the force on the cell equals the force on the mirror, and the mirror
        // moves by f / K_static.
        for model in [SegmentModel::voice_coil(), SegmentModel::piezo()] {
            let mut arr = SegmentArray::new(2, model.clone()).expect("valid");
            let f = [10.0, 10.0, 10.0, 0.0, 0.0, 0.0];
            let zero = [0.0; 6];
            arr.step(5000 * 20, &zero, &zero, &f).expect("step");
            let mut z = [0.0; 6];
            let mut fc = [0.0; 6];
            arr.outputs(&zero, &mut z, &mut fc).expect("outputs");
            let k = model.static_stiffness(Channel::Piston);
            for a in 0..3 {
                assert!((fc[a] - 10.0).abs() < 1e-6, "{fc:?}");
                assert!(
                    (z[a] * k / 10.0 - 1.0).abs() < 1e-6,
                    "{} vs {}",
                    z[a],
                    10.0 / k
                );
            }
            assert!(max_abs(&z[3..]) == 0.0);
        }
    }

    #[test]
    fn voice_coil_is_stiff_below_one_hertz() {
        // The published >= 10 N/um is the servoed actuator's: the mirror's compliance less the
        // support's in series with it (quasi-static below 1 Hz, 40 Hz and up).
        let m = SegmentModel::voice_coil();
        for ch in Channel::ALL {
            for f in [0.01, 0.1, 0.5, 1.0] {
                let c = m.mirror_response(ch, f)[2].norm() - m.support_compliance(ch);
                assert!(1.0 / c > 10e6, "{ch:?} {f} Hz: {} N/um", 1e-6 / c);
            }
        }
    }

    #[test]
    fn issue_14_whiffletree_puts_the_lowest_locked_mode_at_40_hz() {
        let m = SegmentModel::voice_coil();
        let t = m.locked_modes(Channel::Tilt);
        assert!((t[0] - 40.0).abs() < 1e-9, "{t:?}");
        let p = m.locked_modes(Channel::Piston);
        // The piston pair lies above, both upper modes above the clamped-whiffletree ones.
        assert!(p[0] > 40.0 && p[0] < 120.0, "{p:?}");
        assert!(t[1] > 90.0 && p[1] > 120.0, "{t:?} {p:?}");
        // The same from the state matrix: the clamped-node chain's eigenvalues.
        let a = m.plant(Channel::Tilt).a;
        let idx = [
            state::WHIFFLE_POS,
            state::WHIFFLE_VEL,
            state::MIRROR_POS,
            state::MIRROR_VEL,
        ];
        let sub = nalgebra::DMatrix::from_fn(4, 4, |i, j| a[(idx[i], idx[j])]);
        let mut f: Vec<f64> = sub
            .complex_eigenvalues()
            .iter()
            .filter(|l| l.im > 0.0)
            .map(|l| l.norm() / TAU)
            .collect();
        f.sort_by(f64::total_cmp);
        assert!((f[0] / 40.0 - 1.0).abs() < 1e-3, "{f:?}");
    }

    #[test]
    fn misaligned_steps_give_the_aligned_trajectory() {
        // Steps of 0.13 ms and 0.07 ms (servo period 0.2 ms) against whole ticks: both land on
        // t = 4 ms, where the states must agree.
        let model = SegmentModel::piezo_damped_default();
        let mut a = SegmentArray::new(2, model.clone()).expect("valid");
        let mut b = SegmentArray::new(2, model).expect("valid");
        let u = [1e-6, 0.0, -2e-7, 0.0, 3e-7, 0.0];
        let zc = [0.0, 1e-7, 0.0, 0.0, 0.0, -1e-7];
        let fw = [5.0, 0.0, 0.0, -3.0, 0.0, 1.0];
        a.step(20, &u, &zc, &fw).expect("step");
        for k in 0..40 {
            let h = if k % 2 == 0 { 0.13e-3 } else { 0.07e-3 };
            b.advance(h, &u, &zc, &fw).expect("advance");
        }
        assert!(b.phase.abs() < 1e-12, "{}", b.phase);
        for k in 0..2 {
            let d: Vec<f64> = a.x[k].iter().zip(&b.x[k]).map(|(x, y)| x - y).collect();
            assert!(max_abs(&d) <= 1e-9 * max_abs(&a.x[k]), "{}", max_abs(&d));
        }
    }

    #[test]
    fn step_size_does_not_change_the_trajectory() {
        let model = SegmentModel::voice_coil();
        let mut a = SegmentArray::new(3, model.clone()).expect("valid");
        let mut b = SegmentArray::new(3, model).expect("valid");
        let u: Vec<f64> = (0..9).map(|i| 1e-6 * (i as f64 - 4.0)).collect();
        let zc: Vec<f64> = (0..9).map(|i| 1e-7 * (i as f64).sin()).collect();
        let fw: Vec<f64> = (0..9).map(|i| (i as f64).cos()).collect();
        for _ in 0..50 {
            a.step(5, &u, &zc, &fw).expect("step");
            for _ in 0..5 {
                b.step(1, &u, &zc, &fw).expect("step");
            }
        }
        for k in 0..2 {
            let d: Vec<f64> = a.x[k].iter().zip(&b.x[k]).map(|(x, y)| x - y).collect();
            assert!(max_abs(&d) <= 1e-9 * max_abs(&a.x[k]));
        }
    }
}
