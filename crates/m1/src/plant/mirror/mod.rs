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
//! the wind is stepped per communication step in actuator space (its steps on unchanged inputs
//! left pending, [`crate::plant::segment::SegmentArray::set_deferred`]: between changes of the
//! inputs, every tenth step in the standard systems, a step reads the mirror's position from the
//! pending map's row, 15 multiply-adds per channel instead of the whole map's 134, and inputs equal
//! to the last step's are not projected onto the channels again; TMT at 60 modes, a fifth less
//! per mirror step, BENCHMARKS.md twenty-first round), and its projection on the modes
//! by the ticks' maps composed over a chunk of up to ten ticks (`FREE_CHUNK_TICKS`): one pass
//! gives the projected states at the chunk's end and each tick's modal force and drive change
//! (TMT, 300 modes: 6 % of the step; Keck with two sub-steps per servo period: 20 %). A tick then costs $O(r^2)$ (the coupled solve's products below and $O(r)$ axpys
//! of the 12-state maps) and never touches the $na \times r$ shapes, which are used twice per
//! communication step (projecting the held inputs, reconstructing the mirror's displacement).
//! The cell's displacement and force take a second, two-column pass, made only when they are
//! read ([`CoupledMirror::cell_outputs`]; the mirror FMU declares them on demand). The two
//! formulations agree to 2e-13 (checked when this one replaced the per-actuator one).
//!
//! **Memory-bound products.** At TMT size with 300 modes the shapes are 3.5 MB and the
//! coupling's matrices 2.2 MB in double precision: a step streams about 14 MB (9.0 MB as
//! stored, below), and arithmetic is cheap beside it. The
//! shapes and the coupling matrices are stored row-major and multiplied by the streaming
//! kernels of [`crate::linalg::kernels`] (each matrix read once, every right-hand side applied while a
//! chunk is in registers), and the whole coupled part of a step runs inside one
//! [`pulp::Arch::dispatch`], so that it is compiled for the processor's vector instructions.
//! The products read four rows at a time and ask for the next four rows' cache lines meanwhile
//! ([`crate::linalg::kernels::prefetch`]): each row is a stream of its own, about a page long at
//! 1000 modes, which the processor's prefetchers would start on only after its first misses (TMT at
//! 1000 modes, the step about a tenth shorter; BENCHMARKS.md, twenty-fifth round).
//! The general matrix products used before (which pack their operand first) took 1.44 times as
//! long per step at r = 300 (BENCHMARKS.md). The channels' 12-state maps, on the modes and in
//! actuator space alike, go through [`crate::linalg::kernels::state_map`], which computes four
//! rows at a time and skips the states a group of rows does not read (the maps' zero columns:
//! the drive, an absent shunt; the voice coil's maps have 66 non-zero entries of 144). The
//! shapes are streamed in
//! single precision, their rows zero-padded to whole vectors so that the passes have no scalar
//! tail (inputs onto the modes, outputs back: relative error about 1e-7 of the largest term), and so
//! are, from [`SINGLE_COUPLING_MIN_MODES`] modes, the coupled solve's matrices. Up to
//! [`COLUMN_PASS_MAX_MODES`] modes the outputs go back by the shapes' columns (a transposed
//! copy, [`crate::linalg::kernels::cols_dot_f32`]): a channel's row of 60 modes is four vectors,
//! whose reduction across the lanes cost as much as its products (TMT at 60 modes, the mirror
//! step alone 7 % shorter; BENCHMARKS.md, twenty-second round).
//! From [`FIXED24_SHAPES_MIN_MODES`] modes where the processor decodes them with one byte
//! permutation per vector (AVX-512 VBMI), from [`FIXED24_SHAPES_AVX2_MIN_MODES`] on the AVX2
//! path ([`CoupledMirror::shapes_fixed24_default`]), the shapes are streamed in 24-bit fixed
//! point instead, each mode's column scaled by its largest entry
//! ([`crate::linalg::symmetric_scaled::ColumnScaled`], [`CoupledMirror::set_shapes_fixed24`]):
//! three quarters of single precision's traffic, the response within twice what single
//! precision moves it (tested against double precision with the other storages), and TMT's
//! step 3-5 % shorter at 500 to 1000 modes on the Intel VM (BENCHMARKS.md, twenty-eighth
//! round), 4-8 % at 850 to 1000 on an AMD EPYC (Zen 1, twenty-ninth round).
//!
//! **The coupled solve per tick.** With $W = (I - M B_1)^{-1}$ the solve reads
//! $u_{n+1} = h' + W G \psi$, where $G = [G_p, G_t]$ are the Gram matrices of the shapes'
//! piston and tilt rows and $\psi$ the channels' cell-driven forces on the modes: one pass over
//! $W G$ ($r \times 2r$), after a pass over $G$ for the modal force of the drive's jump at a
//! servo sample, $g = G\,\Delta\delta$ (a correction of the size of the drive's change over
//! one servo period, in single precision). In single precision, from
//! [`SINGLE_COUPLING_MIN_MODES`] modes, where the passes are memory-bound, a sample's tick
//! uses an equivalent form with less traffic: with $\psi_0$ the forces before the jump and
//! $W M B_1 = W - I$, $u_{n+1} = h' + y + (W - I)(y + \beta \odot g)$ with $y = G \psi_0$ and
//! $\beta = (b_0 - b_1) d_u / b_1$ per mode. One pass over $G$ with two right-hand sides gives
//! $y$ and $g$ together, one over $W - I$ ($r \times r$; about 4e-7 in norm for the voice coil
//! and 8e-5 for the piezo on TMT) the rest: exact to rounding (TMT at 1000 modes, 1.2-1.5
//! times faster per step; BENCHMARKS.md). $W - I$ is stored in a symmetric form by its upper
//! block triangle ([`crate::linalg::symmetric`]): with $D = B_1^{1/2}$ (every $b_1 > 0$) and
//! $S = D M D$, $W - I = D^{-1} K D$ with $K = (I - S)^{-1} S$ symmetric, so that a sample's
//! tick streams 1.25 $r \times 2r$ matrices instead of 2. From [`HALF_CORRECTION_MIN_MODES`]
//! modes $K$ is stored scaled symmetrically in fewer bits ([`crate::linalg::symmetric_scaled`],
//! [`CoupledMirror::set_correction_storage`]): in 8-bit fixed point where the bound on that
//! rounding's effect on the product is within [`FIXED8_CORRECTION_MAX_BOUND`] (TMT's voice
//! coil: a tick then streams 1.0625 instead of 1.25, and its step at 1000 modes is 3-4 %
//! shorter; BENCHMARKS.md, twenty-seventh round), in half precision otherwise (the piezo,
//! whose correction is 200 times larger: 1.125). Either way the mirror's response moves by no
//! more than single precision itself moves it (tested against double precision for a static
//! load and a pier vibration as well as wind). The Gram matrices need more than half
//! precision: the response to a pier vibration is a small difference of large terms, and their
//! rounding to half precision moved it by 1e-4 of its largest value. From
//! [`FIXED24_GRAM_MIN_MODES`] modes, where the processor decodes them with one byte permutation
//! per vector (AVX-512 VBMI; on the AVX2 path the decoding costs more than the traffic it
//! saves, [`CoupledMirror::gram_fixed24_default`]), they are stored in 24-bit fixed point,
//! scaled as the correction is ([`crate::linalg::symmetric_scaled::SymPacked24`], each entry
//! within about 6e-8 of its row's and column's scale), three quarters of single precision's
//! traffic: the response moves by at most twice what single precision moves it (tested against
//! double precision as the correction is), and TMT's step at 1000 modes is 1-8 % shorter on two
//! threads, 7-12 % on one (BENCHMARKS.md, twenty-sixth round). Below
//! [`SINGLE_COUPLING_MIN_MODES`] the double-precision matrix fits a core's L1 cache with room
//! to spare, and the conversions to single precision cost more than the traffic they save. In single precision (each vector lane sums about `2r / 8`
//! products, then the lanes are summed, and the row's sum is added in double precision)
//! against double precision ([`CoupledMirror::set_coupling_single`]) the mirror's response
//! moves by about 2e-9 of its largest value (TMT, 300 modes).
//!
//! **The Gram matrices by half from 700 modes.** Each of $G_p$, $G_t$ is symmetric, so from
//! [`PACKED_GRAM_MIN_MODES`] modes a sample's tick streams them by their upper block triangles
//! too ([`CoupledMirror::set_gram_packed`]): the same multiply-adds, half the traffic (4 MB
//! instead of 8 MB per sample at 1000 modes, where the pass is bound by the caches'
//! bandwidth; below, where the matrices fit the caches, the pass is bound by its arithmetic
//! and the packed form's extra loads make it slower: 600 modes 6 % on one thread).
//! BENCHMARKS.md, eleventh round.
//!
//! **Two threads from 500 modes (from 150 when they pay).** The tick's pass over the Gram
//! matrices (or `W G`; by kind when they are stored by half), the correction `W - I` (in two
//! parts of block rows with
//! about the same stored entries, each with its own column sums), the channels' maps on the
//! modes and the free part (by kind), the shapes' pass back to the actuators (by channel rows)
//! and the inputs' projection onto the modes (in two parts of channel rows, summed alike on one
//! thread; TMT at 1000 modes, a step whose inputs changed 0.16 ms instead of 0.23 ms there)
//! are split
//! between the calling thread and a helper thread ([`crate::linalg::pair`],
//! [`CoupledMirror::set_two_threads`], default from [`TWO_THREADS_MIN_MODES`]; from
//! [`SHARED_CACHE_MIN_MODES`] the default tries one and two threads in blocks of
//! [`THREADS_TRIAL_BLOCK`] steps, [`THREADS_TRIAL_STEPS`] steps each, every
//! [`THREADS_CHECK_STEPS`] steps, and keeps the faster). Every value is
//! summed as on one thread (from 500 modes the correction is taken in the same two parts on one
//! thread), so the outputs are the same to the bit (tested). The step of a model without any of
//! these large models' forms is compiled without their code (a separate instance of the step),
//! which keeps the one-thread step of the default models as fast as before. Measured in the TMT
//! wind system (`m1cs run --solver-threads 1|2`, eleventh round, with AVX-512): at 1000 modes
//! the mirror alone takes 0.97-1.0 ms per step on one thread and 0.51-0.53 ms on two, and the
//! system runs at 1.5-1.6x on two in most runs; 600 modes 1.85-2.09x -> 2.79x; 300 modes
//! 5.59-5.63x -> 5.95-6.27x in most runs, but 4.4-5.3x in some invocations, so the default
//! stays at two threads from 500 modes (BENCHMARKS.md, tenth and eleventh rounds). The slow
//! runs come when the host puts the VM's two cores on two L3 caches (twelfth round): each value
//! one thread writes and the other reads then crosses between the caches. Each kind's states,
//! right-hand side and single-precision inputs therefore stay on the thread that steps that
//! kind (the tick's ramp part is added by that thread, also at the end of a step). What still
//! crosses per tick is the Gram passes' results and the free part's rows: at 1000 modes 0.79-0.83 ms per step across two L3s against 0.50-0.61 ms on
//! one. Below 500 modes the two threads pay only on one L3 (at 300 modes 107-112 against
//! 160 us per step there, 196 against 165 us across two), hence the timed trial.
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

mod coupled;
mod maps;
mod projection;
#[cfg(test)]
mod tests;
mod tick;

pub use coupled::{
    COLUMN_PASS_MAX_MODES, CorrectionStorage, CoupledMirror, FIXED8_CORRECTION_MAX_BOUND,
    FIXED24_GRAM_MIN_MODES, FIXED24_SHAPES_AVX2_MIN_MODES, FIXED24_SHAPES_MIN_MODES,
    HALF_CORRECTION_MIN_MODES, PACKED_GRAM_MIN_MODES, SHARED_CACHE_MIN_MODES,
    SINGLE_COUPLING_MIN_MODES, THREADS_CHECK_STEPS, THREADS_TRIAL_BLOCK, THREADS_TRIAL_STEPS,
    THREADS_TRIAL_WARM, TWO_THREADS_MIN_MODES,
};
pub use maps::foh_mode;
