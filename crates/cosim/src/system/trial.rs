//! The look-ahead thread's timed trial: whether a run is faster with it or without it, measured
//! now and then while it runs ([`super::SchedulerParams::lookahead_trial_every`]).
//!
//! Why: the look-ahead thread runs components beside the master's on the machine's second
//! core. That pays while the components on the master's thread leave the core free, and costs
//! when they use it themselves: the TMT mirror with 1000 retained modes splits its products
//! with a helper thread of its own, and the look-ahead thread's steps (the edge sensors, the
//! optics) then share that core with the mirror's helper, which slowed the step loop by about a
//! tenth on the project's 2-core VM (BENCHMARKS.md, twenty-fourth round). The master cannot
//! know what a component does inside its steps, so it measures.
//!
//! How: a trial is up to four blocks, with, without, without and with the look-ahead thread (so
//! that a drift of the machine's speed falls on both sides alike), each
//! [`super::SchedulerParams::lookahead_trial_block`] base steps timed after a tenth as many
//! that are not (the caches settle; the switch, which waits for the steps in flight, is not
//! timed). The timed steps of a block are a whole number of periods of every component whose
//! period divides them (by default 100 base steps: the standard systems' 10 Hz PSSN once per
//! block, on whichever thread it runs). The thread is kept unless the mean time per base step
//! without it is shorter. A trial ends after its first block if the thread took no step in it
//! (nothing to compare), and after its second if the two sides differ by more than a quarter:
//! a block on the slower side costs the run its difference. Values are the same either way
//! (the look-ahead changes no value).

use std::time::Instant;

/// What a trial measured and chose ([`super::Simulation::lookahead_trials`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LookaheadTrial {
    /// The base step at which the trial began.
    pub step: u64,
    /// Mean wall time per base step with the look-ahead thread (s).
    pub with_seconds: f64,
    /// Mean wall time per base step without it (s).
    pub without_seconds: f64,
    /// Whether the look-ahead thread was kept for the run until the next trial.
    pub kept: bool,
}

/// The side of each of a trial's blocks: with the look-ahead thread (`true`) or without.
const SIDES: [bool; 4] = [true, false, false, true];

/// After the first two blocks, a difference of more than this (relative to the faster side)
/// decides the trial at once: the last two blocks, which balance a drift of the machine's
/// speed, matter only in close calls, and each block on the slower side costs its difference.
const CLEAR: f64 = 0.25;

/// A trial's state across the base steps (`Simulation::step` asks it before and after each).
#[derive(Debug, Clone)]
pub(super) struct Trials {
    every: u64,
    warm: u64,
    /// Steps of a block: `warm` not timed, then the timed ones.
    block: u64,
    /// The base step at which the next (or current) trial begins.
    next: u64,
    /// Timed seconds and base steps per side (without, with).
    sums: [(f64, u64); 2],
    /// The clock the blocks are timed by ([`Self::now`]), and the time the current block's
    /// timed steps began.
    origin: Instant,
    started: Option<f64>,
    /// The look-ahead's steps when the first block began.
    used_from: u64,
    pub(super) outcomes: Vec<LookaheadTrial>,
}

impl Trials {
    /// Trials every `every` base steps, each block `timed` base steps timed after a tenth as
    /// many not timed (none if `every` is 0, `timed` is below 10, or a trial would not fit
    /// between two).
    pub(super) fn new(every: u64, timed: u64) -> Option<Self> {
        let warm = timed / 10;
        let block = warm + timed;
        (every > 0 && timed >= 10 && every >= 4 * block).then(|| Self {
            every,
            warm,
            block,
            // After a block's length of running as configured: the components' running means,
            // which decide what goes to the thread, are measured by then.
            next: block,
            sums: [(0.0, 0); 2],
            origin: Instant::now(),
            started: None,
            used_from: 0,
            outcomes: Vec::new(),
        })
    }

    /// Seconds since the trials were set up: the time [`Self::before`] and [`Self::after`]
    /// are given.
    pub(super) fn now(&self) -> f64 {
        self.origin.elapsed().as_secs_f64()
    }

    /// Whether base step `k` is in a trial (the only steps [`Self::before`] and [`Self::after`]
    /// need to be asked about).
    pub(super) fn active(&self, k: u64) -> bool {
        self.at(k).is_some()
    }

    /// Where base step `k` falls in the current trial: (block, step in the block).
    fn at(&self, k: u64) -> Option<(usize, u64)> {
        let pos = k.checked_sub(self.next)?;
        let b = pos / self.block;
        (b < 4).then(|| (b as usize, pos % self.block))
    }

    /// Before base step `k`, at time `now` (s), with the look-ahead's steps so far: the side to
    /// switch to when a block begins.
    pub(super) fn before(&mut self, k: u64, now: f64, lookahead_steps: u64) -> Option<bool> {
        let (b, p) = self.at(k)?;
        if p == self.warm {
            self.started = Some(now);
        }
        if p == 0 && b == 0 {
            self.used_from = lookahead_steps;
        }
        (p == 0 && (b == 0 || SIDES[b] != SIDES[b - 1])).then_some(SIDES[b])
    }

