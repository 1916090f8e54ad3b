//! Model wiring of the `global_controller` FMU: the global edge-sensor control loop
//! (reconstructor with global piston/tip/tilt projected out, modal integral control at 20 Hz),
//! computed by [`m1::control::controller::ControlModes`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `y` | input | ns | m |
//! | `y_ref` | input | ns | m |
//! | `u_cmd` | output | na | m |
//!
//! with na = 3 x the number of segments and ns the number of edge sensors of the packaged
//! layout.
//!
//! # Sampling
//!
//! The loop samples at its own instants `t0 + k / rate` (`k >= 1`), whatever the communication
//! step (steps need not divide the period). A step `(t, t + h]` takes every instant in it with
//! the readings held over the step (set at `t`), so `u_cmd` at a communication point equal to a
//! sample instant already shows that sample's command, and is held in between. `u_cmd` never
//! depends directly on `y` (ModelStructure: no dependencies; discrete variability): a closed
//! loop edge sensors -> controller -> segments has no algebraic loop.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use fmu::{
    BoolVar, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T,
    Values, VariableTable,
};
use m1::aperture::geometry::{DEFAULT_LEFF, Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::{
    ControlModes, ControllerParams, ControllerState, DEFAULT_BANDWIDTH, DEFAULT_BANDWIDTH_FOCUS,
    DEFAULT_BANDWIDTH_RADIAL2, DEFAULT_BANDWIDTH_RADIAL34, DEFAULT_FOCUS_GAIN, DEFAULT_RATE,
    LoopGains, Scratch,
};

const DOC: &str = "<h2>Model</h2>\
<p>At each sample instant t<sub>k</sub> = t<sub>0</sub> + k / <code>rate</code> (k &ge; 1) the \
command is updated by a discrete integrator in a modal decomposition:</p>\
<p><code>u<sub>k+1</sub> = u<sub>k</sub> &minus; G P B<sub>0</sub> (y &minus; y_ref)</code>, \
<code>G = g (P &minus; &psi;<sub>f</sub>&psi;<sub>f</sub><sup>T</sup> &minus; R<sub>2</sub> \
R<sub>2</sub><sup>T</sup> &minus; R<sub>34</sub> R<sub>34</sub><sup>T</sup>) + g<sub>34</sub> \
R<sub>34</sub> R<sub>34</sub><sup>T</sup> + g<sub>2</sub> R<sub>2</sub> R<sub>2</sub><sup>T</sup> + \
&Gamma; g<sub>f</sub> &psi;<sub>f</sub>&psi;<sub>f</sub><sup>T</sup></code></p>\
<p>B<sub>0</sub> is the least-squares reconstructor of the A-matrix (the model of the sensors, \
with <code>leff</code>) with global piston, tip and tilt projected out (P), computed by a sparse \
block-Cholesky factorisation. The four mode groups are orthogonal: focus-mode &psi;<sub>f</sub> \
(the least observable mode of A, almost exactly Z4), the radial-degree-2 group R<sub>2</sub> \
(the span of Z4, Z5, Z6 projected on the segments' piston/tip/tilt, without global \
piston/tip/tilt and without its direction closest to focus-mode: astigmatism), the \
radial-degree-3-4 group R<sub>34</sub> (the span of Z7 to Z15 projected the same way, without \
global piston/tip/tilt, the whole radial-degree-2 span and focus-mode: nine modes), and every \
other mode (radial degrees 5 and up). Each group's loop on a perfect plant is exactly a \
first-order discrete integrator with gain <code>g = 1 &minus; exp(&minus;2&pi; f<sub>bw</sub> / \
rate)</code> (the pole of the continuous loop with bandwidth f<sub>bw</sub>): \
<code>bandwidth</code> (1.5 Hz) for radial degrees 5 and up, <code>bandwidth_radial34</code> \
(1 Hz) for radial degrees 3-4, <code>bandwidth_radial2</code> (0.75 Hz) for astigmatism, \
<code>bandwidth_focus</code> (0.1 Hz) times the modal gain &Gamma; = <code>focus_gain</code> for \
focus-mode (the seed paper's baseline tuning). The calculated parameters <code>loop_gain*</code> \
report the gains per sample.</p>\
<p><b>Sign convention</b>: the reading of a displacement z is A z; the loop drives the mirror to \
the state whose readings equal <code>y_ref</code> (u &larr; u &minus; g B (y &minus; y_ref)). \
The command never contains global piston, tip or tilt.</p>\
<p><b>Sampling</b>: samples are taken at the loop's own instants whatever the communication \
step, each with the readings held over the step; u_cmd changes only at sample instants and does \
not depend directly on y (no algebraic loop). <code>enabled</code> = false (tunable) opens the \
loop: the instants pass and u_cmd is held.</p>";

/// Handles of every variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Vars {
    layout: StrVar,
    n_segments: IntVar,
    n_sensors: IntVar,
    y: RealVar,
    y_ref: RealVar,
    u_cmd: RealVar,
    rate: RealVar,
    bandwidth: RealVar,
    bandwidth_radial2: RealVar,
    bandwidth_radial34: RealVar,
    bandwidth_focus: RealVar,
    focus_gain: RealVar,
    leff: RealVar,
    enabled: BoolVar,
    loop_gain: RealVar,
    loop_gain_radial2: RealVar,
    loop_gain_radial34: RealVar,
    loop_gain_focus: RealVar,
}

