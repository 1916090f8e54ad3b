//! One coupled tick, entirely on the modes (module documentation, "Scheme" and "Carried on
//! the modes"): the channels' free and cell-driven parts per kind, the coupled solve for the
//! modal force, the modes; a step's coupled part as one SIMD dispatch ([`Step`]); and the
//! outputs back in actuator space.

use super::coupled::{ChannelMaps, CoupledMirror, LowCorrection};
use pulp::WithSimd;

use super::projection::{Reconstruct, ReconstructCols, Shapes};
use crate::linalg::kernels::{
    SourceMasks, axpy, rows_dot, rows_dot_f32, rows_dot2_f32, rows_map, state_map,
};
use crate::linalg::pair::{LazyPair, Pair};
use crate::linalg::symmetric::{BLOCK, SymPacked32, sym_dot_f32, sym_dot_rows_f32};
use crate::linalg::symmetric_scaled::{SymPacked8, SymPacked24, SymPackedHalf};
use crate::plant::segment::{N_STATE, state};
use nalgebra::{SMatrix, SVector};
use std::ops::Range;

impl CoupledMirror {
    /// One coupled tick, entirely on the modes: the segments' response to the cell motion is
    /// carried per mode (identical segments: the channel dynamics commute with the mode shapes).
    /// Modal arrays are state-major (`[s * r + j]`), so every update is a run of axpys. The
    /// per-mode work between the passes over the large matrices is done in as few passes over
    /// the modes as its order allows ([`TickStart`], [`CorrectionInput`], [`TickEnd`]): at 1000
    /// modes the Gram pass just before each of them has pushed their arrays out of the core's
    /// L2, so each array read costs a read from the L3 (BENCHMARKS.md, twenty-sixth and
    /// twenty-eighth rounds).
    #[inline(always)]
    fn tick<S: pulp::Simd, const LARGE: bool>(
        &mut self,
        simd: S,
        pier_z: f64,
        sample: bool,
        at: (usize, usize),
    ) {
        let r = self.r;
        // The drive jumps at the sample and is held over the tick: the modal force starts the
        // tick at the end value of the last one plus that jump, then ramps (the continuous
        // part of the cell force is what varies within the tick). The free part's jump is
        // the free chunk's drive rows (on the modes already); the cell-driven part's is
        // `g = [G_p, G_t] drive_step`. In single precision a sample's tick takes g from the
        // solve's own pass over the Gram matrices (`split`, below) and adds it after the
        // solve; otherwise it comes first, into `jump`.
        let (split, ld) = (sample && self.coupling_single, self.ld32);
        if split {
            // The modal terms first (they do not wait for g here), so that each kind's pass
            // finishes its own right-hand side, in single precision too, on the thread that
            // then reads it in the pass over its Gram matrix.
            let (start, [d0, d1], _) = self.tick_start(pier_z, at);
            let (d0, d1) = (&d0[..r], &d1[..r]);
            start.run(|j| d0[j] + d1[j]);
            self.tick_channels::<S, LARGE>(simd, sample, true);
        } else {
            if sample {
                let [o0, o1] = &self.free_out;
                let (_, jr) = free_rows(r, at);
                for ((j, d0), d1) in self.jump.iter_mut().zip(&o0[jr.clone()]).zip(&o1[jr]) {
                    *j = d0 + d1;
                }
            }
            self.tick_channels::<S, LARGE>(simd, sample, false);
            if sample {
                kinds_to_f32(&mut self.drive32, &self.drive_step, r, ld);
                rows_dot_f32::<S>(
                    simd,
                    &self.gg32,
                    2 * ld,
                    r,
                    2 * ld,
                    &self.drive32,
                    &mut self.jump,
                );
            }
            let (start, _, jump) = self.tick_start(pier_z, at);
            if sample {
                let jump = &jump[..r];
                start.run(|j| jump[j]);
            } else {
                start.run(|_| 0.0);
            }
            self.add_modal_terms();
        }
        if split {
            // With psi_0 the right-hand side before the jump g (a = a_0 + alpha g),
            // y = G psi_0 and W M alpha = (W - I) beta, beta = alpha / b1:
            // u+ = h' + y + (W - I) (y + beta g). One pass over [G_p, G_t] gives y and g
            // together, one over the small correction W - I (stored by half) gives u+ (the
            // traffic of 1.25 r x 2r passes instead of 2). `psi32` and `drive32` are the
            // channel passes' (`tick_channels`).
            let by_kind = LARGE && (self.gram_24.is_some() || self.gram_packed.is_some());
            if by_kind {
                // By kind, each with its own results and column sums (on one thread in the
                // same order as on two, so the same bits), summed where they are read.
                let (ps, dr) = (&self.psi32, &self.drive32);
                let [[y0, y1], [y2, y3]] = &mut self.gram_y;
                let [[t0, t1], [t2, t3]] = &mut self.gram_t;
                let pair = pair::<LARGE>(&mut self.pair, self.two_threads);
                if let Some(gs) = self.gram_24.as_deref() {
                    let n = gs[0].padded_order();
                    let [[s0, s1], [s2, s3]] = &mut self.gram_xs;
                    let piston = GramKind24 {
                        a: &gs[0],
                        x: [&ps[..n], &dr[..n]],
                        xs: [s0, s1],
                        y: [y0, y1],
                        t: [t0, t1],
                    };
                    let tilt = GramKind24 {
                        a: &gs[1],
                        x: [&ps[ld..ld + n], &dr[ld..ld + n]],
                        xs: [s2, s3],
                        y: [y2, y3],
                        t: [t2, t3],
                    };
                    both(simd, pair, piston, tilt);
                } else if let Some(gs) = self.gram_packed.as_deref() {
                    let n = gs[0].padded_order();
                    let piston = GramKind {
                        a: &gs[0],
                        x: [&ps[..n], &dr[..n]],
                        y: [y0, y1],
                        t: [t0, t1],
                    };
                    let tilt = GramKind {
                        a: &gs[1],
                        x: [&ps[ld..ld + n], &dr[ld..ld + n]],
                        y: [y2, y3],
                        t: [t2, t3],
                    };
                    both(simd, pair, piston, tilt);
                }
            } else {
                self.gpsi.fill(0.0);
                self.gjump.fill(0.0);
                RowsDot {
                    a: &self.gg32,
                    lda: 2 * ld,
                    m: r,
                    k: 2 * ld,
                    x: [&self.psi32, &self.drive32],
                    y: [&mut self.gpsi, &mut self.gjump],
                }
                .split(simd, pair::<LARGE>(&mut self.pair, self.two_threads));
            }
            // W - I = D^-1 K D, K symmetric (stored by its upper block triangle): its input
            // D (y + beta g), scaled by the stored matrix's own scale where it has one.
            let low = self.corr_low.as_ref().filter(|_| LARGE);
            let input = CorrectionInput {
                beta: &self.beta,
                d_half: &self.d_half,
                scale: low.map(LowCorrection::scale),
                win: &mut self.win32[..r],
                u_new: &mut self.u_new[..r],
            };
            if by_kind {
                let [[y0, y1], [y2, y3]] = &self.gram_y;
                let (y0, y1, y2, y3) = (&y0[..r], &y1[..r], &y2[..r], &y3[..r]);
                input.run(|j| (y0[j] + y2[j], y1[j] + y3[j]));
            } else {
                let (gpsi, gjump) = (&self.gpsi[..r], &self.gjump[..r]);
                input.run(|j| (gpsi[j], gjump[j]));
            }
            // From [`TWO_THREADS_MIN_MODES`] in two parts of block rows with about the same
            // stored entries, each with its own column sums (on one thread the same two parts,
            // so the same bits); below, whole.
            self.corr.fill(0.0);
            let (a, s) = (&self.corr32, self.corr_split);
            if low.is_none() && (!LARGE || s == 0) {
                sym_dot_f32::<S, 1>(simd, a, [&self.win32], [&mut self.corr], [&mut self.corr_t]);
            } else {
                let stored = low.map_or(Stored::Single(a), Stored::from);
                let cut = (BLOCK * s).min(r);
                let (y0, y1) = self.corr[..r].split_at_mut(cut);
                let x = [&self.win32[..]];
                let lo = SymRows {
                    a: stored,
                    x,
                    y: [y0],
                    t: [&mut self.corr_t],
                    blocks: 0..s,
                };
                let hi = SymRows {
                    a: stored,
                    x,
                    y: [y1],
                    t: [&mut self.corr_t2],
                    blocks: s..a.padded_order() / BLOCK,
                };
                both(
                    simd,
                    pair::<LARGE>(&mut self.pair, self.two_threads),
                    lo,
                    hi,
                );
                let t = [&self.corr_t[..r], &self.corr_t2[..r]];
                finish_parts(&mut self.corr[..r], t, cut, low.map(LowCorrection::scale));
            }
            // The rest of u+, the cell-driven jump into the tick's start force and the free
            // response, and the modes at the end of the tick.
            let end = TickEnd {
                corr: &self.corr,
                d_half: &self.d_half,
                u_new: &self.u_new,
                alpha: &self.alpha,
                drive_d: self.drive_d,
                cols: &self.cols,
                modes: ModeUpdate::new(
                    &self.a_mode,
                    &self.b0,
                    &self.b1,
                    &mut self.q[..r],
                    &mut self.v[..r],
                    &mut self.u[..r],
                ),
            };
            if by_kind {
                let [[_, y1], [_, y3]] = &self.gram_y;
                let (y1, y3) = (&y1[..r], &y3[..r]);
                end.run(|j| y1[j] + y3[j]);
            } else {
                let gjump = &self.gjump[..r];
                end.run(|j| gjump[j]);
            }
        } else {
            if self.coupling_single {
                kinds_to_f32(&mut self.psi32, &self.psi, r, ld);
                RowsDot {
                    a: &self.wg32,
                    lda: 2 * ld,
                    m: r,
                    k: 2 * ld,
                    x: [&self.psi32],
                    y: [&mut self.u_new],
                }
                .split(simd, pair::<LARGE>(&mut self.pair, self.two_threads));
            } else {
                rows_dot::<S>(simd, &self.wg, 2 * r, r, 2 * r, &self.psi, &mut self.u_new);
            }
            // Modes at the end of the tick.
            let (u_new, cols) = (&self.u_new[..r], &self.cols[..r]);
            let mut modes = ModeUpdate::new(
                &self.a_mode,
                &self.b0,
                &self.b1,
                &mut self.q[..r],
                &mut self.v[..r],
                &mut self.u[..r],
            );
            for j in 0..r {
                modes.advance(j, cols[j], modes.u[j], u_new[j]);
            }
        }
        // Cell-driven states: xi+ = Y + ramp q+. The ramp's part is left pending, for the
        // thread that owns each kind to add at its next pass ([`ChannelKind`]) or at the end of
        // the step ([`Self::flush_ramp`]): added here, by the calling thread, the tilt kind's
        // states crossed between the two threads' caches twice per tick (BENCHMARKS.md,
        // twelfth round: 20-27 us per tick when the two cores do not share their L3).
        for k in 0..2 {
            std::mem::swap(&mut self.xi[k], &mut self.scratch[k]);
        }
        self.ramp_pending = true;
    }

