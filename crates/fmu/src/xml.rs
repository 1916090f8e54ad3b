//! modelDescription.xml, generated from the variable table, and the GUID derived from what it is
//! generated from.

use quick_xml::Writer;
use quick_xml::events::{BytesDecl, BytesEnd, BytesStart, Event};
use sha2::{Digest, Sha256};
use std::collections::BTreeSet;
use std::io::Cursor;

use crate::model::ModelInfo;
use crate::variables::{
    Causality, Dependencies, Initial, VarType, Variable, VariableTable, start_text,
};

/// Log categories the FMUs understand (fmi2SetDebugLogging).
pub const LOG_CATEGORIES: [(&str, &str); 4] = [
    (
        "logStatusError",
        "Errors: bad calls, bad values, failed steps",
    ),
    ("logStatusWarning", "Warnings"),
    (
        "logStatusFatal",
        "Fatal errors: internal failures caught at the FMI boundary",
    ),
    ("logCalls", "Calls to the FMI functions (verbose)"),
];

/// The generating tool's name, written into the XML.
pub const GENERATION_TOOL: &str = concat!("m1cs ", env!("CARGO_PKG_VERSION"));

fn el<'a>(name: &'a str, attrs: &[(&str, &str)]) -> BytesStart<'a> {
    let mut e = BytesStart::new(name);
    for (k, v) in attrs {
        e.push_attribute((*k, *v));
    }
    e
}

struct Xml {
    w: Writer<Cursor<Vec<u8>>>,
}

impl Xml {
    // Writing into a Vec cannot fail; errors are ignored on purpose.
    fn open(&mut self, name: &str, attrs: &[(&str, &str)]) {
        let _ = self.w.write_event(Event::Start(el(name, attrs)));
    }
    fn empty(&mut self, name: &str, attrs: &[(&str, &str)]) {
        let _ = self.w.write_event(Event::Empty(el(name, attrs)));
    }
    fn close(&mut self, name: &str) {
        let _ = self.w.write_event(Event::End(BytesEnd::new(name)));
    }
}

/// The 1-based indices, in ModelVariables, of every scalar of each variable.
fn scalar_indices(table: &VariableTable) -> Vec<usize> {
    let mut first = Vec::with_capacity(table.variables().len());
    let mut next = 1;
    for v in table.variables() {
        first.push(next);
        next += v.len;
    }
    first
}

fn dependency_list(table: &VariableTable, first: &[usize], v: &Variable, i: usize) -> String {
    let index_of = |name: &str| {
        table
            .variables()
            .iter()
            .position(|x| x.name == name)
            .map(|p| (p, &table.variables()[p]))
    };
    match &v.dependencies {
        Dependencies::None => String::new(),
        Dependencies::Elementwise(d) => index_of(d)
            .map(|(p, _)| (first[p] + i).to_string())
            .unwrap_or_default(),
        Dependencies::All(ds) => {
            let mut all = BTreeSet::new();
            for d in ds {
                if let Some((p, x)) = index_of(d) {
                    all.extend(first[p]..first[p] + x.len);
                }
            }
            all.iter()
                .map(|k| k.to_string())
                .collect::<Vec<_>>()
                .join(" ")
        }
    }
}

/// modelDescription.xml for a table, with the given GUID.
pub fn model_description(info: &ModelInfo, table: &VariableTable, guid: &str) -> String {
    let mut x = Xml {
        w: Writer::new_with_indent(Cursor::new(Vec::new()), b' ', 2),
    };
    let _ =
        x.w.write_event(Event::Decl(BytesDecl::new("1.0", Some("UTF-8"), None)));
    write_header(&mut x, info, guid);
    write_unit_definitions(&mut x, table);
    write_log_categories_and_experiment(&mut x, info);
    write_model_variables(&mut x, table);
    write_model_structure(&mut x, table);
    x.close("fmiModelDescription");
    String::from_utf8(x.w.into_inner().into_inner()).unwrap_or_default()
}

/// The root element's attributes and the co-simulation capabilities.
fn write_header(x: &mut Xml, info: &ModelInfo, guid: &str) {
    let n_event = "0";
    x.open(
        "fmiModelDescription",
        &[
            ("fmiVersion", "2.0"),
            ("modelName", info.model_name),
            ("guid", guid),
            ("description", info.description),
            ("generationTool", GENERATION_TOOL),
            ("variableNamingConvention", "structured"),
            ("numberOfEventIndicators", n_event),
        ],
    );
    x.empty(
        "CoSimulation",
        &[
            ("modelIdentifier", info.model_identifier),
            ("needsExecutionTool", "false"),
            ("canHandleVariableCommunicationStepSize", "true"),
            ("canInterpolateInputs", "false"),
            ("maxOutputDerivativeOrder", "0"),
            ("canRunAsynchronuously", "false"),
            ("canBeInstantiatedOnlyOncePerProcess", "false"),
            ("canNotUseMemoryManagementFunctions", "true"),
            ("canGetAndSetFMUstate", "true"),
            ("canSerializeFMUstate", "true"),
            ("providesDirectionalDerivative", "false"),
        ],
    );
}

/// UnitDefinitions: every unit the variables use, with its SI base-unit exponents and factor.
fn write_unit_definitions(x: &mut Xml, table: &VariableTable) {
    let units: BTreeSet<&str> = table
        .variables()
        .iter()
        .filter_map(|v| v.unit.as_deref())
        .collect();
    if !units.is_empty() {
        x.open("UnitDefinitions", &[]);
        for u in &units {
            x.open("Unit", &[("name", u)]);
            if let Some(exps) = crate::units::base_units(u) {
                let vals: Vec<(String, String)> = crate::units::BASE_NAMES
                    .iter()
                    .zip(exps)
                    .filter(|(_, e)| *e != 0)
                    .map(|(n, e)| (n.to_string(), e.to_string()))
                    .collect();
                let mut vals = vals;
                let factor = crate::units::factor(u);
                if factor != 1.0 {
                    vals.push(("factor".into(), crate::variables::format_real(factor)));
                }
                let attrs: Vec<(&str, &str)> =
                    vals.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect();
                x.empty("BaseUnit", &attrs);
            }
            x.close("Unit");
        }
        x.close("UnitDefinitions");
    }
}

