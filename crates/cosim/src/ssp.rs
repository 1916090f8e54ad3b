//! SSP 1.0 (System Structure and Parameterization): reading a system from a `.ssp` archive or a
//! `.ssd` file with its FMUs, and writing one.
//!
//! Read: `ssd:System` with `ssd:Elements/ssd:Component` (`source` = the FMU, relative to the
//! .ssd or inside the archive), `ssd:ParameterBindings` with inline `ssv:ParameterValues` or a
//! `source` .ssv file, `ssd:Connections/ssd:Connection` (`startElement`/`startConnector` ->
//! `endElement`/`endConnector`), and `ssd:DefaultExperiment` (startTime, stopTime). The base
//! step and each component's step multiple are not part of SSP 1.0: they are read from (and
//! written to) an `ssc:Annotation` of type `org.m1cs.master` (`step`, `order`, and `every` per
//! component, as `Rate` children of one `Master` element: the schema allows one element per
//! annotation); without it the caller supplies the step.
//!
//! Write: connections are written per scalar (arrays expanded to `z[1]`..`z[n]`), the form
//! other SSP tools (fmpy.ssp among them) read; each component lists its connectors.

use std::io::Write;
use std::path::{Path, PathBuf};

use quick_xml::Reader;
use quick_xml::events::{BytesStart, Event};

use crate::description::{Causality, VarType};
use crate::error::{CosimError, Result, io};
use crate::fmu::Fmu;
use crate::system::{Component, Connection, Order, System, Value};

const SSD_NS: &str = "http://ssp-standard.org/SSP1/SystemStructureDescription";
const SSC_NS: &str = "http://ssp-standard.org/SSP1/SystemStructureCommon";
const SSV_NS: &str = "http://ssp-standard.org/SSP1/SystemStructureParameterValues";
const ANNOTATION: &str = "org.m1cs.master";

/// A system read from SSP, with the directory its FMUs were unpacked to (kept alive).
#[derive(Debug)]
pub struct SspSystem {
    /// The system (FMU paths resolved to files).
    pub system: System,
    /// Whether the file carried a base step (else the caller's default applies).
    pub has_step: bool,
    /// Unpacked archive, removed when dropped.
    _dir: Option<crate::fmu::TempDir>,
}

fn attr(e: &BytesStart<'_>, name: &str) -> Option<String> {
    e.attributes().flatten().find_map(|a| {
        (a.key.local_name().into_inner() == name)
            .then(|| {
                a.normalized_value(quick_xml::XmlVersion::Implicit1_0)
                    .map(|v| v.into_owned())
                    .ok()
            })
            .flatten()
    })
}

fn local(e: &BytesStart<'_>) -> String {
    e.local_name().into_inner().to_string()
}

fn num(file: &Path, what: &str, s: Option<String>) -> Result<Option<f64>> {
    s.map(|v| {
        v.trim().parse::<f64>().map_err(|_| CosimError::Xml {
            file: file.to_path_buf(),
            reason: format!("{what} = {v:?} is not a number"),
        })
    })
    .transpose()
}

/// Parameters of an `ssv:ParameterSet` document or fragment: (name, value).
fn parse_parameters(xml: &str, file: &Path) -> Result<Vec<(String, Value)>> {
    let mut r = Reader::from_str(xml);
    let mut out = Vec::new();
    let mut current: Option<String> = None;
    loop {
        match r.read_event() {
            Err(e) => {
                return Err(CosimError::Xml {
                    file: file.to_path_buf(),
                    reason: format!("malformed parameter set: {e}"),
                });
            }
            Ok(Event::Eof) => break,
            Ok(Event::Start(e) | Event::Empty(e)) => {
                let name = local(&e);
                if name == "Parameter" {
                    current = attr(&e, "name");
                } else if let Some(p) = &current {
                    let v = attr(&e, "value");
                    let bad = |t: &str| CosimError::Xml {
                        file: file.to_path_buf(),
                        reason: format!("parameter {p}: {t} value {v:?} is invalid"),
                    };
                    let value = match name.as_str() {
                        "Real" => Value::Real(
                            v.as_deref()
                                .and_then(|s| s.trim().parse().ok())
                                .ok_or_else(|| bad("Real"))?,
                        ),
                        "Integer" | "Enumeration" => Value::Integer(
                            v.as_deref()
                                .and_then(|s| s.trim().parse().ok())
                                .ok_or_else(|| bad("Integer"))?,
                        ),
                        "Boolean" => Value::Boolean(match v.as_deref().map(str::trim) {
                            Some("true" | "1") => true,
                            Some("false" | "0") => false,
                            _ => return Err(bad("Boolean")),
                        }),
                        "String" => Value::String(v.unwrap_or_default()),
                        _ => continue,
                    };
                    out.push((p.clone(), value));
                    current = None;
                }
            }
            Ok(_) => {}
        }
    }
    Ok(out)
}