    /// The start of tick `i` of a chunk of `len` ([`TickStart`], the pier's new value
    /// `pier_z` held from here), with the free part's drive change over the tick by kind (the
    /// chunk's rows, [`Self::free_ticks`]) and the modal force's jump `jump`.
    #[inline(always)]
    fn tick_start(
        &mut self,
        pier_z: f64,
        at: (usize, usize),
    ) -> (TickStart<'_>, [&[f64]; 2], &[f64]) {
        let r = self.r;
        // The pier input is held too: a new value loads the modes from the tick's start.
        let dp = pier_z - self.pier;
        self.pier = pier_z;
        let [o0, o1] = &self.free_out;
        let (fr, jr) = free_rows(r, at);
        let ([a0, a1, ..], [b0, _], [b1, _]) = (&self.a_mode, &self.b0, &self.b1);
        let start = TickStart {
            h: [&o0[fr.clone()], &o1[fr]],
            pier_gains: self.structure.pier_gains(),
            a: [a0, a1],
            b0,
            b1,
            q: &self.q,
            v: &self.v,
            u: &mut self.u[..r],
            xs: &mut self.gpsi,
            cols: &mut self.cols,
            u_new: &mut self.u_new,
            drive_d: self.drive_d,
            dp,
            pier: pier_z,
        };
        (start, [&o0[jr.clone()], &o1[jr]], &self.jump)
    }