/// The `global_controller` FMU.
#[derive(Clone, Serialize, Deserialize)]
pub struct GlobalControllerModel {
    vars: Vars,
    layout: String,
    /// The held command and the sample clock; `None` before initialisation.
    state: Option<ControllerState>,
    gains: Option<LoopGains>,
    /// Reconstructor and modes (rebuilt from the parameters after a deserialised state).
    #[serde(skip)]
    modes: Option<Arc<ControlModes>>,
    #[serde(skip)]
    scratch: Option<Scratch>,
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
            .describe("Number of segments (u_cmd has 3 x n_segments elements)"),
    );
    let n_sensors = b.add_integer(
        T::integer("n_sensors")
            .structural()
            .start_int(to_i32(ns))
            .describe("Number of edge sensors (y and y_ref have n_sensors elements)"),
    );
    let y = b.add_real(
        T::real("y")
            .input()
            .len(ns)
            .unit("m")
            .start(0.0)
            .describe("Edge-sensor readings (height + leff x dihedral)"),
    );
    let y_ref = b.add_real(
        T::real("y_ref")
            .input()
            .len(ns)
            .unit("m")
            .start(0.0)
            .describe("Desired edge-sensor readings (set-points)"),
    );
    let u_cmd = b.add_real(
        T::real("u_cmd")
            .output()
            .discrete()
            .len(na)
            .unit("m")
            .depends(Dependencies::None)
            .describe("Actuator position command, updated at the loop's sample instants and held"),
    );
    let hz = |b: &mut T, name: &str, x: f64, desc: &str| {
        b.add_real(
            T::real(name)
                .parameter()
                .unit("Hz")
                .start(x)
                .non_negative()
                .describe(desc),
        )
    };
    let rate = b.add_real(
        T::real("rate")
            .parameter()
            .unit("Hz")
            .start(DEFAULT_RATE)
            .positive()
            .describe("Sample rate of the global loop"),
    );
    let bandwidth = hz(
        &mut b,
        "bandwidth",
        DEFAULT_BANDWIDTH,
        "Closed-loop bandwidth of the modes of radial degrees >= 5 (every mode outside the \
         radial-degree-2 to 4 groups and focus-mode) (< rate / 2)",
    );
    let bandwidth_radial2 = hz(
        &mut b,
        "bandwidth_radial2",
        DEFAULT_BANDWIDTH_RADIAL2,
        "Closed-loop bandwidth of the radial-degree-2 modes without focus-mode (astigmatism) \
         (< rate / 2)",
    );
    let bandwidth_focus = hz(
        &mut b,
        "bandwidth_focus",
        DEFAULT_BANDWIDTH_FOCUS,
        "Closed-loop bandwidth of focus-mode (before the modal gain focus_gain) (< rate / 2)",
    );
    let focus_gain = b.add_real(
        T::real("focus_gain")
            .parameter()
            .unit("1")
            .start(DEFAULT_FOCUS_GAIN)
            .check(fmu::Check::Range(0.0, 1.0))
            .describe("Modal gain Gamma of the reconstructor on focus-mode (the paper uses 1/4)"),
    );
    let leff = b.add_real(
        T::real("leff")
            .parameter()
            .unit("m")
            .start(DEFAULT_LEFF)
            .non_negative()
            .describe("Effective dihedral moment arm of the sensor model the reconstructor uses"),
    );
    let enabled = b.add_boolean(
        T::boolean("enabled")
            .tunable()
            .start_bool(true)
            .describe("Close the loop (false: the sample instants pass and u_cmd is held)"),
    );
    let calc = |b: &mut T, name: &str, desc: &str| {
        b.add_real(
            T::real(name)
                .calculated_parameter()
                .unit("1")
                .describe(desc),
        )
    };
    let loop_gain = calc(
        &mut b,
        "loop_gain",
        "Integrator gain per sample of radial degrees >= 5, 1 - exp(-2 pi bandwidth / rate)",
    );
    let loop_gain_radial2 = calc(
        &mut b,
        "loop_gain_radial2",
        "Integrator gain per sample of the radial-degree-2 group",
    );
    let loop_gain_focus = calc(
        &mut b,
        "loop_gain_focus",
        "Integrator gain per sample of focus-mode, focus_gain x (1 - exp(-2 pi bandwidth_focus / rate))",
    );
    // Declared last: the value references follow the declaration order per type, so those of
    // the Reals declared before are unchanged.
    let bandwidth_radial34 = hz(
        &mut b,
        "bandwidth_radial34",
        DEFAULT_BANDWIDTH_RADIAL34,
        "Closed-loop bandwidth of the modes of radial degrees 3-4 (Z7 to Z15, without radial \
         degree 2 and focus-mode) (< rate / 2)",
    );
    let loop_gain_radial34 = calc(
        &mut b,
        "loop_gain_radial34",
        "Integrator gain per sample of the radial-degree-3-4 group",
    );
    let table = b.build()?;
    Ok((
        table,
        Vars {
            layout: layout_var,
            n_segments,
            n_sensors,
            y,
            y_ref,
            u_cmd,
            rate,
            bandwidth,
            bandwidth_radial2,
            bandwidth_radial34,
            bandwidth_focus,
            focus_gain,
            leff,
            enabled,
            loop_gain,
            loop_gain_radial2,
            loop_gain_radial34,
            loop_gain_focus,
        },
    ))
}

