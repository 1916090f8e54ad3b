//! The coupled solver's state and its public face ([`CoupledMirror`]): built once from the
//! segment model and the retained modes (the coupling matrices, the shapes in the channel
//! basis), advanced a communication step at a time, read in actuator order.

use nalgebra::{DMatrix, SMatrix, SVector};
use pulp::WithSimd;
use serde::{Deserialize, Serialize};

use super::maps::{foh_mode, substep_maps};
use super::projection::{Project, Shapes, input_columns, padded_rows_f32, row_major};
use super::tick::{CellOutputs, Step};
use crate::M1Error;
use crate::linalg::kernels::{SourceMasks, padded_len};
use crate::linalg::pair::LazyPair;
use crate::linalg::symmetric::{SymPacked32, balanced_split, padded_order};
use crate::linalg::symmetric_scaled::{
    ColumnScaled, Encoding, Fixed8, Fixed24, SymPacked8, SymPacked24, SymPackedHalf,
    symmetric_scale,
};
use crate::plant::segment::{
    Channel, Gamma, N_IN, N_STATE, Phi, SegmentArray, SegmentModel, modal_basis, propagate, state,
};
use crate::plant::structure::{Flexibility, ModalModel, ModalSolver};

/// Retained modes from which [`CoupledMirror`] streams its coupled solve's matrices in single
/// precision by default ([`CoupledMirror::set_coupling_single`]), chosen by measurement: there
/// the `r x 2r` matrix `[W G_p, W G_t]` in double precision (`16 r^2` bytes, 32 kB at 45 modes)
/// fills a 32 kB L1 data cache with nothing left for the vectors, and at 60 modes (57.6 kB)
/// outgrows a 48 kB one, so each tick's pass over it waits on the L2 cache. On the project's
/// machine (`mirror_loop`, alternating): Keck 45 modes 12.1-12.4 against 13.1-14.8 us per step,
/// 60 modes 14.2-14.8 against 15.4-16.8 us, TMT 60 modes 30.3-31.1 against 31.3-32.8 us; at 30
/// modes no gain and at 20 a loss (the conversions to single precision). It was 150 until the
/// seventeenth round of issue 18, where the double-precision matrix (360 kB) and the Gram
/// matrices' single-precision copy (180 kB) outgrow the 512 kB L2.
pub const SINGLE_COUPLING_MIN_MODES: usize = 45;

/// Retained modes from which [`CoupledMirror`] streams the coupled solve's correction `W - I`
/// in fewer bits than single precision ([`CoupledMirror::set_correction_storage`]: 8 bits or
/// half precision, by [`CoupledMirror::correction_default`]), where the correction no longer
/// fits the caches beside the Gram matrices. On the project's 2-core Intel VM, single against
/// half precision (`mirror_loop -- MODES 2s,2h,1s,1h`, alternating, TMT, the Gram matrices by
/// half): 1000 modes 986 against 918 us per step on two threads and 1769 against 1576 on one;
/// 700 modes 468 against 443 and 946 against 859; 500 modes 295 against 291 and 502 against
/// 467; at 300 modes within the noise (BENCHMARKS.md, twenty-fourth round). Half precision
/// against 8 bits, the voice coil (`mirror_loop -- MODES 2o,2d,1o,1d`): 1000 modes 659-709
/// against 639-677 us on two threads and 1192-1227 against 1120-1207 on one; 700 modes the
/// same within the noise; 500 modes 247-256 against 242-248 and 560-570 against 538-553
/// (twenty-seventh round).
pub const HALF_CORRECTION_MIN_MODES: usize = 500;

/// The largest rounding bound ([`CoupledMirror::correction_rounding_bound`], relative to the
/// largest entry of the vector it multiplies) at which [`CoupledMirror::correction_default`]
/// stores the correction `W - I` in 8 bits. The bound adds every entry's worst rounding; TMT's
/// voice coil has 4.3e-7 at 300 modes, 6.6e-7 at 500 and 1.2e-6 at 1000, the piezo 8.9e-5,
/// 1.4e-4 and 2.4e-4 (its correction is 200 times larger). Measured at 500 modes (the test
/// `correction_in_fewer_bits_matches_double`): 8 bits leave the voice coil's response as far
/// from double precision's as single precision's to three digits in every case, and take the
/// piezo's response to a pier vibration from 2.0e-7 to 5.1e-7 of its largest value; at this
/// bound that rate would add about 2e-8, a tenth of single precision's own difference.
pub const FIXED8_CORRECTION_MAX_BOUND: f64 = 1e-5;

/// How [`CoupledMirror`] stores the coupled solve's correction `W - I`
/// ([`CoupledMirror::set_correction_storage`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CorrectionStorage {
    /// Single precision.
    Single,
    /// Half precision, scaled ([`SymPackedHalf`]): half single precision's traffic.
    Half,
    /// 8-bit fixed point, scaled ([`SymPacked8`]): a quarter of single precision's traffic.
    Fixed8,
}

/// The correction `K` in fewer bits than single precision.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) enum LowCorrection {
    Half(SymPackedHalf),
    Fixed8(SymPacked8),
}

impl LowCorrection {
    /// The diagonal scale the product's vectors are multiplied by, before and after.
    pub(super) fn scale(&self) -> &[f32] {
        match self {
            Self::Half(a) => a.scale(),
            Self::Fixed8(a) => a.scale(),
        }
    }

    /// The bytes a product streams.
    fn stored_bytes(&self) -> usize {
        match self {
            Self::Half(a) => a.stored_bytes(),
            Self::Fixed8(a) => a.stored_bytes(),
        }
    }
}

/// Retained modes from which [`CoupledMirror`] splits its large streaming products between two
/// threads by default ([`CoupledMirror::set_two_threads`]).
pub const TWO_THREADS_MIN_MODES: usize = 500;

/// From this many modes (up to [`TWO_THREADS_MIN_MODES`]) the automatic choice of threads
/// tries both now and then and keeps the faster ([`THREADS_CHECK_STEPS`]). On the project's
/// 2-core VM two threads take 54 against 78 us per step at 150 modes and 107-112 against 160 us
/// at 300 while the two cores share an L3 cache, but 70 against 56 us at 100 modes and 196
/// against 165 us at 300 while they sit on two (BENCHMARKS.md, twelfth round); the host moves
/// them between the two every few seconds to minutes.
pub const SHARED_CACHE_MIN_MODES: usize = 150;

/// The automatic choice of threads between [`SHARED_CACHE_MIN_MODES`] and
/// [`TWO_THREADS_MIN_MODES`] modes is made again every this many steps: [`THREADS_TRIAL_STEPS`]
/// steps on each side, in blocks of [`THREADS_TRIAL_BLOCK`] steps on one thread, two, two and
/// one (so that a drift of the other components' load falls on both alike), each block timed
/// after its first [`THREADS_TRIAL_WARM`] steps; two threads are kept unless the median of
/// their timed steps is longer than one thread's.
///
/// Why so (the nineteenth round of issue 18, on a 2-core Intel VM with 2 MB of level-2 cache
/// per core, TMT at 300 modes in the wind system):
/// - *Blocks.* Where two cores' level-2 caches together hold a step's matrices and one does
///   not, two threads owe part of their gain to each keeping its half in its own cache. The
///   first version changed sides at every step, timing each on caches the other had filled.
/// - *Medians.* Every 100th step the optics' PSSN evaluation holds the master's look-ahead
///   thread on the other core for about 8 steps (in the standard system they fall at the start
///   of every trial, in its first block); a few such long steps do not decide a median.
/// - *Ties to two threads.* When the helper does not get the other core in time the caller
///   takes its halves back, so two threads then cost what one does; the margin of the first
///   version (two kept only at 0.95 times one's time) kept one thread for the next 1000 steps
///   in such moments, and lost the two threads' gain when the helper got its core back. On two
///   L3 caches (the AMD VM of the earlier rounds) two threads are slower by 15-20 % and lose
///   either way.
pub const THREADS_CHECK_STEPS: u32 = 1000;

/// The steps of a block of a trial of [`THREADS_CHECK_STEPS`] (two blocks a side).
pub const THREADS_TRIAL_BLOCK: u32 = 20;

/// The first steps of each block of a trial, not timed (the caches and the helper settle).
pub const THREADS_TRIAL_WARM: u32 = 5;

/// The steps of each side of a trial of [`THREADS_CHECK_STEPS`].
pub const THREADS_TRIAL_STEPS: u32 = 2 * THREADS_TRIAL_BLOCK;

// Every block's timed steps meet the inputs' changes every tenth step equally often, and a
// choice holds for most of a check period.
const _: () = assert!(
    THREADS_TRIAL_BLOCK.is_multiple_of(10)
        && THREADS_TRIAL_WARM < THREADS_TRIAL_BLOCK
        && THREADS_CHECK_STEPS > 4 * THREADS_TRIAL_STEPS
);

