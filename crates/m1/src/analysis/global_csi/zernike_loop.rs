//! The global loop of a mirror on its structure in the Zernike bases and with all segments
//! ([`GlobalCsi`]): the per-kind projections formed once, the Zernike plant and loop at a
//! frequency, the peak labels, and every basis's extremes at one frequency ([`GlobalPoint`]).

use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use serde::Serialize;
use std::f64::consts::TAU;

use super::{GlobalQuantity, N_VECTORS};
use crate::M1Error;
use crate::analysis::csi::ZernikeChannels;
use crate::aperture::geometry::Geometry;
use crate::aperture::layout::Layout;
use crate::control::controller::{ControlModes, ControllerParams, LoopGains, N_RADIAL34};
use crate::linalg::extreme;
use crate::plant::monolithic::{FrequencyModel, GlobalLoop, PlantOnW, hold};

/// The global loop of a mirror on its structure, with its Zernike bases.
#[derive(Debug, Clone)]
pub struct GlobalCsi {
    pub(super) fm: FrequencyModel,
    zc: ZernikeChannels,
    pub(super) params: ControllerParams,
    pub(super) gl: GlobalLoop,
    /// Orthonormal Zernike columns per degree (prefix sizes).
    pub(super) prefix: Vec<usize>,
    /// Per kind (piston, tilt): `C_k^T B_k` ((nb + 15) x nb), `C_k^T Phi_k` ((nb + 15) x r),
    /// `Phi_k^T B_k` (r x nb).
    ctb: [Mat<f64>; 2],
    ctphi: [Mat<f64>; 2],
    phitb: [Mat<f64>; 2],
    /// `B^T v` for the fifteen controller vectors (nb x 15): N (3), R2 (2), R34 (9), psi (1).
    btv: Mat<f64>,
    pub(super) aliases: usize,
}

/// One frequency of every basis.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GlobalPoint {
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// $\sigma_{max}(L)$ per Zernike degree.
    pub zernike_loop_gain: Vec<f64>,
    /// $\sigma_{max}(S)$ per Zernike degree.
    pub zernike_sensitivity: Vec<f64>,
    /// $\sigma_{max}(L)$ with all segments.
    pub loop_gain: f64,
    /// $\sigma_{max}(S)$ with all segments.
    pub sensitivity: f64,
}

fn c(x: f64) -> c64 {
    c64::new(x, 0.0)
}

/// `a0 x0 + a1 x1` for real matrices and complex scalars.
fn combine(a: [c64; 2], x: &[Mat<f64>; 2]) -> Mat<c64> {
    Mat::from_fn(x[0].nrows(), x[0].ncols(), |i, j| {
        a[0] * x[0][(i, j)] + a[1] * x[1][(i, j)]
    })
}

/// $1 / (e^{i 2 \pi f / f_c} - 1)$, the discrete integrator.
pub(super) fn integrator(f: f64, rate: f64) -> c64 {
    let z = c64::new((TAU * f / rate).cos(), (TAU * f / rate).sin());
    c(1.0) / (z - c(1.0))
}

/// `(sigma_max(M), 1 / sigma_min(I + M))` of the leading `n x n` block.
pub(super) fn extremes(m: &Mat<c64>, n: usize, f: f64) -> Result<(f64, f64), M1Error> {
    if n == 0 {
        return Ok((0.0, 0.0));
    }
    let bad = || M1Error::Numerical(format!("SVD of the global loop failed at {f} Hz"));
    let a = m.as_ref().submatrix(0, 0, n, n);
    let l = extreme::largest_singular_value(a).ok_or_else(bad)?;
    let b = Mat::from_fn(n, n, |i, j| {
        m[(i, j)] + if i == j { c(1.0) } else { c(0.0) }
    });
    let s = 1.0 / extreme::smallest_singular_value(b.as_ref()).ok_or_else(bad)?;
    if l.is_finite() && s.is_finite() {
        Ok((l, s))
    } else {
        Err(M1Error::Unstable {
            channel: "global loop",
            spectral_radius: f64::NAN,
            hint: "the return difference is singular at this frequency",
        })
    }
}

