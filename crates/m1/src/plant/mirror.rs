//! The segments and the structure solved together: the mirror on its flexible cell.
//!
//! # Why one solver
//!
//! The actuators tie every segment stiffly to the cell: the encoder servo (5 kHz) makes a voice
//! coil stiff up to its bandwidth, a piezo stack is stiff outright. Exchanged between two
//! components with a communication step, the actuator force and the cell displacement each lag
//! by a step, and that delay feeds energy into the coupled modes. Measured with the built-in
//! cell (Keck, all 109 modes): Gauss-Seidel exchange diverges at 0.5 ms for the voice coil and
//! at every step tried down to 0.1 ms for the piezo. The coupling therefore has to be solved
//! without delay, at the servo rate, which is what this solver does.
//!
//! # Scheme
//!
//! Per servo tick $T_s$ (the servo samples at the start of the tick, its drive is then held):
//! - each segment channel (see [`crate::plant::segment`]) is advanced exactly with the cell
//!   displacement **ramping linearly** over the tick from $z_n$ to $z_{n+1}$ (first-order hold):
//!   $X_{n+1} = \Phi X_n + \Gamma w_n + \gamma\,\Delta$, $\Delta = z_{n+1} - z_n$, where
//!   $\gamma$ is the exact response to a unit ramp;
//! - each retained structural mode is advanced exactly with its modal force ramping from its
//!   value just after the sample, $u_n^+$, to $u_{n+1}$:
//!   $[q, \dot q]_{n+1} = A [q, \dot q]_n + b_0 u_n^+ + b_1 (u_{n+1} - u_n^+)$. The servo's
//!   drive and the pier input are held over the tick and feed the cell force directly, so the
//!   force jumps at the sample: $u_n^+ = u_n + \Phi_a^T d_u (\delta_n - \delta_{n-1}) +
//!   b_p (p_n - p_{n-1})$, with $\delta$ the drive and $d_u$ its feedthrough. Only the
//!   continuous part of the force is interpolated. (Ramping across the jump instead delays the
//!   drive by half a servo period: measured against the monolithic model of
//!   [`crate::plant::monolithic`], that put the Keck voice-coil mirror's response to a 30 Hz pier tone
//!   1.6 % off, against 0.13 % with the jump.);
//! - the two are consistent at the end of the tick: $u_{n+1} = \Phi_a^T f_{n+1} + b_p p$ with
//!   $f_{n+1} = a_f + E\Delta$ the actuator forces on the cell and $\Delta = \Phi_a (q_{n+1} -
//!   q_n)$. Eliminating $f$ and $\Delta$ leaves one $r \times r$ linear system in the modal forces
//!   ($r$ retained modes), $(I - M B_1) u_{n+1} = \Phi_a^T a_f + b_p p + M c$, with
//!   $M = \Phi_a^T E \Phi_a$ and $B_1 = \mathrm{diag}(b_{1,q})$ constant: it is inverted once.
//!
//! $E$ is block diagonal (one 3x3 block per segment, diagonal in the piston/tilt basis), so
//! $M$ is formed once.
//!
//! **Carried on the modes.** The segments are identical, so their channel dynamics commute with
//! the mode shapes (the seed paper's change-of-basis argument): the part of every channel's
//! state driven by the cell motion is $\Phi_k \xi_k$, with $\xi_k$ ($r \times 10$ per channel kind)
//! stepped by the same per-tick maps on the modal coordinates. The part driven by the command and
//! the wind is stepped per communication step in actuator space, and its projection on the modes
//! per tick. A tick then costs $O(r^2)$ (two $r \times r$ products and $O(r)$ axpys of the
//! 10-state maps) and never touches the $na \times r$ shapes, which are used twice per
//! communication step (projecting the held inputs, reconstructing the outputs). The two
//! formulations agree to 2e-13 (checked when this one replaced the per-actuator one).
//!
//! **Memory-bound products.** At TMT size with 300 modes the shapes are 3.5 MB and the two
//! coupling matrices 1.4 MB: a step streams about 14 MB, and arithmetic is cheap beside it. The
//! shapes and the coupling matrices are stored row-major and multiplied by the streaming
//! kernels of [`crate::linalg::kernels`] (each matrix read once, every right-hand side applied while a
//! chunk is in registers), and the whole coupled part of a step runs inside one
//! [`pulp::Arch::dispatch`], so that it is compiled for the processor's vector instructions.
//! The general matrix products used before (which pack their operand first) took 1.44 times as
//! long per step at r = 300 (BENCHMARKS.md). The shapes are streamed in single precision
//! (inputs onto the modes, outputs back: relative error about 1e-7 of the largest term), and so
//! are the Gram matrices that give the modal force of the drive's jump (a correction of the
//! size of the drive's change over one servo period); the coupled solve itself is in double
//! precision.
//!
//! **No static correction.** The structure is its `n_modes` lowest modes. The static correction
//! of the truncated modes (an instantaneous, dense compliance) cannot lag a tick: against the
//! stiff actuators that lag diverges (measured: Keck voice coil with 30 modes, TMT piezo with 60);
//! solved implicitly it would cost $O(na^2)$ per tick. The retained modes converge instead:
//! Keck's response to a pier tone at 5 and 29.6 Hz changes by less than 0.03 % between 30 modes
//! and all 109.
//!
//! The scheme is consistent with the exact per-component discretisations: both sides see the
//! same piecewise-linear cell displacement and the same actuator force, held drive plus
//! linearly interpolated continuous part. What it approximates is the continuous part of the
//! force within a tick: against the exact discretisation of the coupled plant
//! ([`crate::plant::monolithic::StateSpaceMirror`]) the Keck voice-coil mirror's response to a pier tone
//! at 5 or 30 Hz is 0.1-0.2 % off; the piezo's was 0.1 % at 5 Hz and 1.1 % at 30 Hz with the
//! first, 150 N/um stacks, which rang at 1.4 kHz within a tick (today's 4.3 N/um stacks ring at
//! 233 Hz and stay well inside that).

