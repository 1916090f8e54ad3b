//! The per-frequency pieces of the servo-open plant: the scalars of both channel kinds
//! ([`Kinds`]), the factors of the modes' stiffness, the plant `B^T P B` projected on a real
//! orthonormal basis, and the largest sensitivity singular value of a basis's leading vectors.

use faer::{Mat, c64};

use crate::M1Error;
use crate::linalg::complex_symmetric::ModalFactor;
use crate::plant::monolithic::{
    ChannelTransfer, FrequencyModel, hold, open_channel, servo_transfer,
};
use crate::plant::segment::{Channel, SegmentModel};

/// The scalars of both channel kinds at one frequency (index 0 piston, 1 tilt).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kinds {
    /// Frequency (Hz).
    pub frequency: f64,
    /// The servo, drive units per metre of stroke.
    pub k_s: c64,
    /// The hold of the drive at the fundamental.
    pub hold: c64,
    /// Exact sampled stroke per drive on a rigid base.
    pub p0: [c64; 2],
    /// Stroke per cell displacement.
    pub psz: [c64; 2],
    /// Cell force per cell displacement.
    pub fz: [c64; 2],
    /// Cell force per drive.
    pub fu: [c64; 2],
}

impl Kinds {
    /// The open channels and the servo of `model` at `f` (Hz).
    pub fn new(model: &SegmentModel, f: f64) -> Self {
        let o = Channel::ALL.map(|ch| open_channel(model, ch, f));
        let (_, k_s) = servo_transfer(model, f);
        Self {
            frequency: f,
            k_s,
            hold: hold(f, model.servo_period()),
            p0: [o[0].sampled_stroke, o[1].sampled_stroke],
            psz: [o[0].stroke[1], o[1].stroke[1]],
            fz: [o[0].force[1], o[1].force[1]],
            fu: [o[0].force[0], o[1].force[0]],
        }
    }

    /// The rigid-base sensitivity of channel kind `k` with the servo scaled by `gain`.
    pub fn rigid_sensitivity(&self, k: usize, gain: f64) -> f64 {
        1.0 / (c64::new(1.0, 0.0) + self.k_s * gain * self.p0[k]).norm()
    }
}

/// The modal stiffness's lower triangle (what [`ModalFactor`] reads) at `f` (Hz) with each
/// channel kind's cell force per cell displacement `forces` (piston, tilt):
/// `modal_stiffness_lower` reads it from `force[1]`.
pub(super) fn stiffness_with_forces(fm: &FrequencyModel, f: f64, forces: [c64; 2]) -> Mat<c64> {
    let zero = c64::new(0.0, 0.0);
    let ct = |kind: usize| ChannelTransfer {
        mirror: [zero; 3],
        force: [zero, forces[kind], zero],
        stroke: [zero; 3],
        drive: [zero; 3],
        return_difference: zero,
        loop_gain: zero,
    };
    fm.modal_stiffness_lower(f, &[ct(0), ct(1)])
}

/// The factors of the open-servo modal stiffness $K_0$ at one frequency (`None` without
/// modes): complex symmetric, so $L D L^T$ where stable ([`ModalFactor`]).
pub(super) fn modal_factor(fm: &FrequencyModel, k: &Kinds) -> Option<ModalFactor> {
    if fm.n_modes() == 0 {
        return None;
    }
    Some(ModalFactor::new(|| {
        stiffness_with_forces(fm, k.frequency, k.fz)
    }))
}

pub(super) fn singular(f: f64) -> M1Error {
    M1Error::InvalidInput(format!(
        "the modal system of the actuator servo loop is singular at {f} Hz (an undamped mode)"
    ))
}

/// A real orthonormal basis of channel space in the pieces the plant needs:
/// `C_k = Phi_k^T B_k` (r x nb) and `G_k = B_k^T B_k` (nb x nb) per channel kind; for a basis
/// whose every vector lies in one kind's channels (the segment bases' unit vectors), each
/// vector's kind and `C_p + C_t`.
#[derive(Debug, Clone)]
pub(super) struct Projected {
    nb: usize,
    c: [Mat<c64>; 2],
    pub(super) g: [Mat<f64>; 2],
    /// `(kind of each vector, C_p + C_t)` when every vector has one kind.
    single_kind: Option<(Vec<usize>, Mat<c64>)>,
}

