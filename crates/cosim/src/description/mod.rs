//! modelDescription.xml of an FMI 2.0 Co-Simulation FMU, parsed (quick-xml + serde) into typed
//! structures and checked against the rules of the standard that an importer relies on.
//!
//! The parse keeps what a master needs: the co-simulation capabilities, the default experiment,
//! every scalar variable (type, value reference, causality, variability, initial, start, unit) and
//! the model structure (outputs and their dependencies). A variable's unit is its `unit` attribute,
//! else the unit of its `declaredType` in `TypeDefinitions` (the master compares the units of
//! connected variables by name; `UnitDefinitions` are not read). Attributes are read as strings and
//! converted here, so that an error names the variable and the attribute.

use std::collections::HashMap;
use std::path::Path;

use crate::error::{CosimError, Result};

mod raw;

use raw::{RawModelDescription, RawScalarVariable, RawUnknownList};

pub use fmi_sys::fmi2::{Causality, Initial, Variability};

/// The type of a variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VarType {
    /// fmi2Real.
    Real,
    /// fmi2Integer.
    Integer,
    /// fmi2Boolean.
    Boolean,
    /// fmi2String.
    String,
    /// Enumeration (set and got as fmi2Integer).
    Enumeration,
}

/// A start value.
#[derive(Debug, Clone, PartialEq)]
pub enum Start {
    /// Real.
    Real(f64),
    /// Integer or enumeration.
    Integer(i32),
    /// Boolean.
    Boolean(bool),
    /// String.
    String(String),
}

/// One scalar variable.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarVariable {
    /// Its name (structured names look like `z[12]`).
    pub name: String,
    /// Value reference (unique per type).
    pub value_reference: u32,
    /// Description, if any.
    pub description: Option<String>,
    /// Causality.
    pub causality: Causality,
    /// Variability.
    pub variability: Variability,
    /// Initial, if given.
    pub initial: Option<Initial>,
    /// Type.
    pub var_type: VarType,
    /// Start value, if given.
    pub start: Option<Start>,
    /// Unit (Real), if given: the `unit` attribute, else the unit of its declared type.
    pub unit: Option<String>,
    /// The `declaredType` (a SimpleType of TypeDefinitions), if given.
    pub declared_type: Option<String>,
}

/// An entry of ModelStructure/Outputs or InitialUnknowns.
#[derive(Debug, Clone, PartialEq)]
pub struct Unknown {
    /// Index into [`ModelDescription::variables`] (0-based here; 1-based in the XML).
    pub variable: usize,
    /// The variables it depends on directly (0-based indices); `None` when the attribute is
    /// absent (then it may depend on every input).
    pub dependencies: Option<Vec<usize>>,
}

/// The Co-Simulation capabilities.
#[derive(Debug, Clone, PartialEq)]
pub struct CoSimulation {
    /// Name of the shared library (without extension) and prefix of nothing in FMI 2.0.
    pub model_identifier: String,
    /// canHandleVariableCommunicationStepSize.
    pub can_handle_variable_step: bool,
    /// canBeInstantiatedOnlyOncePerProcess.
    pub instantiated_only_once_per_process: bool,
    /// canGetAndSetFMUstate.
    pub can_get_and_set_state: bool,
    /// canSerializeFMUstate.
    pub can_serialize_state: bool,
    /// needsExecutionTool.
    pub needs_execution_tool: bool,
}

/// The default experiment.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DefaultExperiment {
    /// Start time (s).
    pub start_time: Option<f64>,
    /// Stop time (s).
    pub stop_time: Option<f64>,
    /// Tolerance.
    pub tolerance: Option<f64>,
    /// Step size (s).
    pub step_size: Option<f64>,
}