use nalgebra::{DMatrix, SMatrix, SVector};
use serde::{Deserialize, Serialize};

use crate::M1Error;
use crate::linalg::kernels::{axpy, rows_axpy2_f32, rows_dot, rows_dot_f32, rows_dot3_f32};
use crate::plant::segment::{
    Channel, Gamma, N_CONT, N_IN, N_STATE, Phi, SegmentArray, SegmentModel, modal_basis, state,
};
use crate::plant::structure::{Flexibility, ModalModel, ModalSolver};

/// Exact response of one mode over `h` to its state, a held force and a force ramp:
/// `(A, b0, b1)` with `A` row-major 2x2 and `b0`, `b1` the (q, q') responses to a unit held
/// force and to a force rising linearly from 0 to 1 over the step.
pub fn foh_mode(w: f64, zeta: f64, h: f64) -> ([f64; 4], [f64; 2], [f64; 2]) {
    // State (q, v, u0, rho, sigma): v' = -w^2 q - 2 zeta w v + u0 + rho, rho' = sigma / h.
    let mut m = SMatrix::<f64, 5, 5>::zeros();
    m[(0, 1)] = 1.0;
    m[(1, 0)] = -w * w;
    m[(1, 1)] = -2.0 * zeta * w;
    m[(1, 2)] = 1.0;
    m[(1, 3)] = 1.0;
    m[(3, 4)] = 1.0 / h;
    let e = (m * h).exp();
    (
        [e[(0, 0)], e[(0, 1)], e[(1, 0)], e[(1, 1)]],
        [e[(0, 2)], e[(1, 2)]],
        [e[(0, 4)], e[(1, 4)]],
    )
}

/// Exact response of a segment channel's continuous part over one tick to a cell displacement
/// rising linearly from 0 to 1 (drive and other inputs zero).
fn channel_ramp(model: &SegmentModel, ch: Channel, h: f64) -> SVector<f64, N_STATE> {
    const M: usize = N_CONT + 2;
    let p = model.plant(ch);
    let mut m = SMatrix::<f64, M, M>::zeros();
    for i in 0..N_CONT {
        for j in 0..N_CONT {
            m[(i, j)] = p.a[(i, j)];
        }
        m[(i, N_CONT)] = p.b[(i, 1)];
    }
    m[(N_CONT, N_CONT + 1)] = 1.0 / h;
    let e = (m * h).exp();
    let mut g = SVector::<f64, N_STATE>::zeros();
    for i in 0..N_CONT {
        g[i] = e[(i, N_CONT + 1)];
    }
    g
}

/// The maps of one coupled sub-step of `1 / substeps` servo period for a channel, `(P, S)`
/// for the sub-step that starts with the servo's sample and for the others (the drive held),
/// and `gamma`: `X+ = P X + S w + gamma Delta` when the cell displacement ramps by `Delta` over
/// the sub-step.
fn substep_maps(
    model: &SegmentModel,
    ch: Channel,
    substeps: u32,
) -> ([(Phi, Gamma); 2], SVector<f64, N_STATE>) {
    let d = model.servo_period() / f64::from(substeps);
    (
        [model.closed_loop_over(ch, d), model.plant_only(ch, d)],
        channel_ramp(model, ch, d),
    )
}

/// Every segment on its actuators, coupled without delay to a modal model of the cell.
///
/// Arrays in and out are in actuator order (actuator k of segment i at 3 i + k).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CoupledMirror {
    n_segments: usize,
    model: SegmentModel,
    /// The servo period.
    ts: f64,
    /// Coupled sub-steps per servo period.
    substeps: u32,
    /// Channel maps of one sub-step, by sub-step kind (with the servo's sample, without) and
    /// channel kind (piston, tilt): X+ = P X + S w + ramp Delta.
    tick: [[Phi; 2]; 2],
    tick_in: [[Gamma; 2]; 2],
    ramp: [SVector<f64, N_STATE>; 2],
    cell_c: [SMatrix<f64, 1, N_STATE>; 2],
    /// Feedthrough of the cell displacement into the cell force (same for both kinds).
    cell_d: f64,
    /// `E` per kind: end-of-tick force per unit ramp of the cell displacement.
    e: [f64; 2],
    basis: SMatrix<f64, 3, 3>,
    /// Free part of the channel states: the segments driven by the command and the wind on a
    /// cell at rest (`zeros`), stepped a communication step at a time.
    free: SegmentArray,
    zeros: Vec<f64>,
    // Structure.
    structure: ModalSolver,
    r: usize,
    na: usize,
    /// Modal FOH maps per mode.
    a_mode: Vec<[f64; 4]>,
    b0: Vec<[f64; 2]>,
    b1: Vec<[f64; 2]>,
    /// Mode shapes in the channel basis (rows: piston channels, then tilt channels 2 s + m),
    /// `na x r` row-major.
    phic: Vec<f64>,
    /// The same in single precision, for the two passes per communication step (inputs onto
    /// the modes, outputs back): half the memory traffic, relative error about 1e-7.
    phic32: Vec<f32>,
    /// Single-precision scratch: the channel inputs by kind (command then wind, `2 n_k`), the
    /// projection's accumulators (`r` each) and the output columns (`6 r`).
    w32: [Vec<f32>; 2],
    acc32: [Vec<f32>; 2],
    cols32: Vec<f32>,
    /// `[W G_p, W G_t]` with `W = (I - M B1)^-1`: r x 2r row-major.
    wg: Vec<f64>,
    /// `[G_p, G_t]`, r x 2r row-major, in single precision: the modal force of the drive's
    /// jump at a servo sample (a small correction: the drive's change over one servo period).
    gg: Vec<f32>,
    /// Feedthrough of the drive into the cell force.
    drive_d: f64,
    /// The pier displacement held over the last tick.
    pier: f64,
    /// Projected free states `Phi_k^T X_k` and cell-driven states `xi_k` (state-major:
    /// `[s * r + j]`), by kind.
    proj: [Vec<f64>; 2],
    xi: [Vec<f64>; 2],
    /// Projected inputs `Phi_k^T w_k` (r x 3 column-major), by kind.
    w_proj: [Vec<f64>; 2],
    q: Vec<f64>,
    v: Vec<f64>,
    /// Modal force at the start of the tick.
    u: Vec<f64>,
    /// Outputs at the current time, actuator order.
    f_cell: Vec<f64>,
    z_cell: Vec<f64>,
    z_mirror: Vec<f64>,
    // Scratch.
    scratch: [Vec<f64>; 2],
    /// Right-hand side of the coupled solve: `h` (r), then `[psi_p; psi_t]` (2r).
    rhs: Vec<f64>,
    psi: Vec<f64>,
    /// The cell-driven part's drive change at the sample, by kind (2r), and the modal force's
    /// jump (r).
    drive_step: Vec<f32>,
    jump: Vec<f64>,
    u_new: Vec<f64>,
    out: Vec<f64>,
    cols: Vec<f64>,
}

