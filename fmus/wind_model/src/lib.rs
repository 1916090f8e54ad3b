//! Model wiring of the `wind` FMU: wind loads on the segments from frozen-flow von Karman
//! pressure screens ([`m1::loads::wind`]).
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `f_wind` | output | na | N |
//!
//! with na = 3 x the number of segments of the packaged layout (actuator k of segment i at index
//! 3 i + k, 1-based in FMI names: `f_wind[3 i + k + 1]`). The FMU has no inputs: its output is
//! a function of time, computed by interpolating tables made once at initialisation.

use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};

use fmu::{
    Decl, FmuError, IntVar, Model, ModelInfo, RealVar, Running, StrVar, TableBuilder as T, Values,
    VariableTable,
};
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::loads::wind::{
    DEFAULT_AIR_DENSITY, DEFAULT_PRESSURE_COEFFICIENT, OuterScale, ScreenParams, WindLoads,
    WindParams, pressure_rms_from_cp,
};
use wiring::signals::{F_WIND, layout_decl, n_segments_decl};

/// Number of (outer scale, energy fraction) pairs.
pub const N_SCALES: usize = 3;

/// Default (outer scale m, energy fraction) of each pair.
const DEFAULT_SCALES: [(f64, f64); N_SCALES] = [(5.0, 0.75), (30.0, 0.25), (60.0, 0.0)];

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        f_wind: RealVar = F_WIND.output(layout),
        wind_speed: RealVar = T::real("wind_speed").parameter().unit("m/s").start(1.0)
            .non_negative().describe("Mean wind speed across the mirror (frozen-flow speed)"),
        wind_direction: RealVar = T::real("wind_direction").parameter().unit("deg").start(0.0)
            .describe("Direction the wind blows towards, counter-clockwise from the layout's x \
                       axis"),
        pressure_rms: RealVar = T::real("pressure_rms").parameter().unit("Pa").start(0.0)
            .non_negative()
            .describe("rms pressure fluctuation; 0: use pressure_coefficient x 0.5 air_density \
                       wind_speed^2"),
        pressure_coefficient: RealVar = T::real("pressure_coefficient").parameter().unit("1")
            .start(DEFAULT_PRESSURE_COEFFICIENT).non_negative()
            .describe("rms pressure coefficient Cp (sigma_p = Cp q when pressure_rms is 0; \
                       calibrated: the default TMT plant's open loop at 1 m/s is the seed paper's \
                       Figure 12, 39 nm)"),
        air_density: RealVar = T::real("air_density").parameter().unit("kg/m3")
            .start(DEFAULT_AIR_DENSITY).positive()
            .describe("Air density (0.82 kg/m3 at 4 km altitude)"),
        outer_scale: [RealVar; N_SCALES] => per_scale(b, |j| {
            T::real(&format!("outer_scale_{}", j + 1)).parameter().unit("m")
                .start(DEFAULT_SCALES[j].0).positive()
                .describe(&format!("Outer scale L0 of pressure component {}", j + 1))
        }),
        energy_fraction: [RealVar; N_SCALES] => per_scale(b, |j| {
            T::real(&format!("energy_fraction_{}", j + 1)).parameter().unit("1")
                .start(DEFAULT_SCALES[j].1).non_negative()
                .describe(&format!("Variance share of component {} (normalised by the sum of the \
                                    fractions; 0 disables it)", j + 1))
        }),
        seed: IntVar = T::integer("seed").parameter().start_int(1)
            .describe("Seed of the pressure screen"),
        screen_size: RealVar = T::real("screen_size").parameter().unit("m")
            .start(ScreenParams::default().size).positive()
            .describe("Side of the square periodic screen (> mirror diameter; a few outer scales)"),
        screen_samples: IntVar = T::integer("screen_samples").parameter()
            .start_int(i32::try_from(ScreenParams::default().samples).unwrap_or(1024))
            .check(fmu::Check::Range(16.0, 4096.0))
            .describe("Samples per side of the screen (even; spacing screen_size / \
                       screen_samples)"),
        actuator_radius: RealVar = T::real("actuator_radius").parameter().unit("m")
            .start(GeometryParams::for_layout(layout).actuator_radius).positive()
            .describe("Radius of the actuator circle (equivalent-force points; default a / 2)"),
        effective_pressure_rms: RealVar = calculated("effective_pressure_rms", "Pa")
            .describe("rms pressure sigma_p in use"),
        segment_force_rms: RealVar = calculated("segment_force_rms", "N")
            .describe("Expected rms of the force integrated over one segment (projected area)"),
        aperture_attenuation: RealVar = calculated("aperture_attenuation", "1")
            .describe("segment_force_rms / (sigma_p x segment area): the attenuation by the \
                       integration"),
        flow_period: RealVar = calculated("flow_period", "s")
            .describe("Time after which the frozen flow repeats, screen_size / wind_speed (0 if \
                       no wind)"),
    }
}

