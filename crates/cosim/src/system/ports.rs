//! The values that move between components: one shared buffer per kind of value ([`Values`]:
//! Real, Integer (and enumeration), Boolean, String), and per component and kind a [`Port`]
//! that gathers its connected inputs out of the buffer and publishes its outputs into it, with
//! one bulk FMI call per kind and step and no allocation (Strings excepted: they are copied).
//! Real inputs connected as a few arrays are set straight from the buffer instead, one call
//! per array, when the component steps on the master's thread ([`Port::direct`]): the copy
//! into the port is the larger cost there (a TMT mirror's 2953 inputs).

use super::wiring::Kind;
use crate::error::Result;
use crate::instance::Instance;

/// The latest published outputs of every component, one buffer per kind, each laid out
/// component after component (`wiring.rs`).
#[derive(Debug, Clone, Default)]
pub(super) struct Values {
    pub(super) real: Vec<f64>,
    pub(super) integer: Vec<i32>,
    pub(super) boolean: Vec<bool>,
    pub(super) string: Vec<String>,
}

impl Values {
    /// Buffers of the given lengths (per [`Kind`]), zeroed.
    pub(super) fn zeroed(len: [usize; 4]) -> Self {
        Self {
            real: vec![0.0; len[Kind::Real as usize]],
            integer: vec![0; len[Kind::Integer as usize]],
            boolean: vec![false; len[Kind::Boolean as usize]],
            string: vec![String::new(); len[Kind::String as usize]],
        }
    }

    /// Sets slot `slot` of kind `kind` from a number ([`Self::number`]'s inverse; a String
    /// is left as it is).
    pub(super) fn set_number(&mut self, kind: Kind, slot: usize, v: f64) {
        match kind {
            Kind::Real => self.real[slot] = v,
            Kind::Integer => self.integer[slot] = v as i32,
            Kind::Boolean => self.boolean[slot] = v != 0.0,
            Kind::String => {}
        }
    }

    /// The value in slot `slot` of kind `kind` as a number (a Boolean as 0 or 1; a String has
    /// none: NaN).
    pub(super) fn number(&self, kind: Kind, slot: usize) -> f64 {
        number(&self.real, &self.integer, &self.boolean, kind, slot)
    }
}

/// Slot `slot` of kind `kind` among these buffers as a number: a Boolean as 0 or 1; a String
/// has none (NaN).
fn number(real: &[f64], integer: &[i32], boolean: &[bool], kind: Kind, slot: usize) -> f64 {
    match kind {
        Kind::Real => real[slot],
        Kind::Integer => f64::from(integer[slot]),
        Kind::Boolean => f64::from(u8::from(boolean[slot])),
        Kind::String => f64::NAN,
    }
}

/// The outputs a step reads: their values, and per component how many times its visible
/// outputs have changed (`Simulation::seen`). A run of Real inputs set straight from the
/// buffer whose source has not changed since it was last set is not set again
/// ([`Ports::set_inputs_from`]): inputs keep their values until set (FMI 2.0). Without the
/// counts (`System::set_unchanged_inputs`) every run is set.
#[derive(Debug, Clone, Copy)]
pub(super) struct Visible<'a> {
    pub(super) values: &'a Values,
    pub(super) seen: Option<&'a [u64]>,
}

impl<'a> Visible<'a> {
    /// `values` with the change counts `seen`, unless every input is to be set at every step
    /// (`set_unchanged`).
    pub(super) fn new(values: &'a Values, seen: &'a [u64], set_unchanged: bool) -> Self {
        Self {
            values,
            seen: (!set_unchanged).then_some(seen),
        }
    }
}

/// Most runs of consecutive input slots for which a port's Real inputs are set straight from
/// the shared buffer, a set call per run ([`Port::direct`]): a mirror's command, wind and pier
/// inputs are three runs, a scalar-wired component's inputs may be hundreds (there one copy
/// and one call is cheaper).
pub(super) const DIRECT_MAX_RUNS: usize = 8;

