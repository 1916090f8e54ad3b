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
    BoolVar, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T,
    Values, VariableTable,
};
use m1::aperture::layout::Layout;
use m1::plant::segment::{
    ActuatorParams, Channel, Drive, SegmentArray, SegmentModel, SegmentParams, ServoParams, Shunt,
};

/// What differs between actuator variants: their parameters and how they map to the physics.
pub trait Variant: Clone + Send + 'static {
    /// Static facts of the FMU.
    const INFO: ModelInfo;
    /// Declares the variant's own parameters.
    fn declare(b: &mut T) -> DriveVars;
    /// Reads them back into the physics' actuator description.
    fn actuator(v: &Values, d: &DriveVars, servo: ServoParams, moving_mass: f64) -> ActuatorParams;
}

/// Handles of the drive parameters (the ones that apply to the variant are Some).
#[derive(Debug, Clone, Copy, Serialize, Deserialize, Default)]
pub struct DriveVars {
    spring_stiffness: Option<RealVar>,
    spring_damping: Option<RealVar>,
    piezo_stiffness: Option<RealVar>,
    piezo_damping_ratio: Option<RealVar>,
    shunt_enabled: Option<BoolVar>,
    shunt_coupling: Option<RealVar>,
    shunt_frequency: Option<RealVar>,
    shunt_damping_ratio: Option<RealVar>,
}

/// Handles of every variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Vars {
    layout: StrVar,
    n_segments: IntVar,
    u_cmd: RealVar,
    z_cell: RealVar,
    f_wind: RealVar,
    z: RealVar,
    f_cell: RealVar,
    params: ParamVars,
}

/// Handles of the segment, actuator and servo parameters of a variant (shared with the FMUs
/// that embed the segments, such as the coupled mirror).
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct ParamVars {
    segment_mass: RealVar,
    segment_inertia: RealVar,
    actuator_radius: RealVar,
    support_piston_frequency: RealVar,
    support_tilt_frequency: RealVar,
    support_mass: RealVar,
    whiffletree_frequency: RealVar,
    support_damping_ratio: RealVar,
    actuator_mass: RealVar,
    servo_rate: RealVar,
    servo_kp: RealVar,
    servo_ki: RealVar,
    servo_kd: RealVar,
    derivative_cutoff: RealVar,
    integrator_leak: RealVar,
    setpoint_weight: RealVar,
    servo_feedforward: RealVar,
    static_stiffness_piston: RealVar,
    static_stiffness_tilt: RealVar,
    whiffletree_stiffness: RealVar,
    drive: DriveVars,
}

/// The segments FMU of one actuator variant.
#[derive(Clone, Serialize, Deserialize)]
#[serde(bound = "")]
pub struct Segments<V: Variant> {
    vars: Vars,
    n_segments: usize,
    array: Option<SegmentArray>,
    z: Vec<f64>,
    f_cell: Vec<f64>,
    #[serde(skip)]
    _v: PhantomData<V>,
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

    fn declare(b: &mut T) -> DriveVars {
        DriveVars {
            spring_stiffness: Some(
                b.add_real(
                    T::real("spring_stiffness")
                        .parameter()
                        .unit("N/m")
                        .start(2.0e4)
                        .non_negative()
                        .describe("Offload spring stiffness of each voice-coil actuator"),
                ),
            ),
            spring_damping: Some(
                b.add_real(
                    T::real("spring_damping")
                        .parameter()
                        .unit("N.s/m")
                        .start(50.0)
                        .non_negative()
                        .describe("Damping of the offload spring and coil"),
                ),
            ),
            ..DriveVars::default()
        }
    }

