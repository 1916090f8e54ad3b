//! Model wiring of the `optical_feedback` FMU: the real-time optical feedback between APS runs,
//! an on-instrument wavefront sensor that measures the global low-order modes the edge sensors
//! cannot see (global piston, tip and tilt) and, optionally, focus-mode, integrated at its own
//! bandwidth ([`m1::control::aps::OpticalFeedback`]).
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `z` | input | na | m |
//! | `y_ref_in` | input | ns | m |
//! | `u_lo` | output, no direct dependency | na | m |
//! | `y_ref` | output | ns | m |
//!
//! with na = 3 x the number of segments (actuator k of segment i at index 3 i + k) and ns the
//! number of edge sensors of the packaged layout.
//!
//! # Timing
//!
//! Every communication step `(t, t + h]` is one update of length `h` on the surface `z` held
//! over the step (`c <- c - g (m + noise)`, `g = 1 - exp(-2 pi bandwidth h)`, the noise of
//! update k drawn from `(seed, k)`); the commands show from `t + h` on. `u_lo = N c_ptt`, the
//! global piston/tip/tilt command that the controller adds to its output, depends on `z` only
//! through the updates (a discrete output, no direct dependency: no algebraic loop). `y_ref =
//! y_ref_in + A_0 psi_f c_f`, the desired readings from the APS plus the focus-mode offset,
//! follows `y_ref_in` at once (direct feedthrough, element by element), also in
//! initialisation mode. Both start from `c = 0`: `u_lo = 0`, `y_ref = y_ref_in`.
//!
//! # Saved states
//!
//! A serialised state holds the parameters, the integrated coefficients and the update count
//! (which seeds the next update's noise); reading it back rebuilds the feedback's modes and
//! restores both exactly.

use serde::{Deserialize, Serialize};

use fmu::{
    BoolVar, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T,
    Values, VariableTable,
};
use m1::analysis::quasistatic::default_geometry;
use m1::aperture::layout::Layout;
use m1::control::aps::{OpticalFeedback, OpticalFeedbackParams};
use m1::control::nominal::Nominal;
use wiring::signals::{U_LO, Y_REF, Z, layout_decl, n_segments_decl, n_sensors_decl};

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        n_sensors: IntVar = n_sensors_decl(layout),
        z: RealVar = Z.input(layout),
        y_ref_in: RealVar = T::real("y_ref_in").input().len(layout.n_sensors()).unit("m")
            .start(0.0).describe("Desired readings from the APS"),
        u_lo: RealVar = U_LO.output(layout).discrete().depends(Dependencies::None),
        y_ref: RealVar = Y_REF.output(layout)
            .depends(Dependencies::Elementwise("y_ref_in".into())),
        bandwidth: RealVar = T::real("bandwidth").parameter().unit("Hz")
            .start(OpticalFeedbackParams::default().bandwidth).non_negative()
            .describe("Closed-loop bandwidth of the optical feedback (assumed: a wavefront \
                       sensor read every ~15 s)"),
        noise_rms: RealVar = T::real("noise_rms").parameter().unit("m")
            .start(OpticalFeedbackParams::default().noise_rms).non_negative()
            .describe("rms noise of each measured modal coefficient, per update (assumed)"),
        focus: BoolVar = T::boolean("focus").parameter()
            .start_bool(OpticalFeedbackParams::default().focus)
            .describe("Also close focus-mode (as an offset of the desired readings)"),
        seed: IntVar = T::integer("seed").parameter()
            .start_int(i32::try_from(OpticalFeedbackParams::default().seed).unwrap_or(1))
            .non_negative().describe("Seed of the measurement noise (update k draws from \
                                      (seed, k))"),
    }
}

