//! The step semantics: what one communication step does in each order (module docs). A
//! [`Running`] component sets its gathered inputs, steps and reads its outputs; Jacobi gives
//! every due component the outputs of the communication point and publishes theirs after all
//! have stepped; Gauss-Seidel steps the due components in order, each on the newest outputs,
//! waiting for the steps on the look-ahead thread before anything that reads them. Where the
//! FMU calls run is the thread policy's choice (`threads.rs`) and changes no value.

use std::time::Instant;

use super::definition::Order;
use super::ports::{
    Ports, SourcedRun, Values, Visible, copy_for_other_core, gather_real_for_other_core,
};
use super::queue::TryRecv;
use super::simulation::Simulation;
use super::threads::{
    self, Flight, InFlight, Job, Kept, KeptStep, LOOKAHEAD_SLOTS, Lookahead, Reply, Work,
};
use crate::error::{CosimError, Result};
use crate::instance::Instance;

/// A running component.
pub(super) struct Running {
    pub(super) name: String,
    pub(super) instance: Instance,
    pub(super) every: usize,
    /// Its connected inputs and its connected (or recorded) outputs, per kind of value.
    pub(super) ports: Ports,
    /// Names of its Real outputs (for the message when one is not finite).
    pub(super) out_names: Vec<String>,
    /// Wall time spent in its set/doStep/get calls (s), in the last step, and a running mean.
    pub(super) busy: f64,
    pub(super) last: f64,
    pub(super) mean: f64,
    /// Weight of the newest step in `mean` ([`super::SchedulerParams::mean_weight`]).
    pub(super) mean_weight: f64,
    /// Wall time of its set-up: instantiation to the end of initialisation (s).
    pub(super) setup: f64,
}

impl Running {
    /// Sets its inputs from `shared` (all components' published outputs), steps from `t` over
    /// its own multiple of `h` (cut to the `left` base steps before the stop time), and reads
    /// its outputs into its ports: one set call per kind (per array for Real inputs connected
    /// as a few arrays, [`Ports::set_inputs_from`]), one fmi2DoStep, one get call per kind, no
    /// allocation (for Real, Integer and Boolean values).
    pub(super) fn advance(&mut self, shared: Visible, t: f64, h: f64, left: usize) -> Result<()> {
        self.step_with(t, h, left, |ports, inst| {
            ports.set_inputs_from(shared, inst)
        })
    }

    /// [`Self::advance`] on the inputs already gathered.
    ///
    /// # Errors
    /// The FMU's error; [`CosimError::Ended`] when it discarded the step and asks to end the
    /// simulation (fmi2GetBooleanStatus(fmi2Terminated)).
    pub(super) fn step_gathered(&mut self, t: f64, h: f64, left: usize) -> Result<()> {
        self.step_with(t, h, left, |ports, inst| ports.set_inputs(inst))
    }

    /// One step with the inputs set by `set_inputs` (timed with the FMU's calls).
    fn step_with(
        &mut self,
        t: f64,
        h: f64,
        left: usize,
        set_inputs: impl FnOnce(&mut Ports, &mut Instance) -> Result<()>,
    ) -> Result<()> {
        let t0 = Instant::now();
        set_inputs(&mut self.ports, &mut self.instance)?;
        if let Err(e) = self.instance.do_step(t, h * self.every.min(left) as f64) {
            return Err(self.ended_or(e, t));
        }
        self.ports.get_outputs(&mut self.instance)?;
        self.last = t0.elapsed().as_secs_f64();
        self.busy += self.last;
        self.mean = if self.mean.is_finite() {
            self.mean + self.mean_weight * (self.last - self.mean)
        } else {
            self.last
        };
        let out = &self.ports.real.out_buf;
        if !all_finite(out)
            && let Some(k) = out.iter().position(|v| !v.is_finite())
        {
            return Err(CosimError::NonFinite {
                component: self.name.clone(),
                variable: self.out_names[k].clone(),
                value: out[k],
                time: t + h * self.every.min(left) as f64,
            });
        }
        Ok(())
    }

