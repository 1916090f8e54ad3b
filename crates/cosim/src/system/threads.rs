//! The scheduler's thread policy: which components' steps go to other threads, and how. The
//! step semantics (`step.rs`) fix what every component receives; this file only decides where
//! its FMU calls run, from the running mean of each component's step time and the thresholds
//! of [`SchedulerParams`], so that no choice made here changes a value.
//!
//! - Jacobi: the due components by recursive halving on rayon's pool ([`advance_split`]), the
//!   heaviest alone beside the others stepping in turn on a worker, or all in turn on the
//!   calling thread ([`plan_jacobi`], [`advance_jacobi`]).
//! - Gauss-Seidel: components' steps on the look-ahead thread ([`Lookahead`]), when they take
//!   long enough per step ([`SchedulerParams::worth_lookahead`]).
//! - Both orders: sinks kept on the look-ahead thread, their steps queued there ([`Work`]).
//!
//! At most [`LOOKAHEAD_SLOTS`] messages are in flight to the look-ahead thread; they run there
//! in the order sent.

use super::ports::Visible;
use super::queue::{Receiver, Sender, queue};
use super::step::Running;
use super::wiring::Kind;
use crate::error::{CosimError, Result};

/// The master's scheduling thresholds: the wall-time heuristics that decide when a step goes
/// to another thread. They change the wall time of a run only; every component receives the
/// same values whatever they are (tested). [`Default`] holds the values measured on the
/// project's 2-core machine; a [`super::System`] carries its own ([`super::System::scheduler`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SchedulerParams {
    /// Mean time per step (s) above which a component counts as heavy enough to run on its own
    /// thread in Jacobi order (measured: waking a rayon worker every step costs 50-150 us on
    /// the 2-core machine); a component not yet measured (its first step) never counts. Default
    /// 2e-4.
    pub parallel_min_seconds: f64,
    /// Jacobi with a single heavy component: the others (at least this much work per step, s)
    /// step on a worker while it steps, if it takes at least
    /// [`Self::wake_seconds`] longer than they do. Default 5e-5.
    pub split_min_seconds: f64,
    /// The worst time to wake a sleeping worker measured on the 2-core machine (s). Default
    /// 1.5e-4.
    pub wake_seconds: f64,
    /// Mean time per step (s) from which a component may step on the look-ahead thread in
    /// Gauss-Seidel order. Handing a step over and taking it back costs the master about 1 us
    /// when the thread is awake (measured on the 2-core machine with the TMT edge sensors and
    /// optics, whose inputs are the mirror's 1476 displacements: 0.24-0.54 us to copy them past
    /// the cache, the stores' drain included, a few nanoseconds to send the step, the rest to
    /// receive it); waking a sleeping thread takes 50-150 us there,
    /// hidden while the master steps the others. Default 5e-6, five times that cost;
    /// [`super::Simulation::set_lookahead`] changes it on a running simulation.
    pub lookahead_min_seconds: f64,
    /// Weight of the newest step in each component's running mean of its step time (the mean
    /// the thresholds above are compared with): `mean += weight * (last - mean)`. Default 0.05.
    pub mean_weight: f64,
    /// Base steps between the starts of two timed trials of the look-ahead thread, the first
    /// after [`Self::lookahead_trial_block`] steps: blocks without and with it, the faster
    /// kept until the next trial (`trial.rs`; [`super::Simulation::lookahead_trials`]). 0: no
    /// trial, the thread used whenever the rules above allow. Default 8000: a 5 s run at
    /// 1 ms takes one, at its 110th step.
    pub lookahead_trial_every: u64,
    /// Timed base steps of each of a trial's blocks (at least 10; a tenth as many before them
    /// are not timed). Default 100: in the standard systems the 10 Hz PSSN's evaluation falls
    /// once in each block's timed steps, on whichever thread it runs.
    pub lookahead_trial_block: u64,
}

impl Default for SchedulerParams {
    fn default() -> Self {
        Self {
            parallel_min_seconds: 2e-4,
            split_min_seconds: 5e-5,
            wake_seconds: 1.5e-4,
            lookahead_min_seconds: 5e-6,
            mean_weight: 0.05,
            lookahead_trial_every: 8000,
            lookahead_trial_block: 100,
        }
    }
}