    /// The modes' terms of the solve added to the right-hand side, `psi_k += e_k x` (`x` in
    /// `gpsi`, [`TickStart`]), where the channel passes do not add them.
    #[inline(always)]
    fn add_modal_terms(&mut self) {
        let r = self.r;
        let (psi_p, psi_t) = self.psi.split_at_mut(r);
        let (psi_t, [ep, et]) = (&mut psi_t[..r], self.e);
        for ((p, t), x) in psi_p.iter_mut().zip(psi_t.iter_mut()).zip(&self.gpsi[..r]) {
            *p += ep * x;
            *t += et * x;
        }
    }

    /// Adds the last tick's pending ramp part to the cell-driven states of both kinds, each on
    /// the thread that steps it ([`Self::tick`]); between steps, the states hold it.
    #[inline(always)]
    pub(super) fn flush_ramp<S: pulp::Simd, const LARGE: bool>(&mut self, simd: S) {
        if !std::mem::take(&mut self.ramp_pending) {
            return;
        }
        let [xi_p, xi_t] = &mut self.xi;
        let kind = |k: usize, xi| RampKind {
            ramp: &self.ramp[k],
            q: &self.q,
            xi,
        };
        let (piston, tilt) = (kind(0, xi_p), kind(1, xi_t));
        both(
            simd,
            pair::<LARGE>(&mut self.pair, self.two_threads),
            piston,
            tilt,
        );
    }

    /// The free part of the channels over a chunk of ticks, on the modes: one pass of the
    /// chunk's composed map per kind ([`super::coupled::FreeChunk`]) from the projected free
    /// states and held inputs, giving each tick's modal force and drive change and the states at
    /// the chunk's end (the same values as stepping the per-tick maps, to rounding).
    #[inline(always)]
    pub(super) fn free_ticks<S: pulp::Simd, const LARGE: bool>(&mut self, simd: S, chunk: usize) {
        let r = self.r;
        let c = &self.free_chunks[chunk];
        let [pp, pt] = &mut self.proj;
        let [op, ot] = &mut self.free_out;
        let kind = |k: usize, proj, out| FreeKind {
            a: &c.a[k],
            b: &c.b[k],
            masks: &c.masks[k],
            w: &self.w_proj[k],
            r,
            proj,
            out,
        };
        let piston = kind(0, pp, op);
        let tilt = kind(1, pt, ot);
        both(
            simd,
            pair::<LARGE>(&mut self.pair, self.two_threads),
            piston,
            tilt,
        );
    }

    /// The cell-driven channels of both kinds (0 piston, 1 tilt) over one tick of
    /// [`Self::tick`], on the modes, without this tick's ramp, with their terms of the
    /// coupled solve's right-hand side (`psi`) and, at a servo sample (`sample`), the drive's
    /// change (`drive_step`): one pass of [`state_map`] over the modes (the same
    /// `N_STATE x N_STATE` map for every mode).
    #[inline(always)]
    fn tick_channels<S: pulp::Simd, const LARGE: bool>(
        &mut self,
        simd: S,
        sample: bool,
        terms: bool,
    ) {
        let (r, ld) = (self.r, self.ld32);
        let set = usize::from(!sample);
        let (psi_p, psi_t) = self.psi.split_at_mut(r);
        let (step_p, step_t) = self.drive_step.split_at_mut(r);
        let (p32_p, p32_t) = self.psi32.split_at_mut(ld);
        let (d32_p, d32_t) = self.drive32.split_at_mut(ld);
        let (xs, e) = (&self.gpsi[..r], self.e);
        let pending = std::mem::take(&mut self.ramp_pending);
        let [xi_p, xi_t] = &mut self.xi;
        let [sc_p, sc_t] = &mut self.scratch;
        let kind = |k: usize, xi, scratch, psi, drive_step, psi32, drive32| ChannelKind {
            maps: &self.channel_maps[set][k],
            ramp: &self.ramp[k],
            pending,
            q: &self.q,
            xi,
            scratch,
            psi,
            drive_step: sample.then_some(drive_step),
            terms: terms.then(|| SolveTerms {
                x: xs,
                e: e[k],
                psi32,
                drive32: sample.then_some(drive32),
            }),
        };
        let piston = kind(
            0,
            xi_p,
            sc_p,
            psi_p,
            step_p,
            &mut p32_p[..r],
            &mut d32_p[..r],
        );
        let tilt = kind(
            1,
            xi_t,
            sc_t,
            psi_t,
            step_t,
            &mut p32_t[..r],
            &mut d32_t[..r],
        );
        both(
            simd,
            pair::<LARGE>(&mut self.pair, self.two_threads),
            piston,
            tilt,
        );
    }

