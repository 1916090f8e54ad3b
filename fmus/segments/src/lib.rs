//! Model wiring of the segments FMUs: the variable table of each actuator variant and the glue
//! between the FMI value store and [`m1::plant::segment::SegmentArray`]. Both variants have the same
//! inputs and outputs, so one replaces the other in a system; only their parameters differ.
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `u_cmd` | input | na | m |
//! | `z_cell` | input | na | m |
//! | `f_wind` | input | na | N |
//! | `z` | output | na | m |
//! | `f_cell` | output | na | N |
//!
//! with na = 3 x the number of segments of the packaged layout (actuator k of segment i at
//! index 3 i + k, 1-based in FMI names: `z[3 i + k + 1]`).

use serde::{Deserialize, Serialize};
use std::marker::PhantomData;

use fmu::{
    BoolVar, Check, Decl, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, Running,
    StrVar, TableBuilder as T, Values, VariableTable,
};
use m1::aperture::layout::Layout;
use m1::plant::segment::{
    ActuatorParams, Channel, Drive, PIEZO_STIFFNESS, SegmentArray, SegmentModel, SegmentParams,
    ServoParams, Shunt,
};
use wiring::signals::{F_CELL, F_WIND, U_CMD, Z, Z_CELL, layout_decl, n_segments_decl};

/// What differs between actuator variants: their default parameters and their drive.
pub trait Variant: Clone + Send + 'static {
    /// Static facts of the FMU.
    const INFO: ModelInfo;
    /// Units of the servo gains kp, ki and kd (the feedforward is in kp's): the drive's unit
    /// per m, per m s and s per m.
    const SERVO_UNITS: [&'static str; 3];
    /// The physics' model of the variant with its default parameters: the start values.
    fn defaults() -> SegmentModel;
    /// Declares the variant's own (drive) parameters.
    fn declare(b: &mut T) -> DriveVars;
}

fmu::variables! {
    /// Handles of the voice-coil drive parameters.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    pub struct VoiceCoilDrive(b) {
        spring_stiffness: RealVar = param("spring_stiffness", "N/m", 2.0e4).non_negative()
            .describe("Offload spring stiffness of each voice-coil actuator"),
        spring_damping: RealVar = param("spring_damping", "N.s/m", 50.0).non_negative()
            .describe("Damping of the offload spring and coil"),
    }
}

fmu::variables! {
    /// Handles of the piezo drive parameters (stack and LR shunt).
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    pub struct PiezoDrive(b) {
        piezo_stiffness: RealVar = param("piezo_stiffness", "N/m", PIEZO_STIFFNESS).positive()
            .describe("Open-circuit stiffness of each piezo stack"),
        piezo_damping_ratio: RealVar = param("piezo_damping_ratio", "1", 0.01).non_negative()
            .describe(
                "Structural damping ratio of the stack, on the segment's piston mode \
                 (c = 2 zeta sqrt(K (actuator_mass + segment_mass / 3)))",
            ),
        shunt_enabled: BoolVar = T::boolean("shunt_enabled").parameter().start_bool(false)
            .describe("Connect the resonant LR shunt (true: damped hard actuator)"),
        shunt_coupling: RealVar = param("shunt_coupling", "1", Shunt::default().coupling)
            .check(Check::Range(0.0, 0.99))
            .describe("Generalised electromechanical coupling factor of the stack"),
        shunt_frequency: RealVar = param("shunt_frequency", "Hz", Shunt::default().frequency)
            .positive()
            .describe("Electrical resonance of the shunt, 1/(2 pi sqrt(L C))"),
        shunt_damping_ratio: RealVar =
            param("shunt_damping_ratio", "1", Shunt::default().damping_ratio).non_negative()
            .describe("Electrical damping ratio of the shunt, R/(2 L omega_e)"),
    }
}

/// Handles of the drive parameters of a variant.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub enum DriveVars {
    /// The voice coil's.
    VoiceCoil(VoiceCoilDrive),
    /// The piezo's.
    Piezo(PiezoDrive),
}