impl CoupledMirror {
    /// `n_segments` identical segments of `model` on the structure `cell` (its `n_modes` lowest
    /// modes, `damping_ratio` unless the model carries its own), at rest. The coupling is
    /// solved `substeps` times per servo period (1: at every servo sample; 2 or more also
    /// between samples, which the stiff piezo stack needs for 1 % accuracy at 30 Hz).
    pub fn new(
        n_segments: usize,
        model: SegmentModel,
        cell: ModalModel,
        n_modes: usize,
        damping_ratio: f64,
        substeps: u32,
    ) -> Result<Self, M1Error> {
        model.validate()?;
        if substeps == 0 {
            return Err(M1Error::InvalidParameter {
                name: "substeps",
                value: 0.0,
                reason: "must be >= 1",
            });
        }
        let na = 3 * n_segments;
        if cell.na != na {
            return Err(M1Error::SizeMismatch {
                what: "structure attachments (3 per segment)",
                expected: na,
                found: cell.na,
            });
        }
        let mut cell = cell;
        cell.flexibility = Flexibility::None;
        let structure = ModalSolver::new(cell, n_modes, damping_ratio)?;
        let ts = model.servo_period();
        let d = ts / f64::from(substeps);
        let (cp, dp) = model.cell_force_map(Channel::Piston);
        let (ct, _) = model.cell_force_map(Channel::Tilt);
        let maps = [Channel::Piston, Channel::Tilt].map(|ch| substep_maps(&model, ch, substeps));
        let [(mp, rp), (mt, rt)] = maps;
        let ramp = [rp, rt];
        let cell_d = dp[1];
        let e = [(cp * ramp[0])[0] + cell_d, (ct * ramp[1])[0] + cell_d];
        let r = structure.n_modes();
        let omega: Vec<f64> = structure
            .frequencies()
            .iter()
            .map(|f| std::f64::consts::TAU * f)
            .collect();
        let zeta = structure.damping_ratios().to_vec();
        let mut a_mode = Vec::with_capacity(r);
        let mut b0 = Vec::with_capacity(r);
        let mut b1 = Vec::with_capacity(r);
        for (&w, &z) in omega.iter().zip(&zeta) {
            let (a, p, q) = foh_mode(w, z, d);
            a_mode.push(a);
            b0.push(p);
            b1.push(q);
        }
        // Mode shapes in the channel basis: piston rows, then tilt rows.
        let phi = DMatrix::from_row_slice(na, r, structure.shapes());
        let v = modal_basis();
        let n = n_segments;
        let mut phic = DMatrix::<f64>::zeros(na, r);
        for seg in 0..n {
            let ch = v.transpose() * phi.rows(3 * seg, 3);
            phic.row_mut(seg).copy_from(&ch.row(0));
            phic.row_mut(n + 2 * seg).copy_from(&ch.row(1));
            phic.row_mut(n + 2 * seg + 1).copy_from(&ch.row(2));
        }
        let gram = [
            phic.rows(0, n).transpose() * phic.rows(0, n),
            phic.rows(n, 2 * n).transpose() * phic.rows(n, 2 * n),
        ];
        let m = &gram[0] * e[0] + &gram[1] * e[1];
        let mut lhs = DMatrix::<f64>::identity(r, r);
        for i in 0..r {
            for j in 0..r {
                lhs[(i, j)] -= m[(i, j)] * b1[j][0];
            }
        }
        let w_inv = lhs.try_inverse().ok_or(M1Error::Unstable {
            channel: "coupled segments and structure",
            spectral_radius: f64::NAN,
            hint: "the coupled tick is singular: check the structure model and the actuator \
                   stiffness",
        })?;
        let mut wg = DMatrix::<f64>::zeros(r, 2 * r);
        wg.columns_mut(0, r).copy_from(&(&w_inv * &gram[0]));
        wg.columns_mut(r, r).copy_from(&(&w_inv * &gram[1]));
        let mut gg = DMatrix::<f64>::zeros(r, 2 * r);
        gg.columns_mut(0, r).copy_from(&gram[0]);
        gg.columns_mut(r, r).copy_from(&gram[1]);
        Ok(Self {
            n_segments,
            ts,
            substeps,
            tick: [[mp[0].0, mt[0].0], [mp[1].0, mt[1].0]],
            tick_in: [[mp[0].1, mt[0].1], [mp[1].1, mt[1].1]],
            ramp,
            cell_c: [cp, ct],
            cell_d,
            e,
            basis: v,
            free: SegmentArray::new(n, model.clone())?,
            zeros: vec![0.0; na],
            model,
            structure,
            r,
            na,
            a_mode,
            b0,
            b1,
            phic: row_major(&phic),
            phic32: row_major(&phic).iter().map(|&x| x as f32).collect(),
            w32: [vec![0.0f32; 2 * n], vec![0.0f32; 4 * n]],
            acc32: [vec![0.0f32; r], vec![0.0f32; r]],
            cols32: vec![0.0f32; 6 * r],
            wg: row_major(&wg),
            gg: row_major(&gg).iter().map(|&x| x as f32).collect(),
            drive_d: cp[state::DRIVE],
            pier: 0.0,
            proj: [vec![0.0; r * N_STATE], vec![0.0; r * N_STATE]],
            xi: [vec![0.0; r * N_STATE], vec![0.0; r * N_STATE]],
            w_proj: [vec![0.0; r * N_IN], vec![0.0; r * N_IN]],
            q: vec![0.0; r],
            v: vec![0.0; r],
            u: vec![0.0; r],
            f_cell: vec![0.0; na],
            z_cell: vec![0.0; na],
            z_mirror: vec![0.0; na],
            scratch: [vec![0.0; r * N_STATE], vec![0.0; r * N_STATE]],
            rhs: vec![0.0; r],
            psi: vec![0.0; 2 * r],
            drive_step: vec![0.0f32; 2 * r],
            jump: vec![0.0; r],
            u_new: vec![0.0; r],
            out: vec![0.0; 3 * na],
            cols: vec![0.0; 6 * r],
        })
    }

