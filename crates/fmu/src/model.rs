//! The contract between a physical model and the FMI runtime.

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

/// A co-simulation model. Implementations hold handles into their [`VariableTable`] and read
/// parameters and inputs from, and write outputs to, the [`Values`] store the runtime owns.
///
/// Every method that can fail must leave `self` unchanged when it returns an error.
pub trait Model: Clone + Send + Serialize + DeserializeOwned + 'static {
    /// Static facts.
    const INFO: ModelInfo;

    /// The variants this model is packaged for (e.g. mirror layouts); one .fmu each.
    fn variants() -> Vec<String>;

    /// The variable table and a fresh model for one variant.
    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError>;

    /// Extra files for the archive's resources/ folder, as (relative path, bytes).
    fn resources(_variant: &str) -> Vec<(String, Vec<u8>)> {
        Vec::new()
    }

    /// Tells the model where the unpacked archive's resources/ folder is (decoded from the
    /// fmuResourceLocation given to fmi2Instantiate), when the importer passed one. Called once,
    /// right after [`Model::new`], before any parameter is set. The default ignores it.
    fn set_resource_dir(&mut self, _dir: &std::path::Path) {}

    /// Reads parameters, checks their combination, prepares the computation and writes the
    /// initial outputs. Called when outputs are read during initialisation mode and at
    /// fmi2ExitInitializationMode.
    fn initialize(&mut self, values: &mut Values, start_time: f64) -> Result<(), FmuError>;

    /// Recomputes the outputs that depend directly on inputs, after inputs were set.
    fn update_outputs(&mut self, values: &mut Values) -> Result<(), FmuError>;

    /// Advances from `t` to `t + h` with the inputs held, then writes the outputs at `t + h`.
    fn do_step(&mut self, t: f64, h: f64, values: &mut Values) -> Result<(), FmuError>;
}