    /// The mirror's displacement back in actuator space, `Phi_k xi_k mirror` plus the free
    /// part, per kind: one single-column pass over the mode shapes. The cell's displacement and
    /// force are left to [`Self::update_cell_outputs`] (computed when read).
    #[inline(always)]
    pub(super) fn write_outputs<S: pulp::Simd, const LARGE: bool>(&mut self, simd: S) {
        let (r, n, na, ld) = (self.r, self.n_segments, self.na, self.ld32);
        let mp = state::MIRROR_POS;
        for k in 0..2 {
            let src = &self.xi[k][mp * r..(mp + 1) * r];
            for (d, c) in self.cols32[ld * k..ld * k + r].iter_mut().zip(src) {
                *d = *c as f32;
            }
        }
        let mut outs = std::mem::take(&mut self.out);
        let (phic, cols) = (
            Shapes::new(self.shapes_24.as_deref(), &self.phic32),
            &self.cols32[..2 * ld],
        );
        let (phit, ldt) = (&self.phit32[..], self.ldt);
        // Rows `rows` of the displacement: by the shapes' columns where they are kept, else by
        // their rows.
        let back = move |rows: std::ops::Range<usize>, out: &mut [f64]| {
            if phit.is_empty() {
                simd.vectorize(Reconstruct::<1> {
                    phic,
                    ld,
                    n,
                    rows,
                    cols,
                    out: [out],
                });
            } else {
                simd.vectorize(ReconstructCols {
                    phit,
                    ldt,
                    r,
                    n,
                    rows,
                    cols,
                    ld,
                    out,
                });
            }
        };
        match pair::<LARGE>(&mut self.pair, self.two_threads) {
            Some(p) => {
                let h = split_rows(na);
                let (lo, hi) = outs[..na].split_at_mut(h);
                p.join(|| back(0..h, lo), move || back(h..na, hi));
            }
            None => back(0..na, &mut outs[..na]),
        }
        // The free part's mirror position (its steps may be pending: `SegmentArray::set_deferred`).
        let mut free_z = std::mem::take(&mut self.free_z);
        {
            let mut pos = SMatrix::<f64, 1, N_STATE>::zeros();
            pos[mp] = 1.0;
            let (zp, zt) = free_z[..3 * n].split_at_mut(n);
            self.free.combination(0, &pos, zp);
            self.free.combination(1, &pos, zt);
        }
        // Channel values (rows: piston channels, then tilt) to actuators, segment by segment.
        let v = self.basis;
        let (xp, xt) = (&free_z[..n], &free_z[n..3 * n]);
        let (op, ot) = (&outs[..n], &outs[n..3 * n]);
        for ((((z, p), t), oq), ou) in self.z_mirror[..3 * n]
            .chunks_exact_mut(3)
            .zip(xp)
            .zip(xt.chunks_exact(2))
            .zip(op)
            .zip(ot.chunks_exact(2))
        {
            let zm = [p + oq, t[0] + ou[0], t[1] + ou[1]];
            for (a, za) in z.iter_mut().enumerate() {
                *za = v[(a, 0)] * zm[0] + v[(a, 1)] * zm[1] + v[(a, 2)] * zm[2];
            }
        }
        self.out = outs;
        self.free_z = free_z;
        self.cell_stale = true;
    }

    /// The cell's displacement and force back in actuator space, when a step left them stale:
    /// `Phi_k [q, xi_k c_k^T]` per kind (one two-column pass over the mode shapes), with the
    /// free part's force and the feedthrough of the cell's displacement.
    #[inline(always)]
    pub(super) fn write_cell_outputs<S: pulp::Simd>(&mut self, simd: S) {
        let (r, n, na, ld) = (self.r, self.n_segments, self.na, self.ld32);
        const S: usize = N_STATE;
        for k in 0..2 {
            let c = &self.cell_c[k];
            let force = &mut self.cols[..r];
            force.fill(0.0);
            for s in 0..S {
                if c[s] != 0.0 {
                    axpy(force, c[s], &self.xi[k][s * r..(s + 1) * r]);
                }
            }
            let dst = &mut self.cols32[2 * ld * k..2 * ld * (k + 1)];
            let (dq, df) = dst.split_at_mut(ld);
            for (d, x) in dq.iter_mut().zip(&self.q) {
                *d = *x as f32;
            }
            for (d, x) in df.iter_mut().zip(&self.cols[..r]) {
                *d = *x as f32;
            }
        }
        let mut outs = std::mem::take(&mut self.out);
        {
            let (_, rest) = outs.split_at_mut(na);
            let (o1, o2) = rest.split_at_mut(na);
            Reconstruct::<2> {
                phic: Shapes::new(self.shapes_24.as_deref(), &self.phic32),
                ld,
                n,
                rows: 0..na,
                cols: &self.cols32[..4 * ld],
                out: [o1, o2],
            }
            .with_simd(simd);
        }
        // The free part's cell force per channel (rows as the channels; its steps may be
        // pending: `SegmentArray::set_deferred`).
        let mut free_f = std::mem::take(&mut self.free_force);
        for (k, (off, cnt)) in [(0, n), (n, 2 * n)].into_iter().enumerate() {
            self.free
                .combination(k, &self.cell_c[k], &mut free_f[off..off + cnt]);
        }
        // Channel values (rows: piston channels, then tilt) to actuators, segment by segment.
        let v = self.basis;
        for seg in 0..n {
            let rows = [seg, n + 2 * seg, n + 2 * seg + 1];
            let mut zc = [0.0; 3];
            let mut fc = [0.0; 3];
            for m in 0..3 {
                zc[m] = outs[na + rows[m]];
                fc[m] = free_f[rows[m]] + outs[2 * na + rows[m]] + self.cell_d * zc[m];
            }
            for a in 0..3 {
                let at = |t: &[f64; 3]| v[(a, 0)] * t[0] + v[(a, 1)] * t[1] + v[(a, 2)] * t[2];
                self.z_cell[3 * seg + a] = at(&zc);
                self.f_cell[3 * seg + a] = at(&fc);
            }
        }
        self.out = outs;
        self.free_force = free_f;
        self.cell_stale = false;
    }
}