    /// After base step `k`, at time `now` (s), with the look-ahead's steps so far: at the
    /// trial's end, the side to keep until the next.
    pub(super) fn after(&mut self, k: u64, now: f64, lookahead_steps: u64) -> Option<bool> {
        let (b, p) = self.at(k)?;
        if p + 1 != self.block {
            return None;
        }
        if let Some(t0) = self.started.take() {
            let side = &mut self.sums[usize::from(SIDES[b])];
            side.0 += now - t0;
            side.1 += self.block - self.warm;
        }
        let [without, with] = self.sums.map(|(s, n)| s / n.max(1) as f64);
        // Nothing went to the thread in the first block: nothing to compare, it stays.
        let idle = b == 0 && lookahead_steps == self.used_from;
        let clear = b == 1 && (without - with).abs() > CLEAR * without.min(with);
        if !(idle || clear || b == 3) {
            return None;
        }
        let kept = idle || without >= with;
        self.outcomes.push(LookaheadTrial {
            step: self.next,
            with_seconds: with,
            without_seconds: if idle { f64::NAN } else { without },
            kept,
        });
        self.sums = [(0.0, 0); 2];
        self.next += self.every;
        Some(kept)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Base steps and the side asked or chosen there.
    type Events = Vec<(u64, bool)>;

    /// Feeds base steps `ks` to `t` on a clock of its own, each given `used(k)` look-ahead
    /// steps so far and taking `secs(on)` seconds; returns the switches asked and the
    /// decisions made.
    fn drive(
        t: &mut Trials,
        ks: std::ops::Range<u64>,
        used: impl Fn(u64) -> u64,
        secs: impl Fn(bool) -> f64,
    ) -> (Events, Events) {
        let (mut on, mut now, mut switches, mut decided) = (true, 0.0, Vec::new(), Vec::new());
        for k in ks {
            if let Some(s) = t.before(k, now, used(k)) {
                switches.push((k, s));
                on = s;
            }
            now += secs(on);
            if let Some(kept) = t.after(k, now, used(k)) {
                decided.push((k, kept));
                on = kept;
            }
        }
        (switches, decided)
    }

    /// The blocks fall where the documentation says, and a trial decides after its first block
    /// when the thread took no step, after its second when the sides differ clearly, after its
    /// fourth in a close call (ties keep the thread), each by the timings it was given.
    #[test]
    fn a_trial_switches_at_its_blocks_and_decides_when_it_can() {
        assert!(Trials::new(0, 10).is_none() && Trials::new(40, 10).is_none());
        assert!(Trials::new(100, 9).is_none());
        // Blocks of 11 base steps (1 not timed), the first trial from base step 11.
        let new = || Trials::new(100, 10).expect("trials");
        // Step times that the clock adds up exactly (powers of two and their multiples).
        let base = 2f64.powi(-13);
        // The thread twice as fast: decided after the second block, kept.
        let mut t = new();
        let (sw, dec) = drive(
            &mut t,
            0..60,
            |k| k,
            |on| if on { base } else { 2.0 * base },
        );
        assert_eq!(sw, vec![(11, true), (22, false)]);
        assert_eq!(dec, vec![(32, true)]);
        let o = t.outcomes[0];
        assert_eq!((o.with_seconds, o.without_seconds), (base, 2.0 * base));
        // Twice as fast without it: dropped after the second block, until the next trial.
        let mut t = new();
        let (sw, dec) = drive(
            &mut t,
            0..140,
            |k| k,
            |on| if on { 2.0 * base } else { base },
        );
        assert_eq!(sw, vec![(11, true), (22, false), (111, true), (122, false)]);
        assert_eq!(dec, vec![(32, false), (132, false)]);
        // A close call (equal sides): all four blocks, ties keep the thread.
        let mut t = new();
        let (sw, dec) = drive(&mut t, 0..60, |k| k, |_| base);
        assert_eq!(sw, vec![(11, true), (22, false), (44, true)]);
        assert_eq!(dec, vec![(54, true)]);
        // A close call the thread loses (an eighth slower with it): dropped after four blocks.
        let mut t = new();
        let (_, dec) = drive(
            &mut t,
            0..60,
            |k| k,
            |on| if on { 1.125 * base } else { base },
        );
        assert_eq!(dec, vec![(54, false)]);
        let o = t.outcomes[0];
        assert_eq!(
            (o.step, o.with_seconds, o.without_seconds),
            (11, 1.125 * base, base)
        );
        // Nothing went to the thread in the first block: kept at once, no switch off.
        let mut t = new();
        let (sw, dec) = drive(&mut t, 0..60, |_| 7, |_| base);
        assert_eq!((sw, dec), (vec![(11, true)], vec![(21, true)]));
        assert!(t.outcomes[0].without_seconds.is_nan());
    }
}
