//! The running simulation: the state the master keeps between communication steps (the
//! components, the shared output buffer, time, the look-ahead thread, timing) and what a caller
//! can ask of it between steps. It is built by [`Simulation::new`] (`setup.rs`) and advanced by
//! [`Simulation::step`] (`step.rs`).

use super::definition::Order;
use super::ports::{CopyTrial, SourcedRun, Values};
use super::step::Running;
use super::threads::{InFlight, Lookahead, SchedulerParams};
use super::trial::{LookaheadTrial, Trials};
use super::wiring::Kind;
use crate::error::Result;
use crate::fmu::Fmu;

/// The recorded scalars: their column names and where each is in the shared buffers.
#[derive(Debug, Clone)]
pub struct Recorded {
    /// Column names (`"comp.z[1]"`, ...).
    pub columns: Vec<String>,
    /// Per column, its kind and global slot.
    pub(super) slots: Vec<(Kind, usize)>,
    /// The columns as runs `(first column, first slot, length)`: Real columns of consecutive
    /// slots in one run (an array output recorded whole, such as a mirror's 1476
    /// displacements, is one copy per row), each other column a run of its own
    /// ([`Recorded::runs_of`]).
    pub(super) runs: Vec<(usize, usize, usize)>,
}

impl Recorded {
    /// [`Recorded::runs`] of `slots`.
    pub(super) fn runs_of(slots: &[(Kind, usize)]) -> Vec<(usize, usize, usize)> {
        let mut runs: Vec<(usize, usize, usize)> = Vec::new();
        for (c, &(kind, slot)) in slots.iter().enumerate() {
            match runs.last_mut() {
                Some((c0, s0, n))
                    if kind == Kind::Real
                        && slots[*c0].0 == Kind::Real
                        && *c0 + *n == c
                        && *s0 + *n == slot =>
                {
                    *n += 1;
                }
                _ => runs.push((c, slot, 1)),
            }
        }
        runs
    }
}

/// Per component, its recorded outputs: (column, kind, slot among its outputs of that kind).
pub(super) type RecordedOf = Vec<Vec<(usize, Kind, usize)>>;

/// Recorded values that came back late, per step that brought them: the base step from which
/// its outputs were visible (`due`), the last row sampled before it came back (`upto`), and its
/// recorded columns' values, which rows `due..=upto` should show.
#[derive(Debug, Default)]
pub(super) struct Late {
    /// Per step: `(due, upto, end of its values in `values`)`.
    steps: Vec<(u64, u64, usize)>,
    /// `(column, value)`, step after step.
    values: Vec<(usize, f64)>,
}

/// How a sink kept on the look-ahead thread gets its inputs: its number of Real inputs (they
/// come as [`Simulation::real_runs`] says, or some from the memo: `plans`), and the buffers
/// that come back from its steps.
#[derive(Debug, Default)]
pub(super) struct KeptSink {
    pub(super) inputs: usize,
    /// Per component whose Real inputs share source runs with this sink's: the plan of the
    /// copies from the memo when that component's inputs are the memo.
    pub(super) plans: Vec<MemoPlan>,
    pub(super) free_inputs: Vec<Vec<f64>>,
    pub(super) free_recorded: Vec<Vec<f64>>,
}

/// How a kept sink takes some of its Real inputs from the memo: the Real inputs the look-ahead
/// thread keeps of the last component stepped there with [`Job::memo`](super::threads::Job)
/// (component `from`), when the values those runs came from have not changed since.
#[derive(Debug, Clone, Default)]
pub(super) struct MemoPlan {
    /// The component whose inputs the memo holds.
    pub(super) from: usize,
    /// Per run of the sink's [`Simulation::real_runs`], whether the memo holds it.
    pub(super) covered: Vec<bool>,
    /// The copies from the memo: `(first in the memo, first input, length)`.
    pub(super) runs: Vec<(usize, usize, usize)>,
}

