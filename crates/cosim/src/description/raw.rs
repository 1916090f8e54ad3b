//! The raw serde structure of modelDescription.xml: the elements and attributes the parse
//! keeps, every attribute as a string (converted and checked in the parent module, so that an
//! error names the variable and the attribute). Unknown elements and attributes are ignored.

use serde::Deserialize;

#[derive(Deserialize)]
pub(super) struct RawModelDescription {
    #[serde(rename = "@fmiVersion")]
    pub(super) fmi_version: Option<String>,
    #[serde(rename = "@modelName")]
    pub(super) model_name: Option<String>,
    #[serde(rename = "@guid")]
    pub(super) guid: Option<String>,
    #[serde(rename = "@description")]
    pub(super) description: Option<String>,
    #[serde(rename = "@generationTool")]
    pub(super) generation_tool: Option<String>,
    #[serde(rename = "@variableNamingConvention")]
    pub(super) naming_convention: Option<String>,
    #[serde(rename = "CoSimulation")]
    pub(super) co_simulation: Option<RawCoSimulation>,
    #[serde(rename = "DefaultExperiment")]
    pub(super) default_experiment: Option<RawDefaultExperiment>,
    #[serde(rename = "TypeDefinitions")]
    pub(super) type_definitions: Option<RawTypeDefinitions>,
    #[serde(rename = "ModelVariables")]
    pub(super) model_variables: Option<RawModelVariables>,
    #[serde(rename = "ModelStructure")]
    pub(super) model_structure: Option<RawModelStructure>,
}

#[derive(Deserialize)]
pub(super) struct RawCoSimulation {
    #[serde(rename = "@modelIdentifier")]
    pub(super) model_identifier: Option<String>,
    #[serde(rename = "@needsExecutionTool")]
    pub(super) needs_execution_tool: Option<String>,
    #[serde(rename = "@canHandleVariableCommunicationStepSize")]
    pub(super) can_handle_variable_step: Option<String>,
    #[serde(rename = "@canBeInstantiatedOnlyOncePerProcess")]
    pub(super) once_per_process: Option<String>,
    #[serde(rename = "@canGetAndSetFMUstate")]
    pub(super) can_get_set_state: Option<String>,
    #[serde(rename = "@canSerializeFMUstate")]
    pub(super) can_serialize_state: Option<String>,
}

#[derive(Deserialize)]
pub(super) struct RawDefaultExperiment {
    #[serde(rename = "@startTime")]
    pub(super) start_time: Option<String>,
    #[serde(rename = "@stopTime")]
    pub(super) stop_time: Option<String>,
    #[serde(rename = "@tolerance")]
    pub(super) tolerance: Option<String>,
    #[serde(rename = "@stepSize")]
    pub(super) step_size: Option<String>,
}

#[derive(Deserialize)]
pub(super) struct RawTypeDefinitions {
    #[serde(rename = "SimpleType", default)]
    pub(super) types: Vec<RawSimpleType>,
}

#[derive(Deserialize)]
pub(super) struct RawSimpleType {
    #[serde(rename = "@name")]
    pub(super) name: Option<String>,
    #[serde(rename = "Real")]
    pub(super) real: Option<RawRealType>,
}

#[derive(Deserialize)]
pub(super) struct RawRealType {
    #[serde(rename = "@unit")]
    pub(super) unit: Option<String>,
}

#[derive(Deserialize)]
pub(super) struct RawModelVariables {
    #[serde(rename = "ScalarVariable", default)]
    pub(super) variables: Vec<RawScalarVariable>,
}

#[derive(Deserialize)]
pub(super) struct RawTyped {
    #[serde(rename = "@start")]
    pub(super) start: Option<String>,
    #[serde(rename = "@unit")]
    pub(super) unit: Option<String>,
    #[serde(rename = "@declaredType")]
    pub(super) declared_type: Option<String>,
}

#[derive(Deserialize)]
pub(super) struct RawScalarVariable {
    #[serde(rename = "@name")]
    pub(super) name: Option<String>,
    #[serde(rename = "@valueReference")]
    pub(super) value_reference: Option<String>,
    #[serde(rename = "@description")]
    pub(super) description: Option<String>,
    #[serde(rename = "@causality")]
    pub(super) causality: Option<String>,
    #[serde(rename = "@variability")]
    pub(super) variability: Option<String>,
    #[serde(rename = "@initial")]
    pub(super) initial: Option<String>,
    #[serde(rename = "Real")]
    pub(super) real: Option<RawTyped>,
    #[serde(rename = "Integer")]
    pub(super) integer: Option<RawTyped>,
    #[serde(rename = "Boolean")]
    pub(super) boolean: Option<RawTyped>,
    #[serde(rename = "String")]
    pub(super) string: Option<RawTyped>,
    #[serde(rename = "Enumeration")]
    pub(super) enumeration: Option<RawTyped>,
}

#[derive(Deserialize)]
pub(super) struct RawModelStructure {
    #[serde(rename = "Outputs")]
    pub(super) outputs: Option<RawUnknownList>,
    #[serde(rename = "InitialUnknowns")]
    pub(super) initial_unknowns: Option<RawUnknownList>,
}

#[derive(Deserialize)]
pub(super) struct RawUnknownList {
    #[serde(rename = "Unknown", default)]
    pub(super) unknowns: Vec<RawUnknown>,
}

#[derive(Deserialize)]
pub(super) struct RawUnknown {
    #[serde(rename = "@index")]
    pub(super) index: Option<String>,
    #[serde(rename = "@dependencies")]
    pub(super) dependencies: Option<String>,
}
