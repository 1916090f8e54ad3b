//! The tabulated wind loads of every segment in frozen flow.

use super::spectrum::real_inverse_fft_rows;
use super::*;
use crate::linalg::cache::{Fingerprint, Store};
use crate::linalg::interpolation::periodic_stencil;

/// Tabulated wind loads of every segment over one screen period of frozen flow.
#[derive(Debug, Clone)]
pub struct WindLoads {
    /// The tables, for a unit rms pressure (shared: [`WindLoads::with_flow`] reuses them).
    screen: std::sync::Arc<UnitScreen>,
    speed: f64,
    pressure_rms: f64,
}

/// What the loads of a screen of unit rms pressure are made of (the screen is linear in its rms
/// pressure, which scales them at the end).
#[derive(Debug)]
pub(super) struct UnitScreen {
    samples: usize,
    spacing: f64,
    /// (cos theta, sin theta).
    direction: [f64; 2],
    /// Segment centre along the flow, in samples.
    along: Vec<f64>,
    /// Wind-frame integrals `[G_0, G_xi, G_eta]` -> `Q = [F, M_alpha, M_beta]`, per segment.
    to_load: Vec<[[f64; 3]; 3]>,
    /// Wind-frame integrals -> actuator forces (`P^-T` times `to_load`), per segment.
    to_forces: Vec<[[f64; 3]; 3]>,
    /// `tables[3 (i N + n) + q]`: integral `q` of segment `i` with the screen shifted by
    /// `(along_i - n) dx`. The three integrals of a sample are adjacent, so that a step reads
    /// each segment's four samples around its position in one or two cache lines.
    tables: Vec<f64>,
    /// Expected rms of `G_0`.
    force_rms: f64,
    area: f64,
}

impl WindLoads {
    /// Synthesises the screen and tabulates every segment's loads.
    ///
    /// Fails with [`M1Error::InvalidParameter`] for a bad screen ([`ScreenParams::check`]), a
    /// negative or non-finite speed, a non-finite direction, or a screen narrower than the
    /// mirror (`size` must exceed `2 max|c| + 2 a`: across the flow the screen repeats too).
    ///
    /// The tables are those of the screen of unit rms pressure (the screen is linear in
    /// `pressure_rms`), and the integrals read from them are scaled by it: so
    /// [`WindLoads::with_flow`] gives for another speed or rms pressure exactly what `new`
    /// gives.
    pub fn new(geometry: &Geometry, params: &WindParams) -> Result<WindLoads, M1Error> {
        Self::new_in(geometry, params, &Store::from_env())
    }

