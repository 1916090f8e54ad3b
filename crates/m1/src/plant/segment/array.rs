//! All segments of a mirror stepped together ([`SegmentArray`]): the 3N channels as a structure
//! of arrays with one pair of tick maps per channel kind, communication steps that need not
//! align with the servo samples, and the outputs back in actuator order.

use nalgebra::SMatrix;
use serde::{Deserialize, Serialize};

use super::model::SegmentModel;
use super::sampled::propagate;
use super::{Channel, Gamma, N_IN, N_STATE, Phi, modal_basis, state};
use crate::M1Error;
use crate::linalg::kernels::{SourceMasks, rows_map, state_map};

/// Propagators of both channel kinds for one step size.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct StepMaps {
    ticks: u64,
    p: [Phi; 2],
    s: [Gamma; 2],
}

/// Most whole steps on unchanged inputs that a deferring array ([`SegmentArray::set_deferred`])
/// leaves pending before it applies them: the size of its table of step maps' powers. The
/// standard systems' inputs change at most every tenth 1 ms step (the 100 Hz wind).
pub const MAX_PENDING_STEPS: usize = 16;

/// Whole steps taken on unchanged inputs and not yet applied to the states
/// ([`SegmentArray::set_deferred`]): the channels' states are `P^n x + S_n w` with `n` the
/// pending steps, `(P^n, S_n)` the `n`-step map of the step map `(P, S)` (of `StepMaps`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
struct Pending {
    on: bool,
    steps: usize,
    /// Per kind, `(P^n, S_n)` for `n = 1, 2, ...` as far as used, for the current step map.
    powers: [Vec<(Phi, Gamma)>; 2],
}

/// All segments of a mirror, stepped together.
///
/// Arrays in and out are in actuator order, segment-major: actuator k of segment i at 3 i + k.
/// Internally the 3N channels are stored by state (structure of arrays): piston channels of all
/// segments, then tilt channels (two per segment).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SegmentArray {
    n_segments: usize,
    model: SegmentModel,
    tick: [Phi; 2],
    tick_in: [Gamma; 2],
    cell_c: [SMatrix<f64, 1, N_STATE>; 2],
    cell_d: [SMatrix<f64, 1, N_IN>; 2],
    basis: SMatrix<f64, 3, 3>,
    maps: StepMaps,
    /// Time since the last servo sample (s), in [0, servo period).
    pub(super) phase: f64,
    /// State by kind: `x[kind][s * n + c]` for state s of channel c.
    pub(super) x: [Vec<f64>; 2],
    /// Scratch for the next state.
    next: [Vec<f64>; 2],
    /// Modal inputs by kind: `w[kind][l * n + c]`.
    w: [Vec<f64>; 2],
    /// A deferring array's new inputs, beside the held ones in `w` until the pending steps on
    /// those are applied.
    w_next: [Vec<f64>; 2],
    /// The inputs of the last step as given (actuator order: command, cell displacement, wind
    /// forces), kept by a deferring array: inputs equal to them to the bit are not projected
    /// onto the channels again.
    #[serde(default)]
    last: [Vec<f64>; N_IN],
    /// Whether the last step's inputs were those of the step before, to the bit (a deferring
    /// array's; false otherwise).
    #[serde(default)]
    inputs_same: bool,
    /// The steps left pending (a deferring array only).
    pending: Pending,
}

impl SegmentArray {
    /// A mirror of `n_segments` identical segments, at rest.
    pub fn new(n_segments: usize, model: SegmentModel) -> Result<Self, M1Error> {
        model.validate()?;
        let (pp, gp) = model.closed_loop(Channel::Piston);
        let (pt, gt) = model.closed_loop(Channel::Tilt);
        let (cp, dp) = model.cell_force_map(Channel::Piston);
        let (ct, dt) = model.cell_force_map(Channel::Tilt);
        let counts = [n_segments, 2 * n_segments];
        Ok(Self {
            n_segments,
            tick: [pp, pt],
            tick_in: [gp, gt],
            cell_c: [cp, ct],
            cell_d: [dp, dt],
            basis: modal_basis(),
            maps: StepMaps {
                ticks: 1,
                p: [pp, pt],
                s: [gp, gt],
            },
            phase: 0.0,
            x: counts.map(|n| vec![0.0; N_STATE * n]),
            next: counts.map(|n| vec![0.0; N_STATE * n]),
            w: counts.map(|n| vec![0.0; N_IN * n]),
            w_next: counts.map(|n| vec![0.0; N_IN * n]),
            last: Default::default(),
            inputs_same: false,
            pending: Pending::default(),
            model,
        })
    }