impl GlobalControllerModel {
    fn params(&self, v: &Values) -> ControllerParams {
        let x = &self.vars;
        ControllerParams {
            rate: v.scalar(x.rate),
            bandwidth: v.scalar(x.bandwidth),
            bandwidth_radial34: v.scalar(x.bandwidth_radial34),
            bandwidth_radial2: v.scalar(x.bandwidth_radial2),
            bandwidth_focus: v.scalar(x.bandwidth_focus),
            focus_gain: v.scalar(x.focus_gain),
        }
    }

    fn build(&self, v: &Values) -> Result<ControlModes, FmuError> {
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let mut params = GeometryParams::for_layout(&layout);
        params.leff = v.scalar(self.vars.leff);
        let geometry = Geometry::new(&layout, params).map_err(wiring::model_error)?;
        ControlModes::new(geometry).map_err(wiring::model_error)
    }

    /// The reconstructor and modes, rebuilt if this instance came from a deserialised state.
    fn modes(&mut self, v: &Values) -> Result<Arc<ControlModes>, FmuError> {
        if let Some(m) = &self.modes {
            return Ok(Arc::clone(m));
        }
        let m = Arc::new(self.build(v)?);
        self.modes = Some(Arc::clone(&m));
        Ok(m)
    }

    /// The modes of the initialised instance (for in-process use and tests).
    pub fn control_modes(&self) -> Option<&ControlModes> {
        self.modes.as_deref()
    }
}