fmu::variables! {
    /// Handles of the segment, actuator and servo parameters of a variant and of the calculated
    /// static stiffnesses (shared with the FMUs that embed the segments, such as the coupled
    /// mirror); `d` gives the start values, the variant's [`Variant::defaults`].
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    pub struct ParamVars<V: Variant>(b, d: &SegmentModel) {
        segment_mass: RealVar = param("segment_mass", "kg", d.segment.mass).positive().describe(
            "Mass carried by the three actuators of a segment (glass and support module)",
        ),
        segment_inertia: RealVar = param("segment_inertia", "kg.m2", d.segment.inertia).positive()
            .describe("Moment of inertia of a segment about an in-plane diameter"),
        actuator_radius: RealVar = param("actuator_radius", "m", d.segment.actuator_radius)
            .positive()
            .describe("Radius of the actuator circle"),
        support_piston_frequency: RealVar =
            param("support_piston_frequency", "Hz", d.segment.support_piston_frequency).positive()
            .describe("Piston mode of the glass on its flexures with the whiffletree clamped"),
        support_tilt_frequency: RealVar =
            param("support_tilt_frequency", "Hz", d.segment.support_tilt_frequency).positive()
            .describe("Tip/tilt mode of the glass on its flexures with the whiffletree clamped"),
        support_mass: RealVar = param("support_mass", "kg", d.segment.support_mass).non_negative()
            .describe(
                "Moving frame and whiffletrees between actuators and glass, part of segment_mass \
                 (0: no whiffletree, the glass's flexures on the actuator node)",
            ),
        whiffletree_frequency: RealVar =
            param("whiffletree_frequency", "Hz", d.segment.whiffletree_frequency).positive()
            .describe(
                "Lowest mode of the assembly with the actuators locked (tip/tilt on the \
                 whiffletrees)",
            ),
        support_damping_ratio: RealVar =
            param("support_damping_ratio", "1", d.segment.support_damping_ratio).non_negative()
            .describe("Damping ratio of the support modes"),
        actuator_mass: RealVar = param("actuator_mass", "kg", d.actuator.moving_mass).positive()
            .describe("Moving mass of each actuator's output node"),
        servo_rate: RealVar = param("servo_rate", "Hz", d.actuator.servo.rate).positive()
            .describe("Sample rate of the encoder servo"),
        servo_kp: RealVar = param("servo_kp", V::SERVO_UNITS[0], d.actuator.servo.kp).non_negative()
            .describe("Proportional gain of the encoder servo"),
        servo_ki: RealVar = param("servo_ki", V::SERVO_UNITS[1], d.actuator.servo.ki).non_negative()
            .describe("Integral gain of the encoder servo"),
        servo_kd: RealVar = param("servo_kd", V::SERVO_UNITS[2], d.actuator.servo.kd).non_negative()
            .describe("Derivative gain of the encoder servo (on the measurement)"),
        derivative_cutoff: RealVar =
            param("derivative_cutoff", "Hz", d.actuator.servo.derivative_cutoff).positive()
            .describe("Corner of the derivative's first-order filter"),
        integrator_leak: RealVar =
            param("integrator_leak", "Hz", d.actuator.servo.integrator_leak).non_negative()
            .describe("Leak corner of the servo integrator (0: pure integrator)"),
        setpoint_weight: RealVar =
            param("setpoint_weight", "1", d.actuator.servo.setpoint_weight)
            .check(Check::Range(0.0, 1.0))
            .describe("Weight of the command in the proportional term (1: plain PID)"),
        servo_feedforward: RealVar =
            param("servo_feedforward", V::SERVO_UNITS[0], d.actuator.servo.feedforward)
            .non_negative()
            .describe("Command feedforward of the encoder servo (drive per metre of command)"),
        drive: DriveVars => V::declare(b),
        static_stiffness_piston: RealVar = stiffness("static_stiffness_piston")
            .describe("Analytic static stiffness at the mirror per actuator, piston load pattern"),
        static_stiffness_tilt: RealVar = stiffness("static_stiffness_tilt")
            .describe("Analytic static stiffness at the mirror per actuator, tilt load pattern"),
        whiffletree_stiffness: RealVar = stiffness("whiffletree_stiffness")
            .describe(
                "Stiffness of the whiffletree per actuator (from whiffletree_frequency; infinite \
                 when support_mass is 0)",
            ),
    }
}

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars<V: Variant>(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name),
        n_segments: IntVar = n_segments_decl(layout),
        u_cmd: RealVar = U_CMD.input(layout),
        z_cell: RealVar = Z_CELL.input(layout),
        f_wind: RealVar = F_WIND.input(layout),
        z: RealVar = Z.output(layout),
        f_cell: RealVar =
            F_CELL.output(layout).depends(Dependencies::Elementwise("z_cell".into())),
        params: ParamVars => ParamVars::add_to::<V>(b, &V::defaults()),
    }
}

