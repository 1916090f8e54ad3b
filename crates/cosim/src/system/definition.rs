//! The description of a system, as built in code (or read from SSP): its components with their
//! parameters and rates, the connections between their signals, and the experiment (times,
//! base step, order, scheduling parameters). Nothing here touches an FMU: the checks of the
//! connections against the model descriptions happen when the system is instantiated
//! (`wiring.rs`).

use std::path::PathBuf;

use super::threads::SchedulerParams;

/// A parameter value for a component.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// Real.
    Real(f64),
    /// Integer (or enumeration).
    Integer(i32),
    /// Boolean.
    Boolean(bool),
    /// String.
    String(String),
}

/// One component of a system.
#[derive(Debug, Clone)]
pub struct Component {
    /// Unique name.
    pub name: String,
    /// Its .fmu file.
    pub fmu: PathBuf,
    /// Parameter (or input start) values by variable name.
    pub parameters: Vec<(String, Value)>,
    /// Steps every `every` base steps (>= 1).
    pub every: usize,
}

/// A connection from an output signal to an input signal (scalars, or whole arrays by their
/// structured base name: `z` connects `z[1]..z[n]`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Connection {
    /// Source component.
    pub from: String,
    /// Source signal.
    pub output: String,
    /// Destination component.
    pub to: String,
    /// Destination signal.
    pub input: String,
}

/// Stepping order (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Order {
    /// All due components step in parallel on the values of the last communication point.
    #[default]
    Jacobi,
    /// Due components step in sequence, each on its predecessors' newest outputs.
    GaussSeidel,
}

/// A system: components, connections, experiment.
#[derive(Debug, Clone, Default)]
pub struct System {
    /// Components in order.
    pub components: Vec<Component>,
    /// Connections.
    pub connections: Vec<Connection>,
    /// Start time (s).
    pub start_time: f64,
    /// Stop time (s).
    pub stop_time: f64,
    /// Base communication step (s).
    pub step: f64,
    /// Stepping order.
    pub order: Order,
    /// Start every connection at 0 instead of the components' initial outputs (the convention
    /// of fmpy.ssp, for comparisons with it).
    pub zero_start: bool,
    /// Without the look-ahead thread (module docs): the same values, without its thread.
    pub no_lookahead: bool,
    /// Set every connected input at every step, as fmpy's masters do, also while its source's
    /// outputs have not changed: for FMUs that do not keep their inputs between steps as
    /// FMI 2.0 requires. Off by default: an input set straight from the master's buffer is
    /// set again only when its source's outputs have changed (module docs).
    pub set_unchanged_inputs: bool,
    /// The thresholds by which the master decides which steps go to other threads (the
    /// defaults unless set; they change the wall time only, never a value).
    pub scheduler: SchedulerParams,
}

impl System {
    /// An empty system running from 0 to `stop_time` with base step `step`.
    pub fn new(stop_time: f64, step: f64) -> Self {
        Self {
            stop_time,
            step,
            ..Self::default()
        }
    }

    /// Adds a component stepping every base step.
    pub fn component(mut self, name: &str, fmu: impl Into<PathBuf>) -> Self {
        self.components.push(Component {
            name: name.into(),
            fmu: fmu.into(),
            parameters: Vec::new(),
            every: 1,
        });
        self
    }

    /// Sets how many base steps the last added component's step spans.
    pub fn every(mut self, n: usize) -> Self {
        if let Some(c) = self.components.last_mut() {
            c.every = n;
        }
        self
    }

    /// Sets a parameter of the component called `component`.
    pub fn parameter(mut self, component: &str, name: &str, value: Value) -> Self {
        if let Some(c) = self.components.iter_mut().find(|c| c.name == component) {
            c.parameters.push((name.into(), value));
        }
        self
    }

    /// Connects `from.output` to `to.input` ("comp.signal" each).
    pub fn connect(mut self, from: &str, to: &str) -> Self {
        let split = |s: &str| {
            s.split_once('.')
                .map(|(a, b)| (a.to_string(), b.to_string()))
                .unwrap_or_else(|| (s.to_string(), String::new()))
        };
        let (f, o) = split(from);
        let (t, i) = split(to);
        self.connections.push(Connection {
            from: f,
            output: o,
            to: t,
            input: i,
        });
        self
    }

    /// Sets the stepping order.
    pub fn order(mut self, order: Order) -> Self {
        self.order = order;
        self
    }

    /// Sets the scheduler's thresholds ([`SchedulerParams`]; results do not depend on them).
    pub fn scheduler(mut self, params: SchedulerParams) -> Self {
        self.scheduler = params;
        self
    }
}
