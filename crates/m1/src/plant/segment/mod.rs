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

mod array;
mod model;
mod params;
mod sampled;
#[cfg(test)]
mod tests;

pub use array::{MAX_PENDING_STEPS, SegmentArray};
pub use model::{ChannelPlant, SegmentModel};
pub use params::{ActuatorParams, Drive, SegmentParams, ServoParams, Shunt};
pub use sampled::propagate;

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