impl Projected {
    /// `b`: na x nb in channel order (piston channels first).
    pub(super) fn new(fm: &FrequencyModel, b: &Mat<f64>) -> Self {
        let n = fm.n_segments();
        let na = fm.n_actuators();
        let phic = fm.channel_shapes();
        let nb = b.ncols();
        let rows = [(0, n), (n, na - n)];
        let c = rows.map(|(r0, nr)| {
            let x = phic.subrows(r0, nr).transpose() * b.subrows(r0, nr);
            Mat::from_fn(x.nrows(), nb, |i, j| c64::new(x[(i, j)], 0.0))
        });
        let g = rows.map(|(r0, nr)| b.subrows(r0, nr).transpose() * b.subrows(r0, nr));
        let has = |(r0, nr): (usize, usize), j: usize| (r0..r0 + nr).any(|i| b[(i, j)] != 0.0);
        let kinds: Option<Vec<usize>> = (0..nb)
            .map(|j| match (has(rows[0], j), has(rows[1], j)) {
                (true, true) => None,
                (false, true) => Some(1),
                _ => Some(0),
            })
            .collect();
        let single_kind = kinds.map(|k| (k, &c[0] + &c[1]));
        Self {
            nb,
            c,
            g,
            single_kind,
        }
    }

    /// Whether the basis's vectors each lie in one kind's channels (the cheaper plant).
    #[cfg(test)]
    pub(super) fn is_single_kind(&self) -> bool {
        self.single_kind.is_some()
    }

    /// The same basis with the general plant (for tests: both forms agree).
    #[cfg(test)]
    pub(super) fn general(mut self) -> Self {
        self.single_kind = None;
        self
    }

    /// `B^T P B` (nb x nb) at the frequency of `k`.
    pub(super) fn plant(&self, k: &Kinds, lu: Option<&ModalFactor>) -> Result<Mat<c64>, M1Error> {
        let nb = self.nb;
        let mut m = Mat::from_fn(nb, nb, |i, j| {
            k.p0[0] * self.g[0][(i, j)] + k.p0[1] * self.g[1][(i, j)]
        });
        let Some(lu) = lu else {
            return Ok(m);
        };
        let coupling = if let Some((kind, c)) = &self.single_kind {
            // Vector i of kind k_i: left_i = p_sz,k_i c_i, right_j = H f_u,k_j c_j, so the
            // coupling is diag(p_sz) (C^T K^-1 C) diag(H f_u), C^T K^-1 C from the factors
            // with one triangular solve.
            let x = lu.bilinear(c.as_ref());
            Mat::from_fn(nb, nb, |i, j| {
                k.psz[kind[i]] * x[(i, j)] * (k.fu[kind[j]] * k.hold)
            })
        } else {
            let left = faer::Scale(k.psz[0]) * &self.c[0] + faer::Scale(k.psz[1]) * &self.c[1];
            let right = faer::Scale(k.fu[0] * k.hold) * &self.c[0]
                + faer::Scale(k.fu[1] * k.hold) * &self.c[1];
            left.transpose() * lu.solve(right.as_ref())
        };
        if coupling
            .col_iter()
            .any(|c| c.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())))
        {
            return Err(singular(k.frequency));
        }
        m += coupling;
        Ok(m)
    }
}

/// `1 / sigma_min(I + s M[..n, ..n])`, the largest singular value of the sensitivity of the
/// leading `n` basis vectors (`0` for `n = 0`).
pub(super) fn sensitivity_max(m: &Mat<c64>, s: c64, n: usize) -> Result<f64, M1Error> {
    if n == 0 {
        return Ok(0.0);
    }
    let a = Mat::from_fn(n, n, |i, j| {
        let d = if i == j { 1.0 } else { 0.0 };
        c64::new(d, 0.0) + s * m[(i, j)]
    });
    let sv = a
        .singular_values()
        .map_err(|_| M1Error::InvalidInput("SVD of the return difference failed".into()))?;
    let smin = sv.iter().copied().fold(f64::INFINITY, f64::min);
    let v = 1.0 / smin;
    if v.is_finite() {
        Ok(v)
    } else {
        Err(M1Error::Unstable {
            channel: "actuator servo loop on the structure",
            spectral_radius: f64::NAN,
            hint: "the return difference is singular at this frequency",
        })
    }
}
