//! Model wiring of the `edge_sensors` FMU: edge-sensor readings (height + Leff x dihedral, gap)
//! from segment motion, computed by [`m1::sensing::sensors::EdgeSensors`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `z` | input | na | m |
//! | `w` | input | na | m (radial, azimuthal), rad (clocking) |
//! | `y` | output | ns | m |
//! | `gap` | output | ns | m |
//! | `temperature` | input | 1 | K |
//!
//! with na = 3 x the number of segments (actuator k of segment i at index 3 i + k; in-plane
//! coordinates of segment i at 3 i (radial), 3 i + 1 (azimuthal), 3 i + 2 (clocking)) and ns = 2 x
//! the number of shared edges of the packaged layout. `temperature` (the temperature change from
//! the alignment baseline) only drives the sensors' temperature drift (`drift_per_degc`).
//!
//! # Installed sensors
//!
//! Off by default (every parameter below starts at 0, so the readings are those of ideal
//! sensors with the errors above): the gap law `height_gain_per_gap`, `leff_per_gap` (the
//! height gain and the moment arm as linear functions of the current gap change at the sensor,
//! [`m1::sensing::installed::GapLaw`]; the values calibrated to the quasi-static Table 1 are
//! [`m1::sensing::installed::DEFAULT_HEIGHT_GAIN_PER_GAP`] and
//! [`m1::sensing::installed::DEFAULT_LEFF_PER_GAP`]), the segments' placement errors
//! (`install_segment_position_rms`, `install_segment_clocking_rms`: added to `w` for the gap and
//! the height readings) and the sensors' own gap offsets (`install_sensor_gap_rms`), and the
//! drift `c_n temperature + d_n t / week` of each reading (`drift_per_degc`, `drift_per_week`),
//! with `t` the simulation time of the sample instant.
//!
//! # Sampling
//!
//! The sensors sample at their own instants `t_k = t0 + k / sample_rate` (`k >= 0`) and hold
//! each reading until the next instant; sample `k`'s noise is drawn from a generator seeded by
//! `(seed, k)`, so the readings do not depend on how the time axis is cut into steps. The inputs
//! are held over a communication step (zero-order hold): an instant `t_k` in the step
//! `(t, t + h]` reads the inputs held over it (set at `t`), and the outputs show that reading from
//! `t_k` on; the instant `t0` reads the inputs set during initialisation. So `y` and `gap` never
//! depend directly on `z` or `w` at the same communication point: the ModelStructure declares
//! no dependencies (a direct-feedthrough declaration would list every `z` and `w` for every
//! output, 78 MB of XML for TMT), the outputs are discrete Reals, and a closed loop through these
//! sensors has no algebraic loop.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use fmu::{
    Decl, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T,
    Values, VariableTable,
};
use m1::aperture::geometry::{DEFAULT_LEFF, Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::SampleClock;
use m1::sensing::installed::{DEFAULT_HEIGHT_GAIN_PER_GAP, DEFAULT_LEFF_PER_GAP, GapLaw};
use m1::sensing::sensors::{EdgeSensors, SensorErrors};
use wiring::signals::{GAP, TEMPERATURE, W, Y, Z, layout_decl, n_segments_decl, n_sensors_decl};

/// Default sample rate of the edge sensors (Hz).
pub const DEFAULT_SAMPLE_RATE: f64 = 1000.0;

const DOC: &str = "<h2>Model</h2>\
<p>Sensor <i>n</i> on the edge shared by segments <i>i</i> and <i>j</i> reads \
<code>y = s<sub>n</sub> (A<sub>hz</sub> z + A<sub>hw</sub> w) + &sigma;<sub>y</sub> &nu;</code> \
(height difference plus <code>leff</code> times the dihedral, m) and \
<code>gap = g<sub>0</sub> + A<sub>gz</sub> z + A<sub>gw</sub> w + &sigma;<sub>g</sub> &mu;</code> \
(m), where <code>z</code> are the out-of-plane displacements at the actuators, <code>w</code> the \
in-plane motion of every segment along the prescription (radial and azimuthal slide in m, \
clocking in rad), A<sub>..</sub> the blocks of the full interaction matrix of the installed \
sensors (rigid-body kinematics on the curved prescription, so out-of-plane motion also changes \
the gap), g<sub>0</sub> the layout's nominal gap, s<sub>n</sub> = 1 + &delta;<sub>n</sub> the \
sensor gains with &delta;<sub>n</sub> ~ N(0, <code>gain_error_rms</code>), and &nu;, &mu; unit \
white noise drawn once per sample.</p>\
<p><b>Installation errors</b>: each sensor point moved in its tangent plane by \
N(0, <code>install_position_rms</code>) along the gap and the shear directions, its frame tilted \
by N(0, <code>install_tilt_rms</code>) about the gap and the shear axes; the interaction matrix \
is recomputed for the installed sensors (<code>install_a_change</code> reports the relative \
Frobenius change of A). Each segment placed off its nominal place by \
N(0, <code>install_segment_position_rms</code>) radially and azimuthally and \
N(0, <code>install_segment_clocking_rms</code>) in clocking, w<sub>0</sub>: it carries its sensor \
halves, so w<sub>0</sub> adds to <code>w</code> in both the gap and the height readings \
(A<sub>gw</sub> w<sub>0</sub>, A<sub>hw</sub> w<sub>0</sub>); each sensor's own gap off the \
segments' gap by N(0, <code>install_sensor_gap_rms</code>). Every draw is reproducible from \
<code>seed</code>; gains, installation, the two noises and the drift use separate streams.</p>\
<p><b>Gap law</b>: the height gain and the moment arm of a real sensor depend on its gap. With \
dg<sub>n</sub> = A<sub>gz</sub> z + A<sub>gw</sub> (w + w<sub>0</sub>) + (sensor gap offset) \
the current gap change at sensor n (the gap reading without g<sub>0</sub> and noise), \
<code>y = s<sub>n</sub> (1 + &gamma;<sub>h</sub> dg<sub>n</sub>) (h<sub>n</sub> + (1 + &kappa; \
dg<sub>n</sub>) l<sub>n</sub>)</code> with h<sub>n</sub> the pure height part of the reading and \
l<sub>n</sub> <code>leff</code> times the dihedral, evaluated at every sample; \
&gamma;<sub>h</sub> = <code>height_gain_per_gap</code>, &kappa; = <code>leff_per_gap</code> (1/m). \
Both start at 0 (off: the ideal sensors of the dynamic studies); the values calibrated to the \
seed paper's quasi-static Table 1 are m1::sensing::installed::DEFAULT_HEIGHT_GAIN_PER_GAP and \
DEFAULT_LEFF_PER_GAP.</p>\
<p><b>Drift</b>: each reading gains c<sub>n</sub> <code>temperature</code> + d<sub>n</sub> t / \
week, with c<sub>n</sub> uniform within &plusmn;<code>drift_per_degc</code> (m/K), d<sub>n</sub> \
uniform within &plusmn;<code>drift_per_week</code> (m), drawn once per seed, \
<code>temperature</code> the input (K, held over the step) and t the simulation time of the \
sample instant (s).</p>\
<p><b>Sampling</b>: readings are taken at t<sub>0</sub> + k / <code>sample_rate</code> and held \
in between; sample k's noise depends on (seed, k) only, so the readings do not depend on the \
communication step. A sample instant in the step (t, t + h] reads the inputs held over the step \
(set at t); the instant t<sub>0</sub> reads the inputs set during initialisation. The outputs \
do not depend directly on the inputs (no algebraic loop). All errors default to zero (ideal \
sensors); the specification of the TMT sensors is a noise below 5 nm.</p>";

/// An error rms: a non-negative parameter starting at 0.
fn rms(name: &str, unit: &str, description: &str) -> Decl {
    T::real(name)
        .parameter()
        .unit(unit)
        .start(0.0)
        .non_negative()
        .describe(description)
}

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        n_sensors: IntVar = n_sensors_decl(layout),
        z: RealVar = Z.input(layout),
        w: RealVar = W.input(layout),
        y: RealVar = Y.output(layout).discrete().depends(Dependencies::None),
        gap: RealVar = GAP.output(layout).discrete().depends(Dependencies::None),
        leff: RealVar = T::real("leff").parameter().unit("m").start(DEFAULT_LEFF).non_negative()
            .describe("Effective moment arm of the sensors' dihedral sensitivity (0: pure height)"),
        gain_error_rms: RealVar = rms("gain_error_rms", "1",
            "rms of the sensor gain errors (S = I + delta_S, 0.01 = 1 %)"),
        noise_rms: RealVar = rms("noise_rms", "m", "rms of the white noise on y, per sample"),
        gap_noise_rms: RealVar = rms("gap_noise_rms", "m",
            "rms of the white noise on gap, per sample"),
        install_position_rms: RealVar = rms("install_position_rms", "m",
            "rms in-plane installation error of each sensor point, per axis"),
        install_tilt_rms: RealVar = rms("install_tilt_rms", "rad",
            "rms installation tilt of each sensor about each in-plane axis"),
        sample_rate: RealVar = T::real("sample_rate").parameter().unit("Hz")
            .start(DEFAULT_SAMPLE_RATE).positive()
            .describe("Sample rate of the sensors; readings are held between samples"),
        seed: IntVar = T::integer("seed").parameter().start_int(1).non_negative()
            .describe("Seed of the gain errors, installation errors, drift and noise"),
        install_a_change: RealVar = T::real("install_a_change").calculated_parameter().unit("1")
            .describe("Relative Frobenius change of A caused by the installation errors"),
        // Declared after the variables above: the value references follow the declaration
        // order per type, so those declared before are unchanged.
        height_gain_per_gap: RealVar = T::real("height_gain_per_gap").parameter().unit("1/m")
            .start(0.0).describe(&format!(
                "Gap law: relative height-gain change per metre of gap change, gamma_h (0: off; \
                 {DEFAULT_HEIGHT_GAIN_PER_GAP} is calibrated to the quasi-static Table 1)")),
        leff_per_gap: RealVar = T::real("leff_per_gap").parameter().unit("1/m").start(0.0)
            .describe(&format!(
                "Gap law: relative change of leff per metre of gap change, kappa (0: off; \
                 {DEFAULT_LEFF_PER_GAP} is calibrated to the quasi-static Table 1)")),
        install_segment_position_rms: RealVar = rms("install_segment_position_rms", "m",
            "rms in-plane placement error of each segment, radial and azimuthal"),
        install_segment_clocking_rms: RealVar = rms("install_segment_clocking_rms", "rad",
            "rms clocking error of each segment about its normal"),
        install_sensor_gap_rms: RealVar = rms("install_sensor_gap_rms", "m",
            "rms offset of each sensor's own gap from the segments' gap"),
        drift_per_degc: RealVar = rms("drift_per_degc", "m/K",
            "Bound of each sensor's temperature drift coefficient (uniform within +-)"),
        drift_per_week: RealVar = rms("drift_per_week", "m",
            "Bound of each sensor's drift per week of simulation time (uniform within +-)"),
        temperature: RealVar = TEMPERATURE.input(layout),
    }
}