    fn actuator(v: &Values, d: &DriveVars, servo: ServoParams, moving_mass: f64) -> ActuatorParams {
        let get = |h: Option<RealVar>| h.map_or(0.0, |h| v.scalar(h));
        ActuatorParams {
            moving_mass,
            drive: Drive::VoiceCoil {
                spring_stiffness: get(d.spring_stiffness),
                spring_damping: get(d.spring_damping),
            },
            servo,
        }
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

    fn declare(b: &mut T) -> DriveVars {
        let s = Shunt::default();
        DriveVars {
            piezo_stiffness: Some(
                b.add_real(
                    T::real("piezo_stiffness")
                        .parameter()
                        .unit("N/m")
                        .start(m1::plant::segment::PIEZO_STIFFNESS)
                        .positive()
                        .describe("Open-circuit stiffness of each piezo stack"),
                ),
            ),
            piezo_damping_ratio: Some(
                b.add_real(
                    T::real("piezo_damping_ratio")
                        .parameter()
                        .unit("1")
                        .start(0.01)
                        .non_negative()
                        .describe(
                            "Structural damping ratio of the stack, on the segment's piston mode \
                             (c = 2 zeta sqrt(K (actuator_mass + segment_mass / 3)))",
                        ),
                ),
            ),
            shunt_enabled: Some(
                b.add_boolean(
                    T::boolean("shunt_enabled")
                        .parameter()
                        .start_bool(false)
                        .describe("Connect the resonant LR shunt (true: damped hard actuator)"),
                ),
            ),
            shunt_coupling: Some(
                b.add_real(
                    T::real("shunt_coupling")
                        .parameter()
                        .unit("1")
                        .start(s.coupling)
                        .check(fmu::Check::Range(0.0, 0.99))
                        .describe("Generalised electromechanical coupling factor of the stack"),
                ),
            ),
            shunt_frequency: Some(
                b.add_real(
                    T::real("shunt_frequency")
                        .parameter()
                        .unit("Hz")
                        .start(s.frequency)
                        .positive()
                        .describe("Electrical resonance of the shunt, 1/(2 pi sqrt(L C))"),
                ),
            ),
            shunt_damping_ratio: Some(
                b.add_real(
                    T::real("shunt_damping_ratio")
                        .parameter()
                        .unit("1")
                        .start(s.damping_ratio)
                        .non_negative()
                        .describe("Electrical damping ratio of the shunt, R/(2 L omega_e)"),
                ),
            ),
            ..DriveVars::default()
        }
    }

    fn actuator(v: &Values, d: &DriveVars, servo: ServoParams, moving_mass: f64) -> ActuatorParams {
        let get = |h: Option<RealVar>| h.map_or(0.0, |h| v.scalar(h));
        let shunt = d
            .shunt_enabled
            .is_some_and(|h| v.boolean(h))
            .then(|| Shunt {
                coupling: get(d.shunt_coupling),
                frequency: get(d.shunt_frequency),
                damping_ratio: get(d.shunt_damping_ratio),
            });
        ActuatorParams {
            moving_mass,
            drive: Drive::Piezo {
                stiffness: get(d.piezo_stiffness),
                damping_ratio: get(d.piezo_damping_ratio),
                shunt,
            },
            servo,
        }
    }
}

fn servo_units(piezo: bool) -> [&'static str; 3] {
    if piezo {
        ["1", "1/s", "s"]
    } else {
        ["N/m", "N/(m.s)", "N.s/m"]
    }
}

/// Declares the segment, actuator and servo parameters of variant `V` (and the calculated
/// static stiffnesses) in `b`.
pub fn declare_params<V: Variant>(b: &mut T) -> ParamVars {
    let piezo = V::INFO.model_identifier.contains("piezo");
    let defaults = if piezo {
        SegmentModel::piezo()
    } else {
        SegmentModel::voice_coil()
    };
    let seg = SegmentParams::default();
    let servo = &defaults.actuator.servo;
    let [ukp, uki, ukd] = servo_units(piezo);
    let p = |b: &mut T, name: &str, unit: &str, x: f64, positive: bool, desc: &str| {
        let d = T::real(name).parameter().unit(unit).start(x).describe(desc);
        b.add_real(if positive {
            d.positive()
        } else {
            d.non_negative()
        })
    };
    let segment_mass = p(
        b,
        "segment_mass",
        "kg",
        seg.mass,
        true,
        "Mass carried by the three actuators of a segment (glass and support module)",
    );
    let segment_inertia = p(
        b,
        "segment_inertia",
        "kg.m2",
        seg.inertia,
        true,
        "Moment of inertia of a segment about an in-plane diameter",
    );
    let actuator_radius = p(
        b,
        "actuator_radius",
        "m",
        seg.actuator_radius,
        true,
        "Radius of the actuator circle",
    );
    let support_piston_frequency = p(
        b,
        "support_piston_frequency",
        "Hz",
        seg.support_piston_frequency,
        true,
        "Piston mode of the glass on its flexures with the whiffletree clamped",
    );
    let support_tilt_frequency = p(
        b,
        "support_tilt_frequency",
        "Hz",
        seg.support_tilt_frequency,
        true,
        "Tip/tilt mode of the glass on its flexures with the whiffletree clamped",
    );
    let support_mass = p(
        b,
        "support_mass",
        "kg",
        seg.support_mass,
        false,
        "Moving frame and whiffletrees between actuators and glass, part of segment_mass \
         (0: no whiffletree, the glass's flexures on the actuator node)",
    );
    let whiffletree_frequency = p(
        b,
        "whiffletree_frequency",
        "Hz",
        seg.whiffletree_frequency,
        true,
        "Lowest mode of the assembly with the actuators locked (tip/tilt on the whiffletrees)",
    );
    let support_damping_ratio = p(
        b,
        "support_damping_ratio",
        "1",
        seg.support_damping_ratio,
        false,
        "Damping ratio of the support modes",
    );
    let actuator_mass = p(
        b,
        "actuator_mass",
        "kg",
        defaults.actuator.moving_mass,
        true,
        "Moving mass of each actuator's output node",
    );
    let servo_rate = p(
        b,
        "servo_rate",
        "Hz",
        servo.rate,
        true,
        "Sample rate of the encoder servo",
    );
    let servo_kp = p(
        b,
        "servo_kp",
        ukp,
        servo.kp,
        false,
        "Proportional gain of the encoder servo",
    );
    let servo_ki = p(
        b,
        "servo_ki",
        uki,
        servo.ki,
        false,
        "Integral gain of the encoder servo",
    );
    let servo_kd = p(
        b,
        "servo_kd",
        ukd,
        servo.kd,
        false,
        "Derivative gain of the encoder servo (on the measurement)",
    );
    let derivative_cutoff = p(
        b,
        "derivative_cutoff",
        "Hz",
        servo.derivative_cutoff,
        true,
        "Corner of the derivative's first-order filter",
    );
    let integrator_leak = p(
        b,
        "integrator_leak",
        "Hz",
        servo.integrator_leak,
        false,
        "Leak corner of the servo integrator (0: pure integrator)",
    );
    let setpoint_weight = b.add_real(
        T::real("setpoint_weight")
            .parameter()
            .unit("1")
            .start(servo.setpoint_weight)
            .check(fmu::Check::Range(0.0, 1.0))
            .describe("Weight of the command in the proportional term (1: plain PID)"),
    );
    let servo_feedforward = p(
        b,
        "servo_feedforward",
        ukp,
        servo.feedforward,
        false,
        "Command feedforward of the encoder servo (drive per metre of command)",
    );
    let drive = V::declare(b);
    let calc = |b: &mut T, name: &str, desc: &str| {
        b.add_real(
            T::real(name)
                .calculated_parameter()
                .unit("N/m")
                .describe(desc),
        )
    };
    let static_stiffness_piston = calc(
        b,
        "static_stiffness_piston",
        "Analytic static stiffness at the mirror per actuator, piston load pattern",
    );
    let static_stiffness_tilt = calc(
        b,
        "static_stiffness_tilt",
        "Analytic static stiffness at the mirror per actuator, tilt load pattern",
    );
    let whiffletree_stiffness = calc(
        b,
        "whiffletree_stiffness",
        "Stiffness of the whiffletree per actuator (from whiffletree_frequency; infinite when \
         support_mass is 0)",
    );
    ParamVars {
        segment_mass,
        segment_inertia,
        actuator_radius,
        support_piston_frequency,
        support_tilt_frequency,
        support_mass,
        whiffletree_frequency,
        support_damping_ratio,
        actuator_mass,
        servo_rate,
        servo_kp,
        servo_ki,
        servo_kd,
        derivative_cutoff,
        integrator_leak,
        setpoint_weight,
        servo_feedforward,
        static_stiffness_piston,
        static_stiffness_tilt,
        whiffletree_stiffness,
        drive,
    }
}

fn table<V: Variant>(layout: &Layout) -> Result<(VariableTable, Vars), FmuError> {
    let n = layout.n_segments();
    let na = layout.n_actuators();
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
            .start_int(i32::try_from(n).unwrap_or(i32::MAX))
            .describe("Number of segments (array sizes are 3 x n_segments)"),
    );
    let u_cmd = b.add_real(
        T::real("u_cmd")
            .input()
            .len(na)
            .unit("m")
            .start(0.0)
            .describe("Actuator position command (stroke) from the global controller"),
    );
    let z_cell = b.add_real(
        T::real("z_cell")
            .input()
            .len(na)
            .unit("m")
            .start(0.0)
            .describe("Mirror-cell displacement at each actuator attachment"),
    );
    let f_wind = b.add_real(
        T::real("f_wind")
            .input()
            .len(na)
            .unit("N")
            .start(0.0)
            .describe("Wind load on the mirror as equivalent forces at the actuator points"),
    );
    let z = b.add_real(
        T::real("z")
            .output()
            .len(na)
            .unit("m")
            .describe("Mirror displacement normal to the segment at each actuator"),
    );
    let f_cell = b.add_real(
        T::real("f_cell")
            .output()
            .len(na)
            .unit("N")
            .depends(Dependencies::Elementwise("z_cell".into()))
            .describe("Force of each actuator on the mirror cell"),
    );
    let params = declare_params::<V>(&mut b);
    let table = b.build()?;
    Ok((
        table,
        Vars {
            layout: layout_var,
            n_segments,
            u_cmd,
            z_cell,
            f_wind,
            z,
            f_cell,
            params,
        },
    ))
}

