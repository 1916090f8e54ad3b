//! The global edge-sensor loop on the frequency model ([`GlobalLoop`]): its loop gain and
//! sensitivity projected exactly on the subspace the structure and the controller's mode groups
//! couple ([`PlantOnW`], [`GlobalLoopPoint`]), and the bisection for the highest bandwidth
//! meeting the seed paper's criteria ([`highest_bandwidth`], [`BandwidthLimit`]).

use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use std::f64::consts::TAU;

use super::{FrequencyModel, cis, hold};
use crate::M1Error;
use crate::linalg::extreme;

/// The global edge-sensor loop in the frequency domain: the controller of
/// [`crate::control::controller`] (integrators at its sample rate on four mode groups, output held) on
/// the mirror of a [`FrequencyModel`] read by ideal edge sensors.
///
/// # Loop gain
///
/// With ideal sensors ($y = A z$) the reconstructor gives $B_0 A = P$, so the loop broken at
/// the command is
/// $$L(\omega) = c(\omega)\, G\, T(\omega), \qquad
///   c = \frac{\tilde H_c(\omega)}{e^{i\omega/f_c} - 1},$$
/// with $G = g P + (g_{34} - g) R_{34} R_{34}^T + (g_2 - g) R_2 R_2^T + (g_f - g)\psi\psi^T$
/// the controller's gain matrix (radial degrees >= 5 at $g$, 3-4 at $g_{34}$, astigmatism at
/// $g_2$, focus-mode at $g_f$),
/// $T$ the mirror's response to the command (servo and structure), $f_c$ the loop rate and
/// $\tilde H_c$ its hold. The sensors are sampled at $f_c$: above $f_c/2$ their response
/// folds, which this fundamental-only model leaves out (it is the standard continuous-time
/// reading of a sampled loop, accurate well below $f_c / 2$ and indicative above).
///
/// # Exploiting the identical segments
///
/// In the channel basis $T = \mathrm{diag}(t_k) + \mathrm{diag}(t_{gz}) \Phi_c K^{-1}
/// \Phi_c^T \mathrm{diag}(t_{fr})$ with one coefficient per channel kind, and $G$ is $g$ times
/// the identity plus a rank-15 term in the span of $N$ (3), $R_2$ (2), $R_{34}$ (9), $\psi$ (1).
/// Let $W$ be the span of $\Phi_c$'s columns and of $N$, $R_2$, $R_{34}$, $\psi$, each split into
/// its piston-channel and tilt-channel parts ($2r + 30$ dimensions at most). $L$ maps $W$ and its complement (within
/// each kind) to themselves, and on the complement it is the scalar $c\,g\,t_k$. So the
/// singular values of $L$ and of $S = (I + L)^{-1}$ are those of a $(\dim W)^2$ matrix plus two
/// scalars: exact, at $O(n_a r \dim W)$ per frequency instead of $O(n_a^3)$.
#[derive(Debug, Clone)]
pub struct GlobalLoop {
    rate: f64,
    gains: crate::control::controller::LoopGains,
    /// Orthonormal basis of W in the channel basis (na x w).
    w: Mat<f64>,
    /// N, R2, R34, psi in the channel basis (na x 3, na x 2, na x 9, na x 1).
    null: Mat<f64>,
    radial2: Mat<f64>,
    radial34: Mat<f64>,
    focus: Mat<f64>,
    /// Whether each kind has channels outside W.
    complement: [bool; 2],
    /// Per kind k (piston, tilt rows): `[W V]_k^T W_k` ((w + 15) x w), `[W V]_k^T Phi_k`
    /// ((w + 15) x r) and `Phi_k^T W_k` (r x w), with `V = [N R2 R34 psi]`, so that a plant
    /// needs no product with the n_a rows.
    cw: [Mat<f64>; 2],
    cphi: [Mat<f64>; 2],
    phiw: [Mat<f64>; 2],
    /// `W^T V` (w x 15).
    wv: Mat<f64>,
}