/// The cell's outputs of [`CoupledMirror::write_cell_outputs`] as one SIMD operation.
pub(super) struct CellOutputs<'a> {
    pub(super) mirror: &'a mut CoupledMirror,
}

impl pulp::WithSimd for CellOutputs<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        self.mirror.write_cell_outputs(simd);
    }
}

/// The coupled part of a communication step (the held inputs onto the modes, the ticks, the
/// outputs back), as one SIMD operation for [`pulp::Arch::dispatch`].
pub(super) struct Step<'a> {
    pub(super) mirror: &'a mut CoupledMirror,
    pub(super) ticks: u64,
    pub(super) pier_z: f64,
}

impl pulp::WithSimd for Step<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        // The large models' forms (two threads, the Gram matrices by half, the correction in
        // two parts) in a function of their own: the step of a model without them compiles
        // without their code.
        if self.mirror.large_forms() {
            simd.vectorize(StepAs::<true>(self));
        } else {
            simd.vectorize(StepAs::<false>(self));
        }
    }
}

/// The free part of one kind's channels over a chunk of ticks ([`CoupledMirror::free_ticks`]):
/// the chunk's composed map (`a`, `b`) from the projected free states `proj` and held inputs
/// `w` into `out`, whose first rows (the states at the chunk's end) become `proj`.
struct FreeKind<'a> {
    a: &'a [[f64; N_STATE]],
    b: &'a [[f64; 2]],
    masks: &'a SourceMasks,
    w: &'a [f64],
    r: usize,
    proj: &'a mut [f64],
    out: &'a mut [f64],
}

impl pulp::WithSimd for FreeKind<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (r, w) = (self.r, self.w);
        rows_map::<S, N_STATE, 2>(
            simd,
            self.a,
            self.b,
            self.masks,
            self.proj,
            [&w[..r], &w[2 * r..3 * r]],
            r,
            self.out,
        );
        self.proj.copy_from_slice(&self.out[..N_STATE * r]);
    }
}

/// The cell-driven channels of one kind over a tick ([`CoupledMirror::tick_channels`]), from
/// the tick's maps (row-major, [`ChannelMaps`]), the ramp's response, the modes `q` and
/// the states `xi`: the states without the ramp into `scratch`, the kind's part of the solve's
/// right-hand side into `psi` and, at a servo sample, the drive's change into `drive_step`.
struct ChannelKind<'a> {
    maps: &'a ChannelMaps,
    ramp: &'a SVector<f64, N_STATE>,
    /// Whether `xi` still lacks the last tick's ramp part (`ramp q`, `q` the modes now).
    pending: bool,
    q: &'a [f64],
    xi: &'a mut [f64],
    scratch: &'a mut [f64],
    psi: &'a mut [f64],
    drive_step: Option<&'a mut [f64]>,
    /// With the modes' terms of the solve already known ([`TickStart`]):
    /// the kind's right-hand side finished here, and in single precision.
    terms: Option<SolveTerms<'a>>,
}

/// A kind's share of the modes' terms of the coupled solve, `psi += e x`, and where its
/// right-hand side and drive change go in single precision (each `r` long).
struct SolveTerms<'a> {
    x: &'a [f64],
    e: f64,
    psi32: &'a mut [f32],
    drive32: Option<&'a mut [f32]>,
}

impl pulp::WithSimd for ChannelKind<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(mut self, simd: S) {
        let r = self.psi.len();
        let maps = self.maps;
        if self.pending {
            RampKind {
                ramp: self.ramp,
                q: self.q,
                xi: &mut *self.xi,
            }
            .with_simd(simd);
        }
        // Cell-driven part without this tick's ramp: Y_i = sum_s p_is xi_s + (g_i1 - ramp_i) q;
        // psi~_k = Y c^T.
        self.psi.fill(0.0);
        state_map::<S, N_STATE, 1>(
            simd,
            &maps.p,
            &maps.g,
            &maps.masks,
            self.xi,
            [self.q],
            r,
            self.scratch,
            Some((&maps.c, self.psi)),
        );
        // The cell-driven part's drive change (the ramp does not reach the drive).
        if let Some(out) = self.drive_step.as_deref_mut() {
            let dr = state::DRIVE;
            let (new, old) = (&self.scratch[dr * r..], &self.xi[dr * r..]);
            for j in 0..r {
                out[j] = new[j] - old[j];
            }
        }
        if let Some(t) = self.terms {
            let (psi, x, e) = (&mut self.psi[..r], &t.x[..r], t.e);
            for ((p, p32), x) in psi.iter_mut().zip(t.psi32.iter_mut()).zip(x) {
                *p += e * x;
                *p32 = *p as f32;
            }
            if let (Some(d32), Some(d)) = (t.drive32, self.drive_step.as_deref()) {
                for (d32, d) in d32.iter_mut().zip(d) {
                    *d32 = *d as f32;
                }
            }
        }
    }
}

/// The ramp part of one kind's cell-driven states after a tick, `xi_s += ramp_s q` for each
/// state the ramp reaches ([`CoupledMirror::tick`]).
struct RampKind<'a> {
    ramp: &'a SVector<f64, N_STATE>,
    q: &'a [f64],
    xi: &'a mut [f64],
}

impl pulp::WithSimd for RampKind<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let r = self.q.len();
        for (s, &c) in self.ramp.iter().enumerate() {
            if c != 0.0 {
                axpy(&mut self.xi[s * r..(s + 1) * r], c, self.q);
            }
        }
    }
}

/// The rows of a chunk's free output for tick `i` of `len` ([`CoupledMirror::free_ticks`]):
/// the modal force over the tick and the drive's change at its sample.
fn free_rows(r: usize, (i, len): (usize, usize)) -> (Range<usize>, Range<usize>) {
    let row = |k: usize| k * r..(k + 1) * r;
    (row(N_STATE + i), row(N_STATE + len + i))
}