const DOC: &str = "<h2>Model</h2>\
<p>Between APS runs an on-instrument wavefront sensor measures the modal coefficients m of \
the surface <code>z</code> on the global piston, tip and tilt (an orthonormal basis N in \
actuator space) and, with <code>focus</code>, on focus-mode &psi;<sub>f</sub> (the least \
observable mode of the edge sensors), each with a white noise of rms <code>noise_rms</code> \
(drawn from (<code>seed</code>, k) for update k). Every communication step (t, t + h] is one \
update of the integrator on the surface held over the step: c &larr; c &minus; g (m + noise), \
g = 1 &minus; exp(&minus;2&pi; <code>bandwidth</code> h), so a constant error decays by \
(1 &minus; g) per step. The commands: <code>u_lo</code> = N c<sub>ptt</sub>, a direct \
low-order actuator command added to the global controller's output (the edge sensors do not \
see global piston, tip and tilt; a discrete output without direct dependency on \
<code>z</code>), and <code>y_ref</code> = <code>y_ref_in</code> + A<sub>0</sub> &psi;<sub>f</sub> \
c<sub>f</sub>, the desired readings from the APS with the focus-mode offset (the edge-sensor \
loop would fight a direct command on a mode it sees); <code>y_ref</code> follows \
<code>y_ref_in</code> at once. Both start from c = 0.</p>\
<p>Saved FMU states (in memory or serialised) restore the integrator exactly.</p>";

/// What the optical feedback is built from, fixed at initialisation.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct Spec {
    layout: String,
    params: OpticalFeedbackParams,
}

impl Spec {
    /// The parameters in `v`.
    fn read(x: &Vars, layout: &str, v: &Values) -> Self {
        Self {
            layout: layout.to_string(),
            params: OpticalFeedbackParams {
                bandwidth: v.scalar(x.bandwidth),
                noise_rms: v.scalar(x.noise_rms),
                focus: v.boolean(x.focus),
                seed: u64::from(v.integer(x.seed).unsigned_abs()),
            },
        }
    }

    /// Builds the optical feedback on the nominal A-matrix and focus-mode of the layout.
    fn build(&self) -> Result<OpticalFeedback, FmuError> {
        let layout = Layout::preset(&self.layout).map_err(|e| FmuError::Model(e.to_string()))?;
        let geometry = default_geometry(&layout, false, None).map_err(wiring::model_error)?;
        let nominal = Nominal::new(geometry.clone()).map_err(wiring::model_error)?;
        OpticalFeedback::new(&geometry, &nominal.a, &nominal.focus, self.params).map_err(|e| {
            wiring::model_error_renamed(e, |name| match name {
                "of_bandwidth" => "bandwidth",
                "of_noise_rms" => "noise_rms",
                other => other,
            })
        })
    }
}

/// The `optical_feedback` FMU as configured: the handles and the packaged layout;
/// [`OpticalFeedbackRunning`] integrates.
#[derive(Debug, Clone)]
pub struct OpticalFeedbackFmu {
    vars: Vars,
    layout: String,
}

/// The initialised `optical_feedback` FMU: the integrator (with its update count).
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(into = "SavedFeedback", try_from = "SavedFeedback")]
pub struct OpticalFeedbackRunning {
    vars: Vars,
    spec: Spec,
    feedback: OpticalFeedback,
}

/// The serialised form of [`OpticalFeedbackRunning`].
#[derive(Serialize, Deserialize)]
struct SavedFeedback {
    vars: Vars,
    spec: Spec,
    coefficients: [f64; 4],
    updates: u64,
}

impl From<OpticalFeedbackRunning> for SavedFeedback {
    fn from(r: OpticalFeedbackRunning) -> Self {
        Self {
            vars: r.vars,
            spec: r.spec,
            coefficients: r.feedback.state().0,
            updates: r.feedback.state().1,
        }
    }
}

impl TryFrom<SavedFeedback> for OpticalFeedbackRunning {
    type Error = FmuError;

    fn try_from(s: SavedFeedback) -> Result<Self, FmuError> {
        let mut feedback = s.spec.build()?;
        feedback.set_state(s.coefficients, s.updates);
        Ok(Self {
            vars: s.vars,
            spec: s.spec,
            feedback,
        })
    }
}

impl OpticalFeedbackRunning {
    /// Writes `u_lo` from the coefficients.
    fn write_u_lo(&self, v: &mut Values) {
        self.feedback
            .low_order_command_into(v.real_mut(self.vars.u_lo));
    }

