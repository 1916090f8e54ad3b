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
    FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T, Values, VariableTable,
};
use m1::aperture::geometry::{Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::loads::wind::{
    DEFAULT_AIR_DENSITY, OuterScale, ScreenParams, WindLoads, WindParams, pressure_rms_from_cp,
};

/// Number of (outer scale, energy fraction) pairs.
pub const N_SCALES: usize = 3;

/// Handles of every variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Vars {
    layout: StrVar,
    n_segments: IntVar,
    f_wind: RealVar,
    wind_speed: RealVar,
    wind_direction: RealVar,
    pressure_rms: RealVar,
    pressure_coefficient: RealVar,
    air_density: RealVar,
    outer_scale: [RealVar; N_SCALES],
    energy_fraction: [RealVar; N_SCALES],
    seed: IntVar,
    screen_size: RealVar,
    screen_samples: IntVar,
    actuator_radius: RealVar,
    effective_pressure_rms: RealVar,
    segment_force_rms: RealVar,
    aperture_attenuation: RealVar,
    flow_period: RealVar,
}

/// What the tables depend on.
#[derive(Debug, Clone, PartialEq)]
struct Key {
    wind: WindParams,
    actuator_radius: f64,
}

/// How many screens' tables a process keeps ([`Wind::build`]).
const SCREEN_CACHE: usize = 2;

/// The tables of the last [`SCREEN_CACHE`] screens built in this process, keyed by everything
/// but the speed and the rms pressure (the tables are those of the unit screen: see
/// [`WindLoads::with_flow`]). Instances share them while the library stays loaded: the
/// runtime's copy in initialisation mode, the closed-loop run after the open one, the runs of
/// a sweep over wind speed that reuses one extracted FMU.
static SCREENS: Mutex<Vec<(Key, Arc<WindLoads>)>> = Mutex::new(Vec::new());

/// The `wind` FMU.
#[derive(Clone, Serialize, Deserialize)]
pub struct Wind {
    vars: Vars,
    layout: String,
    na: usize,
    /// Rebuilt from the parameters after a deserialised FMU state (deterministic).
    #[serde(skip)]
    loads: Option<Arc<WindLoads>>,
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
24 N n_segments bytes of tables (11.5 MiB for TMT).</p>";

fn table(layout: &Layout) -> Result<(VariableTable, Vars), FmuError> {
    let na = layout.n_actuators();
    let screen = ScreenParams::default();
    let geometry = GeometryParams::for_layout(layout);
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
            .start_int(i32::try_from(layout.n_segments()).unwrap_or(i32::MAX))
            .describe("Number of segments (f_wind has 3 x n_segments elements)"),
    );
    let f_wind = b.add_real(T::real("f_wind").output().len(na).unit("N").describe(
        "Wind load as equivalent forces along the segment normal at the actuator points",
    ));
    let wind_speed = b.add_real(
        T::real("wind_speed")
            .parameter()
            .unit("m/s")
            .start(1.0)
            .non_negative()
            .describe("Mean wind speed across the mirror (frozen-flow speed)"),
    );
    let wind_direction = b.add_real(
        T::real("wind_direction")
            .parameter()
            .unit("deg")
            .start(0.0)
            .describe(
                "Direction the wind blows towards, counter-clockwise from the layout's x axis",
            ),
    );
    let pressure_rms = b.add_real(
        T::real("pressure_rms")
            .parameter()
            .unit("Pa")
            .start(0.0)
            .non_negative()
            .describe("rms pressure fluctuation; 0: use pressure_coefficient x 0.5 air_density wind_speed^2"),
    );
    let pressure_coefficient = b.add_real(
        T::real("pressure_coefficient")
            .parameter()
            .unit("1")
            .start(m1::loads::wind::DEFAULT_PRESSURE_COEFFICIENT)
            .non_negative()
            .describe(
                "rms pressure coefficient Cp (sigma_p = Cp q when pressure_rms is 0; calibrated: the \
                 default TMT plant's open loop at 1 m/s is the seed paper's Figure 12, 39 nm)",
            ),
    );
    let air_density = b.add_real(
        T::real("air_density")
            .parameter()
            .unit("kg/m3")
            .start(DEFAULT_AIR_DENSITY)
            .positive()
            .describe("Air density (0.82 kg/m3 at 4 km altitude)"),
    );
    let defaults = [(5.0, 0.75), (30.0, 0.25), (60.0, 0.0)];
    let outer_scale = std::array::from_fn(|j| {
        b.add_real(
            T::real(&format!("outer_scale_{}", j + 1))
                .parameter()
                .unit("m")
                .start(defaults[j].0)
                .positive()
                .describe(&format!("Outer scale L0 of pressure component {}", j + 1)),
        )
    });
    let energy_fraction = std::array::from_fn(|j| {
        b.add_real(
            T::real(&format!("energy_fraction_{}", j + 1))
                .parameter()
                .unit("1")
                .start(defaults[j].1)
                .non_negative()
                .describe(&format!(
                    "Variance share of component {} (normalised by the sum of the fractions; 0 disables it)",
                    j + 1
                )),
        )
    });
    let seed = b.add_integer(
        T::integer("seed")
            .parameter()
            .start_int(1)
            .describe("Seed of the pressure screen"),
    );
    let screen_size = b.add_real(
        T::real("screen_size")
            .parameter()
            .unit("m")
            .start(screen.size)
            .positive()
            .describe("Side of the square periodic screen (> mirror diameter; a few outer scales)"),
    );
    let screen_samples = b.add_integer(
        T::integer("screen_samples")
            .parameter()
            .start_int(i32::try_from(screen.samples).unwrap_or(1024))
            .check(fmu::Check::Range(16.0, 4096.0))
            .describe(
                "Samples per side of the screen (even; spacing screen_size / screen_samples)",
            ),
    );
    let actuator_radius = b.add_real(
        T::real("actuator_radius")
            .parameter()
            .unit("m")
            .start(geometry.actuator_radius)
            .positive()
            .describe("Radius of the actuator circle (equivalent-force points; default a / 2)"),
    );
    let calc = |b: &mut T, name: &str, unit: &str, desc: &str| {
        b.add_real(
            T::real(name)
                .calculated_parameter()
                .unit(unit)
                .describe(desc),
        )
    };
    let effective_pressure_rms = calc(
        &mut b,
        "effective_pressure_rms",
        "Pa",
        "rms pressure sigma_p in use",
    );
    let segment_force_rms = calc(
        &mut b,
        "segment_force_rms",
        "N",
        "Expected rms of the force integrated over one segment (projected area)",
    );
    let aperture_attenuation = calc(
        &mut b,
        "aperture_attenuation",
        "1",
        "segment_force_rms / (sigma_p x segment area): the attenuation by the integration",
    );
    let flow_period = calc(
        &mut b,
        "flow_period",
        "s",
        "Time after which the frozen flow repeats, screen_size / wind_speed (0 if no wind)",
    );
    let table = b.build()?;
    Ok((
        table,
        Vars {
            layout: layout_var,
            n_segments,
            f_wind,
            wind_speed,
            wind_direction,
            pressure_rms,
            pressure_coefficient,
            air_density,
            outer_scale,
            energy_fraction,
            seed,
            screen_size,
            screen_samples,
            actuator_radius,
            effective_pressure_rms,
            segment_force_rms,
            aperture_attenuation,
            flow_period,
        },
    ))
}