/// A parsed and checked modelDescription.xml.
#[derive(Debug, Clone)]
pub struct ModelDescription {
    /// "2.0".
    pub fmi_version: String,
    /// modelName.
    pub model_name: String,
    /// The GUID the binary checks at instantiation.
    pub guid: String,
    /// Description.
    pub description: Option<String>,
    /// generationTool.
    pub generation_tool: Option<String>,
    /// "flat" or "structured".
    pub naming_convention: String,
    /// Co-Simulation capabilities.
    pub co_simulation: CoSimulation,
    /// DefaultExperiment, if present.
    pub default_experiment: DefaultExperiment,
    /// Every scalar variable, in document order.
    pub variables: Vec<ScalarVariable>,
    /// ModelStructure/Outputs.
    pub outputs: Vec<Unknown>,
    /// ModelStructure/InitialUnknowns.
    pub initial_unknowns: Vec<Unknown>,
    by_name: HashMap<String, usize>,
}

fn parse_bool(s: &str) -> Option<bool> {
    match s.trim() {
        "true" | "1" => Some(true),
        "false" | "0" => Some(false),
        _ => None,
    }
}

struct Ctx<'a> {
    file: &'a Path,
}

impl Ctx<'_> {
    fn err(&self, reason: impl Into<String>) -> CosimError {
        CosimError::Xml {
            file: self.file.to_path_buf(),
            reason: reason.into(),
        }
    }

    fn flag(&self, what: &str, v: &Option<String>) -> Result<bool> {
        match v {
            None => Ok(false),
            Some(s) => {
                parse_bool(s).ok_or_else(|| self.err(format!("{what} = {s:?} is not a boolean")))
            }
        }
    }

    fn real(&self, what: &str, v: &Option<String>) -> Result<Option<f64>> {
        match v {
            None => Ok(None),
            Some(s) => s
                .trim()
                .parse::<f64>()
                .map(Some)
                .map_err(|_| self.err(format!("{what} = {s:?} is not a number"))),
        }
    }
}

