//! modelDescription.xml and the runtime's get/set dispatch are derived from the same variable
//! table: what the XML promises (names, value references, causality, start values, model
//! structure, units) is what an instance does.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::collections::{BTreeMap, BTreeSet};

use common::*;
use fmu::variables::{Causality, Dependencies, Initial, Start, VarType, Variable};
use fmu::{Model, TableBuilder};

/// The value references the documented scheme gives, computed independently of the runtime:
/// Reals take 0..nR in declaration order, then Integers, Booleans and Strings.
fn expected_vrs(vars: &[Variable]) -> Vec<u32> {
    let order = [
        VarType::Real,
        VarType::Integer,
        VarType::Boolean,
        VarType::String,
    ];
    let count = |t: VarType| -> u32 {
        vars.iter()
            .filter(|v| v.ty == t)
            .map(|v| v.len as u32)
            .sum()
    };
    let mut next: BTreeMap<usize, u32> = BTreeMap::new();
    let mut base = 0;
    for (k, t) in order.iter().enumerate() {
        next.insert(k, base);
        base += count(*t);
    }
    vars.iter()
        .map(|v| {
            let k = order.iter().position(|t| *t == v.ty).unwrap();
            let n = next.get_mut(&k).unwrap();
            let first = *n;
            *n += v.len as u32;
            first
        })
        .collect()
}

fn start_string(s: &Start) -> String {
    match s {
        Start::Real(x) => format!("{x:?}"),
        Start::Integer(x) => x.to_string(),
        Start::Boolean(x) => x.to_string(),
        Start::String(x) => x.clone(),
    }
}

/// Every ScalarVariable agrees with its table entry, for both packaged variants.
#[test]
fn scalar_variables_match_the_table() {
    for variant in Lag::variants() {
        let d = describe(&variant);
        let x = parse_xml(&d.xml);
        let vars = d.table.variables();
        let vrs = expected_vrs(vars);

        let mut k = 0;
        for (v, first_vr) in vars.iter().zip(&vrs) {
            for i in 0..v.len {
                let s = &x.scalars[k];
                k += 1;
                let name = if v.array {
                    format!("{}[{}]", v.name, i + 1)
                } else {
                    v.name.clone()
                };
                assert_eq!(s.name, name, "{variant}: scalar {k}");
                assert_eq!(
                    s.vr,
                    first_vr + i as u32,
                    "{variant}: {name} valueReference"
                );
                assert_eq!(s.ty, v.ty.xml(), "{variant}: {name} type");
                assert_eq!(
                    s.causality,
                    v.causality.xml(),
                    "{variant}: {name} causality"
                );
                assert_eq!(
                    s.variability,
                    v.variability.xml(),
                    "{variant}: {name} variability"
                );
                assert_eq!(
                    s.initial.as_deref(),
                    v.initial.map(Initial::xml),
                    "{variant}: {name} initial"
                );
                assert_eq!(s.unit, v.unit, "{variant}: {name} unit");
                assert_eq!(
                    s.start,
                    v.start.as_ref().map(start_string),
                    "{variant}: {name} start"
                );
                assert_eq!(s.description.as_deref(), Some(v.description.as_str()));
            }
        }
        assert_eq!(k, x.scalars.len(), "{variant}: extra ScalarVariables");

        // Value references are unique, and contiguous over all types.
        let mut all: Vec<u32> = x.scalars.iter().map(|s| s.vr).collect();
        all.sort_unstable();
        assert_eq!(all, (0..x.scalars.len() as u32).collect::<Vec<_>>());
    }
}

