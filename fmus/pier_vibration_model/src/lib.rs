//! Model wiring of the `pier_vibration` FMU: vertical pier vibration, tones plus seeded
//! band-limited noise ([`m1::loads::vibration`]).
//!
//! | variable | causality | size | unit |
//! |---|---|---|---|
//! | `pier_z` | output | 1 | m |
//!
//! The signal does not depend on the mirror layout; the FMU is packaged per layout like the
//! others (it carries the `layout` it was packaged for) so that every system of a layout comes
//! from one folder.

use serde::{Deserialize, Serialize};

use fmu::{
    Decl, FmuError, IntVar, Model, ModelInfo, RealVar, Running, StrVar, TableBuilder as T, Values,
    VariableTable,
};
use m1::aperture::layout::Layout;
use m1::loads::vibration::{NoiseParams, PierVibration, Tone};
use wiring::signals::{PIER_Z, layout_decl};

/// Number of tones.
pub const N_TONES: usize = 3;

/// Default tones (frequency Hz, amplitude m): one 10 nm tone at 29.6 Hz (induction motors,
/// amplitude *assumed*); tones 2 and 3 disabled.
pub const DEFAULT_TONES: [(f64, f64); N_TONES] = [(29.6, 1e-8), (10.0, 0.0), (60.0, 0.0)];

fmu::variables! {
    /// Handles of every variable.
    #[derive(Debug, Clone, Copy, Serialize, Deserialize)]
    struct Vars(b, layout: &Layout) {
        layout: StrVar = layout_decl(&layout.name)
            .describe("Mirror layout this FMU was packaged for (the signal does not depend on it)"),
        pier_z: RealVar = PIER_Z.output(layout),
        tone_frequency: [RealVar; N_TONES] => per_tone(b, |j| {
            T::real(&format!("tone_{}_frequency", j + 1)).parameter().unit("Hz")
                .start(DEFAULT_TONES[j].0).non_negative()
                .describe(&format!("Frequency of tone {}", j + 1))
        }),
        tone_amplitude: [RealVar; N_TONES] => per_tone(b, |j| {
            T::real(&format!("tone_{}_amplitude", j + 1)).parameter().unit("m")
                .start(DEFAULT_TONES[j].1).non_negative()
                .describe(&format!("Amplitude of tone {} (0 disables it)", j + 1))
        }),
        tone_phase: [RealVar; N_TONES] => per_tone(b, |j| {
            T::real(&format!("tone_{}_phase", j + 1)).parameter().unit("rad").start(0.0)
                .describe(&format!("Phase of tone {}: A sin(2 pi f t + phase)", j + 1))
        }),
        noise_rms: RealVar = T::real("noise_rms").parameter().unit("m")
            .start(NoiseParams::default().rms).non_negative()
            .describe("rms of the band-limited noise (0 disables it)"),
        noise_low_frequency: RealVar = T::real("noise_low_frequency").parameter().unit("Hz")
            .start(NoiseParams::default().low).non_negative()
            .describe("Lower edge of the noise band"),
        noise_high_frequency: RealVar = T::real("noise_high_frequency").parameter().unit("Hz")
            .start(NoiseParams::default().high).positive()
            .describe("Upper edge of the noise band (> noise_low_frequency)"),
        noise_period: RealVar = T::real("noise_period").parameter().unit("s")
            .start(NoiseParams::default().period).positive()
            .describe("Period after which the noise repeats (memory: 64 x noise_high_frequency \
                       bytes per second)"),
        noise_seed: IntVar = T::integer("noise_seed").parameter().start_int(1)
            .describe("Seed of the noise"),
        pier_z_rms: RealVar = T::real("pier_z_rms").calculated_parameter().unit("m")
            .describe("Expected rms of pier_z, sqrt(sum A^2 / 2 + noise_rms^2)"),
    }
}

/// One parameter per tone, `tone_1_...` to `tone_3_...` in this order (`decl(j)` declares tone
/// j + 1): the three tones' frequencies come first, then their amplitudes, then their phases.
fn per_tone(b: &mut T, decl: impl Fn(usize) -> Decl) -> [RealVar; N_TONES] {
    std::array::from_fn(|j| b.add_real(decl(j)))
}

/// The `pier_vibration` FMU as configured: the handles; [`PierVibrationRunning`] steps.
#[derive(Debug, Clone)]
pub struct PierVibrationFmu {
    vars: Vars,
}

/// The initialised `pier_vibration` FMU: the vibration source.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PierVibrationRunning {
    vars: Vars,
    source: PierVibration,
}

const DOC: &str = "<h2>Model</h2>\
<p><code>pier_z</code>(t) = &sum;<sub>j</sub> A<sub>j</sub> sin(2&pi; f<sub>j</sub> t + \
&phi;<sub>j</sub>) + n(t): three tones (<code>tone_j_frequency</code>, \
<code>tone_j_amplitude</code>, <code>tone_j_phase</code>; amplitude 0 disables a tone; default \
one 10 nm tone at 29.6 Hz, typical of large induction motors, amplitude <i>assumed</i>) and \
seeded Gaussian noise n(t) of rms <code>noise_rms</code> (default 1 nm, <i>assumed</i>; 0 \
disables it) band-limited to [<code>noise_low_frequency</code>, \
<code>noise_high_frequency</code>]. The noise is synthesised once at initialisation by inverse \
FFT as a periodic signal of period <code>noise_period</code> sampled at 8 times the upper band \
edge (every Fourier bin in the band gets a complex normal coefficient; the rms over the period \
is scaled to <code>noise_rms</code> exactly) and interpolated (cubic) between samples. The tones \
are evaluated exactly at t. The output at t depends on t only: any sequence of communication \
steps gives the same samples.</p>\
<p><code>pier_z_rms</code> = &radic;(&sum; A<sub>j</sub><sup>2</sup>/2 + \
noise_rms<sup>2</sup>) is the expected rms of the output (distinct tone frequencies).</p>";

