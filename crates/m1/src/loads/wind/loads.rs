//! The tabulated wind loads of every segment in frozen flow.

use super::spectrum::{inverse_fft_rows, packed};
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
    /// Number of segments.
    segments: usize,
    /// The segments rounded up to a multiple of [`MAX_LANES`]: the length of each per-segment
    /// array below (zeros past the segments), so that a step takes them a whole vector at a time.
    stride: usize,
    /// Segment centre along the flow, in samples.
    along: Vec<f64>,
    /// `floor(along_i)` modulo the samples per side, as a float (an exact integer): where
    /// segment `i`'s table starts in [`UnitScreen::rows`].
    origin: Vec<f64>,
    /// Wind-frame integrals `[G_0, G_xi, G_eta]` -> `Q = [F, M_alpha, M_beta]`, per segment.
    to_load: Vec<[[f64; 3]; 3]>,
    /// Wind-frame integrals -> actuator forces (`P^-T` times `to_load`): entry `(k, c)` of
    /// segment `i` at `to_forces[(3 k + c) stride + i]`, so that a step reads each entry of
    /// consecutive segments as one vector.
    to_forces: Vec<f64>,
    /// The tables, by rows along the flow: `rows[(3 r + q) stride + i]` is integral `q` of
    /// segment `i` with the screen shifted by `(along_i - j) dx`, `j = (r + origin_i) mod N`.
    /// Each segment's position along the flow relative to its own origin is the same for every
    /// segment up to one sample, so a step reads five consecutive rows (`3 stride` values each)
    /// for all the segments: streamed, where one table per segment (24 kB apart for TMT) made a
    /// step touch several hundred pages.
    rows: Vec<f64>,
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
        let stride = nseg.next_multiple_of(MAX_LANES);
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
        let mut along: Vec<f64> = centres.iter().map(|c| c[0] / dx).collect();
        let origin: Vec<usize> = along
            .iter()
            .map(|&u| (u.floor() as i64).rem_euclid(n as i64) as usize)
            .collect();
        along.resize(stride, 0.0);
        // The tables and the expected variance: from the cache when an earlier run made them
        // for the same screen and segments, else synthesised.
        // "wind-rows": the tables by rows along the flow ([`UnitScreen::rows`]); the entries of
        // the earlier "wind" key hold them by segment (the same shape for a multiple of 8
        // segments; the build's fingerprint in every key keeps them apart anyway).
        let mut key = Fingerprint::new("wind-rows");
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
            .filter(|a| a[0].data.len() == 1 && a[1].shape == [3 * stride * n]);
        let (variance, tables) = match cached {
            Some(mut a) => {
                let tables = a.pop().map(|t| t.data).unwrap_or_default();
                (a[0].data[0], tables)
            }
            None => {
                let (variance, tables) = synthesise(sp, &hexagon, &centres, &origin, stride, dx);
                store.store(
                    &key,
                    &[
                        ("variance", &[], &[variance]),
                        ("tables", &[3 * stride * n], &tables),
                    ],
                );
                (variance, tables)
            }
        };

        // Wind-frame integrals -> generalised forces -> actuator forces.
        let mut to_load = Vec::with_capacity(nseg);
        let mut to_forces = vec![0.0; 9 * stride];
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
            for (k, mk) in m.iter().enumerate() {
                for (c, mkc) in mk.iter().enumerate() {
                    to_forces[(3 * k + c) * stride + i] = *mkc;
                }
            }
        }

        let screen = std::sync::Arc::new(UnitScreen {
            samples: n,
            spacing: dx,
            direction: [cos, sin],
            segments: nseg,
            stride,
            along,
            origin: (0..stride)
                .map(|i| origin.get(i).map_or(0.0, |&c| c as f64))
                .collect(),
            to_load,
            to_forces,
            rows: tables,
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
        self.screen.segments
    }

    /// Number of actuators (3 per segment).
    pub fn n_actuators(&self) -> usize {
        3 * self.screen.segments
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
        let s = &self.screen;
        8 * (s.rows.len()
            + s.along.len()
            + s.origin.len()
            + 9 * s.to_load.len()
            + s.to_forces.len())
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

    /// [`Self::wind_integrals`] of segment `i` from its stencil (sample indices `idx` along
    /// the flow, weights `w`).
    #[inline]
    fn integrals_at(&self, i: usize, (idx, w): &([usize; 4], [f64; 4])) -> [f64; 3] {
        let sc = &*self.screen;
        let (n, stride) = (sc.samples, sc.stride);
        let origin = sc.origin[i] as usize;
        let row = |j: usize| {
            if j >= origin {
                j - origin
            } else {
                j + n - origin
            }
        };
        std::array::from_fn(|q| {
            self.pressure_rms
                * idx
                    .iter()
                    .zip(w)
                    .map(|(&j, wj)| wj * sc.rows[(3 * row(j) + q) * stride + i])
                    .sum::<f64>()
        })
    }

    /// Segment `i`'s three forces with the screen moved by `shift` samples: what
    /// [`Self::forces`] writes at `3 i..3 i + 3`, one segment at a time.
    #[inline]
    fn segment_forces(&self, i: usize, shift: f64, f: &mut [f64]) {
        let g = self.integrals_at(i, &self.stencil(i, shift));
        let stride = self.screen.stride;
        let m = |k: usize, c: usize| self.screen.to_forces[(3 * k + c) * stride + i];
        for (k, fk) in f.iter_mut().enumerate() {
            *fk = m(k, 0) * g[0] + m(k, 1) * g[1] + m(k, 2) * g[2];
        }
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
    ///
    /// The segments are taken a vector of them at a time (the processor's widest), with the
    /// operations of one segment at a time in the same order: the same values to the bit.
    pub fn forces(&self, t: f64, out: &mut [f64]) -> Result<(), M1Error> {
        self.check_forces_len(out)?;
        pulp::Arch::new().dispatch(RowForces {
            loads: self,
            shift: self.shift(t),
            out,
        });
        Ok(())
    }

    /// [`Self::forces`] one segment at a time: the reference of its vectorised steps.
    #[doc(hidden)]
    pub fn forces_by_segment(&self, t: f64, out: &mut [f64]) -> Result<(), M1Error> {
        self.check_forces_len(out)?;
        let shift = self.shift(t);
        for (i, f) in out.chunks_exact_mut(3).enumerate() {
            self.segment_forces(i, shift, f);
        }
        Ok(())
    }

    fn check_forces_len(&self, out: &[f64]) -> Result<(), M1Error> {
        if out.len() == self.n_actuators() {
            Ok(())
        } else {
            Err(M1Error::SizeMismatch {
                what: "f_wind",
                expected: self.n_actuators(),
                found: out.len(),
            })
        }
    }
}

/// [`WindLoads::forces`] with the screen moved by `shift` samples, a vector of segments at a
/// time.
///
/// Every segment's stencil starts at row `K - 1` or `K` of [`UnitScreen::rows`], with
/// `K = -floor(shift) - 1 (mod N)` (the fraction of its position decides which), so each lane
/// weighs the five rows `K - 1 ..= K + 3` with a zero weight on the one its stencil leaves out.
/// That zero term leaves the sum as it is: the forces are [`WindLoads::segment_forces`]' to the
/// bit. A vector with a lane whose stencil starts elsewhere (a position rounded onto the next
/// sample, or outside the range the stencil wraps by comparison) is done one segment at a time.
struct RowForces<'a> {
    loads: &'a WindLoads,
    shift: f64,
    out: &'a mut [f64],
}

impl<'a> pulp::WithSimd for RowForces<'a> {
    /// How many vectors were done one segment at a time.
    type Output = usize;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) -> usize {
        let RowForces { loads, shift, out } = self;
        let sc = &*loads.screen;
        let (n, nseg, stride) = (sc.samples, sc.segments, sc.stride);
        let lanes = S::F64_LANES;
        debug_assert!(lanes <= MAX_LANES && stride.is_multiple_of(lanes));
        fn vectors<S: pulp::Simd>(a: &[f64]) -> &[S::f64s] {
            S::as_simd_f64s(a).0
        }
        let part = |a: &'a [f64], j: usize| vectors::<S>(&a[j * stride..(j + 1) * stride]);
        let along = vectors::<S>(&sc.along);
        let origin = vectors::<S>(&sc.origin);
        // `shift` is in [0, n] ([`WindLoads::shift`]).
        let k = n - 1 - (shift as usize) % n;
        let rows: [[&[S::f64s]; 3]; 5] = std::array::from_fn(|m| {
            let r = (k + n - 1 + m) % n;
            std::array::from_fn(|q| part(&sc.rows, 3 * r + q))
        });
        let map: [[&[S::f64s]; 3]; 3] =
            std::array::from_fn(|kk| std::array::from_fn(|c| part(&sc.to_forces, 3 * kk + c)));
        let c = |x: f64| simd.splat_f64s(x);
        let (nf, zero, one, kf) = (c(n as f64), c(0.0), c(1.0), c(k as f64));
        let (s, rms, minus_two_n) = (c(shift), c(loads.pressure_rms), c(-2.0 * n as f64));
        // Adding and subtracting 2^52 rounds a float in [0, 2^51] to an integer.
        let round = c(4_503_599_627_370_496.0);
        let [half, two, three, minus_three, four, five] = [0.5, 2.0, 3.0, -3.0, 4.0, 5.0].map(c);
        let mut f = [0.0f64; 3 * MAX_LANES];
        let mut by_segment = 0;
        // (No closures over `simd` in the loop: they would not inline its vector instructions.)
        // The vectors that hold a segment (the rest of the padding is left alone).
        for v in 0..nseg.div_ceil(lanes) {
            // The stencil as `periodic_stencil` takes it: the position wrapped into [0, n] by
            // adding the period at most twice, then its floor and fraction.
            let u = simd.sub_f64s(along[v], s);
            let wrapped = simd.and_m64s(
                simd.greater_than_or_equal_f64s(u, minus_two_n),
                simd.less_than_f64s(u, nf),
            );
            let u = up(simd, up(simd, u, nf), nf);
            let r = simd.sub_f64s(simd.add_f64s(u, round), round);
            let fl = simd.select_f64s(simd.less_than_f64s(u, r), simd.sub_f64s(r, one), r);
            let t = simd.sub_f64s(u, fl);
            // Row K - 1 (d = 0) or K (d = 1): d = floor - origin - K mod n.
            let d = simd.sub_f64s(simd.sub_f64s(fl, origin[v]), kf);
            let d = up(simd, up(simd, d, nf), nf);
            let d = simd.select_f64s(simd.less_than_f64s(d, nf), d, simd.sub_f64s(d, nf));
            let first = simd.equal_f64s(d, zero);
            let usable = simd.and_m64s(wrapped, simd.or_m64s(first, simd.equal_f64s(d, one)));
            if simd.first_true_m64s(simd.not_m64s(usable)) < lanes {
                for i in v * lanes..((v + 1) * lanes).min(nseg) {
                    loads.segment_forces(i, shift, &mut out[3 * i..3 * i + 3]);
                }
                by_segment += 1;
                continue;
            }
            // The Catmull-Rom weights, as `catmull_rom` computes them.
            let t2 = simd.mul_f64s(t, t);
            let t3 = simd.mul_f64s(t2, t);
            let w0 = simd.sub_f64s(simd.add_f64s(simd.neg_f64s(t3), simd.mul_f64s(two, t2)), t);
            let w1 = simd.add_f64s(
                simd.sub_f64s(simd.mul_f64s(three, t3), simd.mul_f64s(five, t2)),
                two,
            );
            let w2 = simd.add_f64s(
                simd.add_f64s(simd.mul_f64s(minus_three, t3), simd.mul_f64s(four, t2)),
                t,
            );
            let w3 = simd.sub_f64s(t3, t2);
            let [w0, w1, w2, w3] = [w0, w1, w2, w3].map(|w| simd.mul_f64s(half, w));
            let w = [
                simd.select_f64s(first, w0, zero),
                simd.select_f64s(first, w1, w0),
                simd.select_f64s(first, w2, w1),
                simd.select_f64s(first, w3, w2),
                simd.select_f64s(first, zero, w3),
            ];
            let mut g = [zero; 3];
            for (q, gq) in g.iter_mut().enumerate() {
                let mut acc = simd.mul_f64s(w[0], rows[0][q][v]);
                for m in 1..5 {
                    acc = simd.add_f64s(acc, simd.mul_f64s(w[m], rows[m][q][v]));
                }
                *gq = simd.mul_f64s(rms, acc);
            }
            for (kk, mk) in map.iter().enumerate() {
                let fk = simd.add_f64s(
                    simd.add_f64s(simd.mul_f64s(mk[0][v], g[0]), simd.mul_f64s(mk[1][v], g[1])),
                    simd.mul_f64s(mk[2][v], g[2]),
                );
                simd.partial_store_f64s(&mut f[kk * lanes..(kk + 1) * lanes], fk);
            }
            // The last vector's lanes past the segments are padding.
            let o = &mut out[3 * v * lanes..(3 * (v + 1) * lanes).min(3 * nseg)];
            for (l, ol) in o.chunks_exact_mut(3).enumerate() {
                ol.copy_from_slice(&[f[l], f[lanes + l], f[2 * lanes + l]]);
            }
        }
        by_segment
    }
}