    /// [`WindLoads::new`] with the tables from (or into) the cache `store` (the on-disk cache
    /// of [`crate::linalg::cache`]; [`WindLoads::new`] takes the environment's).
    ///
    /// # Errors
    /// As [`WindLoads::new`].
    pub fn new_in(
        geometry: &Geometry,
        params: &WindParams,
        store: &Store,
    ) -> Result<WindLoads, M1Error> {
        params.screen.check()?;
        let unit = ScreenParams {
            pressure_rms: 1.0,
            ..params.screen.clone()
        };
        let sp = &unit;
        if !(params.speed.is_finite() && params.speed >= 0.0) {
            return Err(invalid(
                "wind_speed",
                params.speed,
                "must be finite and >= 0",
            ));
        }
        if !params.direction.is_finite() {
            return Err(invalid(
                "wind_direction",
                params.direction,
                "must be finite",
            ));
        }
        let layout = &geometry.layout;
        let nseg = layout.n_segments();
        let a = layout.circumradius;
        let extent = layout
            .segments
            .iter()
            .map(|s| s.center[0].hypot(s.center[1]))
            .fold(0.0, f64::max);
        if sp.size <= 2.0 * (extent + a) {
            return Err(invalid(
                "screen_size",
                sp.size,
                "must exceed the mirror's diameter (2 max|centre| + 2 a): the screen repeats across the flow",
            ));
        }
        let n = sp.samples;
        let dx = sp.spacing();
        let theta = params.direction.to_radians();
        let (sin, cos) = theta.sin_cos();
        let to_wind = |p: [f64; 2]| [cos * p[0] + sin * p[1], -sin * p[0] + cos * p[1]];

        // The hexagon relative to its centre, in the wind frame (counter-clockwise).
        let c0 = layout.segments[0].center;
        let corners = layout.vertices(0).ok_or(M1Error::SizeMismatch {
            what: "layout segments",
            expected: 1,
            found: 0,
        })?;
        let mut hexagon: Vec<[f64; 2]> = corners
            .iter()
            .map(|v| to_wind([v[0] - c0[0], v[1] - c0[1]]))
            .collect();
        let (area, _) = polygon_moments(&hexagon);
        if area < 0.0 {
            hexagon.reverse();
        }
        let area = area.abs();

        // Segment positions in the wind frame, in samples.
        let centres: Vec<[f64; 2]> = layout.segments.iter().map(|s| to_wind(s.center)).collect();
        let along: Vec<f64> = centres.iter().map(|c| c[0] / dx).collect();
        // The tables and the expected variance: from the cache when an earlier run made them
        // for the same screen and segments, else synthesised.
        let mut key = Fingerprint::new("wind");
        key.bytes(
            serde_json::to_string(sp)
                .map_err(|e| M1Error::Numerical(format!("wind cache key: {e}")))?
                .as_bytes(),
        )
        .usizes(&[n, nseg])
        .f64s(&[dx, cos, sin]);
        for p in hexagon.iter().chain(&centres) {
            key.f64s(p);
        }
        let cached = store
            .load(&key, &["variance", "tables"])
            .filter(|a| a[0].data.len() == 1 && a[1].shape == [3 * nseg * n]);
        let (variance, tables) = match cached {
            Some(mut a) => {
                let tables = a.pop().map(|t| t.data).unwrap_or_default();
                (a[0].data[0], tables)
            }
            None => {
                let (variance, tables) = synthesise(sp, &hexagon, &centres, dx);
                store.store(
                    &key,
                    &[
                        ("variance", &[], &[variance]),
                        ("tables", &[3 * nseg * n], &tables),
                    ],
                );
                (variance, tables)
            }
        };

        // Wind-frame integrals -> generalised forces -> actuator forces.
        let mut to_load = Vec::with_capacity(nseg);
        let mut to_forces = Vec::with_capacity(nseg);
        for i in 0..nseg {
            let s = &geometry.segments[i];
            let g = 1.0 / s.normal[2];
            let rad = unit2([s.radial[0], s.radial[1]]);
            let az = unit2([s.azimuthal[0], s.azimuthal[1]]);
            let (rad, az) = (to_wind(rad), to_wind(az));
            let b = [
                [-g, 0.0, 0.0],
                [0.0, -g * az[0], -g * az[1]],
                [0.0, g * g * rad[0], g * g * rad[1]],
            ];
            let pinv = geometry.ptt_inverse(i);
            let m: [[f64; 3]; 3] = std::array::from_fn(|k| {
                std::array::from_fn(|col| (0..3).map(|j| pinv[j][k] * b[j][col]).sum())
            });
            to_load.push(b);
            to_forces.push(m);
        }

        let screen = std::sync::Arc::new(UnitScreen {
            samples: n,
            spacing: dx,
            direction: [cos, sin],
            along,
            to_load,
            to_forces,
            tables,
            force_rms: variance.sqrt(),
            area,
        });
        WindLoads {
            screen,
            speed: 0.0,
            pressure_rms: 0.0,
        }
        .with_flow(params.speed, params.screen.pressure_rms)
    }

    /// The same screen and direction at another wind `speed` (m/s, finite, >= 0) and rms
    /// pressure `pressure_rms` (Pa, finite, >= 0), sharing the tables: identical to
    /// [`WindLoads::new`] with those values (a sweep over wind speed builds the screen once).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] for a bad speed or rms pressure.
    pub fn with_flow(&self, speed: f64, pressure_rms: f64) -> Result<WindLoads, M1Error> {
        if !(speed.is_finite() && speed >= 0.0) {
            return Err(invalid("wind_speed", speed, "must be finite and >= 0"));
        }
        if !(pressure_rms.is_finite() && pressure_rms >= 0.0) {
            return Err(invalid(
                "pressure_rms",
                pressure_rms,
                "must be finite and >= 0",
            ));
        }
        Ok(WindLoads {
            screen: self.screen.clone(),
            speed,
            pressure_rms,
        })
    }

    /// Mean wind speed (m/s).
    pub fn speed(&self) -> f64 {
        self.speed
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.screen.along.len()
    }

    /// Number of actuators (3 per segment).
    pub fn n_actuators(&self) -> usize {
        3 * self.screen.along.len()
    }

    /// Screen spacing `dx` (m): the shift between table entries.
    pub fn spacing(&self) -> f64 {
        self.screen.spacing
    }

    /// Time after which the flow repeats, `L / U` (s); None for `U = 0`.
    pub fn period(&self) -> Option<f64> {
        (self.speed > 0.0).then(|| self.screen.samples as f64 * self.screen.spacing / self.speed)
    }

    /// Area of a segment's hexagon in the aperture plane (m^2).
    pub fn segment_area(&self) -> f64 {
        self.screen.area
    }

