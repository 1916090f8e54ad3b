//! A segment with its actuators ([`SegmentModel`]): the presets, the parameter ranges, the
//! mechanics of the chain (channel masses, support and whiffletree stiffness, locked modes,
//! static stiffness) and the continuous-time model of one channel ([`ChannelPlant`]).

use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};
use std::f64::consts::TAU;

use super::params::{ActuatorParams, Drive, SegmentParams};
use super::{Channel, N_CONT, N_IN, state};
use crate::M1Error;

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
        self.validate_segment()?;
        self.validate_actuator()?;
        self.validate_servo()?;
        self.validate_stability()
    }

    /// The ranges of the segment and its support.
    fn validate_segment(&self) -> Result<(), M1Error> {
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
        Ok(())
    }

    /// The ranges of the actuator and its drive.
    fn validate_actuator(&self) -> Result<(), M1Error> {
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
        Ok(())
    }

    /// The ranges of the servo.
    fn validate_servo(&self) -> Result<(), M1Error> {
        let v = &self.actuator.servo;
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
        Ok(())
    }

    /// The servo loop of each channel on a rigid base is stable (one-tick spectral radius
    /// below 1).
    fn validate_stability(&self) -> Result<(), M1Error> {
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
}
