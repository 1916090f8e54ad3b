//! Model wiring of the `structure` FMU: the telescope structure seen by M1 (modal model driven by
//! actuator forces and pier motion). The physics is [`m1::plant::structure`]; this crate declares the
//! variables and moves values between the FMI value store and [`ModalSolver`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `f_cell` | input | na | N |
//! | `pier_z` | input | 1 | m |
//! | `z_cell` | output (no direct dependency on inputs) | na | m |
//!
//! with na = 3 x the number of segments of the packaged layout (actuator k of segment i at
//! index 3 i + k, 1-based in FMI names: `z_cell[3 i + k + 1]`).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use fmu::{
    Check, Decl, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, Running, StrVar,
    TableBuilder as T, Values, VariableTable,
};
use m1::M1Error;
use m1::aperture::layout::Layout;
use m1::plant::structure::{CellModel, CellParams, ModalModel, ModalSolver, StructurePreset};
use wiring::signals::{F_CELL, PIER_Z, Z_CELL, layout_decl, n_segments_decl};

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        f_cell: RealVar = F_CELL.input(layout),
        pier_z: RealVar = PIER_Z.input(layout),
        z_cell: RealVar = Z_CELL.output(layout).depends(Dependencies::None),
        cell: CellVars => CellVars::add_to(b, 60),
    }
}

fmu::variables! {
    /// Handles of the structure-model parameters and the calculated modal facts (shared with the
    /// FMUs that embed the structure, such as the coupled mirror), with `default_modes` retained
    /// modes by default.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    pub struct CellVars(b, default_modes: i32) {
        structure: StrVar = T::string("structure")
            .parameter()
            .start_str(StructurePreset::Tmt.name())
            .describe(
                "Structure model: a preset of the built-in mirror cell (tmt: TMT-representative, \
                 the default; soft-cell: a cell too soft for a 1 Hz global loop), custom (the \
                 built-in cell with the cell_* and other Built-in model parameters below), or the \
                 path of a .npz modal model (as modal_file)",
            ),
        modal_file: StrVar = T::string("modal_file").parameter().start_str("").describe(
            "NumPy .npz modal model exported from an FE model (empty: the model named by \
             `structure`); relative paths are looked up in resources/ first",
        ),
        n_modes: IntVar = T::integer("n_modes").parameter().start_int(default_modes).positive()
            .describe(
                "Number of lowest modes integrated (all if the model has fewer); the others \
                 enter through the static correction where the FMU applies one",
            ),
        damping_ratio: RealVar = T::real("damping_ratio").parameter().unit("1").start(0.02)
            .check(Check::Range(0.0, 10.0))
            .describe("Modal damping ratio of every mode (unless the modal file gives its own)"),
        cell_mass: RealVar = built_in("cell_mass", "kg", CellParams::default().cell_mass)
            .describe("Built-in model: cell structural mass lumped at each segment node"),
        mount_mass_ratio: RealVar =
            built_in("mount_mass_ratio", "1", CellParams::default().mount_mass_ratio)
            .describe("Built-in model: mount mass as a multiple of the total cell mass"),
        mount_frequency: RealVar =
            built_in("mount_frequency", "Hz", CellParams::default().mount_frequency).describe(
                "Built-in model: target bounce frequency of the rigid cell and mount on the pier \
                 spring",
            ),
        support_frequency: RealVar =
            built_in("support_frequency", "Hz", CellParams::default().support_frequency)
            .describe("Built-in model: target bounce frequency of the rigid cell on its supports"),
        cell_frequency: RealVar =
            built_in("cell_frequency", "Hz", CellParams::default().cell_frequency).describe(
                "Built-in model: target first elastic mode of the grillage pinned at its supports",
            ),
        torsion_ratio: RealVar =
            built_in("torsion_ratio", "1", CellParams::default().torsion_ratio).describe(
                "Built-in model: torsion to bending stiffness ratio GJ/EI of the grillage beams",
            ),
        support_radius: RealVar = T::real("support_radius").parameter().unit("1")
            .start(CellParams::default().support_radius)
            .check(Check::Range(0.05, 1.0))
            .describe(
                "Built-in model: radius of the support ring as a fraction of the largest \
                 segment-centre radius",
            ),
        first_mode_frequency: RealVar =
            T::real("first_mode_frequency").calculated_parameter().unit("Hz")
            .describe("Lowest natural frequency of the structure model"),
        highest_mode_frequency: RealVar =
            T::real("highest_mode_frequency").calculated_parameter().unit("Hz")
            .describe("Highest natural frequency among the integrated modes"),
        n_modes_retained: IntVar = T::integer("n_modes_retained").calculated_parameter()
            .describe("Number of modes integrated (n_modes, or all the model has)"),
    }
}