/// The values of one kind that a component exchanges: its connected inputs and where each
/// comes from in the shared buffer, and its outputs (connected or recorded) and where they go.
#[derive(Debug, Default)]
pub(super) struct Port<T> {
    /// Value references of its connected inputs and their values gathered for the next step.
    pub(super) in_vrs: Vec<u32>,
    pub(super) in_buf: Vec<T>,
    /// Where the inputs come from in the shared buffer, as runs of consecutive slots `(first
    /// source slot, first input, length)`: an array input connected to an array output is one
    /// copy instead of one per scalar.
    in_runs: Vec<(usize, usize, usize)>,
    /// Per run, the component whose outputs it reads (None: it spans two), and that
    /// component's change count when the run was last set straight from the shared buffer
    /// (`u64::MAX`: not yet).
    in_from: Vec<Option<usize>>,
    in_seen: Vec<u64>,
    /// Value references of its outputs, the first of their consecutive slots, and their latest
    /// values (published after its step, when they are due).
    pub(super) out_vrs: Vec<u32>,
    pub(super) out_slot: usize,
    pub(super) out_buf: Vec<T>,
}

impl<T: Clone + Default> Port<T> {
    /// A port for inputs `(value reference, global slot of the source)` and outputs `out_vrs`
    /// published from global slot `out_slot` on.
    pub(super) fn new(inputs: Vec<(u32, usize)>, out_vrs: Vec<u32>, out_slot: usize) -> Self {
        let (in_vrs, in_src): (Vec<u32>, Vec<usize>) = inputs.into_iter().unzip();
        let mut in_runs: Vec<(usize, usize, usize)> = Vec::new();
        for (k, &src) in in_src.iter().enumerate() {
            match in_runs.last_mut() {
                Some((s, d, n)) if *s + *n == src && *d + *n == k => *n += 1,
                _ => in_runs.push((src, k, 1)),
            }
        }
        Self {
            in_from: vec![None; in_runs.len()],
            in_seen: vec![u64::MAX; in_runs.len()],
            in_runs,
            in_buf: vec![T::default(); in_vrs.len()],
            in_vrs,
            out_buf: vec![T::default(); out_vrs.len()],
            out_vrs,
            out_slot,
        }
    }

    /// Copies its inputs out of the shared buffer `shared`.
    pub(super) fn gather(&mut self, shared: &[T]) {
        for &(src, dst, n) in &self.in_runs {
            self.in_buf[dst..dst + n].clone_from_slice(&shared[src..src + n]);
        }
    }

    /// Whether its inputs are set straight from the shared buffer, one set call per run of
    /// consecutive slots, instead of gathered into `in_buf` and set in one call: when they form
    /// at most [`DIRECT_MAX_RUNS`] runs (array connections), so that the copy saved is larger
    /// than the calls added.
    pub(super) fn direct(&self) -> bool {
        !self.in_runs.is_empty() && self.in_runs.len() <= DIRECT_MAX_RUNS
    }

    /// Notes the component each run of inputs reads: component `c`'s outputs are slots
    /// `offsets[c]..offsets[c + 1]` (`Wiring::offsets`).
    pub(super) fn set_sources(&mut self, offsets: &[usize]) {
        for (from, &(src, _, n)) in self.in_from.iter_mut().zip(&self.in_runs) {
            let c = owner(offsets, src);
            *from = (src + n <= offsets[c + 1]).then_some(c);
        }
    }

    /// Where its inputs come from: runs of `(first source slot, first input, length)`.
    pub(super) fn in_runs(&self) -> &[(usize, usize, usize)] {
        &self.in_runs
    }

    /// Copies its outputs into the shared buffer `shared`.
    pub(super) fn publish(&self, shared: &mut [T]) {
        let dst = &mut shared[self.out_slot..self.out_slot + self.out_buf.len()];
        dst.clone_from_slice(&self.out_buf);
    }
}

/// A component's ports, one per kind.
#[derive(Debug, Default)]
pub(super) struct Ports {
    pub(super) real: Port<f64>,
    pub(super) integer: Port<i32>,
    pub(super) boolean: Port<bool>,
    pub(super) string: Port<String>,
}