    /// The rms pressure `sigma_p` (Pa).
    pub fn pressure_rms(&self) -> f64 {
        self.pressure_rms
    }

    /// Expected rms of `int_Hex p dA` over the aperture-plane hexagon (N):
    /// `sqrt(sum_k Phi_d(k) |H(k)|^2)`; compare with `sigma_p A` for the aperture attenuation.
    pub fn expected_force_rms(&self) -> f64 {
        self.pressure_rms * self.screen.force_rms
    }

    /// Bytes held by the tables and maps.
    pub fn memory_bytes(&self) -> usize {
        8 * (self.screen.tables.len() + self.screen.along.len() + 18 * self.screen.to_load.len())
    }

    /// Wind-frame integrals `[G_0, G_xi, G_eta]` of segment `i` at time `t` (the unit screen's,
    /// times the rms pressure).
    fn wind_integrals(&self, i: usize, t: f64) -> [f64; 3] {
        self.integrals_at(i, &self.stencil(i, self.shift(t)))
    }

    /// How far the screen has moved along the flow at time `t`, in samples, brought within one
    /// period (`[0, samples]`: the remainder can round up to `samples`) once per call, so that
    /// each segment's position stays within a period or two of the table's range, where its
    /// stencil wraps by adding the period ([`periodic_stencil`]) instead of taking a remainder
    /// per segment: that `fmod` cost the TMT forces 4 us per call, a third of them, once a run
    /// had gone past the screen's first period (128 s at 1 m/s, 12.8 s at 10 m/s with the
    /// default 128 m screen). Within the first period it is the plain ratio, unchanged.
    #[inline]
    fn shift(&self, t: f64) -> f64 {
        let (s, n) = (
            self.speed * t / self.screen.spacing,
            self.screen.samples as f64,
        );
        if (0.0..n).contains(&s) {
            s
        } else {
            s.rem_euclid(n)
        }
    }

    /// The four table samples of segment `i` around its position with the screen moved by
    /// `shift` samples ([`Self::shift`]), and their weights.
    #[inline]
    fn stencil(&self, i: usize, shift: f64) -> ([usize; 4], [f64; 4]) {
        let u = self.screen.along[i] - shift;
        periodic_stencil(u, self.screen.samples)
    }

    /// [`Self::wind_integrals`] of segment `i` from its stencil.
    #[inline]
    fn integrals_at(&self, i: usize, (idx, w): &([usize; 4], [f64; 4])) -> [f64; 3] {
        let n = self.screen.samples;
        let tab = &self.screen.tables[3 * i * n..3 * (i + 1) * n];
        std::array::from_fn(|q| {
            self.pressure_rms
                * idx
                    .iter()
                    .zip(w)
                    .map(|(&j, wj)| wj * tab[3 * j + q])
                    .sum::<f64>()
        })
    }

    /// `[int p dA, int p (x - c_x) dA, int p (y - c_y) dA]` over segment `i`'s hexagon in the
    /// aperture plane at time `t` (N, N.m), in the layout's axes (p the front-face pressure).
    ///
    /// # Panics
    /// If `i >= n_segments()`.
    pub fn integrals(&self, i: usize, t: f64) -> [f64; 3] {
        let [g0, g1, g2] = self.wind_integrals(i, t);
        let [c, s] = self.screen.direction;
        [g0, c * g1 - s * g2, s * g1 + c * g2]
    }

    /// Generalised load `[F, M_alpha, M_beta]` on segment `i` at time `t`: the normal force
    /// (N, along `+normal`) and the moments (N.m) about its radial and azimuthal axes.
    ///
    /// # Panics
    /// If `i >= n_segments()`.
    pub fn segment_load(&self, i: usize, t: f64) -> [f64; 3] {
        let g = self.wind_integrals(i, t);
        let b = &self.screen.to_load[i];
        std::array::from_fn(|r| (0..3).map(|c| b[r][c] * g[c]).sum())
    }