/// LogCategories and DefaultExperiment.
fn write_log_categories_and_experiment(x: &mut Xml, info: &ModelInfo) {
    x.open("LogCategories", &[]);
    for (name, desc) in LOG_CATEGORIES {
        x.empty("Category", &[("name", name), ("description", desc)]);
    }
    x.close("LogCategories");

    let stop = format!("{}", info.default_stop_time);
    let step = format!("{}", info.default_step);
    x.empty(
        "DefaultExperiment",
        &[
            ("startTime", "0.0"),
            ("stopTime", &stop),
            ("stepSize", &step),
        ],
    );
}

/// ModelVariables: every scalar of every variable, arrays in structured naming.
fn write_model_variables(x: &mut Xml, table: &VariableTable) {
    x.open("ModelVariables", &[]);
    for v in table.variables() {
        for i in 0..v.len {
            let name = v.scalar_name(i);
            let vr = (v.vr + i as u32).to_string();
            let mut attrs: Vec<(&str, &str)> = vec![
                ("name", &name),
                ("valueReference", &vr),
                ("description", &v.description),
                ("causality", v.causality.xml()),
                ("variability", v.variability.xml()),
            ];
            if let Some(init) = v.initial {
                attrs.push(("initial", init.xml()));
            }
            x.open("ScalarVariable", &attrs);
            let start = start_text(v.start.as_ref());
            let mut tattrs: Vec<(&str, &str)> = Vec::new();
            if v.ty == VarType::Real
                && let Some(u) = &v.unit
            {
                tattrs.push(("unit", u));
            }
            if v.start.is_some() {
                tattrs.push(("start", &start));
            }
            x.empty(v.ty.xml(), &tattrs);
            x.close("ScalarVariable");
        }
    }
    x.close("ModelVariables");
}

/// ModelStructure: the outputs with their dependencies, and the initial unknowns.
fn write_model_structure(x: &mut Xml, table: &VariableTable) {
    let first = scalar_indices(table);
    x.open("ModelStructure", &[]);
    let outputs: Vec<(usize, &Variable)> = table
        .variables()
        .iter()
        .enumerate()
        .filter(|(_, v)| v.causality == Causality::Output)
        .collect();
    if !outputs.is_empty() {
        x.open("Outputs", &[]);
        for (p, v) in &outputs {
            for i in 0..v.len {
                let idx = (first[*p] + i).to_string();
                let deps = dependency_list(table, &first, v, i);
                x.empty("Unknown", &[("index", &idx), ("dependencies", &deps)]);
            }
        }
        x.close("Outputs");
    }
    let initial_unknowns: Vec<(usize, &Variable)> = table
        .variables()
        .iter()
        .enumerate()
        .filter(|(_, v)| {
            (v.causality == Causality::Output
                && matches!(v.initial, Some(Initial::Approx | Initial::Calculated)))
                || v.causality == Causality::CalculatedParameter
        })
        .collect();
    if !initial_unknowns.is_empty() {
        x.open("InitialUnknowns", &[]);
        for (p, v) in &initial_unknowns {
            for i in 0..v.len {
                let idx = (first[*p] + i).to_string();
                x.empty("Unknown", &[("index", &idx)]);
            }
        }
        x.close("InitialUnknowns");
    }
    x.close("ModelStructure");
}

/// The code that turns a table into its description: the writer of this file, the unit
/// definitions and the start values' text ([`crate::units`], [`crate::variables`]). Its text is
/// part of every GUID, so a change to how descriptions are written changes them all.
const WRITER_SOURCES: [&str; 3] = [
    include_str!("xml.rs"),
    include_str!("units.rs"),
    include_str!("variables.rs"),
];

/// The GUID of a model description: a hash of what the description is written from (the model
/// information, the variable table, the code that writes it, the generating tool), so the same
/// model, variant and build give the same GUID and any change to the description changes it.
///
/// Hashing the description's inputs instead of its text keeps `fmi2Instantiate`'s check of the
/// GUID cheap: writing the text of a TMT description (2.5 MB for the edge sensors) took about
/// 15 ms per instantiation.
pub fn guid(info: &ModelInfo, table: &VariableTable) -> String {
    let mut h = Sha256::new();
    let mut field = |bytes: &[u8]| {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    field(b"m1cs modelDescription 1");
    field(GENERATION_TOOL.as_bytes());
    for source in WRITER_SOURCES {
        field(source.as_bytes());
    }
    for text in [
        info.model_identifier,
        info.model_name,
        info.description,
        info.documentation,
    ] {
        field(text.as_bytes());
    }
    field(&info.default_stop_time.to_le_bytes());
    field(&info.default_step.to_le_bytes());
    // A table that cannot be serialised (not seen: every field is plain data) still gets a
    // GUID from its debug form, which names every field as well.
    match postcard::to_allocvec(table) {
        Ok(bytes) => field(&bytes),
        Err(_) => field(format!("{table:?}").as_bytes()),
    }
    let digest = h.finalize();
    let hex: String = digest.iter().take(16).map(|b| format!("{b:02x}")).collect();
    format!(
        "{{{}-{}-{}-{}-{}}}",
        &hex[0..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..32]
    )
}