/// Retained modes from which [`CoupledMirror`] streams the Gram matrices by their upper block
/// triangles ([`CoupledMirror::set_gram_packed`]): TMT at 800 modes 21-27 % faster per step on
/// one thread, at 600 modes 6 % slower (BENCHMARKS.md, eleventh round).
pub const PACKED_GRAM_MIN_MODES: usize = 700;

/// Retained modes from which [`CoupledMirror`] streams the Gram matrices by their upper block
/// triangles in 24-bit fixed point ([`CoupledMirror::set_gram_fixed24`]), where the processor
/// decodes them with one byte permutation per vector ([`Fixed24::permuted`]): on the project's
/// Intel VM (AVX-512 with VBMI), TMT on two threads at 1000 modes 825-850 against 835-920 us
/// per step, at 700 modes 465-481 against 478-505; at 500 modes, where they are whole in single
/// precision, 300-312 against 290-303 (BENCHMARKS.md, twenty-sixth round). On the AVX2 path
/// their decoding costs more than the traffic it saves: on an AMD EPYC (Zen 1) VM, TMT on two
/// threads at 1000 modes 1680-1730 us per step in 24 bits against 1510-1532 in single
/// precision, at 850 modes 1288-1318 against 1138-1163, at 700 modes 902-916 against 790-817
/// (twenty-ninth round).
pub const FIXED24_GRAM_MIN_MODES: usize = 700;

/// Retained modes from which [`CoupledMirror`] streams the mode shapes in 24-bit fixed point
/// ([`CoupledMirror::set_shapes_fixed24`]) where the processor decodes them with one byte
/// permutation per vector ([`Fixed24::permuted`]): on the project's Intel VM (AVX-512 with
/// VBMI), TMT on two threads at 1000 modes 610-689 against 685-711 us per step, at 700 modes
/// 371-395 against 388-415, at 500 modes 252-257 against 263-271; at 300 modes, where the
/// shapes are half a core's L2 per core, 123-126 against 119-129 (BENCHMARKS.md,
/// twenty-eighth round). Elsewhere from [`FIXED24_SHAPES_AVX2_MIN_MODES`].
pub const FIXED24_SHAPES_MIN_MODES: usize = 500;

/// Retained modes from which [`CoupledMirror`] streams the mode shapes in 24-bit fixed point
/// where the processor decodes them on the AVX2 path (two loads, an insert, a byte shuffle and
/// a conversion per eight entries): on an AMD EPYC (Zen 1) VM, TMT on two threads with the
/// Gram matrices in single precision at 1000 modes 1510-1532 us per step against 1598-1658 in
/// single precision, at 850 modes 1138-1163 against 1190-1216; at 700 modes 790-817 against
/// 780-789 and at 500 modes 477-545 against 449-510, where single precision is faster
/// (BENCHMARKS.md, twenty-ninth round).
pub const FIXED24_SHAPES_AVX2_MIN_MODES: usize = 800;

/// Most coupled ticks whose free part [`CoupledMirror`] composes into one map (a chunk): the
/// default 1 ms TMT step (five ticks) is one chunk; the composed map's rows grow with the
/// chunk (`12 + 2 len`), so a longer step takes several.
pub(super) const FREE_CHUNK_TICKS: usize = 10;

/// Rows of a chunk's composed map: the free states at its end, then per tick the free part's
/// modal force and its drive's change.
pub(super) const fn free_rows(len: usize) -> usize {
    N_STATE + 2 * len
}

/// The free part of the channels on the modes over a chunk of `len` consecutive coupled ticks
/// (the first at sub-step `phase` of its servo period), composed into one map per kind from
/// the projected free states and the two held inputs (command, wind): rows
/// [`free_rows`]`(len)`, the states at the chunk's end, then each tick's modal force
/// `c X_t`, then each tick's change of the drive `X_t[drive] - X_t-1[drive]`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct FreeChunk {
    pub(super) phase: u32,
    pub(super) len: usize,
    pub(super) a: [Vec<[f64; N_STATE]>; 2],
    pub(super) b: [Vec<[f64; 2]>; 2],
    /// The sources each group of rows reads, per kind ([`SourceMasks`]).
    pub(super) masks: [SourceMasks; 2],
}

/// `m` (r x 2r row-major, the two kinds' r columns side by side) in single precision, each
/// kind's columns zero-padded to [`padded_len`]`(r)`.
fn kinds_padded_f32(m: &[f64], r: usize) -> Vec<f32> {
    let ld = padded_len(r);
    let mut out = vec![0.0f32; r * 2 * ld];
    for (row, src) in out.chunks_exact_mut(2 * ld).zip(m.chunks_exact(2 * r)) {
        for k in 0..2 {
            for (d, s) in row[k * ld..k * ld + r]
                .iter_mut()
                .zip(&src[k * r..(k + 1) * r])
            {
                *d = *s as f32;
            }
        }
    }
    out
}