/// Reads a system from `path`: a `.ssp` archive (unpacked to a temporary directory) or a
/// `.ssd` file whose component sources are relative to it.
///
/// # Errors
/// Naming the file and the element at fault (malformed XML, a missing FMU or .ssv, a
/// connection without its ends, a bad number).
pub fn read(path: &Path) -> Result<SspSystem> {
    let is_archive = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ssp"));
    let (ssd, base, dir) = if is_archive {
        let dir =
            crate::fmu::TempDir::new(path.file_stem().and_then(|s| s.to_str()).unwrap_or("ssp"))?;
        crate::fmu::unzip(path, dir.path())?;
        let ssd = dir.path().join("SystemStructure.ssd");
        if !ssd.is_file() {
            return Err(CosimError::MissingFile {
                archive: path.to_path_buf(),
                file: "SystemStructure.ssd".into(),
            });
        }
        let base = dir.path().to_path_buf();
        (ssd, base, Some(dir))
    } else {
        let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
        (path.to_path_buf(), base, None)
    };
    let xml = std::fs::read_to_string(&ssd).map_err(io(&ssd))?;
    let named = |reason: String| CosimError::Xml {
        file: if is_archive {
            path.join("SystemStructure.ssd")
        } else {
            path.to_path_buf()
        },
        reason,
    };
    let mut system = System::default();
    let mut has_step = false;
    let mut everies: Vec<(String, usize)> = Vec::new();
    let mut r = Reader::from_str(&xml);
    let mut current_component: Option<usize> = None;
    let mut in_annotation = false;
    let mut depth_system = 0usize;
    loop {
        let pos_before = r.buffer_position();
        let ev = r
            .read_event()
            .map_err(|e| named(format!("malformed SSD at byte {}: {e}", r.error_position())))?;
        match ev {
            Event::Eof => break,
            Event::Start(ref e) | Event::Empty(ref e) => {
                let is_empty = matches!(ev, Event::Empty(_));
                let name = local(e);
                match name.as_str() {
                    "System" => depth_system += 1,
                    "Component" if depth_system == 1 => {
                        let cname = attr(e, "name")
                            .ok_or_else(|| named("a Component has no name".into()))?;
                        let source = attr(e, "source")
                            .ok_or_else(|| named(format!("component {cname} has no source")))?;
                        let fmu = base.join(&source);
                        if !fmu.is_file() {
                            return Err(named(format!(
                                "component {cname}: source {source} not found ({})",
                                fmu.display()
                            )));
                        }
                        system.components.push(Component {
                            name: cname,
                            fmu,
                            parameters: Vec::new(),
                            every: 1,
                        });
                        current_component = Some(system.components.len() - 1);
                    }
                    "ParameterBinding" => {
                        if let (Some(c), Some(src)) = (current_component, attr(e, "source")) {
                            let f = base.join(&src);
                            let text = std::fs::read_to_string(&f).map_err(io(&f))?;
                            let p = parse_parameters(&text, &f)?;
                            system.components[c].parameters.extend(p);
                        }
                    }
                    "ParameterValues" if !is_empty => {
                        // Read to the matching end and parse the fragment.
                        let start = usize::try_from(pos_before).unwrap_or(0);
                        let span = r
                            .read_to_end(e.name())
                            .map_err(|err| named(format!("malformed ParameterValues: {err}")))?;
                        let end = usize::try_from(span.end)
                            .unwrap_or(xml.len())
                            .min(xml.len());
                        let fragment = &xml[start.min(end)..end];
                        if let Some(c) = current_component {
                            let p = parse_parameters(fragment, path)?;
                            system.components[c].parameters.extend(p);
                        }
                        continue;
                    }
                    "Connection" => {
                        let get = |k: &str| {
                            attr(e, k).ok_or_else(|| named(format!("a Connection has no {k}")))
                        };
                        system.connections.push(Connection {
                            from: get("startElement")?,
                            output: get("startConnector")?,
                            to: get("endElement")?,
                            input: get("endConnector")?,
                        });
                    }
                    "DefaultExperiment" => {
                        if let Some(t) = num(&ssd, "startTime", attr(e, "startTime"))? {
                            system.start_time = t;
                        }
                        if let Some(t) = num(&ssd, "stopTime", attr(e, "stopTime"))? {
                            system.stop_time = t;
                        }
                    }
                    "Annotation" => {
                        in_annotation = attr(e, "type").as_deref() == Some(ANNOTATION);
                    }
                    "Master" if in_annotation => {
                        if let Some(h) = num(&ssd, "step", attr(e, "step"))? {
                            system.step = h;
                            has_step = true;
                        }
                        system.order = match attr(e, "order").as_deref() {
                            Some("gauss-seidel") => Order::GaussSeidel,
                            _ => Order::Jacobi,
                        };
                    }
                    "Rate" if in_annotation => {
                        let c = attr(e, "component")
                            .ok_or_else(|| named("a Rate has no component".into()))?;
                        let every = attr(e, "every")
                            .and_then(|s| s.trim().parse::<usize>().ok())
                            .ok_or_else(|| named(format!("Rate of {c}: every is not a count")))?;
                        everies.push((c, every));
                    }
                    _ => {}
                }
            }
            Event::End(ref e) => {
                let name = e.local_name().into_inner().to_string();
                match name.as_str() {
                    "System" => depth_system = depth_system.saturating_sub(1),
                    "Component" => current_component = None,
                    "Annotation" => in_annotation = false,
                    _ => {}
                }
            }
            _ => {}
        }
    }
    for (c, every) in everies {
        let comp = system
            .components
            .iter_mut()
            .find(|x| x.name == c)
            .ok_or_else(|| named(format!("Rate names no component {c}")))?;
        comp.every = every;
    }
    Ok(SspSystem {
        system,
        has_step,
        _dir: dir,
    })
}