/// A Real parameter with its unit and start value.
fn param(name: &str, unit: &str, start: f64) -> Decl {
    T::real(name).parameter().unit(unit).start(start)
}

/// A calculated stiffness (N/m).
fn stiffness(name: &str) -> Decl {
    T::real(name).calculated_parameter().unit("N/m")
}

/// The segments FMU of one actuator variant, as configured; [`SegmentsRunning`] steps.
#[derive(Debug, Clone)]
pub struct Segments<V: Variant> {
    vars: Vars,
    n_segments: usize,
    _v: PhantomData<V>,
}

/// An initialised segments FMU: the physics and the handles it reads and writes.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SegmentsRunning {
    vars: Vars,
    array: SegmentArray,
}

/// The baseline soft voice-coil variant.
#[derive(Clone, Debug)]
pub struct VoiceCoilVariant;
/// The hard piezo variant, LR shunt optional.
#[derive(Clone, Debug)]
pub struct PiezoVariant;

/// The `segments_voicecoil` FMU.
pub type VoiceCoil = Segments<VoiceCoilVariant>;
/// The `segments_piezo` FMU.
pub type Piezo = Segments<PiezoVariant>;

const DOC_COMMON: &str = "<h2>Model</h2><p>Every segment is a rigid mirror on three identical \
actuators. Each actuator chain is cell &rarr; actuator (drive, stiffness) &rarr; actuator node \
(mass <code>actuator_mass</code>) &rarr; whiffletree (the support module's moving frame, \
<code>support_mass</code> of the carried <code>segment_mass</code>, a third at each actuator; \
its stiffness puts the lowest mode of the assembly with the actuators locked, tip/tilt, at \
<code>whiffletree_frequency</code>) &rarr; the glass's flexures (stiffness from the modes with \
the whiffletree clamped, <code>support_piston_frequency</code> and \
<code>support_tilt_frequency</code>) &rarr; mirror. In the orthonormal actuator basis each \
segment splits exactly into one piston and two tilt channels (effective glass masses \
(m &minus; m<sub>w</sub>)/3 and (I &minus; m<sub>w</sub> r<sub>a</sub><sup>2</sup>/2)/(1.5 \
r<sub>a</sub><sup>2</sup>)). The encoder servo is a discrete PID on the actuator stroke at \
<code>servo_rate</code> with a leaky integrator (<code>integrator_leak</code>; 0 = pure \
integrator), a filtered derivative on the measurement and a command feedforward \
(<code>servo_feedforward</code>: 1 for the piezo, whose free extension follows the command). \
The continuous dynamics are discretised exactly (zero-order hold, matrix exponential) and the \
communication step applies the exact multi-tick map, so results do not depend on the \
communication step. Steps need not be multiples of the servo period: the servo samples at its \
own instants and a period cut by a communication point is completed exactly in the next step.</p>\
<p><code>z</code> is the mirror displacement normal to the segment at each actuator, \
<code>f_cell</code> the force of each actuator on the mirror cell (the drive applied over the \
last servo period plus the spring on the current cell displacement, so it depends directly on \
<code>z_cell</code>). The calculated parameters give the analytic static stiffness at the \
mirror, per actuator, for piston and tilt load patterns.</p>";