impl Ports {
    /// Gathers its Integer, Boolean and String inputs out of `shared` (for a step on another
    /// thread: the Real ones come through [`gather_real_for_other_core`]).
    pub(super) fn gather_other_kinds(&mut self, shared: &Values) {
        self.integer.gather(&shared.integer);
        self.boolean.gather(&shared.boolean);
        self.string.gather(&shared.string);
    }

    /// Whether it has inputs of a kind other than Real.
    pub(super) fn has_other_inputs(&self) -> bool {
        !(self.integer.in_vrs.is_empty()
            && self.boolean.in_vrs.is_empty()
            && self.string.in_vrs.is_empty())
    }

    /// Publishes every kind's outputs into `shared`.
    pub(super) fn publish(&self, shared: &mut Values) {
        self.real.publish(&mut shared.real);
        self.integer.publish(&mut shared.integer);
        self.boolean.publish(&mut shared.boolean);
        self.string.publish(&mut shared.string);
    }

    /// Its latest output in slot `slot` (among its outputs) of kind `kind`, as a number (as
    /// [`Values::number`]).
    pub(super) fn number(&self, kind: Kind, slot: usize) -> f64 {
        let (r, i, b) = (&self.real, &self.integer, &self.boolean);
        number(&r.out_buf, &i.out_buf, &b.out_buf, kind, slot)
    }

    /// Sets the gathered inputs on `inst`: one call per kind that has any.
    pub(super) fn set_inputs(&self, inst: &mut Instance) -> Result<()> {
        if !self.real.in_vrs.is_empty() {
            inst.set_real(&self.real.in_vrs, &self.real.in_buf)?;
        }
        self.set_other_inputs(inst)
    }

    /// Sets its inputs on `inst` from `shared` (every kind's connected inputs): the Real ones
    /// straight from the shared buffer, one call per run of consecutive slots, when the port
    /// allows it ([`Port::direct`]); otherwise (and for the other kinds) gathered first and set
    /// with one call per kind. The FMU receives the same values either way, Real first.
    pub(super) fn set_inputs_from(&mut self, shared: Visible, inst: &mut Instance) -> Result<()> {
        let (seen, shared) = (shared.seen, shared.values);
        let real = &mut self.real;
        if real.direct() {
            for (k, &(src, dst, n)) in real.in_runs.iter().enumerate() {
                // Unchanged since it was set: the FMU holds these values (a wind force
                // changing every tenth step, a controller's command every fiftieth).
                let now = real.in_from[k]
                    .zip(seen)
                    .map_or(u64::MAX, |(c, seen)| seen[c]);
                if now != u64::MAX && now == real.in_seen[k] {
                    continue;
                }
                inst.set_real(&real.in_vrs[dst..dst + n], &shared.real[src..src + n])?;
                real.in_seen[k] = now;
            }
        } else if !real.in_vrs.is_empty() {
            real.gather(&shared.real);
            inst.set_real(&real.in_vrs, &real.in_buf)?;
        }
        self.integer.gather(&shared.integer);
        self.boolean.gather(&shared.boolean);
        self.string.gather(&shared.string);
        self.set_other_inputs(inst)
    }

    /// Sets the gathered Integer, Boolean and String inputs: one call per kind that has any.
    fn set_other_inputs(&self, inst: &mut Instance) -> Result<()> {
        if !self.integer.in_vrs.is_empty() {
            inst.set_integer(&self.integer.in_vrs, &self.integer.in_buf)?;
        }
        if !self.boolean.in_vrs.is_empty() {
            inst.set_boolean(&self.boolean.in_vrs, &self.boolean.in_buf)?;
        }
        if !self.string.in_vrs.is_empty() {
            let values: Vec<&str> = self.string.in_buf.iter().map(String::as_str).collect();
            inst.set_string(&self.string.in_vrs, &values)?;
        }
        Ok(())
    }