/// The global loop at one frequency.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct GlobalLoopPoint {
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// Largest singular value of the loop gain (the principal loop gain).
    pub loop_gain_max: f64,
    /// Largest singular value of the sensitivity $(I + L)^{-1}$.
    pub sensitivity_max: f64,
}

impl GlobalLoop {
    /// The loop of `controls` (from the mirror's geometry) with `params` on `model`'s mirror.
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] from the controller parameters, [`M1Error::SizeMismatch`]
    /// if the controller and the model have different numbers of actuators.
    pub fn new(
        model: &FrequencyModel,
        controls: &crate::control::controller::ControlModes,
        params: &crate::control::controller::ControllerParams,
    ) -> Result<Self, M1Error> {
        let gains = params.gains()?;
        let na = model.n_actuators();
        let (na_c, _) = controls.shape();
        if na_c != na {
            return Err(M1Error::SizeMismatch {
                what: "controller actuators",
                expected: na,
                found: na_c,
            });
        }
        let n = model.n_segments();
        let real = |a: &[f64]| -> Vec<f64> {
            let c: Vec<c64> = a.iter().map(|&x| c64::new(x, 0.0)).collect();
            model.to_channels(&c).iter().map(|x| x.re).collect()
        };
        let nsp = controls.null_space();
        let null_cols: Vec<Vec<f64>> = (0..nsp.ncols())
            .map(|j| real(&(0..na).map(|i| nsp[(i, j)]).collect::<Vec<_>>()))
            .collect();
        let r2_cols: Vec<Vec<f64>> = controls.radial2().iter().map(|v| real(v)).collect();
        let r34_cols: Vec<Vec<f64>> = controls.radial34().iter().map(|v| real(v)).collect();
        let focus_col = real(controls.focus());
        let as_mat = |cols: &[Vec<f64>]| Mat::from_fn(na, cols.len(), |i, j| cols[j][i]);
        // W: the kind-split shapes and controller modes.
        let r = model.n_modes();
        let mut cols: Vec<Vec<f64>> = Vec::new();
        let split = |v: &[f64], kind: usize| -> Vec<f64> {
            (0..na)
                .map(|i| {
                    if usize::from(i >= n) == kind {
                        v[i]
                    } else {
                        0.0
                    }
                })
                .collect()
        };
        for j in 0..r {
            let col: Vec<f64> = (0..na).map(|i| model.phic[(i, j)]).collect();
            cols.push(split(&col, 0));
            cols.push(split(&col, 1));
        }
        for v in null_cols
            .iter()
            .chain(&r2_cols)
            .chain(&r34_cols)
            .chain(std::iter::once(&focus_col))
        {
            cols.push(split(v, 0));
            cols.push(split(v, 1));
        }
        let m = as_mat(&cols);
        let svd = m.thin_svd().map_err(|_| {
            M1Error::InvalidInput("SVD of the global loop's coupled subspace failed".into())
        })?;
        let sv = svd.S().column_vector();
        let smax = (0..sv.nrows()).map(|i| sv[i]).fold(0.0f64, f64::max);
        let keep: Vec<usize> = (0..sv.nrows()).filter(|&i| sv[i] > 1e-10 * smax).collect();
        let u = svd.U();
        let w = Mat::from_fn(na, keep.len(), |i, j| u[(i, keep[j])]);
        // Channels of each kind outside W.
        let dim_kind = |kind: usize| -> usize {
            let rows: Vec<usize> = (0..na).filter(|&i| usize::from(i >= n) == kind).collect();
            let sub = Mat::from_fn(rows.len(), w.ncols(), |i, j| w[(rows[i], j)]);
            sub.singular_values()
                .map(|s| s.iter().filter(|&&x| x > 0.5).count())
                .unwrap_or(rows.len())
        };
        let complement = [dim_kind(0) < n, dim_kind(1) < 2 * n];
        let null = as_mat(&null_cols);
        let radial2 = as_mat(&r2_cols);
        let radial34 = as_mat(&r34_cols);
        let focus = as_mat(std::slice::from_ref(&focus_col));
        let wdim = w.ncols();
        // V = [N R2 R34 psi].
        let v_cols: Vec<&Vec<f64>> = null_cols
            .iter()
            .chain(&r2_cols)
            .chain(&r34_cols)
            .chain(std::iter::once(&focus_col))
            .collect();
        let nv = v_cols.len();
        let vmat = Mat::from_fn(na, nv, |i, j| v_cols[j][i]);
        let cmat = Mat::from_fn(na, wdim + nv, |i, j| {
            if j < wdim {
                w[(i, j)]
            } else {
                vmat[(i, j - wdim)]
            }
        });
        let rows = [(0, n), (n, na - n)];
        let phic = &model.phic;
        let cw = rows.map(|(r0, nr)| cmat.subrows(r0, nr).transpose() * w.subrows(r0, nr));
        let cphi = rows.map(|(r0, nr)| cmat.subrows(r0, nr).transpose() * phic.subrows(r0, nr));
        let phiw = rows.map(|(r0, nr)| phic.subrows(r0, nr).transpose() * w.subrows(r0, nr));
        let wv = w.transpose() * &vmat;
        Ok(Self {
            rate: params.rate,
            gains,
            w,
            null,
            radial2,
            radial34,
            focus,
            complement,
            cw,
            cphi,
            phiw,
            wv,
        })
    }

    /// The loop at `f` (Hz) on `model` (the one the loop was built with).
    ///
    /// # Errors
    /// [`M1Error::Unstable`] if the modal system is singular at `f`, [`M1Error::InvalidInput`]
    /// if an SVD fails.
    pub fn at(&self, model: &FrequencyModel, f: f64) -> Result<GlobalLoopPoint, M1Error> {
        self.at_with_aliases(model, f, 0)
    }

    /// The same, with the sensors' sampling folded in: the loop seen by the controller's
    /// samples is $\frac{1}{z - 1} G \sum_{|k| \le K} T(f + k f_c) \tilde H_c(f + k f_c)$,
    /// exact for the sampled loop as `aliases` (K) grows (the mirror's response falls off
    /// above the servo bandwidth).
    pub fn at_with_aliases(
        &self,
        model: &FrequencyModel,
        f: f64,
        aliases: usize,
    ) -> Result<GlobalLoopPoint, M1Error> {
        self.point(&self.plant(model, f, aliases), &self.gains)
    }

    /// The loop gain on W (in the basis of W) and the scalar loop gain of each kind's
    /// complement (`None` where a kind has no channel outside W), at `f` (Hz) with `aliases`
    /// images of the sensors' sampling.
    pub fn loop_matrix(
        &self,
        model: &FrequencyModel,
        f: f64,
        aliases: usize,
    ) -> (Mat<c64>, [Option<c64>; 2]) {
        self.loop_from_plant(&self.plant(model, f, aliases), &self.gains)
    }

    /// The gain-independent part of the loop at `f`: the mirror's response to the command on
    /// W (summed over `aliases` images), for evaluating many controller gains.
    pub fn plant(&self, model: &FrequencyModel, f: f64, aliases: usize) -> PlantOnW {
        let r = model.n_modes();
        let wdim = self.w.ncols();
        let rows = self.cw[0].nrows();
        let combine = |a: [c64; 2], x: &[Mat<f64>; 2]| {
            Mat::from_fn(x[0].nrows(), x[0].ncols(), |i, j| {
                a[0] * x[0][(i, j)] + a[1] * x[1][(i, j)]
            })
        };
        // [W V]^T T W, summed over the images: the diagonal part plus the coupling
        // through the modes, from the per-kind projections.
        let mut ctw = Mat::<c64>::zeros(rows, wdim);
        // The complement's scalar per kind, summed over the same images.
        let mut t_kind = [c64::new(0.0, 0.0); 2];
        let k_max = i32::try_from(aliases).unwrap_or(i32::MAX);
        for k in -k_max..=k_max {
            let fk = f + f64::from(k) * self.rate;
            let ch = model.channels(fk);
            let h = hold(fk, 1.0 / self.rate);
            ctw += combine([ch[0].mirror[0] * h, ch[1].mirror[0] * h], &self.cw);
            if r > 0 {
                let rhs = combine([ch[0].force[0], ch[1].force[0]], &self.phiw);
                let q = model.modal_stiffness(fk, &ch).partial_piv_lu().solve(&rhs);
                let left = combine([ch[0].mirror[1] * h, ch[1].mirror[1] * h], &self.cphi);
                ctw += left * q;
            }
            for (t, c) in t_kind.iter_mut().zip(&ch) {
                *t += c.mirror[0] * h;
            }
        }
        // W^T T W and the low-rank pieces the gains act through: (W^T B, B^T T W).
        let wtw = Mat::from_fn(wdim, wdim, |i, j| ctw[(i, j)]);
        let (n0, n1, n2) = (
            self.null.ncols(),
            self.radial2.ncols(),
            self.radial34.ncols(),
        );
        let piece = |c0: usize, nc: usize| -> (Mat<c64>, Mat<c64>) {
            (
                Mat::from_fn(wdim, nc, |i, j| c64::new(self.wv[(i, c0 + j)], 0.0)),
                Mat::from_fn(nc, wdim, |i, j| ctw[(wdim + c0 + i, j)]),
            )
        };
        let pieces = [
            piece(0, n0),
            piece(n0, n1),
            piece(n0 + n1, n2),
            piece(n0 + n1 + n2, self.focus.ncols()),
        ];
        PlantOnW {
            frequency: f,
            wtw,
            pieces,
            t_kind,
        }
    }

    /// The loop gain on W and the complement's scalars for the gains `gains`.
    pub fn loop_from_plant(
        &self,
        p: &PlantOnW,
        gains: &crate::control::controller::LoopGains,
    ) -> (Mat<c64>, [Option<c64>; 2]) {
        let g = gains.rest;
        let z = cis(TAU * p.frequency / self.rate);
        let c = c64::new(1.0, 0.0) / (z - c64::new(1.0, 0.0));
        let mut gtw = faer::Scale(c64::new(g, 0.0)) * &p.wtw;
        for ((wb, btw), coef) in
            p.pieces
                .iter()
                .zip([-g, gains.radial2 - g, gains.radial34 - g, gains.focus - g])
        {
            gtw += faer::Scale(c64::new(coef, 0.0)) * (wb * btw);
        }
        let lw = faer::Scale(c) * gtw;
        let scalars = [0, 1].map(|k| self.complement[k].then(|| c * g * p.t_kind[k]));
        (lw, scalars)
    }

    /// Largest singular values of the loop gain and of the sensitivity for `gains`.
    pub fn point(
        &self,
        p: &PlantOnW,
        gains: &crate::control::controller::LoopGains,
    ) -> Result<GlobalLoopPoint, M1Error> {
        let f = p.frequency;
        let (lw, scalars) = self.loop_from_plant(p, gains);
        let wdim = lw.nrows();
        let bad = || M1Error::InvalidInput(format!("SVD of the loop gain failed at {f} Hz"));
        let mut l_max = extreme::largest_singular_value(lw.as_ref()).ok_or_else(bad)?;
        let ident = Mat::<c64>::identity(wdim, wdim);
        let s_inv = &ident + &lw;
        // sigma_max(S) = 1 / sigma_min(I + L).
        let mut s_max = 1.0 / extreme::smallest_singular_value(s_inv.as_ref()).ok_or_else(bad)?;
        for l in scalars.into_iter().flatten() {
            l_max = l_max.max(l.norm());
            s_max = s_max.max(1.0 / (c64::new(1.0, 0.0) + l).norm());
        }
        if !(l_max.is_finite() && s_max.is_finite()) {
            return Err(M1Error::Unstable {
                channel: "global loop",
                spectral_radius: f64::NAN,
                hint: "the mirror's response is singular at this frequency",
            });
        }
        Ok(GlobalLoopPoint {
            frequency_hz: f,
            loop_gain_max: l_max,
            sensitivity_max: s_max,
        })
    }

    /// The loop's sample rate (Hz).
    pub fn rate(&self) -> f64 {
        self.rate
    }
}