/// Every segment on its actuators, coupled without delay to a modal model of the cell.
///
/// Arrays in and out are in actuator order (actuator k of segment i at 3 i + k).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CoupledMirror {
    pub(super) n_segments: usize,
    pub(super) model: SegmentModel,
    /// The servo period.
    pub(super) ts: f64,
    /// Coupled sub-steps per servo period.
    pub(super) substeps: u32,
    /// Channel maps of one sub-step, by sub-step kind (with the servo's sample, without) and
    /// channel kind (piston, tilt): X+ = P X + S w + ramp Delta.
    pub(super) tick: [[Phi; 2]; 2],
    pub(super) tick_in: [[Gamma; 2]; 2],
    pub(super) ramp: [SVector<f64, N_STATE>; 2],
    pub(super) cell_c: [SMatrix<f64, 1, N_STATE>; 2],
    /// The same maps as plain row-major arrays, by sub-step kind and channel kind, as the tick's
    /// kernel reads them ([`ChannelMaps`]): made once, not at every tick.
    pub(super) channel_maps: [[ChannelMaps; 2]; 2],
    /// Feedthrough of the cell displacement into the cell force (same for both kinds).
    pub(super) cell_d: f64,
    /// `E` per kind: end-of-tick force per unit ramp of the cell displacement.
    pub(super) e: [f64; 2],
    pub(super) basis: SMatrix<f64, 3, 3>,
    /// Free part of the channel states: the segments driven by the command and the wind on a
    /// cell at rest (`zeros`), stepped a communication step at a time.
    pub(super) free: SegmentArray,
    pub(super) zeros: Vec<f64>,
    // Structure.
    pub(super) structure: ModalSolver,
    pub(super) r: usize,
    pub(super) na: usize,
    /// Modal FOH maps per mode.
    /// Component-major (`a_mode[c][j]`: component `c` of mode `j`'s map), so that the
    /// per-mode updates of a tick run as vector operations.
    pub(super) a_mode: [Vec<f64>; 4],
    pub(super) b0: [Vec<f64>; 2],
    pub(super) b1: [Vec<f64>; 2],
    /// Mode shapes in the channel basis (rows: piston channels, then tilt channels 2 s + m),
    /// `na x r` row-major.
    pub(super) phic: Vec<f64>,
    /// The same in single precision, for the two passes per communication step (inputs onto
    /// the modes, outputs back): half the memory traffic, relative error about 1e-7. Rows are
    /// `ld32` long, zero-padded to whole vectors so that the passes have no scalar tail.
    pub(super) phic32: Vec<f32>,
    /// The same by rows in 24-bit fixed point (each mode's column scaled by its largest entry), read
    /// instead of `phic32` by the passes between the channels and the modes when present
    /// ([`Self::set_shapes_fixed24`]).
    #[serde(default)]
    pub(super) shapes_24: Option<Box<ColumnScaled<Fixed24>>>,
    /// Row stride of `phic32`, and length of each column of `cols32` and of `acc32`:
    /// [`padded_len`]`(r)`.
    pub(super) ld32: usize,
    /// Up to [`COLUMN_PASS_MAX_MODES`] modes, `phic32` transposed (`r x ldt`, row `j` mode
    /// `j` at every channel): the mirror's displacement back by columns
    /// ([`crate::linalg::kernels::cols_dot_f32`]), whose rows of a few vectors would each end in
    /// a reduction across the lanes. Empty above.
    pub(super) phit32: Vec<f32>,
    /// Row stride of `phit32`: [`padded_len`]`(na)`.
    pub(super) ldt: usize,
    /// Single-precision scratch: the channel inputs by kind (command then wind, `2 n_k`), the
    /// projection's accumulators (`ld32` each) and the output columns (at most 4 columns of
    /// `ld32`, zero past `r`: the mirror's displacement one per kind, the cell's two per kind).
    pub(super) w32: [Vec<f32>; 2],
    pub(super) acc32: [Vec<f32>; 2],
    /// The second part's sums of the inputs' projection in two parts (the large models'
    /// form, [`Self::project_inputs`]): its scratch and its tilt sums.
    #[serde(default)]
    pub(super) acc32_part: [Vec<f32>; 2],
    #[serde(default)]
    pub(super) tilt_part: [Vec<f64>; 2],
    pub(super) cols32: Vec<f32>,
    /// `[W G_p, W G_t]` with `W = (I - M B1)^-1` and `G_k` the Gram matrices of the shapes'
    /// piston and tilt rows: r x 2r row-major, the coupled solve of a tick in one product
    /// with the channels' cell-driven forces (after the drive's jump). In single precision too
    /// (`wg32`), read instead when [`Self::coupling_single`].
    pub(super) wg: Vec<f64>,
    pub(super) wg32: Vec<f32>,
    /// `[G_p, G_t]`, r x 2r row-major, in single precision (as `wg32`: each kind's columns
    /// zero-padded to `ld32`, so that a row is whole vectors): the modal force of the drive's
    /// jump at a servo sample, and in single precision the whole solve of a sample's tick
    /// (below).
    pub(super) gg32: Vec<f32>,
    /// The solve's correction `W - I = W M B1` in its symmetric form `K = (I - S)^-1 S`,
    /// `S = D M D` with `D = B1^(1/2)` (so `W - I = D^-1 K D`), in single precision by its
    /// upper block triangle (about half of the whole r x r): with [`Self::coupling_single`],
    /// a sample's tick takes one pass over `[G_p, G_t]` with two right-hand sides (the forces
    /// before the jump and the jump) and one over this small correction, instead of a pass
    /// over `G` for the jump and one over `W G`.
    pub(super) corr32: SymPacked32,
    /// `G_p` and `G_t` by their upper block triangles (half the traffic of `gg32`), read
    /// instead of `gg32` when present ([`CoupledMirror::set_gram_packed`]); the products'
    /// results per kind (`G_k psi_k`, `G_k drive_k`) and their column sums' scratch.
    #[serde(default)]
    pub(super) gram_packed: Option<Box<[SymPacked32; 2]>>,
    /// `G_p` and `G_t` by their upper block triangles in 24-bit fixed point, read instead of
    /// `gram_packed` and `gg32` when present ([`CoupledMirror::set_gram_fixed24`]), and the
    /// scaled right-hand sides' scratch (by kind).
    #[serde(default)]
    pub(super) gram_24: Option<Box<[SymPacked24; 2]>>,
    #[serde(default)]
    pub(super) gram_xs: [[Vec<f32>; 2]; 2],
    /// The correction `K` in half precision or 8-bit fixed point, read instead of `corr32`
    /// when present ([`CoupledMirror::set_correction_storage`]).
    #[serde(default)]
    pub(super) corr_low: Option<LowCorrection>,
    #[serde(default)]
    pub(super) gram_y: [[Vec<f64>; 2]; 2],
    #[serde(default)]
    pub(super) gram_t: [[Vec<f32>; 2]; 2],
    /// `D = B1^(1/2)` per mode (every first-order-hold gain `b1` is positive).
    pub(super) d_half: Vec<f64>,
    /// The solve's right-hand sides in single precision, each kind's `r` values zero-padded
    /// to `ld32` (the columns of `gg32` and `wg32`).
    pub(super) psi32: Vec<f32>,
    pub(super) drive32: Vec<f32>,
    /// Whether the coupled solve's products stream the single-precision copies.
    pub(super) coupling_single: bool,
    /// Whether the large streaming products are split between two threads
    /// ([`CoupledMirror::set_two_threads`]).
    #[serde(default)]
    pub(super) two_threads: bool,
    /// The helper thread of [`Self::two_threads`], started on the first step that uses it.
    #[serde(skip)]
    pub(super) pair: LazyPair,
    /// Whether the threads are chosen automatically ([`CoupledMirror::set_two_threads`] not
    /// called): between [`SHARED_CACHE_MIN_MODES`] and [`TWO_THREADS_MIN_MODES`] modes by a
    /// timed trial of both every [`THREADS_CHECK_STEPS`] steps (`trial`).
    #[serde(default)]
    pub(super) threads_auto: bool,
    #[serde(skip)]
    pub(super) trial: ThreadsTrial,
    /// Per mode, the modal force's jump at a sample reaches the tick's start force through
    /// `alpha = (b0 - b1) d` (`d` the drive's feedthrough), and the solve through
    /// `beta = alpha / b1` (`W M alpha = (W - I) beta`).
    pub(super) alpha: Vec<f64>,
    pub(super) beta: Vec<f64>,
    /// The products' results: `G psi`, `G drive_step`, the correction's input (scaled by
    /// `D`, `ld32` long) and its product with `K`; scratch for the symmetric product.
    pub(super) gpsi: Vec<f64>,
    pub(super) gjump: Vec<f64>,
    pub(super) win32: Vec<f32>,
    pub(super) corr: Vec<f64>,
    pub(super) corr_t: Vec<f32>,
    #[serde(default)]
    pub(super) corr_t2: Vec<f32>,
    /// The block row at which the correction's product is cut in two parts (which two
    /// threads may run at once), from [`TWO_THREADS_MIN_MODES`] modes; 0: one part.
    #[serde(default)]
    pub(super) corr_split: usize,
    /// Feedthrough of the drive into the cell force.
    pub(super) drive_d: f64,
    /// The pier displacement held over the last tick.
    pub(super) pier: f64,
    /// Projected free states `Phi_k^T X_k` and cell-driven states `xi_k` (state-major:
    /// `[s * r + j]`), by kind.
    pub(super) proj: [Vec<f64>; 2],
    pub(super) xi: [Vec<f64>; 2],
    /// Within a step, whether `xi` lacks the last tick's ramp part ([`Self::flush_ramp`]);
    /// false between steps.
    #[serde(skip)]
    pub(super) ramp_pending: bool,
    /// Projected inputs `Phi_k^T w_k` (r x 3 column-major), by kind.
    pub(super) w_proj: [Vec<f64>; 2],
    pub(super) q: Vec<f64>,
    pub(super) v: Vec<f64>,
    /// Modal force at the start of the tick.
    pub(super) u: Vec<f64>,
    /// Outputs at the current time, actuator order. The cell's two are computed when read
    /// (`cell_stale`: a step since they were): a master that does not read them saves a
    /// two-column pass over the shapes per step.
    pub(super) cell_stale: bool,
    pub(super) f_cell: Vec<f64>,
    pub(super) z_cell: Vec<f64>,
    pub(super) z_mirror: Vec<f64>,
    /// The free part's ticks composed, built when a chunk of ticks first needs them
    /// ([`FreeChunk`]), and their values over the chunk, by kind: `free_rows(len) x r`.
    pub(super) free_chunks: Vec<FreeChunk>,
    pub(super) free_out: [Vec<f64>; 2],
    // Scratch.
    pub(super) scratch: [Vec<f64>; 2],
    pub(super) psi: Vec<f64>,
    /// The cell-driven part's drive change at the sample, by kind (2r), and the modal force's
    /// jump at the sample (r: the free part's, and outside the one-pass form the cell-driven
    /// part's too).
    pub(super) drive_step: Vec<f64>,
    pub(super) jump: Vec<f64>,
    pub(super) u_new: Vec<f64>,
    pub(super) out: Vec<f64>,
    /// Per mode, the tick's free response of the modes (`a`); between steps, scratch for the
    /// cell's force on the modes.
    pub(super) cols: Vec<f64>,
    /// The free part's cell force per channel (piston channels, then tilt), per step.
    pub(super) free_force: Vec<f64>,
    /// The free part's mirror position per channel (piston channels, then tilt), per step.
    pub(super) free_z: Vec<f64>,
}

/// Most retained modes for which the mirror's displacement goes back by the shapes' columns
/// (a transposed copy of the single-precision shapes,
/// [`crate::linalg::kernels::cols_dot_f32`]). Measured (TMT's 1476 channels, one thread,
/// `cols_dot_f32` against `rows_dot_f32`, BENCHMARKS.md twenty-second round): 3.9 against 5.7 us
/// at 60 modes, 6.7 against 8.8 at 100, 8.6 against 9.2 at 128, 13.7 against 15.6 at 200 and
/// the same time at 300, where the pass is bound by the shapes' traffic; above, the transposed
/// copy, kept beside the rows the inputs' projection reads, would be memory for no gain.
pub const COLUMN_PASS_MAX_MODES: usize = 128;

/// The timed steps of each side of a trial: two blocks, each after its first steps.
const TIMED_PER_SIDE: usize = 2 * (THREADS_TRIAL_BLOCK - THREADS_TRIAL_WARM) as usize;

/// Where the automatic choice of threads is ([`CoupledMirror::set_two_threads`]): steps since
/// its last choice and the trial's timed steps on one and two threads (s).
#[derive(Debug, Clone)]
pub(super) struct ThreadsTrial {
    step: u32,
    times: [[f64; TIMED_PER_SIDE]; 2],
    timed: [usize; 2],
}

impl Default for ThreadsTrial {
    fn default() -> Self {
        Self {
            step: 0,
            times: [[0.0; TIMED_PER_SIDE]; 2],
            timed: [0; 2],
        }
    }
}