/// Where `a < 0`, `a + n`.
#[inline(always)]
fn up<S: pulp::Simd>(simd: S, a: S::f64s, n: S::f64s) -> S::f64s {
    simd.select_f64s(
        simd.less_than_f64s(a, simd.splat_f64s(0.0)),
        simd.add_f64s(a, n),
        a,
    )
}

/// The most `f64` lanes of a vector ([`pulp::Simd`]: 8 with AVX-512): the per-segment arrays
/// of [`UnitScreen`] are padded to a multiple of it.
const MAX_LANES: usize = 8;

pub(super) fn unit2(v: [f64; 2]) -> [f64; 2] {
    let n = v[0].hypot(v[1]);
    if n > 0.0 {
        [v[0] / n, v[1] / n]
    } else {
        [1.0, 0.0]
    }
}

/// The screen's filtered spectra turned into every segment's tables (`3 stride n` values: the
/// integrals of the unit screen over the hexagon at each sample along the flow) and the
/// expected variance of `G_0`: the random draws of the spectrum, the hexagon's transform at
/// every wavenumber, and two inverse 2-D FFTs (the first two fields packed in one), finished
/// only at the grid rows the segments read. `sp` has passed [`ScreenParams::check`].
fn synthesise(
    sp: &ScreenParams,
    hexagon: &[[f64; 2]],
    centres: &[[f64; 2]],
    origin: &[usize],
    stride: usize,
    dx: f64,
) -> (f64, Vec<f64>) {
    let n = sp.samples;

    // The generator's draws (one after the other) beside the spectrum's powers.
    let (psd, draws) = rayon::join(|| sp.discrete_psd(), || ScreenSpectrum::normals(sp));
    let spectrum = ScreenSpectrum::scaled(sp, &psd, draws);
    let k: Vec<f64> = (0..n).map(|i| psd.wavenumber(i)).collect();
    let grid = PolygonGrid::new(hexagon, &k, &k);
    let (coefficients, eta, variance) = filtered(&grid, &psd, spectrum.coefficients);

    // The rows of the grid the segments' stencils read, each transformed once.
    let stencils: Vec<([usize; 4], [f64; 4])> = centres
        .iter()
        .map(|c| periodic_stencil(c[1] / dx, n))
        .collect();
    let mut rows: Vec<usize> = stencils.iter().flat_map(|(r, _)| *r).collect();
    rows.sort_unstable();
    rows.dedup();
    // Row `r` of the grid is row `at(r)` of the transforms' output (`rows` is sorted).
    let at = |r: usize| rows.binary_search(&r).unwrap_or_default();
    let read: Vec<([usize; 4], [f64; 4], usize)> = stencils
        .iter()
        .zip(origin)
        .map(|((rs, w), &c)| (rs.map(at), w.map(|w| w * SQRT_2), c))
        .collect();
    // Sample k of segment i of field q from column (origin_i + k) mod n of its stencil's rows,
    // the samples in parallel (each one's values for every segment side by side); each value
    // summed over the stencil's rows in their order.
    let mut tables = vec![0.0; 3 * stride * n];
    let fill = |tables: &mut [f64], buf: &[Complex64], fields: &[Field]| {
        tables
            .par_chunks_mut(3 * stride)
            .enumerate()
            .for_each(|(k, t)| {
                for &(q, part) in fields {
                    for (i, (rs, w, c)) in read.iter().enumerate() {
                        let col = (c + k) % n;
                        let mut sum = 0.0;
                        for (r, wr) in rs.iter().zip(w) {
                            sum += wr * part(&buf[r * n + col]);
                        }
                        t[q * stride + i] = sum;
                    }
                }
            });
    };
    let g01 = inverse_fft_rows(&coefficients, n, &rows);
    drop(coefficients);
    fill(&mut tables, &g01, &[(0, |v| v.re), (1, |v| v.im)]);
    drop(g01);
    let g2 = inverse_fft_rows(&eta, n, &rows);
    fill(&mut tables, &g2, &[(2, |v| v.re)]);
    (variance, tables)
}

