//! Model wiring of the `deformation` FMU: gravity and thermal deformation of the mirror cell as
//! the telescope tracks, the in-plane motion of every segment and the out-of-plane motion of the
//! cell at the actuators, from the zenith angle and the temperature
//! ([`m1::loads::deformation`]).
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `zenith_angle` | input | 1 | deg |
//! | `temperature` | input | 1 | K |
//! | `w` | output | na | m (radial, azimuthal), rad (clocking) |
//! | `z_cell` | output | na | m |
//!
//! with na = 3 x the number of segments (actuator k of segment i at index 3 i + k; in-plane
//! coordinates of segment i at 3 i (radial), 3 i + 1 (azimuthal), 3 i + 2 (clocking)).
//!
//! The outputs are algebraic functions of the inputs (direct feedthrough: the ModelStructure
//! lists both inputs for every output), relative to the baseline at which the mirror was
//! aligned (`baseline_zenith`, `baseline_temperature`). They follow the inputs at once, in
//! initialisation mode and after every fmi2SetReal, without a step. The source is the built-in
//! parametric model, or the FEA results of the `.npz` named by `fea_file` interpolated
//! bilinearly. A zenith angle outside [0, 90] deg, or an input outside the table, is an error
//! (fmi2Error, logged), never an extrapolation.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use fmu::{
    Check, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T,
    Values, VariableTable,
};
use m1::M1Error;
use m1::analysis::quasistatic::default_geometry;
use m1::aperture::layout::Layout;
use m1::loads::deformation::{Deformation, DeformationModel, DeformationParams, DeformationTable};
use wiring::signals::{TEMPERATURE, W, Z_CELL, ZENITH_ANGLE, layout_decl, n_segments_decl};

/// The inputs every output depends on.
fn inputs() -> Dependencies {
    Dependencies::All(vec![ZENITH_ANGLE.name.into(), TEMPERATURE.name.into()])
}

/// A Real parameter of the parametric model starting at `start`.
fn param(name: &str, unit: &str, start: f64, description: &str) -> fmu::Decl {
    T::real(name)
        .parameter()
        .unit(unit)
        .start(start)
        .describe(description)
}

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        zenith_angle: RealVar = ZENITH_ANGLE.input(layout),
        temperature: RealVar = TEMPERATURE.input(layout),
        w: RealVar = W.output(layout).depends(inputs()),
        z_cell: RealVar = Z_CELL.output(layout).depends(inputs()),
        baseline_zenith: RealVar = param("baseline_zenith", "deg",
            DeformationParams::default().baseline_zenith_deg,
            "Zenith angle at which the mirror was aligned (zero deformation)")
            .check(Check::Range(0.0, 90.0)),
        baseline_temperature: RealVar = param("baseline_temperature", "K",
            DeformationParams::default().baseline_temperature,
            "Temperature change at which the mirror was aligned (zero deformation)"),
        thermal_expansion: RealVar = param("thermal_expansion", "1/K",
            DeformationParams::default().thermal_expansion,
            "Thermal expansion of the cell relative to the glass (assumed: steel on a \
             near-zero-expansion glass)"),
        axial_strain: RealVar = param("axial_strain", "1",
            DeformationParams::default().axial_strain,
            "Radial in-plane strain of the cell per g along the optical axis (calibrated)"),
        lateral_shear: RealVar = param("lateral_shear", "m",
            DeformationParams::default().lateral_shear,
            "In-plane shear of the cell per g across the axis, centre relative to the rim \
             (calibrated)"),
        axial_sag: RealVar = param("axial_sag", "m",
            DeformationParams::default().axial_sag,
            "Out-of-plane sag of the cell at the rim per g along the axis (assumed)"),
        lateral_sag: RealVar = param("lateral_sag", "m",
            DeformationParams::default().lateral_sag,
            "Out-of-plane coma-like motion of the cell at the rim per g across the axis \
             (assumed)"),
        local_axial_rms: RealVar = param("local_axial_rms", "m",
            DeformationParams::default().local_axial_rms,
            "rms of each segment's own in-plane motion per g along the axis (calibrated)")
            .non_negative(),
        local_lateral_rms: RealVar = param("local_lateral_rms", "m",
            DeformationParams::default().local_lateral_rms,
            "rms of each segment's own in-plane motion per g across the axis (calibrated)")
            .non_negative(),
        seed: IntVar = T::integer("seed").parameter()
            .start_int(i32::try_from(DeformationParams::default().seed).unwrap_or(1))
            .non_negative().describe("Seed of the segments' local motions"),
        fea_file: StrVar = T::string("fea_file").parameter().start_str("").describe(
            "NumPy .npz of FEA results (zenith_deg, temperature_c, w, z_cell) interpolated \
             bilinearly; empty: the built-in parametric model"),
    }
}