/// A positive Real parameter of the built-in cell model with its unit and start value.
fn built_in(name: &str, unit: &str, start: f64) -> Decl {
    T::real(name).parameter().unit(unit).start(start).positive()
}

/// The `structure` FMU as configured; [`StructureRunning`] steps.
#[derive(Debug, Clone)]
pub struct Structure {
    vars: Vars,
    layout: String,
    na: usize,
    resource_dir: Option<PathBuf>,
}

/// The initialised `structure` FMU: the modal solver and the handles it reads and writes.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct StructureRunning {
    vars: Vars,
    solver: ModalSolver,
}

const DOC: &str = "<h2>Model</h2><p>The telescope structure as seen by M1, as a modal model: \
<code>q<sub>j</sub>'' + 2&zeta;<sub>j</sub>&omega;<sub>j</sub>q<sub>j</sub>' + \
&omega;<sub>j</sub><sup>2</sup>q<sub>j</sub> = u<sub>j</sub></code>, \
<code>u = &Phi;<sub>a</sub><sup>T</sup> f_cell + k<sub>p</sub> &phi;<sub>p</sub> pier_z</code>, \
<code>z_cell = &Phi;<sub>a</sub> q + R</code>, with mass-normalised mode shapes &Phi;<sub>a</sub> \
at the actuator attachments (na &times; n) and &phi;<sub>p</sub> at the node of the pier spring \
k<sub>p</sub>. The <code>n_modes</code> lowest modes are integrated exactly over each \
communication step (zero-order hold: exact 2&times;2 matrix exponential per mode); the static \
response of the truncated modes is added back (static correction, residual flexibility) \
<code>R = G f + g<sub>p</sub> p &minus; &Phi;<sub>a</sub>&Omega;<sup>&minus;2</sup>u</code>, \
so the static deflection is exact for any <code>n_modes</code>.</p>\
<p><b>No direct feedthrough.</b> <code>z_cell</code> declares no dependency on the inputs (the \
segments' <code>f_cell</code> depends directly on <code>z_cell</code>, so this avoids an \
algebraic loop): the static correction uses the inputs held over the last completed step, i.e. \
the quasi-static residual lags the inputs by one communication step. The FMU starts at rest, \
undeformed (<code>z_cell = 0</code>).</p>\
<p><b>Pier.</b> The mount rests on the pier through the spring k<sub>p</sub>; pier motion is a \
base excitation through it, the force k<sub>p</sub> pier_z on the mount of a model whose pier \
spring is grounded. At DC the structure follows the pier rigidly.</p>\
<h2>Presets (<code>structure</code>)</h2><p><code>tmt</code> (the default): 1000 kg of cell \
per segment node (4.5 times the 220 kg each segment puts on its actuators: 492 t of cell for \
108 t of segments) resting on a support ring at 0.85 of the largest centre radius; the first \
modes are the axisymmetric bounces (7.5 and 11.4 Hz for TMT) and the first non-axisymmetric \
cell modes lie above 20 Hz, so the segment supports, not the cell, limit the loops. \
<code>soft-cell</code>: 500 kg per node on a ring at 0.65, first modes 6.3 and 9.1 Hz: a cell \
too soft for a 1 Hz global loop. <code>custom</code>: the Built-in model parameters below \
(their start values are the tmt preset's); with a preset they must stay at their start \
values. A path ending in <code>.npz</code> loads that modal model.</p>\
<h2>Built-in model (<code>modal_file</code> empty)</h2><p>A beam grillage with one node \
(w, &theta;<sub>x</sub>, &theta;<sub>y</sub>) at every segment centre and an Euler-Bernoulli \
beam (EI, GJ = <code>torsion_ratio</code> EI) along every shared edge; the three actuator \
attachments are rigid offsets of the node (z = w + &theta;<sub>x</sub> dy &minus; \
&theta;<sub>y</sub> dx). Each node carries <code>cell_mass</code> (and the rotary inertia of a \
pitch-sized square patch). The cell rests on vertical support springs at the ring of nodes near \
<code>support_radius</code> &times; the largest centre radius, on a mount of mass \
<code>mount_mass_ratio</code> &times; the cell mass, on the pier spring. The stiffnesses come \
from target frequencies: the rigid cell and mount on the pier (<code>mount_frequency</code>), \
the rigid cell on its supports (<code>support_frequency</code>) and the first elastic mode of \
the grillage pinned at its supports (<code>cell_frequency</code>). The coupled modes (3N+1 \
degrees of freedom; at initialisation the <code>n_modes</code> lowest alone by block Lanczos up \
to a tenth of them, 60 ms for TMT's 60, else one dense eigensolve, 0.4 s for TMT; both \
kept in the on-disk cache) are damped with \
<code>damping_ratio</code>; the static correction is the FE model's exact static solve.</p>\
<h2>Imported model (<code>modal_file</code>)</h2><p>A NumPy <code>.npz</code> file of \
little-endian float64 arrays (n modes, na actuators): <code>frequencies</code> (n,) Hz, all \
&gt; 0; <code>phi_cell</code> (na, n) mass-normalised shapes at the attachments, 1/sqrt(kg); \
<code>phi_pier</code> (n,) shapes at the pier spring's node; <code>k_pier</code> () N/m; \
optional <code>damping_ratios</code> (n,) (else <code>damping_ratio</code>), \
<code>flexibility</code> (na, na) m/N static compliance at the attachments (enables the static \
correction of f_cell; costs O(na<sup>2</sup>) per step) and <code>static_pier</code> (na,) m/m \
static response to pier_z. A relative path is looked up in the FMU's resources/ folder first, \
then in the importer's working directory. See examples/write_structure_npz.py.</p>";