/// Spot checks written out by hand, so that a systematic error shared by the table and the
/// writer (e.g. in structured names or value references) cannot go unnoticed.
#[test]
fn known_scalars_of_the_small_variant() {
    let x = parse_xml(&describe("small").xml);
    let by_name: BTreeMap<&str, &XmlScalar> =
        x.scalars.iter().map(|s| (s.name.as_str(), s)).collect();
    let names: Vec<&str> = x.scalars.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "tau", "n", "gain", "enabled", "y0", "bias", "panic_at", "substeps", "layout", "label",
            "u[1]", "u[2]", "u[3]", "y[1]", "y[2]", "y[3]", "yd[1]", "yd[2]", "yd[3]", "total",
            "corner", "steps"
        ]
    );
    // Reals: tau gain y0 bias panic_at u1..3 y1..3 yd1..3 total corner = 0..=15; Integers:
    // n substeps steps = 16..=18; Boolean enabled = 19; Strings layout label = 20, 21.
    let expect = [
        (
            "tau",
            0,
            "parameter",
            "fixed",
            Some("exact"),
            "Real",
            Some("s"),
            Some("0.5"),
        ),
        (
            "n",
            16,
            "parameter",
            "fixed",
            Some("exact"),
            "Integer",
            None,
            Some("3"),
        ),
        (
            "gain",
            1,
            "parameter",
            "fixed",
            Some("exact"),
            "Real",
            Some("1"),
            Some("2.0"),
        ),
        (
            "enabled",
            19,
            "parameter",
            "fixed",
            Some("exact"),
            "Boolean",
            None,
            Some("true"),
        ),
        (
            "bias",
            3,
            "parameter",
            "tunable",
            Some("exact"),
            "Real",
            Some("m"),
            Some("0.0"),
        ),
        (
            "substeps",
            17,
            "parameter",
            "fixed",
            Some("exact"),
            "Integer",
            None,
            Some("4"),
        ),
        (
            "layout",
            20,
            "parameter",
            "fixed",
            Some("exact"),
            "String",
            None,
            Some("small"),
        ),
        (
            "label",
            21,
            "parameter",
            "fixed",
            Some("exact"),
            "String",
            None,
            Some(LABEL_START),
        ),
        (
            "u[1]",
            5,
            "input",
            "continuous",
            None,
            "Real",
            Some("m"),
            Some("0.25"),
        ),
        (
            "u[3]",
            7,
            "input",
            "continuous",
            None,
            "Real",
            Some("m"),
            Some("0.25"),
        ),
        (
            "y[1]",
            8,
            "output",
            "continuous",
            Some("calculated"),
            "Real",
            Some("m"),
            None,
        ),
        (
            "yd[2]",
            12,
            "output",
            "continuous",
            Some("calculated"),
            "Real",
            Some("m"),
            None,
        ),
        (
            "total",
            14,
            "output",
            "continuous",
            Some("calculated"),
            "Real",
            Some("m"),
            None,
        ),
        (
            "corner",
            15,
            "calculatedParameter",
            "fixed",
            Some("calculated"),
            "Real",
            Some("Hz"),
            None,
        ),
        (
            "steps",
            18,
            "output",
            "discrete",
            Some("calculated"),
            "Integer",
            None,
            None,
        ),
    ];
    for (name, vr, causality, variability, initial, ty, unit, start) in expect {
        let s = by_name[name];
        assert_eq!(
            (
                s.vr,
                s.causality.as_str(),
                s.variability.as_str(),
                s.initial.as_deref(),
                s.ty.as_str(),
                s.unit.as_deref(),
                s.start.as_deref()
            ),
            (vr, causality, variability, initial, ty, unit, start),
            "{name}"
        );
    }
}

/// After fmi2Instantiate (with the XML's GUID) and fmi2EnterInitializationMode, every
/// variable with a start value reads back as the XML's start value, through the getter of
/// the type the XML declares.
#[test]
fn instance_starts_with_the_xml_start_values() {
    for variant in Lag::variants() {
        let d = describe(&variant);
        let x = parse_xml(&d.xml);
        assert_eq!(x.attrs["guid"], d.guid);
        let mut fmu = instantiate("starts", &x.attrs["guid"], None, false)
            .unwrap_or_else(|l| panic!("{}", l.dump()));
        assert_eq!(fmu.enter_init(), OK);
        let mut checked = 0;
        for s in x.scalars.iter() {
            let Some(start) = &s.start else { continue };
            let vr = [s.vr];
            match s.ty.as_str() {
                "Real" => {
                    let want: f64 = start.parse().unwrap();
                    assert_eq!(fmu.get_real(&vr).unwrap()[0], want, "{variant} {}", s.name);
                }
                "Integer" => {
                    let want: i32 = start.parse().unwrap();
                    assert_eq!(
                        fmu.get_integer(&vr).unwrap()[0],
                        want,
                        "{variant} {}",
                        s.name
                    );
                }
                "Boolean" => {
                    let want = match start.as_str() {
                        "true" | "1" => true,
                        "false" | "0" => false,
                        other => panic!("{}: boolean start {other}", s.name),
                    };
                    assert_eq!(
                        fmu.get_boolean(&vr).unwrap()[0],
                        want,
                        "{variant} {}",
                        s.name
                    );
                }
                "String" => {
                    assert_eq!(
                        &fmu.get_string(&vr).unwrap()[0],
                        start,
                        "{variant} {}",
                        s.name
                    );
                }
                other => panic!("type {other}"),
            }
            checked += 1;
        }
        // tau n gain enabled y0 bias panic_at substeps layout label + the inputs.
        assert_eq!(checked, 10 + variant_len(&variant).unwrap(), "{variant}");

        // A value reference of one type is refused by the getter of another.
        let n_vr = [x.scalars.iter().find(|s| s.name == "n").unwrap().vr];
        assert_eq!(fmu.get_real(&n_vr), Err(ERROR));
        let tau_vr = [x.scalars[0].vr];
        assert_eq!(fmu.get_integer(&tau_vr), Err(ERROR));
        // One past the last value reference is unknown to every getter.
        let past = [x.scalars.len() as u32];
        assert_eq!(fmu.get_real(&past), Err(ERROR));
        assert_eq!(fmu.get_string(&past), Err(ERROR));
        assert!(
            fmu.logged(&["unknown", "value reference"]),
            "{}",
            fmu.log.dump()
        );
    }
}

