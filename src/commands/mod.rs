//! The analysis subcommands of `m1cs`, one module per family.

pub mod cosim;
pub mod csi;
pub mod dynamics;
pub mod optics;
pub mod quasistatic;
pub mod report;
pub mod wind;

/// Help text of every `--structure` flag.
pub const STRUCTURE_HELP: &str = "Structure under the segments: a preset of the built-in mirror \
cell (tmt: TMT-representative, the default; soft-cell: a cell too soft for a 1 Hz global loop) \
or the path of a .npz modal model (see examples/write_structure_npz.py)";

/// Every mode of the structure `name` (a preset or a `.npz` path) under `layout`.
pub fn structure_modes(
    name: &str,
    layout: &m1::aperture::layout::Layout,
) -> Result<m1::plant::structure::ModalModel, String> {
    let source = m1::plant::structure::StructureSource::parse(name)
        .map_err(|e| format!("--structure: {e}"))?;
    source
        .modes(layout)
        .map_err(|e| format!("--structure {name} under {}: {e}", layout.name))
}