    /// Whether whole steps on unchanged inputs are left pending (off by default): the states
    /// then stay as they were when the inputs last changed (or [`MAX_PENDING_STEPS`] steps
    /// ago), and the steps since are applied at once, by the power of the step map: with the
    /// step that brings new inputs (one pass over the states with both sets of inputs), or
    /// when the step differs, or when [`Self::settle`] is called. A step whose inputs have not
    /// changed writes no state, and what the caller needs of them comes from
    /// [`Self::combination`] (one dot product of the pending map's row per channel, against a
    /// full map of the states per step). Inputs that change at every step are stepped as
    /// without it, to the bit. Otherwise the values are those of stepping every time, to
    /// rounding (the pending map's products are summed in another order). For a caller that
    /// reads only combinations of the states between changes of its inputs: the coupled
    /// mirror's free part (the mirror's displacement every step, the cell's force when read).
    pub fn set_deferred(&mut self, on: bool) {
        if !on {
            self.settle();
        }
        self.pending.on = on;
    }

    /// Applies the pending steps ([`Self::set_deferred`]) to the states: afterwards
    /// [`Self::state`] is current.
    pub fn settle(&mut self) {
        let n = std::mem::take(&mut self.pending.steps);
        if n > 0 {
            let maps = [0, 1].map(|k| self.pending.powers[k][n - 1]);
            self.apply(&maps);
        }
    }

    /// Whether the last step's inputs were those of the step before, to the bit, so that the
    /// inputs on the channels did not change: known to a deferring array
    /// only ([`Self::set_deferred`]; false otherwise).
    pub fn inputs_unchanged(&self) -> bool {
        self.inputs_same
    }

    /// Whole steps pending ([`Self::set_deferred`]).
    pub fn pending_steps(&self) -> usize {
        self.pending.steps
    }

    /// `c x_j` for every channel `j` of kind `kind` (0 piston, 1 tilt), `x_j` its current
    /// state (with the pending steps: [`Self::set_deferred`]), into `out` (one per channel of
    /// the kind: `n` piston or `2n` tilt).
    ///
    /// # Panics
    /// If `kind` is not 0 or 1 or `out` is shorter than the kind's channels (programming
    /// errors).
    pub fn combination(&self, kind: usize, c: &SMatrix<f64, 1, N_STATE>, out: &mut [f64]) {
        let x = &self.x[kind];
        let n = x.len() / N_STATE;
        let out = &mut out[..n];
        let steps = self.pending.steps;
        if steps == 0 {
            let one = c
                .iter()
                .position(|&v| v != 0.0)
                .filter(|&s| c[s] == 1.0 && c.iter().filter(|&&v| v != 0.0).count() == 1);
            match one {
                // A single state: a copy.
                Some(st) => out.copy_from_slice(&x[st * n..(st + 1) * n]),
                None => {
                    out.fill(0.0);
                    for (st, &cs) in c.iter().enumerate() {
                        if cs != 0.0 {
                            crate::linalg::kernels::axpy(out, cs, &x[st * n..(st + 1) * n]);
                        }
                    }
                }
            }
            return;
        }
        let (p, g) = &self.pending.powers[kind][steps - 1];
        let a = c * p;
        let b = c * g;
        pulp::Arch::new().dispatch(Combination {
            a: [std::array::from_fn(|j| a[j])],
            b: [std::array::from_fn(|l| b[l])],
            n,
            x,
            w: &self.w[kind],
            out,
        });
    }