impl GlobalCsi {
    /// The global loop of `params` on `fm`'s mirror (`layout`, `geometry`), with Zernike bases
    /// up to `max_degree` and `aliases` images of the sampling on each side.
    ///
    /// # Errors
    /// From the controller parameters, the Zernike basis or the geometry.
    pub fn new(
        fm: FrequencyModel,
        layout: &Layout,
        geometry: &Geometry,
        params: ControllerParams,
        max_degree: u32,
        aliases: usize,
    ) -> Result<Self, M1Error> {
        params.gains()?;
        let controls = ControlModes::new(geometry.clone())?;
        let gl = GlobalLoop::new(&fm, &controls, &params)?;
        let zc = ZernikeChannels::new(&fm, layout, geometry, max_degree)?;
        let n = fm.n_segments();
        let na = fm.n_actuators();
        let nb = zc.basis.ncols();
        let chan = |a: &[f64]| -> Vec<f64> {
            let v: Vec<c64> = a.iter().map(|&x| c(x)).collect();
            fm.to_channels(&v).iter().map(|x| x.re).collect()
        };
        let nsp = controls.null_space();
        let mut vecs: Vec<Vec<f64>> = (0..nsp.ncols())
            .map(|j| chan(&(0..na).map(|i| nsp[(i, j)]).collect::<Vec<_>>()))
            .collect();
        vecs.extend(controls.radial2().iter().map(|v| chan(v)));
        vecs.extend(controls.radial34().iter().map(|v| chan(v)));
        vecs.push(chan(controls.focus()));
        if vecs.len() != N_VECTORS {
            return Err(M1Error::SizeMismatch {
                what: "controller vectors (3 null-space, 2 astigmatism, 9 radial degrees 3-4, \
                       1 focus-mode)",
                expected: N_VECTORS,
                found: vecs.len(),
            });
        }
        let cmat = Mat::from_fn(na, nb + N_VECTORS, |i, j| {
            if j < nb {
                zc.basis[(i, j)]
            } else {
                vecs[j - nb][i]
            }
        });
        let phic = fm.channel_shapes();
        let rows = [(0, n), (n, na - n)];
        let ctb = rows.map(|(r0, nr)| cmat.subrows(r0, nr).transpose() * zc.basis.subrows(r0, nr));
        let ctphi = rows.map(|(r0, nr)| cmat.subrows(r0, nr).transpose() * phic.subrows(r0, nr));
        let phitb =
            rows.map(|(r0, nr)| phic.subrows(r0, nr).transpose() * zc.basis.subrows(r0, nr));
        let btv = Mat::from_fn(nb, N_VECTORS, |i, j| {
            (0..na).map(|a| zc.basis[(a, i)] * vecs[j][a]).sum()
        });
        Ok(Self {
            fm,
            params,
            gl,
            prefix: zc.prefix.clone(),
            zc,
            ctb,
            ctphi,
            phitb,
            btv,
            aliases,
        })
    }

    /// The frequency model.
    pub fn model(&self) -> &FrequencyModel {
        &self.fm
    }

    /// Number of orthonormal Zernike vectors up to each radial degree.
    pub fn zernike_sizes(&self) -> &[usize] {
        &self.prefix
    }