    /// Reads its outputs from `inst` into the output buffers: one call per kind that has any.
    pub(super) fn get_outputs(&mut self, inst: &mut Instance) -> Result<()> {
        if !self.real.out_vrs.is_empty() {
            inst.get_real(&self.real.out_vrs, &mut self.real.out_buf)?;
        }
        if !self.integer.out_vrs.is_empty() {
            inst.get_integer(&self.integer.out_vrs, &mut self.integer.out_buf)?;
        }
        if !self.boolean.out_vrs.is_empty() {
            inst.get_boolean(&self.boolean.out_vrs, &mut self.boolean.out_buf)?;
        }
        if !self.string.out_vrs.is_empty() {
            self.string.out_buf = inst.get_string(&self.string.out_vrs)?;
        }
        Ok(())
    }
}

/// A run of consecutive Real inputs that come from one component's consecutive outputs: the
/// first source slot in the shared buffer, the source component and the first of its outputs,
/// the first input, the length. A port's runs ([`Port::in_runs`]) cut where one component's
/// outputs end and the next one's begin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct SourcedRun {
    pub(super) slot: usize,
    pub(super) comp: usize,
    pub(super) at: usize,
    pub(super) dst: usize,
    pub(super) n: usize,
}

/// The component whose outputs hold slot `slot`: the last whose region (`offsets[c]..offsets[c +
/// 1]`) starts at or before it (an empty region shares its start with the next one).
fn owner(offsets: &[usize], slot: usize) -> usize {
    offsets.partition_point(|&o| o <= slot) - 1
}

/// `runs` (`(first source slot, first input, length)`) cut at the components' output regions:
/// component `c`'s outputs are slots `offsets[c]..offsets[c + 1]` (`Wiring::offsets`).
pub(super) fn sourced_runs(runs: &[(usize, usize, usize)], offsets: &[usize]) -> Vec<SourcedRun> {
    let mut out = Vec::with_capacity(runs.len());
    for &(mut slot, mut dst, mut n) in runs {
        while n > 0 {
            let comp = owner(offsets, slot);
            let len = n.min(offsets[comp + 1] - slot);
            out.push(SourcedRun {
                slot,
                comp,
                at: slot - offsets[comp],
                dst,
                n: len,
            });
            slot += len;
            dst += len;
            n -= len;
        }
    }
    out
}

/// Copies Real inputs into `dst` for a step on another thread, the way `way` says
/// ([`copy_for_other_core`]): each run from `from(run)`, which gives the source's values (its
/// ports' latest outputs while they are not yet published, the shared buffer otherwise).
/// Returns how many values it copied.
pub(super) fn gather_real_for_other_core<'a>(
    dst: &mut [f64],
    runs: &[SourcedRun],
    way: CopyWay,
    mut from: impl FnMut(&SourcedRun) -> &'a [f64],
) -> usize {
    let mut n = 0;
    for r in runs {
        copy_for_other_core(&mut dst[r.dst..r.dst + r.n], from(r), way);
        n += r.n;
    }
    n
}

/// How the master copies a step's inputs into a buffer that the look-ahead thread's core read
/// last ([`copy_for_other_core`]). Which is cheaper for the master depends on the machine, so
/// the master measures both now and then (a trial of a few dozen copies every 4096, the
/// cheaper by its median kept until the next).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CopyWay {
    /// A plain copy: the stores first take the buffer's cache lines back from the other core.
    Plain,
    /// On x86-64, non-temporal stores: the lines go to memory without being taken back (the
    /// other core then reads them from memory, off the master's path), and a fence before the
    /// hand-over waits for them to leave. Elsewhere a plain copy.
    PastCache,
}