    /// Equivalent forces at every actuator at time `t` (N, along each segment's normal;
    /// actuator `k` of segment `i` at `3 i + k`).
    pub fn forces(&self, t: f64, out: &mut [f64]) -> Result<(), M1Error> {
        if out.len() != self.n_actuators() {
            return Err(M1Error::SizeMismatch {
                what: "f_wind",
                expected: self.n_actuators(),
                found: out.len(),
            });
        }
        // By chunks of segments: first their stencils, each with a load of the first and the
        // last table entry it reads, then their forces. The loads do not depend on each other,
        // so their cache misses overlap (the TMT tables, 12 MB, are mostly out of the caches by
        // the next 100 Hz step: one segment at a time, each miss was waited for in turn).
        let n = self.screen.samples;
        let tables = &self.screen.tables;
        let mut stencils = [([0usize; 4], [0.0f64; 4]); FORCE_CHUNK];
        let shift = self.shift(t);
        for (c, fc) in out.chunks_mut(3 * FORCE_CHUNK).enumerate() {
            let first = c * FORCE_CHUNK;
            let mut touch = 0.0;
            for (k, st) in stencils[..fc.len() / 3].iter_mut().enumerate() {
                let i = first + k;
                *st = self.stencil(i, shift);
                touch += tables[3 * (i * n + st.0[0])] + tables[3 * (i * n + st.0[3]) + 2];
            }
            std::hint::black_box(touch);
            for (k, f) in fc.chunks_exact_mut(3).enumerate() {
                let i = first + k;
                let g = self.integrals_at(i, &stencils[k]);
                let m = &self.screen.to_forces[i];
                for (k, fk) in f.iter_mut().enumerate() {
                    *fk = m[k][0] * g[0] + m[k][1] * g[1] + m[k][2] * g[2];
                }
            }
        }
        Ok(())
    }
}

/// Segments per chunk of [`WindLoads::forces`].
const FORCE_CHUNK: usize = 32;

pub(super) fn unit2(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    if n > 0.0 {
        [v[0] / n, v[1] / n]
    } else {
        [1.0, 0.0]
    }
}

/// The screen's filtered spectra turned into every segment's tables (`3 nseg n` values: the
/// integrals of the unit screen over the hexagon at each sample along the flow) and the
/// expected variance of `G_0`: the random draws of the spectrum, the hexagon's transform at
/// every wavenumber, and two inverse 2-D FFTs (the first two fields packed in one), finished
/// only at the grid rows the segments read. `sp` has passed [`ScreenParams::check`].
fn synthesise(
    sp: &ScreenParams,
    hexagon: &[[f64; 2]],
    centres: &[[f64; 2]],
    dx: f64,
) -> (f64, Vec<f64>) {
    let n = sp.samples;
    let nseg = centres.len();
    // Filtered spectra: c H, c H_xi, c H_eta; and the expected variance of G_0.
    let psd = sp.discrete_psd();
    let spectrum = ScreenSpectrum::drawn(sp, &psd);
    let k: Vec<f64> = (0..n).map(|i| psd.wavenumber(i)).collect();
    let grid = PolygonGrid::new(hexagon, &k, &k);
    let mut b0 = spectrum.coefficients;
    let mut b1 = vec![Complex64::ZERO; n * n];
    let mut b2 = vec![Complex64::ZERO; n * n];
    // Per row in parallel, then summed in row order (the same sum whatever the threads).
    let per_row: Vec<f64> = b0
        .par_chunks_mut(n)
        .zip(b1.par_chunks_mut(n))
        .zip(b2.par_chunks_mut(n))
        .enumerate()
        .map(|(iy, ((r0, r1), r2))| {
            let mut var = 0.0;
            for ix in 0..n {
                let c = r0[ix];
                if c == Complex64::ZERO {
                    continue;
                }
                let [h, hx, hy] = grid.at(ix, iy);
                var += psd.bin(ix, iy) * h.norm_sqr();
                r0[ix] = c * h;
                r1[ix] = c * hx;
                r2[ix] = c * hy;
            }
            var
        })
        .collect();
    let variance: f64 = per_row.iter().sum();

    // The rows of the grid the segments' stencils read, each transformed once.
    let stencils: Vec<([usize; 4], [f64; 4])> = centres
        .iter()
        .map(|c| periodic_stencil(c[1] / dx, n))
        .collect();
    let mut rows: Vec<usize> = stencils.iter().flat_map(|(r, _)| *r).collect();
    rows.sort_unstable();
    rows.dedup();
    let mut tables = vec![0.0; 3 * nseg * n];
    let mut fill = |q: usize, buf: &[Complex64], part: fn(&Complex64) -> f64| {
        for (i, (rs, w)) in stencils.iter().enumerate() {
            let out = &mut tables[3 * i * n..3 * (i + 1) * n];
            for (r, wr) in rs.iter().zip(w) {
                let row = &buf[r * n..(r + 1) * n];
                for (o, v) in out.chunks_exact_mut(3).zip(row) {
                    o[q] += wr * SQRT_2 * part(v);
                }
            }
        }
    };
    let g01 = real_inverse_fft_rows(&b0, Some(&b1), n, &rows);
    drop((b0, b1));
    fill(0, &g01, |v| v.re);
    fill(1, &g01, |v| v.im);
    drop(g01);
    let g2 = real_inverse_fft_rows(&b2, None, n, &rows);
    fill(2, &g2, |v| v.re);
    (variance, tables)
}