impl SchedulerParams {
    /// Whether a component with this mean step time (s; infinite until measured) is worth
    /// handing to the look-ahead thread.
    pub(super) fn worth_lookahead(&self, mean: f64) -> bool {
        mean.is_finite() && mean >= self.lookahead_min_seconds
    }
}

/// How long the look-ahead thread polls for its next job before it sleeps. A job handed to
/// a sleeping thread costs the master a wake-up system call (a few microseconds on the 2-core
/// machine, a per-cent of a 1 ms TMT step) and the thread its scheduling latency; polling
/// through the idle part of a typical step avoids both. The poll only reads an atomic in the
/// core's own cache, so it takes no memory bandwidth from the components; beyond it the thread
/// sleeps, so a run that stops handing over (or a pause) costs next to nothing (a look at the
/// queue every 2 ms, `queue.rs`).
const SPIN_WORKER: std::time::Duration = std::time::Duration::from_micros(500);

/// How long the master polls for the component on the look-ahead thread before it sleeps.
pub(super) const SPIN_MASTER: std::time::Duration = std::time::Duration::from_micros(200);

/// A component's step on the look-ahead thread: it goes there with its inputs gathered and
/// comes back stepped, with the outcome.
pub(super) struct Job {
    pub(super) index: usize,
    pub(super) comp: Box<Running>,
    t: f64,
    h: f64,
    left: usize,
    /// Whether the thread keeps a copy of its Real inputs (the memo) for the kept sinks' next
    /// steps that read the same values ([`KeptStep::from_memo`]).
    memo: bool,
    /// The outcome, the error boxed: a message is then two cache lines, not three.
    pub(super) result: std::result::Result<(), Box<CosimError>>,
}

impl Job {
    pub(super) fn new(
        index: usize,
        comp: Box<Running>,
        (t, h, left): (f64, f64, usize),
        memo: bool,
    ) -> Self {
        Self {
            index,
            comp,
            t,
            h,
            left,
            memo,
            result: Ok(()),
        }
    }

    /// The component, back, and the outcome of its step.
    pub(super) fn into_parts(self) -> (usize, Box<Running>, Result<()>) {
        (self.index, self.comp, self.result.map_err(|e| *e))
    }
}

/// A step of a component kept on the look-ahead thread (a sink, [`Work::Keep`]): its Real
/// inputs, and room for its recorded outputs; both come back with the outcome.
pub(super) struct KeptStep {
    pub(super) index: usize,
    t: f64,
    h: f64,
    left: usize,
    /// Its Real inputs, laid out as its port's (coming back: the buffer they replaced).
    pub(super) inputs: Vec<f64>,
    /// Its recorded outputs after the step, as numbers (in [`Kept::recorded`]'s order).
    pub(super) recorded: Vec<f64>,
    /// Which of its [`Kept::memo_plans`] fills the rest of its inputs from the memo (the Real
    /// inputs of the last component stepped there with [`Job::memo`]); None: all came with it.
    from_memo: Option<usize>,
    /// The outcome (boxed, as [`Job::result`]).
    pub(super) result: std::result::Result<(), Box<CosimError>>,
}

impl KeptStep {
    pub(super) fn new(
        index: usize,
        t: f64,
        h: f64,
        left: usize,
        inputs: Vec<f64>,
        recorded: Vec<f64>,
        from_memo: Option<usize>,
    ) -> Self {
        Self {
            index,
            t,
            h,
            left,
            inputs,
            recorded,
            from_memo,
            result: Ok(()),
        }
    }

    /// Its buffers, for the next step.
    pub(super) fn into_buffers(self) -> (Vec<f64>, Vec<f64>) {
        (self.inputs, self.recorded)
    }
}

/// A component that stays on the look-ahead thread, and where its recorded outputs are among
/// its outputs (kind, slot).
pub(super) struct Kept {
    pub(super) comp: Box<Running>,
    pub(super) recorded: Vec<(Kind, usize)>,
    /// Per component whose inputs may be the memo, the runs `(first in the memo, first input,
    /// length)` of its inputs that the memo then holds (`KeptSink::plans`, same order).
    pub(super) memo_plans: Vec<Vec<(usize, usize, usize)>>,
    /// Whether one of its steps failed: it steps no more (the sequential order would not
    /// have stepped it again), and its later steps reply with no values.
    pub(super) failed: bool,
}