    /// After fmi2DoStep from `t` failed with `e`: for fmi2Discard, asks the FMU whether it wants
    /// the simulation to end (fmi2GetBooleanStatus(fmi2Terminated)) and, if so, until when it
    /// got (fmi2GetRealStatus(fmi2LastSuccessfulTime), `t` if it does not say):
    /// [`CosimError::Ended`]. Otherwise `e` as it is.
    fn ended_or(&mut self, e: CosimError, t: f64) -> CosimError {
        if !matches!(e, CosimError::Discarded { .. }) {
            return e;
        }
        match self.instance.terminated() {
            Ok(true) => CosimError::Ended {
                component: self.name.clone(),
                time: self
                    .instance
                    .last_successful_time()
                    .ok()
                    .filter(|x| x.is_finite())
                    .unwrap_or(t),
            },
            _ => e,
        }
    }

    /// Copies its outputs into the shared buffers.
    pub(super) fn publish(&self, shared: &mut Values) {
        self.ports.publish(shared);
    }
}

impl Simulation {
    /// Advances one base step.
    ///
    /// # Errors
    /// The first component error, naming the component and the time;
    /// [`CosimError::Ended`] when a component ended the simulation. After an error the time
    /// stays at the step's start, but components that stepped before the failing one (in
    /// Gauss-Seidel order) have already published their outputs for its end: read nothing
    /// more from the simulation but its timings. [`run_into`](super::run_into) handles this.
    pub fn step(&mut self) -> Result<()> {
        let k = self.n_steps;
        // A block of the look-ahead's timed trial begins: the thread on or off.
        self.trial_turn(k, false)?;
        let t = self.time;
        let h = self.step;
        // Base steps left before the stop time, this one included: a slower component's last
        // step ends at the stop time, not past it (FMUs refuse to step past the stopTime
        // given to fmi2SetupExperiment).
        let left = ((self.stop - t) / h - 1e-6).ceil().max(1.0) as usize;
        match self.order {
            Order::Jacobi => self.step_jacobi(k, t, h, left)?,
            Order::GaussSeidel => self.step_gauss_seidel(k, t, h, left)?,
        }
        self.collect_ready()?;
        self.n_steps += 1;
        self.time = self.start + self.n_steps as f64 * h;
        // A trial ends: the faster side kept.
        self.trial_turn(k, true)?;
        Ok(())
    }

    /// The look-ahead's timed trial before (`after` false) or after base step `k`: outside a
    /// trial nothing (no clock read); in one, the block's timing and the switch it asks for.
    fn trial_turn(&mut self, k: u64, after: bool) -> Result<()> {
        if !self.trials.as_ref().is_some_and(|tr| tr.active(k)) {
            return Ok(());
        }
        let ahead = self.lookahead_steps();
        let on = self.trials.as_mut().and_then(|tr| {
            let now = tr.now();
            if after {
                tr.after(k, now, ahead)
            } else {
                tr.before(k, now, ahead)
            }
        });
        match on {
            Some(on) => self.trial_switch(on),
            None => Ok(()),
        }
    }

    /// A trial's switch of the look-ahead thread: off after the steps in flight there are back
    /// (their errors are the run's), or on with a new thread; if none can be started the run
    /// goes on without one, and without trials.
    fn trial_switch(&mut self, on: bool) -> Result<()> {
        if !on {
            return self.switch_lookahead(None);
        }
        if self.lookahead.is_none() && self.comps.len() > 1 {
            match Lookahead::start(self.comps.len()) {
                Ok(l) => {
                    // A new thread: nothing in its memo yet.
                    self.memo.from = None;
                    self.lookahead = Some(l);
                }
                Err(_) => self.trials = None,
            }
        }
        Ok(())
    }

    /// The base step at which the outputs of component `i`'s step at base step `k` become
    /// visible: the end of that step (FMI timing: doStep(t, H) gives the outputs at t + H).
    fn due_at(&self, i: usize, k: u64, left: usize) -> u64 {
        k + self.every[i].min(left as u64)
    }

    /// Makes visible every output whose time has come: the components whose pending outputs
    /// are due at base step `limit` or before publish them (one still on the look-ahead thread
    /// publishes when it comes back, [`Self::settle`]).
    /// A lazy component's due outputs stay in its ports, marked stale, until a reader's turn
    /// ([`Self::fresh_sources`]): the edge sensors' outputs, read by the controller at every
    /// 50th step, are then copied once per 50 steps, not at every step.
    fn publish_due(&mut self, limit: u64) {
        self.visible = limit;
        for (i, p) in self.pending.iter_mut().enumerate() {
            if p.is_some_and(|at| at <= limit)
                && let Some(r) = self.comps[i].as_deref()
            {
                if self.lazy[i] {
                    self.stale[i] = true;
                } else {
                    r.publish(&mut self.outputs);
                }
                self.seen[i] += 1;
                *p = None;
            }
        }
    }