/// The mirror's response to the command on the global loop's subspace at one frequency
/// (see [`GlobalLoop::plant`]).
#[derive(Debug, Clone)]
pub struct PlantOnW {
    frequency: f64,
    wtw: Mat<c64>,
    /// (W^T B, B^T T W) for B = N, R2, R34, psi.
    pieces: [(Mat<c64>, Mat<c64>); 4],
    t_kind: [c64; 2],
}

/// The highest global-loop bandwidth meeting the seed paper's criteria, and the loop there.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct BandwidthLimit {
    /// Bandwidth of radial degrees >= 5 (Hz); radial degrees 3-4 get `radial34_ratio` of it,
    /// radial degree 2 `radial2_ratio`.
    pub bandwidth_hz: f64,
    /// Peak sensitivity over the grid at that bandwidth.
    pub peak_sensitivity: f64,
    /// Largest principal loop gain over the high-frequency band at that bandwidth.
    pub high_frequency_loop_gain: f64,
    /// Where that loop gain peaks (Hz).
    pub high_frequency_loop_gain_at_hz: f64,
    /// Which criterion limits it: "sensitivity", "loop gain" or "search range".
    pub limited_by: String,
}

/// Bisects the global-loop bandwidth (radial degrees >= 5; radial degrees 3-4 at
/// `radial34_ratio` of it, radial degree 2 at `radial2_ratio`, focus-mode as in `base`) for
/// the highest one with the sensitivity below `max_sensitivity` on every point of `plants` and
/// the principal loop gain below `max_loop_gain` on those at or above `band_start_hz`, between
/// 0.01 Hz and `upper_hz` (below half the loop rate).
///
/// # Errors
/// From the controller gains and the singular values.
#[allow(clippy::too_many_arguments)]
pub fn highest_bandwidth(
    gl: &GlobalLoop,
    plants: &[PlantOnW],
    base: &crate::control::controller::ControllerParams,
    radial34_ratio: f64,
    radial2_ratio: f64,
    band_start_hz: f64,
    max_sensitivity: f64,
    max_loop_gain: f64,
    upper_hz: f64,
) -> Result<BandwidthLimit, M1Error> {
    let eval = |b: f64| -> Result<(f64, f64, f64), M1Error> {
        let params = crate::control::controller::ControllerParams {
            bandwidth: b,
            bandwidth_radial34: radial34_ratio * b,
            bandwidth_radial2: radial2_ratio * b,
            ..*base
        };
        let gains = params.gains()?;
        let (mut s, mut l, mut at) = (0.0f64, 0.0f64, f64::NAN);
        for p in plants {
            let pt = gl.point(p, &gains)?;
            s = s.max(pt.sensitivity_max);
            if p.frequency >= band_start_hz && pt.loop_gain_max > l {
                l = pt.loop_gain_max;
                at = p.frequency;
            }
        }
        Ok((s, l, at))
    };
    let ok = |(s, l, _): (f64, f64, f64)| s <= max_sensitivity && l <= max_loop_gain;
    let (mut lo, mut hi) = (0.01, upper_hz.min(0.49 * base.rate));
    let top = eval(hi)?;
    if ok(top) {
        return Ok(BandwidthLimit {
            bandwidth_hz: hi,
            peak_sensitivity: top.0,
            high_frequency_loop_gain: top.1,
            high_frequency_loop_gain_at_hz: top.2,
            limited_by: "search range".into(),
        });
    }
    let mut best = eval(lo)?;
    for _ in 0..24 {
        let mid = 0.5 * (lo + hi);
        let e = eval(mid)?;
        if ok(e) {
            lo = mid;
            best = e;
        } else {
            hi = mid;
        }
        if hi - lo < 1e-3 {
            break;
        }
    }
    let at_hi = eval(hi)?;
    Ok(BandwidthLimit {
        bandwidth_hz: lo,
        peak_sensitivity: best.0,
        high_frequency_loop_gain: best.1,
        high_frequency_loop_gain_at_hz: best.2,
        limited_by: if at_hi.0 > max_sensitivity {
            "sensitivity".into()
        } else {
            "loop gain".into()
        },
    })
}