/// Every Real the XML declares settable (parameter or input) round-trips through fmi2SetReal
/// and fmi2GetReal, one at a time and as one batch; the others are refused.
#[test]
fn settable_reals_round_trip() {
    let d = describe("big");
    let x = parse_xml(&d.xml);
    let mut fmu = instantiate("set", &d.guid, None, false).unwrap();
    assert_eq!(fmu.enter_init(), OK);
    let reals: Vec<&XmlScalar> = x.scalars.iter().filter(|s| s.ty == "Real").collect();
    let settable: Vec<&&XmlScalar> = reals
        .iter()
        .filter(|s| s.causality == "parameter" || s.causality == "input")
        .collect();
    assert_eq!(settable.len(), 5 + 5, "tau gain y0 bias panic_at u[1..5]");
    for (k, s) in settable.iter().enumerate() {
        let start: f64 = s.start.as_ref().unwrap().parse().unwrap();
        let new = start + 1.0 + k as f64 / 8.0;
        assert_eq!(
            fmu.set_real(&[s.vr], &[new]),
            OK,
            "{}: {}",
            s.name,
            fmu.log.dump()
        );
        assert_eq!(fmu.get_real(&[s.vr]).unwrap(), [new], "{}", s.name);
    }
    // The whole batch, in reverse order, with other values.
    let vr: Vec<u32> = settable.iter().rev().map(|s| s.vr).collect();
    let vals: Vec<f64> = (0..vr.len()).map(|k| 3.0 + k as f64 * 0.5).collect();
    assert_eq!(fmu.set_real(&vr, &vals), OK, "{}", fmu.log.dump());
    assert_eq!(fmu.get_real(&vr).unwrap(), vals);

    for s in reals
        .iter()
        .filter(|s| s.causality != "parameter" && s.causality != "input")
    {
        fmu.log.take();
        assert_eq!(
            fmu.set_real(&[s.vr], &[1.0]),
            ERROR,
            "{} is not settable",
            s.name
        );
        assert!(
            fmu.logged(&[&s.name, "cannot be set"]),
            "{}",
            fmu.log.dump()
        );
    }
}

/// ModelStructure: Outputs lists exactly the output scalars, by their 1-based index in
/// ModelVariables, with the declared dependencies; InitialUnknowns lists the outputs with
/// initial="calculated" and the calculated parameters.
#[test]
fn model_structure_matches_the_declarations() {
    for variant in Lag::variants() {
        let d = describe(&variant);
        let x = parse_xml(&d.xml);
        let index: BTreeMap<&str, usize> = x
            .scalars
            .iter()
            .enumerate()
            .map(|(k, s)| (s.name.as_str(), k + 1))
            .collect();

        // From the table declarations.
        let mut outputs = Vec::new();
        let mut initial_unknowns = Vec::new();
        for v in d.table.variables() {
            for i in 0..v.len {
                let me = index[v.scalar_name(i).as_str()];
                if v.causality == Causality::Output {
                    let deps = match &v.dependencies {
                        Dependencies::None => String::new(),
                        Dependencies::Elementwise(u) => {
                            let input = d.table.by_name(u).unwrap();
                            index[input.scalar_name(i).as_str()].to_string()
                        }
                        Dependencies::All(_) => panic!("not used by the test model"),
                    };
                    outputs.push((me, Some(deps)));
                }
                if (v.causality == Causality::Output && v.initial == Some(Initial::Calculated))
                    || v.causality == Causality::CalculatedParameter
                {
                    initial_unknowns.push((me, None));
                }
            }
        }
        assert_eq!(x.outputs, outputs, "{variant}: Outputs");
        assert_eq!(
            x.initial_unknowns, initial_unknowns,
            "{variant}: InitialUnknowns"
        );

        // The same, from the XML attributes alone.
        let xml_outputs: Vec<usize> = x
            .scalars
            .iter()
            .enumerate()
            .filter(|(_, s)| s.causality == "output")
            .map(|(k, _)| k + 1)
            .collect();
        assert_eq!(
            x.outputs.iter().map(|o| o.0).collect::<Vec<_>>(),
            xml_outputs
        );
        let xml_unknowns: Vec<usize> = x
            .scalars
            .iter()
            .enumerate()
            .filter(|(_, s)| {
                (s.causality == "output"
                    && matches!(s.initial.as_deref(), Some("calculated" | "approx")))
                    || s.causality == "calculatedParameter"
            })
            .map(|(k, _)| k + 1)
            .collect();
        assert_eq!(
            x.initial_unknowns.iter().map(|o| o.0).collect::<Vec<_>>(),
            xml_unknowns
        );

        // And by hand: yd[i] depends on u[i] only; y, total and steps on no input.
        let n = variant_len(&variant).unwrap();
        for i in 1..=n {
            let yd = index[format!("yd[{i}]").as_str()];
            let u = index[format!("u[{i}]").as_str()];
            assert!(x.outputs.contains(&(yd, Some(u.to_string()))), "yd[{i}]");
            let y = index[format!("y[{i}]").as_str()];
            assert!(x.outputs.contains(&(y, Some(String::new()))), "y[{i}]");
        }
        assert!(x.outputs.contains(&(index["total"], Some(String::new()))));
        assert!(x.outputs.contains(&(index["steps"], Some(String::new()))));
        assert_eq!(x.outputs.len(), 2 * n + 2);
        assert!(x.initial_unknowns.contains(&(index["corner"], None)));
        assert_eq!(x.initial_unknowns.len(), 2 * n + 3);
    }
}