    /// Copies the stale outputs of component `i`'s sources into the shared buffer, before `i`
    /// reads them. (A source on the look-ahead thread has been waited for before any reader's
    /// turn: its outputs are in its ports by then.)
    fn fresh_sources(&mut self, i: usize) {
        for &s in &self.sources[i] {
            if self.stale[s]
                && let Some(r) = self.comps[s].as_deref()
            {
                r.publish(&mut self.outputs);
                self.stale[s] = false;
            }
        }
    }

    /// Copies every stale output into the shared buffer.
    pub(super) fn fresh_all(&mut self) {
        for (s, stale) in self.stale.iter_mut().enumerate() {
            if *stale && let Some(r) = self.comps[s].as_deref() {
                r.publish(&mut self.outputs);
                *stale = false;
            }
        }
    }

    /// Jacobi: every due component steps on the outputs of the communication point, on the
    /// threads the policy picks; their outputs become visible at the end of their steps (this
    /// step's end for those stepping every base step).
    ///
    /// The visible outputs do not change until every due component has stepped (they are
    /// published after, [`Self::publish_due`]), so the components read them in place: no
    /// snapshot. The one write meanwhile is a kept sink's recorded outputs coming back (when
    /// the look-ahead queue is full, [`Self::kept_turn`] waits for a reply), and no component
    /// reads a sink.
    fn step_jacobi(&mut self, k: u64, t: f64, h: f64, left: usize) -> Result<()> {
        let due = |r: &Running| due_at_step(k, r.every as u64);
        // Sinks kept on the look-ahead thread get their inputs now and step there.
        for i in 0..self.comps.len() {
            if due_at_step(k, self.every[i]) {
                self.kept_turn(i, k, t, h, left)?;
            }
        }
        let plan = threads::plan_jacobi(&self.comps, &due, &self.params);
        if plan.is_parallel() {
            self.parallel_steps += 1;
        }
        let visible = Visible::new(&self.outputs, &self.seen, self.set_unchanged_inputs);
        let critical = threads::advance_jacobi(plan, &mut self.comps, &due, visible, t, h, left)?;
        for i in 0..self.comps.len() {
            if due_at_step(k, self.every[i]) {
                self.pending[i] = Some(self.due_at(i, k, left));
            }
        }
        self.publish_due(k + 1);
        self.fmu_critical += critical;
        Ok(())
    }

    /// Gauss-Seidel: the due components in turn, each on the newest outputs visible by the end
    /// of this base step; one whose outputs are not needed right away may go to the look-ahead
    /// thread (module docs).
    fn step_gauss_seidel(&mut self, k: u64, t: f64, h: f64, left: usize) -> Result<()> {
        // Outputs of slower components whose steps end with this base step.
        self.publish_due(k + 1);
        for i in 0..self.comps.len() {
            if !due_at_step(k, self.every[i]) {
                continue;
            }
            // Wait for the components in flight up to the last that is this one (its previous
            // step) or that it reads and whose outputs are visible to this step: replies come
            // in the order the steps went. A source's step whose outputs become visible only
            // later (a slower component's: the controller's at 20 Hz gives its command 50 base
            // steps on) is not waited for: until then its readers read its previous outputs,
            // in the shared buffer; a reader's turn once they are due waits for it (and it is
            // published when it comes back, `publish_due`). A kept sink's steps are not waited
            // for: nobody reads it, and its steps queue there.
            let (sources, visible) = (&self.sources[i], self.visible);
            let wait = self.lookahead.as_ref().and_then(|l| {
                l.in_flight.iter().rposition(|f| {
                    f.what == Flight::Step
                        && (f.index == i
                            || (f.due <= visible && sources.binary_search(&f.index).is_ok()))
                })
            });
            if let Some(p) = wait {
                self.settle_some(p + 1)?;
            }
            if !self.kept_turn(i, k, t, h, left)? {
                self.gs_turn(i, k, t, h, left)?;
            }
        }
        Ok(())
    }