    /// `(P^n, S_n)` of the current step map for `n` of `1..=MAX_PENDING_STEPS` steps, made
    /// once per step map.
    fn extend_powers(&mut self, n: usize) {
        for k in 0..2 {
            let (p1, s1) = (self.maps.p[k], self.maps.s[k]);
            let pw = &mut self.pending.powers[k];
            while pw.len() < n {
                pw.push(match pw.last() {
                    None => (p1, s1),
                    // n + 1 steps: n, then one more.
                    Some((p, s)) => (p1 * p, p1 * s + s1),
                });
            }
        }
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// Number of actuators (3 per segment).
    pub fn n_actuators(&self) -> usize {
        3 * self.n_segments
    }

    /// The model parameters.
    pub fn model(&self) -> &SegmentModel {
        &self.model
    }

    /// Back to rest.
    pub fn reset(&mut self) {
        for x in &mut self.x {
            x.fill(0.0);
        }
        self.phase = 0.0;
        self.pending.steps = 0;
    }

    fn check_len(what: &'static str, v: &[f64], n: usize) -> Result<(), M1Error> {
        if v.len() == n {
            Ok(())
        } else {
            Err(M1Error::SizeMismatch {
                what,
                expected: n,
                found: v.len(),
            })
        }
    }

    /// Advances `ticks` servo periods with the inputs held (actuator order, lengths 3N).
    pub fn step(
        &mut self,
        ticks: u64,
        u_cmd: &[f64],
        z_cell: &[f64],
        f_wind: &[f64],
    ) -> Result<(), M1Error> {
        let h = ticks as f64 * self.model.servo_period();
        self.advance(h, u_cmd, z_cell, f_wind)
    }

    /// Advances `h` seconds with the inputs held (actuator order, lengths 3N). The servo samples
    /// at its own instants, multiples of its period from the start: a step that ends between two
    /// samples carries the drive over into the next step, so any sequence of steps gives the
    /// trajectory of one long step with the same held inputs.
    pub fn advance(
        &mut self,
        h: f64,
        u_cmd: &[f64],
        z_cell: &[f64],
        f_wind: &[f64],
    ) -> Result<(), M1Error> {
        let na = self.n_actuators();
        Self::check_len("u_cmd", u_cmd, na)?;
        Self::check_len("z_cell", z_cell, na)?;
        Self::check_len("f_wind", f_wind, na)?;
        if !(h.is_finite() && h >= 0.0) {
            return Err(M1Error::InvalidParameter {
                name: "communicationStepSize",
                value: h,
                reason: "must be finite and >= 0",
            });
        }
        let ts = self.model.servo_period();
        // Sample instants closer than this are the same instant (rounding of step sums).
        let eps = 1e-9 * ts;
        if self.pending.on {
            // The new inputs beside the held ones: a step of the same length on the same
            // inputs from a servo sample is left pending.
            self.inputs_same = self.same_as_last([u_cmd, z_cell, f_wind]);
            let changed = !self.inputs_same;
            if changed {
                self.load_next(u_cmd, z_cell, f_wind);
            }
            let whole = (h + eps) / ts;
            let ticks = whole.floor();
            let regular = self.phase == 0.0
                && ticks >= 1.0
                && h - ticks * ts <= eps
                && ticks as u64 == self.maps.ticks;
            if regular && !changed && self.pending.steps < MAX_PENDING_STEPS {
                self.pending.steps += 1;
                self.extend_powers(self.pending.steps);
                return Ok(());
            }
            if regular && changed {
                // The pending steps on the held inputs and this one on the new, in one pass:
                // x <- P^(n+1) x + P S_n w + S w_next (a plain step when none is pending).
                let n = std::mem::take(&mut self.pending.steps);
                if n == 0 {
                    std::mem::swap(&mut self.w, &mut self.w_next);
                    let maps = [0, 1].map(|k| (self.maps.p[k], self.maps.s[k]));
                    self.apply(&maps);
                } else {
                    self.extend_powers(n + 1);
                    self.apply_across(n);
                    std::mem::swap(&mut self.w, &mut self.w_next);
                }
                return Ok(());
            }
            self.settle();
            if changed {
                std::mem::swap(&mut self.w, &mut self.w_next);
            }
            if regular {
                // As many steps pending as the table holds: one more, from them.
                self.pending.steps = 1;
                return Ok(());
            }
        } else {
            self.inputs_same = false;
            self.load_inputs(u_cmd, z_cell, f_wind);
        }
        let mut rest = h;
        if self.phase > 0.0 {
            // Finish the servo period under way: plant only, drive held.
            let d = (ts - self.phase).min(rest);
            if d > eps {
                let maps = Channel::ALL.map(|ch| self.model.plant_only(ch, d));
                self.apply(&maps);
            }
            self.phase += d;
            rest -= d;
            if ts - self.phase > eps {
                return Ok(());
            }
            self.phase = 0.0;
        }
        let ticks = ((rest + eps) / ts).floor();
        if ticks >= 1.0 {
            let ticks = ticks as u64;
            if self.maps.ticks != ticks {
                let (p0, s0) = propagate(&self.tick[0], &self.tick_in[0], ticks);
                let (p1, s1) = propagate(&self.tick[1], &self.tick_in[1], ticks);
                self.maps = StepMaps {
                    ticks,
                    p: [p0, p1],
                    s: [s0, s1],
                };
                // (No step is pending here: the pending ones were applied above.)
                self.pending.powers = Default::default();
            }
            let maps = [
                (self.maps.p[0], self.maps.s[0]),
                (self.maps.p[1], self.maps.s[1]),
            ];
            self.apply(&maps);
            rest -= ticks as f64 * ts;
        }
        if rest > eps {
            // A servo sample, then part of its period.
            let maps = Channel::ALL.map(|ch| self.model.closed_loop_over(ch, rest));
            self.apply(&maps);
            self.phase = rest;
        }
        Ok(())
    }

    /// `x <- P^(n+1) x + P S_n w + S w_next` per kind, in one pass: `n` pending steps on the
    /// held inputs `w`, then one step of the step map `(P, S)` on the new ones, `w_next`.
    fn apply_across(&mut self, n: usize) {
        for k in 0..2 {
            let (p1, s1) = (self.maps.p[k], self.maps.s[k]);
            let (pn1, _) = self.pending.powers[k][n];
            let held = p1 * self.pending.powers[k][n - 1].1;
            let cnt = self.x[k].len() / N_STATE;
            let a: [[f64; N_STATE]; N_STATE] =
                std::array::from_fn(|i| std::array::from_fn(|j| pn1[(i, j)]));
            let b: [[f64; 2 * N_IN]; N_STATE] = std::array::from_fn(|i| {
                std::array::from_fn(|l| {
                    if l < N_IN {
                        held[(i, l)]
                    } else {
                        s1[(i, l - N_IN)]
                    }
                })
            });
            pulp::Arch::new().dispatch(ApplyAcross {
                a: &a,
                b: &b,
                n: cnt,
                x: &self.x[k],
                w: [&self.w[k], &self.w_next[k]],
                next: &mut self.next[k],
            });
            std::mem::swap(&mut self.x[k], &mut self.next[k]);
        }
    }

    /// Applies one linear map per channel kind to every channel: X <- P X + S w, in one pass
    /// over the states ([`ApplyMaps`], compiled for the processor's vector instructions).
    fn apply(&mut self, maps: &[(Phi, Gamma); 2]) {
        for (k, (p, s)) in maps.iter().enumerate() {
            let n = self.x[k].len() / N_STATE;
            pulp::Arch::new().dispatch(ApplyMaps {
                p,
                s,
                n,
                x: &self.x[k],
                w: &self.w[k],
                next: &mut self.next[k],
            });
            std::mem::swap(&mut self.x[k], &mut self.next[k]);
        }
    }

    /// Whether `inputs` are those of the last step to the bit; if not, they are kept as the
    /// last ones. (Equal inputs project onto the same channel inputs.)
    fn same_as_last(&mut self, inputs: [&[f64]; N_IN]) -> bool {
        let same = self
            .last
            .iter()
            .zip(inputs)
            .all(|(last, now)| last.len() == now.len() && same_bits(last, now));
        if !same {
            for (last, now) in self.last.iter_mut().zip(inputs) {
                last.clear();
                last.extend_from_slice(now);
            }
        }
        same
    }

    /// [`Self::load_inputs`] into `w_next` (`w` keeps the held inputs).
    fn load_next(&mut self, u_cmd: &[f64], z_cell: &[f64], f_wind: &[f64]) {
        std::mem::swap(&mut self.w, &mut self.w_next);
        self.load_inputs(u_cmd, z_cell, f_wind);
        std::mem::swap(&mut self.w, &mut self.w_next);
    }

    /// Projects actuator-space inputs onto the channels: q = V^T a per segment.
    fn load_inputs(&mut self, u_cmd: &[f64], z_cell: &[f64], f_wind: &[f64]) {
        let n = self.n_segments;
        let v = self.basis;
        let [wp, wt] = &mut self.w;
        for (l, input) in [u_cmd, z_cell, f_wind].into_iter().enumerate() {
            let (p, t) = (
                &mut wp[l * n..(l + 1) * n],
                &mut wt[l * 2 * n..(l + 1) * 2 * n],
            );
            for ((a, p), t) in input.chunks_exact(3).zip(p).zip(t.chunks_exact_mut(2)) {
                *p = v[(0, 0)] * a[0] + v[(1, 0)] * a[1] + v[(2, 0)] * a[2];
                t[0] = v[(0, 1)] * a[0] + v[(1, 1)] * a[1] + v[(2, 1)] * a[2];
                t[1] = v[(0, 2)] * a[0] + v[(1, 2)] * a[1] + v[(2, 2)] * a[2];
            }
        }
    }

    /// The outputs at the current time: mirror displacement `z` and force on the cell `f_cell`
    /// at each actuator (lengths 3N), with the current cell displacement `z_cell`.
    pub fn outputs(
        &self,
        z_cell: &[f64],
        z: &mut [f64],
        f_cell: &mut [f64],
    ) -> Result<(), M1Error> {
        let na = self.n_actuators();
        Self::check_len("z_cell", z_cell, na)?;
        Self::check_len("z", z, na)?;
        Self::check_len("f_cell", f_cell, na)?;
        let n = self.n_segments;
        let v = self.basis;
        let mp = state::MIRROR_POS;
        for seg in 0..n {
            // Modal mirror displacement and cell force of the three channels of this segment.
            let idx = [
                (0usize, seg, n),
                (1, 2 * seg, 2 * n),
                (1, 2 * seg + 1, 2 * n),
            ];
            let zc = &z_cell[3 * seg..3 * seg + 3];
            let mut qz = [0.0; 3];
            let mut qf = [0.0; 3];
            for (m, &(k, c, nk)) in idx.iter().enumerate() {
                let x = &self.x[k];
                qz[m] = x[mp * nk + c];
                let cc = &self.cell_c[k];
                let mut f = 0.0;
                for s in 0..N_STATE {
                    f += cc[s] * x[s * nk + c];
                }
                qf[m] = f;
            }
            for a in 0..3 {
                z[3 * seg + a] = v[(a, 0)] * qz[0] + v[(a, 1)] * qz[1] + v[(a, 2)] * qz[2];
                f_cell[3 * seg + a] = v[(a, 0)] * qf[0] + v[(a, 1)] * qf[1] + v[(a, 2)] * qf[2];
            }
            // The cell-displacement feedthrough is the same for both kinds (actuator spring),
            // so it maps actuator by actuator.
            let d = self.cell_d[0][1];
            for a in 0..3 {
                f_cell[3 * seg + a] += d * zc[a];
            }
        }
        Ok(())
    }

    /// The inputs held over the last step in the piston/tilt channel basis, by kind: column-major
    /// `count x 3` (`u_cmd`, `z_cell`, `f_wind`; count = N piston or 2N tilt channels).
    pub(crate) fn channel_inputs(&self) -> [&[f64]; 2] {
        [&self.w[0], &self.w[1]]
    }

    /// The full state, by kind (piston, tilt), for checkpoints: the current one unless steps
    /// are pending ([`Self::set_deferred`], [`Self::settle`]).
    pub fn state(&self) -> [&[f64]; 2] {
        [&self.x[0], &self.x[1]]
    }
}

/// `next = P x + S w` for `n` channels stored by state (`x[j n + c]`, `w[l n + c]`), a SIMD
/// operation for [`pulp::Arch::dispatch`]: one pass of [`state_map`] (each vector of channels
/// read once, its new states written once).
struct ApplyMaps<'a> {
    p: &'a Phi,
    s: &'a Gamma,
    n: usize,
    x: &'a [f64],
    w: &'a [f64],
    next: &'a mut [f64],
}

