//! Packaging: the .fmu archive (zip) of a model variant, with its modelDescription.xml, the
//! shared library, resources and an HTML page describing the variables.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::FmuError;
use crate::instance::VARIANT_FILE;
use crate::model::Model;
use crate::variables::{Variable, VariableTable, start_text};

/// Everything an archive holds, computed from the model alone (no binary).
pub struct Description {
    /// The variant (layout) name.
    pub variant: String,
    /// The GUID.
    pub guid: String,
    /// modelDescription.xml.
    pub xml: String,
    /// documentation/index.html.
    pub html: String,
    /// The variable table.
    pub table: VariableTable,
}

/// Describes a model variant: table, GUID, XML and documentation, all from the one table.
pub fn describe<M: Model>(variant: &str) -> Result<Description, FmuError> {
    let (table, _) = M::new(variant)?;
    let guid = crate::xml::guid(&M::INFO, &table);
    let xml = crate::xml::model_description(&M::INFO, &table, &guid);
    let html = documentation::<M>(variant, &table, &guid);
    Ok(Description {
        variant: variant.to_string(),
        guid,
        xml,
        html,
        table,
    })
}

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn row(v: &Variable) -> String {
    let name = if v.array {
        format!("{}[1..{}]", v.name, v.len)
    } else {
        v.name.clone()
    };
    let vrs = if v.len > 1 {
        format!("{}..{}", v.vr, v.vr + v.len as u32 - 1)
    } else {
        v.vr.to_string()
    };
    format!(
        "<tr><td><code>{}</code></td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>\n",
        esc(&name),
        v.causality.xml(),
        v.ty.xml(),
        esc(v.unit.as_deref().unwrap_or("")),
        esc(&start_text(v.start.as_ref())),
        esc(&v.check_text()),
        vrs,
        esc(&v.description)
    )
}

fn documentation<M: Model>(variant: &str, table: &VariableTable, guid: &str) -> String {
    let info = &M::INFO;
    let rows: String = table.variables().iter().map(row).collect();
    format!(
        "<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{id} ({variant})</title>\n\
         <style>body{{font-family:sans-serif;max-width:70em;margin:auto}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px;vertical-align:top}}</style></head><body>\n\
         <h1>{name}</h1>\n<p>{desc}</p>\n<p>Packaged variant: <b>{variant}</b>. GUID <code>{guid}</code>. \
         FMI 2.0 co-simulation; default communication step {step} s.</p>\n{doc}\n\
         <h2>Variables</h2>\n<table><tr><th>name</th><th>causality</th><th>type</th><th>unit</th>\
         <th>start</th><th>allowed</th><th>value references</th><th>description</th></tr>\n{rows}</table>\n</body></html>\n",
        id = info.model_identifier,
        name = esc(info.model_name),
        desc = esc(info.description),
        step = info.default_step,
        doc = info.documentation,
    )
}

/// Writes `<out_dir>/<model_identifier>.fmu` for one variant, with the shared library at
/// `library` (the cdylib cargo built). Returns the archive's path.
pub fn write_fmu<M: Model>(
    variant: &str,
    library: &Path,
    out_dir: &Path,
) -> Result<PathBuf, FmuError> {
    let d = describe::<M>(variant)?;
    let io = |e: std::io::Error| FmuError::Model(format!("writing the archive: {e}"));
    let bin = std::fs::read(library)
        .map_err(|e| FmuError::Model(format!("reading {}: {e}", library.display())))?;
    std::fs::create_dir_all(out_dir).map_err(io)?;
    let path = out_dir.join(format!("{}.fmu", M::INFO.model_identifier));
    let file = std::fs::File::create(&path).map_err(io)?;
    let mut zip = zip::ZipWriter::new(file);
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .unix_permissions(0o644);
    let zerr = |e: zip::result::ZipError| FmuError::Model(format!("writing the archive: {e}"));
    let mut add = |name: &str, bytes: &[u8], mode: u32| -> Result<(), FmuError> {
        zip.start_file(name, opts.unix_permissions(mode))
            .map_err(zerr)?;
        zip.write_all(bytes).map_err(io)
    };
    add("modelDescription.xml", d.xml.as_bytes(), 0o644)?;
    add(
        &format!("binaries/linux64/{}.so", M::INFO.model_identifier),
        &bin,
        0o755,
    )?;
    add("documentation/index.html", d.html.as_bytes(), 0o644)?;
    add(
        &format!("resources/{VARIANT_FILE}"),
        format!("{variant}\n").as_bytes(),
        0o644,
    )?;
    for (name, bytes) in M::resources(variant) {
        add(&format!("resources/{name}"), &bytes, 0o644)?;
    }
    zip.finish().map_err(zerr)?;
    Ok(path)
}