    /// `C^T T B` ((nb + 15) x nb) at `f` (Hz), summed over the images.
    fn zernike_plant(&self, f: f64) -> Result<Mat<c64>, M1Error> {
        let rate = self.params.rate;
        let (rows, nb) = (self.ctb[0].nrows(), self.ctb[0].ncols());
        let mut acc = Mat::<c64>::zeros(rows, nb);
        let r = self.fm.n_modes();
        let kmax = i64::try_from(self.aliases).unwrap_or(i64::MAX);
        for k in -kmax..=kmax {
            let fk = f + k as f64 * rate;
            let ch = self.fm.channels(fk);
            let h = hold(fk, 1.0 / rate);
            acc += combine([ch[0].mirror[0] * h, ch[1].mirror[0] * h], &self.ctb);
            if r > 0 {
                let rhs = combine([ch[0].force[0], ch[1].force[0]], &self.phitb);
                let x = self
                    .fm
                    .modal_stiffness(fk, &ch)
                    .partial_piv_lu()
                    .solve(&rhs);
                if x.col_iter()
                    .any(|cl| cl.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())))
                {
                    return Err(M1Error::Unstable {
                        channel: "global loop",
                        spectral_radius: f64::NAN,
                        hint: "the mirror's modal system is singular at this frequency",
                    });
                }
                let left = combine([ch[0].mirror[1] * h, ch[1].mirror[1] * h], &self.ctphi);
                acc += left * x;
            }
        }
        Ok(acc)
    }

    /// The Zernike loop gain (nb x nb) at `f` for `gains`, from the plant.
    pub(super) fn zernike_loop(&self, f: f64, p: &Mat<c64>, gains: &LoopGains) -> Mat<c64> {
        let nb = p.ncols();
        let g = gains.rest;
        // gamma_v = g_group(v) - g for N, R2, R34, psi in the order of btv's columns.
        let mut coef = [-g; N_VECTORS];
        coef[3..5].fill(gains.radial2 - g);
        coef[5..5 + N_RADIAL34].fill(gains.radial34 - g);
        coef[N_VECTORS - 1] = gains.focus - g;
        let cf = integrator(f, self.params.rate);
        Mat::from_fn(nb, nb, |i, j| {
            let mut x = p[(i, j)] * g;
            for (v, cv) in coef.iter().enumerate() {
                x += p[(nb + v, j)] * (self.btv[(i, v)] * cv);
            }
            x * cf
        })
    }

    /// The dominant Zernike mode at `f` (Hz) of `quantity` in the Zernike basis of radial
    /// degree `degree`, with the analysed controller: `(label, Noll index)`.
    ///
    /// # Errors
    /// As [`Self::point`]; [`M1Error::InvalidParameter`] for a degree beyond the basis.
    pub fn peak_label(
        &self,
        f: f64,
        degree: u32,
        quantity: GlobalQuantity,
    ) -> Result<(String, usize), M1Error> {
        let gains = self.params.gains()?;
        let pz = self.zernike_plant(f)?;
        self.label_from_plant(f, &pz, &gains, degree, quantity)
    }

    /// [`Self::peak_label`] from the Zernike plant at `f`.
    pub(super) fn label_from_plant(
        &self,
        f: f64,
        pz: &Mat<c64>,
        gains: &LoopGains,
        degree: u32,
        quantity: GlobalQuantity,
    ) -> Result<(String, usize), M1Error> {
        let nb = *self
            .prefix
            .get(degree as usize)
            .ok_or(M1Error::InvalidParameter {
                name: "degree",
                value: f64::from(degree),
                reason: "beyond the largest Zernike degree of the analysis",
            })?;
        let lz = self.zernike_loop(f, pz, gains);
        let one = if quantity == GlobalQuantity::Sensitivity {
            1.0
        } else {
            0.0
        };
        let a = Mat::from_fn(nb, nb, |i, j| {
            lz[(i, j)] + if i == j { c(one) } else { c(0.0) }
        });
        let svd = a
            .svd()
            .map_err(|_| M1Error::Numerical(format!("SVD of the global loop failed at {f} Hz")))?;
        let sv = svd.S().column_vector();
        let order = |x: &usize, y: &usize| sv[*x].re.total_cmp(&sv[*y].re);
        // S_B = V Sigma^-1 U^H for I + L_B = U Sigma V^H: its top left singular vector is V's
        // column of the smallest singular value; L_B's is U's column of the largest.
        let u: Vec<c64> = match quantity {
            GlobalQuantity::Sensitivity => {
                let k = (0..nb).min_by(order).unwrap_or(0);
                (0..nb).map(|i| svd.V()[(i, k)]).collect()
            }
            GlobalQuantity::LoopGain => {
                let k = (0..nb).max_by(order).unwrap_or(0);
                (0..nb).map(|i| svd.U()[(i, k)]).collect()
            }
        };
        Ok(self.zc.dominant(&u, degree))
    }

    /// Every basis at `f` (Hz) with the analysed controller, and the all-segment plant (for
    /// bandwidth searches).
    ///
    /// # Errors
    /// [`M1Error::Unstable`] at a singular point, [`M1Error::Numerical`] if an SVD fails.
    pub fn point(&self, f: f64) -> Result<(GlobalPoint, PlantOnW), M1Error> {
        self.point_with_plants(f).map(|(p, a, _)| (p, a))
    }

    pub(super) fn point_with_plants(
        &self,
        f: f64,
    ) -> Result<(GlobalPoint, PlantOnW, Mat<c64>), M1Error> {
        let gains = self.params.gains()?;
        let pz = self.zernike_plant(f)?;
        let lz = self.zernike_loop(f, &pz, &gains);
        let mut zl = Vec::with_capacity(self.prefix.len());
        let mut zs = Vec::with_capacity(self.prefix.len());
        for &nb in &self.prefix {
            let (l, s) = extremes(&lz, nb, f)?;
            zl.push(l);
            zs.push(s);
        }
        let plant = self.gl.plant(&self.fm, f, self.aliases);
        let all = self.gl.point(&plant, &gains)?;
        Ok((
            GlobalPoint {
                frequency_hz: f,
                zernike_loop_gain: zl,
                zernike_sensitivity: zs,
                loop_gain: all.loop_gain_max,
                sensitivity: all.sensitivity_max,
            },
            plant,
            pz,
        ))
    }
}
