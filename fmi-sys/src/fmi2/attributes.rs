//! The attribute values of a `ScalarVariable` in modelDescription.xml (FMI 2.0, section 2.2.7):
//! causality, variability and initial, with their XML spellings. Shared by the exporter, which
//! writes them, and the importer, which reads them, so that both speak one vocabulary.

/// `causality`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Causality {
    /// Independent parameter, set before initialisation (fixed) or between steps (tunable).
    Parameter,
    /// Computed from parameters during initialisation.
    CalculatedParameter,
    /// Set by the master between steps.
    Input,
    /// Read by the master.
    Output,
    /// Internal, readable (the default).
    Local,
    /// The independent variable (time).
    Independent,
}

/// `variability`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Variability {
    /// Never changes.
    Constant,
    /// Fixed after initialisation.
    Fixed,
    /// May change between steps (parameters only).
    Tunable,
    /// Changes at communication points only.
    Discrete,
    /// Real variables that may change continuously (the default).
    Continuous,
}

/// `initial`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum Initial {
    /// The start value is the value.
    Exact,
    /// The start value is a guess.
    Approx,
    /// Computed by the FMU during initialisation; no start value.
    Calculated,
}

/// The XML spellings of an attribute enum: `xml()`, `from_xml()` and `ALL`, from one list.
macro_rules! spelled {
    ($ty:ident { $($variant:ident = $text:literal),* $(,)? }) => {
        impl $ty {
            /// Every value, in the standard's order.
            pub const ALL: &'static [$ty] = &[$($ty::$variant),*];

            /// The XML spelling.
            pub const fn xml(self) -> &'static str {
                match self {
                    $($ty::$variant => $text,)*
                }
            }

            /// The value spelled `s`, if any.
            pub fn from_xml(s: &str) -> Option<Self> {
                match s {
                    $($text => Some($ty::$variant),)*
                    _ => None,
                }
            }
        }
    };
}

spelled!(Causality {
    Parameter = "parameter",
    CalculatedParameter = "calculatedParameter",
    Input = "input",
    Output = "output",
    Local = "local",
    Independent = "independent",
});

spelled!(Variability {
    Constant = "constant",
    Fixed = "fixed",
    Tunable = "tunable",
    Discrete = "discrete",
    Continuous = "continuous",
});

spelled!(Initial {
    Exact = "exact",
    Approx = "approx",
    Calculated = "calculated",
});

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_spelling_reads_back() {
        for v in Causality::ALL {
            assert_eq!(Causality::from_xml(v.xml()), Some(*v));
        }
        for v in Variability::ALL {
            assert_eq!(Variability::from_xml(v.xml()), Some(*v));
        }
        for v in Initial::ALL {
            assert_eq!(Initial::from_xml(v.xml()), Some(*v));
        }
        assert_eq!(Causality::from_xml("Input"), None);
        assert_eq!(Causality::CalculatedParameter.xml(), "calculatedParameter");
        assert_eq!(Causality::ALL.len(), 6);
    }
}
