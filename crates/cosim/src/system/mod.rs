//! A system of FMU components and the connections between them, built in code (or read from
//! SSP), and the master algorithm that runs it.
//!
//! # Scheduling
//!
//! The master advances with a fixed base communication step `h`. Component `c` steps every
//! `every[c]` base steps with step `every[c] * h` (multi-rate: e.g. the controller at 20 Hz,
//! wind at 100 Hz, segments and structure at 1 kHz with `h` = 1 ms); a slower component's last
//! step is cut to end at the stop time. Two orders:
//!
//! - **Jacobi** (the library's default): at a communication point every due component first
//!   receives the outputs all components had at that point, then all due components step, in
//!   parallel on rayon's pool when at least two of them take over
//!   [`SchedulerParams::parallel_min_seconds`] per step (a running mean); with one such
//!   component, it steps on the calling thread while the others step in turn on a worker when
//!   they add up to [`SchedulerParams::split_min_seconds`] and it outlasts them by
//!   [`SchedulerParams::wake_seconds`] (the worker's wake-up hides behind it); in turn otherwise
//!   (same results in every case). Results do not depend on the order
//!   of components; each connection carries a value one step old, which is the standard
//!   co-simulation delay (fmpy.ssp works the same way).
//! - **Gauss-Seidel**: due components step one after the other in the order they were added,
//!   each receiving the outputs its predecessors just produced: less delay along the order.
//!   **Look-ahead**: a component whose outputs nobody needs right away (the next due component
//!   does not read them, they are not recorded, and no other component is an instance of its
//!   FMU, whose library might keep global state) may step on a second thread while the
//!   master goes on with the next components, into the next base step if nothing reads it:
//!   its inputs are gathered at its turn, and it is waited for before anything that reads it
//!   (or its own next step, or the end of the run). Every component therefore receives exactly
//!   the values of the sequential order, bit for bit (tested); only the wall time changes. One
//!   component is in flight at a time, and only one taking at least
//!   [`SchedulerParams::lookahead_min_seconds`] per step (a running mean), so that handing it
//!   over pays. In the standard TMT system the edge sensors (read by the 20 Hz controller
//!   only) step while the master moves on to the optics and the next step's wind and mirror.
//!
//! The thresholds of these decisions are one parameter struct, [`SchedulerParams`] (its
//! [`Default`] holds the measured values; [`System::scheduler`] sets others); they change the
//! wall time only.
//!
//! Values move in bulk: per component and step one `fmi2SetReal` over all its connected inputs
//! and one `fmi2GetReal` over all its connected outputs, through buffers allocated once.
//!
//! # Set-up
//!
//! Components are instantiated and given their parameters in turn, then leave initialisation
//! mode (`fmi2ExitInitializationMode`, where FMUs typically build their models: the structure's
//! eigensolve, the wind screens) in parallel on rayon's pool, one instance per task: FMI 2.0
//! lets different instances be called from different threads, as Jacobi stepping already does.
//! The wall time of each component's set-up is reported ([`Simulation::component_setup_seconds`]).
//!
//! # Files
//!
//! - `definition.rs`: the system as described ([`System`], [`Component`], [`Connection`],
//!   [`Order`], [`Value`]).
//! - `wiring.rs`: the connection checks and the layout of the shared output buffer.
//! - `setup.rs`: [`Simulation::new`], phase by phase.
//! - `simulation.rs`: the state kept between steps and its accessors ([`Simulation`]).
//! - `step.rs`: the step semantics, what a communication step does in each order.
//! - `threads.rs`: the scheduler's thread policy beside it ([`SchedulerParams`], the
//!   look-ahead thread, the Jacobi threads).
//! - `run.rs`: the run loop and its results ([`run`], [`Results`], [`Timing`], [`Failure`]).

mod definition;
mod run;
mod setup;
mod simulation;
mod step;
mod threads;
mod wiring;

pub use definition::{Component, Connection, Order, System, Value};
pub use run::{Failure, Results, Timing, run};
pub use simulation::{Recorded, Simulation};
pub use threads::SchedulerParams;