impl CellVars {
    /// The modal model the parameters describe: the built-in cell of `layout` or the modal file
    /// (a relative path is looked up in `resource_dir` first, then in the working directory).
    pub fn modal_model(
        &self,
        v: &Values,
        layout: &str,
        na: usize,
        resource_dir: Option<&Path>,
    ) -> Result<ModalModel, FmuError> {
        let x = self;
        let structure = v.string(x.structure).trim().to_string();
        let mut file = v.string(x.modal_file).trim().to_string();
        if file.is_empty() && structure.to_ascii_lowercase().ends_with(".npz") {
            file = structure.clone();
        }
        if file.is_empty() {
            let s = |h: RealVar| v.scalar(h);
            let given = CellParams {
                cell_mass: s(x.cell_mass),
                mount_mass_ratio: s(x.mount_mass_ratio),
                mount_frequency: s(x.mount_frequency),
                support_frequency: s(x.support_frequency),
                cell_frequency: s(x.cell_frequency),
                torsion_ratio: s(x.torsion_ratio),
                support_radius: s(x.support_radius),
            };
            let params = if structure == "custom" {
                given
            } else if let Some(preset) = StructurePreset::from_name(&structure) {
                // A preset takes all its values: a Built-in model parameter moved from its
                // start value would be silently ignored, so it is an error.
                let start = CellParams::default();
                if let Some((name, value)) = changed_cell_parameter(&given, &start) {
                    return Err(FmuError::BadValue {
                        variable: name.into(),
                        value: format!("{value}"),
                        reason: format!(
                            "would be ignored: structure = \"{structure}\" takes every value from its preset: set \
                             structure = \"custom\" to use the Built-in model parameters"
                        ),
                    });
                }
                preset.params()
            } else {
                return Err(FmuError::BadValue {
                    variable: "structure".into(),
                    value: format!("\"{structure}\""),
                    reason: format!(
                        "is not a preset ({}), custom, nor the path of a .npz modal model",
                        StructurePreset::names()
                    ),
                });
            };
            built_in_modes(layout, &params, self.modes_and_damping(v).0)
        } else {
            let path = resolve(resource_dir, &file);
            ModalModel::from_npz(&path, na).map_err(|e| FmuError::BadValue {
                variable: "modal_file".into(),
                value: format!("\"{file}\""),
                reason: match e {
                    M1Error::InvalidInput(m) => m,
                    other => other.to_string(),
                },
            })
        }
    }