/// The `edge_sensors` FMU as configured: the handles and the packaged layout;
/// [`EdgeSensorsRunning`] samples.
#[derive(Debug, Clone)]
pub struct EdgeSensorsModel {
    vars: Vars,
    layout: String,
}

/// What the sensors are built from, fixed at initialisation: the layout and the sensor
/// parameters.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct SensorSpec {
    layout: String,
    leff: f64,
    errors: SensorErrors,
}

impl SensorSpec {
    /// The parameters in `v`.
    fn read(x: &Vars, layout: &str, v: &Values) -> Self {
        Self {
            layout: layout.to_string(),
            leff: v.scalar(x.leff),
            errors: SensorErrors {
                gain_rms: v.scalar(x.gain_error_rms),
                noise_rms: v.scalar(x.noise_rms),
                gap_noise_rms: v.scalar(x.gap_noise_rms),
                position_rms: v.scalar(x.install_position_rms),
                tilt_rms: v.scalar(x.install_tilt_rms),
                seed: u64::from(v.integer(x.seed).unsigned_abs()),
                gap_law: GapLaw {
                    height_gain_per_gap: v.scalar(x.height_gain_per_gap),
                    leff_per_gap: v.scalar(x.leff_per_gap),
                },
                segment_position_rms: v.scalar(x.install_segment_position_rms),
                segment_clocking_rms: v.scalar(x.install_segment_clocking_rms),
                sensor_gap_rms: v.scalar(x.install_sensor_gap_rms),
                drift_per_degc: v.scalar(x.drift_per_degc),
                drift_per_week: v.scalar(x.drift_per_week),
            },
        }
    }