    /// Number of segments.
    pub fn n_segments(&self) -> usize {
        self.n_segments
    }

    /// Number of actuators (3 per segment).
    pub fn n_actuators(&self) -> usize {
        self.na
    }

    /// The segment model.
    pub fn model(&self) -> &SegmentModel {
        &self.model
    }

    /// The structure's modal model (retained modes, shapes, damping).
    pub fn structure(&self) -> &ModalSolver {
        &self.structure
    }

    /// The servo period, the smallest step (s).
    pub fn tick_period(&self) -> f64 {
        self.ts
    }

    /// Number of whole servo periods in `h`, or an error naming the step if `h` is not a
    /// positive multiple of the servo period (to 1e-9 of it).
    pub fn ticks_in(&self, h: f64) -> Result<u64, M1Error> {
        let k = (h / self.ts).round();
        if h.is_finite() && k >= 1.0 && (h - k * self.ts).abs() <= 1e-9 * self.ts {
            Ok(k as u64)
        } else {
            Err(M1Error::InvalidParameter {
                name: "communicationStepSize",
                value: h,
                reason: "must be a positive multiple of the servo period (1 / servo_rate): the \
                         segments and the cell are solved together at every servo sample",
            })
        }
    }

    /// Advances `h` seconds (a whole number of ticks) with the command, the wind forces
    /// (actuator order, length 3N) and the pier displacement held.
    pub fn advance(
        &mut self,
        h: f64,
        u_cmd: &[f64],
        f_wind: &[f64],
        pier_z: f64,
    ) -> Result<(), M1Error> {
        let ticks = self.ticks_in(h)?;
        crate::error::check_lengths(self.na, &[("u_cmd", u_cmd), ("f_wind", f_wind)])?;
        // The free part over the whole step at once (its inputs, projected on the channels,
        // are then read back for the modes).
        self.free.advance(h, u_cmd, &self.zeros, f_wind)?;
        // The held inputs on the modes.
        {
            let r = self.r;
            let [p, t] = &mut self.w_proj;
            let (pu, pf) = input_columns(p, r);
            let (tu, tf) = input_columns(t, r);
            // Command and wind columns of each kind, in single precision.
            for (kind, w) in self.free.channel_inputs().into_iter().enumerate() {
                let cnt = self.w32[kind].len() / 2;
                let dst = &mut self.w32[kind];
                for c in 0..cnt {
                    dst[c] = w[c] as f32;
                    dst[cnt + c] = w[2 * cnt + c] as f32;
                }
            }
            let [a0, a1] = &mut self.acc32;
            pulp::Arch::new().dispatch(Project {
                phic: &self.phic32,
                r,
                n: self.n_segments,
                w: [&self.w32[0], &self.w32[1]],
                acc: [a0, a1],
                out: [pu, pf, tu, tf],
            });
        }
        // The ticks, vectorised for this processor (everything in them is inlined into a
        // function compiled for its instruction set).
        pulp::Arch::new().dispatch(Ticks {
            mirror: self,
            ticks,
            pier_z,
        });
        self.write_outputs();
        Ok(())
    }

    /// Mirror displacement `z` at each actuator (length 3N).
    pub fn mirror(&self, z: &mut [f64]) {
        z.copy_from_slice(&self.z_mirror);
    }