impl pulp::WithSimd for ApplyMaps<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (p, s, n) = (self.p, self.s, self.n);
        let a: [[f64; N_STATE]; N_STATE] =
            std::array::from_fn(|i| std::array::from_fn(|j| p[(i, j)]));
        let b: [[f64; N_IN]; N_STATE] = std::array::from_fn(|i| std::array::from_fn(|l| s[(i, l)]));
        let u: [&[f64]; N_IN] = std::array::from_fn(|l| &self.w[l * n..(l + 1) * n]);
        let masks = SourceMasks::of(&a, &b);
        state_map::<S, N_STATE, N_IN>(simd, &a, &b, &masks, self.x, u, n, self.next, None);
    }
}

/// Whether `a` and `b` (of the same length) hold the same values to the bit: their bits
/// xor-ed and or-ed over sixteen lanes, so that the loop vectorises.
fn same_bits(a: &[f64], b: &[f64]) -> bool {
    let mut lanes = [0u64; 16];
    let (ca, cb) = (a.chunks_exact(16), b.chunks_exact(16));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..16 {
            lanes[l] |= x[l].to_bits() ^ y[l].to_bits();
        }
    }
    let rest = ra
        .iter()
        .zip(rb)
        .fold(0, |acc, (x, y)| acc | (x.to_bits() ^ y.to_bits()));
    lanes.iter().fold(rest, |acc, l| acc | l) == 0
}