/// What the master sends the look-ahead thread; each message has one reply, and replies come
/// in the order of the messages.
pub(super) enum Work {
    /// Step this component, then give it back ([`Reply::Stepped`]).
    Step(Job),
    /// Keep this component (the first of its kept steps follows).
    Keep(usize, Box<Kept>),
    /// Step a kept component on these inputs ([`Reply::KeptStepped`]).
    KeptStep(KeptStep),
    /// Give this kept component back ([`Reply::Returned`]).
    GiveBack(usize),
}

/// The look-ahead thread's replies.
pub(super) enum Reply {
    Stepped(Job),
    Kept,
    KeptStepped(KeptStep),
    Returned(usize, Option<Box<Running>>),
}

/// Most messages in flight to the look-ahead thread at once. Its steps run there one after the
/// other in the order they were sent: components' steps in their order of the sequential run,
/// and a kept component's steps one after the other, as many as this allows (a sink whose step
/// takes several base steps now and then, such as the optics when they compute PSSN, catches
/// up over the next ones).
pub(super) const LOOKAHEAD_SLOTS: usize = 256;

/// What a message in flight is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Flight {
    /// A component's step, the component with it.
    Step,
    /// A component going to be kept.
    Keep,
    /// A step of a kept component.
    KeptStep,
    /// A kept component coming back.
    GiveBack,
}

/// A message in flight to the look-ahead thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct InFlight {
    /// The component.
    pub(super) index: usize,
    /// The base step at which its step began.
    pub(super) since: u64,
    /// The base step at which its outputs become visible.
    pub(super) due: u64,
    pub(super) what: Flight,
}

/// The look-ahead thread of a simulation and the messages it has in flight.
pub(super) struct Lookahead {
    pub(super) jobs: Option<Sender<Work>>,
    pub(super) done: Receiver<Reply>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// The messages in flight, oldest first: the order in which their replies come.
    pub(super) in_flight: std::collections::VecDeque<InFlight>,
    /// Per component, whether the thread keeps it.
    pub(super) kept: Vec<bool>,
    /// Components' steps taken there so far.
    pub(super) deferred: u64,
}

impl Lookahead {
    /// The thread, for a simulation of `n` components.
    pub(super) fn start(n: usize) -> Result<Self> {
        // Room for every message in flight in either channel: a send never blocks.
        let (jobs, mut inbox) = queue::<Work>(LOOKAHEAD_SLOTS);
        let (mut outbox, done) = queue::<Reply>(LOOKAHEAD_SLOTS);
        let thread = std::thread::Builder::new()
            .name("cosim-lookahead".into())
            .spawn(move || work(&mut inbox, &mut outbox, n))
            .map_err(|e| CosimError::Invalid(format!("cannot start the look-ahead thread: {e}")))?;
        Ok(Self {
            jobs: Some(jobs),
            done,
            thread: Some(thread),
            in_flight: std::collections::VecDeque::with_capacity(LOOKAHEAD_SLOTS),
            kept: vec![false; n],
            deferred: 0,
        })
    }

    /// Whether another message can go in flight.
    pub(super) fn has_room(&self) -> bool {
        self.jobs.is_some() && self.in_flight.len() < LOOKAHEAD_SLOTS
    }

    /// Sends `work` (about `flight`), in flight until its reply is received from `done`. Gives
    /// it back if the thread is gone (or no room is left: the caller checks
    /// [`Self::has_room`] first).
    pub(super) fn send(
        &mut self,
        flight: InFlight,
        work: Work,
    ) -> std::result::Result<(), Box<Work>> {
        let Some(tx) = self
            .jobs
            .as_mut()
            .filter(|_| self.in_flight.len() < LOOKAHEAD_SLOTS)
        else {
            return Err(Box::new(work));
        };
        tx.send(work).map_err(Box::new)?;
        self.in_flight.push_back(flight);
        if matches!(flight.what, Flight::Step | Flight::KeptStep) {
            self.deferred += 1;
        }
        Ok(())
    }
}