const DOC: &str = "<h2>Model</h2>\
<p>The deformation of the mirror cell relative to the baseline at which the mirror was aligned \
(<code>baseline_zenith</code>, default 30 deg; <code>baseline_temperature</code>, default 0 K), \
as an algebraic function of the inputs <code>zenith_angle</code> &zeta; (deg, in [0, 90]) and \
<code>temperature</code> T (K, a change): <code>w</code>, the in-plane motion of every segment \
along the prescription (radial and azimuthal slide in m, clocking in rad), and \
<code>z_cell</code>, the out-of-plane motion of the cell at every actuator (m). Both outputs \
depend directly on both inputs and follow them at once (also in initialisation mode).</p>\
<h2>Parametric model (<code>fea_file</code> empty)</h2>\
<p>With c = cos &zeta; &minus; cos &zeta;<sub>0</sub>, s = sin &zeta; &minus; sin \
&zeta;<sub>0</sub> (changes of the gravity components along and across the optical axis, in g), \
dT = T &minus; T<sub>0</sub>, &rho;<sub>max</sub> the outermost segment radius and (x, y) \
aperture coordinates: thermal expansion of the cell is an isotropic strain about the vertex, \
every support point p moving by <code>thermal_expansion</code> dT p (3-D), which opens every gap \
by about <code>thermal_expansion</code> dT times the pitch and moves each attachment along the \
segment normal (a focus-like change of the cell's curvature); axial gravity strains the cell \
isotropically by <code>axial_strain</code> c and sags it by <code>axial_sag</code> c \
(&rho;/&rho;<sub>max</sub>)<sup>2</sup>; lateral gravity shears it by <code>lateral_shear</code> \
s (1 &minus; (&rho;/&rho;<sub>max</sub>)<sup>2</sup>) along y with a coma-like motion \
<code>lateral_sag</code> s (&rho;/&rho;<sub>max</sub>)<sup>2</sup> y/&rho;<sub>max</sub>; each \
segment also moves by its own seeded amount, N(0, <code>local_axial_rms</code>) per g along the \
axis and N(0, <code>local_lateral_rms</code>) per g across it (<code>seed</code>). \
<code>w</code> is the displacement at each segment centre projected on its radial and azimuthal \
tangents plus its own motion; <code>z_cell</code> the normal part at each attachment plus the \
sag patterns. The defaults are assumed or calibrated to the zenith and temperature rows of the \
seed paper's Table 1.</p>\
<h2>FEA results (<code>fea_file</code>)</h2>\
<p>A NumPy <code>.npz</code> of float64 arrays <code>zenith_deg</code> (nz,) increasing, \
<code>temperature_c</code> (nt,) increasing, <code>w</code> and <code>z_cell</code> (nz, nt, \
na), interpolated bilinearly and taken relative to their value at the baseline (which must lie \
in the table); the parametric parameters are then ignored. An input outside the table is an \
error, not an extrapolation. A relative path is looked up in the FMU's resources/ folder first, \
then in the importer's working directory.</p>";

/// What the deformation source is built from, fixed at initialisation.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Spec {
    layout: String,
    params: DeformationParams,
    /// The FEA table, resolved; `None` for the parametric model.
    fea_file: Option<PathBuf>,
    /// `fea_file` as given (for messages).
    fea_given: String,
}

impl Spec {
    /// The parameters in `v`; a relative `fea_file` is looked up in `resource_dir` first.
    fn read(x: &Vars, layout: &str, v: &Values, resource_dir: Option<&Path>) -> Self {
        let s = |h: RealVar| v.scalar(h);
        let given = v.string(x.fea_file).trim().to_string();
        Self {
            layout: layout.to_string(),
            params: DeformationParams {
                baseline_zenith_deg: s(x.baseline_zenith),
                baseline_temperature: s(x.baseline_temperature),
                thermal_expansion: s(x.thermal_expansion),
                axial_strain: s(x.axial_strain),
                lateral_shear: s(x.lateral_shear),
                axial_sag: s(x.axial_sag),
                lateral_sag: s(x.lateral_sag),
                local_axial_rms: s(x.local_axial_rms),
                local_lateral_rms: s(x.local_lateral_rms),
                seed: u64::from(v.integer(x.seed).unsigned_abs()),
            },
            fea_file: (!given.is_empty()).then(|| resolve(resource_dir, &given)),
            fea_given: given,
        }
    }