    /// Number of modes asked for, and the damping ratio of modes without their own.
    pub fn modes_and_damping(&self, v: &Values) -> (usize, f64) {
        (
            usize::try_from(v.integer(self.n_modes)).unwrap_or(0),
            v.scalar(self.damping_ratio),
        )
    }

    /// Writes the calculated parameters (first and highest retained frequencies, count).
    pub fn write_calculated(&self, v: &mut Values, solver: &ModalSolver) {
        let f = solver.frequencies();
        v.real_mut(self.first_mode_frequency)[0] = f.first().copied().unwrap_or(0.0);
        v.real_mut(self.highest_mode_frequency)[0] = f.last().copied().unwrap_or(0.0);
        v.integers[self.n_modes_retained.slot] =
            i32::try_from(solver.n_modes()).unwrap_or(i32::MAX);
    }
}

/// The first built-in cell parameter whose value in `given` differs from `start`, with that value.
fn changed_cell_parameter(given: &CellParams, start: &CellParams) -> Option<(&'static str, f64)> {
    given
        .named()
        .into_iter()
        .zip(start.named())
        .find(|(g, s)| g.1.to_bits() != s.1.to_bits())
        .map(|(g, _)| g)
}

/// Where `file` points: absolute as given; relative, in `resource_dir` if it exists there, else
/// relative to the working directory.
fn resolve(resource_dir: Option<&Path>, file: &str) -> PathBuf {
    let p = Path::new(file);
    if p.is_relative()
        && let Some(dir) = resource_dir
    {
        let candidate = dir.join(p);
        if candidate.exists() {
            return candidate;
        }
    }
    p.to_path_buf()
}

/// How many built-in cells' modal models a process keeps ([`built_in_modes`]).
const MODE_CACHE: usize = 2;

/// The `n_modes` lowest modes of the built-in cell of `layout` with `params`
/// ([`CellModel::lowest_modes`]: about 60 ms for TMT's default 60, a dense eigensolve of every
/// mode, 0.4 s for TMT's 1477 degrees of freedom, from 148 modes up), so the last [`MODE_CACHE`]
/// results are kept while the library stays loaded and reused by later instances with the
/// same layout, number of modes and bit-identical parameters (e.g. a sweep that instantiates one extracted FMU run after run, as fmpy's
/// `simulate_fmu` with a reused unzip directory does). Shared by the structure and the mirror
/// FMUs.
fn built_in_modes(
    layout: &str,
    params: &CellParams,
    n_modes: usize,
) -> Result<ModalModel, FmuError> {
    type Key = (String, [u64; 7], usize);
    static CACHE: std::sync::Mutex<Vec<(Key, ModalModel)>> = std::sync::Mutex::new(Vec::new());
    let p = params;
    let key: Key = (
        layout.to_string(),
        p.named().map(|(_, v)| v.to_bits()),
        n_modes,
    );
    // A poisoned lock only means another instance panicked while holding it: the cached
    // entries are complete values, still valid.
    let cached = {
        let cache = CACHE
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        cache
            .iter()
            .find(|(k, _)| *k == key)
            .map(|(_, m)| m.clone())
    };
    if let Some(m) = cached {
        return Ok(m);
    }
    let preset = Layout::preset(layout).map_err(|e| FmuError::Model(e.to_string()))?;
    let cell = CellModel::new(&preset, params).map_err(wiring::model_error)?;
    let modes = cell.lowest_modes(n_modes).map_err(wiring::model_error)?;
    let mut cache = CACHE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if !cache.iter().any(|(k, _)| *k == key) {
        if cache.len() >= MODE_CACHE {
            cache.remove(0);
        }
        cache.push((key, modes.clone()));
    }
    Ok(modes)
}

impl Structure {
    fn modal_model(&self, v: &Values) -> Result<ModalModel, FmuError> {
        self.vars
            .cell
            .modal_model(v, &self.layout, self.na, self.resource_dir.as_deref())
    }
}

impl StructureRunning {
    /// The modal solver (for in-process use and tests).
    pub fn solver(&self) -> &ModalSolver {
        &self.solver
    }

    fn write_outputs(&self, v: &mut Values) {
        v.real_mut(self.vars.z_cell)
            .copy_from_slice(self.solver.output());
    }
}