/// The look-ahead thread's loop: each message in turn, one reply each, until the master hangs
/// up; the components it keeps are dropped here then (after every reply).
fn work(inbox: &mut Receiver<Work>, outbox: &mut Sender<Reply>, n: usize) {
    let mut kept: Vec<Option<Box<Kept>>> = (0..n).map(|_| None).collect();
    let mut memo: Vec<f64> = Vec::new();
    while let Some(w) = inbox.recv(SPIN_WORKER) {
        let reply = match w {
            Work::Step(mut job) => {
                if job.memo {
                    // Copied before the step: the step reads them from this core's cache then.
                    memo.clear();
                    memo.extend_from_slice(&job.comp.ports.real.in_buf);
                }
                job.result = job
                    .comp
                    .step_gathered(job.t, job.h, job.left)
                    .map_err(Box::new);
                Reply::Stepped(job)
            }
            Work::Keep(i, k) => {
                if let Some(slot) = kept.get_mut(i) {
                    *slot = Some(k);
                }
                Reply::Kept
            }
            Work::KeptStep(mut s) => {
                s.result = match kept.get_mut(s.index).and_then(Option::as_mut) {
                    Some(k) if k.failed => {
                        s.recorded.clear();
                        Ok(())
                    }
                    Some(k)
                        if s.from_memo.is_some_and(|p| {
                            !k.memo_plans.get(p).is_some_and(|plan| {
                                plan.iter().all(|&(m, dst, len)| {
                                    m + len <= memo.len() && dst + len <= s.inputs.len()
                                })
                            })
                        }) =>
                    {
                        Err(CosimError::Invalid(format!(
                            "component {}: its inputs are not in the memo (internal error)",
                            s.index
                        )))
                    }
                    Some(k) => {
                        if let Some(plan) = s.from_memo.and_then(|p| k.memo_plans.get(p)) {
                            for &(m, dst, len) in plan {
                                s.inputs[dst..dst + len].copy_from_slice(&memo[m..m + len]);
                            }
                        }
                        let r = &mut k.comp;
                        std::mem::swap(&mut r.ports.real.in_buf, &mut s.inputs);
                        let out = r.step_gathered(s.t, s.h, s.left);
                        s.recorded.clear();
                        s.recorded.extend(
                            k.recorded
                                .iter()
                                .map(|&(kind, slot)| r.ports.number(kind, slot)),
                        );
                        k.failed = out.is_err();
                        out
                    }
                    None => Err(CosimError::Invalid(format!(
                        "component {} is not kept on the look-ahead thread (internal error)",
                        s.index
                    ))),
                }
                .map_err(Box::new);
                Reply::KeptStepped(s)
            }
            Work::GiveBack(i) => {
                Reply::Returned(i, kept.get_mut(i).and_then(Option::take).map(|k| k.comp))
            }
        };
        // Never full: at most as many replies as messages in flight.
        if outbox.send(reply).is_err() {
            break;
        }
    }
}

