//! Model wiring of the `edge_sensors` FMU: edge-sensor readings (height + Leff x dihedral, gap)
//! from segment motion, computed by [`m1::sensing::sensors::EdgeSensors`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `z` | input | na | m |
//! | `w` | input | na | m (radial, azimuthal), rad (clocking) |
//! | `y` | output | ns | m |
//! | `gap` | output | ns | m |
//!
//! with na = 3 x the number of segments (actuator k of segment i at index 3 i + k; in-plane
//! coordinates of segment i at 3 i (radial), 3 i + 1 (azimuthal), 3 i + 2 (clocking)) and ns = 2 x
//! the number of shared edges of the packaged layout.
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
    Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T, Values,
    VariableTable,
};
use m1::M1Error;
use m1::aperture::geometry::{DEFAULT_LEFF, Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::SampleClock;
use m1::sensing::sensors::{EdgeSensors, SensorErrors};

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
Frobenius change of A). Every draw is reproducible from <code>seed</code>; gains, installation \
and the two noises use separate streams.</p>\
<p><b>Sampling</b>: readings are taken at t<sub>0</sub> + k / <code>sample_rate</code> and held \
in between; sample k's noise depends on (seed, k) only, so the readings do not depend on the \
communication step. A sample instant in the step (t, t + h] reads the inputs held over the step \
(set at t); the instant t<sub>0</sub> reads the inputs set during initialisation. The outputs \
do not depend directly on the inputs (no algebraic loop). All errors default to zero (ideal \
sensors); the specification of the TMT sensors is a noise below 5 nm.</p>";

/// Handles of every variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Vars {
    layout: StrVar,
    n_segments: IntVar,
    n_sensors: IntVar,
    z: RealVar,
    w: RealVar,
    y: RealVar,
    gap: RealVar,
    leff: RealVar,
    gain_error_rms: RealVar,
    noise_rms: RealVar,
    gap_noise_rms: RealVar,
    install_position_rms: RealVar,
    install_tilt_rms: RealVar,
    sample_rate: RealVar,
    seed: IntVar,
    install_a_change: RealVar,
}

/// The `edge_sensors` FMU.
#[derive(Clone, Serialize, Deserialize)]
pub struct EdgeSensorsModel {
    vars: Vars,
    layout: String,
    /// The sample instants; `None` before initialisation.
    clock: Option<SampleClock>,
    /// The sensors (rebuilt from the parameters after a deserialised state).
    #[serde(skip)]
    sensors: Option<Arc<EdgeSensors>>,
    #[serde(skip)]
    y: Vec<f64>,
    #[serde(skip)]
    gap: Vec<f64>,
}

fn to_i32(n: usize) -> i32 {
    i32::try_from(n).unwrap_or(i32::MAX)
}

fn table(layout: &Layout) -> Result<(VariableTable, Vars), FmuError> {
    let na = layout.n_actuators();
    let ns = layout.n_sensors();
    let mut b = T::new();
    let layout_var = b.add_string(
        T::string("layout")
            .structural()
            .start_str(&layout.name)
            .describe("Mirror layout this FMU was packaged for"),
    );
    let n_segments = b.add_integer(
        T::integer("n_segments")
            .structural()
            .start_int(to_i32(layout.n_segments()))
            .describe("Number of segments (z and w have 3 x n_segments elements)"),
    );
    let n_sensors = b.add_integer(
        T::integer("n_sensors")
            .structural()
            .start_int(to_i32(ns))
            .describe(
                "Number of edge sensors (2 per shared edge; y and gap have n_sensors elements)",
            ),
    );
    let z = b.add_real(
        T::real("z")
            .input()
            .len(na)
            .unit("m")
            .start(0.0)
            .describe("Mirror displacement normal to the segment at each actuator"),
    );
    let w = b.add_real(T::real("w").input().len(na).start(0.0).describe(
        "In-plane segment motion along the prescription: w[3i+1] radial (m), \
                 w[3i+2] azimuthal (m), w[3i+3] clocking (rad) of segment i",
    ));
    let y = b.add_real(
        T::real("y")
            .output()
            .discrete()
            .len(ns)
            .unit("m")
            .depends(Dependencies::None)
            .describe("Edge-sensor reading: height difference + leff x dihedral, sampled and held"),
    );
    let gap = b.add_real(
        T::real("gap")
            .output()
            .discrete()
            .len(ns)
            .unit("m")
            .depends(Dependencies::None)
            .describe(
                "Edge-sensor gap reading: nominal gap + change from the motion, sampled and held",
            ),
    );
    let rms = |b: &mut T, name: &str, unit: &str, desc: &str| {
        b.add_real(
            T::real(name)
                .parameter()
                .unit(unit)
                .start(0.0)
                .non_negative()
                .describe(desc),
        )
    };
    let leff = b.add_real(
        T::real("leff")
            .parameter()
            .unit("m")
            .start(DEFAULT_LEFF)
            .non_negative()
            .describe("Effective moment arm of the sensors' dihedral sensitivity (0: pure height)"),
    );
    let gain_error_rms = rms(
        &mut b,
        "gain_error_rms",
        "1",
        "rms of the sensor gain errors (S = I + delta_S, 0.01 = 1 %)",
    );
    let noise_rms = rms(
        &mut b,
        "noise_rms",
        "m",
        "rms of the white noise on y, per sample",
    );
    let gap_noise_rms = rms(
        &mut b,
        "gap_noise_rms",
        "m",
        "rms of the white noise on gap, per sample",
    );
    let install_position_rms = rms(
        &mut b,
        "install_position_rms",
        "m",
        "rms in-plane installation error of each sensor point, per axis",
    );
    let install_tilt_rms = rms(
        &mut b,
        "install_tilt_rms",
        "rad",
        "rms installation tilt of each sensor about each in-plane axis",
    );
    let sample_rate = b.add_real(
        T::real("sample_rate")
            .parameter()
            .unit("Hz")
            .start(DEFAULT_SAMPLE_RATE)
            .positive()
            .describe("Sample rate of the sensors; readings are held between samples"),
    );
    let seed = b.add_integer(
        T::integer("seed")
            .parameter()
            .start_int(1)
            .non_negative()
            .describe("Seed of the gain errors, installation errors and noise"),
    );
    let install_a_change = b.add_real(
        T::real("install_a_change")
            .calculated_parameter()
            .unit("1")
            .describe("Relative Frobenius change of A caused by the installation errors"),
    );
    let table = b.build()?;
    Ok((
        table,
        Vars {
            layout: layout_var,
            n_segments,
            n_sensors,
            z,
            w,
            y,
            gap,
            leff,
            gain_error_rms,
            noise_rms,
            gap_noise_rms,
            install_position_rms,
            install_tilt_rms,
            sample_rate,
            seed,
            install_a_change,
        },
    ))
}