impl Model for Structure {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "structure",
        model_name: "Telescope structure seen by M1",
        description: "Modal model of the mirror cell, mount and pier (built-in parametric grillage \
            or imported from an FE model's .npz export), with static correction of the \
            truncated modes, driven by the actuator forces and the pier motion",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };

    type Running = StructureRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        let model = Self {
            vars,
            layout: variant.to_string(),
            na: layout.n_actuators(),
            resource_dir: None,
        };
        Ok((table, model))
    }

    fn set_resource_dir(&mut self, dir: &Path) {
        self.resource_dir = Some(dir.to_path_buf());
    }

    fn initialize(&self, v: &mut Values, _start_time: f64) -> Result<StructureRunning, FmuError> {
        let model = self.modal_model(v)?;
        let (n_modes, damping) = self.vars.cell.modes_and_damping(v);
        let solver = ModalSolver::new(model, n_modes, damping).map_err(wiring::model_error)?;
        self.vars.cell.write_calculated(v, &solver);
        let running = StructureRunning {
            vars: self.vars,
            solver,
        };
        running.write_outputs(v);
        Ok(running)
    }
}

impl Running for StructureRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        // No direct feedthrough: new inputs change nothing until the next step.
        self.write_outputs(v);
        Ok(())
    }

    fn do_step(&mut self, _t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let vars = self.vars;
        self.solver
            .step(h, v.real(vars.f_cell), v.scalar(vars.pier_z))
            .map_err(wiring::model_error)?;
        self.write_outputs(v);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    /// The cached modes are the eigensolve's, per layout, number of modes and parameters: the
    /// same parameters give the same model as a fresh solve, other parameters or another layout
    /// a new one.
    #[test]
    fn built_in_modes_are_cached_per_layout_and_parameters() {
        let p = CellParams::default();
        let fresh = CellModel::new(&Layout::keck(), &p)
            .and_then(|c| c.lowest_modes(30))
            .expect("modes");
        let a = built_in_modes("keck", &p, 30).expect("first");
        let b = built_in_modes("keck", &p, 30).expect("cached");
        assert_eq!(a, fresh);
        assert_eq!(b, fresh);
        let stiffer = CellParams {
            cell_frequency: 2.0 * p.cell_frequency,
            ..p
        };
        let c = built_in_modes("keck", &stiffer, 30).expect("other parameters");
        assert!(c.frequencies != fresh.frequencies);
        // TMT's 60 lowest modes alone (block Lanczos), the dense solve's to round-off.
        let tmt = built_in_modes("tmt", &p, 60).expect("other layout");
        assert_ne!(tmt.na, fresh.na);
        assert_eq!(tmt.n_modes(), 60);
        let all = CellModel::new(&Layout::tmt(), &p)
            .and_then(|c| c.modes_in(&m1::linalg::cache::Store::off()))
            .expect("every mode");
        for (j, (a, b)) in tmt.frequencies.iter().zip(&all.frequencies).enumerate() {
            assert!((a - b).abs() < 1e-7 * b, "mode {j}: {a} Hz against {b} Hz");
        }
        // Still right after the cache turned over.
        assert_eq!(built_in_modes("keck", &p, 30).expect("again"), fresh);
    }

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, m) = Structure::new(variant).expect("table");
            let na = Layout::preset(variant).expect("layout").n_actuators();
            assert_eq!(m.na, na);
            for (name, len) in [("f_cell", na), ("z_cell", na), ("pier_z", 1)] {
                assert_eq!(t.by_name(name).expect(name).len, len);
            }
            let z = t.by_name("z_cell").expect("z_cell");
            assert_eq!(z.dependencies, Dependencies::None);
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<Structure>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// A serialised FMU state steps on exactly as the instance it was taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let (table, _) = Structure::new("keck").expect("table");
        let guid = fmu::xml::guid(&Structure::INFO, &table);
        let mut fmu = Instance::<Structure>::new("test", &guid, None, None, false).expect("new");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu.exit_initialization_mode().expect("initialise");
        assert_eq!(fmu.running().expect("running").solver().n_modes(), 60);
        let f = fmu.table().by_name("f_cell").expect("f_cell").vr;
        fmu.set_real(&[f], &[1000.0]).expect("set f_cell");
        let z = fmu.table().by_name("z_cell").expect("z_cell");
        let z: Vec<u32> = (z.vr..z.vr + z.len as u32).collect();
        let run = |fmu: &mut Instance<Structure>, steps: usize| {
            for _ in 0..steps {
                let t = fmu.time();
                fmu.do_step(t, 1e-3).expect("step");
            }
            let mut out = vec![f64::NAN; z.len()];
            fmu.get_real(&z, &mut out).expect("get");
            out
        };
        run(&mut fmu, 2);
        let bytes =
            Instance::<Structure>::serialize(&fmu.get_state().expect("state")).expect("serialise");
        let original = run(&mut fmu, 3);
        let state = fmu.deserialize(&bytes).expect("deserialise");
        fmu.set_state(&state).expect("set state");
        assert_eq!(run(&mut fmu, 3), original);
        assert!(original.iter().any(|&x| x != 0.0));
    }

    #[test]
    fn keck_initialises_and_steps() {
        let (t, m) = Structure::new("keck").expect("keck");
        let mut v = t.initial_values();
        let mut r = m.initialize(&mut v, 0.0).expect("init");
        let f1 = v.scalar(m.vars.cell.first_mode_frequency);
        assert!((5.0..20.0).contains(&f1), "{f1}");
        assert_eq!(v.integers[m.vars.cell.n_modes_retained.slot], 60);
        v.real_mut(m.vars.f_cell)[0] = 1000.0;
        r.do_step(0.0, 1e-3, &mut v).expect("step");
        assert!(v.real(m.vars.z_cell)[0] < 0.0 || v.real(m.vars.z_cell)[0] > 0.0);
    }

    #[test]
    fn a_missing_modal_file_names_the_parameter() {
        let (t, m) = Structure::new("keck").expect("keck");
        let mut v = t.initial_values();
        v.strings[m.vars.cell.modal_file.slot] =
            std::ffi::CString::new("/nonexistent/modes.npz").expect("cstring");
        let e = m
            .initialize(&mut v, 0.0)
            .expect_err("missing file")
            .to_string();
        assert!(
            e.contains("modal_file") && e.contains("/nonexistent/modes.npz"),
            "{e}"
        );
    }

    /// Issue 14: the `structure` parameter picks a preset; `custom` takes the individual
    /// parameters; a preset with a changed individual parameter, or an unknown name, is an
    /// error naming the variable.
    #[test]
    fn issue_14_structure_parameter_picks_a_preset() {
        let first_mode = |set: &dyn Fn(&mut Values, &Vars)| {
            let (t, m) = Structure::new("keck").expect("keck");
            let mut v = t.initial_values();
            set(&mut v, &m.vars);
            m.initialize(&mut v, 0.0)
                .map(|_| v.scalar(m.vars.cell.first_mode_frequency))
                .map_err(|e| e.to_string())
        };
        let name = |v: &mut Values, x: &Vars, s: &str| {
            v.strings[x.cell.structure.slot] = std::ffi::CString::new(s).expect("cstring");
        };
        let direct = |p: &CellParams| {
            CellModel::new(&Layout::keck(), p)
                .and_then(|c| c.modes())
                .expect("modes")
                .frequencies[0]
        };
        let tmt = first_mode(&|_, _| {}).expect("default");
        assert_eq!(tmt, direct(&CellParams::tmt()));
        let soft = first_mode(&|v, x| name(v, x, "soft-cell")).expect("soft-cell");
        assert_eq!(soft, direct(&CellParams::soft_cell()));
        assert_ne!(soft, tmt);
        let custom = first_mode(&|v, x| {
            name(v, x, "custom");
            v.real_mut(x.cell.support_radius)[0] = 0.65;
            v.real_mut(x.cell.cell_mass)[0] = 500.0;
        })
        .expect("custom");
        assert_eq!(custom, soft);
        let e = first_mode(&|v, x| v.real_mut(x.cell.cell_mass)[0] = 700.0).expect_err("mixed");
        assert!(e.contains("cell_mass") && e.contains("custom"), "{e}");
        let e = first_mode(&|v, x| name(v, x, "stiff")).expect_err("unknown");
        assert!(e.contains("structure") && e.contains("soft-cell"), "{e}");
        let e = first_mode(&|v, x| name(v, x, "/nonexistent/cell.npz")).expect_err("no file");
        assert!(e.contains("/nonexistent/cell.npz"), "{e}");
    }
}