/// The screen's coefficients `c` (row-major, `n x n`, `n` even) filtered by the polygon of
/// `grid`: the packed spectrum of `c H` and `c H_xi` ([`packed`]), `c H_eta`, and the
/// expected variance of `G_0` (`sum psd |H|^2`). The coefficients become the packed spectrum
/// in place; rows `p` and `n - p` are filtered together (the packing pairs bin `k` with `-k`),
/// the pairs in parallel, the variance summed per row in row order (the same sum whatever the
/// threads).
fn filtered(
    grid: &PolygonGrid,
    psd: &super::spectrum::DiscretePsd,
    mut coefficients: Vec<Complex64>,
) -> (Vec<Complex64>, Vec<Complex64>, f64) {
    let n = psd.n;
    let mut eta = vec![Complex64::ZERO; n * n];
    // Rows 0 ..= n/2 and n/2 + 1 .. n: rows p and n - p pair for 1 <= p < n/2, rows 0 and
    // n/2 with themselves.
    let lo = n / 2 + 1;
    let pairs = n - lo;
    let (c_lo, c_hi) = coefficients.split_at_mut(lo * n);
    let (e_lo, e_hi) = eta.split_at_mut(lo * n);
    let (c_self, c_pair) = c_lo.split_at_mut(n);
    let (e_self, e_pair) = e_lo.split_at_mut(n);
    let paired: Vec<(f64, f64)> = c_pair[..pairs * n]
        .par_chunks_mut(n)
        .zip(e_pair[..pairs * n].par_chunks_mut(n))
        .zip(
            c_hi.par_chunks_mut(n)
                .rev()
                .zip(e_hi.par_chunks_mut(n).rev()),
        )
        .enumerate()
        .map_init(
            || RowPair::new(n),
            |rp, (i, ((cp, ep), (cq, eq)))| {
                let p = i + 1;
                rp.filter(grid, psd, (p, cp, ep), Some((n - p, cq, eq)))
            },
        )
        .collect();
    let mut per_row = vec![0.0; n];
    for (i, (vp, vq)) in paired.into_iter().enumerate() {
        per_row[i + 1] = vp;
        per_row[n - i - 1] = vq;
    }
    let mut rp = RowPair::new(n);
    per_row[0] = rp.filter(grid, psd, (0, c_self, e_self), None).0;
    let (c_half, e_half) = (&mut c_pair[pairs * n..], &mut e_pair[pairs * n..]);
    per_row[n / 2] = rp.filter(grid, psd, (n / 2, c_half, e_half), None).0;
    (coefficients, eta, per_row.iter().sum())
}