    /// Cell displacement at each attachment (length 3N).
    pub fn cell_displacement(&self) -> &[f64] {
        &self.z_cell
    }

    /// Force of each actuator on the cell (length 3N).
    pub fn cell_force(&self) -> &[f64] {
        &self.f_cell
    }

    /// Back to rest.
    pub fn reset(&mut self) {
        self.free.reset();
        self.pier = 0.0;
        for a in self.proj.iter_mut().chain(self.xi.iter_mut()) {
            a.fill(0.0);
        }
        for a in [
            &mut self.q,
            &mut self.v,
            &mut self.u,
            &mut self.f_cell,
            &mut self.z_cell,
            &mut self.z_mirror,
        ] {
            a.fill(0.0);
        }
    }

    /// One coupled tick, entirely on the modes: the segments' response to the cell motion is
    /// carried per mode (identical segments: the channel dynamics commute with the mode shapes).
    /// Modal arrays are state-major (`[s * r + j]`), so every update is a run of axpys.
    #[inline(always)]
    fn tick<S: pulp::Simd>(&mut self, simd: S, pier_z: f64, sample: bool) {
        let r = self.r;
        const S: usize = N_STATE;
        self.rhs.fill(0.0);
        self.jump.fill(0.0);
        let dr = state::DRIVE;
        for k in 0..2 {
            let set = usize::from(!sample);
            let (p, g, ramp, c) = (
                &self.tick[set][k],
                &self.tick_in[set][k],
                &self.ramp[k],
                &self.cell_c[k],
            );
            let wp = &self.w_proj[k];
            // Free part, projected: P+_i = sum_s p_is P_s + g_i0 W_u + g_i2 W_f.
            let (src, dst) = (&self.proj[k], &mut self.scratch[k]);
            for i in 0..S {
                let out = &mut dst[i * r..(i + 1) * r];
                out.fill(0.0);
                for s in 0..S {
                    let a = p[(i, s)];
                    if a != 0.0 {
                        axpy(out, a, &src[s * r..(s + 1) * r]);
                    }
                }
                for l in [0, 2] {
                    let a = g[(i, l)];
                    if a != 0.0 {
                        axpy(out, a, &wp[l * r..(l + 1) * r]);
                    }
                }
            }
            std::mem::swap(&mut self.proj[k], &mut self.scratch[k]);
            // The free part's drive change at the sample, on the modes.
            if sample {
                let (new, old) = (&self.proj[k][dr * r..], &self.scratch[k][dr * r..]);
                for j in 0..r {
                    self.jump[j] += new[j] - old[j];
                }
            }
            // h += P+ c^T.
            for i in 0..S {
                if c[i] != 0.0 {
                    axpy(&mut self.rhs, c[i], &self.proj[k][i * r..(i + 1) * r]);
                }
            }
            // Cell-driven part without this tick's ramp: Y_i = sum_s p_is xi_s + (g_i1 - ramp_i) q.
            let (src, dst) = (&self.xi[k], &mut self.scratch[k]);
            for i in 0..S {
                let out = &mut dst[i * r..(i + 1) * r];
                out.fill(0.0);
                for s in 0..S {
                    let a = p[(i, s)];
                    if a != 0.0 {
                        axpy(out, a, &src[s * r..(s + 1) * r]);
                    }
                }
                let a = g[(i, 1)] - ramp[i];
                if a != 0.0 {
                    axpy(out, a, &self.q);
                }
            }
            // The cell-driven part's drive change (the ramp does not reach the drive).
            if sample {
                let (new, old) = (&self.scratch[k][dr * r..], &self.xi[k][dr * r..]);
                let out = &mut self.drive_step[k * r..(k + 1) * r];
                for j in 0..r {
                    out[j] = (new[j] - old[j]) as f32;
                }
            }
            // psi~_k = Y c^T.
            let psi = &mut self.psi[k * r..(k + 1) * r];
            psi.fill(0.0);
            for i in 0..S {
                if c[i] != 0.0 {
                    axpy(psi, c[i], &self.scratch[k][i * r..(i + 1) * r]);
                }
            }
        }
        // The drive jumps at the sample and is held over the tick: the modal force starts the
        // tick at the end value of the last one plus that jump, then ramps (the continuous
        // part of the cell force is what varies within the tick).
        if sample {
            rows_dot_f32::<S>(
                simd,
                &self.gg,
                2 * r,
                r,
                2 * r,
                &self.drive_step,
                &mut self.jump,
            );
        }
        // The pier input is held too: a new value loads the modes from the tick's start.
        let dp = pier_z - self.pier;
        self.pier = pier_z;
        let bp = self.structure.pier_gains();
        for ((u, jump), b) in self.u.iter_mut().zip(&self.jump).zip(bp) {
            *u += self.drive_d * jump + dp * b;
        }
        // a = free q+ (held and ramp parts of the old modal force): q+ = a + b1_q u+.
        axpy(&mut self.rhs, pier_z, self.structure.pier_gains());
        for j in 0..r {
            let (a, b0, b1) = (&self.a_mode[j], &self.b0[j], &self.b1[j]);
            let abar = a[0] * self.q[j] + a[1] * self.v[j] + (b0[0] - b1[0]) * self.u[j];
            self.psi[j] += self.e[0] * abar;
            self.psi[r + j] += self.e[1] * abar;
            self.cols[j] = abar;
        }
        // u+ = W (h + b_p p) + W G_p (psi_p + e_p a) + W G_t (psi_t + e_t a), with
        // W = (I - M B1)^-1 = I + W M B1 and W M = e_p W G_p + e_t W G_t, so that
        // u+ = h' + W G_p (psi_p + e_p a + e_p B1 h') + W G_t (psi_t + e_t a + e_t B1 h'):
        // one r x 2r product (it fits a core's cache up to r of about 350).
        for j in 0..r {
            let bh = self.b1[j][0] * self.rhs[j];
            self.psi[j] += self.e[0] * bh;
            self.psi[r + j] += self.e[1] * bh;
        }
        self.u_new.copy_from_slice(&self.rhs);
        rows_dot::<S, 1>(
            simd,
            &self.wg,
            2 * r,
            r,
            2 * r,
            [&self.psi],
            [&mut self.u_new],
        );
        // Modes at the end of the tick.
        for j in 0..r {
            let (a, b0, b1) = (&self.a_mode[j], &self.b0[j], &self.b1[j]);
            let (q, vq, u0, u1) = (self.q[j], self.v[j], self.u[j], self.u_new[j]);
            self.q[j] = self.cols[j] + b1[0] * u1;
            self.v[j] = a[2] * q + a[3] * vq + b0[1] * u0 + b1[1] * (u1 - u0);
            self.u[j] = u1;
        }
        // Cell-driven states with this tick's ramp: xi+_i = Y_i + ramp_i q+.
        for k in 0..2 {
            let ramp = &self.ramp[k];
            for i in 0..S {
                if ramp[i] != 0.0 {
                    axpy(&mut self.scratch[k][i * r..(i + 1) * r], ramp[i], &self.q);
                }
            }
            std::mem::swap(&mut self.xi[k], &mut self.scratch[k]);
        }
    }

