//! Model wiring of the `global_controller` FMU: the global edge-sensor control loop
//! (reconstructor with global piston/tip/tilt projected out, modal integral control at 20 Hz),
//! computed by [`m1::control::controller::ControlModes`].
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `y` | input | ns | m |
//! | `y_ref` | input | ns | m |
//! | `u_cmd` | output | na | m |
//! | `u_lo` | input | na | m |
//!
//! with na = 3 x the number of segments and ns the number of edge sensors of the packaged
//! layout.
//!
//! # Sampling
//!
//! The loop samples at its own instants `t0 + k / rate` (`k >= 1`), whatever the communication
//! step (steps need not divide the period). A step `(t, t + h]` takes every instant in it with
//! the readings held over the step (set at `t`), so the integrator's command at a communication
//! point equal to a sample instant already shows that sample's command, and is held in between.
//!
//! # Low-order command
//!
//! `u_cmd = u + u_lo`: the integrator's command `u` plus the low-order command `u_lo` (global
//! piston/tip/tilt from the optical feedback), passed through at once: `u_cmd` is recomputed
//! whenever `u_lo` is set, and `u_lo` never enters the integrator. So `u_cmd` depends directly
//! on `u_lo` (ModelStructure: element i on `u_lo[i]`) but never on `y` (discrete variability):
//! a closed loop edge sensors -> controller -> segments has no algebraic loop, and with
//! `u_lo = 0` (its start value) `u_cmd` is the integrator's command.

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use fmu::{
    BoolVar, Decl, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar,
    TableBuilder as T, Values, VariableTable,
};
use m1::aperture::geometry::{DEFAULT_LEFF, Geometry, GeometryParams};
use m1::aperture::layout::Layout;
use m1::control::controller::{
    ControlModes, ControllerParams, ControllerState, DEFAULT_BANDWIDTH, DEFAULT_BANDWIDTH_FOCUS,
    DEFAULT_BANDWIDTH_RADIAL2, DEFAULT_BANDWIDTH_RADIAL34, DEFAULT_FOCUS_GAIN, DEFAULT_RATE,
    LoopGains, Scratch,
};
use wiring::signals::{U_CMD, U_LO, Y, Y_REF, layout_decl, n_segments_decl, n_sensors_decl};

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
step, each with the readings held over the step; the integrator's command u changes only at \
sample instants and u_cmd does not depend directly on y (no algebraic loop). \
<code>enabled</code> = false (tunable) opens the loop: the instants pass and u is held.</p>\
<p><b>Low-order command</b>: <code>u_cmd = u + u_lo</code>, with <code>u_lo</code> the \
low-order actuator command (global piston/tip/tilt from the optical feedback) passed straight \
through: u_cmd follows u_lo as soon as it is set (element i of u_cmd depends directly on \
element i of u_lo), and u_lo does not enter the integrator. It starts at 0.</p>";

/// A closed-loop bandwidth: a non-negative parameter in Hz.
fn hz(name: &str, start: f64, description: &str) -> Decl {
    T::real(name)
        .parameter()
        .unit("Hz")
        .start(start)
        .non_negative()
        .describe(description)
}

