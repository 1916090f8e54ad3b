//! A system of FMU components and the connections between them, built in code (or read from
//! SSP), and the master algorithm that runs it.
//!
//! # Scheduling
//!
//! The master advances with a fixed base communication step `h`. Component `c` steps every
//! `every[c]` base steps with step `every[c] * h` (multi-rate: e.g. the controller at 20 Hz,
//! wind at 100 Hz, segments and structure at 1 kHz with `h` = 1 ms); a slower component's last
//! step is cut to end at the stop time.
//!
//! **Timing (FMI 2.0).** The outputs a component gives after `fmi2DoStep(t, H)` are its
//! outputs at `t + H`, and no other component sees them before then; its initial outputs
//! (after initialisation) are those at the start time. A row recorded at `t_k` shows every
//! output's latest value for a time no later than `t_k`. Two orders decide what "before" means
//! within a base step `[t_k, t_k + h]`:
//!
//! - **Jacobi**: every due component steps on the outputs for times up to `t_k`, in parallel
//!   when that pays (below). Each connection carries a value one base step old (the standard
//!   co-simulation delay; fmpy.ssp works the same way), and results do not depend on the order
//!   of components.
//! - **Gauss-Seidel**: the due components step one after the other in the order they were
//!   added, each on the outputs for times up to `t_k + h` that exist when its turn comes: those
//!   its predecessors just produced at `t_k + h` (less delay along the order), and those a
//!   slower component produced earlier for `t_k + h`.
//!
//! A two-rate example, `h` = 1 ms, a controller `C` stepping every 3 base steps feeding a
//! segment `S` stepping every base step (`C` added first):
//!
//! ```text
//! base step     0      1      2      3      4      5      6
//! C steps       [0 -------------> 3)  [3 -------------> 6)
//! C's outputs   init   init   init   C(3)   C(3)   C(3)   C(6)   <- visible at t_k (row t_k)
//! S (Jacobi)    init   init   init   C(3)   C(3)   C(3)   C(6)   <- what S's step from t_k gets
//! S (G.-S.)     init   init   C(3)   C(3)   C(3)   C(6)   C(6)   <- from t_k: values up to t_k + h
//! ```
//!
//! The initial outputs feed the first step; [`System::zero_start`] starts every connection at
//! 0 instead (fmpy.ssp's convention, for comparisons with it).
//!
//! **Threads.** In Jacobi order the due components step in parallel on rayon's pool when at
//! least two of them take over [`SchedulerParams::parallel_min_seconds`] per step (a running
//! mean); with one such component, it steps on the calling thread while the others step in turn
//! on a worker when they add up to [`SchedulerParams::split_min_seconds`] and it outlasts them by
//! [`SchedulerParams::wake_seconds`] (the worker's wake-up hides behind it); in turn otherwise
//! (same results in every case).
//!
//! **The look-ahead thread** (started with the simulation unless [`System::no_lookahead`]) takes
//! steps that nothing needs right away, so that they run beside the master's:
//!
//! - In Gauss-Seidel order, a component whose outputs the next turn does not read (and that is
//!   the only instance of its FMU, whose library might keep global state) may step there while
//!   the master goes on with the next components, into the next base step if nothing reads
//!   it: its inputs are gathered at its turn, and it is waited for before anything that reads
//!   it (or its own next step, or the end of the run).
//! - In both orders, a **sink** (a component no other one reads, stepping every base step,
//!   the only instance of its FMU, with Real inputs only: the optics metrics of the standard
//!   systems) is kept there: at each of its turns the master sends its inputs (the outputs of
//!   the communication point in Jacobi order, the newest outputs in Gauss-Seidel order) and goes on. Its steps
//!   queue there one after the other, so a step that takes many base steps now and then (the
//!   optics' PSSN at 10 Hz, about 1 ms) is caught up over the next ones instead of making the
//!   master wait; the master waits only when 256 messages are in flight.
//!
//! The Real inputs of a step sent there are copied into buffers the other core read last, by
//! one of two ways, whichever the master measured cheaper in its latest trial (every 4096
//! such copies; `ports::CopyTrial`): past the master's caches (non-temporal stores: the other
//! core reads them from memory, and the master does not wait for lines that core holds; much
//! the cheaper on the AMD VM of the project's earlier measurements) or a plain copy (cheaper
//! on an Intel VM, where the non-temporal stores' fence waits longer than the lines take to
//! come back). Either way the same values cross. Those from a component whose outputs still
//! wait in its ports (below) come straight from there. A kept sink reading some of the same outputs as the component sent
//! there just before it takes those from that component's inputs, which the thread keeps
//! (the memo), when the outputs have not changed since: in the TMT systems the mirror's 1476
//! displacements cross once per step for both the edge sensors and the optics
//! ([`Simulation::lookahead_memo_steps`] counts those steps).
//!
//! Messages and replies go through a wait-free ring of one sender and one receiver (`rtrb`):
//! a send is a plain store, not a locked instruction that would wait for the message's lines to
//! reach the other core. A thread that has polled for a while sleeps and is woken by the next
//! message (`queue.rs`).
//!
//! Its steps run in the order they were sent and their replies come back in that order. Only
//! components taking at least [`SchedulerParams::lookahead_min_seconds`] per step (a running
//! mean) go there, so that handing one over pays. A recorded component may go too when [`run`]
//! or [`run_into`] drives the simulation: the rows sampled while its step is there are held (as
//! every row after the oldest step there began, so that a failure there keeps the rows of the
//! sequential order) and get its outputs when they come back. Every component therefore
//! receives exactly the values of the sequential order, and every row shows them, bit for bit
//! (tested); only the wall time changes. In the standard TMT system the edge sensors (read by
//! the 20 Hz controller only) step there while the master moves on, and the optics are kept
//! there. [`Simulation::step`] driven directly keeps recorded components on the master's
//! thread, so that [`Simulation::recorded_values`] is current after every step.
//!
//! **Whether the look-ahead thread pays is measured.** It pays while the components on the
//! master's thread leave the second core free, and costs when they use it themselves (the TMT
//! mirror with 1000 retained modes splits its products with a thread of its own: the step loop
//! ran about a tenth slower with the look-ahead thread beside it). Every
//! [`SchedulerParams::lookahead_trial_every`] base steps the master times blocks of base steps
//! with and without it and keeps the faster until the next trial (`trial.rs`;
//! [`Simulation::lookahead_trials`] and [`Timing::lookahead_trials`] report each); an
//! explicit [`Simulation::set_lookahead`] ends the trials.
//!
//! The thresholds of these decisions are one parameter struct, [`SchedulerParams`] (its
//! [`Default`] holds the measured values; [`System::scheduler`] sets others); they change the
//! wall time only.
//!
//! Values move in bulk: per component, step and kind of value (Real, Integer and enumeration,
//! Boolean, String) one `fmi2Set*` over all its connected inputs and one `fmi2Get*` over all
//! its connected or recorded outputs, through buffers allocated once (`ports.rs`). In
//! Gauss-Seidel order the outputs of a component that steps every base step and has none
//! recorded stay in its ports until a reader's turn comes (each step's replace the last's
//! before anyone else could read those): the TMT edge sensors' 2772 readings, taken on the
//! look-ahead thread, are copied into the shared buffer for the 20 Hz controller only, not at
//! every step.
//!
//! **Unchanged inputs are not set again.** An FMU keeps an input's value until it is set
//! (FMI 2.0), so a component's Real inputs that are set straight from the shared buffer (a
//! few arrays of consecutive connections) are set again only when their source's visible
//! outputs have changed since (each component counts those changes): the TMT mirror's wind
//! forces, 1476 values from the 100 Hz wind, are set at every tenth step, the controller's
//! command at every fiftieth. [`System::set_unchanged_inputs`] (`m1cs run
//! --set-unchanged-inputs`) sets every input at every step, as fmpy's masters do, for FMUs
//! that forget their inputs.
//!
//! # Set-up
//!
//! Components are instantiated and given their parameters in turn and enter initialisation
//! mode; the values of direct-feedthrough chains are then propagated in topological order
//! (`init.rs`: an algebraic loop is an error naming it); then the components leave
//! initialisation mode (`fmi2ExitInitializationMode`, where FMUs typically build their models:
//! the structure's eigensolve, the wind screens) in parallel on rayon's pool, one instance per
//! task: FMI 2.0 lets different instances be called from different threads, as Jacobi stepping
//! already does. The wall time of each component's set-up is reported
//! ([`Simulation::component_setup_seconds`]).
//!
//! # Ending
//!
//! A component whose `fmi2DoStep` returns `fmi2Discard` and which answers
//! `fmi2GetBooleanStatus(fmi2Terminated)` with true ends the simulation: [`run`] stops at the
//! last communication point reached, with its results and [`Results::ended`] naming it. Any
//! other discard or error stops the run as a failure ([`Failure`]).
//!
//! # Files
//!
//! - `definition.rs`: the system as described ([`System`], [`Component`], [`Connection`],
//!   [`Order`], [`Value`]).
//! - `wiring.rs`: the connection checks, the recorded signals and the layout of the shared
//!   output buffers.
//! - `ports.rs`: the shared buffers, one per kind of value, and each component's ports.
//! - `init.rs`: the propagation through direct feedthrough in initialisation mode.
//! - `setup.rs`: [`Simulation::new`], phase by phase.
//! - `simulation.rs`: the state kept between steps and its accessors ([`Simulation`]).
//! - `step.rs`: the step semantics, what a communication step does in each order.
//! - `threads.rs`: the scheduler's thread policy beside it ([`SchedulerParams`], the
//!   look-ahead thread, the Jacobi threads).
//! - `run.rs`: the run loop and its results ([`run`], [`Results`], [`Timing`], [`Failure`]).

mod background;
mod definition;
mod init;
mod ports;
mod queue;
mod run;
mod setup;
mod simulation;
mod step;
mod threads;
mod trial;
mod wiring;

pub use background::BackgroundSink;
pub use definition::{Component, Connection, Order, System, Value};
pub use ports::{CopyWay, copy_for_other_core};
pub use run::{CsvSink, Ended, Failure, Report, Results, RunOptions, Sink, Timing, run, run_into};
pub use simulation::{Recorded, Simulation};
pub use threads::SchedulerParams;
pub use trial::LookaheadTrial;
pub use wiring::record_selects;