/// Copies `src` into `dst` (of the same length) for another core to read, the way `way` says.
///
/// Measured (the master's hand-over of the TMT mirror's 1476 displacements for the edge
/// sensors' step, a buffer the look-ahead thread read a step earlier): on the AMD EPYC VM of
/// the earlier rounds of issue 18 a plain copy took about 4 us, nearly all of it waiting for
/// those lines, and the non-temporal one about 0.3 us; on the Intel VM of its twentieth round,
/// its stores drained, the plain copy took 0.46-0.77 ns per value (0.7-1.1 us) and the
/// non-temporal one 0.85-0.88 ns (1.25-1.3 us) in the master's trials, and 1.15 and 1.16 us
/// in the floors bench (`benches/floors.rs`, `cross_core_copy`; BENCHMARKS.md).
///
/// # Panics
/// If the lengths differ.
pub fn copy_for_other_core(dst: &mut [f64], src: &[f64], way: CopyWay) {
    assert_eq!(dst.len(), src.len(), "copy_for_other_core: lengths differ");
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_loadu_pd, _mm_sfence, _mm_stream_pd};
        // A short run is not worth the fence.
        if way == CopyWay::PastCache && dst.len() >= 32 {
            // Whole 16-byte pairs from the first aligned element.
            let head = dst.as_ptr().align_offset(16).min(dst.len());
            let pairs = (dst.len() - head) / 2;
            let tail = head + 2 * pairs;
            dst[..head].copy_from_slice(&src[..head]);
            dst[tail..].copy_from_slice(&src[tail..]);
            let (d, s) = (dst[head..tail].as_mut_ptr(), src[head..tail].as_ptr());
            for k in 0..pairs {
                // SAFETY: SSE2 is part of x86-64; `d + 2k` and `s + 2k` are within the
                // `head..tail` ranges of both slices (2 * pairs values), and `d` is 16-byte
                // aligned (`align_offset`), as `_mm_stream_pd` requires.
                unsafe { _mm_stream_pd(d.add(2 * k), _mm_loadu_pd(s.add(2 * k))) };
            }
            // Non-temporal stores are not ordered with the later ones that hand the values
            // over (the channel's release): fence them.
            // SAFETY: SSE is part of x86-64.
            unsafe { _mm_sfence() };
            return;
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = way;
    dst.copy_from_slice(src);
}

/// Hand-over copies from one trial of [`CopyTrial`] to the next.
pub(super) const COPY_CHECK_EVERY: u32 = 4096;

/// Hand-over copies in a block of a trial (two blocks a side: plain, past the cache, past the
/// cache, plain, so that a drift of the machine's load falls on both alike).
pub(super) const COPY_TRIAL_BLOCK: u32 = 16;

/// The first copies of each block, not timed (the caches settle into the block's way).
pub(super) const COPY_TRIAL_WARM: u32 = 4;

const COPY_TIMED_PER_SIDE: usize = 2 * (COPY_TRIAL_BLOCK - COPY_TRIAL_WARM) as usize;

const _: () =
    assert!(COPY_TRIAL_WARM < COPY_TRIAL_BLOCK && COPY_CHECK_EVERY > 4 * COPY_TRIAL_BLOCK);

/// The master's choice of [`CopyWay`] for its hand-over copies, by measurement: every
/// [`COPY_CHECK_EVERY`] copies it times four blocks of [`COPY_TRIAL_BLOCK`] (plain, past the
/// cache, past the cache, plain; the first [`COPY_TRIAL_WARM`] of each not timed), compares
/// the medians of each side's time per value, and keeps the cheaper until the next trial (a
/// tie keeps the copy past the cache). Both ways copy the same values: the choice changes no
/// result, only the master's time.
#[derive(Debug, Clone)]
pub(super) struct CopyTrial {
    /// The way kept between trials.
    way: CopyWay,
    /// Copies since the last trial began.
    n: u32,
    /// The trial's timed copies, nanoseconds per value (room for all made at the start).
    plain: Vec<f32>,
    past: Vec<f32>,
}

impl Default for CopyTrial {
    fn default() -> Self {
        Self {
            way: CopyWay::PastCache,
            n: 0,
            plain: Vec::with_capacity(COPY_TIMED_PER_SIDE),
            past: Vec::with_capacity(COPY_TIMED_PER_SIDE),
        }
    }
}

