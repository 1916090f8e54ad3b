//! The mirror as one linear model, assembled from the component equations without FMI: the
//! independent check of the co-simulation, and the engine of the frequency-domain studies
//! (control-structure interaction, vibration).
//!
//! # Frequency response ([`FrequencyModel`])
//!
//! Every segment channel (see [`crate::plant::segment`]: the piston channel and the two tilt channels
//! of a segment, in the orthonormal actuator basis `V`) is the same continuous plant
//! $\dot x = A x + b_u u + b_z z_c + b_w f_w$ under the same discrete servo. The structure is
//! modal: $D(\omega) q = \Phi_c^T f + b_p p$ with $D_j = \omega_j^2 - \omega^2 + 2 i \zeta_j
//! \omega_j \omega$, $\Phi_c$ the shapes at the attachments in the channel basis, $f$ the forces
//! of the actuators on the cell and $p$ the pier displacement; the cell moves the channels by
//! $z_c = \Phi_c q$, continuously (no communication step: this is the coupling the co-simulation
//! approximates).
//!
//! **The sampled servo.** At 5 kHz the servo samples the stroke $s = x_a - z_c$ and holds its
//! drive $u_k = K_r(z) r_k - K_s(z) s_k$ ($z = e^{i\omega T_s}$; $K_r$, $K_s$ from the PID
//! recursions, with the setpoint weight on $r$). For a sinusoid the response of a
//! sampled-data loop is a fundamental plus images at $\omega + m\,2\pi/T_s$; this model gives
//! the fundamental. The hold puts $\tilde H(\omega) u_k$ on the plant at the fundamental,
//! $\tilde H = (1 - e^{-i\omega T_s}) / (i \omega T_s)$, and sampling folds every image of the
//! drive's response back onto the samples: the stroke samples are exactly
//! $P_d(z) u_k$ plus the samples of the exogenous part, with $P_d$ the exact zero-order-hold
//! discretisation of the channel from drive to stroke. So per channel
//!
//! $$u_k = \frac{K_r r - K_s (P_{sz} z_c + P_{sw} f_w)}{1 + K_s P_d}$$
//!
//! exactly on a rigid base, where $1 + K_s P_d$ is the discrete return difference. On the
//! flexible cell the stroke's dependence on the drive through the structure is taken at the
//! fundamental only; its images lie beyond $1/T_s - f$ (about 5 kHz), where the structure's modes
//! are inert (relative size $(f_{mode} T_s)^2$).
//!
//! **Identical segments.** With these channel transfer functions the forces are
//! $f = t_{fz} z_c + f_{ext}$ channel by channel, with one coefficient per channel kind, so
//! eliminating $f$ and $z_c$ leaves one $r \times r$ complex system per frequency
//! ($r$ retained modes):
//!
//! $$\left(D - t_{fz,p} \Phi_p^T\Phi_p - t_{fz,t} \Phi_t^T \Phi_t\right) q
//!   = \Phi_c^T f_{ext} + b_p p,$$
//!
//! with the two Gram matrices formed once: the seed paper's point that a diagonal system of
//! identical subsystems stays diagonal in any basis, used here in the basis of the mode shapes.
//! A TMT frequency point with 500 modes is one 500 x 500 complex LU.

use faer::c64;
use nalgebra::SMatrix;
use std::f64::consts::TAU;

use crate::M1Error;
use crate::plant::segment::{Channel, N_CONT, SegmentModel, state};
use crate::plant::structure::{ModalModel, ModalSolver};

mod frequency;
mod global_loop;
mod state_space;
#[cfg(test)]
mod tests;

pub use frequency::{FrequencyModel, Inputs, Response};
pub use global_loop::{BandwidthLimit, GlobalLoop, GlobalLoopPoint, PlantOnW, highest_bandwidth};
pub use state_space::{StateSpaceMirror, wind_run};

/// `exp(i x)`.
fn cis(x: f64) -> c64 {
    c64::new(x.cos(), x.sin())
}

/// The zero-order hold at the fundamental, $(1 - e^{-i\omega T}) / (i\omega T)$ (1 at DC).
pub fn hold(f: f64, period: f64) -> c64 {
    let x = TAU * f * period;
    if x.abs() < 1e-8 {
        return c64::new(1.0, -x / 2.0);
    }
    (c64::new(1.0, 0.0) - cis(-x)) / c64::new(0.0, x)
}