impl Drop for Lookahead {
    fn drop(&mut self) {
        // Closing the channel ends the thread's loop; the messages still in flight get their
        // replies (or are dropped with the thread), and the kept components are dropped there,
        // before the libraries close: Simulation's fields drop after this one.
        self.jobs = None;
        for _ in self.in_flight.drain(..) {
            if self.done.recv(SPIN_MASTER).is_none() {
                break;
            }
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// How the due components of a Jacobi step are spread over threads ([`plan_jacobi`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum JacobiPlan {
    /// All in parallel by recursive halving.
    Parallel,
    /// Component `i` (the heaviest) on this thread, the others in turn on a worker.
    Split(usize),
    /// All in turn on this thread.
    InTurn,
}

impl JacobiPlan {
    /// Whether the step uses more than one thread.
    pub(super) fn is_parallel(self) -> bool {
        self != Self::InTurn
    }
}

/// Decides the threads of a Jacobi step from the due components' mean step times: in
/// parallel when at least two take over [`SchedulerParams::parallel_min_seconds`] per step;
/// with one such component (the heaviest), it on this thread and the others in turn on a
/// worker, when they add up to [`SchedulerParams::split_min_seconds`] and it outlasts them by
/// [`SchedulerParams::wake_seconds`]; otherwise all in turn on this thread.
pub(super) fn plan_jacobi(
    comps: &[Option<Box<Running>>],
    due: &dyn Fn(&Running) -> bool,
    params: &SchedulerParams,
) -> JacobiPlan {
    // Threads only pay when at least two components take long enough per step to
    // hide waking a worker (tens of microseconds): otherwise step them in turn,
    // which gives the same (Jacobi) results.
    // Also: with one heavy component and enough light work to move, the heavy one
    // on this thread, the others in turn on a worker, whose wake-up hides behind it.
    let (mut heavy, mut top, mut top_mean, mut rest) = (0, None, 0.0, 0.0);
    for (i, r) in comps.iter().enumerate() {
        if let Some(r) = r.as_deref().filter(|r| due(r)) {
            // Unmeasured (infinite mean): not heavy, as for the look-ahead.
            heavy += usize::from(r.mean.is_finite() && r.mean >= params.parallel_min_seconds);
            let m = if r.mean.is_finite() { r.mean } else { 0.0 };
            if m > top_mean {
                rest += top_mean;
                top = Some(i);
                top_mean = m;
            } else {
                rest += m;
            }
        }
    }
    if heavy > 1 {
        JacobiPlan::Parallel
    } else if let Some(i) = top
        && rest >= params.split_min_seconds
        && top_mean >= rest + params.wake_seconds
    {
        JacobiPlan::Split(i)
    } else {
        JacobiPlan::InTurn
    }
}

/// Steps the due components of a Jacobi step on the values `outputs` of the communication
/// point, on the threads of `plan`; returns the wall time of the FMU calls on the critical
/// path.
pub(super) fn advance_jacobi(
    plan: JacobiPlan,
    comps: &mut [Option<Box<Running>>],
    due: &(dyn Fn(&Running) -> bool + Sync),
    outputs: Visible<'_>,
    t: f64,
    h: f64,
    left: usize,
) -> Result<f64> {
    Ok(match plan {
        JacobiPlan::Parallel => advance_split(comps, due, outputs, t, h, left)?,
        JacobiPlan::Split(i) => {
            let (before, from) = comps.split_at_mut(i);
            let (heaviest, after) = from.split_at_mut(1);
            let (x, y) = rayon::join(
                || advance_split(heaviest, due, outputs, t, h, left),
                || {
                    let others = before.iter_mut().chain(after.iter_mut());
                    advance_in_turn(others, due, outputs, t, h, left)
                },
            );
            x?.max(y?)
        }
        JacobiPlan::InTurn => advance_in_turn(comps.iter_mut(), due, outputs, t, h, left)?,
    })
}

/// Steps the due components of `comps` in parallel by recursive halving (`rayon::join`: no
/// allocation, and the calling thread takes one half). Returns the wall time of the FMU calls
/// on the critical path (the longer of the two halves, recursively).
pub(super) fn advance_split(
    comps: &mut [Option<Box<Running>>],
    due: &(dyn Fn(&Running) -> bool + Sync),
    outputs: Visible<'_>,
    t: f64,
    h: f64,
    left: usize,
) -> Result<f64> {
    match comps {
        [] => Ok(0.0),
        [r] => match r.as_deref_mut() {
            Some(r) if due(r) => r.advance(outputs, t, h, left).map(|()| r.last),
            _ => Ok(0.0),
        },
        _ => {
            let (a, b) = comps.split_at_mut(comps.len() / 2);
            let (x, y) = rayon::join(
                || advance_split(a, due, outputs, t, h, left),
                || advance_split(b, due, outputs, t, h, left),
            );
            Ok(x?.max(y?))
        }
    }
}

/// Steps the due components of `comps` one after the other on `outputs`; returns the wall
/// time of their FMU calls.
pub(super) fn advance_in_turn<'a>(
    comps: impl Iterator<Item = &'a mut Option<Box<Running>>>,
    due: &dyn Fn(&Running) -> bool,
    outputs: Visible<'_>,
    t: f64,
    h: f64,
    left: usize,
) -> Result<f64> {
    let mut sum = 0.0;
    for r in comps.flatten().filter(|r| due(r)) {
        r.advance(outputs, t, h, left)?;
        sum += r.last;
    }
    Ok(sum)
}
