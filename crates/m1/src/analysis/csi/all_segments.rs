//! The exact all-segment sensitivity of the actuator loop (module documentation, "All
//! segments"): the two channel kinds' complements in closed form, the coupled subspace by
//! Lanczos on $S_W^H S_W$ with the modal solves in the calling thread
//! ([`crate::linalg::complex_symmetric`]).

use faer::c64;

use super::actuator_loop::ActuatorLoop;
use super::projected::{Kinds, singular, stiffness_with_forces};
use crate::M1Error;
use crate::linalg::complex_symmetric::ModalFactor;

/// Lanczos steps at least from the generic start: enough for the top of the spectrum to be
/// reached before the residual test is trusted.
const COLD_MIN_STEPS: usize = 12;
/// Lanczos steps at least from a warm start ([`WARM_MIX`] keeps every eigenvector's share of
/// the start large enough that an unresolved top still shows in the residual).
const WARM_MIN_STEPS: usize = 8;
/// Lanczos steps at most for the all-segment $\sigma_{max}(S)$ by default
/// ([`ActuatorLoop::with_lanczos_steps`] sets another limit). Where the top singular values
/// cluster (TMT, 1000 modes: below 2.2 Hz, 20-60 Hz and from 200 Hz; about 3e-4 wide at
/// 39.4 Hz) the top Ritz value creeps up the cluster and this limit, not the residual test,
/// ends the iteration. The value is then a lower bound within 3e-5 of the dense reference:
/// measured 5e-6 below it at 39.4 Hz and 1.4e-5 at 238.5 Hz from a cold start, 2.2e-5 there
/// along the sweep's warm-started run (120 steps, up to twice as many, gave 1.0e-6 and 1.3e-12).
/// Separated tops (the peaks, where the criteria are decided) converge to the residual test in
/// 12-40 steps.
pub const LANCZOS_STEPS: usize = 60;
/// The step limits [`ActuatorLoop::with_lanczos_steps`] accepts: at least a cold start's least
/// number of steps.
pub const LANCZOS_STEPS_RANGE: std::ops::RangeInclusive<usize> = COLD_MIN_STEPS..=10_000;
/// Relative residual of the top Ritz pair of $S^H S$ at which Lanczos stops: the Ritz value
/// is then within this relative distance of an eigenvalue, and in practice far closer to the
/// top one (the error is quadratic in the residual for a separated top). Tighter is wasted:
/// the operator itself is accurate only to about 1e-8 relative where the loop gain is high
/// (below ~2 Hz the closed-loop modal stiffness is ill-conditioned and $|S| \sim 10^{-3}$).
const LANCZOS_TOL: f64 = 1e-7;

/// Weight of the fixed generic vector added to a warm start (each normalised): it keeps every
/// eigenvector's share of the start vector at about `WARM_MIX / sqrt(dimension)` or more, so a
/// top eigenvector orthogonal to the previous one (a crossing of two branches) is still found.
const WARM_MIX: f64 = 0.1;

/// The all-segment value at one frequency with the coupled subspace's top vector (`None` when
/// the subspace is empty), to start the Lanczos of a neighbouring frequency or gain from.
pub(super) type AllSegments = (f64, Option<Vec<c64>>);

/// The start of the coupled subspace's Lanczos (dimension `w`): a fixed generic vector, or
/// `warm` (normalised, of length `w`) plus [`WARM_MIX`] times the generic one (normalised);
/// with whether `warm` was used.
pub(super) fn start_vector(w: usize, warm: Option<&[c64]>) -> (Vec<c64>, bool) {
    let mut v0: Vec<c64> = (0..w)
        .map(|i| {
            let t = i as f64;
            c64::new(1.0 + (0.7 * t).sin(), (1.3 * t).cos())
        })
        .collect();
    let norm = |v: &[c64]| v.iter().map(|x| x.norm_sqr()).sum::<f64>().sqrt();
    if let Some(u) = warm.filter(|u| u.len() == w) {
        let (nu, ng) = (norm(u), norm(&v0));
        if nu > 0.0 && nu.is_finite() {
            for (g, x) in v0.iter_mut().zip(u) {
                *g = x / nu + *g * (WARM_MIX / ng);
            }
            return (v0, true);
        }
    }
    (v0, false)
}