    /// Builds the sensors.
    fn build(&self) -> Result<EdgeSensors, FmuError> {
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let mut params = GeometryParams::for_layout(&layout);
        params.leff = self.leff;
        let geometry = Geometry::new(&layout, params).map_err(wiring::model_error)?;
        EdgeSensors::new(&geometry, &self.errors).map_err(wiring::model_error)
    }
}

/// The initialised `edge_sensors` FMU: the sensors and their sample clock. A saved state holds
/// the clock and what the sensors are built from; the sensors are rebuilt when it is read back.
#[derive(Clone, Serialize, Deserialize)]
#[serde(into = "SavedSensors", try_from = "SavedSensors")]
pub struct EdgeSensorsRunning {
    vars: Vars,
    spec: SensorSpec,
    clock: SampleClock,
    sensors: Arc<EdgeSensors>,
}

/// The serialised form of [`EdgeSensorsRunning`].
#[derive(Serialize, Deserialize)]
struct SavedSensors {
    vars: Vars,
    spec: SensorSpec,
    clock: SampleClock,
}

impl From<EdgeSensorsRunning> for SavedSensors {
    fn from(r: EdgeSensorsRunning) -> Self {
        Self {
            vars: r.vars,
            spec: r.spec,
            clock: r.clock,
        }
    }
}