/// One parameter per pair, `..._1` to `..._3` in this order (`decl(j)` declares pair j + 1):
/// the three outer scales come first, then the three energy fractions.
fn per_scale(b: &mut T, decl: impl Fn(usize) -> Decl) -> [RealVar; N_SCALES] {
    std::array::from_fn(|j| b.add_real(decl(j)))
}

/// A calculated parameter with its unit.
fn calculated(name: &str, unit: &str) -> Decl {
    T::real(name).calculated_parameter().unit(unit)
}

/// What the tables depend on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Key {
    wind: WindParams,
    actuator_radius: f64,
}

/// How many screens' tables a process keeps ([`build`]).
const SCREEN_CACHE: usize = 2;

/// The tables of the last [`SCREEN_CACHE`] screens built in this process, keyed by everything
/// but the speed and the rms pressure (the tables are those of the unit screen: see
/// [`WindLoads::with_flow`]). Instances share them while the library stays loaded: the
/// runtime's initialisation in initialisation mode, the closed-loop run after the open one, the
/// runs of a sweep over wind speed that reuses one extracted FMU, a deserialised FMU state.
static SCREENS: Mutex<Vec<(Key, Arc<WindLoads>)>> = Mutex::new(Vec::new());

/// The `wind` FMU as configured: the handles and the layout; [`WindRunning`] steps.
#[derive(Debug, Clone)]
pub struct Wind {
    vars: Vars,
    layout: String,
    na: usize,
}

/// The initialised `wind` FMU: the tables of the wind loads.
///
/// An FMU state serialises the parameters the tables were made from, not the tables: they are
/// rebuilt (deterministic, from the process's cache when there) when it is read back.
#[derive(Clone, Serialize, Deserialize)]
#[serde(try_from = "WindState", into = "WindState")]
pub struct WindRunning {
    vars: Vars,
    layout: String,
    key: Key,
    loads: Arc<WindLoads>,
}

/// What a serialised [`WindRunning`] holds.
#[derive(Serialize, Deserialize)]
struct WindState {
    vars: Vars,
    layout: String,
    key: Key,
}

impl From<WindRunning> for WindState {
    fn from(r: WindRunning) -> Self {
        WindState {
            vars: r.vars,
            layout: r.layout,
            key: r.key,
        }
    }
}

impl TryFrom<WindState> for WindRunning {
    type Error = FmuError;

    fn try_from(s: WindState) -> Result<Self, FmuError> {
        let loads = build(&s.layout, &s.key)?;
        Ok(WindRunning {
            vars: s.vars,
            layout: s.layout,
            key: s.key,
            loads,
        })
    }
}

const DOC: &str = "<h2>Model</h2>\
<p>The pressure fluctuation on the mirror is a sum of von Karman fields (2-D spectrum \
&Phi;(k) = &sigma;<sup>2</sup> (&beta;/2&minus;1)/&pi; k<sub>0</sub><sup>&beta;&minus;2</sup> \
(k<sup>2</sup>+k<sub>0</sub><sup>2</sup>)<sup>&minus;&beta;/2</sup>, &beta; = 11/3, \
k<sub>0</sub> = 1/L<sub>0</sub>, k in cycles/m), one per outer scale \
<code>outer_scale_j</code> with variance share <code>energy_fraction_j</code> (fractions normalised \
by their sum; 0 disables a pair). One periodic screen of <code>screen_samples</code><sup>2</sup> \
points over <code>screen_size</code><sup>2</sup> is synthesised by FFT at initialisation \
(seeded by <code>seed</code>; the discrete spectrum, mean removed, is scaled to total variance \
&sigma;<sub>p</sub><sup>2</sup> exactly). It moves across the mirror in frozen flow at \
<code>wind_speed</code> towards <code>wind_direction</code> (degrees counter-clockwise from the \
layout's x axis) and repeats seamlessly after <code>flow_period</code> = \
<code>screen_size</code>/<code>wind_speed</code>.</p>\
<p>&sigma;<sub>p</sub> = <code>pressure_rms</code>, or when that is 0, \
C<sub>p</sub> &middot; &frac12; &rho; U<sup>2</sup> with C<sub>p</sub> = \
<code>pressure_coefficient</code> and &rho; = <code>air_density</code>.</p>\
<p>On each segment the pressure is integrated exactly over its hexagon (force and the two first \
moments about the centre, by the hexagon's Fourier transform: the aperture filter that \
attenuates the high spatial frequencies, reported as <code>aperture_attenuation</code> = \
rms force / (&sigma;<sub>p</sub> &times; area)). The pressure pushes the front face: the force \
along the segment normal is F = &minus;&int;p dA. The load [F, M<sub>radial</sub>, \
M<sub>azimuthal</sub>] becomes the equivalent forces at the three actuator points (radius \
<code>actuator_radius</code>), f = P<sup>&minus;T</sup> [F, M<sub>r</sub>, M<sub>a</sub>], which \
reproduce the force and both moments exactly. The loads are tabulated along the flow at \
initialisation; each step only interpolates them (cubic) at the shift U t, so <code>f_wind</code> \
at time t is the load at t whatever the communication steps.</p>\
<p>Initialisation: under a second for TMT at the default 1024<sup>2</sup> screen \
(release build); memory 48 N<sup>2</sup> bytes during initialisation (48 MiB at N = 1024) and \
24 N s bytes of tables, s the segments rounded up to a multiple of 8 (11.6 MiB for TMT).</p>";