/// The least Lanczos steps from a warm or a cold start.
pub(super) fn min_steps(warm: bool) -> usize {
    if warm { WARM_MIN_STEPS } else { COLD_MIN_STEPS }
}

impl ActuatorLoop {
    /// The exact all-segment $\sigma_{max}(S)$ for the channel scalars `k` with the servo
    /// scaled by `gain`: the complements' rigid-base values and the coupled subspace's.
    pub(super) fn all_from_kinds(&self, k: &Kinds, gain: f64) -> Result<f64, M1Error> {
        self.all_from_kinds_warm(k, gain, None).map(|(v, _)| v)
    }

    /// [`Self::all_from_kinds`] with the coupled subspace's Lanczos started from `warm` (the
    /// top vector of a nearby frequency or gain, mixed with the generic start: [`WARM_MIX`]),
    /// returning the top vector found. From a close vector it takes fewer steps: a fifth fewer
    /// over the TMT sweep at 1000 modes (60 frequencies, the limit at 120).
    pub(super) fn all_from_kinds_warm(
        &self,
        k: &Kinds,
        gain: f64,
        warm: Option<&[c64]>,
    ) -> Result<AllSegments, M1Error> {
        let one = c64::new(1.0, 0.0);
        let s = k.k_s * gain;
        let e = [one + s * k.p0[0], one + s * k.p0[1]];
        if e.iter()
            .any(|x| x.norm() == 0.0 || !x.re.is_finite() || !x.im.is_finite())
        {
            return Err(M1Error::Unstable {
                channel: "actuator servo loop on a rigid base",
                spectral_radius: f64::NAN,
                hint: "the return difference 1 + K_s P_d is zero at this frequency",
            });
        }
        let mut v = 0.0f64;
        for (kind, &c) in self.complement.iter().enumerate() {
            if c {
                v = v.max(1.0 / e[kind].norm());
            }
        }
        let w = self.coupled_dimension();
        if w == 0 {
            return Ok((v, None));
        }
        let (sw, top) = self.coupled_sensitivity(k, s, e, warm)?;
        Ok((v.max(sw), Some(top)))
    }

    /// The factors of the closed-loop modal stiffness for the servo `s` (scaled) and the
    /// rigid-base return differences `e`: each kind's force per cell displacement with the
    /// servo closed is $f_z - s f_u H p_{sz} / E$. Complex symmetric: $L D L^T$ where stable,
    /// else LU ([`ModalFactor`]).
    pub(super) fn closed_loop_factor(&self, k: &Kinds, s: c64, e: [c64; 2]) -> ModalFactor {
        let forces = [0, 1].map(|kd| k.fz[kd] - s * (k.fu[kd] * k.hold * k.psz[kd] / e[kd]));
        ModalFactor::new(|| stiffness_with_forces(&self.fm, k.frequency, forces))
    }