impl TryFrom<SavedSensors> for EdgeSensorsRunning {
    type Error = FmuError;

    fn try_from(s: SavedSensors) -> Result<Self, FmuError> {
        let sensors = Arc::new(s.spec.build()?);
        Ok(Self::new(s.vars, s.spec, s.clock, sensors))
    }
}

impl EdgeSensorsRunning {
    fn new(vars: Vars, spec: SensorSpec, clock: SampleClock, sensors: Arc<EdgeSensors>) -> Self {
        Self {
            vars,
            spec,
            clock,
            sensors,
        }
    }

    /// Reads sample `k` (at its instant, for the drift) from the inputs in `v` and writes the
    /// outputs there, in place (a copy of the TMT's 5544 values through a buffer took about
    /// 0.9 us of each step). Nothing is written if the inputs are refused.
    fn read(&mut self, v: &mut Values, k: u64) -> Result<(), FmuError> {
        let x = self.vars;
        let temperature = v.scalar(x.temperature);
        let [z, w, y, gap] = v.reals_mut([x.z, x.w, x.y, x.gap]).ok_or_else(|| {
            FmuError::Model(
                "edge sensors: the inputs and outputs overlap or lie outside the values \
                 (internal error)"
                    .into(),
            )
        })?;
        self.sensors
            .read_into_at(z, w, temperature, self.clock.instant(k), k, y, gap)
            .map_err(wiring::model_error)
    }

    /// The sensors (for in-process use and tests).
    pub fn edge_sensors(&self) -> &EdgeSensors {
        &self.sensors
    }
}

impl Model for EdgeSensorsModel {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "edge_sensors",
        model_name: "M1 edge sensors",
        description: "Edge-sensor readings (height + Leff x dihedral, gap) of a segmented mirror \
            from out-of-plane and in-plane segment motion, with gain errors, noise, installation \
            errors, drift (seeded) and an optional gap law, sampled and held",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };

    type Running = EdgeSensorsRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        let layout = variant.to_string();
        Ok((table, Self { vars, layout }))
    }

    fn initialize(&self, v: &mut Values, start_time: f64) -> Result<EdgeSensorsRunning, FmuError> {
        let x = self.vars;
        let clock = SampleClock::new(start_time, v.scalar(x.sample_rate)).map_err(|e| {
            wiring::model_error_renamed(e, |name| if name == "rate" { "sample_rate" } else { name })
        })?;
        let spec = SensorSpec::read(&x, &self.layout, v);
        let sensors = Arc::new(spec.build()?);
        v.real_mut(x.install_a_change)[0] = sensors.install_change();
        let mut running = EdgeSensorsRunning::new(x, spec, clock, sensors);
        running.read(v, 0)?;
        Ok(running)
    }
}