/// Reads and checks the parameters.
fn key(x: &Vars, v: &Values) -> Result<Key, FmuError> {
    let s = |h: RealVar| v.scalar(h);
    let fractions: f64 = x.energy_fraction.iter().map(|&h| s(h)).sum();
    if fractions <= 0.0 {
        return Err(FmuError::BadValue {
            variable: "energy_fraction_1".into(),
            value: s(x.energy_fraction[0]).to_string(),
            reason: "the energy fractions energy_fraction_1..3 must have a positive sum".into(),
        });
    }
    let samples = v.integer(x.screen_samples);
    if samples % 2 != 0 {
        return Err(FmuError::BadValue {
            variable: "screen_samples".into(),
            value: samples.to_string(),
            reason: "must be even".into(),
        });
    }
    let speed = s(x.wind_speed);
    let mut sigma = s(x.pressure_rms);
    if sigma == 0.0 {
        sigma = pressure_rms_from_cp(s(x.pressure_coefficient), s(x.air_density), speed);
    }
    Ok(Key {
        wind: WindParams {
            speed,
            direction: s(x.wind_direction),
            screen: ScreenParams {
                pressure_rms: sigma,
                outer_scales: (0..N_SCALES)
                    .map(|j| OuterScale {
                        outer_scale: s(x.outer_scale[j]),
                        fraction: s(x.energy_fraction[j]),
                    })
                    .collect(),
                size: s(x.screen_size),
                samples: usize::try_from(samples).unwrap_or(0),
                seed: u64::from(v.integer(x.seed) as u32),
            },
        },
        actuator_radius: s(x.actuator_radius),
    })
}

/// The tables of `layout` for `key`: the screen from the process's cache (at this speed and
/// rms pressure), or built and cached.
fn build(layout: &str, key: &Key) -> Result<Arc<WindLoads>, FmuError> {
    let (speed, sigma) = (key.wind.speed, key.wind.screen.pressure_rms);
    let mut screen_key = key.clone();
    screen_key.wind.speed = 0.0;
    screen_key.wind.screen.pressure_rms = 1.0;
    // A poisoned lock only means another instance panicked while holding it: the cached
    // entries are complete values, still valid.
    let cached = SCREENS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .iter()
        .find(|(k, _)| *k == screen_key)
        .map(|(_, l)| l.clone());
    if let Some(loads) = cached {
        let loads = loads.with_flow(speed, sigma).map_err(wiring::model_error)?;
        return Ok(Arc::new(loads));
    }
    let layout = Layout::preset(layout).map_err(|e| FmuError::Model(e.to_string()))?;
    let params = GeometryParams {
        actuator_radius: key.actuator_radius,
        ..GeometryParams::for_layout(&layout)
    };
    let geometry = Geometry::new(&layout, params).map_err(wiring::model_error)?;
    let loads = Arc::new(WindLoads::new(&geometry, &key.wind).map_err(wiring::model_error)?);
    let mut cache = SCREENS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    cache.retain(|(k, _)| *k != screen_key);
    cache.push((screen_key, loads.clone()));
    if cache.len() > SCREEN_CACHE {
        cache.remove(0);
    }
    Ok(loads)
}