fn escape(s: &str) -> String {
    quick_xml::escape::escape(s).into_owned()
}

fn value_xml(v: &Value) -> String {
    match v {
        Value::Real(x) => format!("<ssv:Real value=\"{x:e}\"/>"),
        Value::Integer(x) => format!("<ssv:Integer value=\"{x}\"/>"),
        Value::Boolean(x) => format!("<ssv:Boolean value=\"{x}\"/>"),
        Value::String(x) => format!("<ssv:String value=\"{}\"/>", escape(x)),
    }
}

/// The SystemStructure.ssd text of `system`, with component sources `sources[i]` (paths as
/// they should appear in the file, e.g. `resources/segments_voicecoil.fmu`). Connections are
/// expanded per scalar using the FMUs' model descriptions.
///
/// # Errors
/// A connection naming an unknown component or signal, or of mismatched sizes.
pub fn ssd_text(system: &System, name: &str, sources: &[String]) -> Result<String> {
    let mut fmus: Vec<Fmu> = Vec::new();
    let mut fmu_of = Vec::new();
    for c in &system.components {
        let k = match fmus.iter().position(|f| f.path == c.fmu) {
            Some(k) => k,
            None => {
                fmus.push(Fmu::open(&c.fmu)?);
                fmus.len() - 1
            }
        };
        fmu_of.push(k);
    }
    let comp_index = |n: &str| {
        system
            .components
            .iter()
            .position(|c| c.name == n)
            .ok_or_else(|| CosimError::Invalid(format!("no component named {n}")))
    };
    let mut s = String::new();
    s.push_str("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    s.push_str(&format!(
        "<ssd:SystemStructureDescription xmlns:ssc=\"{SSC_NS}\" xmlns:ssd=\"{SSD_NS}\" \
         xmlns:ssv=\"{SSV_NS}\" version=\"1.0\" name=\"{}\">\n",
        escape(name)
    ));
    s.push_str(&format!(
        "  <ssd:System name=\"{}\">\n    <ssd:Elements>\n",
        escape(name)
    ));
    for (i, c) in system.components.iter().enumerate() {
        let fmu = &fmus[fmu_of[i]];
        s.push_str(&format!(
            "      <ssd:Component name=\"{}\" type=\"application/x-fmu-sharedlibrary\" \
             source=\"{}\">\n        <ssd:Connectors>\n",
            escape(&c.name),
            escape(&sources[i])
        ));
        for v in &fmu.description.variables {
            let kind = match v.causality {
                Causality::Input => "input",
                Causality::Output => "output",
                Causality::Parameter => "parameter",
                Causality::CalculatedParameter => "calculatedParameter",
                _ => continue,
            };
            let ty = match v.var_type {
                VarType::Real => "<ssc:Real/>",
                VarType::Integer | VarType::Enumeration => "<ssc:Integer/>",
                VarType::Boolean => "<ssc:Boolean/>",
                VarType::String => "<ssc:String/>",
            };
            s.push_str(&format!(
                "          <ssd:Connector name=\"{}\" kind=\"{kind}\">{ty}</ssd:Connector>\n",
                escape(&v.name)
            ));
        }
        s.push_str("        </ssd:Connectors>\n");
        if !c.parameters.is_empty() {
            s.push_str(
                "        <ssd:ParameterBindings>\n          <ssd:ParameterBinding>\n            \
                 <ssd:ParameterValues>\n              <ssv:ParameterSet version=\"1.0\" \
                 name=\"parameters\">\n                <ssv:Parameters>\n",
            );
            for (pname, v) in &c.parameters {
                s.push_str(&format!(
                    "                  <ssv:Parameter name=\"{}\">{}</ssv:Parameter>\n",
                    escape(pname),
                    value_xml(v)
                ));
            }
            s.push_str(
                "                </ssv:Parameters>\n              </ssv:ParameterSet>\n            \
                 </ssd:ParameterValues>\n          </ssd:ParameterBinding>\n        \
                 </ssd:ParameterBindings>\n",
            );
        }
        s.push_str("      </ssd:Component>\n");
    }
    s.push_str("    </ssd:Elements>\n    <ssd:Connections>\n");
    for conn in &system.connections {
        let (a, b) = (comp_index(&conn.from)?, comp_index(&conn.to)?);
        let outs = fmus[fmu_of[a]]
            .description
            .signal(&conn.output)
            .ok_or_else(|| CosimError::UnknownVariable {
                component: conn.from.clone(),
                name: conn.output.clone(),
            })?;
        let ins = fmus[fmu_of[b]]
            .description
            .signal(&conn.input)
            .ok_or_else(|| CosimError::UnknownVariable {
                component: conn.to.clone(),
                name: conn.input.clone(),
            })?;
        if outs.len() != ins.len() {
            return Err(CosimError::Mismatch {
                what: format!(
                    "{}.{} -> {}.{}",
                    conn.from, conn.output, conn.to, conn.input
                ),
                reason: format!("{} values into {}", outs.len(), ins.len()),
            });
        }
        for (o, i) in outs.iter().zip(&ins) {
            s.push_str(&format!(
                "      <ssd:Connection startElement=\"{}\" startConnector=\"{}\" \
                 endElement=\"{}\" endConnector=\"{}\"/>\n",
                escape(&conn.from),
                escape(&o.name),
                escape(&conn.to),
                escape(&i.name)
            ));
        }
    }
    s.push_str("    </ssd:Connections>\n  </ssd:System>\n");
    s.push_str(&format!(
        "  <ssd:DefaultExperiment startTime=\"{}\" stopTime=\"{}\">\n    <ssd:Annotations>\n      \
         <ssc:Annotation type=\"{ANNOTATION}\">\n        <Master step=\"{:e}\" order=\"{}\">\n",
        system.start_time,
        system.stop_time,
        system.step,
        match system.order {
            Order::Jacobi => "jacobi",
            Order::GaussSeidel => "gauss-seidel",
        }
    ));
    for c in &system.components {
        s.push_str(&format!(
            "          <Rate component=\"{}\" every=\"{}\"/>\n",
            escape(&c.name),
            c.every
        ));
    }
    s.push_str(
        "        </Master>\n      </ssc:Annotation>\n    </ssd:Annotations>\n  </ssd:DefaultExperiment>\n\
         </ssd:SystemStructureDescription>\n",
    );
    Ok(s)
}

