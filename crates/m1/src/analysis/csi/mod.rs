//! Control-structure interaction (CSI) of the actuator servo loop: the largest singular value
//! of the servo's sensitivity on the flexible cell versus frequency, computed in reduced bases
//! of actuator space (Zernike modes of increasing radial degree, or the actuators of the first
//! segments) and exactly with all segments (the seed paper's Figure 11).
//!
//! # The loop
//!
//! The servo loop of every actuator is broken at its drive, with the servo open and the
//! structure coupled (see [`crate::plant::monolithic`] for the channel model). At frequency $f$, per
//! channel kind $k$ (piston, tilt) the open channel ([`open_channel`]) gives the exact sampled
//! drive-to-stroke response on a rigid base $p_{0,k}$, the stroke per cell displacement
//! $p_{sz,k}$, the cell force per cell displacement $f_{z,k}$ and the cell force per (held)
//! drive $f_{u,k}$. With the hold $H$ ([`hold`]), $D = \mathrm{diag}(\omega_j^2 - \omega^2 +
//! 2 i \zeta_j \omega_j \omega)$ and the channel shapes $\Phi_c$, the modes' stiffness with the
//! servos open is $K_0 = D - f_{z,p} G_p - f_{z,t} G_t$ and the drive-to-sampled-stroke plant
//! in channel space is
//!
//! $$P = \mathrm{diag}(p_{0}) + \mathrm{diag}(p_{sz}) \Phi_c K_0^{-1} \Phi_c^T
//!   \mathrm{diag}(f_u) H.$$
//!
//! Every channel has the same scalar servo $K_s(z)$ ([`servo_transfer`]), so the loop gain is
//! $L = K_s P$ and the sensitivity $S = (I + L)^{-1}$; $\sigma_{max}(S) = 1 / \sigma_{min}(I +
//! L)$.
//!
//! # Bases
//!
//! In an orthonormal basis $B$ of actuator space ($n_a \times n_b$; real, so it is also
//! orthonormal in channel space, the per-segment change of basis
//! [`crate::plant::segment::modal_basis`] being orthogonal) the reduced sensitivity is
//! $S_B = (I + K_s B^T P B)^{-1}$. Three families:
//!
//! * **Zernike** up to radial degree $p$: Noll's modes projected on the segments'
//!   piston/tip/tilt ([`ZernikeBasis`]), converted to actuator displacements
//!   ([`ptt_to_actuators`]) and orthonormalised in Noll order by Gram–Schmidt (twice, columns
//!   dependent on the previous ones dropped). The bases are nested, so one projected matrix at
//!   the largest degree serves every degree through its leading blocks.
//! * **Segments**: the three actuators of the first $m$ segments ordered by distance from the
//!   centre (unit vectors), nested the same way.
//! * **All segments** ($B = I$), exact and cheap: the coupling term maps into, and only sees,
//!   $\mathrm{span}(\Phi_p) \oplus \mathrm{span}(\Phi_t)$ (per kind), and the diagonal part is
//!   a scalar per kind, so $I + L$ is block diagonal between that subspace (dimension
//!   $r_p + r_t \le 2r$) and its complement, where it is $1 + K_s p_{0,k}$. The singular values
//!   of $S$ are those of the projected square matrix together with $1/|1 + K_s p_{0,k}|$ for
//!   each kind with a non-empty complement.
//!
//! **No monotonicity.** $S_B$ is the inverse of the compression $B^T (I + L) B$, not the
//! compression $B^T S B$ of $S$, so $\sigma_{max}(S_B)$ may exceed $\sigma_{max}(S)$: the
//! reduced bases converge to the all-segment curve, without a bound from either side. Even on a
//! rigid base a basis mixing the two channel kinds within one vector gives
//! $1/|1 + K_s (\lambda p_{0,p} + (1 - \lambda) p_{0,t})|$ for the eigenvalues $\lambda$ of
//! $B_p^T B_p$, not only the two channel values.
//!
//! # Peak labels
//!
//! At a peak of a Zernike curve (and of the all-segment curve, with the largest Zernike degree)
//! the top left singular vector of $S_B$ is written in Zernike coefficients (through the
//! triangular factor of the Gram–Schmidt), and the peak takes the family of the largest
//! coefficient in modulus: `P` for an axisymmetric mode ($m = 0$) whose actuator pattern is
//! mostly segment piston (more than half its norm in the piston channels; always so for Z1),
//! `TT` for azimuthal order $|m| = 1$ (tip/tilt, coma, ...), `FA` for the other modes of radial
//! degree 2 (focus, astigmatism), else `Z<j>`.
//!
//! # Servo bandwidth
//!
//! The servo's `kp`, `ki`, `kd` scaled together by $a$ scale $K_s$ by $a$ and leave $P$
//! unchanged. [`highest_gain`] bisects (geometrically) for the largest $a$ keeping the
//! all-segment $\sigma_{max}(S)$ under a limit on the grid below a frequency, with the scaled
//! segment model valid (its rigid-base loop stable: [`SegmentModel::validate`]). The criterion
//! is a frequency-domain one: it does not by itself prove the coupled loop stable.
//!
//! [`open_channel`]: crate::plant::monolithic::open_channel
//! [`hold`]: crate::plant::monolithic::hold
//! [`servo_transfer`]: crate::plant::monolithic::servo_transfer
//! [`ZernikeBasis`]: crate::aperture::zernike::ZernikeBasis
//! [`ptt_to_actuators`]: crate::optics::metrics::ptt_to_actuators
//! [`SegmentModel::validate`]: crate::plant::segment::SegmentModel::validate

mod actuator_loop;
mod all_segments;
mod frequency_sweep;
mod projected;
mod servo_gain;
#[cfg(test)]
mod tests;
mod zernike;

pub use actuator_loop::{ActuatorLoop, CsiPoint};
pub use all_segments::{LANCZOS_STEPS, LANCZOS_STEPS_RANGE};
pub(crate) use frequency_sweep::local_maxima;
pub use frequency_sweep::{BasisCurve, CsiSweep, LabelledPeak, log_grid, sweep};
pub use projected::Kinds;
pub use servo_gain::{GainLimit, SCAN, crossover, highest_gain, scaled_servo};
pub(crate) use zernike::ZernikeChannels;
pub use zernike::family_label;
