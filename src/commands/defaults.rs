//! How the flags show the library's defaults. A flag's default is the `m1` constant or the
//! parameter struct's `Default` itself (`default_value_t = m1::...`); where `--help` shows a
//! default as text that `Display` would not give (engineering notation such as `500e-9`, or a
//! comma-separated list), the text is built once from the value ([`engineering`], [`list`]), so
//! no flag restates a number the library defines.

/// `x` in engineering notation, the exponent a multiple of 3 and the digits those of the
/// shortest round-trip form: `500e-9` for 5e-7, `10e-9` for 1e-8, `12.5e-9` for 1.25e-8, `2`
/// for 2 (no exponent when it is 0). Parses back to `x` exactly.
pub fn engineering(x: f64) -> String {
    let text = format!("{x:e}");
    let Some((mantissa, exponent)) = text.split_once('e') else {
        return text;
    };
    let Ok(exponent) = exponent.parse::<i32>() else {
        return text;
    };
    let (sign, mantissa) = match mantissa.strip_prefix('-') {
        Some(m) => ("-", m),
        None => ("", mantissa),
    };
    let digits: String = mantissa.chars().filter(|c| *c != '.').collect();
    let scaled = exponent.div_euclid(3) * 3;
    // One digit before the point in `{:e}`, then as many more as the exponent drops.
    let before = 1 + (exponent - scaled) as usize;
    let mut integer: String = digits.chars().take(before).collect();
    while integer.len() < before {
        integer.push('0');
    }
    let fraction: String = digits.chars().skip(before).collect();
    let number = if fraction.is_empty() {
        integer
    } else {
        format!("{integer}.{fraction}")
    };
    if scaled == 0 {
        format!("{sign}{number}")
    } else {
        format!("{sign}{number}e{scaled}")
    }
}

/// `values` comma-separated, each as `Display` writes it: `0.05,20` for `[0.05, 20.0]` (the
/// form `value_delimiter = ','` reads back).
pub fn list(values: &[f64]) -> String {
    values
        .iter()
        .map(f64::to_string)
        .collect::<Vec<_>>()
        .join(",")
}

#[cfg(test)]
mod tests {
    use super::*;

    use clap::CommandFactory;

    #[test]
    fn engineering_notation_round_trips() {
        assert_eq!(engineering(500e-9), "500e-9");
        assert_eq!(engineering(10e-9), "10e-9");
        assert_eq!(engineering(1.25e-8), "12.5e-9");
        assert_eq!(engineering(-3e-6), "-3e-6");
        assert_eq!(engineering(2.0), "2");
        assert_eq!(engineering(45_000.0), "45e3");
        for x in [500e-9, 10e-9, 1.25e-8, 0.1 + 0.2, 6.02e23, 1e-300] {
            assert_eq!(engineering(x).parse::<f64>(), Ok(x), "{x:e}");
        }
        assert_eq!(list(&[0.0002, 0.0004, 0.001]), "0.0002,0.0004,0.001");
        assert_eq!(list(&[0.5, 1.0, 2.0]), "0.5,1,2");
    }

    /// The defaults `--help` shows for `--flag` of `m1cs cmd`, read back.
    fn default_of(cmd: &str, flag: &str) -> Vec<f64> {
        let cli = crate::Cli::command();
        let sub = cli
            .find_subcommand(cmd)
            .unwrap_or_else(|| panic!("no subcommand {cmd}"));
        let arg = sub
            .get_arguments()
            .find(|a| a.get_long() == Some(flag))
            .unwrap_or_else(|| panic!("m1cs {cmd}: no --{flag}"));
        arg.get_default_values()
            .iter()
            .flat_map(|v| {
                v.to_str()
                    .unwrap_or_default()
                    .split(',')
                    .map(|x| x.parse::<f64>().unwrap())
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    fn default_text(cmd: &str, flag: &str) -> String {
        let cli = crate::Cli::command();
        let sub = cli.find_subcommand(cmd).unwrap();
        let arg = sub
            .get_arguments()
            .find(|a| a.get_long() == Some(flag))
            .unwrap();
        arg.get_default_values()[0]
            .to_str()
            .unwrap_or_default()
            .to_string()
    }

    /// The flags' defaults are the library's: they cannot drift apart.
    #[test]
    fn flag_defaults_are_the_library_defaults() {
        use m1::analysis::defaults as study;
        use m1::control::controller as ctl;
        let pssn = m1::optics::pssn::PssnParams::default();
        let robustness = m1::analysis::quasistatic::RobustnessParams::default();
        let criteria = m1::analysis::global_csi::GlobalCriteria::default();
        let tone = m1::analysis::coupling::Excitation::default();
        let checks: &[(&str, &str, &[f64])] = &[
            ("run", "bandwidth", &[ctl::DEFAULT_BANDWIDTH]),
            (
                "run",
                "bandwidth-radial34",
                &[ctl::DEFAULT_BANDWIDTH_RADIAL34],
            ),
            ("system", "focus-bandwidth", &[ctl::DEFAULT_BANDWIDTH_FOCUS]),
            (
                "run",
                "wind-speed",
                &[m1::loads::wind::WindParams::default().speed],
            ),
            ("run", "structure-modes", &[study::STRUCTURE_MODES as f64]),
            ("csi", "bandwidth-focus", &[ctl::DEFAULT_BANDWIDTH_FOCUS]),
            ("csi", "loop-rate", &[ctl::DEFAULT_RATE]),
            ("csi", "damping", &[study::DAMPING_RATIO]),
            ("csi", "allowance", &[criteria.allowance]),
            ("csi", "gain-range", &study::csi::GAIN_RANGE),
            ("csi", "global-modes", &[study::global_csi::MODES as f64]),
            ("wind", "speeds", &study::wind::SPEEDS),
            ("wind", "bandwidths", &study::wind::BANDWIDTHS),
            ("coupling", "steps", &study::coupling::STEPS),
            ("coupling", "tone", &[tone.frequency]),
            ("coupling", "duration", &[tone.duration]),
            ("vibration", "pier-rms", &[study::vibration::PIER_RMS]),
            (
                "robustness",
                "realizations",
                &[robustness.realizations as f64],
            ),
            (
                "robustness",
                "focus-gain-factor",
                &[robustness.focus_gain_factor],
            ),
            ("robustness", "krylov", &[robustness.krylov_dim as f64]),
            ("pssn", "samples", &[pssn.samples as f64]),
            ("pssn", "wavelength", &[pssn.wavelength]),
            ("pssn", "r0", &[pssn.r0]),
            ("pssn", "l0", &[pssn.l0]),
            (
                "pssn",
                "piston-rms",
                &[m1::optics::statistics::DEFAULT_PISTON_RMS],
            ),
        ];
        for (cmd, flag, expected) in checks {
            assert_eq!(default_of(cmd, flag), *expected, "m1cs {cmd} --{flag}");
        }
        let layout = m1::aperture::layout::DEFAULT_LAYOUT;
        for cmd in ["demo", "geometry", "amatrix", "csi", "pssn", "run", "wind"] {
            assert_eq!(default_text(cmd, "layout"), layout, "m1cs {cmd} --layout");
        }
        assert_eq!(default_text("coupling", "layout"), study::coupling::LAYOUT);
        assert_eq!(
            default_text("csi", "structure"),
            m1::plant::structure::DEFAULT_STRUCTURE
        );
        // The help's engineering notation of the library's values.
        assert_eq!(default_text("pssn", "wavelength"), "500e-9");
        assert_eq!(default_text("pssn", "tilt-rms"), "10e-9");
    }
}