impl MemoPlan {
    /// The plan for a sink reading `sink` (its sourced runs) from the memo of `from`'s inputs
    /// (`memo`, its sourced runs): a run is covered when one of `from`'s runs holds the same
    /// source outputs. None if none is.
    pub(super) fn new(from: usize, sink: &[SourcedRun], memo: &[SourcedRun]) -> Option<Self> {
        let mut plan = Self {
            from,
            ..Self::default()
        };
        for r in sink {
            let held = memo
                .iter()
                .find(|q| q.comp == r.comp && q.at <= r.at && r.at + r.n <= q.at + q.n);
            plan.covered.push(held.is_some());
            if let Some(q) = held {
                plan.runs.push((q.dst + (r.at - q.at), r.dst, r.n));
            }
        }
        (!plan.runs.is_empty()).then_some(plan)
    }
}

/// The memo's content as the master knows it: whose inputs (None: nothing usable), and the
/// [`Simulation::seen`] counts of every component when they were gathered (room for all made
/// at the start: the step loop allocates nothing).
#[derive(Debug, Clone, Default)]
pub(super) struct Memo {
    pub(super) from: Option<usize>,
    pub(super) seen: Vec<u64>,
}

/// The system instantiated and initialised, ready to step.
pub struct Simulation {
    /// The components in order; `None` while on the look-ahead thread.
    pub(super) comps: Vec<Option<Box<Running>>>,
    /// Per component, the components it reads from (sorted, without duplicates).
    pub(super) sources: Vec<Vec<usize>>,
    /// Per component, its period in base steps.
    pub(super) every: Vec<u64>,
    /// Component names in order (also while one is on the look-ahead thread).
    pub(super) names: Vec<String>,
    /// Per component, whether it must stay on the master's thread in Gauss-Seidel order:
    /// another instance of its FMU is in the system.
    pub(super) stay_on_master: Vec<bool>,
    /// Per component, its recorded outputs.
    pub(super) recorded_of: RecordedOf,
    /// Whether components with recorded outputs may step on the look-ahead thread: the caller
    /// then takes the values the rows sampled meanwhile missed ([`Self::take_late`]).
    pub(super) late_rows: bool,
    /// Recorded values that came back from the look-ahead thread after rows that should show
    /// them were sampled ([`Self::take_late`]).
    pub(super) late: Late,
    /// The look-ahead thread (None: off, or a single component).
    pub(super) lookahead: Option<Lookahead>,
    /// The look-ahead thread's timed trials (None: none, [`SchedulerParams::lookahead_trial_every`]).
    pub(super) trials: Option<Trials>,
    /// Steps taken on look-ahead threads ended since the start (a trial's switches).
    pub(super) lookahead_steps_before: u64,
    /// Per component, if it is a sink that may be kept on the look-ahead thread (no other
    /// component reads it, it steps every base step, it is the only instance of its FMU and
    /// its connected inputs are all Real): how its inputs are gathered there.
    pub(super) sinks: Vec<Option<KeptSink>>,
    /// The base step at which a step that came back from the look-ahead thread with an error
    /// (or an end) had begun.
    pub(super) lookahead_failed_at: Option<u64>,
    /// The scheduler's thresholds (the look-ahead's among them: the mean step time from which a
    /// component may go to the look-ahead thread).
    pub(super) params: SchedulerParams,
    /// Jacobi base steps whose components stepped on more than one thread.
    pub(super) parallel_steps: u64,
    /// The visible outputs of all components, per kind, concatenated.
    pub(super) outputs: Values,
    /// Per component, the base step at which the outputs of its latest step become visible,
    /// while they are not yet (FMI timing: the end of that step).
    pub(super) pending: Vec<Option<u64>>,
    /// Per component, whether its due outputs may wait in its ports until something reads
    /// them ([`Self::publish_due`]): in Gauss-Seidel order, a component that steps every base
    /// step and has no recorded outputs (its outputs in the shared buffer are read only as
    /// another component's inputs, and each step's replace the last's at once).
    pub(super) lazy: Vec<bool>,
    /// Per component, where its Real inputs come from, run by run and source by source: a
    /// step on the look-ahead thread takes a stale source's values straight from its ports.
    pub(super) real_runs: Vec<Vec<SourcedRun>>,
    /// Per component, how many times its visible outputs have changed (made visible, or
    /// marked stale): equal counts, equal values.
    pub(super) seen: Vec<u64>,
    /// Per component, whether its steps on the look-ahead thread leave their Real inputs
    /// there (the memo) for a kept sink that reads some of the same values.
    pub(super) memo_for: Vec<bool>,
    /// What the memo on the look-ahead thread holds.
    pub(super) memo: Memo,
    /// Kept sinks' steps that took inputs from the memo.
    pub(super) memo_steps: u64,
    /// How the master copies the inputs of the steps it hands to the look-ahead thread.
    pub(super) copy_trial: CopyTrial,
    /// Whether unchanged inputs are set at every step too ([`super::System::set_unchanged_inputs`]).
    pub(super) set_unchanged_inputs: bool,
    /// Per lazy component, whether its ports hold due outputs not yet copied to `outputs`
    /// (copied when a reader's turn comes, [`Self::fresh_sources`], or at [`Self::settle`]).
    pub(super) stale: Vec<bool>,
    /// The latest base step whose outputs are visible now: the current one in Jacobi order,
    /// the next one during a Gauss-Seidel step (module docs).
    pub(super) visible: u64,
    pub(super) order: Order,
    pub(super) step: f64,
    pub(super) time: f64,
    pub(super) start: f64,
    pub(super) stop: f64,
    pub(super) n_steps: u64,
    pub(super) recorded: Recorded,
    /// Wall time of the FMU calls on the critical path (s): per step, the longest of the
    /// parallel components (Jacobi) or their sum (Gauss-Seidel).
    pub(super) fmu_critical: f64,
    /// FMUs kept open (libraries and files) for the instances' lifetime.
    pub(super) _fmus: Vec<Fmu>,
}