    /// Writes `y_ref = y_ref_in + A_0 psi_f c_f`.
    fn write_y_ref(&self, v: &mut Values) {
        let (from, to) = (self.vars.y_ref_in, self.vars.y_ref);
        v.reals
            .copy_within(from.slot..from.slot + from.len, to.slot);
        self.feedback.add_reference_offset(v.real_mut(to));
    }

    /// The optical feedback (for in-process use and tests).
    pub fn feedback(&self) -> &OpticalFeedback {
        &self.feedback
    }
}

impl Model for OpticalFeedbackFmu {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "optical_feedback",
        model_name: "Optical feedback",
        description: "Optical feedback between APS runs: a wavefront sensor's global piston, tip, \
            tilt and focus-mode, integrated at its bandwidth, as a low-order actuator command and \
            a focus-mode offset of the desired edge-sensor readings",
        documentation: DOC,
        default_stop_time: 600.0,
        default_step: 1.0,
    };

    type Running = OpticalFeedbackRunning;

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
        _start_time: f64,
    ) -> Result<OpticalFeedbackRunning, FmuError> {
        let spec = Spec::read(&self.vars, &self.layout, v);
        let feedback = spec.build()?;
        let running = OpticalFeedbackRunning {
            vars: self.vars,
            spec,
            feedback,
        };
        running.write_u_lo(v);
        running.write_y_ref(v);
        Ok(running)
    }
}