    /// The turn of due component `i` in Gauss-Seidel order (nothing it reads is in flight).
    fn gs_turn(&mut self, i: usize, k: u64, t: f64, h: f64, left: usize) -> Result<()> {
        let n = self.comps.len();
        let room = self.lookahead.as_ref().is_some_and(|l| l.has_room());
        let at = self.due_at(i, k, left);
        let Some(r) = self.comps[i].as_deref_mut() else {
            return Err(CosimError::Invalid(format!(
                "{}: missing from the master (internal error)",
                self.names[i]
            )));
        };
        // The next turn (the next due component of this step, or the first of the next step)
        // must not read it, or it would be waited for at once.
        let next = || {
            (i + 1..n)
                .find(|&j| due_at_step(k, self.every[j]))
                .or_else(|| (0..=i).find(|&j| due_at_step(k + 1, self.every[j])))
        };
        let mut defer = room
            && !self.stay_on_master[i]
            && (self.late_rows || self.recorded_of[i].is_empty())
            && self.params.worth_lookahead(r.mean)
            && next().is_some_and(|j| j != i && self.sources[j].binary_search(&i).is_err());
        if defer {
            // Not behind a kept sink's steps still under way there (the optics' PSSN takes
            // milliseconds), nor behind a slower component's step whose outputs are not due by
            // the end of this one (the controller's, tens of microseconds): its next turn would
            // wait for them. What has come back is taken first.
            self.collect_ready()?;
            let visible = self.visible;
            defer = self.lookahead.as_ref().is_some_and(|l| {
                !l.in_flight.iter().any(|f| {
                    matches!(f.what, Flight::Keep | Flight::KeptStep)
                        || (f.what == Flight::Step && f.due > visible)
                })
            });
        }
        self.pending[i] = Some(at);
        // Its inputs for a step on the look-ahead thread are copied now, the Real ones of
        // stale sources straight from their ports (they stay stale); its other kinds, and its
        // own outputs if it reads them, from the shared buffer.
        if defer
            && (self.sources[i].binary_search(&i).is_ok()
                || self.comps[i]
                    .as_deref()
                    .is_some_and(|c| c.ports.has_other_inputs()))
        {
            self.fresh_sources(i);
        }
        if defer
            && self.lookahead.is_some()
            && let Some(mut comp) = self.comps[i].take()
        {
            // The thread steps it while the master moves on.
            comp.ports.gather_other_kinds(&self.outputs);
            let (comps, stale, shared) = (&self.comps, &self.stale, &self.outputs.real);
            let (dst, runs) = (&mut comp.ports.real.in_buf, &self.real_runs[i]);
            self.copy_trial.copy(|way| {
                gather_real_for_other_core(dst, runs, way, |r| {
                    source_values(comps, stale, shared, r)
                })
            });
            let flight = InFlight {
                index: i,
                since: k,
                due: at,
                what: Flight::Step,
            };
            let memo = self.memo_for[i];
            let job = Work::Step(Job::new(i, comp, (t, h, left), memo));
            match self.lookahead.as_mut().map(|la| la.send(flight, job)) {
                Some(Ok(())) => {
                    if memo {
                        // The memo now holds its inputs, gathered from these values.
                        self.memo.from = Some(i);
                        self.memo.seen.copy_from_slice(&self.seen);
                    }
                    return Ok(());
                }
                Some(Err(work)) => {
                    // The thread is gone: step it here, and no more look-ahead.
                    if let Work::Step(job) = *work {
                        self.comps[i] = Some(job.comp);
                    }
                    self.lookahead = None;
                }
                None => {}
            }
        }
        self.fresh_sources(i);
        if let Some(r) = self.comps[i].as_deref_mut() {
            let visible = Visible::new(&self.outputs, &self.seen, self.set_unchanged_inputs);
            r.advance(visible, t, h, left)?;
            self.fmu_critical += r.last;
        }
        self.publish_due(self.visible);
        Ok(())
    }

