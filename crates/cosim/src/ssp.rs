//! SSP 1.0 (System Structure and Parameterization): reading a system from a `.ssp` archive or a
//! `.ssd` file with its FMUs, and writing one.
//!
//! Read: `ssd:System` with `ssd:Elements/ssd:Component` (`source` = the FMU, a URI reference:
//! a percent-encoded path relative to the .ssd or inside the archive, an absolute path, or a
//! `file:` URI), `ssd:ParameterBindings` with inline `ssv:ParameterValues` or a
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
    /// The archive and where it is unpacked (None for a `.ssd` file).
    unpacked: Option<(PathBuf, PathBuf)>,
    /// Unpacked archive, removed when dropped.
    _dir: Option<crate::fmu::TempDir>,
}

impl SspSystem {
    /// `text` (an error message, say) with every path inside the unpacked archive named as
    /// the user knows it, `X.ssp: resources/x.fmu`, instead of the temporary folder.
    pub fn localize(&self, text: &str) -> String {
        match &self.unpacked {
            Some((archive, dir)) => {
                let mut prefix = dir.display().to_string();
                prefix.push('/');
                text.replace(&prefix, &format!("{}: ", archive.display()))
            }
            None => text.to_string(),
        }
    }
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

/// Where an SSD is read from.
struct Located {
    /// The SystemStructure.ssd (or .ssd) file itself.
    ssd: PathBuf,
    /// The directory its component and .ssv sources are relative to.
    base: PathBuf,
    /// The file named in errors about the SSD's content (inside the archive for a .ssp).
    named: PathBuf,
    /// The unpacked archive, if any (kept alive with the system).
    dir: Option<crate::fmu::TempDir>,
}

/// Unpacks a `.ssp` archive to a temporary directory, or takes a `.ssd` file as it is.
fn locate(path: &Path) -> Result<Located> {
    let is_archive = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ssp"));
    if is_archive {
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
        Ok(Located {
            ssd,
            base: dir.path().to_path_buf(),
            named: path.join("SystemStructure.ssd"),
            dir: Some(dir),
        })
    } else {
        Ok(Located {
            ssd: path.to_path_buf(),
            base: path.parent().map(Path::to_path_buf).unwrap_or_default(),
            named: path.to_path_buf(),
            dir: None,
        })
    }
}

/// The state of reading one SSD: the system so far and where in the document the reader is.
struct SsdReader<'a> {
    /// As [`locate`] found it.
    at: &'a Located,
    /// The path given to [`read`] (named for inline parameter values).
    path: &'a Path,
    system: System,
    has_step: bool,
    /// The `Rate`s of the master annotation, applied once every component is known.
    everies: Vec<(String, usize)>,
    current_component: Option<usize>,
    in_annotation: bool,
    depth_system: usize,
}