impl PierVibrationRunning {
    /// The vibration source (for in-process use and tests).
    pub fn source(&self) -> &PierVibration {
        &self.source
    }
}

impl Model for PierVibrationFmu {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "pier_vibration",
        model_name: "Pier vibration",
        description: "Vertical pier vibration: equipment tones plus seeded band-limited noise",
        documentation: DOC,
        default_stop_time: 1.0,
        default_step: 1e-3,
    };

    type Running = PierVibrationRunning;

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = T::declare(|b| Vars::add_to(b, &layout))?;
        Ok((table, PierVibrationFmu { vars }))
    }

    fn initialize(
        &self,
        v: &mut Values,
        start_time: f64,
    ) -> Result<PierVibrationRunning, FmuError> {
        let x = self.vars;
        let s = |h: RealVar| v.scalar(h);
        let tones: Vec<Tone> = (0..N_TONES)
            .map(|j| Tone {
                frequency: s(x.tone_frequency[j]),
                amplitude: s(x.tone_amplitude[j]),
                phase: s(x.tone_phase[j]),
            })
            .collect();
        let noise = NoiseParams {
            rms: s(x.noise_rms),
            low: s(x.noise_low_frequency),
            high: s(x.noise_high_frequency),
            period: s(x.noise_period),
            seed: u64::from(v.integer(x.noise_seed) as u32),
        };
        let source = PierVibration::new(&tones, &noise).map_err(wiring::model_error)?;
        v.real_mut(x.pier_z_rms)[0] = source.expected_rms();
        v.real_mut(x.pier_z)[0] = source.at(start_time);
        Ok(PierVibrationRunning { vars: x, source })
    }
}

impl Running for PierVibrationRunning {
    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // No inputs: the output only changes with time.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        v.real_mut(self.vars.pier_z)[0] = self.source.at(t + h);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use fmu::Instance;

    /// An instance of `variant` through the runtime, in initialisation mode (start time 0).
    fn instance(variant: &str) -> Instance<PierVibrationFmu> {
        let (table, _) = PierVibrationFmu::new(variant).expect("table");
        let guid = fmu::xml::guid(&PierVibrationFmu::INFO, &table);
        let mut fmu =
            Instance::<PierVibrationFmu>::new("test", &guid, None, None, false).expect("instance");
        fmu.setup_experiment(0.0, None).expect("setup");
        fmu.enter_initialization_mode()
            .expect("initialisation mode");
        fmu
    }

    /// The value references of a variable's scalars.
    fn vrs(fmu: &Instance<PierVibrationFmu>, name: &str) -> Vec<u32> {
        let v = fmu.table().by_name(name).expect(name);
        (v.vr..v.vr + v.len as u32).collect()
    }

    /// `steps` communication steps of 10 ms, then the values of `name`.
    fn run(fmu: &mut Instance<PierVibrationFmu>, steps: usize, name: &str) -> Vec<f64> {
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
            let (t, _) = PierVibrationFmu::new(variant).expect("table");
            assert_eq!(t.by_name("pier_z").map(|v| v.len), Some(1));
        }
    }

    /// `pier_z` stays the scalar `pier_z` (not the array `pier_z[1]`), with the vocabulary's
    /// unit and description.
    #[test]
    fn pier_z_is_the_scalar_of_the_vocabulary() {
        let (t, _) = PierVibrationFmu::new("keck").expect("table");
        let v = t.by_name("pier_z").expect("pier_z");
        assert_eq!(v.scalar_name(0), "pier_z");
        assert_eq!(v.unit.as_deref(), Some(PIER_Z.unit));
        assert_eq!(v.description, PIER_Z.description);
    }

    #[test]
    fn the_module_documentation_lists_the_signals() {
        assert_eq!(
            wiring::check_documented_signals::<PierVibrationFmu>(include_str!("lib.rs")),
            Ok(())
        );
    }

    /// A serialised FMU state steps on exactly as the instance it was taken from.
    #[test]
    fn a_serialised_state_steps_on_as_the_original() {
        let mut fmu = instance("keck");
        fmu.exit_initialization_mode().expect("initialise");
        assert!(fmu.running().expect("running").source().expected_rms() > 0.0);
        run(&mut fmu, 2, "pier_z");
        let bytes = Instance::<PierVibrationFmu>::serialize(&fmu.get_state().expect("state"))
            .expect("serialise");
        let original = run(&mut fmu, 3, "pier_z");
        let state = fmu.deserialize(&bytes).expect("deserialise");
        fmu.set_state(&state).expect("set state");
        assert_eq!(run(&mut fmu, 3, "pier_z"), original);
        assert_ne!(original, [0.0]);
    }
}