/// A field of the tables (0: the integral of the screen, 1 and 2: its first moments) and how
/// it reads a transformed value.
type Field = (usize, fn(&Complex64) -> f64);

/// One hexagon transform `[H, H_xi, H_eta]` per bin of a grid row.
type RowTransforms = Vec<[Complex64; 3]>;

/// Scratch of [`synthesise`]'s filtering of a pair of rows `p` and `q = -p`: the hexagon's
/// transforms on both rows and each row's `c H` and `c H_xi`.
struct RowPair {
    h: [RowTransforms; 2],
    a: [Vec<Complex64>; 2],
    b: [Vec<Complex64>; 2],
}

impl RowPair {
    fn new(n: usize) -> Self {
        Self {
            h: std::array::from_fn(|_| vec![[Complex64::ZERO; 3]; n]),
            a: std::array::from_fn(|_| vec![Complex64::ZERO; n]),
            b: std::array::from_fn(|_| vec![Complex64::ZERO; n]),
        }
    }

    /// Filters row `p` (its coefficients `c` and the `c H_eta` row `e`) with its partner row
    /// `q = n - p` (`None`: the row is its own partner, rows 0 and n/2): the coefficients
    /// become the packed spectrum of `c H` and `c H_xi` and `e` receives `c H_eta` (bins with
    /// `c = 0` are left as they are); returns each row's share of the variance of `G_0`.
    /// With a centrally symmetric hexagon the partner row's transforms are row `p`'s at the
    /// negated wavenumbers (`H(-k) = H(k)`, `H_xi(-k) = -H_xi(k)`, bit for bit).
    #[allow(clippy::type_complexity)]
    fn filter(
        &mut self,
        grid: &PolygonGrid,
        psd: &super::spectrum::DiscretePsd,
        (p, cp, ep): (usize, &mut [Complex64], &mut [Complex64]),
        partner: Option<(usize, &mut [Complex64], &mut [Complex64])>,
    ) -> (f64, f64) {
        let n = cp.len();
        let neg = |i: usize| (n - i) % n;
        let [hp, hq] = &mut self.h;
        let Some((q, cq, eq)) = partner else {
            for (ix, h) in hp.iter_mut().enumerate() {
                if cp[ix] != Complex64::ZERO || cp[neg(ix)] != Complex64::ZERO {
                    *h = grid.at(ix, p);
                }
            }
            let v = Self::products(hp, psd, p, cp, ep, &mut self.a[0], &mut self.b[0]);
            let (a, b) = (&self.a[0], &self.b[0]);
            for (ix, z) in cp.iter_mut().enumerate() {
                *z = packed(a[ix], a[neg(ix)], b[ix], b[neg(ix)]);
            }
            return (v, v);
        };
        for (ix, h) in hp.iter_mut().enumerate() {
            if cp[ix] != Complex64::ZERO || cq[neg(ix)] != Complex64::ZERO {
                *h = grid.at(ix, p);
            }
        }
        for (ix, h) in hq.iter_mut().enumerate() {
            if cq[ix] != Complex64::ZERO || cp[neg(ix)] != Complex64::ZERO {
                *h = if grid.symmetric {
                    let [h0, hx, hy] = hp[neg(ix)];
                    [h0, Complex64::new(0.0, -hx.im), Complex64::new(0.0, -hy.im)]
                } else {
                    grid.at(ix, q)
                };
            }
        }
        let [ap, aq] = &mut self.a;
        let [bp, bq] = &mut self.b;
        let vp = Self::products(hp, psd, p, cp, ep, ap, bp);
        let vq = Self::products(hq, psd, q, cq, eq, aq, bq);
        for (ix, z) in cp.iter_mut().enumerate() {
            *z = packed(ap[ix], aq[neg(ix)], bp[ix], bq[neg(ix)]);
        }
        for (ix, z) in cq.iter_mut().enumerate() {
            *z = packed(aq[ix], ap[neg(ix)], bq[ix], bp[neg(ix)]);
        }
        (vp, vq)
    }