impl ThreadsTrial {
    /// Records a timed step on one thread (`side` 0) or two (1).
    fn record(&mut self, side: usize, seconds: f64) {
        if let Some(t) = self.times[side].get_mut(self.timed[side]) {
            *t = seconds;
            self.timed[side] += 1;
        }
    }

    /// Before a step on `two` threads (the current choice): the threads for this step and
    /// whether to time it. Steps since the last choice: `0..2 THREADS_TRIAL_STEPS` the trial
    /// in four blocks, on one, two, two and one threads (each block's timed steps meet as many
    /// of the inputs' changes every tenth step as the others', the blocks being multiples of
    /// ten steps), then the choice, kept until [`THREADS_CHECK_STEPS`].
    fn before_step(&mut self, two: bool) -> (bool, bool) {
        let (trial, check) = (THREADS_TRIAL_STEPS, THREADS_CHECK_STEPS);
        let (block, warm) = (THREADS_TRIAL_BLOCK, THREADS_TRIAL_WARM);
        let k = self.step;
        self.step = if k + 1 >= check.max(2 * trial + 1) {
            0
        } else {
            k + 1
        };
        if k == 0 {
            self.timed = [0; 2];
        }
        if k < 2 * trial {
            let b = k / block;
            // The first steps of a block wake the helper or let it go, and fill the caches as
            // the side needs them: not timed.
            return (b == 1 || b == 2, k % block >= warm);
        }
        if k == 2 * trial {
            return (self.median(1) <= self.median(0), false);
        }
        (two, false)
    }

    /// The median of a side's timed steps (s; infinite when none was timed).
    fn median(&mut self, side: usize) -> f64 {
        let t = &mut self.times[side][..self.timed[side]];
        if t.is_empty() {
            return f64::INFINITY;
        }
        let mid = t.len() / 2;
        *t.select_nth_unstable_by(mid, f64::total_cmp).1
    }
}

/// One channel kind's tick maps as row-major arrays ([`CoupledMirror::channel_maps`]): the
/// state map `p`, the cell displacement's input column without the ramp, `g[:, 1] - ramp`,
/// and the cell force's row `c`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(super) struct ChannelMaps {
    pub(super) p: [[f64; N_STATE]; N_STATE],
    pub(super) g: [[f64; 1]; N_STATE],
    pub(super) c: [f64; N_STATE],
    /// The sources each group of rows of `[p g]` reads ([`SourceMasks`]).
    pub(super) masks: SourceMasks,
}

