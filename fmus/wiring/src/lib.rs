//! What every FMU's model wiring shares: the layouts an FMU is packaged for, the signals
//! between the FMUs and the structural layout header ([`signals`]), and the mapping of physics
//! errors ([`M1Error`]) to FMI errors ([`FmuError`]) naming the variable at fault.
//! The `fmu` runtime knows nothing of mirrors and `m1` nothing of FMI, so this glue lives here.

pub mod signals;

use fmu::FmuError;
use m1::M1Error;
use m1::aperture::layout::Layout;

/// The layouts every FMU is packaged for (one .fmu each): [`Layout::PRESETS`].
pub fn layout_variants() -> Vec<String> {
    Layout::PRESETS.iter().map(|s| s.to_string()).collect()
}

/// The preset layout called `variant`, or an instantiation error.
///
/// # Errors
/// [`FmuError::Instantiate`] for an unknown layout.
pub fn preset(variant: &str) -> Result<Layout, FmuError> {
    Layout::preset(variant).map_err(|e| FmuError::Instantiate(e.to_string()))
}

/// Checks model `M`'s module documentation `doc` (its `lib.rs`, `include_str!`) against its
/// variable table on the Keck and TMT layouts: the documented signals are the declared inputs
/// and outputs, with their sizes (`na` = actuators, `ns` = edge sensors, or a number) and units
/// ([`fmu::docs::check_signal_table`]). For the wiring crates' unit tests.
///
/// # Errors
/// Every disagreement, naming the layout.
pub fn check_documented_signals<M: fmu::Model>(doc: &str) -> Result<(), String> {
    for variant in ["keck", "tmt"] {
        let layout = preset(variant).map_err(|e| e.to_string())?;
        let (table, _) = M::new(variant).map_err(|e| format!("{variant}: {e}"))?;
        let size = |s: &str| match s {
            "na" => Some(layout.n_actuators()),
            "ns" => Some(layout.n_sensors()),
            _ => None,
        };
        fmu::docs::check_signal_table(doc, &table, size).map_err(|e| format!("{variant}: {e}"))?;
    }
    Ok(())
}

/// An invalid parameter becomes [`FmuError::BadValue`] naming it; any other physics error a
/// model error.
pub fn model_error(e: M1Error) -> FmuError {
    model_error_renamed(e, |name| name)
}

/// As [`model_error`], with `rename` mapping the physics' parameter names to the FMU's variable
/// names where they differ.
pub fn model_error_renamed(e: M1Error, rename: impl Fn(&'static str) -> &'static str) -> FmuError {
    match e {
        M1Error::InvalidParameter {
            name,
            value,
            reason,
        } => FmuError::BadValue {
            variable: rename(name).to_string(),
            value: value.to_string(),
            reason: reason.to_string(),
        },
        other => FmuError::Model(other.to_string()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn invalid_parameters_name_the_variable() {
        let e = M1Error::InvalidParameter {
            name: "l0",
            value: -1.0,
            reason: "must be > 0",
        };
        match model_error_renamed(e.clone(), |n| if n == "l0" { "L0" } else { n }) {
            FmuError::BadValue { variable, .. } => assert_eq!(variable, "L0"),
            other => panic!("{other:?}"),
        }
        match model_error(e) {
            FmuError::BadValue { variable, .. } => assert_eq!(variable, "l0"),
            other => panic!("{other:?}"),
        }
        assert!(matches!(
            model_error(M1Error::Numerical("x".into())),
            FmuError::Model(_)
        ));
        assert!(preset("keck").is_ok());
        assert!(matches!(preset("nosuch"), Err(FmuError::Instantiate(_))));
        assert_eq!(layout_variants().len(), Layout::PRESETS.len());
    }
}