impl SsdReader<'_> {
    /// An error about the SSD's content, naming its file.
    fn named(&self, reason: String) -> CosimError {
        CosimError::Xml {
            file: self.at.named.clone(),
            reason,
        }
    }

    /// A start (or empty) element other than a non-empty `ParameterValues`.
    fn start(&mut self, e: &BytesStart<'_>, name: &str) -> Result<()> {
        let ssd = self.at.ssd.as_path();
        match name {
            "System" => self.depth_system += 1,
            "Component" if self.depth_system == 1 => self.component(e)?,
            "ParameterBinding" => {
                if let (Some(c), Some(src)) = (self.current_component, attr(e, "source")) {
                    let f = resolve_source(&self.at.base, &src)
                        .map_err(|why| self.named(format!("parameter source {src}: {why}")))?;
                    let text = std::fs::read_to_string(&f).map_err(io(&f))?;
                    let p = parse_parameters(&text, &f)?;
                    self.system.components[c].parameters.extend(p);
                }
            }
            "Connection" => {
                let get = |k: &str| {
                    attr(e, k).ok_or_else(|| self.named(format!("a Connection has no {k}")))
                };
                let connection = Connection {
                    from: get("startElement")?,
                    output: get("startConnector")?,
                    to: get("endElement")?,
                    input: get("endConnector")?,
                };
                self.system.connections.push(connection);
            }
            "DefaultExperiment" => {
                let start = num(ssd, "startTime", attr(e, "startTime"))?;
                let stop = num(ssd, "stopTime", attr(e, "stopTime"))?;
                if let (Some(t0), Some(t1)) = (start, stop)
                    && t1 < t0
                {
                    return Err(self.named(format!(
                        "DefaultExperiment: stopTime {t1} is before startTime {t0}"
                    )));
                }
                if let Some(t) = start {
                    self.system.start_time = t;
                }
                if let Some(t) = stop {
                    self.system.stop_time = t;
                }
            }
            "Annotation" => {
                self.in_annotation = attr(e, "type").as_deref() == Some(ANNOTATION);
            }
            "Master" if self.in_annotation => {
                if let Some(h) = num(ssd, "step", attr(e, "step"))? {
                    self.system.step = h;
                    self.has_step = true;
                }
                self.system.order = match attr(e, "order").as_deref() {
                    Some("gauss-seidel") => Order::GaussSeidel,
                    Some("jacobi") | None => Order::Jacobi,
                    Some(other) => {
                        return Err(self.named(format!(
                            "the master annotation's order \"{other}\" is neither \"jacobi\" \
                             nor \"gauss-seidel\""
                        )));
                    }
                };
            }
            "Rate" if self.in_annotation => {
                let c = attr(e, "component")
                    .ok_or_else(|| self.named("a Rate has no component".into()))?;
                let every = attr(e, "every")
                    .and_then(|s| s.trim().parse::<usize>().ok())
                    .ok_or_else(|| self.named(format!("Rate of {c}: every is not a count")))?;
                self.everies.push((c, every));
            }
            _ => {}
        }
        Ok(())
    }

    /// A top-level `Component`: its FMU must exist.
    fn component(&mut self, e: &BytesStart<'_>) -> Result<()> {
        let cname = attr(e, "name").ok_or_else(|| self.named("a Component has no name".into()))?;
        let source = attr(e, "source")
            .ok_or_else(|| self.named(format!("component {cname} has no source")))?;
        let fmu = resolve_source(&self.at.base, &source)
            .map_err(|why| self.named(format!("component {cname}: source {source}: {why}")))?;
        if !fmu.is_file() {
            let shown = match (&self.at.dir, fmu.strip_prefix(&self.at.base)) {
                (Some(_), Ok(inside)) => {
                    format!("{} has no {}", self.path.display(), inside.display())
                }
                _ => fmu.display().to_string(),
            };
            return Err(self.named(format!(
                "component {cname}: source {source} not found ({shown})"
            )));
        }
        self.system.components.push(Component {
            name: cname,
            fmu,
            parameters: Vec::new(),
            every: 1,
        });
        self.current_component = Some(self.system.components.len() - 1);
        Ok(())
    }

    /// Inline `ParameterValues` starting at byte `start` of `xml`: read to the matching end and
    /// parse the fragment.
    fn parameter_values(
        &mut self,
        r: &mut Reader<&[u8]>,
        e: &BytesStart<'_>,
        xml: &str,
        start: u64,
    ) -> Result<()> {
        let start = usize::try_from(start).unwrap_or(0);
        let span = r
            .read_to_end(e.name())
            .map_err(|err| self.named(format!("malformed ParameterValues: {err}")))?;
        let end = usize::try_from(span.end)
            .unwrap_or(xml.len())
            .min(xml.len());
        let fragment = &xml[start.min(end)..end];
        if let Some(c) = self.current_component {
            let p = parse_parameters(fragment, self.path)?;
            self.system.components[c].parameters.extend(p);
        }
        Ok(())
    }

    /// An end element.
    fn end(&mut self, name: &str) {
        match name {
            "System" => self.depth_system = self.depth_system.saturating_sub(1),
            "Component" => self.current_component = None,
            "Annotation" => self.in_annotation = false,
            _ => {}
        }
    }

    /// Reads every event of `xml`.
    fn read_all(&mut self, xml: &str) -> Result<()> {
        let mut r = Reader::from_str(xml);
        loop {
            let pos_before = r.buffer_position();
            let ev = r.read_event().map_err(|e| {
                self.named(format!("malformed SSD at byte {}: {e}", r.error_position()))
            })?;
            match ev {
                Event::Eof => break,
                Event::Start(ref e) | Event::Empty(ref e) => {
                    let is_empty = matches!(ev, Event::Empty(_));
                    let name = local(e);
                    if name == "ParameterValues" && !is_empty {
                        self.parameter_values(&mut r, e, xml, pos_before)?;
                    } else {
                        self.start(e, &name)?;
                    }
                }
                Event::End(ref e) => {
                    let name = e.local_name().into_inner().to_string();
                    self.end(&name);
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// The system with the rates applied to their components.
    fn finish(mut self) -> Result<(System, bool)> {
        if self.system.components.is_empty() {
            return Err(self.named("the system has no component".into()));
        }
        for (i, c) in self.system.components.iter().enumerate() {
            if self.system.components[..i].iter().any(|o| o.name == c.name) {
                return Err(self.named(format!("two components are named {}", c.name)));
            }
        }
        for (c, every) in std::mem::take(&mut self.everies) {
            let Some(comp) = self.system.components.iter_mut().find(|x| x.name == c) else {
                return Err(self.named(format!("Rate names no component {c}")));
            };
            comp.every = every;
        }
        Ok((self.system, self.has_step))
    }
}

/// Reads a system from `path`: a `.ssp` archive (unpacked to a temporary directory) or a
/// `.ssd` file whose component sources are relative to it.
///
/// # Errors
/// Naming the file and the element at fault (malformed XML, a missing FMU or .ssv, a
/// connection without its ends, a bad number).
pub fn read(path: &Path) -> Result<SspSystem> {
    let at = locate(path)?;
    let xml = std::fs::read_to_string(&at.ssd).map_err(io(&at.ssd))?;
    let mut reader = SsdReader {
        at: &at,
        path,
        system: System::default(),
        has_step: false,
        everies: Vec::new(),
        current_component: None,
        in_annotation: false,
        depth_system: 0,
    };
    reader.read_all(&xml)?;
    let (system, has_step) = reader.finish()?;
    Ok(SspSystem {
        system,
        has_step,
        unpacked: at
            .dir
            .as_ref()
            .map(|d| (path.to_path_buf(), d.path().to_path_buf())),
        _dir: at.dir,
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
/// under `resources/`. Returns the number of scalar connections written (an array signal is
/// one connection per element).
///
/// # Errors
/// I/O errors naming the file, or as [`ssd_text`].
pub fn write_ssp(system: &System, name: &str, path: &Path) -> Result<usize> {
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
    let scalars = ssd.matches("<ssd:Connection ").count();
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
    Ok(scalars)
}

/// The file an SSP `source` attribute names. SSP 1.0 makes it a URI reference: a `file:` URI
/// (`file:///abs/x.fmu`, `file://localhost/abs/x.fmu`, `file:/abs/x.fmu`) or a relative or
/// absolute path, percent-encoded (`my%20dir/x.fmu`); relative references resolve against
/// `base`. Other schemes (`http:`) are refused.
pub(crate) fn resolve_source(base: &Path, source: &str) -> std::result::Result<PathBuf, String> {
    let decode = |s: &str| -> std::result::Result<String, String> {
        percent_encoding::percent_decode_str(s)
            .decode_utf8()
            .map(|c| c.into_owned())
            .map_err(|e| format!("not valid UTF-8 once percent-decoded ({e})"))
    };
    // A scheme has two characters or more (a single letter would be a Windows drive).
    let scheme = source.split_once(':').map(|(s, _)| s).filter(|s| {
        s.len() > 1
            && s.chars().next().is_some_and(|c| c.is_ascii_alphabetic())
            && s.chars()
                .all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c))
    });
    match scheme {
        None => {
            let p = PathBuf::from(decode(source)?);
            Ok(if p.is_absolute() { p } else { base.join(p) })
        }
        Some(s) if s.eq_ignore_ascii_case("file") => {
            let rest = &source[s.len() + 1..];
            let path = match rest.strip_prefix("//") {
                // file://host/path: only the local host.
                Some(after) => {
                    let (host, path) = after.split_at(after.find('/').unwrap_or(after.len()));
                    if !(host.is_empty() || host.eq_ignore_ascii_case("localhost")) {
                        return Err(format!("host {host} is not this machine"));
                    }
                    path
                }
                None => rest,
            };
            if !path.starts_with('/') {
                return Err("a file: URI needs an absolute path".into());
            }
            Ok(PathBuf::from(decode(path)?))
        }
        Some(s) => Err(format!(
            "the {s}: scheme is not supported (use a path or a file: URI)"
        )),
    }
}

#[cfg(test)]
mod source_tests {
    use super::resolve_source;
    use std::path::{Path, PathBuf};

    #[test]
    fn sources_are_uri_references() {
        let base = Path::new("/systems/s");
        let ok = |s: &str| resolve_source(base, s).unwrap();
        assert_eq!(
            ok("resources/a.fmu"),
            PathBuf::from("/systems/s/resources/a.fmu")
        );
        assert_eq!(
            ok("my%20dir/a.fmu"),
            PathBuf::from("/systems/s/my dir/a.fmu")
        );
        assert_eq!(ok("/abs/a.fmu"), PathBuf::from("/abs/a.fmu"));
        assert_eq!(
            ok("file:///abs/my%20dir/a.fmu"),
            PathBuf::from("/abs/my dir/a.fmu")
        );
        assert_eq!(
            ok("file://localhost/abs/a.fmu"),
            PathBuf::from("/abs/a.fmu")
        );
        assert_eq!(ok("FILE:/abs/a.fmu"), PathBuf::from("/abs/a.fmu"));
        for (bad, why) in [
            ("http://example.org/a.fmu", "http: scheme"),
            ("file://server/a.fmu", "host server"),
            ("file:a.fmu", "absolute path"),
            ("a%FF.fmu", "UTF-8"),
        ] {
            let e = resolve_source(base, bad).unwrap_err();
            assert!(e.contains(why), "{bad}: {e}");
        }
    }
}