/// Actuator order to channel order (piston channels, then tilt channels 2 s + m) with the
/// segment basis `v` (real or complex values).
fn to_channel_order<T>(v: &SMatrix<f64, 3, 3>, a: &[T]) -> Vec<T>
where
    T: Copy + Default + std::ops::Add<Output = T> + std::ops::Mul<f64, Output = T>,
{
    let n = a.len() / 3;
    let mut c = vec![T::default(); 3 * n];
    for s in 0..n {
        let x = &a[3 * s..3 * s + 3];
        let proj = |j: usize| x[0] * v[(0, j)] + x[1] * v[(1, j)] + x[2] * v[(2, j)];
        c[s] = proj(0);
        c[n + 2 * s] = proj(1);
        c[n + 2 * s + 1] = proj(2);
    }
    c
}

/// Channel order back to actuator order.
fn to_actuator_order<T>(v: &SMatrix<f64, 3, 3>, c: &[T]) -> Vec<T>
where
    T: Copy + Default + std::ops::Add<Output = T> + std::ops::Mul<f64, Output = T>,
{
    let n = c.len() / 3;
    let mut a = vec![T::default(); 3 * n];
    for s in 0..n {
        let ch = [c[s], c[n + 2 * s], c[n + 2 * s + 1]];
        for k in 0..3 {
            a[3 * s + k] = ch[0] * v[(k, 0)] + ch[1] * v[(k, 1)] + ch[2] * v[(k, 2)];
        }
    }
    a
}

/// The retained modes of `cell` for `n_segments` segments, or an error if its attachments
/// do not match.
fn retained_modes(
    n_segments: usize,
    cell: ModalModel,
    n_modes: usize,
    damping_ratio: f64,
) -> Result<ModalSolver, M1Error> {
    let na = 3 * n_segments;
    if cell.na != na {
        return Err(M1Error::SizeMismatch {
            what: "structure attachments (3 per segment)",
            expected: na,
            found: cell.na,
        });
    }
    ModalSolver::new(cell, n_modes, damping_ratio)
}

/// The number of whole periods in `h`, or an error naming `name` if `h` is not a positive
/// multiple of `period` (to 1e-9 of it).
fn whole_periods(h: f64, period: f64, name: &'static str) -> Result<u64, M1Error> {
    let k = (h / period).round();
    if h.is_finite() && k >= 1.0 && (h - k * period).abs() <= 1e-9 * period {
        Ok(k as u64)
    } else {
        Err(M1Error::InvalidParameter {
            name,
            value: h,
            reason: "must be a positive multiple of the period it is stepped at",
        })
    }
}

/// The discrete servo at frequency `f` (Hz): `(K_r, K_s)` with $u_k = K_r r_k - K_s s_k$ for
/// the command $r$ and the stroke $s$ (drive units per metre).
pub fn servo_transfer(model: &SegmentModel, f: f64) -> (c64, c64) {
    let v = &model.actuator.servo;
    let ts = model.servo_period();
    let z = cis(TAU * f * ts);
    let zi = z.inv();
    let one = c64::new(1.0, 0.0);
    let ai = (-TAU * v.integrator_leak * ts).exp();
    let ad = (-TAU * v.derivative_cutoff * ts).exp();
    let c1 = (1.0 - ad) / ts;
    // I_{k+1} = a_i I_k + Ts e_k, used after the update: Ts e / (1 - a_i z^-1).
    let integ = c64::new(ts, 0.0) / (one - zi * ai);
    // D_k = a_d D_{k-1} - c1 (s_k - s_{k-1}).
    let deriv = (one - zi) * c1 / (one - zi * ad);
    let k_r = integ * v.ki + v.kp * v.setpoint_weight + v.feedforward;
    let k_s = integ * v.ki + deriv * v.kd + v.kp;
    (k_r, k_s)
}