/// `out_c = a x_c + b w_c` over `n` channels stored by state (one row of [`state_map`]'s
/// maps), a SIMD operation for [`pulp::Arch::dispatch`].
struct Combination<'a> {
    a: [[f64; N_STATE]; 1],
    b: [[f64; N_IN]; 1],
    n: usize,
    x: &'a [f64],
    w: &'a [f64],
    out: &'a mut [f64],
}

impl pulp::WithSimd for Combination<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let n = self.n;
        let u: [&[f64]; N_IN] = std::array::from_fn(|l| &self.w[l * n..(l + 1) * n]);
        let masks = SourceMasks::of(&self.a, &self.b);
        rows_map::<S, N_STATE, N_IN>(simd, &self.a, &self.b, &masks, self.x, u, n, self.out);
    }
}

/// `next = A x + B [w; w_next]` for `n` channels stored by state ([`SegmentArray::apply_across`]),
/// a SIMD operation for [`pulp::Arch::dispatch`]: one pass of [`state_map`] with both input sets.
struct ApplyAcross<'a> {
    a: &'a [[f64; N_STATE]; N_STATE],
    b: &'a [[f64; 2 * N_IN]; N_STATE],
    n: usize,
    x: &'a [f64],
    w: [&'a [f64]; 2],
    next: &'a mut [f64],
}

impl pulp::WithSimd for ApplyAcross<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let n = self.n;
        let u: [&[f64]; 2 * N_IN] =
            std::array::from_fn(|l| &self.w[l / N_IN][(l % N_IN) * n..(l % N_IN + 1) * n]);
        let masks = SourceMasks::of(self.a, self.b);
        state_map::<S, N_STATE, { 2 * N_IN }>(
            simd, self.a, self.b, &masks, self.x, u, n, self.next, None,
        );
    }
}