    /// The turn of due component `i` as a sink kept on the look-ahead thread (module docs):
    /// if it is one (or becomes one now), its inputs go there from `self.outputs` and it steps
    /// there, and this returns true. A full queue is waited for first. (Only a Gauss-Seidel
    /// hand-over fills the memo: in Jacobi order it stays empty.)
    fn kept_turn(&mut self, i: usize, k: u64, t: f64, h: f64, left: usize) -> Result<bool> {
        let Some(la) = self.lookahead.as_ref() else {
            return Ok(false);
        };
        if self.sinks[i].is_none() {
            return Ok(false);
        }
        let kept = la.kept[i];
        if !kept {
            // Kept from now on if its rows can wait for it and it is worth handing over.
            let eligible = (self.late_rows || self.recorded_of[i].is_empty())
                && self.comps[i]
                    .as_deref()
                    .is_some_and(|r| self.params.worth_lookahead(r.mean));
            if !eligible {
                return Ok(false);
            }
        }
        let need = if kept { 1 } else { 2 };
        while self
            .lookahead
            .as_ref()
            .is_some_and(|l| l.jobs.is_some() && l.in_flight.len() + need > LOOKAHEAD_SLOTS)
        {
            self.settle_some(1)?;
        }
        let at = self.due_at(i, k, left);
        if !kept {
            let Some(comp) = self.comps[i].take() else {
                return Ok(false);
            };
            let recorded = self.recorded_of[i]
                .iter()
                .map(|&(_, kind, slot)| (kind, slot))
                .collect();
            let flight = InFlight {
                index: i,
                since: k,
                due: at,
                what: Flight::Keep,
            };
            let Some(la) = self.lookahead.as_mut() else {
                self.comps[i] = Some(comp);
                return Ok(false);
            };
            match la.send(
                flight,
                Work::Keep(
                    i,
                    Box::new(Kept {
                        comp,
                        recorded,
                        memo_plans: self.sinks[i]
                            .as_ref()
                            .map(|k| k.plans.iter().map(|p| p.runs.clone()).collect())
                            .unwrap_or_default(),
                        failed: false,
                    }),
                ),
            ) {
                Ok(()) => la.kept[i] = true,
                Err(work) => {
                    if let Work::Keep(_, kept) = *work {
                        self.comps[i] = Some(kept.comp);
                    }
                    self.lookahead = None;
                    return Ok(false);
                }
            }
        }
        // A sink has Real inputs only: those of stale sources come straight from their ports
        // (they stay stale; in Jacobi order none is).
        let shared = &self.outputs.real;
        let Some(sink) = self.sinks[i].as_mut() else {
            return Ok(false);
        };
        let mut inputs = sink.free_inputs.pop().unwrap_or_default();
        inputs.resize(sink.inputs, 0.0);
        // The runs the memo holds with the values of now are copied there, from the memo; the
        // others here.
        let (seen, runs) = (&self.seen, &self.real_runs[i]);
        let m = &self.memo;
        let plan = m.from.and_then(|from| {
            sink.plans.iter().position(|p| {
                p.from == from
                    && runs
                        .iter()
                        .zip(&p.covered)
                        .all(|(r, &c)| !c || m.seen[r.comp] == seen[r.comp])
            })
        });
        self.memo_steps += u64::from(plan.is_some());
        let covered = plan.map(|p| &sink.plans[p].covered[..]);
        let (comps, stale) = (&self.comps, &self.stale);
        let mut copy = |way| {
            let mut n = 0;
            for (k, r) in runs.iter().enumerate() {
                if !covered.is_some_and(|c| c[k]) {
                    copy_for_other_core(
                        &mut inputs[r.dst..r.dst + r.n],
                        source_values(comps, stale, shared, r),
                        way,
                    );
                    n += r.n;
                }
            }
            n
        };
        // Only copies of many values are worth timing for the trial (a memo step copies few or
        // none).
        if plan.is_none() {
            self.copy_trial.copy(copy);
        } else {
            copy(self.copy_trial.way());
        }
        let recorded = sink.free_recorded.pop().unwrap_or_default();
        let step = KeptStep::new(i, t, h, left, inputs, recorded, plan);
        let flight = InFlight {
            index: i,
            since: k,
            due: at,
            what: Flight::KeptStep,
        };
        self.pending[i] = Some(at);
        let sent = self
            .lookahead
            .as_mut()
            .map(|la| la.send(flight, Work::KeptStep(step)));
        match sent {
            Some(Ok(())) => Ok(true),
            _ => {
                // The thread is gone, and the component with it.
                self.lookahead = None;
                Err(CosimError::Invalid(format!(
                    "{}: the look-ahead thread stopped",
                    self.names[i]
                )))
            }
        }
    }

    /// Reads component `c`'s current outputs and publishes them at once (after
    /// [`Self::settle`]): its initial outputs.
    pub(super) fn read_outputs(&mut self, c: usize) -> Result<()> {
        self.settle()?;
        if let Some(r) = self.comps[c].as_deref_mut() {
            r.ports.get_outputs(&mut r.instance)?;
            r.publish(&mut self.outputs);
        }
        self.seen[c] += 1;
        self.pending[c] = None;
        self.stale[c] = false;
        Ok(())
    }