    /// Builds the deformation source.
    fn build(&self) -> Result<DeformationModel, FmuError> {
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let p = &self.params;
        match &self.fea_file {
            None => {
                let geometry =
                    default_geometry(&layout, false, None).map_err(wiring::model_error)?;
                DeformationModel::parametric(&geometry, *p).map_err(|e| {
                    wiring::model_error_renamed(e, |name| match name {
                        "zenith_angle" => "baseline_zenith",
                        "temperature" => "baseline_temperature",
                        other => other,
                    })
                })
            }
            Some(path) => DeformationTable::from_npz(
                path,
                layout.n_actuators(),
                p.baseline_zenith_deg,
                p.baseline_temperature,
            )
            .map(DeformationModel::Table)
            .map_err(|e| FmuError::BadValue {
                variable: "fea_file".into(),
                value: format!("\"{}\"", self.fea_given),
                reason: match e {
                    M1Error::InvalidInput(m) => m,
                    M1Error::InvalidParameter {
                        name,
                        value,
                        reason,
                    } => format!(
                        "the baseline ({name} = {value}) {reason}: it must lie in the table"
                    ),
                    other => other.to_string(),
                },
            }),
        }
    }
}

/// Where `file` points: absolute as given; relative, in `resource_dir` if it exists there, else
/// relative to the working directory.
fn resolve(resource_dir: Option<&Path>, file: &str) -> PathBuf {
    let p = Path::new(file);
    match resource_dir {
        Some(dir) if p.is_relative() && dir.join(p).exists() => dir.join(p),
        _ => p.to_path_buf(),
    }
}

/// The `deformation` FMU as configured: the handles, the packaged layout and the resources
/// folder; [`DeformationRunning`] evaluates.
#[derive(Debug, Clone)]
pub struct DeformationFmu {
    vars: Vars,
    layout: String,
    resource_dir: Option<PathBuf>,
}

/// The initialised `deformation` FMU: the deformation source. A saved state holds what the
/// source is built from; the source is rebuilt (the table read again) when it is read back.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(into = "SavedDeformation", try_from = "SavedDeformation")]
pub struct DeformationRunning {
    vars: Vars,
    spec: Spec,
    model: Arc<DeformationModel>,
    /// Buffer of one evaluation.
    out: Deformation,
}

/// The serialised form of [`DeformationRunning`].
#[derive(Serialize, Deserialize)]
struct SavedDeformation {
    vars: Vars,
    spec: Spec,
}

impl From<DeformationRunning> for SavedDeformation {
    fn from(r: DeformationRunning) -> Self {
        Self {
            vars: r.vars,
            spec: r.spec,
        }
    }
}

impl TryFrom<SavedDeformation> for DeformationRunning {
    type Error = FmuError;

    fn try_from(s: SavedDeformation) -> Result<Self, FmuError> {
        let model = Arc::new(s.spec.build()?);
        Ok(Self::new(s.vars, s.spec, model))
    }
}

impl DeformationRunning {
    fn new(vars: Vars, spec: Spec, model: Arc<DeformationModel>) -> Self {
        let n = model.len();
        Self {
            vars,
            spec,
            model,
            out: Deformation {
                w: vec![0.0; n],
                z_cell: vec![0.0; n],
            },
        }
    }

    /// Evaluates the source at the inputs in `v` and writes the outputs (nothing is written
    /// on an error).
    fn write_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        let x = self.vars;
        self.model
            .evaluate_into(
                v.scalar(x.zenith_angle),
                v.scalar(x.temperature),
                &mut self.out,
            )
            .map_err(wiring::model_error)?;
        v.real_mut(x.w).copy_from_slice(&self.out.w);
        v.real_mut(x.z_cell).copy_from_slice(&self.out.z_cell);
        Ok(())
    }

    /// The deformation source (for in-process use and tests).
    pub fn model(&self) -> &DeformationModel {
        &self.model
    }
}