impl CopyTrial {
    /// The way for the next copy, and whether to time it.
    pub(super) fn next(&self) -> (CopyWay, bool) {
        if self.n >= 4 * COPY_TRIAL_BLOCK {
            return (self.way, false);
        }
        let way = match self.n / COPY_TRIAL_BLOCK {
            0 | 3 => CopyWay::Plain,
            _ => CopyWay::PastCache,
        };
        (way, self.n % COPY_TRIAL_BLOCK >= COPY_TRIAL_WARM)
    }

    /// Notes the copy [`Self::next`] asked for: its time per value if it was timed (ns).
    pub(super) fn done(&mut self, way: CopyWay, timed: Option<f32>) {
        if let Some(t) = timed {
            let side = match way {
                CopyWay::Plain => &mut self.plain,
                CopyWay::PastCache => &mut self.past,
            };
            side.push(t);
        }
        self.n += 1;
        if self.n == 4 * COPY_TRIAL_BLOCK {
            if let (Some(p), Some(q)) = (median(&mut self.plain), median(&mut self.past)) {
                self.way = if p < q {
                    CopyWay::Plain
                } else {
                    CopyWay::PastCache
                };
            }
            self.plain.clear();
            self.past.clear();
        } else if self.n >= COPY_CHECK_EVERY {
            self.n = 0;
        }
    }

    /// The way kept between trials.
    pub(super) fn way(&self) -> CopyWay {
        self.way
    }

    /// Copies with `copy` (which returns how many values it copied) the way the trial says,
    /// timed if it says so. A timed copy ends with a full fence, so that its time includes
    /// the stores still on their way to the other core's lines (a plain copy's stores leave
    /// the core after the loop; what follows would otherwise pay for them).
    pub(super) fn copy(&mut self, copy: impl FnOnce(CopyWay) -> usize) {
        let (way, timed) = self.next();
        let t = if timed {
            let t0 = std::time::Instant::now();
            let n = copy(way);
            std::sync::atomic::fence(std::sync::atomic::Ordering::SeqCst);
            Some(t0.elapsed().as_nanos() as f32 / n.max(1) as f32)
        } else {
            copy(way);
            None
        };
        self.done(way, t);
    }
}

/// The median of `x` (sorted in place; the upper of the two middle values), None if empty.
fn median(x: &mut [f32]) -> Option<f32> {
    x.sort_unstable_by(f32::total_cmp);
    x.get(x.len() / 2).copied()
}

#[cfg(test)]
mod tests {
    use super::{
        COPY_CHECK_EVERY, COPY_TRIAL_BLOCK, COPY_TRIAL_WARM, CopyTrial, CopyWay, SourcedRun,
        copy_for_other_core, sourced_runs,
    };

    /// Runs are cut where a component's outputs end, empty regions are skipped, and every
    /// input keeps its source slot.
    #[test]
    fn runs_are_cut_at_the_components_outputs() {
        // Components: 0 has slots 0..3, 1 none, 2 has 3..7, 3 has 7..8.
        let offsets = [0, 3, 3, 7, 8];
        let runs = [(1, 0, 5), (7, 5, 1), (0, 6, 1)];
        let cut = sourced_runs(&runs, &offsets);
        let run = |slot, comp, at, dst, n| SourcedRun {
            slot,
            comp,
            at,
            dst,
            n,
        };
        assert_eq!(
            cut,
            [
                run(1, 0, 1, 0, 2),
                run(3, 2, 0, 2, 3),
                run(7, 3, 0, 5, 1),
                run(0, 0, 0, 6, 1),
            ]
        );
    }