impl Simulation {
    /// Turns the look-ahead thread off (`None`) or lets components of at least that mean step
    /// time (s) use it (the default is [`SchedulerParams::lookahead_min_seconds`]): in
    /// Gauss-Seidel order components whose outputs are not needed right away, in both orders
    /// sinks kept there (module docs). Results are the same either way. This call ends the
    /// look-ahead's timed trials ([`SchedulerParams::lookahead_trial_every`]): the choice is
    /// the caller's from then on.
    ///
    /// # Errors
    /// As [`Self::settle`] (a component in flight is waited for first).
    pub fn set_lookahead(&mut self, min_seconds: Option<f64>) -> Result<()> {
        self.trials = None;
        self.switch_lookahead(min_seconds)
    }

    /// The look-ahead's timed trials so far, oldest first.
    pub fn lookahead_trials(&self) -> &[LookaheadTrial] {
        self.trials.as_ref().map_or(&[], |t| t.outcomes.as_slice())
    }

    /// [`Self::set_lookahead`] without ending the trials.
    pub(super) fn switch_lookahead(&mut self, min_seconds: Option<f64>) -> Result<()> {
        self.settle()?;
        match min_seconds {
            None => {
                if let Some(l) = self.lookahead.take() {
                    self.lookahead_steps_before += l.deferred;
                }
                self.memo.from = None;
            }
            Some(m) => {
                self.params.lookahead_min_seconds = m;
                if self.lookahead.is_none() && self.comps.len() > 1 {
                    // A new thread: nothing in its memo yet.
                    self.memo.from = None;
                    self.lookahead = Some(Lookahead::start(self.comps.len())?);
                }
            }
        }
        Ok(())
    }

    /// The scheduler's thresholds in use.
    pub fn scheduler(&self) -> &SchedulerParams {
        &self.params
    }

    /// Jacobi base steps so far whose components stepped on more than one thread.
    pub fn parallel_steps(&self) -> u64 {
        self.parallel_steps
    }