impl EdgeSensorsModel {
    /// Builds the sensors from the parameters in `v`.
    fn build(&self, v: &Values) -> Result<EdgeSensors, FmuError> {
        let x = &self.vars;
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let mut params = GeometryParams::for_layout(&layout);
        params.leff = v.scalar(x.leff);
        let geometry = Geometry::new(&layout, params).map_err(wiring::model_error)?;
        let errors = SensorErrors {
            gain_rms: v.scalar(x.gain_error_rms),
            noise_rms: v.scalar(x.noise_rms),
            gap_noise_rms: v.scalar(x.gap_noise_rms),
            position_rms: v.scalar(x.install_position_rms),
            tilt_rms: v.scalar(x.install_tilt_rms),
            seed: u64::from(v.integer(x.seed).unsigned_abs()),
        };
        EdgeSensors::new(&geometry, &errors).map_err(wiring::model_error)
    }

    /// The sensors, rebuilt if this instance came from a deserialised state.
    fn sensors(&mut self, v: &Values) -> Result<Arc<EdgeSensors>, FmuError> {
        if let Some(s) = &self.sensors {
            return Ok(Arc::clone(s));
        }
        let s = Arc::new(self.build(v)?);
        self.y = vec![0.0; s.n_sensors()];
        self.gap = vec![0.0; s.n_sensors()];
        self.sensors = Some(Arc::clone(&s));
        Ok(s)
    }

    /// Reads sample `k` from the inputs in `v` and writes the outputs.
    fn read(&mut self, v: &mut Values, k: u64) -> Result<(), FmuError> {
        let s = self.sensors(v)?;
        let x = self.vars;
        s.read_into(v.real(x.z), v.real(x.w), k, &mut self.y, &mut self.gap)
            .map_err(wiring::model_error)?;
        v.real_mut(x.y).copy_from_slice(&self.y);
        v.real_mut(x.gap).copy_from_slice(&self.gap);
        Ok(())
    }

    fn clock(&self) -> Result<SampleClock, FmuError> {
        self.clock
            .ok_or_else(|| FmuError::Model("the edge sensors are not initialised".into()))
    }

    /// The sensors of the initialised instance (for in-process use and tests).
    pub fn edge_sensors(&self) -> Option<&EdgeSensors> {
        self.sensors.as_deref()
    }
}

impl Model for EdgeSensorsModel {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "edge_sensors",
        model_name: "M1 edge sensors",
        description: "Edge-sensor readings (height + Leff x dihedral, gap) of a segmented mirror \
            from out-of-plane and in-plane segment motion, with gain errors, noise and \
            installation errors (seeded), sampled and held",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = table(&layout)?;
        Ok((
            table,
            Self {
                vars,
                layout: variant.to_string(),
                clock: None,
                sensors: None,
                y: Vec::new(),
                gap: Vec::new(),
            },
        ))
    }

    fn initialize(&mut self, v: &mut Values, start_time: f64) -> Result<(), FmuError> {
        let clock =
            SampleClock::new(start_time, v.scalar(self.vars.sample_rate)).map_err(|e| match e {
                M1Error::InvalidParameter { value, reason, .. } => FmuError::BadValue {
                    variable: "sample_rate".into(),
                    value: value.to_string(),
                    reason: reason.into(),
                },
                other => wiring::model_error(other),
            })?;
        let sensors = Arc::new(self.build(v)?);
        let ns = sensors.n_sensors();
        v.real_mut(self.vars.install_a_change)[0] = sensors.install_change();
        self.sensors = Some(sensors);
        self.y = vec![0.0; ns];
        self.gap = vec![0.0; ns];
        self.clock = Some(clock);
        self.read(v, 0)
    }

    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // The readings change only at sample instants, inside fmi2DoStep.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let mut clock = self.clock()?;
        let new = clock.advance_to(t + h);
        // Only the latest instant of the step shows; the inputs are held over the step.
        if let Some(k) = new.last() {
            self.read(v, k)?;
        }
        self.clock = Some(clock);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