/// An integrator gain per sample, calculated at initialisation.
fn gain(name: &str, description: &str) -> Decl {
    T::real(name)
        .calculated_parameter()
        .unit("1")
        .describe(description)
}

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        n_sensors: IntVar = n_sensors_decl(layout),
        y: RealVar = Y.input(layout),
        y_ref: RealVar = Y_REF.input(layout),
        u_cmd: RealVar = U_CMD.output(layout).discrete()
            .depends(Dependencies::Elementwise(U_LO.name.into())),
        rate: RealVar = T::real("rate").parameter().unit("Hz").start(DEFAULT_RATE).positive()
            .describe("Sample rate of the global loop"),
        bandwidth: RealVar = hz("bandwidth", DEFAULT_BANDWIDTH,
            "Closed-loop bandwidth of the modes of radial degrees >= 5 (every mode outside the \
             radial-degree-2 to 4 groups and focus-mode) (< rate / 2)"),
        bandwidth_radial2: RealVar = hz("bandwidth_radial2", DEFAULT_BANDWIDTH_RADIAL2,
            "Closed-loop bandwidth of the radial-degree-2 modes without focus-mode (astigmatism) \
             (< rate / 2)"),
        bandwidth_focus: RealVar = hz("bandwidth_focus", DEFAULT_BANDWIDTH_FOCUS,
            "Closed-loop bandwidth of focus-mode (before the modal gain focus_gain) (< rate / 2)"),
        focus_gain: RealVar = T::real("focus_gain").parameter().unit("1")
            .start(DEFAULT_FOCUS_GAIN).check(fmu::Check::Range(0.0, 1.0))
            .describe("Modal gain Gamma of the reconstructor on focus-mode (the paper uses 1/4)"),
        leff: RealVar = T::real("leff").parameter().unit("m").start(DEFAULT_LEFF).non_negative()
            .describe("Effective dihedral moment arm of the sensor model the reconstructor uses"),
        enabled: BoolVar = T::boolean("enabled").tunable().start_bool(true)
            .describe("Close the loop (false: the sample instants pass and u_cmd is held)"),
        loop_gain: RealVar = gain("loop_gain",
            "Integrator gain per sample of radial degrees >= 5, 1 - exp(-2 pi bandwidth / rate)"),
        loop_gain_radial2: RealVar = gain("loop_gain_radial2",
            "Integrator gain per sample of the radial-degree-2 group"),
        loop_gain_focus: RealVar = gain("loop_gain_focus",
            "Integrator gain per sample of focus-mode, \
             focus_gain x (1 - exp(-2 pi bandwidth_focus / rate))"),
        // Declared last: the value references follow the declaration order per type, so those
        // of the Reals declared before are unchanged.
        bandwidth_radial34: RealVar = hz("bandwidth_radial34", DEFAULT_BANDWIDTH_RADIAL34,
            "Closed-loop bandwidth of the modes of radial degrees 3-4 (Z7 to Z15, without radial \
             degree 2 and focus-mode) (< rate / 2)"),
        loop_gain_radial34: RealVar = gain("loop_gain_radial34",
            "Integrator gain per sample of the radial-degree-3-4 group"),
        u_lo: RealVar = U_LO.input(layout),
    }
}

/// Writes `u_cmd = u + u_lo` into `v`.
fn write_command(x: &Vars, u: &[f64], v: &mut Values) {
    // Two variables of the one table: their slots, not a borrow of each per value.
    let (lo, cmd) = (x.u_lo.slot, x.u_cmd.slot);
    for (i, ui) in u.iter().enumerate() {
        v.reals[cmd + i] = ui + v.reals[lo + i];
    }
}

/// The `global_controller` FMU as configured: the handles and the packaged layout;
/// [`GlobalControllerRunning`] samples.
#[derive(Debug, Clone)]
pub struct GlobalControllerModel {
    vars: Vars,
    layout: String,
}

/// What the reconstructor and the modes are built from, fixed at initialisation: the layout
/// and `leff`.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct ModesSpec {
    layout: String,
    leff: f64,
}

impl ModesSpec {
    /// Builds the reconstructor and the modes.
    fn build(&self) -> Result<ControlModes, FmuError> {
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let mut params = GeometryParams::for_layout(&layout);
        params.leff = self.leff;
        let geometry = Geometry::new(&layout, params).map_err(wiring::model_error)?;
        ControlModes::new(geometry).map_err(wiring::model_error)
    }
}

/// The initialised `global_controller` FMU: the reconstructor and modes, the loop gains, the
/// held command and the sample clock. A saved state holds the gains, the command, the clock
/// and what the modes are built from; the modes are rebuilt when it is read back.
#[derive(Clone, Serialize, Deserialize)]
#[serde(into = "SavedController", try_from = "SavedController")]
pub struct GlobalControllerRunning {
    vars: Vars,
    spec: ModesSpec,
    gains: LoopGains,
    state: ControllerState,
    modes: Arc<ControlModes>,
    scratch: Scratch,
}

/// The serialised form of [`GlobalControllerRunning`].
#[derive(Serialize, Deserialize)]
struct SavedController {
    vars: Vars,
    spec: ModesSpec,
    gains: LoopGains,
    state: ControllerState,
}