    /// The base step at which the oldest step now on the look-ahead thread began (None: none
    /// is). Rows recorded since then are only final once it is back ([`Self::settle`]).
    pub fn in_flight_since(&self) -> Option<u64> {
        self.lookahead
            .as_ref()
            .and_then(|l| l.in_flight.front())
            .map(|f| f.since)
    }

    /// Lets components whose outputs are recorded step on the look-ahead thread: the rows
    /// sampled while such a step is in flight show its component's previous outputs, and
    /// [`Self::take_late`] hands over the values they should show once it is back. The caller
    /// must hold those rows until then ([`Self::in_flight_since`]); [`super::run_into`] does.
    pub(super) fn set_late_rows(&mut self, on: bool) {
        self.late_rows = on;
    }

    /// Notes the recorded values of a step back from the look-ahead thread, if rows sampled
    /// before it came back should show them (when on, [`Self::set_late_rows`]): a kept sink's
    /// `values` as its reply brought them (in `recorded_of` order), else its component's
    /// outputs, back in place.
    pub(super) fn note_late(&mut self, step: InFlight, values: Option<&[f64]>) {
        let cols = &self.recorded_of[step.index];
        // Rows sampled so far are those of base steps up to `n_steps` (a step under way has
        // not counted itself yet).
        let upto = self.n_steps;
        if !self.late_rows || cols.is_empty() || step.due > upto {
            return;
        }
        let late = &mut self.late;
        match values {
            Some(values) => late
                .values
                .extend(cols.iter().zip(values).map(|(&(c, _, _), &v)| (c, v))),
            None => {
                let Some(r) = self.comps[step.index].as_deref() else {
                    return;
                };
                late.values.extend(
                    cols.iter()
                        .map(|&(c, kind, slot)| (c, r.ports.number(kind, slot))),
                );
            }
        }
        late.steps.push((step.due, upto, late.values.len()));
    }

    /// Hands each recorded value that came back late to `patch(due, upto, values)`: rows of
    /// base steps `due..=upto` should show `values` (`(column, value)`, columns counted without
    /// time), in the order they came back; then forgets them.
    pub(super) fn take_late(&mut self, mut patch: impl FnMut(u64, u64, &[(usize, f64)])) {
        let mut start = 0;
        for &(due, upto, end) in &self.late.steps {
            patch(due, upto, &self.late.values[start..end]);
            start = end;
        }
        self.late.steps.clear();
        self.late.values.clear();
    }

    /// The base step at which a step that came back from the look-ahead thread with an error
    /// or an end had begun: the steps taken after it would not have been taken in the
    /// sequential order, and rows recorded after it are not to be kept.
    pub fn lookahead_failed_at(&self) -> Option<u64> {
        self.lookahead_failed_at
    }

    /// Steps of sinks kept on the look-ahead thread that took some of their inputs from the
    /// memo there (the Real inputs of a component stepped there just before them, from the
    /// same outputs): values the master copied once for two components.
    pub fn lookahead_memo_steps(&self) -> u64 {
        self.memo_steps
    }

    /// Components' steps taken on the look-ahead thread so far.
    pub fn lookahead_steps(&self) -> u64 {
        self.lookahead_steps_before + self.lookahead.as_ref().map_or(0, |l| l.deferred)
    }

    /// Current simulation time (s).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Stop time (s).
    pub fn stop_time(&self) -> f64 {
        self.stop
    }

    /// The recorded columns (without time).
    pub fn recorded_columns(&self) -> &[String] {
        &self.recorded.columns
    }

    /// The current values of the recorded columns, into `out` (as many as there are columns
    /// at the most): a run of Real columns of consecutive slots in one copy.
    pub fn recorded_values(&self, out: &mut [f64]) {
        let n = out.len().min(self.recorded.slots.len());
        for &(c, s, len) in &self.recorded.runs {
            if c >= n {
                break;
            }
            let len = len.min(n - c);
            let (kind, _) = self.recorded.slots[c];
            if kind == Kind::Real {
                out[c..c + len].copy_from_slice(&self.outputs.real[s..s + len]);
            } else {
                out[c] = self.outputs.number(kind, s);
            }
        }
    }