impl ChannelMaps {
    fn new(p: &Phi, g: &Gamma, ramp: &SVector<f64, N_STATE>, c: &SMatrix<f64, 1, N_STATE>) -> Self {
        let (p, g) = (
            std::array::from_fn(|i| std::array::from_fn(|s| p[(i, s)])),
            std::array::from_fn(|i| [g[(i, 1)] - ramp[i]]),
        );
        Self {
            masks: SourceMasks::of(&p, &g),
            p,
            g,
            c: std::array::from_fn(|i| c[i]),
        }
    }
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
        let drive_d = cp[state::DRIVE];
        let alpha: Vec<f64> = (0..r).map(|j| (b0[j][0] - b1[j][0]) * drive_d).collect();
        let beta: Vec<f64> = (0..r).map(|j| alpha[j] / b1[j][0]).collect();
        if let Some(j) = (0..r).find(|&j| !(b1[j][0] > 0.0 && beta[j].is_finite())) {
            return Err(M1Error::InvalidParameter {
                name: "structure frequencies",
                value: omega[j],
                reason: "a retained mode does not respond within one coupled tick (its \
                         first-order-hold gain is not positive)",
            });
        }
        // The solve W = (I - M B1)^-1 through its symmetric form: with D = B1^(1/2) and
        // S = D M D, W - I = W M B1 = D^-1 K D with K = (I - S)^-1 S. K is formed by that one
        // factorisation (not as a difference with the identity) so that the small correction
        // keeps its relative precision, symmetrised against the solve's rounding; W follows
        // from it.
        let d_half: Vec<f64> = b1.iter().map(|b| b[0].sqrt()).collect();
        let s_mat = DMatrix::from_fn(r, r, |i, j| d_half[i] * m[(i, j)] * d_half[j]);
        let k_mat = (DMatrix::<f64>::identity(r, r) - &s_mat)
            .lu()
            .solve(&s_mat)
            .ok_or(M1Error::Unstable {
                channel: "coupled segments and structure",
                spectral_radius: f64::NAN,
                hint: "the coupled tick is singular: check the structure model and the \
                       actuator stiffness",
            })?;
        let k_sym = DMatrix::from_fn(r, r, |i, j| 0.5 * (k_mat[(i, j)] + k_mat[(j, i)]));
        let w_inv = DMatrix::from_fn(r, r, |i, j| {
            f64::from(u8::from(i == j)) + k_sym[(i, j)] * d_half[j] / d_half[i]
        });
        let corr32 = SymPacked32::from_fn(r, |i, j| k_sym[(i, j)]);
        let corr_split = if r >= TWO_THREADS_MIN_MODES {
            balanced_split(&corr32)
        } else {
            0
        };
        let mut gg = DMatrix::<f64>::zeros(r, 2 * r);
        gg.columns_mut(0, r).copy_from(&gram[0]);
        gg.columns_mut(r, r).copy_from(&gram[1]);
        let wg = row_major(&(&w_inv * &gg));
        let gg = row_major(&gg);
        let tick = [[mp[0].0, mt[0].0], [mp[1].0, mt[1].0]];
        let tick_in = [[mp[0].1, mt[0].1], [mp[1].1, mt[1].1]];
        let cell_c = [cp, ct];
        let channel_maps = std::array::from_fn(|set| {
            std::array::from_fn(|k| {
                ChannelMaps::new(&tick[set][k], &tick_in[set][k], &ramp[k], &cell_c[k])
            })
        });
        let mut mirror = Self {
            n_segments,
            ts,
            substeps,
            tick,
            tick_in,
            ramp,
            cell_c,
            channel_maps,
            cell_d,
            e,
            basis: v,
            free: {
                // Only combinations of its states are read between changes of its inputs: its
                // steps on unchanged inputs are left pending (most steps in the standard
                // systems, whose inputs change at the 100 Hz wind's steps).
                let mut free = SegmentArray::new(n, model.clone())?;
                free.set_deferred(true);
                free
            },
            zeros: vec![0.0; na],
            model,
            structure,
            r,
            na,
            a_mode: std::array::from_fn(|c| a_mode.iter().map(|a| a[c]).collect()),
            b0: std::array::from_fn(|c| b0.iter().map(|b| b[c]).collect()),
            b1: std::array::from_fn(|c| b1.iter().map(|b| b[c]).collect()),
            phic: row_major(&phic),
            phic32: padded_rows_f32(&phic, padded_len(r)),
            shapes_24: None,
            ld32: padded_len(r),
            phit32: if r <= COLUMN_PASS_MAX_MODES {
                padded_rows_f32(&phic.transpose(), padded_len(na))
            } else {
                Vec::new()
            },
            ldt: padded_len(na),
            w32: [vec![0.0f32; 2 * n], vec![0.0f32; 4 * n]],
            acc32: [vec![0.0f32; padded_len(r)], vec![0.0f32; padded_len(r)]],
            acc32_part: [vec![0.0f32; padded_len(r)], vec![0.0f32; padded_len(r)]],
            tilt_part: [vec![0.0; r], vec![0.0; r]],
            cols32: vec![0.0f32; 4 * padded_len(r)],
            wg32: kinds_padded_f32(&wg, r),
            wg,
            gg32: kinds_padded_f32(&gg, r),
            corr32,
            d_half,
            psi32: vec![0.0f32; 2 * padded_len(r)],
            drive32: vec![0.0f32; 2 * padded_len(r)],
            coupling_single: r >= SINGLE_COUPLING_MIN_MODES,
            two_threads: r >= TWO_THREADS_MIN_MODES,
            pair: LazyPair::default(),
            threads_auto: true,
            trial: ThreadsTrial::default(),
            gram_packed: None,
            gram_24: None,
            gram_xs: Default::default(),
            corr_low: None,
            gram_y: Default::default(),
            gram_t: Default::default(),
            alpha,
            beta,
            gpsi: vec![0.0; r],
            gjump: vec![0.0; r],
            win32: vec![0.0f32; padded_len(r)],
            corr: vec![0.0; r],
            corr_t: vec![0.0f32; padded_order(r)],
            corr_t2: vec![0.0f32; padded_order(r)],
            corr_split,
            drive_d,
            pier: 0.0,
            proj: [vec![0.0; r * N_STATE], vec![0.0; r * N_STATE]],
            xi: [vec![0.0; r * N_STATE], vec![0.0; r * N_STATE]],
            ramp_pending: false,
            w_proj: [vec![0.0; r * N_IN], vec![0.0; r * N_IN]],
            q: vec![0.0; r],
            v: vec![0.0; r],
            u: vec![0.0; r],
            cell_stale: false,
            f_cell: vec![0.0; na],
            z_cell: vec![0.0; na],
            z_mirror: vec![0.0; na],
            free_chunks: Vec::new(),
            free_out: [
                vec![0.0; r * free_rows(FREE_CHUNK_TICKS)],
                vec![0.0; r * free_rows(FREE_CHUNK_TICKS)],
            ],
            scratch: [vec![0.0; r * N_STATE], vec![0.0; r * N_STATE]],
            psi: vec![0.0; 2 * r],
            drive_step: vec![0.0; 2 * r],
            jump: vec![0.0; r],
            u_new: vec![0.0; r],
            out: vec![0.0; 3 * na],
            cols: vec![0.0; r],
            free_force: vec![0.0; na],
            free_z: vec![0.0; na],
        };
        mirror.set_gram_packed(r >= PACKED_GRAM_MIN_MODES);
        mirror.set_gram_fixed24(Self::gram_fixed24_default(r));
        mirror.set_shapes_fixed24(Self::shapes_fixed24_default(r));
        if r >= HALF_CORRECTION_MIN_MODES {
            mirror.set_correction_storage(mirror.correction_default());
        }
        Ok(mirror)
    }

    /// Streams the coupled solve's matrices in single precision (`true`, the default from
    /// [`SINGLE_COUPLING_MIN_MODES`] retained modes, where a sample's tick also takes the
    /// one-pass form of the module documentation) or double precision (`false`, the default
    /// below, where the double-precision matrix fits a core's L1 cache and halving it gains
    /// nothing). A TMT step with 300 modes streams 14.4 MB in double precision, 8.2 MB in single;
    /// against double precision single moves the mirror's response by about 2e-9 of its largest
    /// value on TMT (the test `coupling_precision_single_matches_double` bounds it by 1e-7 for the
    /// voice coil and 1e-6 for the piezo).
    pub fn set_coupling_single(&mut self, single: bool) {
        self.coupling_single = single;
    }

    /// Splits the step's large parts (the coupled solve's passes over the Gram matrices or
    /// `W G` and over the correction `W - I`, the channels' maps on the modes and the free
    /// part by kind, the shapes' pass back to the actuators) between this thread and a helper
    /// thread (`true`), or keeps them on the calling thread (`false`). Every value is summed as
    /// on one thread, so the results are the same to the bit. The default is `true` from
    /// [`TWO_THREADS_MIN_MODES`] modes, where the products are bound by one core's share of the
    /// cache bandwidth, and from [`SHARED_CACHE_MIN_MODES`] whichever a timed trial of both
    /// finds faster (every [`THREADS_CHECK_STEPS`] steps); this call ends that automatic
    /// choice. The helper polls for work for 0.3 ms after each part and sleeps after that
    /// ([`crate::linalg::pair`]).
    pub fn set_two_threads(&mut self, two: bool) {
        self.threads_auto = false;
        self.two_threads = two;
        if !two {
            self.pair.stop();
        }
    }

    /// Streams the Gram matrices `G_p`, `G_t` of a servo sample's tick by their upper block
    /// triangles (`true`, the default from [`PACKED_GRAM_MIN_MODES`] modes) or whole
    /// (`false`). Stored so, each entry read serves its row's and its column's products: half
    /// the traffic, the same multiply-adds; the results agree to single-precision rounding.
    /// Only the single-precision one-pass solve reads them ([`Self::set_coupling_single`]).
    pub fn set_gram_packed(&mut self, packed: bool) {
        let r = self.r;
        if packed && self.gram_packed.is_none() {
            let kind = |k: usize| SymPacked32::from_fn(r, self.gram_entries(k));
            self.gram_packed = Some(Box::new([kind(0), kind(1)]));
            self.gram_by_kind_scratch();
        } else if !packed {
            self.gram_packed = None;
        }
    }

    /// Streams the Gram matrices by their upper block triangles in 24-bit fixed point
    /// ([`SymPacked24`]: three quarters of the traffic of [`Self::set_gram_packed`]'s single
    /// precision, each entry within about `6e-8 sqrt(max_j |G_ij| max_j |G_kj|)` of the
    /// single-precision one) (`true`, the default by [`Self::gram_fixed24_default`]) or not
    /// (`false`: the storage of [`Self::set_gram_packed`]). Read instead of that storage by the
    /// single-precision one-pass solve of the large models' step
    /// ([`Self::set_coupling_single`]).
    pub fn set_gram_fixed24(&mut self, on: bool) {
        let r = self.r;
        if on && self.gram_24.is_none() {
            let kind = |k: usize| SymPacked24::from_fn(r, self.gram_entries(k));
            // The single-precision Gram matrices are finite (checked when formed).
            if let (Some(p), Some(t)) = (kind(0), kind(1)) {
                self.gram_24 = Some(Box::new([p, t]));
                self.gram_by_kind_scratch();
            }
        } else if !on {
            self.gram_24 = None;
        }
    }

    /// Whether the Gram matrices are streamed in 24-bit fixed point
    /// ([`Self::set_gram_fixed24`]).
    pub fn gram_fixed24(&self) -> bool {
        self.gram_24.is_some()
    }

    /// Whether a mirror of `r` retained modes streams the Gram matrices in 24-bit fixed point
    /// by default on this processor: from [`FIXED24_GRAM_MIN_MODES`] modes where it decodes
    /// them with one byte permutation per vector ([`Fixed24::permuted`]).
    pub fn gram_fixed24_default(r: usize) -> bool {
        r >= FIXED24_GRAM_MIN_MODES && Fixed24::permuted()
    }

    /// Whether a mirror of `r` retained modes streams the mode shapes in 24-bit fixed point by
    /// default on this processor: from [`FIXED24_SHAPES_MIN_MODES`] modes where it decodes
    /// them with one byte permutation per vector ([`Fixed24::permuted`]), from
    /// [`FIXED24_SHAPES_AVX2_MIN_MODES`] where it decodes them with other vector instructions,
    /// never on the scalar path.
    pub fn shapes_fixed24_default(r: usize) -> bool {
        if Fixed24::permuted() {
            r >= FIXED24_SHAPES_MIN_MODES
        } else {
            r >= FIXED24_SHAPES_AVX2_MIN_MODES && Fixed24::vectorised()
        }
    }

    /// Streams the mode shapes of the passes between the channels and the modes (the inputs
    /// onto the modes, the mirror's displacement and the cell's outputs back) by rows in 24-bit
    /// fixed point ([`ColumnScaled`]: three quarters of single precision's traffic, each entry
    /// within `6e-8` of its column's largest) (`true`, the default by
    /// [`Self::shapes_fixed24_default`]) or in single precision (`false`). Up to
    /// [`COLUMN_PASS_MAX_MODES`] modes the displacement's pass back reads the shapes'
    /// single-precision columns either way.
    pub fn set_shapes_fixed24(&mut self, on: bool) {
        if on && self.shapes_24.is_none() {
            let (r, phic) = (self.r, &self.phic);
            // The shapes are finite (checked when the structure's modes are solved).
            self.shapes_24 =
                ColumnScaled::from_fn(self.na, r, |i, j| phic[i * r + j]).map(Box::new);
        } else if !on {
            self.shapes_24 = None;
        }
    }

    /// Whether the mode shapes are streamed in 24-bit fixed point
    /// ([`Self::set_shapes_fixed24`]).
    pub fn shapes_fixed24(&self) -> bool {
        self.shapes_24.is_some()
    }

    /// Entry `(i, j)` of the Gram matrix of kind `k` (0 piston, 1 tilt), from `gg32`.
    fn gram_entries(&self, k: usize) -> impl Fn(usize, usize) -> f64 + '_ {
        let (gg, ld) = (&self.gg32, self.ld32);
        move |i, j| f64::from(gg[i * 2 * ld + k * ld + j])
    }

    /// The scratch of the Gram matrices' products by kind, sized.
    fn gram_by_kind_scratch(&mut self) {
        let (r, n) = (self.r, padded_order(self.r));
        self.gram_y = std::array::from_fn(|_| std::array::from_fn(|_| vec![0.0; r]));
        self.gram_t = std::array::from_fn(|_| std::array::from_fn(|_| vec![0.0f32; n]));
        self.gram_xs = std::array::from_fn(|_| std::array::from_fn(|_| vec![0.0f32; n]));
    }

    /// Stores the coupled solve's correction `W - I` (its symmetric form `K`, by its upper
    /// block triangle) as `storage` says. Only the single-precision one-pass solve reads it
    /// ([`Self::set_coupling_single`]). The correction is a small term of the solve (about 4e-7
    /// of it in norm for the voice coil, 8e-5 for the piezo), so its entries need less
    /// precision than the rest: the default from [`HALF_CORRECTION_MIN_MODES`] modes is
    /// [`Self::correction_default`], 8 bits where their rounding bound
    /// ([`Self::correction_rounding_bound`]) is within [`FIXED8_CORRECTION_MAX_BOUND`], half
    /// precision otherwise. The test `correction_in_fewer_bits_matches_double` bounds the mirror's response to wind, a
    /// command, a static load and a pier vibration against double precision with each storage.
    /// A correction with an entry that is not finite stays in single precision. The Gram
    /// matrices are not small terms: rounded to half precision they moved the mirror's response
    /// to a pier vibration by 5e-4 of its rms (TMT, 300 modes; single against double
    /// precision: 1.4e-7), hence [`Self::set_gram_fixed24`].
    pub fn set_correction_storage(&mut self, storage: CorrectionStorage) {
        if storage == self.correction_storage() {
            return;
        }
        let corr = &self.corr32;
        let get = |i: usize, j: usize| f64::from(corr.get(i, j));
        self.corr_low = match storage {
            CorrectionStorage::Single => None,
            CorrectionStorage::Half => SymPackedHalf::from_fn(self.r, get).map(LowCorrection::Half),
            CorrectionStorage::Fixed8 => {
                SymPacked8::from_fn(self.r, get).map(LowCorrection::Fixed8)
            }
        };
    }

    /// How the correction `W - I` is stored ([`Self::set_correction_storage`]).
    pub fn correction_storage(&self) -> CorrectionStorage {
        match self.corr_low {
            None => CorrectionStorage::Single,
            Some(LowCorrection::Half(_)) => CorrectionStorage::Half,
            Some(LowCorrection::Fixed8(_)) => CorrectionStorage::Fixed8,
        }
    }

    /// A bound on the rounding of the correction's product `(W - I) x` by `storage`, relative
    /// to `max_j |x_j|`: `max_i sum_j e_ij d_j / d_i` (`W - I = D^-1 K D`), with `e_ij` the
    /// storage's bound on its rounding of `K_ij` (single precision `2^-24 |K_ij|`, half
    /// precision `2^-11 |K_ij| + 2^-25 s_i s_j`, 8 bits `s_i s_j / 254`, with
    /// `s_i = sqrt(max_j |K_ij|)`; [`crate::linalg::symmetric_scaled`]).
    pub fn correction_rounding_bound(&self, storage: CorrectionStorage) -> f64 {
        let (r, k, d) = (self.r, &self.corr32, &self.d_half);
        // The scale the scaled storages take (`None`: an entry not finite, no bound).
        let Some(s) = symmetric_scale(r, &|i, j| f64::from(k.get(i, j))) else {
            return f64::INFINITY;
        };
        let e = |i: usize, j: usize| {
            let kij = f64::from(k.get(i, j)).abs();
            match storage {
                CorrectionStorage::Single => 2f64.powi(-24) * kij,
                CorrectionStorage::Half => 2f64.powi(-11) * kij + 2f64.powi(-25) * s[i] * s[j],
                CorrectionStorage::Fixed8 => s[i] * s[j] / 254.0,
            }
        };
        (0..r)
            .map(|i| (0..r).map(|j| e(i, j) * d[j]).sum::<f64>() / d[i])
            .fold(0.0, f64::max)
    }

    /// The storage of the correction the mirror takes from [`HALF_CORRECTION_MIN_MODES`]
    /// modes: 8 bits where their rounding bound ([`Self::correction_rounding_bound`]) is within
    /// [`FIXED8_CORRECTION_MAX_BOUND`] (TMT's voice coil) and the processor decodes them with
    /// vector instructions, else half precision (the piezo, whose correction is 200 times
    /// larger).
    pub fn correction_default(&self) -> CorrectionStorage {
        if Fixed8::vectorised()
            && self.correction_rounding_bound(CorrectionStorage::Fixed8)
                <= FIXED8_CORRECTION_MAX_BOUND
        {
            CorrectionStorage::Fixed8
        } else {
            CorrectionStorage::Half
        }
    }

    /// Whether the Gram matrices are streamed by their upper block triangles.
    pub fn gram_packed(&self) -> bool {
        self.gram_packed.is_some()
    }

    /// Whether a step takes any of the large models' forms (two threads, the Gram matrices by
    /// half, the correction in two parts or in fewer bits).
    pub(super) fn large_forms(&self) -> bool {
        self.two_threads
            || self.gram_packed.is_some()
            || self.gram_24.is_some()
            || self.corr_split > 0
            || self.corr_low.is_some()
    }

    /// Whether the large products are split between two threads.
    pub fn two_threads(&self) -> bool {
        self.two_threads
    }

    /// Whether the coupled solve streams its matrix in single precision.
    pub fn coupling_single(&self) -> bool {
        self.coupling_single
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

    /// The matrices a communication step of `h` seconds streams, with how many times each is
    /// read per step on average when the command and the wind forces change every
    /// `inputs_every` steps (at least 1; the standard systems' 100 Hz wind changes them every
    /// 10 steps of 1 ms): `(name, bytes, reads per step)`, each a distinct array. The inputs'
    /// pass over the shapes is made only in a step whose inputs changed (otherwise their
    /// projection is the last step's), so it counts `1 / inputs_every` per step. The sum is the
    /// step's unavoidable memory traffic once the matrices no longer fit a core's cache (a
    /// floor for benchmarks: at TMT size with 300 modes and inputs changing every tenth step,
    /// 6.6 MB per 1 ms step).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] if `h` is not a whole number of servo periods.
    pub fn streamed_per_step(
        &self,
        h: f64,
        inputs_every: u64,
    ) -> Result<Vec<(&'static str, usize, f64)>, M1Error> {
        let samples = self.ticks_in(h)?;
        let ticks = samples * u64::from(self.substeps);
        let inputs = 1.0 / inputs_every.max(1) as f64;
        let (rows, rows_bytes) = match self.shapes_24.as_deref() {
            Some(a) => (
                "mode shapes by rows in 24-bit fixed point",
                a.stored_bytes(),
            ),
            None => (
                "mode shapes by rows (single precision)",
                std::mem::size_of_val(self.phic32.as_slice()),
            ),
        };
        let shapes = if self.phit32.is_empty() {
            vec![(rows, rows_bytes, 1.0 + inputs)]
        } else {
            vec![
                (rows, rows_bytes, inputs),
                (
                    "mode shapes by columns (single precision)",
                    std::mem::size_of_val(self.phit32.as_slice()),
                    1.0,
                ),
            ]
        };
        // Read at every coupled tick or servo sample (`u64` counts).
        let on_ticks: [(&'static str, usize, u64); 3] = [
            (
                "[W G_p, W G_t], one per coupled tick (in single precision: between samples)",
                if self.coupling_single {
                    std::mem::size_of_val(self.wg32.as_slice())
                } else {
                    std::mem::size_of_val(self.wg.as_slice())
                },
                if self.coupling_single {
                    ticks - samples
                } else {
                    ticks
                },
            ),
            match (
                self.gram_24.as_deref(),
                self.gram_packed.as_deref(),
                self.coupling_single,
            ) {
                (Some([p, t]), _, true) => (
                    "Gram matrices G_p, G_t by their upper block triangles in 24-bit fixed \
                     point, one per servo sample",
                    p.stored_bytes() + t.stored_bytes(),
                    samples,
                ),
                (None, Some([p, t]), true) => (
                    "Gram matrices G_p, G_t by their upper block triangles, one per servo sample",
                    std::mem::size_of_val(p.as_slice()) + std::mem::size_of_val(t.as_slice()),
                    samples,
                ),
                _ => (
                    "Gram matrices [G_p, G_t], one per servo sample",
                    std::mem::size_of_val(self.gg32.as_slice()),
                    samples,
                ),
            },
            (
                match self.correction_storage() {
                    CorrectionStorage::Single => {
                        "the solve's correction W - I in symmetric form by its upper block \
                         triangle, one per servo sample (single precision)"
                    }
                    CorrectionStorage::Half => {
                        "the solve's correction W - I in symmetric form by its upper block \
                         triangle, one per servo sample (half precision)"
                    }
                    CorrectionStorage::Fixed8 => {
                        "the solve's correction W - I in symmetric form by its upper block \
                         triangle, one per servo sample (8-bit fixed point)"
                    }
                },
                self.corr_low.as_ref().map_or_else(
                    || std::mem::size_of_val(self.corr32.as_slice()),
                    LowCorrection::stored_bytes,
                ),
                if self.coupling_single { samples } else { 0 },
            ),
        ];
        Ok(shapes
            .into_iter()
            .chain(on_ticks.map(|(name, bytes, reads)| (name, bytes, reads as f64)))
            .collect())
    }

    /// The multiply-adds a communication step of `h` seconds cannot avoid in this scheme, by
    /// part: `(name, multiply-adds, single precision)`, when the command and the wind forces
    /// change every `inputs_every` steps (at least 1; the standard systems' 100 Hz wind
    /// changes them every 10 steps of 1 ms). Zero coefficients of the channel maps are not
    /// counted (the kernels skip most of them), nor are the O(r) per-mode updates and the
    /// O(na) conversions and copies. Their sum at the machine's peak rate of fused
    /// multiply-adds is the step's arithmetic floor (a benchmark's; at TMT size with 60
    /// modes the arithmetic, not the memory traffic, bounds a step).
    ///
    /// # Errors
    /// [`M1Error::InvalidParameter`] if `h` is not a whole number of servo periods.
    pub fn multiply_adds_per_step(
        &self,
        h: f64,
        inputs_every: u64,
    ) -> Result<Vec<(&'static str, u64, bool)>, M1Error> {
        let samples = self.ticks_in(h)?;
        let ticks = samples * u64::from(self.substeps);
        let nnz = |m: &[f64]| m.iter().filter(|v| **v != 0.0).count() as u64;
        let (r, n) = (self.r as u64, self.n_segments as u64);
        let channels = [n, 2 * n];
        let mut free = 0;
        let mut on_modes = 0;
        for (kind, ch) in [Channel::Piston, Channel::Tilt].into_iter().enumerate() {
            let (p, s) = self.model.closed_loop(ch);
            let (p, s) = propagate(&p, &s, samples);
            let per_channel = free_part_multiply_adds(&p, &s, inputs_every.max(1));
            free += (channels[kind] * per_channel).div_ceil(inputs_every.max(1));
            // Per coupled tick and mode: the cell-driven part's map with its ramp input and
            // force row, the ramp (the first tick of a servo period samples, the others hold
            // the drive).
            for set in (0..self.substeps).map(|s| usize::from(s > 0)) {
                let map = nnz(self.tick[set][kind].as_slice());
                let g = &self.tick_in[set][kind];
                let inputs = (0..N_STATE)
                    .filter(|&i| g[(i, 1)] != self.ramp[kind][i])
                    .count() as u64;
                let ramp = nnz(self.ramp[kind].as_slice());
                on_modes += samples * r * (map + inputs + N_STATE as u64 + ramp);
            }
        }
        // The free part on the modes: per chunk of ticks, its composed map.
        let mut composed = 0;
        for (phase, len) in self.chunks(ticks as usize) {
            let c = self.compose_free(phase, len);
            for k in 0..2 {
                let rows = c.a[k].iter().flatten().chain(c.b[k].iter().flatten());
                composed += r * rows.filter(|v| **v != 0.0).count() as u64;
            }
        }
        let na = self.na as u64;
        Ok(vec![
            (
                "free part: channel maps in actuator space (the steps on unchanged inputs \
                 pending, the mirror's position read from them), per step",
                free,
                false,
            ),
            (
                "channel maps on the modes: the cell-driven part, per coupled tick",
                on_modes,
                false,
            ),
            (
                "the free part on the modes: its ticks composed, per chunk of ticks",
                composed,
                false,
            ),
            (
                "coupled solve [W G_p, W G_t] (r x 2r), per coupled tick (in single precision: \
                 between samples)",
                if self.coupling_single {
                    (ticks - samples) * 2 * r * r
                } else {
                    ticks * 2 * r * r
                },
                self.coupling_single,
            ),
            (
                "drive jump [G_p, G_t] (r x 2r), per servo sample (in single precision: with \
                 the solve's right-hand side, and the correction W - I, r x r)",
                if self.coupling_single {
                    samples * 5 * r * r
                } else {
                    samples * 2 * r * r
                },
                true,
            ),
            ("inputs onto the modes (two columns)", 2 * na * r, true),
            (
                "outputs back: the mirror's displacement (one column; the cell's two are \
                 computed when read)",
                na * r,
                true,
            ),
        ])
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
        let timed = self.choose_threads();
        // The free part over the whole step at once (its inputs, projected on the channels,
        // are then read back for the modes).
        self.free.advance(h, u_cmd, &self.zeros, f_wind)?;
        // The held inputs onto the modes, the ticks and the outputs back, in one function
        // compiled for this processor's vector instructions (everything in it is inlined).
        pulp::Arch::new().dispatch(Step {
            mirror: self,
            ticks,
            pier_z,
        });
        if let Some(t0) = timed {
            self.trial
                .record(usize::from(self.two_threads), t0.elapsed().as_secs_f64());
        }
        Ok(())
    }

    /// The automatic choice of threads between [`SHARED_CACHE_MIN_MODES`] and
    /// [`TWO_THREADS_MIN_MODES`] modes ([`Self::set_two_threads`]), before a step: every
    /// [`THREADS_CHECK_STEPS`] steps a trial of [`THREADS_TRIAL_STEPS`] steps on one thread
    /// and as many on two, in blocks (one, two, two, one), then the faster kept. Either gives
    /// the same values to the bit. Returns the time at which this step starts when the trial
    /// times it.
    fn choose_threads(&mut self) -> Option<std::time::Instant> {
        if !self.threads_auto || !(SHARED_CACHE_MIN_MODES..TWO_THREADS_MIN_MODES).contains(&self.r)
        {
            return None;
        }
        let (two, timed) = self.trial.before_step(self.two_threads);
        self.two_threads = two;
        timed.then(std::time::Instant::now)
    }

    /// The composed map of a chunk of `len` ticks starting at sub-step `phase` (built from the
    /// per-tick maps in the order the ticks take them, kept for the next steps).
    pub(super) fn free_chunk(&mut self, phase: u32, len: usize) -> usize {
        if let Some(i) = self
            .free_chunks
            .iter()
            .position(|c| c.phase == phase && c.len == len)
        {
            return i;
        }
        let chunk = self.compose_free(phase, len);
        self.free_chunks.push(chunk);
        self.free_chunks.len() - 1
    }

    /// The chunks a step of `ticks` coupled ticks is taken in: `(phase, len)` each.
    pub(super) fn chunks(&self, ticks: usize) -> impl Iterator<Item = (u32, usize)> + use<> {
        let sub = self.substeps as usize;
        (0..ticks)
            .step_by(FREE_CHUNK_TICKS)
            .map(move |t| ((t % sub) as u32, FREE_CHUNK_TICKS.min(ticks - t)))
    }

    /// The composed map of a chunk ([`FreeChunk`]).
    fn compose_free(&self, phase: u32, len: usize) -> FreeChunk {
        let dr = state::DRIVE;
        let compose = |k: usize| {
            let mut a = SMatrix::<f64, N_STATE, N_STATE>::identity();
            let mut b = SMatrix::<f64, N_STATE, 2>::zeros();
            let mut force = Vec::with_capacity(len);
            let mut drive = Vec::with_capacity(len);
            for i in 0..len {
                let sample = (phase as usize + i).is_multiple_of(self.substeps as usize);
                let set = usize::from(!sample);
                let (p, g) = (&self.tick[set][k], &self.tick_in[set][k]);
                let (a0, b0) = (a.row(dr).into_owned(), b.row(dr).into_owned());
                a = p * a;
                let mut gin = SMatrix::<f64, N_STATE, 2>::zeros();
                gin.set_column(0, &g.column(0));
                gin.set_column(1, &g.column(2));
                b = p * b + gin;
                let c = &self.cell_c[k];
                force.push((c * a, c * b));
                drive.push((a.row(dr) - a0, b.row(dr) - b0));
            }
            let mut ra: Vec<[f64; N_STATE]> = Vec::with_capacity(free_rows(len));
            let mut rb: Vec<[f64; 2]> = Vec::with_capacity(free_rows(len));
            for i in 0..N_STATE {
                ra.push(std::array::from_fn(|j| a[(i, j)]));
                rb.push(std::array::from_fn(|l| b[(i, l)]));
            }
            for (fa, fb) in force.iter().chain(&drive) {
                ra.push(std::array::from_fn(|j| fa[j]));
                rb.push(std::array::from_fn(|l| fb[l]));
            }
            (ra, rb)
        };
        let (a0, b0) = compose(0);
        let (a1, b1) = compose(1);
        FreeChunk {
            phase,
            len,
            masks: [SourceMasks::of(&a0, &b0), SourceMasks::of(&a1, &b1)],
            a: [a0, a1],
            b: [b0, b1],
        }
    }

    /// The held inputs on the modes: `Phi_k^T w_k` for the command and wind columns of each
    /// kind, from the single-precision shapes. A kind whose inputs are the same as at the last
    /// step, to the bit in single precision, keeps its projection (`w_proj` is always the
    /// projection of `w32`): in the standard system the command changes at the global loop's
    /// 20 Hz and the wind at 100 Hz, so most 1 ms steps skip the pass.
    #[inline(always)]
    pub(super) fn project_inputs<S: pulp::Simd, const LARGE: bool>(&mut self, simd: S) {
        // Inputs given as at the last step, to the bit: their projection is the last one.
        if self.free.inputs_unchanged() {
            return;
        }
        let r = self.r;
        let [p, t] = &mut self.w_proj;
        let (pu, pf) = input_columns(p, r);
        let (tu, tf) = input_columns(t, r);
        // Command and wind columns of each kind, in single precision.
        let mut changed = [false; 2];
        for (kind, w) in self.free.channel_inputs().into_iter().enumerate() {
            let cnt = self.w32[kind].len() / 2;
            let (du, df) = self.w32[kind].split_at_mut(cnt);
            let cu = store_f32(du, &w[..cnt]);
            let cf = store_f32(df, &w[2 * cnt..3 * cnt]);
            changed[kind] = cu || cf;
        }
        if changed == [false; 2] {
            return;
        }
        let (ld, n) = (self.ld32, self.n_segments);
        let phic = Shapes::new(self.shapes_24.as_deref(), &self.phic32);
        let w = [&self.w32[0][..], &self.w32[1][..]];
        let project = |rows, acc, out| Project {
            phic,
            ld,
            n,
            rows,
            kinds: changed,
            w,
            acc,
            out,
        };
        let [a0, a1] = &mut self.acc32;
        // In two parts of channel rows, at once on two threads (on one, whatever the model, the
        // same two parts in turn: the same sums): the piston rows and the first tilt rows, the
        // other tilt rows into `tilt_part`, then added. Whole rows each (split by modes, the
        // two cores' halves of a row shared its cache lines' prefetches: no faster than one
        // core).
        let cut = n + ((n / 2) & !3);
        let [part_u, part_f] = &mut self.tilt_part;
        let [b0, b1] = &mut self.acc32_part;
        let lo = project(0..cut, [a0, a1], [pu, pf, &mut *tu, &mut *tf]);
        let hi = project(
            cut..3 * n,
            [b0, b1],
            [&mut [], &mut [], &mut *part_u, &mut *part_f],
        );
        let pair = if LARGE && self.two_threads {
            self.pair.get()
        } else {
            None
        };
        match pair {
            Some(p) => p.join(|| simd.vectorize(lo), move || simd.vectorize(hi)),
            None => {
                lo.with_simd(simd);
                hi.with_simd(simd);
            }
        }
        if changed[1] {
            for (t, p) in tu.iter_mut().zip(part_u.iter()) {
                *t += p;
            }
            for (t, p) in tf.iter_mut().zip(part_f.iter()) {
                *t += p;
            }
        }
    }

    /// Mirror displacement `z` at each actuator (length 3N).
    pub fn mirror(&self, z: &mut [f64]) {
        z.copy_from_slice(&self.z_mirror);
    }

    /// Cell displacement at each attachment (length 3N). Computed on the first read after a
    /// step, with [`Self::cell_force`] (one pass over the mode shapes for both).
    pub fn cell_displacement(&mut self) -> &[f64] {
        self.update_cell_outputs();
        &self.z_cell
    }

    /// Force of each actuator on the cell (length 3N). Computed on the first read after a
    /// step, with [`Self::cell_displacement`].
    pub fn cell_force(&mut self) -> &[f64] {
        self.update_cell_outputs();
        &self.f_cell
    }

    /// The cell's displacement and force, both computed if a step left them stale.
    pub fn cell_outputs(&mut self) -> (&[f64], &[f64]) {
        self.update_cell_outputs();
        (&self.z_cell, &self.f_cell)
    }

    fn update_cell_outputs(&mut self) {
        if self.cell_stale {
            pulp::Arch::new().dispatch(CellOutputs { mirror: self });
        }
    }

    /// Back to rest.
    pub fn reset(&mut self) {
        self.free.reset();
        self.pier = 0.0;
        self.cell_stale = false;
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
}

/// Stores `src` in single precision into `dst` (of the same length), and says whether any
/// value changed (to the bit): one pass that vectorises.
fn store_f32(dst: &mut [f32], src: &[f64]) -> bool {
    let mut same = true;
    for (d, s) in dst.iter_mut().zip(src) {
        let v = *s as f32;
        same &= v.to_bits() == d.to_bits();
        *d = v;
    }
    !same
}

/// The free part's multiply-adds per channel over one period of `every` steps whose inputs
/// change at its first ([`SegmentArray::set_deferred`]), in the steady state, with the step map
/// `(p, s)`: the step that brings new inputs applies the pending steps with it in one pass, the
/// others read the mirror's position from the pending map's row (one pass of the whole map
/// when the table of its powers ends), and only the step whose inputs changed projects them
/// onto the channel (`N_STATE`, as counted at every step before the steps were left pending:
/// inputs equal to the last step's are not projected again).
fn free_part_multiply_adds(p: &Phi, s: &Gamma, every: u64) -> u64 {
    use crate::plant::segment::MAX_PENDING_STEPS;
    let nnz = |m: &[f64]| m.iter().filter(|v| **v != 0.0).count() as u64;
    let mp = state::MIRROR_POS;
    // (P^k, S_k) for k = 1..=MAX_PENDING_STEPS + 1.
    let mut powers = vec![(*p, *s)];
    while powers.len() <= MAX_PENDING_STEPS {
        let (pk, sk) = powers[powers.len() - 1];
        powers.push((p * pk, p * sk + s));
    }
    let row = |k: usize| {
        let (pk, sk) = &powers[k - 1];
        nnz(pk.row(mp).transpose().as_slice()) + nnz(sk.row(mp).transpose().as_slice())
    };
    let (mut pending, mut total) = (0usize, 0u64);
    // Two periods: the second one's count is the steady state's.
    for period in 0..2 {
        let mut count = 0;
        for j in 0..every {
            if j == 0 {
                count += N_STATE as u64;
            }
            if j > 0 && pending < MAX_PENDING_STEPS {
                pending += 1;
                count += row(pending);
            } else if j > 0 {
                let (pk, sk) = &powers[pending - 1];
                count += nnz(pk.as_slice()) + nnz(sk.as_slice()) + row(1);
                pending = 1;
            } else if pending == 0 {
                count += nnz(p.as_slice()) + nnz(s.as_slice());
            } else {
                let (pn1, _) = &powers[pending];
                let held = p * powers[pending - 1].1;
                count += nnz(pn1.as_slice()) + nnz(held.as_slice()) + nnz(s.as_slice());
                pending = 0;
            }
        }
        if period == 1 {
            total = count;
        }
    }
    total
}

#[cfg(test)]
mod tests {
    use super::{
        THREADS_CHECK_STEPS, THREADS_TRIAL_BLOCK, THREADS_TRIAL_WARM, TIMED_PER_SIDE, ThreadsTrial,
    };

    /// Runs a whole check period of the trial with one thread's steps taking `one(k)` and two
    /// threads' `two(k)` (k: the step's index among its side's timed steps); returns the
    /// threads of every step.
    fn period(
        trial: &mut ThreadsTrial,
        one: impl Fn(usize) -> f64,
        two: impl Fn(usize) -> f64,
    ) -> Vec<bool> {
        let (block, warm) = (THREADS_TRIAL_BLOCK, THREADS_TRIAL_WARM);
        let mut current = false;
        (0..THREADS_CHECK_STEPS)
            .map(|k| {
                let (t, timed) = trial.before_step(current);
                // Timed: the trial's steps after each block's first ones, nothing else.
                assert_eq!(timed, k < 4 * block && k % block >= warm, "step {k}");
                current = t;
                if timed {
                    let side = usize::from(t);
                    let i = trial.timed[side];
                    trial.record(side, if t { two(i) } else { one(i) });
                }
                t
            })
            .collect()
    }

    /// The trial's blocks (one, two, two, one thread), the steps it times in each, and the
    /// choice by the medians: a few long steps on one side (a PSSN evaluation holding the
    /// other core) do not decide it, a tie goes to two threads, a slower two to one.
    #[test]
    fn the_trial_runs_in_blocks_and_chooses_by_medians() {
        let (block, warm) = (THREADS_TRIAL_BLOCK as usize, THREADS_TRIAL_WARM as usize);
        let mut trial = ThreadsTrial::default();
        // Two threads faster in most steps, but their first eight timed steps very long: the
        // sum would keep one thread, the median keeps two.
        let threads = period(
            &mut trial,
            |_| 220e-6,
            |i| if i < 8 { 2e-3 } else { 160e-6 },
        );
        for (k, &t) in threads.iter().enumerate().take(4 * block) {
            assert_eq!(t, (block..3 * block).contains(&k), "step {k}");
        }
        let per_side = 2 * (block - warm);
        assert_eq!(trial.timed, [per_side, per_side]);
        assert_eq!(per_side, TIMED_PER_SIDE);
        assert!(threads[4 * block..].iter().all(|&t| t), "two threads kept");
        // The next period starts a new trial (its first block on one thread).
        let threads = period(&mut trial, |_| 200e-6, |_| 200e-6);
        assert!(!threads[0] && threads[block]);
        assert!(
            threads[4 * block..].iter().all(|&t| t),
            "a tie goes to two threads"
        );
        let threads = period(&mut trial, |_| 165e-6, |i| 190e-6 + 1e-9 * i as f64);
        assert!(
            threads[4 * block..].iter().all(|&t| !t),
            "slower two threads: one kept"
        );
    }
}