impl Variant for VoiceCoilVariant {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "segments_voicecoil",
        model_name: "M1 segments on voice-coil actuators",
        description: "Every segment of a segmented primary mirror on three soft voice-coil actuators \
            (offload spring, 5 kHz encoder PID), with the segment-support flexibility",
        documentation: DOC_COMMON,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };
    const SERVO_UNITS: [&'static str; 3] = ["N/m", "N/(m.s)", "N.s/m"];

    fn defaults() -> SegmentModel {
        SegmentModel::voice_coil()
    }

    fn declare(b: &mut T) -> DriveVars {
        DriveVars::VoiceCoil(VoiceCoilDrive::add_to(b))
    }
}

impl Variant for PiezoVariant {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "segments_piezo",
        model_name: "M1 segments on piezo actuators",
        description: "Every segment of a segmented primary mirror on three hard piezo actuators \
            (command feedforward with a slow integral correction sampled at 5 kHz, optional LR-shunt damping), with the \
            segment-support flexibility",
        documentation: DOC_COMMON,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };
    const SERVO_UNITS: [&'static str; 3] = ["1", "1/s", "s"];

    fn defaults() -> SegmentModel {
        SegmentModel::piezo()
    }

    fn declare(b: &mut T) -> DriveVars {
        DriveVars::Piezo(PiezoDrive::add_to(b))
    }
}

impl DriveVars {
    /// The physics' actuator from the drive parameter values, the servo and the moving mass.
    fn actuator(&self, v: &Values, servo: ServoParams, moving_mass: f64) -> ActuatorParams {
        let drive = match self {
            DriveVars::VoiceCoil(d) => Drive::VoiceCoil {
                spring_stiffness: v.scalar(d.spring_stiffness),
                spring_damping: v.scalar(d.spring_damping),
            },
            DriveVars::Piezo(d) => Drive::Piezo {
                stiffness: v.scalar(d.piezo_stiffness),
                damping_ratio: v.scalar(d.piezo_damping_ratio),
                shunt: v.boolean(d.shunt_enabled).then(|| Shunt {
                    coupling: v.scalar(d.shunt_coupling),
                    frequency: v.scalar(d.shunt_frequency),
                    damping_ratio: v.scalar(d.shunt_damping_ratio),
                }),
            },
        };
        ActuatorParams {
            moving_mass,
            drive,
            servo,
        }
    }
}

impl ParamVars {
    /// The physics' segment model from the parameter values.
    pub fn model(&self, v: &Values) -> SegmentModel {
        let x = self;
        let s = |h: RealVar| v.scalar(h);
        let servo = ServoParams {
            rate: s(x.servo_rate),
            kp: s(x.servo_kp),
            ki: s(x.servo_ki),
            kd: s(x.servo_kd),
            derivative_cutoff: s(x.derivative_cutoff),
            integrator_leak: s(x.integrator_leak),
            setpoint_weight: s(x.setpoint_weight),
            feedforward: s(x.servo_feedforward),
        };
        SegmentModel {
            segment: SegmentParams {
                mass: s(x.segment_mass),
                inertia: s(x.segment_inertia),
                actuator_radius: s(x.actuator_radius),
                support_piston_frequency: s(x.support_piston_frequency),
                support_tilt_frequency: s(x.support_tilt_frequency),
                support_mass: s(x.support_mass),
                whiffletree_frequency: s(x.whiffletree_frequency),
                support_damping_ratio: s(x.support_damping_ratio),
            },
            actuator: x.drive.actuator(v, servo, s(x.actuator_mass)),
        }
    }

    /// Writes the calculated parameters (analytic static stiffnesses) of `model`.
    pub fn write_calculated(&self, v: &mut Values, model: &SegmentModel) {
        v.real_mut(self.static_stiffness_piston)[0] = model.static_stiffness(Channel::Piston);
        v.real_mut(self.static_stiffness_tilt)[0] = model.static_stiffness(Channel::Tilt);
        v.real_mut(self.whiffletree_stiffness)[0] = model.whiffletree_stiffness();
    }
}