impl fmu::Running for OpticalFeedbackRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        // y_ref follows y_ref_in; u_lo changes only with the updates.
        self.write_y_ref(v);
        Ok(())
    }

    fn do_step(&mut self, _t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        // The library checks its arguments before changing anything.
        self.feedback
            .update(v.real(self.vars.z), h)
            .map_err(wiring::model_error)?;
        self.write_u_lo(v);
        self.write_y_ref(v);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;
    use m1::control::reconstructor::{orthonormalize, sparse_mul};
    use m1::sensing::interaction::global_ptt;

    /// An instance of `variant` through the runtime, in initialisation mode (start time 0),
    /// with the Real parameters `params` set.
    fn instance(variant: &str, params: &[(&str, f64)]) -> Instance<OpticalFeedbackFmu> {
        let (table, _) = OpticalFeedbackFmu::new(variant).expect("table");
        let guid = fmu::xml::guid(&OpticalFeedbackFmu::INFO, &table);
        let mut fmu = Instance::<OpticalFeedbackFmu>::new("test", &guid, None, None, false)
            .expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        for (name, value) in params {
            let vr = vrs(&fmu, name)[0];
            fmu.set_real(&[vr], &[*value]).expect(name);
        }
        fmu
    }

    /// The value references of a variable's scalars.
    fn vrs(fmu: &Instance<OpticalFeedbackFmu>, name: &str) -> Vec<u32> {
        let v = fmu.table().by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    fn get(fmu: &mut Instance<OpticalFeedbackFmu>, name: &str) -> Vec<f64> {
        let vr = vrs(fmu, name);
        let mut out = vec![f64::NAN; vr.len()];
        fmu.get_real(&vr, &mut out).expect(name);
        out
    }

    fn set(fmu: &mut Instance<OpticalFeedbackFmu>, name: &str, x: &[f64]) {
        let vr = vrs(fmu, name);
        fmu.set_real(&vr, x).expect(name);
    }

    fn step(fmu: &mut Instance<OpticalFeedbackFmu>, h: f64) {
        let t = fmu.time();
        fmu.do_step(t, h).expect("step");
    }

    /// A surface with every mode in it.
    fn surface(na: usize, k: usize) -> Vec<f64> {
        (0..na)
            .map(|i| 1e-8 * ((i * (k + 1)) as f64 * 0.37).sin() + 2e-9 * (i as f64))
            .collect()
    }

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = OpticalFeedbackFmu::new(variant).expect("table");
            let layout = Layout::preset(variant).expect("layout");
            let u = t.by_name("u_lo").expect("u_lo");
            assert_eq!(u.len, layout.n_actuators());
            assert_eq!(u.dependencies, Dependencies::None);
            let y = t.by_name("y_ref").expect("y_ref");
            assert_eq!(y.len, layout.n_sensors());
            assert_eq!(y.dependencies, Dependencies::Elementwise("y_ref_in".into()));
            let y_in = t.by_name("y_ref_in").expect("y_ref_in");
            assert_eq!(
                (y_in.len, y_in.unit.as_deref()),
                (layout.n_sensors(), Some("m"))
            );
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<OpticalFeedbackFmu>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// A fixed global tilt with u_lo fed back into z decays by 1 - g per step,
    /// g = 1 - exp(-2 pi bandwidth h).
    #[test]
    fn a_global_tilt_is_removed_at_the_bandwidth() {
        let (bandwidth, h) = (0.1, 1.0);
        let mut fmu = instance("keck", &[("noise_rms", 0.0), ("bandwidth", bandwidth)]);
        fmu.exit_initialization_mode().expect("initialise");
        let layout = Layout::preset("keck").expect("layout");
        let g = default_geometry(&layout, false, None).expect("geometry");
        let modes = orthonormalize(global_ptt(&g).as_ref());
        let tilt: Vec<f64> = (0..g.n_actuators()).map(|i| 1e-6 * modes[(i, 2)]).collect();
        let gain = 1.0 - (-2.0 * std::f64::consts::PI * bandwidth * h).exp();
        let mut u = get(&mut fmu, "u_lo");
        assert!(u.iter().all(|&x| x == 0.0));
        for k in 1..=5 {
            let z: Vec<f64> = tilt.iter().zip(&u).map(|(a, b)| a + b).collect();
            set(&mut fmu, "z", &z);
            // u_lo has no direct feedthrough: it changes only with the step.
            assert_eq!(get(&mut fmu, "u_lo"), u);
            step(&mut fmu, h);
            u = get(&mut fmu, "u_lo");
            let residual: Vec<f64> = tilt.iter().zip(&u).map(|(a, b)| a + b).collect();
            let m = fmu
                .running()
                .expect("running")
                .feedback()
                .modes_of(&residual);
            let expected = 1e-6 * (1.0 - gain).powi(k);
            assert!(
                (m[2] - expected).abs() < 1e-15,
                "step {k}: {} vs {expected}",
                m[2]
            );
            assert!(m[0].abs() < 1e-15 && m[1].abs() < 1e-15);
        }
    }

    /// y_ref = y_ref_in while the focus-mode coefficient is 0 (at the start, and always with
    /// focus off), and follows y_ref_in without a step; with focus on, the offset is
    /// A_0 psi_f c_f.
    #[test]
    fn y_ref_is_y_ref_in_plus_the_focus_offset() {
        for focus in [false, true] {
            let mut fmu = instance("keck", &[("noise_rms", 0.0)]);
            let vr = fmu.table().by_name("focus").expect("focus").vr;
            fmu.set_boolean(&[vr], &[focus]).expect("focus");
            let ns = vrs(&fmu, "y_ref_in").len();
            let na = vrs(&fmu, "z").len();
            let y_in: Vec<f64> = (0..ns).map(|n| 1e-9 * n as f64).collect();
            set(&mut fmu, "y_ref_in", &y_in);
            assert_eq!(get(&mut fmu, "y_ref"), y_in, "initialisation mode");
            fmu.exit_initialization_mode().expect("initialise");
            for k in 0..3 {
                set(&mut fmu, "z", &surface(na, k));
                step(&mut fmu, 10.0);
            }
            let c = fmu.running().expect("running").feedback().coefficients();
            assert!(c[0] != 0.0);
            let y = get(&mut fmu, "y_ref");
            if focus {
                assert!(c[3] != 0.0);
                let mut offset = vec![0.0; ns];
                fmu.running()
                    .expect("running")
                    .feedback()
                    .add_reference_offset(&mut offset);
                let want: Vec<f64> = y_in.iter().zip(&offset).map(|(a, b)| a + b).collect();
                assert_eq!(y, want);
                assert_ne!(y, y_in);
            } else {
                assert_eq!(c[3], 0.0);
                assert_eq!(y, y_in);
            }
            // Direct feedthrough of y_ref_in, element by element.
            let y_in2: Vec<f64> = y_in.iter().map(|y| -2.0 * y).collect();
            set(&mut fmu, "y_ref_in", &y_in2);
            let mut want = y_in2.clone();
            fmu.running()
                .expect("running")
                .feedback()
                .add_reference_offset(&mut want);
            assert_eq!(get(&mut fmu, "y_ref"), want);
        }
    }

    /// The focus-mode offset is A_0 psi_f c_f with psi_f the nominal focus-mode.
    #[test]
    fn the_focus_offset_is_a0_times_focus_mode() {
        let mut fmu = instance("keck", &[("noise_rms", 0.0)]);
        fmu.exit_initialization_mode().expect("initialise");
        let layout = Layout::preset("keck").expect("layout");
        let g = default_geometry(&layout, false, None).expect("geometry");
        let nominal = Nominal::new(g).expect("nominal");
        let z: Vec<f64> = nominal.focus.iter().map(|f| 1e-7 * f).collect();
        set(&mut fmu, "z", &z);
        step(&mut fmu, 10.0);
        let c = fmu.running().expect("running").feedback().coefficients();
        let gain = 1.0 - (-2.0 * std::f64::consts::PI * 0.01 * 10.0).exp();
        assert!((c[3].abs() - 1e-7 * gain).abs() < 1e-15, "{c:?}");
        let mut a_focus = vec![0.0; nominal.a.nrows()];
        sparse_mul(&nominal.a, &nominal.focus, &mut a_focus);
        let y = get(&mut fmu, "y_ref");
        let scale = a_focus.iter().fold(0.0_f64, |m, a| m.max(a.abs())) * c[3].abs();
        for (y, a) in y.iter().zip(&a_focus) {
            // focus-mode up to its sign
            assert!((y.abs() - (a * c[3]).abs()).abs() < 1e-9 * scale);
        }
    }

    /// Negative or non-finite parameters are refused with an error status.
    #[test]
    fn bad_parameters_are_refused() {
        let mut fmu = instance("keck", &[]);
        for (name, value) in [
            ("bandwidth", -0.01),
            ("noise_rms", -1e-9),
            ("bandwidth", f64::NAN),
        ] {
            let vr = vrs(&fmu, name)[0];
            let e = fmu.set_real(&[vr], &[value]).expect_err(name);
            assert!(e.to_string().contains(name), "{e}");
        }
        fmu.exit_initialization_mode().expect("defaults");
    }

    /// A serialised state, and an in-memory one, step on exactly as the instance they were
    /// taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let mut fmu = instance("keck", &[("bandwidth", 0.05)]);
        fmu.exit_initialization_mode().expect("initialise");
        let na = vrs(&fmu, "z").len();
        let ns = vrs(&fmu, "y_ref_in").len();
        set(&mut fmu, "y_ref_in", &vec![1e-9; ns]);
        for k in 0..3 {
            set(&mut fmu, "z", &surface(na, k));
            step(&mut fmu, 2.0);
        }
        let state = fmu.get_state().expect("state");
        let bytes = Instance::serialize(&state).expect("serialize");
        let saved = fmu.running().expect("running").feedback().coefficients();
        let go = |fmu: &mut Instance<OpticalFeedbackFmu>| {
            let mut all = Vec::new();
            for k in 3..6 {
                set(fmu, "z", &surface(na, k));
                step(fmu, 2.0);
                all.extend(get(fmu, "u_lo"));
                all.extend(get(fmu, "y_ref"));
            }
            all
        };
        let straight = go(&mut fmu);
        fmu.set_state(&state).expect("in-memory state");
        assert_eq!(go(&mut fmu), straight);
        let back = fmu.deserialize(&bytes).expect("deserialize");
        fmu.set_state(&back).expect("set state");
        let restored = fmu.running().expect("running").feedback().coefficients();
        assert_eq!(restored, saved);
        assert_eq!(go(&mut fmu), straight);
    }
}