/// The per-mode start of a tick ([`CoupledMirror::tick_start`]) in one pass: the held inputs
/// into the start force `u` (the drive's jump, and the pier's change through its gains
/// `b_p`), `h' = h + b_p p` (`h` the free part's modal force over the tick, the sum of the
/// kinds' rows), the modes' free response `abar` (into `cols`), `x = abar + b1 h'` (into
/// `xs`: the modes' terms of the solve) and `h'` into `u_new` (which the solve adds to).
struct TickStart<'a> {
    h: [&'a [f64]; 2],
    pier_gains: &'a [f64],
    a: [&'a [f64]; 2],
    b0: &'a [f64],
    b1: &'a [f64],
    q: &'a [f64],
    v: &'a [f64],
    u: &'a mut [f64],
    xs: &'a mut [f64],
    cols: &'a mut [f64],
    u_new: &'a mut [f64],
    /// The drive's feedthrough into the cell force.
    drive_d: f64,
    /// The pier's change from the last tick, and its value held over this one.
    dp: f64,
    pier: f64,
}

impl TickStart<'_> {
    /// With the modal force's jump at the tick's start by mode (`jump`).
    #[inline(always)]
    fn run(self, jump: impl Fn(usize) -> f64) {
        let r = self.u.len();
        let ([h0, h1], [a0, a1]) = (self.h.map(|h| &h[..r]), self.a.map(|a| &a[..r]));
        let (bp, b0, b1) = (&self.pier_gains[..r], &self.b0[..r], &self.b1[..r]);
        let (q, v, u) = (&self.q[..r], &self.v[..r], self.u);
        let (xs, cols, u_new) = (&mut self.xs[..r], &mut self.cols[..r], &mut self.u_new[..r]);
        let (dd, dp, pier) = (self.drive_d, self.dp, self.pier);
        for j in 0..r {
            let u0 = u[j] + (dd * jump(j) + dp * bp[j]);
            let h = (h0[j] + h1[j]) + pier * bp[j];
            // u+ = W (h + b_p p) + W G_p (psi_p + e_p a) + W G_t (psi_t + e_t a), with
            // W = (I - M B1)^-1 = I + W M B1 and W M = e_p W G_p + e_t W G_t, so that
            // u+ = h' + W G_p (psi_p + e_p x) + W G_t (psi_t + e_t x): one r x 2r product.
            let abar = a0[j] * q[j] + a1[j] * v[j] + (b0[j] - b1[j]) * u0;
            u[j] = u0;
            xs[j] = abar + b1[j] * h;
            cols[j] = abar;
            u_new[j] = h;
        }
    }
}

/// A sample's solve between the pass over the Gram matrices and the correction's, per mode:
/// from the pass's `y = G psi_0` and `g = G drive_step`, the correction's input
/// `D (y + beta g)` (in single precision, times the stored correction's own scale where it
/// has one) into `win`, and `y` added to `u_new`.
struct CorrectionInput<'a> {
    beta: &'a [f64],
    d_half: &'a [f64],
    scale: Option<&'a [f32]>,
    win: &'a mut [f32],
    u_new: &'a mut [f64],
}

impl CorrectionInput<'_> {
    /// With `(y_j, g_j)` from `g`.
    #[inline(always)]
    fn run(self, g: impl Fn(usize) -> (f64, f64)) {
        match self.scale {
            Some(s) => {
                let s = &s[..self.win.len()];
                self.each(g, |j, w| w * s[j]);
            }
            None => self.each(g, |_, w| w),
        }
    }

    #[inline(always)]
    fn each(self, g: impl Fn(usize) -> (f64, f64), scale: impl Fn(usize, f32) -> f32) {
        let r = self.win.len();
        let (beta, d_half) = (&self.beta[..r], &self.d_half[..r]);
        let (win, u_new) = (self.win, &mut self.u_new[..r]);
        for j in 0..r {
            let (y, g) = g(j);
            win[j] = scale(j, (d_half[j] * (y + beta[j] * g)) as f32);
            u_new[j] += y;
        }
    }
}

/// The correction's product in two parts of block rows finished in one pass: each part's
/// column sums `t` (the first part's over every column, the second's from `cut`) added, then
/// the stored matrix's own scale applied where it has one.
fn finish_parts(y: &mut [f64], t: [&[f32]; 2], cut: usize, scale: Option<&[f32]>) {
    #[inline(always)]
    fn each(y: &mut [f64], [t0, t1]: [&[f32]; 2], cut: usize, f: impl Fn(usize, f64) -> f64) {
        let r = y.len();
        let (t0, t1, cut) = (&t0[..r], &t1[..r], cut.min(r));
        for j in 0..cut {
            y[j] = f(j, y[j] + f64::from(t0[j]));
        }
        for j in cut..r {
            y[j] = f(j, (y[j] + f64::from(t0[j])) + f64::from(t1[j]));
        }
    }
    match scale {
        Some(s) => {
            let s = &s[..y.len()];
            each(y, t, cut, |j, c| c * f64::from(s[j]));
        }
        None => each(y, t, cut, |_, c| c),
    }
}

/// The end of a sample's tick in single precision, per mode: the rest of the new modal force
/// `u+ = u_new + D^-1 corr`, the cell-driven jump `g` into the tick's start force
/// (`drive_d g`) and into the free response (`alpha g`, `cols`), and the modes.
struct TickEnd<'a> {
    corr: &'a [f64],
    d_half: &'a [f64],
    u_new: &'a [f64],
    alpha: &'a [f64],
    drive_d: f64,
    cols: &'a [f64],
    modes: ModeUpdate<'a>,
}