impl Model for DeformationFmu {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "deformation",
        model_name: "Mirror-cell deformation",
        description: "Gravity and thermal deformation of the mirror cell (in-plane segment motion \
            and cell motion at the actuators) from the zenith angle and the temperature, \
            parametric or interpolated from FEA results",
        documentation: DOC,
        default_stop_time: 3600.0,
        default_step: 60.0,
    };

    type Running = DeformationRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        let model = Self {
            vars,
            layout: variant.to_string(),
            resource_dir: None,
        };
        Ok((table, model))
    }

    fn set_resource_dir(&mut self, dir: &Path) {
        self.resource_dir = Some(dir.to_path_buf());
    }

    fn initialize(&self, v: &mut Values, _start_time: f64) -> Result<DeformationRunning, FmuError> {
        let spec = Spec::read(&self.vars, &self.layout, v, self.resource_dir.as_deref());
        let model = Arc::new(spec.build()?);
        let mut running = DeformationRunning::new(self.vars, spec, model);
        running.write_outputs(v)?;
        Ok(running)
    }
}

impl fmu::Running for DeformationRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        // Direct feedthrough: the outputs follow the inputs just set.
        self.write_outputs(v)
    }

    fn do_step(&mut self, _t: f64, _h: f64, v: &mut Values) -> Result<(), FmuError> {
        // No state: the outputs at t + h are those of the inputs held over the step.
        self.write_outputs(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    /// An instance of `variant` through the runtime, in initialisation mode (start time 0).
    fn instance(variant: &str) -> Instance<DeformationFmu> {
        let (table, _) = DeformationFmu::new(variant).expect("table");
        let guid = fmu::xml::guid(&DeformationFmu::INFO, &table);
        let mut fmu =
            Instance::<DeformationFmu>::new("test", &guid, None, None, false).expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu
    }

    /// The value references of a variable's scalars.
    fn vrs(fmu: &Instance<DeformationFmu>, name: &str) -> Vec<u32> {
        let v = fmu.table().by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    /// The values of `name`.
    fn get(fmu: &mut Instance<DeformationFmu>, name: &str) -> Result<Vec<f64>, FmuError> {
        let vr = vrs(fmu, name);
        let mut out = vec![f64::NAN; vr.len()];
        fmu.get_real(&vr, &mut out)?;
        Ok(out)
    }

    /// Sets the two inputs.
    fn set_inputs(fmu: &mut Instance<DeformationFmu>, zenith: f64, temperature: f64) {
        let vr = [vrs(fmu, "zenith_angle")[0], vrs(fmu, "temperature")[0]];
        fmu.set_real(&vr, &[zenith, temperature]).expect("inputs");
    }

    /// The library's parametric model with the default parameters on the FMU's geometry.
    fn library(variant: &str) -> DeformationModel {
        let layout = Layout::preset(variant).expect("layout");
        let g = default_geometry(&layout, false, None).expect("geometry");
        DeformationModel::parametric(&g, DeformationParams::default()).expect("model")
    }

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = DeformationFmu::new(variant).expect("table");
            let layout = Layout::preset(variant).expect("layout");
            for name in ["w", "z_cell"] {
                let v = t.by_name(name).expect(name);
                assert_eq!(v.len, layout.n_actuators());
                assert_eq!(v.dependencies, inputs());
            }
            assert_eq!(t.by_name("zenith_angle").map(|v| v.len), Some(1));
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<DeformationFmu>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// At the baseline the mirror is as aligned: every output is zero.
    #[test]
    fn baseline_inputs_give_zero_outputs() {
        let mut fmu = instance("keck");
        set_inputs(&mut fmu, 30.0, 0.0);
        fmu.exit_initialization_mode().expect("initialise");
        for name in ["w", "z_cell"] {
            assert!(get(&mut fmu, name).expect(name).iter().all(|&x| x == 0.0));
        }
        fmu.do_step(0.0, 60.0).expect("step");
        assert!(get(&mut fmu, "w").expect("w").iter().all(|&x| x == 0.0));
    }

    /// +5 K at the baseline zenith angle gives the library's thermal field, bit for bit.
    #[test]
    fn five_kelvin_gives_the_library_field_exactly() {
        let want = library("keck").evaluate(30.0, 5.0).expect("library");
        assert!(want.w.iter().any(|&x| x.abs() > 1e-7));
        let mut fmu = instance("keck");
        set_inputs(&mut fmu, 30.0, 5.0);
        // In initialisation mode already.
        assert_eq!(get(&mut fmu, "w").expect("w"), want.w);
        fmu.exit_initialization_mode().expect("initialise");
        assert_eq!(get(&mut fmu, "w").expect("w"), want.w);
        assert_eq!(get(&mut fmu, "z_cell").expect("z_cell"), want.z_cell);
    }

    /// Direct feedthrough: the outputs follow an input set after initialisation without a
    /// step; a step holds them.
    #[test]
    fn outputs_follow_the_inputs_without_a_step() {
        let lib = library("keck");
        let mut fmu = instance("keck");
        fmu.exit_initialization_mode().expect("initialise");
        // The inputs start at 0: zenith 0 deg, no temperature change.
        assert_eq!(
            get(&mut fmu, "z_cell").expect("z_cell"),
            lib.evaluate(0.0, 0.0).expect("library").z_cell
        );
        set_inputs(&mut fmu, 60.0, -2.0);
        let want = lib.evaluate(60.0, -2.0).expect("library");
        assert_eq!(get(&mut fmu, "w").expect("w"), want.w);
        assert_eq!(get(&mut fmu, "z_cell").expect("z_cell"), want.z_cell);
        fmu.do_step(0.0, 60.0).expect("step");
        assert_eq!(get(&mut fmu, "z_cell").expect("z_cell"), want.z_cell);
    }

    /// A zenith angle outside [0, 90] is an error naming the input, in initialisation mode,
    /// on reading the outputs and on a step; back in range, the FMU goes on.
    #[test]
    fn a_zenith_angle_out_of_range_is_an_error() {
        let mut fmu = instance("keck");
        set_inputs(&mut fmu, 95.0, 0.0);
        let e = fmu.exit_initialization_mode().expect_err("zenith 95");
        assert!(e.to_string().contains("zenith_angle"), "{e}");
        set_inputs(&mut fmu, 45.0, 0.0);
        fmu.exit_initialization_mode().expect("initialise");
        set_inputs(&mut fmu, -1.0, 0.0);
        let e = get(&mut fmu, "w").expect_err("zenith -1");
        assert!(matches!(&e, FmuError::BadValue { variable, .. } if variable == "zenith_angle"));
        assert!(fmu.do_step(0.0, 60.0).is_err());
        set_inputs(&mut fmu, 45.0, 0.0);
        fmu.do_step(0.0, 60.0).expect("step");
    }

    /// A missing FEA file is an error naming `fea_file` and the path.
    #[test]
    fn a_missing_fea_file_is_an_error() {
        let mut fmu = instance("keck");
        let vr = fmu.table().by_name("fea_file").expect("fea_file").vr;
        fmu.set_string(&[vr], &["/nonexistent/fea.npz"])
            .expect("fea_file");
        let e = fmu
            .exit_initialization_mode()
            .expect_err("no file")
            .to_string();
        assert!(
            e.contains("fea_file") && e.contains("/nonexistent/fea.npz"),
            "{e}"
        );
    }

    /// A serialised state reads back with the source rebuilt from its parameters: the outputs
    /// are those of the state, and the rebuilt source evaluates as the original.
    #[test]
    fn a_serialised_state_rebuilds_the_source() {
        let mut fmu = instance("keck");
        let vr = fmu.table().by_name("seed").expect("seed").vr;
        fmu.set_integer(&[vr], &[7]).expect("seed");
        fmu.exit_initialization_mode().expect("initialise");
        set_inputs(&mut fmu, 45.0, 3.0);
        fmu.do_step(0.0, 60.0).expect("step");
        let bytes = Instance::serialize(&fmu.get_state().expect("state")).expect("serialize");
        let saved = get(&mut fmu, "w").expect("w");
        set_inputs(&mut fmu, 10.0, -3.0);
        fmu.do_step(60.0, 60.0).expect("step");
        let later = get(&mut fmu, "w").expect("w");
        assert_ne!(later, saved);
        let state = fmu.deserialize(&bytes).expect("deserialize");
        fmu.set_state(&state).expect("set state");
        assert_eq!(fmu.time(), 60.0);
        assert_eq!(get(&mut fmu, "w").expect("w"), saved);
        let layout = Layout::preset("keck").expect("layout");
        let g = default_geometry(&layout, false, None).expect("geometry");
        let seven = DeformationParams {
            seed: 7,
            ..DeformationParams::default()
        };
        let lib = DeformationModel::parametric(&g, seven).expect("model");
        assert_eq!(lib.evaluate(45.0, 3.0).expect("library").w, saved);
        assert_eq!(
            fmu.running()
                .expect("running")
                .model()
                .evaluate(45.0, 3.0)
                .expect("rebuilt"),
            lib.evaluate(45.0, 3.0).expect("library")
        );
        set_inputs(&mut fmu, 10.0, -3.0);
        fmu.do_step(60.0, 60.0).expect("step");
        assert_eq!(get(&mut fmu, "w").expect("w"), later);
    }
}