impl Wind {
    /// Reads and checks the parameters.
    fn key(&self, v: &Values) -> Result<Key, FmuError> {
        let x = &self.vars;
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

    /// The tables for the current parameters: the screen from the process's cache (at this
    /// speed and rms pressure), or built and cached.
    fn build(&self, v: &Values) -> Result<Arc<WindLoads>, FmuError> {
        let key = self.key(v)?;
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
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
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

    fn write_outputs(
        loads: &WindLoads,
        vars: &Vars,
        t: f64,
        v: &mut Values,
    ) -> Result<(), FmuError> {
        loads
            .forces(t, v.real_mut(vars.f_wind))
            .map_err(wiring::model_error)
    }

    /// The wind loads, once initialised (for in-process use and tests).
    pub fn loads(&self) -> Option<&WindLoads> {
        self.loads.as_deref()
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

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = table(&layout)?;
        Ok((
            table,
            Wind {
                vars,
                layout: layout.name.clone(),
                na: layout.n_actuators(),
                loads: None,
            },
        ))
    }

    fn initialize(&mut self, v: &mut Values, start_time: f64) -> Result<(), FmuError> {
        let loads = self.build(v)?;
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
        Self::write_outputs(&loads, &x, start_time, v)?;
        self.loads = Some(loads);
        Ok(())
    }

    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // No inputs: the outputs only change with time.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let loads = match self.loads.take() {
            Some(l) => l,
            // After a deserialised FMU state: the tables are rebuilt from the parameters.
            None => self.build(v)?,
        };
        // The tables go back whatever happens: an error leaves the model as it was.
        let r = Self::write_outputs(&loads, &self.vars, t + h, v);
        self.loads = Some(loads);
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = Wind::new(variant).expect("table");
            let na = Layout::preset(variant).expect("layout").n_actuators();
            let f = t.by_name("f_wind").expect("f_wind");
            assert_eq!((f.len, f.unit.as_deref()), (na, Some("N")));
        }
    }
}
