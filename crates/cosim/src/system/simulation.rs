//! The running simulation: the state the master keeps between communication steps (the
//! components, the shared output buffer, time, the look-ahead thread, timing) and what a caller
//! can ask of it between steps. It is built by [`Simulation::new`] (`setup.rs`) and advanced by
//! [`Simulation::step`] (`step.rs`).

use super::definition::Order;
use super::ports::Values;
use super::step::Running;
use super::threads::{Lookahead, SchedulerParams};
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
    /// Per component, whether it must stay on the master's thread in Gauss-Seidel order: any of
    /// its outputs recorded, or another instance of its FMU in the system.
    pub(super) stay_on_master: Vec<bool>,
    /// Gauss-Seidel's look-ahead thread (None: off, or Jacobi).
    pub(super) lookahead: Option<Lookahead>,
    /// The base step at which the step now on the look-ahead thread began.
    pub(super) in_flight_since: Option<u64>,
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
    /// Snapshot of `outputs` at the communication point (Jacobi).
    pub(super) snapshot: Values,
    /// Per component, the base step at which the outputs of its latest step become visible,
    /// while they are not yet (FMI timing: the end of that step).
    pub(super) pending: Vec<Option<u64>>,
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
    /// Turns Gauss-Seidel's look-ahead off (`None`) or lets components of at least that mean
    /// step time (s) use it (the default is [`SchedulerParams::lookahead_min_seconds`]);
    /// results are the same either way. No effect in Jacobi order.
    ///
    /// # Errors
    /// As [`Self::settle`] (a component in flight is waited for first).
    pub fn set_lookahead(&mut self, min_seconds: Option<f64>) -> Result<()> {
        self.settle()?;
        match min_seconds {
            None => self.lookahead = None,
            Some(m) => {
                self.params.lookahead_min_seconds = m;
                if self.lookahead.is_none() && self.order == Order::GaussSeidel {
                    self.lookahead = Some(Lookahead::start()?);
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

    /// The base step at which the component now on the look-ahead thread began its step (None:
    /// none is). Rows recorded since then are only final once it is back ([`Self::settle`]).
    pub fn in_flight_since(&self) -> Option<u64> {
        self.in_flight_since
    }

    /// The base step at which a step that came back from the look-ahead thread with an error
    /// or an end had begun: the steps taken after it would not have been taken in the
    /// sequential order, and rows recorded after it are not to be kept.
    pub fn lookahead_failed_at(&self) -> Option<u64> {
        self.lookahead_failed_at
    }

    /// Components' steps taken on the look-ahead thread so far.
    pub fn lookahead_steps(&self) -> u64 {
        self.lookahead.as_ref().map_or(0, |l| l.deferred)
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

    /// The current values of the recorded columns, into `out`.
    pub fn recorded_values(&self, out: &mut [f64]) {
        for (o, &(k, s)) in out.iter_mut().zip(&self.recorded.slots) {
            *o = self.outputs.number(k, s);
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