impl WindRunning {
    /// The wind loads (for in-process use and tests).
    pub fn loads(&self) -> &WindLoads {
        &self.loads
    }

    /// Writes `f_wind` at time `t`.
    fn write_outputs(&self, t: f64, v: &mut Values) -> Result<(), FmuError> {
        self.loads
            .forces(t, v.real_mut(self.vars.f_wind))
            .map_err(wiring::model_error)
    }
}

impl Model for Wind {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "wind",
        model_name: "M1 wind loads",
        description: "Wind loads on every segment of a segmented primary mirror: von Karman pressure \
            screens (several outer scales) in frozen flow, integrated over each hexagon, as \
            equivalent forces at the actuator points",
        documentation: DOC,
        default_stop_time: 10.0,
        default_step: 1e-2,
    };

    type Running = WindRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        Ok((
            table,
            Wind {
                vars,
                layout: layout.name.clone(),
                na: layout.n_actuators(),
            },
        ))
    }

    fn initialize(&self, v: &mut Values, start_time: f64) -> Result<WindRunning, FmuError> {
        let key = key(&self.vars, v)?;
        let loads = build(&self.layout, &key)?;
        if loads.n_actuators() != self.na {
            return Err(FmuError::Model(format!(
                "the wind tables have {} actuators, the FMU {}",
                loads.n_actuators(),
                self.na
            )));
        }
        let x = self.vars;
        let sigma = loads.pressure_rms();
        let rms = loads.expected_force_rms();
        let reference = sigma * loads.segment_area();
        v.real_mut(x.effective_pressure_rms)[0] = sigma;
        v.real_mut(x.segment_force_rms)[0] = rms;
        v.real_mut(x.aperture_attenuation)[0] = if reference > 0.0 {
            rms / reference
        } else {
            0.0
        };
        v.real_mut(x.flow_period)[0] = loads.period().unwrap_or(0.0);
        let running = WindRunning {
            vars: x,
            layout: self.layout.clone(),
            key,
            loads,
        };
        running.write_outputs(start_time, v)?;
        Ok(running)
    }
}

impl Running for WindRunning {
    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // No inputs: the outputs only change with time.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        self.write_outputs(t + h, v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    /// An instance of `variant` through the runtime, in initialisation mode (start time 0).
    fn instance(variant: &str) -> Instance<Wind> {
        let (table, _) = Wind::new(variant).expect("table");
        let guid = fmu::xml::guid(&Wind::INFO, &table);
        let mut fmu = Instance::<Wind>::new("test", &guid, None, None, false).expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu
    }

    /// The value references of a variable's scalars.
    fn vrs(fmu: &Instance<Wind>, name: &str) -> Vec<u32> {
        let v = fmu.table().by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    /// `steps` communication steps of 10 ms, then the values of `name`.
    fn run(fmu: &mut Instance<Wind>, steps: usize, name: &str) -> Vec<f64> {
        for _ in 0..steps {
            let t = fmu.time();
            fmu.do_step(t, 0.01).expect("step");
        }
        let vr = vrs(fmu, name);
        let mut out = vec![f64::NAN; vr.len()];
        fmu.get_real(&vr, &mut out).expect("get");
        out
    }

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = Wind::new(variant).expect("table");
            let na = Layout::preset(variant).expect("layout").n_actuators();
            let f = t.by_name("f_wind").expect("f_wind");
            assert_eq!((f.len, f.unit.as_deref()), (na, Some("N")));
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<Wind>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// A serialised FMU state (the tables rebuilt from the parameters it holds) steps on
    /// exactly as the instance it was taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let mut fmu = instance("keck");
        fmu.set_integer(&vrs(&fmu, "screen_samples"), &[64])
            .expect("screen_samples");
        fmu.set_real(&vrs(&fmu, "wind_speed"), &[5.0])
            .expect("wind_speed");
        fmu.exit_initialization_mode().expect("initialise");
        let na = Layout::preset("keck").expect("layout").n_actuators();
        assert_eq!(fmu.running().expect("running").loads().n_actuators(), na);
        run(&mut fmu, 1, "f_wind");
        let bytes =
            Instance::<Wind>::serialize(&fmu.get_state().expect("state")).expect("serialise");
        let original = run(&mut fmu, 3, "f_wind");
        let state = fmu.deserialize(&bytes).expect("deserialise");
        fmu.set_state(&state).expect("set state");
        let restored = run(&mut fmu, 3, "f_wind");
        assert!(original.iter().any(|&f| f != 0.0));
        assert_eq!(original, restored);
    }
}