impl ParamVars {
    /// The physics' segment model from the parameter values.
    pub fn model<V: Variant>(&self, v: &Values) -> SegmentModel {
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
            actuator: V::actuator(v, &x.drive, servo, s(x.actuator_mass)),
        }
    }

    /// Writes the calculated parameters (analytic static stiffnesses) of `model`.
    pub fn write_calculated(&self, v: &mut Values, model: &SegmentModel) {
        v.real_mut(self.static_stiffness_piston)[0] = model.static_stiffness(Channel::Piston);
        v.real_mut(self.static_stiffness_tilt)[0] = model.static_stiffness(Channel::Tilt);
        v.real_mut(self.whiffletree_stiffness)[0] = model.whiffletree_stiffness();
    }
}

impl<V: Variant> Segments<V> {
    fn physics(&self, v: &Values) -> SegmentModel {
        self.vars.params.model::<V>(v)
    }

    fn write_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        let Some(array) = &self.array else {
            return Err(FmuError::Model("the segments are not initialised".into()));
        };
        array
            .outputs(v.real(self.vars.z_cell), &mut self.z, &mut self.f_cell)
            .map_err(wiring::model_error)?;
        v.real_mut(self.vars.z).copy_from_slice(&self.z);
        v.real_mut(self.vars.f_cell).copy_from_slice(&self.f_cell);
        Ok(())
    }

    /// The physics of the segments, once initialised (for in-process use and tests).
    pub fn array(&self) -> Option<&SegmentArray> {
        self.array.as_ref()
    }
}

impl<V: Variant> Model for Segments<V> {
    const INFO: ModelInfo = V::INFO;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = table::<V>(&layout)?;
        let na = layout.n_actuators();
        Ok((
            table,
            Self {
                vars,
                n_segments: layout.n_segments(),
                array: None,
                z: vec![0.0; na],
                f_cell: vec![0.0; na],
                _v: PhantomData,
            },
        ))
    }

    fn initialize(&mut self, v: &mut Values, _start_time: f64) -> Result<(), FmuError> {
        let model = self.physics(v);
        let array =
            SegmentArray::new(self.n_segments, model.clone()).map_err(wiring::model_error)?;
        self.vars.params.write_calculated(v, &model);
        self.array = Some(array);
        self.write_outputs(v)
    }

    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        self.write_outputs(v)
    }

    fn do_step(&mut self, _t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let vars = self.vars;
        let Some(array) = &mut self.array else {
            return Err(FmuError::Model("the segments are not initialised".into()));
        };
        array
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
}