    /// $\sigma_{max}$ of the sensitivity on the coupled subspace (dimension $r_p + r_t > 0$)
    /// for the servo `s` (scaled) and the rigid-base return differences `e` of both kinds, with
    /// its top right singular vector; Lanczos starts from `warm` when given (of length w).
    fn coupled_sensitivity(
        &self,
        k: &Kinds,
        s: c64,
        e: [c64; 2],
        warm: Option<&[c64]>,
    ) -> Result<(f64, Vec<c64>), M1Error> {
        let one = c64::new(1.0, 0.0);
        let w = self.coupled_dimension();
        let lu = self.closed_loop_factor(k, s, e);
        let zero = c64::new(0.0, 0.0);
        let rp = self.coupled_rank[0];
        let r = self.fm.n_modes();
        // S_W x = D x - X K_cl^-1 Y^T x in the coordinates of the coupled subspace, with per
        // kind D = 1 / E, X = (s p_sz / E) R, Y = (f_u H / E) R; S_W^H S_W x is applied with
        // one pass over R^T, one over R and one over a weighted Gram matrix in between:
        //   a_k = R_k^T x_k, z = K^-1 sum_k y_k a_k,
        //   z' = K^-H sum_k conj(x_k) (d_k a_k - x_k G_k z)
        //      = K^-H (sum_k conj(x_k) d_k a_k - G_x z), G_x = sum_k |x_k|^2 G_k (one pass),
        //   out_k = |d_k|^2 x_k - R_k (conj(d_k) x_k z + conj(y_k) z').
        let d = [one / e[0], one / e[1]];
        let cy = [0, 1].map(|kd| k.fu[kd] * k.hold / e[kd]);
        let cx = [0, 1].map(|kd| s * k.psz[kd] / e[kd]);
        let ranges = [0..rp, rp..w];
        let (rr, gram, rank) = (&self.coupled_r, &self.coupled_gram, self.coupled_rank);
        let wx = [cx[0].norm_sqr(), cx[1].norm_sqr()];
        let gram_f = gram[0].scaled_sum(wx[0], &gram[1], wx[1]);
        let big = r.max(w);
        let mut buf = vec![0.0; 4 * big];
        // The solves sit in the Lanczos loop of one frequency, in this thread (the frequencies
        // are what runs in parallel), one right-hand side each.
        let mut work = Vec::with_capacity(r);
        let (mut a, mut z, mut z2) = ([vec![zero; r], vec![zero; r]], vec![zero; r], vec![zero; r]);
        let op = |x: &[c64], o: &mut [c64]| {
            let (xr, rest) = buf.split_at_mut(big);
            let (xi, rest) = rest.split_at_mut(big);
            let (t0, t1) = rest.split_at_mut(big);
            for (i, v) in x.iter().enumerate() {
                xr[i] = v.re;
                xi[i] = v.im;
            }
            for kd in 0..2 {
                let rg = ranges[kd].clone();
                rr[kd].t_times_complex([&xr[rg.clone()], &xi[rg]], [&mut t0[..r], &mut t1[..r]]);
                for (j, aj) in a[kd].iter_mut().enumerate() {
                    *aj = c64::new(t0[j], t1[j]);
                }
            }
            for (j, zj) in z.iter_mut().enumerate() {
                *zj = cy[0] * a[0][j] + cy[1] * a[1][j];
            }
            lu.solve_in_place(&mut z, &mut work);
            for (j, zj) in z.iter().enumerate() {
                xr[j] = zj.re;
                xi[j] = zj.im;
            }
            gram_f.symmetric_times_complex([&xr[..r], &xi[..r]], [&mut t0[..r], &mut t1[..r]]);
            let c = [cx[0].conj() * d[0], cx[1].conj() * d[1]];
            for (j, z2j) in z2.iter_mut().enumerate() {
                *z2j = c[0] * a[0][j] + c[1] * a[1][j] - c64::new(t0[j], t1[j]);
            }
            lu.solve_adjoint_in_place(&mut z2, &mut work);
            for kd in 0..2 {
                let (c1, c2) = (d[kd].conj() * cx[kd], cy[kd].conj());
                for j in 0..r {
                    let v = c1 * z[j] + c2 * z2[j];
                    xr[j] = v.re;
                    xi[j] = v.im;
                }
                let m = rank[kd];
                rr[kd].times_complex([&xr[..r], &xi[..r]], [&mut t0[..m], &mut t1[..m]]);
                let d2 = d[kd].norm_sqr();
                let start = ranges[kd].start;
                for (i, oi) in o[ranges[kd].clone()].iter_mut().enumerate() {
                    *oi = x[start + i] * d2 - c64::new(t0[i], t1[i]);
                }
            }
        };
        let (v0, warmed) = start_vector(w, warm);
        let pair = crate::linalg::krylov::largest_hermitian_eigenpair(
            w,
            (min_steps(warmed), self.lanczos_steps),
            &v0,
            LANCZOS_TOL,
            op,
        );
        let theta = pair.value;
        let sw = theta.max(0.0).sqrt();
        if !sw.is_finite() {
            return Err(singular(k.frequency));
        }
        Ok((sw, pair.vector))
    }
}