    /// Waits for everything on the look-ahead thread and brings every component back (the kept
    /// ones too), publishing their outputs if they are due: afterwards every component is in
    /// place and every visible output current.
    ///
    /// # Errors
    /// The error of the first of those steps that failed (naming the component and the time),
    /// or a look-ahead thread that stopped.
    pub fn settle(&mut self) -> Result<()> {
        let mut first = Ok(());
        let n = self.comps.len();
        for i in 0..n {
            if !self.lookahead.as_ref().is_some_and(|l| l.kept[i]) {
                continue;
            }
            while self
                .lookahead
                .as_ref()
                .is_some_and(|l| l.jobs.is_some() && !l.has_room())
            {
                let r = self.settle_some(1);
                if first.is_ok() {
                    first = r;
                }
            }
            let flight = InFlight {
                index: i,
                since: self.n_steps,
                due: self.n_steps,
                what: Flight::GiveBack,
            };
            if let Some(la) = self.lookahead.as_mut()
                && la.send(flight, Work::GiveBack(i)).is_err()
            {
                self.lookahead = None;
            }
        }
        let all = self.lookahead.as_ref().map_or(0, |l| l.in_flight.len());
        let r = self.settle_some(all);
        if first.is_ok() {
            first = r;
        }
        if first.is_ok() && self.comps.iter().any(Option::is_none) {
            first = Err(CosimError::Invalid(
                "the look-ahead thread stopped with components on it".into(),
            ));
        }
        self.fresh_all();
        first
    }

    /// Takes the replies of the look-ahead thread that have come, without waiting: the kept
    /// sinks' outputs for the rows, the components stepped there. The first error among them.
    pub(super) fn collect_ready(&mut self) -> Result<()> {
        let mut first = Ok(());
        while let Some(r) = self.take_reply(false) {
            if first.is_ok() {
                first = r;
            }
        }
        first
    }

    /// Waits for the replies to the `n` oldest messages on the look-ahead thread (they come in
    /// the order the messages went), as [`Self::settle`]: all of them come even if one step
    /// failed, and the first failure is the error.
    fn settle_some(&mut self, n: usize) -> Result<()> {
        let mut first = Ok(());
        for _ in 0..n {
            match self.take_reply(true) {
                None => break,
                Some(r) => {
                    if first.is_ok() {
                        first = r;
                    }
                }
            }
        }
        first
    }

    /// Takes the reply to the oldest message on the look-ahead thread: waits for it (`wait`)
    /// or takes it only if it has come. None: nothing in flight, or not come.
    fn take_reply(&mut self, wait: bool) -> Option<Result<()>> {
        let la = self.lookahead.as_mut()?;
        let flight = *la.in_flight.front()?;
        // Only a wait is timed (it counts as the FMU's time): a look is not worth a clock read.
        let t0 = wait.then(Instant::now);
        let reply = if wait {
            la.done.recv(threads::SPIN_MASTER)
        } else {
            match la.done.try_recv() {
                TryRecv::Ready(r) => Some(r),
                TryRecv::Empty => return None,
                TryRecv::Closed => None,
            }
        };
        la.in_flight.pop_front();
        let Some(reply) = reply else {
            // The thread is gone with what it had: no more look-ahead.
            la.in_flight.clear();
            self.lookahead = None;
            self.failed_since(flight.since);
            return Some(Err(CosimError::Invalid(format!(
                "{}: the look-ahead thread stopped during its step",
                self.names[flight.index]
            ))));
        };
        if let Some(t0) = t0 {
            self.fmu_critical += t0.elapsed().as_secs_f64();
        }
        Some(match reply {
            Reply::Stepped(job) => {
                let (index, comp, result) = job.into_parts();
                self.comps[index] = Some(comp);
                match result {
                    Ok(()) => {
                        self.publish_due(self.visible);
                        self.note_late(flight, None);
                        Ok(())
                    }
                    Err(e) => {
                        self.failed_since(flight.since);
                        Err(e)
                    }
                }
            }
            Reply::Kept => Ok(()),
            Reply::KeptStepped(mut step) => {
                let result = std::mem::replace(&mut step.result, Ok(())).map_err(|e| *e);
                let out = match result {
                    Ok(()) => {
                        // The sink's recorded outputs into the shared buffer (later rows read
                        // them there) and into the rows sampled before they came.
                        for (&(c, _, _), &v) in
                            self.recorded_of[flight.index].iter().zip(&step.recorded)
                        {
                            let (kind, slot) = self.recorded.slots[c];
                            self.outputs.set_number(kind, slot, v);
                        }
                        self.note_late(flight, Some(&step.recorded));
                        Ok(())
                    }
                    Err(e) => {
                        self.failed_since(flight.since);
                        Err(e)
                    }
                };
                if let Some(sink) = self.sinks[flight.index].as_mut() {
                    let (inputs, recorded) = step.into_buffers();
                    sink.free_inputs.push(inputs);
                    sink.free_recorded.push(recorded);
                }
                out
            }
            Reply::Returned(index, comp) => {
                if let Some(la) = self.lookahead.as_mut() {
                    la.kept[index] = false;
                }
                match comp {
                    Some(comp) => {
                        self.comps[index] = Some(comp);
                        self.publish_due(self.visible);
                        Ok(())
                    }
                    None => Err(CosimError::Invalid(format!(
                        "{}: not kept on the look-ahead thread (internal error)",
                        self.names[index]
                    ))),
                }
            }
        })
    }