impl From<GlobalControllerRunning> for SavedController {
    fn from(r: GlobalControllerRunning) -> Self {
        Self {
            vars: r.vars,
            spec: r.spec,
            gains: r.gains,
            state: r.state,
        }
    }
}

impl TryFrom<SavedController> for GlobalControllerRunning {
    type Error = FmuError;

    fn try_from(s: SavedController) -> Result<Self, FmuError> {
        let modes = Arc::new(s.spec.build()?);
        Ok(Self {
            scratch: modes.scratch(),
            vars: s.vars,
            spec: s.spec,
            gains: s.gains,
            state: s.state,
            modes,
        })
    }
}

impl GlobalControllerRunning {
    /// The reconstructor and modes (for in-process use and tests).
    pub fn control_modes(&self) -> &ControlModes {
        &self.modes
    }

    /// The integrator's command `u` (without `u_lo`).
    pub fn integrator_command(&self) -> &[f64] {
        &self.state.u
    }
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
}

impl Model for GlobalControllerModel {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "global_controller",
        model_name: "M1 global edge-sensor controller",
        description: "Global control loop of a segmented mirror: sparse reconstructor with global \
            piston/tip/tilt projected out, modal discrete integrators (radial degrees >= 5 at \
            1.5 Hz, 3-4 at 1 Hz, 2 at 0.75 Hz, focus-mode at 0.1 Hz) sampled at 20 Hz, command \
            held between samples, plus the low-order command u_lo passed through",
        documentation: DOC,
        default_stop_time: 2.0,
        default_step: 1e-3,
    };

    type Running = GlobalControllerRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        let layout = variant.to_string();
        Ok((table, Self { vars, layout }))
    }

    fn initialize(
        &self,
        v: &mut Values,
        start_time: f64,
    ) -> Result<GlobalControllerRunning, FmuError> {
        let x = self.vars;
        let params = self.params(v);
        let gains = params.gains().map_err(wiring::model_error)?;
        let spec = ModesSpec {
            layout: self.layout.clone(),
            leff: v.scalar(x.leff),
        };
        let modes = Arc::new(spec.build()?);
        let na = modes.shape().0;
        let state =
            ControllerState::new(na, start_time, params.rate).map_err(wiring::model_error)?;
        v.real_mut(x.loop_gain)[0] = gains.rest;
        v.real_mut(x.loop_gain_radial2)[0] = gains.radial2;
        v.real_mut(x.loop_gain_radial34)[0] = gains.radial34;
        v.real_mut(x.loop_gain_focus)[0] = gains.focus;
        write_command(&x, &state.u, v);
        Ok(GlobalControllerRunning {
            scratch: modes.scratch(),
            vars: x,
            spec,
            gains,
            state,
            modes,
        })
    }
}