/// Every unit used by a variable is defined in UnitDefinitions (and only those), with the
/// right SI exponents.
#[test]
fn units_are_defined() {
    let x = parse_xml(&describe("small").xml);
    let used: BTreeSet<&str> = x.scalars.iter().filter_map(|s| s.unit.as_deref()).collect();
    let defined: BTreeSet<&str> = x.units.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(used, defined);
    assert_eq!(used, BTreeSet::from(["1", "Hz", "m", "s"]));
    let exps: BTreeMap<&str, &BTreeMap<String, i32>> =
        x.units.iter().map(|(n, e)| (n.as_str(), e)).collect();
    assert_eq!(*exps["m"], BTreeMap::from([("m".to_string(), 1)]));
    assert_eq!(*exps["s"], BTreeMap::from([("s".to_string(), 1)]));
    assert_eq!(*exps["Hz"], BTreeMap::from([("s".to_string(), -1)]));
    assert!(exps["1"].is_empty());
    // The unit element comes before the variables, as the schema orders them.
    let pos = |p: &str| x.paths.iter().position(|q| q == p).unwrap();
    assert!(pos("fmiModelDescription/UnitDefinitions") < pos("fmiModelDescription/ModelVariables"));
}

/// The header: CoSimulation capabilities the runtime implements, the log categories the
/// runtime accepts in fmi2SetDebugLogging, and the default experiment.
#[test]
fn header_matches_the_runtime() {
    let d = describe("small");
    let x = parse_xml(&d.xml);
    assert_eq!(x.attrs["fmiVersion"], "2.0");
    assert_eq!(x.attrs["variableNamingConvention"], "structured");
    assert_eq!(x.cosim["modelIdentifier"], Lag::INFO.model_identifier);
    assert_eq!(x.cosim["canGetAndSetFMUstate"], "true");
    assert_eq!(x.cosim["canSerializeFMUstate"], "true");
    assert_eq!(x.cosim["canBeInstantiatedOnlyOncePerProcess"], "false");
    let cats: Vec<&str> = fmu::xml::LOG_CATEGORIES.iter().map(|c| c.0).collect();
    assert_eq!(x.log_categories, cats);
    assert!(cats.contains(&"logStatusFatal") && cats.contains(&"logStatusError"));
    let order: Vec<&str> = [
        "fmiModelDescription/CoSimulation",
        "fmiModelDescription/UnitDefinitions",
        "fmiModelDescription/LogCategories",
        "fmiModelDescription/DefaultExperiment",
        "fmiModelDescription/ModelVariables",
        "fmiModelDescription/ModelStructure",
    ]
    .into_iter()
    .collect();
    let found: Vec<&str> = x
        .paths
        .iter()
        .map(String::as_str)
        .filter(|p| order.contains(p))
        .collect();
    assert_eq!(found, order, "schema order of the top-level elements");
}

/// A String start value with characters XML normalises in attribute values (newline, tab,
/// carriage return) must still read back as the start value the instance uses, so they must
/// be written as character references.
#[test]
fn string_start_with_newline_survives_the_xml() {
    let mut b = TableBuilder::new();
    b.add_string(
        TableBuilder::string("note")
            .parameter()
            .start_str("line 1\nline 2\tend\r"),
    );
    let t = b.build().unwrap();
    let xml = fmu::xml::model_description(&Lag::INFO, &t, "{x}");
    let x = parse_xml(&xml);
    assert_eq!(x.scalars[0].start.as_deref(), Some("line 1\nline 2\tend\r"));
}