impl TickEnd<'_> {
    /// With `g_j` from `g`.
    #[inline(always)]
    fn run(self, g: impl Fn(usize) -> f64) {
        let mut modes = self.modes;
        let r = modes.q.len();
        let (corr, d_half, u_new) = (&self.corr[..r], &self.d_half[..r], &self.u_new[..r]);
        let (alpha, cols, dd) = (&self.alpha[..r], &self.cols[..r], self.drive_d);
        for j in 0..r {
            let g = g(j);
            let u1 = u_new[j] + corr[j] / d_half[j];
            let u0 = modes.u[j] + dd * g;
            modes.advance(j, cols[j] + alpha[j] * g, u0, u1);
        }
    }
}

/// The modes over a tick (`q`, `v`, and the modal force at the tick's start `u`), from
/// their maps' components (`a2`, `a3`, `b0`, `b1q`, `b1v`, `r` long each).
struct ModeUpdate<'a> {
    a2: &'a [f64],
    a3: &'a [f64],
    b0: &'a [f64],
    b1q: &'a [f64],
    b1v: &'a [f64],
    q: &'a mut [f64],
    v: &'a mut [f64],
    u: &'a mut [f64],
}

impl<'a> ModeUpdate<'a> {
    /// From the modes' maps (`a_mode`, `b0`, `b1` of [`CoupledMirror`]) and their state, `r`
    /// long each.
    #[inline(always)]
    fn new(
        a: &'a [Vec<f64>; 4],
        b0: &'a [Vec<f64>; 2],
        b1: &'a [Vec<f64>; 2],
        q: &'a mut [f64],
        v: &'a mut [f64],
        u: &'a mut [f64],
    ) -> Self {
        let r = q.len();
        Self {
            a2: &a[2][..r],
            a3: &a[3][..r],
            b0: &b0[1][..r],
            b1q: &b1[0][..r],
            b1v: &b1[1][..r],
            q,
            v,
            u,
        }
    }

    /// Mode `j` from the tick's free response `cols`, the modal force at the tick's start
    /// `u0` and at its end `u1`: `q+ = cols + b1q u1`, `v+` from the maps, `u = u1`.
    #[inline(always)]
    fn advance(&mut self, j: usize, cols: f64, u0: f64, u1: f64) {
        let (q, v) = (self.q[j], self.v[j]);
        self.q[j] = cols + self.b1q[j] * u1;
        self.v[j] = self.a2[j] * q + self.a3[j] * v + self.b0[j] * u0 + self.b1v[j] * (u1 - u0);
        self.u[j] = u1;
    }
}

/// One tick ([`CoupledMirror::tick`]) as a function of its own.
struct Tick<'a, const LARGE: bool> {
    mirror: &'a mut CoupledMirror,
    pier_z: f64,
    sample: bool,
    at: (usize, usize),
}

impl<const LARGE: bool> pulp::WithSimd for Tick<'_, LARGE> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        self.mirror
            .tick::<S, LARGE>(simd, self.pier_z, self.sample, self.at);
    }
}

/// [`Step`] with or without the large models' forms.
struct StepAs<'a, const LARGE: bool>(Step<'a>);

impl<const LARGE: bool> pulp::WithSimd for StepAs<'_, LARGE> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let Step {
            mirror: m,
            ticks,
            pier_z,
        } = self.0;
        m.project_inputs::<S, LARGE>(simd);
        // The ticks in chunks of at most FREE_CHUNK_TICKS, each with its free part composed.
        let sub = m.substeps as usize;
        let mut t = 0;
        for (phase, len) in m.chunks(ticks as usize * sub) {
            let chunk = m.free_chunk(phase, len);
            m.free_ticks::<S, LARGE>(simd, chunk);
            for i in 0..len {
                simd.vectorize(Tick::<LARGE> {
                    mirror: &mut *m,
                    pier_z,
                    sample: (t + i).is_multiple_of(sub),
                    at: (i, len),
                });
            }
            t += len;
        }
        m.flush_ramp::<S, LARGE>(simd);
        m.write_outputs::<S, LARGE>(simd);
    }
}

/// `dst` (two kinds of `ld` entries) from `src` (two kinds of `r`) in single precision; the
/// padding past each kind's `r` stays as it is (zero).
#[inline(always)]
fn kinds_to_f32(dst: &mut [f32], src: &[f64], r: usize, ld: usize) {
    for (d, s) in dst.chunks_exact_mut(ld).zip(src.chunks_exact(r)) {
        for (d, s) in d.iter_mut().zip(s) {
            *d = *s as f32;
        }
    }
}

/// `here` and `there` as SIMD operations: at once on the two threads of `pair`, or one after the
/// other on this thread without it.
#[inline(always)]
fn both<S, A, B>(simd: S, pair: Option<&mut Pair>, here: A, there: B)
where
    S: pulp::Simd,
    A: pulp::WithSimd<Output = ()>,
    B: pulp::WithSimd<Output = ()> + Send,
{
    match pair {
        Some(p) => p.join(|| simd.vectorize(here), move || simd.vectorize(there)),
        None => {
            here.with_simd(simd);
            there.with_simd(simd);
        }
    }
}

/// The helper pair when a model splits its products (started on first use; never in the
/// instance without the large models' forms).
fn pair<const LARGE: bool>(lazy: &mut LazyPair, two: bool) -> Option<&mut Pair> {
    if LARGE && two { lazy.get() } else { None }
}

/// Where a product of `m` rows is split between the two threads: half, rounded down to whole
/// groups of four rows (each row's sum is the same wherever the split falls; this keeps the
/// kernels' four-row groups as they are on one thread).
fn split_rows(m: usize) -> usize {
    (m / 2) & !3
}