impl fmu::Running for GlobalControllerRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        // The integrator's command changes only at sample instants, inside fmi2DoStep; u_lo
        // passes through at once.
        write_command(&self.vars, &self.state.u, v);
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let x = self.vars;
        self.modes
            .advance(
                &self.gains,
                &mut self.state,
                v.boolean(x.enabled),
                t + h,
                v.real(x.y),
                v.real(x.y_ref),
                &mut self.scratch,
            )
            .map_err(wiring::model_error)?;
        write_command(&x, &self.state.u, v);
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
            let (t, _) = GlobalControllerModel::new(variant).expect("table");
            let layout = Layout::preset(variant).expect("layout");
            let u = t.by_name("u_cmd").expect("u_cmd");
            assert_eq!(u.len, layout.n_actuators());
            assert_eq!(u.dependencies, Dependencies::Elementwise("u_lo".into()));
            assert_eq!(t.by_name("u_lo").expect("u_lo").len, layout.n_actuators());
            assert_eq!(t.by_name("y").expect("y").len, layout.n_sensors());
        }
    }

    /// `bandwidth_radial34` and `loop_gain_radial34` are the last Reals: the value references of
    /// the Reals declared before are those they had without them. The start values are the
    /// seed paper's baseline and the new bandwidth reaches its calculated gain.
    #[test]
    fn the_radial34_bandwidth_is_appended_and_sets_its_gain() {
        let (t, m) = GlobalControllerModel::new("keck").expect("model");
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
        // u_lo is the last Real: the Reals above keep their value references.
        assert_eq!(vr("u_lo"), 2 * ns + na + scalars.len());
        for (k, name) in scalars.iter().enumerate() {
            assert_eq!(vr(name), 2 * ns + na + k, "{name}");
        }
        let mut v = t.initial_values();
        assert_eq!(v.reals[vr("bandwidth")], 1.5);
        assert_eq!(v.reals[vr("bandwidth_radial34")], 1.0);
        assert_eq!(v.reals[vr("bandwidth_radial2")], 0.75);
        assert_eq!(v.reals[vr("bandwidth_focus")], 0.1);
        v.reals[vr("bandwidth_radial34")] = 0.5;
        let running = m.initialize(&mut v, 0.0).expect("initialize");
        let g = |f: f64| 1.0 - (-std::f64::consts::TAU * f / 20.0).exp();
        for (name, f) in [
            ("loop_gain", 1.5),
            ("loop_gain_radial34", 0.5),
            ("loop_gain_radial2", 0.75),
            ("loop_gain_focus", 0.1),
        ] {
            assert!((v.reals[vr(name)] - g(f)).abs() < 1e-15, "{name}");
        }
        assert_eq!(running.control_modes().radial34().len(), 9);
    }

    /// The module documentation's table of signals is the table's inputs and outputs.
    #[test]
    fn the_documented_signals_are_the_declared_ones() {
        assert_eq!(
            wiring::check_documented_signals::<GlobalControllerModel>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// An instance of the keck controller, initialised, with the readings `y` set.
    fn started(y: &[f64]) -> (VariableTable, Instance<GlobalControllerModel>) {
        let (table, _) = GlobalControllerModel::new("keck").expect("table");
        let guid = fmu::xml::guid(&GlobalControllerModel::INFO, &table);
        let mut fmu = Instance::<GlobalControllerModel>::new("gc", &guid, None, None, false)
            .expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode().expect("enter");
        fmu.exit_initialization_mode().expect("exit");
        let vrs = vrs_of(&table, "y");
        fmu.set_real(&vrs, y).expect("y");
        (table, fmu)
    }

    fn vrs_of(table: &VariableTable, name: &str) -> Vec<u32> {
        let v = table.by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    fn get(fmu: &mut Instance<GlobalControllerModel>, table: &VariableTable, n: &str) -> Vec<f64> {
        let vrs = vrs_of(table, n);
        let mut out = vec![0.0; vrs.len()];
        fmu.get_real(&vrs, &mut out).expect(n);
        out
    }

    /// A constant u_lo shows in u_cmd at once (before any step), is added to the integrator's
    /// command at every step, and leaves the integrator alone: the command is that of a twin
    /// instance without it.
    #[test]
    fn u_lo_passes_to_u_cmd_at_once_and_leaves_the_integrator_alone() {
        let layout = Layout::preset("keck").expect("layout");
        let y: Vec<f64> = (0..layout.n_sensors())
            .map(|i| 1e-7 * (i as f64).sin())
            .collect();
        let lo: Vec<f64> = (0..layout.n_actuators())
            .map(|i| 1e-6 * (0.3 * i as f64).cos())
            .collect();
        let (table, mut with) = started(&y);
        let (_, mut without) = started(&y);
        let h = 0.01;
        let mut t = 0.0;
        for _ in 0..7 {
            with.do_step(t, h).expect("step");
            without.do_step(t, h).expect("step");
            t += h;
        }
        let u = get(&mut without, &table, "u_cmd");
        assert!(u.iter().any(|x| *x != 0.0));
        assert_eq!(get(&mut with, &table, "u_cmd"), u);
        // Set between samples: u_cmd follows at once, without a step.
        with.set_real(&vrs_of(&table, "u_lo"), &lo).expect("u_lo");
        let sum: Vec<f64> = u.iter().zip(&lo).map(|(a, b)| a + b).collect();
        assert_eq!(get(&mut with, &table, "u_cmd"), sum);
        for _ in 0..13 {
            with.do_step(t, h).expect("step");
            without.do_step(t, h).expect("step");
            t += h;
            let u = get(&mut without, &table, "u_cmd");
            let sum: Vec<f64> = u.iter().zip(&lo).map(|(a, b)| a + b).collect();
            assert_eq!(get(&mut with, &table, "u_cmd"), sum);
            let integrator = |f: &Instance<GlobalControllerModel>| {
                f.running().expect("running").integrator_command().to_vec()
            };
            assert_eq!(integrator(&with), integrator(&without));
            assert_eq!(integrator(&without), u);
        }
        // Back to zero: u_cmd is the integrator's command again.
        with.set_real(&vrs_of(&table, "u_lo"), &vec![0.0; lo.len()])
            .expect("u_lo");
        assert_eq!(
            get(&mut with, &table, "u_cmd"),
            get(&mut without, &table, "u_cmd")
        );
    }

    /// A u_lo set during initialisation shows in the initial u_cmd.
    #[test]
    fn u_lo_set_during_initialisation_is_the_initial_command() {
        let (table, _) = GlobalControllerModel::new("keck").expect("table");
        let guid = fmu::xml::guid(&GlobalControllerModel::INFO, &table);
        let mut fmu = Instance::<GlobalControllerModel>::new("gc", &guid, None, None, false)
            .expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode().expect("enter");
        let lo: Vec<f64> = (0..table.by_name("u_lo").expect("u_lo").len)
            .map(|i| 1e-7 * i as f64)
            .collect();
        fmu.set_real(&vrs_of(&table, "u_lo"), &lo).expect("u_lo");
        assert_eq!(get(&mut fmu, &table, "u_cmd"), lo);
        fmu.exit_initialization_mode().expect("exit");
        assert_eq!(get(&mut fmu, &table, "u_cmd"), lo);
    }

    /// A serialised state reads back with the reconstructor and modes rebuilt: the commands go
    /// on exactly as after the state was taken.
    #[test]
    fn a_serialised_state_rebuilds_the_modes() {
        // Without and with a low-order command.
        for scale in [0.0, 1e-8] {
            let (table, _) = GlobalControllerModel::new("keck").expect("table");
            let guid = fmu::xml::guid(&GlobalControllerModel::INFO, &table);
            let var = |n: &str| table.by_name(n).expect(n).clone();
            let vrs = |n: &str| {
                let v = var(n);
                (v.vr..v.vr + v.len as u32).collect::<Vec<_>>()
            };
            let mut fmu = Instance::<GlobalControllerModel>::new("gc", &guid, None, None, false)
                .expect("instance");
            fmu.setup_experiment(0.0, None).expect("setup");
            fmu.enter_initialization_mode().expect("enter");
            fmu.exit_initialization_mode().expect("exit");
            let y: Vec<f64> = (0..var("y").len).map(|i| 1e-7 * (i as f64).sin()).collect();
            fmu.set_real(&vrs("y"), &y).expect("y");
            if scale != 0.0 {
                let lo: Vec<f64> = (0..var("u_lo").len).map(|i| scale * i as f64).collect();
                fmu.set_real(&vrs("u_lo"), &lo).expect("u_lo");
            }
            let h = 0.05;
            let mut t = 0.0;
            for _ in 0..2 {
                fmu.do_step(t, h).expect("step");
                t += h;
            }
            let bytes = Instance::serialize(&fmu.get_state().expect("state")).expect("serialize");
            let commands = |fmu: &mut Instance<GlobalControllerModel>| {
                let mut t = t;
                let mut out = vec![0.0; var("u_cmd").len];
                let mut all = Vec::new();
                for _ in 0..3 {
                    fmu.do_step(t, h).expect("step");
                    t += h;
                    fmu.get_real(&vrs("u_cmd"), &mut out).expect("u_cmd");
                    all.extend_from_slice(&out);
                    let u = fmu.running().expect("running").integrator_command();
                    all.extend_from_slice(u);
                }
                all
            };
            let straight = commands(&mut fmu);
            let back = fmu.deserialize(&bytes).expect("deserialize");
            fmu.set_state(&back).expect("set state");
            let modes = fmu.running().expect("running").control_modes();
            assert_eq!(modes.radial34().len(), 9);
            assert!(straight.iter().any(|&u| u != 0.0));
            assert_eq!(commands(&mut fmu), straight);
        }
    }
}