impl SegmentsRunning {
    /// Writes `z` and `f_cell` in place, from the cell's displacement input.
    fn write_outputs(&self, v: &mut Values) -> Result<(), FmuError> {
        let x = self.vars;
        let [z_cell, z, f_cell] = v.reals_mut([x.z_cell, x.z, x.f_cell]).ok_or_else(|| {
            FmuError::Model(
                "segments: the inputs and outputs overlap or lie outside the values (internal \
                 error)"
                    .into(),
            )
        })?;
        self.array
            .outputs(z_cell, z, f_cell)
            .map_err(wiring::model_error)
    }

    /// The physics of the segments (for in-process use and tests).
    pub fn array(&self) -> &SegmentArray {
        &self.array
    }
}

impl<V: Variant> Model for Segments<V> {
    const INFO: ModelInfo = V::INFO;

    type Running = SegmentsRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to::<V>(b, &layout))?;
        let model = Self {
            vars,
            n_segments: layout.n_segments(),
            _v: PhantomData,
        };
        Ok((table, model))
    }

    fn initialize(&self, v: &mut Values, _start_time: f64) -> Result<SegmentsRunning, FmuError> {
        let model = self.vars.params.model(v);
        let array =
            SegmentArray::new(self.n_segments, model.clone()).map_err(wiring::model_error)?;
        self.vars.params.write_calculated(v, &model);
        let running = SegmentsRunning {
            vars: self.vars,
            array,
        };
        running.write_outputs(v)?;
        Ok(running)
    }
}

impl Running for SegmentsRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        self.write_outputs(v)
    }

    fn do_step(&mut self, _t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let vars = self.vars;
        self.array
            .advance(
                h,
                v.real(vars.u_cmd),
                v.real(vars.z_cell),
                v.real(vars.f_wind),
            )
            .map_err(wiring::model_error)?;
        self.write_outputs(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    #[test]
    fn tables_build_for_every_layout() {
        for variant in Layout::PRESETS {
            let (t, _) = VoiceCoil::new(variant).expect("voice coil");
            let (p, _) = Piezo::new(variant).expect("piezo");
            let na = Layout::preset(variant).expect("layout").n_actuators();
            for name in ["u_cmd", "z_cell", "f_wind", "z", "f_cell"] {
                // Same signals, same value references in both variants: one replaces the other.
                let a = t.by_name(name).expect("voice coil signal");
                let b = p.by_name(name).expect("piezo signal");
                assert_eq!((a.len, a.vr, &a.unit), (na, b.vr, &b.unit));
            }
        }
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        let doc = include_str!("lib.rs");
        assert_eq!(wiring::check_documented_signals::<VoiceCoil>(doc), Ok(()));
        assert_eq!(wiring::check_documented_signals::<Piezo>(doc), Ok(()));
    }

    /// A serialised FMU state steps on exactly as the instance it was taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let (table, _) = Piezo::new("keck").expect("table");
        let guid = fmu::xml::guid(&Piezo::INFO, &table);
        let mut fmu = Instance::<Piezo>::new("test", &guid, None, None, false).expect("new");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu.exit_initialization_mode().expect("initialise");
        let running = fmu.running().expect("running");
        assert_eq!(running.array().n_segments(), Layout::keck().n_segments());
        let u = fmu.table().by_name("u_cmd").expect("u_cmd").vr;
        fmu.set_real(&[u], &[1e-6]).expect("set u_cmd");
        let z = fmu.table().by_name("z").expect("z");
        let z: Vec<u32> = (z.vr..z.vr + z.len as u32).collect();
        let run = |fmu: &mut Instance<Piezo>, steps: usize| {
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
            Instance::<Piezo>::serialize(&fmu.get_state().expect("state")).expect("serialise");
        let original = run(&mut fmu, 3);
        let state = fmu.deserialize(&bytes).expect("deserialise");
        fmu.set_state(&state).expect("set state");
        assert_eq!(run(&mut fmu, 3), original);
        assert!(original.iter().any(|&x| x != 0.0));
    }
}
