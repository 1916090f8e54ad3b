//! The subcommands of `m1cs`, one module per family. Each parses its flags, calls the library
//! (`m1`, or the co-simulation master) and reports: a table, `--json` or `--plot`.

pub mod cache;
pub mod cosim;
pub mod csi;
pub mod defaults;
pub mod demo;
pub mod dynamics;
pub mod geometry;
pub mod optics;
pub mod overall;
pub mod quasistatic;
pub mod report;
pub mod wind;

use m1::aperture::layout::Layout;

/// Help text of every `--structure` flag.
pub const STRUCTURE_HELP: &str = "Structure under the segments: a preset of the built-in mirror \
cell (tmt: TMT-representative, the default; soft-cell: a cell too soft for a 1 Hz global loop) \
or the path of a .npz modal model (see examples/write_structure_npz.py)";

/// Default of every `--fmu-dir` flag: where `cargo xtask package` writes the FMUs.
pub const FMU_DIR: &str = "target/fmu";

/// The layout of `--layout NAME` ([`Layout::load`]: a preset, or a JSON file when `name` ends
/// in `.json` in any case), the error naming the flag.
pub fn load_layout(name: &str) -> Result<Layout, String> {
    Layout::load(name).map_err(|e| format!("--layout {name}: {e}"))
}

/// The `modes` lowest modes of the structure `name` (a preset or a `.npz` path) under `layout`
/// ([`m1::plant::structure::StructureSource::lowest_modes`]: a file's are all read).
pub fn structure_modes(
    name: &str,
    layout: &Layout,
    modes: usize,
) -> Result<m1::plant::structure::ModalModel, String> {
    let source = m1::plant::structure::StructureSource::parse(name)
        .map_err(|e| format!("--structure: {e}"))?;
    source
        .lowest_modes(layout, modes)
        .map_err(|e| format!("--structure {name} under {}: {e}", layout.name))
}