    /// Row `iy`'s `a = c H`, `b = c H_xi` and `e = c H_eta` (`a = c`, `b = 0` and `e` left
    /// where `c = 0`) from its transforms `h`, and its share of the variance.
    fn products(
        h: &[[Complex64; 3]],
        psd: &super::spectrum::DiscretePsd,
        iy: usize,
        c: &[Complex64],
        e: &mut [Complex64],
        a: &mut [Complex64],
        b: &mut [Complex64],
    ) -> f64 {
        let mut var = 0.0;
        for ix in 0..c.len() {
            let ci = c[ix];
            if ci == Complex64::ZERO {
                a[ix] = ci;
                b[ix] = Complex64::ZERO;
                continue;
            }
            let [h0, hx, hy] = h[ix];
            var += psd.bin(ix, iy) * h0.norm_sqr();
            a[ix] = ci * h0;
            b[ix] = ci * hx;
            e[ix] = ci * hy;
        }
        var
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::geometry::GeometryParams;
    use crate::aperture::layout::Layout;

    /// The paired filtering is the bin-by-bin product of the coefficients with the polygon's
    /// transforms, packed bin against negated bin, bit for bit: for the centrally symmetric
    /// hexagon (the partner row's transforms derived) and for a polygon that is not (computed).
    #[test]
    fn rows_filtered_in_pairs_are_the_bin_by_bin_products() {
        let sp = ScreenParams {
            samples: 16,
            size: 20.0,
            ..ScreenParams::default()
        };
        let psd = sp.discrete_psd();
        let n = psd.n;
        let k: Vec<f64> = (0..n).map(|i| psd.wavenumber(i)).collect();
        let hexagon: Vec<[f64; 2]> = (0..6)
            .map(|j| {
                let t = std::f64::consts::FRAC_PI_3 * j as f64 + 0.3;
                [0.7 * t.cos(), 0.7 * t.sin()]
            })
            .collect();
        let mut skewed = hexagon.clone();
        skewed[2] = [skewed[2][0] + 0.1, skewed[2][1] - 0.05];
        for (vertices, symmetric) in [(&hexagon, true), (&skewed, false)] {
            let grid = PolygonGrid::new(vertices, &k, &k);
            assert_eq!(grid.symmetric, symmetric);
            let c = ScreenSpectrum::drawn(&sp, &psd).coefficients;
            let (packed_c, eta, variance) = filtered(&grid, &psd, c.clone());
            let neg = |i: usize| (n - i) % n;
            let (mut a, mut b, mut e) = (c.clone(), vec![Complex64::ZERO; n * n], eta.clone());
            let mut want_var = 0.0;
            for iy in 0..n {
                let mut row = 0.0;
                for ix in 0..n {
                    let i = iy * n + ix;
                    if c[i] == Complex64::ZERO {
                        e[i] = Complex64::ZERO;
                        continue;
                    }
                    let [h, hx, hy] = grid.at(ix, iy);
                    row += psd.bin(ix, iy) * h.norm_sqr();
                    (a[i], b[i], e[i]) = (c[i] * h, c[i] * hx, c[i] * hy);
                }
                want_var += row;
            }
            for iy in 0..n {
                for ix in 0..n {
                    let (i, j) = (iy * n + ix, neg(iy) * n + neg(ix));
                    let want = super::super::spectrum::packed(a[i], a[j], b[i], b[j]);
                    assert_eq!(packed_c[i], want, "({ix}, {iy}) symmetric {symmetric}");
                    assert_eq!(eta[i], e[i], "({ix}, {iy}) symmetric {symmetric}");
                }
            }
            assert_eq!(
                variance.to_bits(),
                want_var.to_bits(),
                "symmetric {symmetric}"
            );
            assert!(variance > 0.0);
        }
    }

    /// The vector widths (f64 lanes) the forces are run on: the processor's widest (0), and
    /// 1, 2 and 4 lanes as portable code (the widths of other processors).
    const WIDTHS: [usize; 4] = [0, 1, 2, 4];

    /// The forces of every segment at `shift` on vectors of `width` lanes, and how many vectors
    /// were done one segment at a time.
    fn vectorised(loads: &WindLoads, shift: f64, width: usize) -> (Vec<f64>, usize) {
        let mut out = vec![f64::NAN; loads.n_actuators()];
        let op = RowForces {
            loads,
            shift,
            out: &mut out,
        };
        let by_segment = match width {
            0 => pulp::Arch::new().dispatch(op),
            1 => pulp::WithSimd::with_simd(op, pulp::Scalar),
            2 => pulp::WithSimd::with_simd(op, pulp::Scalar128b),
            4 => pulp::WithSimd::with_simd(op, pulp::Scalar256b),
            _ => unreachable!("width {width}"),
        };
        (out, by_segment)
    }

    /// The forces of every segment at `shift`, one segment at a time.
    fn by_segment(loads: &WindLoads, shift: f64) -> Vec<f64> {
        let mut out = vec![f64::NAN; loads.n_actuators()];
        for (i, f) in out.chunks_exact_mut(3).enumerate() {
            loads.segment_forces(i, shift, f);
        }
        out
    }

    /// Bit patterns, so that a NaN left unwritten or a sign of zero counts.
    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// `layout`'s loads on a small screen (64 samples over 32 m), at 3 m/s and 2 Pa.
    fn small(layout: &Layout, direction: f64) -> WindLoads {
        let geometry = Geometry::new(layout, GeometryParams::for_layout(layout)).unwrap();
        let mut params = WindParams {
            direction,
            ..WindParams::default()
        };
        params.screen.size = 32.0;
        params.screen.samples = 64;
        WindLoads::new_in(&geometry, &params, &Store::off())
            .unwrap()
            .with_flow(3.0, 2.0)
            .unwrap()
    }

    #[test]
    fn a_vector_with_a_stencil_off_the_five_rows_is_done_one_segment_at_a_time() {
        let mut loads = small(&Layout::preset("keck").unwrap(), 0.0);
        let n = 64.0;
        let screen = std::sync::Arc::get_mut(&mut loads.screen).unwrap();
        // Segment 0 just below 5 and the shift just above: the position -2^-49 wraps to
        // -2^-49 + n, which rounds to n itself: its stencil starts at row K + 1.
        screen.along[0] = 5.0 - 2f64.powi(-50);
        screen.origin[0] = 4.0;
        // Segment 9 just beyond two periods behind, out of the range the stencil wraps by
        // comparison: the remainder's `r + n` rounds to n, so its stencil starts at sample 0
        // with fraction 0, where two additions of n would leave the fraction near 1.
        screen.along[9] = -2.0 * n - 2f64.powi(-40);
        screen.origin[9] = 0.0;
        let shift_0 = 5.0 + 2f64.powi(-50);
        assert_eq!(screen.along[0] - shift_0 + n, n);
        for shift in [shift_0, 0.0, 0.37, 17.5, n - 1e-12, n] {
            let want = by_segment(&loads, shift);
            for width in WIDTHS {
                let (got, fallbacks) = vectorised(&loads, shift, width);
                assert_eq!(bits(&got), bits(&want), "shift {shift}, width {width}");
                assert!(fallbacks >= 1, "shift {shift}, width {width}");
            }
        }
    }

    /// On Keck (36 segments, padded to 40), TMT (492, padded to 496) and a layout of 18
    /// segments (padded to 24: more padding than a vector of 4), on every vector width, over a
    /// whole period of shifts on and beside the samples; almost every vector is done as one.
    #[test]
    fn the_vectorised_forces_are_those_of_one_segment_at_a_time_to_the_bit() {
        let hexagonal = Layout::hexagonal("h18", 2, 0, 1.0, 0.005, None).unwrap();
        assert_eq!(hexagonal.n_segments(), 18);
        let layouts = [
            Layout::preset("keck").unwrap(),
            Layout::preset("tmt").unwrap(),
            hexagonal,
        ];
        for layout in &layouts {
            let loads = small(layout, 23.0);
            for k in 0..=320 {
                // Whole samples, then fractions through the period.
                let shift = if k < 64 {
                    f64::from(k)
                } else {
                    (f64::from(k) * 0.2137) % 64.0
                };
                let want = by_segment(&loads, shift);
                for width in WIDTHS {
                    let (got, fallbacks) = vectorised(&loads, shift, width);
                    let name = &layout.name;
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "{name}, shift {shift}, width {width}"
                    );
                    assert!(
                        fallbacks <= 1,
                        "{name}, shift {shift}, width {width}: {fallbacks}"
                    );
                }
            }
        }
    }
}