    /// Whether the stop time is reached (within a millionth of a step).
    pub fn finished(&self) -> bool {
        self.time >= self.stop - 1e-6 * self.step
    }

    /// Terminates every component.
    ///
    /// # Errors
    /// The first component that fails to terminate.
    pub fn terminate(&mut self) -> Result<()> {
        self.settle()?;
        for r in self.comps.iter_mut().flatten() {
            r.instance.terminate()?;
        }
        Ok(())
    }

    /// Wall time spent in each component's calls so far (s), in component order (a component
    /// on the look-ahead thread is missing until [`Self::settle`]).
    pub fn component_seconds(&self) -> Vec<(String, f64)> {
        self.comps
            .iter()
            .flatten()
            .map(|r| (r.name.clone(), r.busy))
            .collect()
    }

    /// Wall time of each component's set-up, from instantiation to the end of initialisation
    /// (s; the components leave initialisation in parallel, so these can add up to more than
    /// the set-up's wall time).
    pub fn component_setup_seconds(&self) -> Vec<(String, f64)> {
        self.comps
            .iter()
            .flatten()
            .map(|r| (r.name.clone(), r.setup))
            .collect()
    }

    /// Wall time of the FMU calls on the critical path so far (s).
    pub fn fmu_critical_seconds(&self) -> f64 {
        self.fmu_critical
    }

    /// Component names in order.
    pub fn component_names(&self) -> Vec<&str> {
        self.names.iter().map(String::as_str).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::{Kind, MemoPlan, Recorded, SourcedRun};

    fn run(slot: usize, comp: usize, at: usize, dst: usize, n: usize) -> SourcedRun {
        SourcedRun {
            slot,
            comp,
            at,
            dst,
            n,
        }
    }

    /// A sink's run is taken from the memo where one of the memo's runs holds all of the same
    /// source outputs (at its place among the memo's inputs), and not where it holds only part
    /// of them or those of another component.
    #[test]
    fn memo_plans_cover_whole_runs_of_the_same_outputs() {
        // The memo's component reads outputs 2..10 of component 0 into inputs 4..12, and
        // output 0 of component 1 into input 0.
        let memo = [run(2, 0, 2, 4, 8), run(20, 1, 0, 0, 1)];
        let sink = [
            run(3, 0, 3, 0, 5),  // held: memo inputs 5..10
            run(8, 0, 8, 5, 4),  // outputs 8..12: only part held
            run(20, 1, 0, 9, 1), // held: memo input 0
            run(21, 1, 1, 10, 1),
        ];
        let plan = MemoPlan::new(7, &sink, &memo).unwrap();
        assert_eq!(plan.from, 7);
        assert_eq!(plan.covered, [true, false, true, false]);
        assert_eq!(plan.runs, [(5, 0, 5), (0, 9, 1)]);
        // Nothing in common: no plan.
        assert!(MemoPlan::new(7, &sink[3..], &memo).is_none());
    }

    /// Real columns of consecutive slots make one run; a gap in the slots, a column of another
    /// kind or a Real column after one makes a new run; other kinds are one column a run.
    #[test]
    fn recorded_columns_run_over_consecutive_real_slots() {
        let slots = [
            (Kind::Real, 10),
            (Kind::Real, 11),
            (Kind::Real, 12),
            (Kind::Real, 20),
            (Kind::Integer, 21),
            (Kind::Integer, 22),
            (Kind::Real, 13),
            (Kind::Real, 14),
            (Kind::Boolean, 0),
        ];
        assert_eq!(
            Recorded::runs_of(&slots),
            [
                (0, 10, 3),
                (3, 20, 1),
                (4, 21, 1),
                (5, 22, 1),
                (6, 13, 2),
                (8, 0, 1)
            ]
        );
        assert!(Recorded::runs_of(&[]).is_empty());
    }
}
