//! The nested Zernike bases of the analysis in channel space ([`ZernikeChannels`]: Gram–Schmidt
//! in Noll order, with the triangular factor to read a pattern back in Zernike coefficients)
//! and the family labels of the peaks ([`family_label`]).

use faer::{Mat, c64};

use crate::M1Error;
use crate::aperture::geometry::Geometry;
use crate::aperture::layout::Layout;
use crate::aperture::zernike::{ZernikeBasis, modes_up_to_degree, noll_to_nm};
use crate::optics::metrics::ptt_to_actuators;
use crate::plant::monolithic::FrequencyModel;

/// Which family a Zernike peak belongs to (see the module documentation).
pub fn family_label(noll: usize, piston_share: f64) -> String {
    let (n, m) = noll_to_nm(noll);
    if m == 0 && (n == 0 || piston_share > 0.5) {
        "P".into()
    } else if m.abs() == 1 {
        "TT".into()
    } else if n == 2 {
        "FA".into()
    } else {
        format!("Z{noll}")
    }
}

/// Nested Zernike bases in channel space.
#[derive(Debug, Clone)]
pub(crate) struct ZernikeChannels {
    /// Orthonormal columns (na x kept).
    pub(crate) basis: Mat<f64>,
    /// Noll index of each kept column.
    pub(crate) kept: Vec<usize>,
    /// Upper-triangular factor: kept Zernike column `i` = `basis * r[:, i]` (kept x kept).
    pub(crate) r: Mat<f64>,
    /// Number of kept columns up to each radial degree `0..=max`.
    pub(crate) prefix: Vec<usize>,
    /// Share of each Noll mode's actuator pattern (norm squared) in the piston channels.
    pub(crate) piston_share: Vec<f64>,
}

impl ZernikeChannels {
    pub(crate) fn new(
        fm: &FrequencyModel,
        layout: &Layout,
        geometry: &Geometry,
        max_degree: u32,
    ) -> Result<Self, M1Error> {
        let n = fm.n_segments();
        let na = fm.n_actuators();
        let zb = ZernikeBasis::up_to_degree(layout, max_degree)?;
        let nz = zb.n_modes();
        let mut cols: Vec<Vec<f64>> = Vec::with_capacity(nz);
        let mut piston_share = Vec::with_capacity(nz);
        for j in 1..=nz {
            let ptt = zb.mode(j).ok_or_else(|| {
                M1Error::InvalidInput(format!("Zernike mode {j} missing from the basis"))
            })?;
            let a: Vec<c64> = ptt_to_actuators(geometry, &ptt)?
                .into_iter()
                .map(|x| c64::new(x, 0.0))
                .collect();
            let ch: Vec<f64> = fm.to_channels(&a).iter().map(|x| x.re).collect();
            let total: f64 = ch.iter().map(|x| x * x).sum();
            let pist: f64 = ch[..n].iter().map(|x| x * x).sum();
            piston_share.push(if total > 0.0 { pist / total } else { 0.0 });
            cols.push(ch);
        }
        // Gram-Schmidt, twice, in Noll order.
        let mut q: Vec<Vec<f64>> = Vec::new();
        let mut kept = Vec::new();
        let mut rcols: Vec<Vec<f64>> = Vec::new();
        let mut prefix = vec![0; max_degree as usize + 1];
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        for (idx, col) in cols.iter().enumerate() {
            let j = idx + 1;
            let norm0 = dot(col, col).sqrt();
            let mut v = col.clone();
            let mut coef = vec![0.0; q.len()];
            for _ in 0..2 {
                for (c, qi) in coef.iter_mut().zip(&q) {
                    let d = dot(qi, &v);
                    *c += d;
                    for (x, y) in v.iter_mut().zip(qi) {
                        *x -= d * y;
                    }
                }
            }
            let nv = dot(&v, &v).sqrt();
            if norm0 > 0.0 && nv > 1e-9 * norm0 {
                for x in &mut v {
                    *x /= nv;
                }
                coef.push(nv);
                q.push(v);
                kept.push(j);
                rcols.push(coef);
            }
            let (deg, _) = noll_to_nm(j);
            for p in prefix.iter_mut().skip(deg as usize) {
                *p = q.len();
            }
        }
        let nk = q.len();
        let basis = Mat::from_fn(na, nk, |i, k| q[k][i]);
        let r = Mat::from_fn(nk, nk, |i, k| rcols[k].get(i).copied().unwrap_or(0.0));
        Ok(Self {
            basis,
            kept,
            r,
            prefix,
            piston_share,
        })
    }

    /// The family and Noll index of the largest Zernike coefficient (in modulus) of the
    /// pattern `basis[.., ..u.len()] u`, among the modes up to radial degree `degree`.
    pub(crate) fn dominant(&self, u: &[c64], degree: u32) -> (String, usize) {
        let nz = modes_up_to_degree(degree);
        let c = self.coefficients(u, nz);
        let j = (0..nz)
            .max_by(|&a, &b| c[a].norm().total_cmp(&c[b].norm()))
            .map_or(1, |i| i + 1);
        (family_label(j, self.piston_share[j - 1]), j)
    }

    /// Zernike coefficients (by Noll index - 1, `nz` of them) of the pattern `basis[.., ..n] u`.
    pub(crate) fn coefficients(&self, u: &[c64], nz: usize) -> Vec<c64> {
        let n = u.len();
        let mut c = vec![c64::new(0.0, 0.0); n];
        // Back substitution with the leading n x n block of r.
        for i in (0..n).rev() {
            let mut s = u[i];
            for (k, ck) in c.iter().enumerate().skip(i + 1) {
                s -= *ck * self.r[(i, k)];
            }
            c[i] = s / self.r[(i, i)];
        }
        let mut out = vec![c64::new(0.0, 0.0); nz];
        for (k, ci) in c.into_iter().enumerate() {
            out[self.kept[k] - 1] = ci;
        }
        out
    }
}