impl fmu::Running for EdgeSensorsRunning {
    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // The readings change only at sample instants, inside fmi2DoStep.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let mut clock = self.clock;
        let new = clock.advance_to(t + h);
        // Only the latest instant of the step shows; the inputs are held over the step.
        if let Some(k) = new.last() {
            self.read(v, k)?;
        }
        self.clock = clock;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = EdgeSensorsModel::new(variant).expect("table");
            let layout = Layout::preset(variant).expect("layout");
            let y = t.by_name("y").expect("y");
            assert_eq!(y.len, layout.n_sensors());
            assert_eq!(y.dependencies, Dependencies::None);
            assert_eq!(t.by_name("w").expect("w").len, layout.n_actuators());
        }
    }

    /// The module documentation's table of signals is the table's inputs and outputs.
    #[test]
    fn the_documented_signals_are_the_declared_ones() {
        assert_eq!(
            wiring::check_documented_signals::<EdgeSensorsModel>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// The new variables come after the old ones: the value references of the Reals declared
    /// before are those they had without them, and every new parameter starts at 0 (off).
    #[test]
    fn the_installed_sensor_variables_are_appended_and_off() {
        let (t, _) = EdgeSensorsModel::new("keck").expect("table");
        let layout = Layout::preset("keck").expect("layout");
        let (na, ns) = (layout.n_actuators(), layout.n_sensors());
        let vr = |n: &str| t.by_name(n).expect(n).vr as usize;
        assert_eq!(
            (vr("z"), vr("w"), vr("y"), vr("gap")),
            (0, na, 2 * na, 2 * na + ns)
        );
        let names = [
            "leff",
            "gain_error_rms",
            "noise_rms",
            "gap_noise_rms",
            "install_position_rms",
            "install_tilt_rms",
            "sample_rate",
            "install_a_change",
            "height_gain_per_gap",
            "leff_per_gap",
            "install_segment_position_rms",
            "install_segment_clocking_rms",
            "install_sensor_gap_rms",
            "drift_per_degc",
            "drift_per_week",
            "temperature",
        ];
        for (k, name) in names.iter().enumerate() {
            assert_eq!(vr(name), 2 * na + 2 * ns + k, "{name}");
        }
        let v = t.initial_values();
        for name in &names[8..] {
            assert_eq!(v.reals[vr(name)], 0.0, "{name}");
        }
        assert_eq!(
            t.by_name("temperature").expect("T").unit.as_deref(),
            Some("K")
        );
    }

    /// Readings of the keck FMU after two 1 ms steps with the parameters `params` and the
    /// inputs `inputs` set, then a saved state; returns the instance, the serialised state, the
    /// time and the next three readings of `y` and `gap`.
    fn run_and_save(params: &[(&str, f64)], inputs: &[(&str, f64)]) -> (f64, Vec<f64>, Vec<f64>) {
        let (table, _) = EdgeSensorsModel::new("keck").expect("table");
        let guid = fmu::xml::guid(&EdgeSensorsModel::INFO, &table);
        let var = |n: &str| table.by_name(n).expect(n).clone();
        let vrs = |n: &str| {
            let v = var(n);
            (v.vr..v.vr + v.len as u32).collect::<Vec<_>>()
        };
        let mut fmu =
            Instance::<EdgeSensorsModel>::new("es", &guid, None, None, false).expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode().expect("enter");
        for (name, value) in params {
            fmu.set_real(&[var(name).vr], &[*value]).expect(name);
        }
        fmu.exit_initialization_mode().expect("exit");
        let z: Vec<f64> = (0..var("z").len).map(|i| 1e-7 * (i as f64).sin()).collect();
        fmu.set_real(&vrs("z"), &z).expect("z");
        for (name, value) in inputs {
            fmu.set_real(&[var(name).vr], &[*value]).expect(name);
        }
        let h = 1e-3;
        let mut t = 0.0;
        for _ in 0..2 {
            fmu.do_step(t, h).expect("step");
            t += h;
        }
        let bytes = Instance::serialize(&fmu.get_state().expect("state")).expect("serialize");
        let change = fmu
            .running()
            .expect("running")
            .edge_sensors()
            .install_change();
        let readings = |fmu: &mut Instance<EdgeSensorsModel>| {
            let mut t = t;
            let mut out = vec![0.0; var("y").len];
            let mut all = Vec::new();
            for _ in 0..3 {
                fmu.do_step(t, h).expect("step");
                t += h;
                for name in ["y", "gap"] {
                    fmu.get_real(&vrs(name), &mut out).expect(name);
                    all.extend_from_slice(&out);
                }
            }
            all
        };
        let straight = readings(&mut fmu);
        let back = fmu.deserialize(&bytes).expect("deserialize");
        fmu.set_state(&back).expect("set state");
        let rebuilt = fmu
            .running()
            .expect("running")
            .edge_sensors()
            .install_change();
        assert_eq!(rebuilt, change);
        let again = readings(&mut fmu);
        (change, straight, again)
    }

    /// A serialised state reads back with the sensors rebuilt from their parameters: the
    /// readings go on exactly as after the state was taken (noise and installation errors
    /// included).
    #[test]
    fn a_serialised_state_rebuilds_the_sensors() {
        let (change, straight, again) =
            run_and_save(&[("noise_rms", 1e-9), ("install_position_rms", 1e-4)], &[]);
        assert!(change > 0.0);
        assert!(straight.iter().any(|&y| y != 0.0));
        assert_eq!(again, straight);
    }

    /// The same with the installed-sensor errors on: gap law, segment and sensor-gap
    /// installation, drift at a temperature change; they change the readings.
    #[test]
    fn a_serialised_state_rebuilds_the_installed_sensors() {
        let base = [
            ("noise_rms", 1e-9),
            ("install_position_rms", 1e-4),
            ("gain_error_rms", 0.01),
        ];
        let installed: Vec<(&str, f64)> = base
            .iter()
            .copied()
            .chain([
                ("height_gain_per_gap", DEFAULT_HEIGHT_GAIN_PER_GAP),
                ("leff_per_gap", DEFAULT_LEFF_PER_GAP),
                ("install_segment_position_rms", 1e-4),
                ("install_segment_clocking_rms", 1e-4),
                ("install_sensor_gap_rms", 1e-5),
                ("drift_per_degc", 1e-9),
                ("drift_per_week", 1e-9),
            ])
            .collect();
        let (change, straight, again) = run_and_save(&installed, &[("temperature", 3.0)]);
        assert!(change > 0.0);
        assert_eq!(again, straight);
        let (_, plain, _) = run_and_save(&base, &[("temperature", 3.0)]);
        let ns = plain.len() / 6;
        // Both y and gap differ on every reading.
        for (k, (a, b)) in plain.chunks(ns).zip(straight.chunks(ns)).enumerate() {
            assert!(a.iter().zip(b).all(|(x, y)| x != y), "block {k}");
        }
    }

    /// A temperature change moves the readings only through the drift, by c_n T.
    #[test]
    fn the_temperature_input_drives_the_drift() {
        let params = [("drift_per_degc", 1e-9)];
        let (_, cold, _) = run_and_save(&params, &[]);
        let (_, warm, _) = run_and_save(&params, &[("temperature", 2.0)]);
        let (_, ideal, _) = run_and_save(&[], &[("temperature", 2.0)]);
        assert_eq!(cold, ideal, "no drift at T = 0 (and no time drift)");
        let ns = cold.len() / 6;
        let (y_cold, y_warm) = (&cold[..ns], &warm[..ns]);
        assert!(y_cold.iter().zip(y_warm).any(|(a, b)| a != b));
        assert!(
            y_cold
                .iter()
                .zip(y_warm)
                .all(|(a, b)| (a - b).abs() <= 2e-9 * (1.0 + 1e-12))
        );
        assert_eq!(
            &cold[ns..2 * ns],
            &warm[ns..2 * ns],
            "the gap does not drift"
        );
    }
}