    /// Channel states, forces and displacements back in actuator space: one product with the
    /// mode shapes per kind, `Phi_k [xi_k mirror, q, xi_k c_k^T]`.
    fn write_outputs(&mut self) {
        let (r, n, na) = (self.r, self.n_segments, self.na);
        const S: usize = N_STATE;
        let mp = state::MIRROR_POS;
        let mut outs = std::mem::take(&mut self.out);
        for k in 0..2 {
            let c = &self.cell_c[k];
            let cols = &mut self.cols[3 * r * k..3 * r * (k + 1)];
            cols[..r].copy_from_slice(&self.xi[k][mp * r..(mp + 1) * r]);
            cols[r..2 * r].copy_from_slice(&self.q);
            let force = &mut cols[2 * r..];
            force.fill(0.0);
            for s in 0..S {
                if c[s] != 0.0 {
                    axpy(force, c[s], &self.xi[k][s * r..(s + 1) * r]);
                }
            }
        }
        {
            // Phi_c [cols_k] over all channel rows.
            let (o0, rest) = outs.split_at_mut(na);
            let (o1, o2) = rest.split_at_mut(na);
            for (d, c) in self.cols32.iter_mut().zip(&self.cols) {
                *d = *c as f32;
            }
            pulp::Arch::new().dispatch(Reconstruct {
                phic: &self.phic32,
                r,
                n,
                rows: 0..na,
                cols: &self.cols32,
                out: [o0, o1, o2],
            });
        }
        // Channel values (rows: piston channels, then tilt) to actuators, segment by segment.
        let v = self.basis;
        for seg in 0..n {
            let rows = [seg, n + 2 * seg, n + 2 * seg + 1];
            let idx = [
                (0usize, seg, n),
                (1, 2 * seg, 2 * n),
                (1, 2 * seg + 1, 2 * n),
            ];
            let mut zm = [0.0; 3];
            let mut zc = [0.0; 3];
            let mut fc = [0.0; 3];
            for m in 0..3 {
                let (k, c, cnt) = idx[m];
                let x = self.free.state()[k];
                let free_f: f64 = (0..S).map(|s| self.cell_c[k][s] * x[s * cnt + c]).sum();
                zm[m] = x[mp * cnt + c] + outs[rows[m]];
                zc[m] = outs[na + rows[m]];
                fc[m] = free_f + outs[2 * na + rows[m]] + self.cell_d * zc[m];
            }
            for a in 0..3 {
                let at = |t: &[f64; 3]| v[(a, 0)] * t[0] + v[(a, 1)] * t[1] + v[(a, 2)] * t[2];
                self.z_mirror[3 * seg + a] = at(&zm);
                self.z_cell[3 * seg + a] = at(&zc);
                self.f_cell[3 * seg + a] = at(&fc);
            }
        }
        self.out = outs;
    }
}

/// The ticks of a communication step, as a SIMD operation for [`pulp::Arch::dispatch`].
struct Ticks<'a> {
    mirror: &'a mut CoupledMirror,
    ticks: u64,
    pier_z: f64,
}

impl pulp::WithSimd for Ticks<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        for _ in 0..self.ticks {
            for s in 0..self.mirror.substeps {
                self.mirror.tick(simd, self.pier_z, s == 0);
            }
        }
    }
}

/// The two input columns the ticks use (command, wind) of an `r x N_IN` column-major block.
fn input_columns(w: &mut [f64], r: usize) -> (&mut [f64], &mut [f64]) {
    let (u, rest) = w.split_at_mut(r);
    (u, &mut rest[r..2 * r])
}

