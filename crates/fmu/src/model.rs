//! The contract between a physical model and the FMI runtime, as types: a [`Model`] is the
//! configured model of one packaged variant (its variable table, the handles into it, the
//! resources); [`Model::initialize`] reads the parameters and returns the [`Running`] model,
//! the only thing that steps. The runtime ([`crate::Instance`]) holds the running model from
//! fmi2ExitInitializationMode to fmi2Reset, so a wiring crate cannot step or read outputs of
//! a model that was not initialised, and needs no `Option` of its own for it.

use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::error::FmuError;
use crate::variables::{Values, VariableTable};

/// Static facts about a model, the same for every packaged variant.
#[derive(Debug, Clone, Copy)]
pub struct ModelInfo {
    /// modelIdentifier: the shared library's name (`<id>.so`) and the FMU's file name.
    pub model_identifier: &'static str,
    /// modelName shown by importers.
    pub model_name: &'static str,
    /// One-line description.
    pub description: &'static str,
    /// An HTML fragment for documentation/index.html (equations, units, defaults).
    pub documentation: &'static str,
    /// DefaultExperiment stopTime (s).
    pub default_stop_time: f64,
    /// DefaultExperiment stepSize (s): the communication step importers use by default.
    pub default_step: f64,
}

/// A co-simulation model as configured: the variable table's handles and whatever is fixed at
/// instantiation. [`Model::initialize`] turns it, with the parameters in the [`Values`] store
/// the runtime owns, into the [`Running`] model.
pub trait Model: Send + 'static {
    /// Static facts.
    const INFO: ModelInfo;

    /// The initialised model: steps and recomputes outputs.
    type Running: Running;

    /// The variants this model is packaged for (e.g. mirror layouts); one .fmu each.
    fn variants() -> Vec<String>;

    /// The variable table and a fresh model for one variant.
    ///
    /// # Errors
    /// An unknown variant, or a table that does not build.
    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError>
    where
        Self: Sized;

    /// Extra files for the archive's resources/ folder, as (relative path, bytes).
    fn resources(_variant: &str) -> Vec<(String, Vec<u8>)> {
        Vec::new()
    }

    /// Tells the model where the unpacked archive's resources/ folder is (decoded from the
    /// fmuResourceLocation given to fmi2Instantiate), when the importer passed one. Called once,
    /// right after [`Model::new`], before any parameter is set. The default ignores it.
    fn set_resource_dir(&mut self, _dir: &std::path::Path) {}

    /// Reads the parameters, checks their combination, prepares the computation, writes the
    /// initial outputs (and calculated parameters) and returns the running model. Called at
    /// fmi2ExitInitializationMode, and when outputs are read during initialisation mode (that
    /// model is kept for fmi2ExitInitializationMode if no value is set in between; any set
    /// builds it again).
    ///
    /// # Errors
    /// A parameter or a combination of parameters the model cannot run with, naming it.
    fn initialize(&self, values: &mut Values, start_time: f64) -> Result<Self::Running, FmuError>;
}

/// An initialised model. Every method that can fail must leave `self` unchanged when it
/// returns an error. It is cloned and serialised for fmi2GetFMUstate and
/// fmi2SerializeFMUstate.
pub trait Running: Clone + Send + Serialize + DeserializeOwned + 'static {
    /// Recomputes the outputs that depend directly on inputs, after inputs were set.
    ///
    /// # Errors
    /// The model cannot evaluate its outputs on these inputs.
    fn update_outputs(&mut self, values: &mut Values) -> Result<(), FmuError>;

    /// Advances from `t` to `t + h` with the inputs held, then writes the outputs at `t + h`.
    ///
    /// # Errors
    /// A step the model cannot take (its size, its inputs), naming the reason.
    fn do_step(&mut self, t: f64, h: f64, values: &mut Values) -> Result<(), FmuError>;

    /// Real outputs that [`Running::do_step`] leaves to be computed when they are read, as
    /// ranges of value references (none by default): outputs that cost real work and that a
    /// master often does not read at all. After a step the runtime calls
    /// [`Running::write_on_demand`] before the first read of any of them (`fmi2GetReal`), so
    /// an importer sees the FMI meaning unchanged: every output is that of the current state.
    fn on_demand(&self) -> &[std::ops::Range<u32>] {
        &[]
    }

    /// Writes the [`Running::on_demand`] outputs for the current state.
    ///
    /// # Errors
    /// The model cannot evaluate them.
    fn write_on_demand(&mut self, _values: &mut Values) -> Result<(), FmuError> {
        Ok(())
    }
}