    /// Every length (below and above the streaming threshold, odd and even) at both alignments
    /// of source and destination is copied exactly either way, with nothing written outside.
    #[test]
    fn copies_for_the_other_core_exactly() {
        let src: Vec<f64> = (0..300)
            .map(|k| (k as f64).sin() * 1e-7 + k as f64)
            .collect();
        let cases = [0usize, 1, 2, 31, 32, 33, 64, 99, 257]
            .into_iter()
            .flat_map(|n| [CopyWay::Plain, CopyWay::PastCache].map(|w| (n, w)));
        for (n, way) in cases {
            for (so, d_off) in (0..2).flat_map(|so| (0..9).map(move |d| (so, d))) {
                let mut dst = vec![f64::NAN; n + 11];
                copy_for_other_core(&mut dst[d_off..d_off + n], &src[so..so + n], way);
                assert!(dst[..d_off].iter().all(|x| x.is_nan()), "{n} {so} {d_off}");
                assert!(
                    dst[d_off + n..].iter().all(|x| x.is_nan()),
                    "{n} {so} {d_off}"
                );
                let same = dst[d_off..d_off + n]
                    .iter()
                    .zip(&src[so..so + n])
                    .all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{n} {so} {d_off}");
            }
        }
    }

    /// The trial runs its four blocks (plain, past the cache twice, plain), times all but each
    /// block's first copies, keeps the way whose median is lower (a tie keeps the copy past
    /// the cache) until the next trial, and starts again after [`COPY_CHECK_EVERY`] copies.
    /// The medians, not the sums, decide: a few long copies on one side do not.
    #[test]
    fn the_copy_trial_runs_in_blocks_and_keeps_the_cheaper_by_medians() {
        // `cost(way, k)`: the time per value the k-th copy of a trial takes that way.
        let trial = |t: &mut CopyTrial, cost: &dyn Fn(CopyWay, u32) -> f32| {
            let mut ways = Vec::new();
            for k in 0..4 * COPY_TRIAL_BLOCK {
                let (way, timed) = t.next();
                assert_eq!(timed, k % COPY_TRIAL_BLOCK >= COPY_TRIAL_WARM, "copy {k}");
                ways.push(way);
                t.done(way, timed.then(|| cost(way, k)));
            }
            let b = COPY_TRIAL_BLOCK as usize;
            let blocks: Vec<CopyWay> = ways.chunks(b).map(|c| c[0]).collect();
            assert!(ways.chunks(b).all(|c| c.iter().all(|&w| w == c[0])));
            assert_eq!(
                blocks,
                [
                    CopyWay::Plain,
                    CopyWay::PastCache,
                    CopyWay::PastCache,
                    CopyWay::Plain
                ]
            );
        };
        let mut t = CopyTrial::default();
        assert_eq!(t.way(), CopyWay::PastCache);
        // Plain cheaper by its median, though three of its copies are very long (their sum is
        // the larger).
        trial(&mut t, &|w, k| match w {
            CopyWay::Plain if k % 7 == 5 => 100.0,
            CopyWay::Plain => 0.3,
            CopyWay::PastCache => 0.6,
        });
        assert_eq!(t.way(), CopyWay::Plain);
        // Kept until the next trial.
        for _ in 4 * COPY_TRIAL_BLOCK..COPY_CHECK_EVERY {
            assert_eq!(t.next(), (CopyWay::Plain, false));
            t.done(CopyWay::Plain, None);
        }
        // A tie keeps the copy past the cache.
        trial(&mut t, &|_, _| 0.5);
        assert_eq!(t.way(), CopyWay::PastCache);
        for _ in 4 * COPY_TRIAL_BLOCK..COPY_CHECK_EVERY {
            t.done(t.next().0, None);
        }
        trial(&mut t, &|w, _| if w == CopyWay::Plain { 0.2 } else { 0.25 });
        assert_eq!(t.way(), CopyWay::Plain);
        // `copy` copies the way it is told, once per call.
        let mut t = CopyTrial::default();
        let mut seen = Vec::new();
        for _ in 0..4 * COPY_TRIAL_BLOCK {
            t.copy(|w| {
                seen.push(w);
                1476
            });
        }
        assert_eq!(seen.len(), 4 * COPY_TRIAL_BLOCK as usize);
        assert_eq!(seen[0], CopyWay::Plain);
        assert_eq!(seen[COPY_TRIAL_BLOCK as usize], CopyWay::PastCache);
    }
}