impl Model for GlobalControllerModel {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "global_controller",
        model_name: "M1 global edge-sensor controller",
        description: "Global control loop of a segmented mirror: sparse reconstructor with global \
            piston/tip/tilt projected out, modal discrete integrators (radial degrees >= 5 at \
            1.5 Hz, 3-4 at 1 Hz, 2 at 0.75 Hz, focus-mode at 0.1 Hz) sampled at 20 Hz, command \
            held between samples",
        documentation: DOC,
        default_stop_time: 2.0,
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
                state: None,
                gains: None,
                modes: None,
                scratch: None,
            },
        ))
    }

    fn initialize(&mut self, v: &mut Values, start_time: f64) -> Result<(), FmuError> {
        let params = self.params(v);
        let gains = params.gains().map_err(wiring::model_error)?;
        let modes = Arc::new(self.build(v)?);
        let na = modes.shape().0;
        let state =
            ControllerState::new(na, start_time, params.rate).map_err(wiring::model_error)?;
        v.real_mut(self.vars.loop_gain)[0] = gains.rest;
        v.real_mut(self.vars.loop_gain_radial2)[0] = gains.radial2;
        v.real_mut(self.vars.loop_gain_radial34)[0] = gains.radial34;
        v.real_mut(self.vars.loop_gain_focus)[0] = gains.focus;
        v.real_mut(self.vars.u_cmd).copy_from_slice(&state.u);
        self.scratch = Some(modes.scratch());
        self.modes = Some(modes);
        self.gains = Some(gains);
        self.state = Some(state);
        Ok(())
    }

    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // u_cmd changes only at sample instants, inside fmi2DoStep.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let modes = self.modes(v)?;
        let x = self.vars;
        let (Some(state), Some(gains)) = (self.state.as_mut(), self.gains) else {
            return Err(FmuError::Model(
                "the global controller is not initialised".into(),
            ));
        };
        let scratch = self.scratch.get_or_insert_with(|| modes.scratch());
        modes
            .advance(
                &gains,
                state,
                v.boolean(x.enabled),
                t + h,
                v.real(x.y),
                v.real(x.y_ref),
                scratch,
            )
            .map_err(wiring::model_error)?;
        v.real_mut(x.u_cmd).copy_from_slice(&state.u);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = GlobalControllerModel::new(variant).expect("table");
            let layout = Layout::preset(variant).expect("layout");
            let u = t.by_name("u_cmd").expect("u_cmd");
            assert_eq!(u.len, layout.n_actuators());
            assert_eq!(u.dependencies, Dependencies::None);
            assert_eq!(t.by_name("y").expect("y").len, layout.n_sensors());
        }
    }

    /// `bandwidth_radial34` and `loop_gain_radial34` are the last Reals: the value references of
    /// the Reals declared before are those they had without them. The start values are the
    /// seed paper's baseline and the new bandwidth reaches its calculated gain.
    #[test]
    fn the_radial34_bandwidth_is_appended_and_sets_its_gain() {
        let (t, mut m) = GlobalControllerModel::new("keck").expect("model");
        let layout = Layout::preset("keck").expect("layout");
        let (na, ns) = (layout.n_actuators(), layout.n_sensors());
        let vr = |n: &str| t.by_name(n).expect(n).vr as usize;
        assert_eq!((vr("y"), vr("y_ref"), vr("u_cmd")), (0, ns, 2 * ns));
        let scalars = [
            "rate",
            "bandwidth",
            "bandwidth_radial2",
            "bandwidth_focus",
            "focus_gain",
            "leff",
            "loop_gain",
            "loop_gain_radial2",
            "loop_gain_focus",
            "bandwidth_radial34",
            "loop_gain_radial34",
        ];
        for (k, name) in scalars.iter().enumerate() {
            assert_eq!(vr(name), 2 * ns + na + k, "{name}");
        }
        let mut v = t.initial_values();
        assert_eq!(v.reals[vr("bandwidth")], 1.5);
        assert_eq!(v.reals[vr("bandwidth_radial34")], 1.0);
        assert_eq!(v.reals[vr("bandwidth_radial2")], 0.75);
        assert_eq!(v.reals[vr("bandwidth_focus")], 0.1);
        v.reals[vr("bandwidth_radial34")] = 0.5;
        m.initialize(&mut v, 0.0).expect("initialize");
        let g = |f: f64| 1.0 - (-std::f64::consts::TAU * f / 20.0).exp();
        for (name, f) in [
            ("loop_gain", 1.5),
            ("loop_gain_radial34", 0.5),
            ("loop_gain_radial2", 0.75),
            ("loop_gain_focus", 0.1),
        ] {
            assert!((v.reals[vr(name)] - g(f)).abs() < 1e-15, "{name}");
        }
        assert_eq!(m.control_modes().expect("modes").radial34().len(), 9);
    }
}