/// Responses of one channel kind at one frequency, per unit of each input: the command `r`
/// (a sequence at the servo rate), the cell displacement `z_c` and the wind force `f_w` (both
/// continuous sinusoids). Index 0, 1, 2 of each array is `r`, `z_c`, `f_w`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelTransfer {
    /// Mirror displacement at the actuator point (m per unit input).
    pub mirror: [c64; 3],
    /// Force of the actuator on the cell (N per unit input).
    pub force: [c64; 3],
    /// Continuous stroke `x_a - z_c` (m per unit input).
    pub stroke: [c64; 3],
    /// Servo output sequence (drive units per unit input).
    pub drive: [c64; 3],
    /// The discrete return difference of the servo loop on a rigid base, $1 + K_s P_d$.
    pub return_difference: c64,
    /// The servo loop gain on a rigid base, $K_s P_d$.
    pub loop_gain: c64,
}

/// Open-loop (servo off) responses of one channel kind at one frequency: columns drive,
/// `z_c`, `f_w`, continuous.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpenChannel {
    /// Mirror displacement.
    pub mirror: [c64; 3],
    /// Force on the cell.
    pub force: [c64; 3],
    /// Stroke `x_a - z_c`.
    pub stroke: [c64; 3],
    /// Exact sampled stroke per held drive sequence, $P_d(z)$, on a rigid base.
    pub sampled_stroke: c64,
}

type CMatC = SMatrix<c64, N_CONT, N_CONT>;

/// The open channel at `f` (Hz).
pub fn open_channel(model: &SegmentModel, ch: Channel, f: f64) -> OpenChannel {
    let p = model.plant(ch);
    let w = TAU * f;
    let jw = c64::new(0.0, w);
    let a = p.a.map(|x| c64::new(x, 0.0));
    let m: CMatC = CMatC::identity() * jw - a;
    let b = p.b.map(|x| c64::new(x, 0.0));
    let x = m
        .lu()
        .solve(&b)
        .unwrap_or_else(|| b.map(|_| c64::new(f64::NAN, 0.0)));
    let mut out = OpenChannel {
        mirror: [c64::new(0.0, 0.0); 3],
        force: [c64::new(0.0, 0.0); 3],
        stroke: [c64::new(0.0, 0.0); 3],
        sampled_stroke: c64::new(0.0, 0.0),
    };
    for j in 0..3 {
        out.mirror[j] = x[(state::MIRROR_POS, j)];
        out.stroke[j] = x[(state::NODE_POS, j)] - if j == 1 { 1.0 } else { 0.0 };
        let mut fj = c64::new(p.df[j], 0.0);
        for i in 0..N_CONT {
            fj += x[(i, j)] * p.cf[i];
        }
        out.force[j] = fj;
    }
    // P_d(z) = e_a^T (z I - A_d)^-1 B_d,u.
    let (ad, bd) = model.zoh(ch, model.servo_period());
    let z = cis(w * model.servo_period());
    let md: CMatC = CMatC::identity() * z - ad.map(|x| c64::new(x, 0.0));
    let bu = bd.column(0).map(|x| c64::new(x, 0.0));
    out.sampled_stroke = md
        .lu()
        .solve(&bu)
        .map_or(c64::new(f64::NAN, 0.0), |x| x[state::NODE_POS]);
    out
}

/// The channel with its servo closed, on a base whose motion `z_c` is an input.
pub fn channel_transfer(model: &SegmentModel, ch: Channel, f: f64) -> ChannelTransfer {
    let o = open_channel(model, ch, f);
    let (k_r, k_s) = servo_transfer(model, f);
    let h = hold(f, model.servo_period());
    let loop_gain = k_s * o.sampled_stroke;
    let rd = c64::new(1.0, 0.0) + loop_gain;
    // u_k per unit input; the drive on the plant is h u_k.
    let drive = [k_r / rd, -k_s * o.stroke[1] / rd, -k_s * o.stroke[2] / rd];
    let mut t = ChannelTransfer {
        mirror: [c64::new(0.0, 0.0); 3],
        force: [c64::new(0.0, 0.0); 3],
        stroke: [c64::new(0.0, 0.0); 3],
        drive,
        return_difference: rd,
        loop_gain,
    };
    for j in 0..3 {
        let direct = |a: &[c64; 3]| if j == 0 { c64::new(0.0, 0.0) } else { a[j] };
        let u = h * drive[j];
        t.mirror[j] = o.mirror[0] * u + direct(&o.mirror);
        t.force[j] = o.force[0] * u + direct(&o.force);
        t.stroke[j] = o.stroke[0] * u + direct(&o.stroke);
    }
    t
}
