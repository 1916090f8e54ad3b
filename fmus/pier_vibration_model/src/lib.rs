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
    FmuError, IntVar, Model, ModelInfo, RealVar, StrVar, TableBuilder as T, Values, VariableTable,
};
use m1::loads::vibration::{NoiseParams, PierVibration, Tone};

/// Number of tones.
pub const N_TONES: usize = 3;

/// Default tones (frequency Hz, amplitude m): one 10 nm tone at 29.6 Hz (induction motors,
/// amplitude *assumed*); tones 2 and 3 disabled.
pub const DEFAULT_TONES: [(f64, f64); N_TONES] = [(29.6, 1e-8), (10.0, 0.0), (60.0, 0.0)];

/// Handles of every variable.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
struct Vars {
    layout: StrVar,
    pier_z: RealVar,
    tone_frequency: [RealVar; N_TONES],
    tone_amplitude: [RealVar; N_TONES],
    tone_phase: [RealVar; N_TONES],
    noise_rms: RealVar,
    noise_low_frequency: RealVar,
    noise_high_frequency: RealVar,
    noise_period: RealVar,
    noise_seed: IntVar,
    pier_z_rms: RealVar,
}

/// The `pier_vibration` FMU.
#[derive(Clone, Serialize, Deserialize)]
pub struct PierVibrationFmu {
    vars: Vars,
    source: Option<PierVibration>,
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

fn table(layout: &str) -> Result<(VariableTable, Vars), FmuError> {
    let noise = NoiseParams::default();
    let mut b = T::new();
    let layout_var =
        b.add_string(T::string("layout").structural().start_str(layout).describe(
            "Mirror layout this FMU was packaged for (the signal does not depend on it)",
        ));
    let pier_z = b.add_real(
        T::real("pier_z")
            .output()
            .unit("m")
            .describe("Vertical pier displacement"),
    );
    let tone_frequency = std::array::from_fn(|j| {
        b.add_real(
            T::real(&format!("tone_{}_frequency", j + 1))
                .parameter()
                .unit("Hz")
                .start(DEFAULT_TONES[j].0)
                .non_negative()
                .describe(&format!("Frequency of tone {}", j + 1)),
        )
    });
    let tone_amplitude = std::array::from_fn(|j| {
        b.add_real(
            T::real(&format!("tone_{}_amplitude", j + 1))
                .parameter()
                .unit("m")
                .start(DEFAULT_TONES[j].1)
                .non_negative()
                .describe(&format!("Amplitude of tone {} (0 disables it)", j + 1)),
        )
    });
    let tone_phase = std::array::from_fn(|j| {
        b.add_real(
            T::real(&format!("tone_{}_phase", j + 1))
                .parameter()
                .unit("rad")
                .start(0.0)
                .describe(&format!("Phase of tone {}: A sin(2 pi f t + phase)", j + 1)),
        )
    });
    let noise_rms = b.add_real(
        T::real("noise_rms")
            .parameter()
            .unit("m")
            .start(noise.rms)
            .non_negative()
            .describe("rms of the band-limited noise (0 disables it)"),
    );
    let noise_low_frequency = b.add_real(
        T::real("noise_low_frequency")
            .parameter()
            .unit("Hz")
            .start(noise.low)
            .non_negative()
            .describe("Lower edge of the noise band"),
    );
    let noise_high_frequency = b.add_real(
        T::real("noise_high_frequency")
            .parameter()
            .unit("Hz")
            .start(noise.high)
            .positive()
            .describe("Upper edge of the noise band (> noise_low_frequency)"),
    );
    let noise_period = b.add_real(
        T::real("noise_period")
            .parameter()
            .unit("s")
            .start(noise.period)
            .positive()
            .describe("Period after which the noise repeats (memory: 64 x noise_high_frequency bytes per second)"),
    );
    let noise_seed = b.add_integer(
        T::integer("noise_seed")
            .parameter()
            .start_int(1)
            .describe("Seed of the noise"),
    );
    let pier_z_rms = b.add_real(
        T::real("pier_z_rms")
            .calculated_parameter()
            .unit("m")
            .describe("Expected rms of pier_z, sqrt(sum A^2 / 2 + noise_rms^2)"),
    );
    let table = b.build()?;
    Ok((
        table,
        Vars {
            layout: layout_var,
            pier_z,
            tone_frequency,
            tone_amplitude,
            tone_phase,
            noise_rms,
            noise_low_frequency,
            noise_high_frequency,
            noise_period,
            noise_seed,
            pier_z_rms,
        },
    ))
}

impl PierVibrationFmu {
    /// The vibration source, once initialised (for in-process use and tests).
    pub fn source(&self) -> Option<&PierVibration> {
        self.source.as_ref()
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

    fn variants() -> Vec<String> {
        wiring::layout_variants()
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let layout = wiring::preset(variant)?;
        let (table, vars) = table(&layout.name)?;
        Ok((table, PierVibrationFmu { vars, source: None }))
    }

    fn initialize(&mut self, v: &mut Values, start_time: f64) -> Result<(), FmuError> {
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
        self.source = Some(source);
        Ok(())
    }

    fn update_outputs(&mut self, _v: &mut Values) -> Result<(), FmuError> {
        // No inputs: the output only changes with time.
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let Some(source) = &self.source else {
            return Err(FmuError::Model(
                "the pier vibration is not initialised".into(),
            ));
        };
        v.real_mut(self.vars.pier_z)[0] = source.at(t + h);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_build_for_every_layout() {
        for variant in m1::aperture::layout::Layout::PRESETS {
            let (t, _) = PierVibrationFmu::new(variant).expect("table");
            assert_eq!(t.by_name("pier_z").map(|v| v.len), Some(1));
        }
    }
}