    /// Notes that a step begun at base step `since` failed on the look-ahead thread.
    fn failed_since(&mut self, since: u64) {
        self.lookahead_failed_at = Some(self.lookahead_failed_at.map_or(since, |f| f.min(since)));
    }
}

/// Whether a component stepping every `every` base steps steps at base step `k`: without a
/// division for the usual `every` of 1 (a 64-bit division takes tens of cycles, and a base
/// step asks this several times per component).
#[inline]
fn due_at_step(k: u64, every: u64) -> bool {
    every == 1 || k.is_multiple_of(every)
}

/// The values of Real run `r` as the step about to be taken should see them: from its source's
/// ports while the source is stale (its due outputs not yet copied to `shared`), from `shared`
/// otherwise.
fn source_values<'a>(
    comps: &'a [Option<Box<Running>>],
    stale: &[bool],
    shared: &'a [f64],
    r: &SourcedRun,
) -> &'a [f64] {
    match comps[r.comp].as_deref() {
        Some(c) if stale[r.comp] => &c.ports.real.out_buf[r.at..r.at + r.n],
        _ => &shared[r.slot..r.slot + r.n],
    }
}

/// Whether every value is finite: `0 * v` is 0 for a finite `v` and NaN otherwise, summed in
/// sixteen independent lanes so that the loop vectorises, compiled for the processor's widest
/// vectors (`pulp`'s runtime dispatch: the TMT mirror's 1476 displacements are checked on the
/// master's thread at every step; with the baseline's two-lane vectors that took 0.3 us).
fn all_finite(x: &[f64]) -> bool {
    struct Check<'a>(&'a [f64]);
    impl pulp::WithSimd for Check<'_> {
        type Output = bool;
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) -> bool {
            let mut lanes = [0.0f64; 16];
            let chunks = self.0.chunks_exact(16);
            let tail = chunks.remainder();
            for c in chunks {
                for (l, v) in lanes.iter_mut().zip(c) {
                    *l += 0.0 * v;
                }
            }
            let rest: f64 = tail.iter().map(|v| 0.0 * v).sum();
            (lanes.iter().sum::<f64>() + rest) == 0.0
        }
    }
    pulp::Arch::new().dispatch(Check(x))
}

#[cfg(test)]
mod tests {
    use super::all_finite;

    #[test]
    fn all_finite_finds_any_non_finite_value_at_any_position() {
        // The extremes of the finite values among ordinary ones.
        let edges = [
            0.0,
            -0.0,
            f64::MAX,
            f64::MIN,
            5e-324,
            -5e-324,
            f64::MIN_POSITIVE,
        ];
        for n in [0usize, 1, 7, 8, 9, 15, 16, 17, 33, 100] {
            let x: Vec<f64> = (0..n)
                .map(|k| match k % 3 {
                    0 => edges[(k / 3) % edges.len()],
                    _ => (k as f64 - 3.5) * 1e300,
                })
                .collect();
            assert!(all_finite(&x), "{n}");
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                for at in 0..n {
                    let mut y = x.clone();
                    y[at] = bad;
                    assert!(!all_finite(&y), "{n} {at} {bad}");
                }
            }
        }
    }
}