/// `Phi_k^T w_k` (command and wind columns) for both kinds, from the single-precision shapes:
/// `out` is (piston command, piston wind, tilt command, tilt wind), each `r` long; `w[kind]` is
/// the kind's command column then its wind column.
struct Project<'a> {
    phic: &'a [f32],
    r: usize,
    n: usize,
    w: [&'a [f32]; 2],
    acc: [&'a mut [f32]; 2],
    out: [&'a mut [f64]; 4],
}

impl pulp::WithSimd for Project<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (r, n) = (self.r, self.n);
        let [pu, pf, tu, tf] = self.out;
        let [a0, a1] = self.acc;
        for (kind, (lo, count), yu, yf) in [(0usize, (0usize, n), pu, pf), (1, (n, 2 * n), tu, tf)]
        {
            let x = self.w[kind];
            rows_axpy2_f32::<S>(
                simd,
                &self.phic[lo * r..],
                r,
                count,
                r,
                [&x[..count], &x[count..2 * count]],
                [yu, yf],
                [&mut *a0, &mut *a1],
            );
        }
    }
}

/// Rows `rows` of `Phi_c [cols_k]` (channel rows: piston `0..n`, tilt `n..3n`; `cols` holds
/// the three `r`-columns of each kind in turn): `out` is the three output columns over `rows`.
struct Reconstruct<'a> {
    phic: &'a [f32],
    r: usize,
    n: usize,
    rows: std::ops::Range<usize>,
    cols: &'a [f32],
    out: [&'a mut [f64]; 3],
}

impl pulp::WithSimd for Reconstruct<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        let (r, n) = (self.r, self.n);
        let [o0, o1, o2] = self.out;
        for (kind, kinds) in [(0usize, 0..n), (1, n..3 * n)] {
            let lo = self.rows.start.max(kinds.start);
            let hi = self.rows.end.min(kinds.end);
            if lo >= hi {
                continue;
            }
            let cols = &self.cols[3 * r * kind..3 * r * (kind + 1)];
            let (c0, rest) = cols.split_at(r);
            let (c1, c2) = rest.split_at(r);
            let at = lo - self.rows.start..hi - self.rows.start;
            for o in [&mut *o0, &mut *o1, &mut *o2] {
                o[at.clone()].fill(0.0);
            }
            rows_dot3_f32::<S>(
                simd,
                &self.phic[lo * r..],
                r,
                hi - lo,
                r,
                [c0, c1, c2],
                [&mut o0[at.clone()], &mut o1[at.clone()], &mut o2[at]],
            );
        }
    }
}