/// `y = G_k [psi_k, drive_k]` for one kind's Gram matrix stored by its upper block triangle
/// ([`sym_dot_f32`]), as a SIMD operation.
struct GramKind<'a> {
    a: &'a SymPacked32,
    x: [&'a [f32]; 2],
    y: [&'a mut [f64]; 2],
    t: [&'a mut [f32]; 2],
}

impl pulp::WithSimd for GramKind<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let mut y = self.y;
        for yl in y.iter_mut() {
            yl.fill(0.0);
        }
        sym_dot_f32::<S, 2>(simd, self.a, self.x, y, self.t);
    }
}

/// `y = G_k [psi_k, drive_k]` for one kind's Gram matrix in 24-bit fixed point
/// ([`SymPacked24`]: `G = C G'' C`; the right-hand sides scaled into `xs`, the rows' and the
/// columns' sums added, then the result scaled), as a SIMD operation (the matrix's kernel runs
/// on its own instructions).
struct GramKind24<'a> {
    a: &'a SymPacked24,
    x: [&'a [f32]; 2],
    xs: [&'a mut [f32]; 2],
    y: [&'a mut [f64]; 2],
    t: [&'a mut [f32]; 2],
}

impl pulp::WithSimd for GramKind24<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let (a, c) = (self.a, self.a.scale());
        let [xs0, xs1] = self.xs;
        for (xs, x) in [(&mut *xs0, self.x[0]), (&mut *xs1, self.x[1])] {
            for ((d, v), s) in xs.iter_mut().zip(x).zip(c) {
                *d = v * s;
            }
        }
        let mut y = self.y;
        for yl in y.iter_mut() {
            yl.fill(0.0);
        }
        let [t0, t1] = self.t;
        {
            let [y0, y1] = &mut y;
            a.scaled_rows::<2>(
                [&*xs0, &*xs1],
                [&mut **y0, &mut **y1],
                [&mut *t0, &mut *t1],
                0..a.padded_order() / BLOCK,
            );
        }
        let m = a.order();
        for (yl, tl) in y.into_iter().zip([&*t0, &*t1]) {
            for ((yj, tj), s) in yl[..m].iter_mut().zip(tl).zip(c) {
                *yj = (*yj + f64::from(*tj)) * f64::from(*s);
            }
        }
    }
}

/// A symmetric matrix stored by its upper block triangle, in single precision or (scaled) in
/// half precision or 8-bit fixed point.
#[derive(Clone, Copy)]
enum Stored<'a> {
    Single(&'a SymPacked32),
    Half(&'a SymPackedHalf),
    Fixed8(&'a SymPacked8),
}

impl<'a> From<&'a LowCorrection> for Stored<'a> {
    fn from(c: &'a LowCorrection) -> Self {
        match c {
            LowCorrection::Half(a) => Self::Half(a),
            LowCorrection::Fixed8(a) => Self::Fixed8(a),
        }
    }
}

/// Block rows of a symmetric product ([`sym_dot_rows_f32`], or scaled
/// [`SymScaled::scaled_rows`](crate::linalg::symmetric_scaled::SymScaled::scaled_rows) on its
/// own instructions, whatever the SIMD operation's: `x` already scaled) as a SIMD operation.
struct SymRows<'a, const L: usize> {
    a: Stored<'a>,
    x: [&'a [f32]; L],
    y: [&'a mut [f64]; L],
    t: [&'a mut [f32]; L],
    blocks: std::ops::Range<usize>,
}

impl<const L: usize> pulp::WithSimd for SymRows<'_, L> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        match self.a {
            Stored::Single(a) => {
                sym_dot_rows_f32::<S, L>(simd, a, self.x, self.y, self.t, self.blocks);
            }
            Stored::Half(a) => a.scaled_rows::<L>(self.x, self.y, self.t, self.blocks),
            Stored::Fixed8(a) => a.scaled_rows::<L>(self.x, self.y, self.t, self.blocks),
        }
    }
}

/// `y_l += A x_l` for `C` (1 or 2) right-hand sides ([`rows_dot_f32`], [`rows_dot2_f32`]) as a
/// SIMD operation, split by rows between a [`Pair`]'s threads ([`Self::split`]).
struct RowsDot<'a, const C: usize> {
    a: &'a [f32],
    lda: usize,
    m: usize,
    k: usize,
    x: [&'a [f32]; C],
    y: [&'a mut [f64]; C],
}

impl<const C: usize> pulp::WithSimd for RowsDot<'_, C> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (a, lda, m, k) = (self.a, self.lda, self.m, self.k);
        let mut y = self.y;
        match (&self.x[..], &mut y[..]) {
            ([x], [y]) => rows_dot_f32::<S>(simd, a, lda, m, k, x, y),
            ([x0, x1], [y0, y1]) => rows_dot2_f32::<S>(simd, a, lda, m, k, [x0, x1], [y0, y1]),
            _ => unreachable!("RowsDot: 1 or 2 right-hand sides"),
        }
    }
}

impl<const C: usize> RowsDot<'_, C> {
    /// The product, on this thread alone without `pair`.
    #[inline(always)]
    fn split<S: pulp::Simd>(self, simd: S, pair: Option<&mut Pair>) {
        let Some(p) = pair else {
            return self.with_simd(simd);
        };
        let (h, lda, k, x) = (split_rows(self.m), self.lda, self.k, self.x);
        let (mut lo, mut hi): ([&mut [f64]; C], [&mut [f64]; C]) = (
            std::array::from_fn(|_| Default::default()),
            std::array::from_fn(|_| Default::default()),
        );
        for (l, y) in self.y.into_iter().enumerate() {
            (lo[l], hi[l]) = y.split_at_mut(h);
        }
        let (a_hi, rest) = (&self.a[h * lda..], self.m - h);
        let a = self.a;
        p.join(
            || {
                simd.vectorize(RowsDot {
                    a,
                    lda,
                    m: h,
                    k,
                    x,
                    y: lo,
                });
            },
            move || {
                simd.vectorize(RowsDot {
                    a: a_hi,
                    lda,
                    m: rest,
                    k,
                    x,
                    y: hi,
                });
            },
        );
    }
}