/// Writes `system` as a `.ssp` archive at `path`: SystemStructure.ssd plus each distinct FMU
/// under `resources/`.
///
/// # Errors
/// I/O errors naming the file, or as [`ssd_text`].
pub fn write_ssp(system: &System, name: &str, path: &Path) -> Result<()> {
    let mut files: Vec<(PathBuf, String)> = Vec::new();
    let mut sources = Vec::new();
    for c in &system.components {
        let existing = files
            .iter()
            .find(|(p, _)| *p == c.fmu)
            .map(|(_, s)| s.clone());
        let src = match existing {
            Some(s) => s,
            None => {
                let stem = c
                    .fmu
                    .file_name()
                    .and_then(|s| s.to_str())
                    .unwrap_or("component.fmu")
                    .to_string();
                let mut src = format!("resources/{stem}");
                if files.iter().any(|(_, s)| *s == src) {
                    src = format!("resources/{}_{stem}", files.len());
                }
                files.push((c.fmu.clone(), src.clone()));
                src
            }
        };
        sources.push(src);
    }
    let ssd = ssd_text(system, name, &sources)?;
    let bad = |reason: String| CosimError::Archive {
        path: path.to_path_buf(),
        reason,
    };
    let f = std::fs::File::create(path).map_err(io(path))?;
    let mut z = zip::ZipWriter::new(f);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    z.start_file("SystemStructure.ssd", opts)
        .map_err(|e| bad(e.to_string()))?;
    z.write_all(ssd.as_bytes()).map_err(io(path))?;
    for (fmu, src) in &files {
        let bytes = std::fs::read(fmu).map_err(io(fmu))?;
        z.start_file(src.as_str(), opts)
            .map_err(|e| bad(e.to_string()))?;
        z.write_all(&bytes).map_err(io(path))?;
    }
    z.finish().map_err(|e| bad(e.to_string()))?;
    Ok(())
}