fn is_c_identifier(s: &str) -> bool {
    let mut chars = s.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// The entries of ModelStructure's `what` list (Outputs or InitialUnknowns), their 1-based
/// indices checked against the `n_vars` variables and made 0-based.
fn unknowns(
    ctx: &Ctx<'_>,
    list: Option<RawUnknownList>,
    what: &str,
    n_vars: usize,
) -> Result<Vec<Unknown>> {
    let mut out = Vec::new();
    for u in list.map(|l| l.unknowns).unwrap_or_default() {
        let index = u
            .index
            .as_deref()
            .and_then(|s| s.trim().parse::<usize>().ok())
            .filter(|&i| i >= 1 && i <= n_vars)
            .ok_or_else(|| {
                ctx.err(format!(
                    "{what}: Unknown index {:?} is not a variable index 1..{}",
                    u.index, n_vars
                ))
            })?;
        let dependencies = match u.dependencies.as_deref() {
            None => None,
            Some(d) => Some(
                d.split_whitespace()
                    .map(|s| {
                        s.parse::<usize>()
                            .ok()
                            .filter(|&i| i >= 1 && i <= n_vars)
                            .map(|i| i - 1)
                            .ok_or_else(|| {
                                ctx.err(format!(
                                    "{what}: dependency {s:?} of variable {index} is \
                                         not a variable index"
                                ))
                            })
                    })
                    .collect::<Result<Vec<usize>>>()?,
            ),
        };
        out.push(Unknown {
            variable: index - 1,
            dependencies,
        });
    }
    Ok(out)
}

impl ModelDescription {
    /// Parses `xml`, read from `file` (named in errors).
    ///
    /// # Errors
    /// [`CosimError::Xml`] for malformed XML or a rule of FMI 2.0 Co-Simulation violated (named).
    pub fn parse(xml: &str, file: &Path) -> Result<Self> {
        let ctx = Ctx { file };
        let raw: RawModelDescription = quick_xml::de::from_str(xml)
            .map_err(|e| ctx.err(format!("malformed modelDescription: {e}")))?;
        let fmi_version = raw
            .fmi_version
            .ok_or_else(|| ctx.err("fmiModelDescription has no fmiVersion"))?;
        if fmi_version.trim() != "2.0" {
            return Err(ctx.err(format!(
                "fmiVersion = {fmi_version:?}: only FMI 2.0 is supported"
            )));
        }
        let model_name = raw
            .model_name
            .ok_or_else(|| ctx.err("fmiModelDescription has no modelName"))?;
        let guid = raw
            .guid
            .filter(|g| !g.trim().is_empty())
            .ok_or_else(|| ctx.err("fmiModelDescription has no guid"))?;
        let cs = raw.co_simulation.ok_or_else(|| {
            ctx.err("no <CoSimulation> element: not a Co-Simulation FMU (Model Exchange only)")
        })?;
        let model_identifier = cs
            .model_identifier
            .ok_or_else(|| ctx.err("<CoSimulation> has no modelIdentifier"))?;
        if !is_c_identifier(&model_identifier) {
            return Err(ctx.err(format!(
                "modelIdentifier = {model_identifier:?} is not a valid C identifier"
            )));
        }
        let co_simulation = CoSimulation {
            model_identifier,
            can_handle_variable_step: ctx.flag(
                "canHandleVariableCommunicationStepSize",
                &cs.can_handle_variable_step,
            )?,
            instantiated_only_once_per_process: ctx
                .flag("canBeInstantiatedOnlyOncePerProcess", &cs.once_per_process)?,
            can_get_and_set_state: ctx.flag("canGetAndSetFMUstate", &cs.can_get_set_state)?,
            can_serialize_state: ctx.flag("canSerializeFMUstate", &cs.can_serialize_state)?,
            needs_execution_tool: ctx.flag("needsExecutionTool", &cs.needs_execution_tool)?,
        };
        let default_experiment = match &raw.default_experiment {
            None => DefaultExperiment::default(),
            Some(d) => DefaultExperiment {
                start_time: ctx.real("DefaultExperiment startTime", &d.start_time)?,
                stop_time: ctx.real("DefaultExperiment stopTime", &d.stop_time)?,
                tolerance: ctx.real("DefaultExperiment tolerance", &d.tolerance)?,
                step_size: ctx.real("DefaultExperiment stepSize", &d.step_size)?,
            },
        };
        // The unit of each SimpleType that declares a Real unit.
        let type_units: HashMap<String, String> = raw
            .type_definitions
            .map(|t| t.types)
            .unwrap_or_default()
            .into_iter()
            .filter_map(|t| Some((t.name?, t.real?.unit?)))
            .collect();
        let raw_vars = raw
            .model_variables
            .ok_or_else(|| ctx.err("no <ModelVariables> element"))?
            .variables;
        let mut variables = Vec::with_capacity(raw_vars.len());
        let mut by_name = HashMap::with_capacity(raw_vars.len());
        for (k, rv) in raw_vars.into_iter().enumerate() {
            let v = Self::variable(&ctx, k, rv, &type_units)?;
            if by_name.insert(v.name.clone(), k).is_some() {
                return Err(ctx.err(format!("variable name {:?} is used twice", v.name)));
            }
            variables.push(v);
        }
        let (outputs, initial_unknowns) = match raw.model_structure {
            None => (Vec::new(), Vec::new()),
            Some(ms) => (
                unknowns(&ctx, ms.outputs, "ModelStructure/Outputs", variables.len())?,
                unknowns(
                    &ctx,
                    ms.initial_unknowns,
                    "ModelStructure/InitialUnknowns",
                    variables.len(),
                )?,
            ),
        };
        // Outputs lists exactly the outputs.
        let declared: Vec<usize> = (0..variables.len())
            .filter(|&i| variables[i].causality == Causality::Output)
            .collect();
        let mut listed: Vec<usize> = outputs.iter().map(|u| u.variable).collect();
        listed.sort_unstable();
        if listed != declared {
            return Err(ctx.err(format!(
                "ModelStructure/Outputs lists {} variables but {} have causality=\"output\"",
                listed.len(),
                declared.len()
            )));
        }
        Ok(Self {
            fmi_version,
            model_name,
            guid,
            description: raw.description,
            generation_tool: raw.generation_tool,
            naming_convention: raw.naming_convention.unwrap_or_else(|| "flat".into()),
            co_simulation,
            default_experiment,
            variables,
            outputs,
            initial_unknowns,
            by_name,
        })
    }

    fn variable(
        ctx: &Ctx<'_>,
        k: usize,
        rv: RawScalarVariable,
        type_units: &HashMap<String, String>,
    ) -> Result<ScalarVariable> {
        let name = rv
            .name
            .ok_or_else(|| ctx.err(format!("ScalarVariable #{} has no name", k + 1)))?;
        let e = |what: String| ctx.err(format!("variable {name:?}: {what}"));
        let value_reference = rv
            .value_reference
            .as_deref()
            .and_then(|s| s.trim().parse::<u32>().ok())
            .ok_or_else(|| {
                e(format!(
                    "valueReference {:?} is not a u32",
                    rv.value_reference
                ))
            })?;
        let unknown = |name: &str, text: &str| e(format!("unknown {name} {text:?}"));
        let text = rv.causality.as_deref().unwrap_or("local");
        let causality = Causality::from_xml(text).ok_or_else(|| unknown("causality", text))?;
        let text = rv.variability.as_deref().unwrap_or("continuous");
        let variability =
            Variability::from_xml(text).ok_or_else(|| unknown("variability", text))?;
        let initial = match rv.initial.as_deref() {
            None => None,
            Some(text) => Some(Initial::from_xml(text).ok_or_else(|| unknown("initial", text))?),
        };
        let typed = [
            (VarType::Real, rv.real),
            (VarType::Integer, rv.integer),
            (VarType::Boolean, rv.boolean),
            (VarType::String, rv.string),
            (VarType::Enumeration, rv.enumeration),
        ];
        let mut found = typed.into_iter().filter_map(|(t, r)| r.map(|r| (t, r)));
        let (var_type, t) = found.next().ok_or_else(|| {
            e("no type element (Real, Integer, Boolean, String, Enumeration)".into())
        })?;
        if found.next().is_some() {
            return Err(e("more than one type element".into()));
        }
        if variability == Variability::Continuous && var_type != VarType::Real {
            return Err(e("only Real variables may be continuous".into()));
        }
        let start = match &t.start {
            None => None,
            Some(s) => Some(match var_type {
                VarType::Real => Start::Real(
                    s.trim()
                        .parse()
                        .map_err(|_| e(format!("start {s:?} is not a number")))?,
                ),
                VarType::Integer | VarType::Enumeration => Start::Integer(
                    s.trim()
                        .parse()
                        .map_err(|_| e(format!("start {s:?} is not an integer")))?,
                ),
                VarType::Boolean => Start::Boolean(
                    parse_bool(s).ok_or_else(|| e(format!("start {s:?} is not a boolean")))?,
                ),
                VarType::String => Start::String(s.clone()),
            }),
        };
        if causality == Causality::Input && start.is_none() {
            return Err(e("an input needs a start value".into()));
        }
        if initial == Some(Initial::Calculated) && start.is_some() {
            return Err(e("initial=\"calculated\" forbids a start value".into()));
        }
        Ok(ScalarVariable {
            name,
            value_reference,
            description: rv.description,
            causality,
            variability,
            initial,
            var_type,
            start,
            unit: t.unit.or_else(|| {
                t.declared_type
                    .as_ref()
                    .and_then(|d| type_units.get(d).cloned())
            }),
            declared_type: t.declared_type,
        })
    }

    /// Reads and parses `path`.
    ///
    /// # Errors
    /// [`CosimError::Io`] if the file cannot be read, else as [`Self::parse`].
    pub fn from_file(path: &Path) -> Result<Self> {
        let xml = std::fs::read_to_string(path).map_err(crate::error::io(path))?;
        Self::parse(&xml, path)
    }

    /// The variable called `name`.
    pub fn variable_by_name(&self, name: &str) -> Option<&ScalarVariable> {
        self.by_name.get(name).map(|&i| &self.variables[i])
    }

    /// Index of the variable called `name`.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        self.by_name.get(name).copied()
    }

    /// A signal by name: the scalar `name`, or the array `name[1]`, `name[2]`, ... in index
    /// order (structured naming). `None` if neither exists.
    pub fn signal(&self, name: &str) -> Option<Vec<&ScalarVariable>> {
        if let Some(v) = self.variable_by_name(name) {
            return Some(vec![v]);
        }
        let mut out = Vec::new();
        while let Some(v) = self.variable_by_name(&format!("{name}[{}]", out.len() + 1)) {
            out.push(v);
        }
        (!out.is_empty()).then_some(out)
    }
}