fn row_major(m: &DMatrix<f64>) -> Vec<f64> {
    m.transpose().as_slice().to_vec()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::aperture::layout::Layout;
    use crate::plant::structure::{CellModel, CellParams};

    fn keck(model: SegmentModel, n_modes: usize) -> (CoupledMirror, CellModel) {
        keck_on(model, n_modes, &CellParams::soft_cell())
    }

    fn keck_on(model: SegmentModel, n_modes: usize, p: &CellParams) -> (CoupledMirror, CellModel) {
        let layout = Layout::keck();
        let cell = CellModel::new(&layout, p).expect("cell");
        let modes = cell.modes().expect("modes");
        let m = CoupledMirror::new(layout.n_segments(), model, modes, n_modes, 0.02, 1)
            .expect("mirror");
        (m, cell)
    }

    fn wind(na: usize) -> Vec<f64> {
        (0..na)
            .map(|i| ((i * 7919 % 13) as f64 - 6.0) * 5.0)
            .collect()
    }

    /// At the end of every step the two sides agree: the force on the cell is the segments'
    /// output for the channel states they ended on (free part plus the part carried on the
    /// modes) and the cell displacement, and the modal force is that force projected on the
    /// modes (the identities the implicit solve enforces).
    #[test]
    fn every_step_ends_consistent() {
        for model in [
            SegmentModel::voice_coil(),
            SegmentModel::piezo_damped_default(),
        ] {
            let (mut m, _) = keck(model, 1000);
            let na = m.n_actuators();
            let n = m.n_segments();
            let r = m.r;
            let u_cmd: Vec<f64> = (0..na).map(|i| 1e-8 * (i % 5) as f64).collect();
            let fw = wind(na);
            for k in 0..40 {
                let p = 1e-9 * (k as f64 * 0.3).sin();
                m.advance(m.tick_period(), &u_cmd, &fw, p).expect("tick");
                // Channel states X = x_free + Phi_c xi; f = c X + d z_cell, channel by channel.
                let v = m.basis;
                let z = m.cell_displacement().to_vec();
                let mut f = vec![0.0; na];
                for seg in 0..n {
                    let idx = [(0usize, seg, n, seg), (1, 2 * seg, 2 * n, n + 2 * seg)];
                    let idx = [idx[0], idx[1], (1, 2 * seg + 1, 2 * n, n + 2 * seg + 1)];
                    let zc = &z[3 * seg..3 * seg + 3];
                    let mut fch = [0.0; 3];
                    for (j, &(kind, c, cnt, row)) in idx.iter().enumerate() {
                        let zch = v[(0, j)] * zc[0] + v[(1, j)] * zc[1] + v[(2, j)] * zc[2];
                        let x = |s: usize| {
                            m.free.state()[kind][s * cnt + c]
                                + (0..r)
                                    .map(|q| m.phic[row * r + q] * m.xi[kind][s * r + q])
                                    .sum::<f64>()
                        };
                        fch[j] = (0..N_STATE).map(|s| m.cell_c[kind][s] * x(s)).sum::<f64>()
                            + m.cell_d * zch;
                    }
                    for a in 0..3 {
                        f[3 * seg + a] =
                            v[(a, 0)] * fch[0] + v[(a, 1)] * fch[1] + v[(a, 2)] * fch[2];
                    }
                }
                let scale = f.iter().fold(0.0f64, |a, b| a.max(b.abs()));
                // The outputs come back through the single-precision shapes.
                for (a, b) in f.iter().zip(m.cell_force()) {
                    assert!((a - b).abs() <= 1e-6 * scale, "force {a} vs {b}");
                }
                let phi = m.structure.shapes();
                let bp = m.structure.pier_gains();
                let modal: Vec<f64> = (0..r)
                    .map(|j| (0..na).map(|i| phi[i * r + j] * f[i]).sum::<f64>() + bp[j] * p)
                    .collect();
                let uscale = modal.iter().fold(1e-300, |a: f64, b| a.max(b.abs()));
                for (j, &u) in modal.iter().enumerate() {
                    // Within 1e-6 of the largest modal force: the inputs reach the modes through
                    // the single-precision shapes.
                    assert!(
                        (u - m.u[j]).abs() <= 1e-6 * uscale,
                        "mode {j}: {u} vs {}",
                        m.u[j]
                    );
                }
                // The free part's projection, stepped on the modes, matches the free states.
                for kind in 0..2 {
                    let (lo, cnt) = if kind == 0 { (0, n) } else { (n, 2 * n) };
                    for s in [state::NODE_POS, state::MIRROR_POS, state::DRIVE] {
                        let direct = |j: usize| -> f64 {
                            (0..cnt)
                                .map(|c| {
                                    m.phic[(lo + c) * r + j] * m.free.state()[kind][s * cnt + c]
                                })
                                .sum()
                        };
                        let scale = (0..r).map(|j| direct(j).abs()).fold(1e-300, f64::max);
                        for j in (0..r).step_by(7) {
                            let direct = direct(j);
                            let carried = m.proj[kind][s * r + j];
                            // The inputs reach the modes through the single-precision shapes:
                            // within 1e-6 of the largest projection.
                            assert!(
                                (direct - carried).abs() <= 1e-6 * scale,
                                "proj {direct} vs {carried}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// Under a constant load the mirror settles on the analytic static solution: the cell (all
    /// modes retained) deflects by the exact static compliance under the actuator reactions
    /// (f_cell = f_wind),
    /// the integral servo of the piezo holds the stroke at zero, and the mirror sits on the
    /// whiffletree and the flexures in series, f (1/k_w + 1/k_s) per channel.
    #[test]
    fn settles_on_the_static_solution() {
        let model = SegmentModel::piezo();
        let (mut m, cell) = keck(model.clone(), 1000);
        let na = m.n_actuators();
        let fw = wind(na);
        let zero = vec![0.0; na];
        // 24 s: the piezo's integral correction (0.25 Hz, time constant 0.64 s) and the slowest
        // mode (the 10 Hz mount, 2 % damping) decay by e^-30 or more.
        for _ in 0..48 {
            m.advance(0.5, &zero, &fw, 0.0).expect("advance");
        }
        let zc = cell.static_deflection(&fw, 0.0).expect("static");
        let scale = zc.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for (a, b) in m.cell_displacement().iter().zip(&zc) {
            assert!((a - b).abs() <= 1e-5 * scale, "z_cell {a} vs {b}");
        }
        // The outputs come back through the single-precision shapes, and the piezo's force is
        // a difference of stiff terms (K_D times displacements): 1e-4 N of 30 N.
        for (a, b) in m.cell_force().iter().zip(&fw) {
            assert!((a - b).abs() <= 1e-4, "f_cell {a} vs {b}");
        }
        let v = m.basis;
        let mut z = vec![0.0; na];
        m.mirror(&mut z);
        for seg in 0..m.n_segments() {
            let f = &fw[3 * seg..3 * seg + 3];
            let c = &zc[3 * seg..3 * seg + 3];
            let mut ch = [0.0; 3];
            for (j, kind) in [Channel::Piston, Channel::Tilt, Channel::Tilt]
                .iter()
                .enumerate()
            {
                let fj = v[(0, j)] * f[0] + v[(1, j)] * f[1] + v[(2, j)] * f[2];
                let cj = v[(0, j)] * c[0] + v[(1, j)] * c[1] + v[(2, j)] * c[2];
                ch[j] = cj + fj * model.support_compliance(*kind);
            }
            for a in 0..3 {
                let want = v[(a, 0)] * ch[0] + v[(a, 1)] * ch[1] + v[(a, 2)] * ch[2];
                let got = z[3 * seg + a];
                assert!((got - want).abs() <= 1e-5 * scale, "z {got} vs {want}");
            }
        }
    }

    /// The coupled solve gives the same answer (to rounding) for any split of time into
    /// communication steps, on both structure presets, and refuses a step off the servo grid.
    #[test]
    fn results_do_not_depend_on_the_communication_step() {
        for p in [CellParams::soft_cell(), CellParams::tmt()] {
            let (mut a, _) = keck_on(SegmentModel::voice_coil(), 50, &p);
            let mut b = a.clone();
            let na = a.n_actuators();
            let fw = wind(na);
            let u = vec![2e-8; na];
            for _ in 0..10 {
                a.advance(1e-3, &u, &fw, 1e-9).expect("1 ms");
            }
            for _ in 0..50 {
                b.advance(2e-4, &u, &fw, 1e-9).expect("0.2 ms");
            }
            // Equal to rounding: the free part takes one 5-tick map against five 1-tick maps.
            for (x, y) in [
                (a.cell_displacement(), b.cell_displacement()),
                (a.cell_force(), b.cell_force()),
            ] {
                let scale = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                for (p, q) in x.iter().zip(y) {
                    assert!((p - q).abs() <= 1e-12 * scale, "{p} vs {q}");
                }
            }
            let e = a
                .advance(3e-4, &u, &fw, 0.0)
                .expect_err("off grid")
                .to_string();
            assert!(e.contains("communicationStepSize"), "{e}");
        }
    }
}
