//! The signals between the FMUs, declared once: name, unit, length and meaning. Each FMU adds
//! a signal to its table as an input or an output ([`Signal::input`], [`Signal::output`]), so
//! that both ends of every connection of the standard system carry the same name, unit, length
//! and description, and the master's unit check ([`cosim`-side](https://fmi-standard.org))
//! passes by construction.
//!
//! | signal | unit | length | meaning |
//! |---|---|---|---|
//! | `u_cmd` | m | na | actuator position command (stroke) from the global controller |
//! | `z` | m | na | mirror displacement normal to the segment at each actuator |
//! | `f_cell` | N | na | force of each actuator on the mirror cell, +z towards the sky |
//! | `z_cell` | m | na | cell displacement at each actuator attachment |
//! | `f_wind` | N | na | wind load as equivalent forces along the segment normal at the actuators |
//! | `pier_z` | m | 1 | vertical pier displacement (base excitation) |
//! | `y` | m | ns | edge-sensor readings (height difference + Leff x dihedral) |
//! | `y_ref` | m | ns | desired edge-sensor readings (set-points) |
//! | `gap` | m | ns | gap between the segments at each sensor |
//! | `w` | m, m, rad | na | in-plane segment motion: radial, azimuthal (m), clocking (rad) per segment |
//! | `u_lo` | m | na | low-order actuator command from the optical feedback (global piston/tip/tilt) |
//! | `zenith_angle` | deg | 1 | telescope zenith angle |
//! | `temperature` | K | 1 | mirror-cell temperature change from the alignment baseline |
//!
//! na = 3 x the number of segments, ns = the number of edge sensors of the layout.

use fmu::{Decl, TableBuilder as T};
use m1::aperture::layout::Layout;

/// How long a signal is, in terms of the layout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Length {
    /// One scalar.
    One,
    /// One per actuator: 3 x the number of segments.
    Actuators,
    /// One per edge sensor.
    Sensors,
}

impl Length {
    /// The number of scalars on `layout`.
    pub fn of(self, layout: &Layout) -> usize {
        match self {
            Length::One => 1,
            Length::Actuators => layout.n_actuators(),
            Length::Sensors => layout.n_sensors(),
        }
    }
}

/// A signal between FMUs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Signal {
    /// The variable's name (the structured base name of an array).
    pub name: &'static str,
    /// Its unit (empty: mixed units, none declared).
    pub unit: &'static str,
    /// Its length.
    pub length: Length,
    /// What it is.
    pub description: &'static str,
}

impl Signal {
    /// The declaration without causality: name, length on `layout`, unit, description.
    pub fn decl(&self, layout: &Layout) -> Decl {
        let mut d = T::real(self.name).describe(self.description);
        // A scalar signal stays a scalar (`pier_z`, not the array `pier_z[1]`).
        if self.length != Length::One {
            d = d.len(self.length.of(layout));
        }
        if !self.unit.is_empty() {
            d = d.unit(self.unit);
        }
        d
    }

    /// The signal as an input of an FMU on `layout`, starting at 0.
    pub fn input(&self, layout: &Layout) -> Decl {
        self.decl(layout).input().start(0.0)
    }

    /// The signal as an output of an FMU on `layout`.
    pub fn output(&self, layout: &Layout) -> Decl {
        self.decl(layout).output()
    }
}

/// `u_cmd`: actuator position command (stroke) from the global controller.
pub const U_CMD: Signal = Signal {
    name: "u_cmd",
    unit: "m",
    length: Length::Actuators,
    description: "Actuator position command (stroke) from the global controller",
};

/// `z`: mirror displacement normal to the segment at each actuator.
pub const Z: Signal = Signal {
    name: "z",
    unit: "m",
    length: Length::Actuators,
    description: "Mirror displacement normal to the segment at each actuator",
};

/// `f_cell`: force of each actuator on the mirror cell, +z towards the sky.
pub const F_CELL: Signal = Signal {
    name: "f_cell",
    unit: "N",
    length: Length::Actuators,
    description: "Force of each actuator on the mirror cell, +z towards the sky",
};

/// `z_cell`: mirror-cell displacement at each actuator attachment.
pub const Z_CELL: Signal = Signal {
    name: "z_cell",
    unit: "m",
    length: Length::Actuators,
    description: "Mirror-cell displacement at each actuator attachment",
};

/// `f_wind`: wind load as equivalent forces along the segment normal at the actuator points.
pub const F_WIND: Signal = Signal {
    name: "f_wind",
    unit: "N",
    length: Length::Actuators,
    description: "Wind load as equivalent forces along the segment normal at the actuator points",
};

/// `pier_z`: vertical pier displacement (base excitation through the pier spring).
pub const PIER_Z: Signal = Signal {
    name: "pier_z",
    unit: "m",
    length: Length::One,
    description: "Vertical pier displacement (base excitation through the pier spring)",
};

/// `y`: edge-sensor readings: height difference + Leff x dihedral.
pub const Y: Signal = Signal {
    name: "y",
    unit: "m",
    length: Length::Sensors,
    description: "Edge-sensor readings: height difference + Leff x dihedral",
};

/// `y_ref`: desired edge-sensor readings (set-points).
pub const Y_REF: Signal = Signal {
    name: "y_ref",
    unit: "m",
    length: Length::Sensors,
    description: "Desired edge-sensor readings (set-points)",
};

/// `gap`: gap between the segments at each edge sensor.
pub const GAP: Signal = Signal {
    name: "gap",
    unit: "m",
    length: Length::Sensors,
    description: "Gap between the segments at each edge sensor",
};

/// `w`: in-plane segment motion along the prescription: w[3i+1] radial (m), w[3i+2] azimuthal (m), w[3i+3] clocking (rad) of segment i.
pub const W: Signal = Signal {
    name: "w",
    unit: "",
    length: Length::Actuators,
    description: "In-plane segment motion along the prescription: w[3i+1] radial (m), w[3i+2] azimuthal (m), w[3i+3] clocking (rad) of segment i",
};

/// `u_lo`: low-order actuator command from the optical feedback, added to the controller's
/// output.
pub const U_LO: Signal = Signal {
    name: "u_lo",
    unit: "m",
    length: Length::Actuators,
    description: "Low-order actuator command from the optical feedback (global piston/tip/tilt), added to the global controller's output",
};

/// `zenith_angle`: telescope zenith angle.
pub const ZENITH_ANGLE: Signal = Signal {
    name: "zenith_angle",
    unit: "deg",
    length: Length::One,
    description: "Telescope zenith angle",
};

/// `temperature`: mirror-cell temperature change from the alignment baseline (a difference, so
/// in K: 1 K = 1 degC of change).
pub const TEMPERATURE: Signal = Signal {
    name: "temperature",
    unit: "K",
    length: Length::One,
    description: "Mirror-cell temperature change from the alignment baseline (1 K = 1 degC of change)",
};

/// Every signal of the vocabulary.
pub const ALL: [Signal; 13] = [
    U_CMD,
    Z,
    F_CELL,
    Z_CELL,
    F_WIND,
    PIER_Z,
    Y,
    Y_REF,
    GAP,
    W,
    U_LO,
    ZENITH_ANGLE,
    TEMPERATURE,
];

/// The structural `layout` string every FMU starts with: the layout it was packaged for.
pub fn layout_decl(layout: &str) -> Decl {
    T::string("layout")
        .structural()
        .start_str(layout)
        .describe("Mirror layout this FMU was packaged for")
}

/// The structural `n_segments`: the number of segments of `layout` (actuator-sized arrays have
/// 3 x n_segments elements).
pub fn n_segments_decl(layout: &Layout) -> Decl {
    T::integer("n_segments")
        .structural()
        .start_int(count(layout.n_segments()))
        .describe("Number of segments (actuator-sized arrays have 3 x n_segments elements)")
}

/// The structural `n_sensors`: the number of edge sensors of `layout` (sensor-sized arrays).
pub fn n_sensors_decl(layout: &Layout) -> Decl {
    T::integer("n_sensors")
        .structural()
        .start_int(count(layout.n_sensors()))
        .describe("Number of edge sensors (sensor-sized arrays have n_sensors elements)")
}

/// A count as an FMI Integer (saturating: no layout comes near i32::MAX).
fn count(n: usize) -> i32 {
    i32::try_from(n).unwrap_or(i32::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Names are unique, and each signal declares its name, length and unit on a layout.
    #[test]
    fn every_signal_declares_its_name_length_and_unit() {
        let layout = Layout::preset("keck").expect("keck");
        for (i, s) in ALL.iter().enumerate() {
            assert!(
                ALL[..i].iter().all(|o| o.name != s.name),
                "{} twice",
                s.name
            );
            let mut b = T::new();
            let v = b.add_real(s.input(&layout));
            let table = b.build().expect("table");
            let var = table.by_name(s.name).expect("declared");
            assert_eq!(var.len, s.length.of(&layout));
            assert_eq!(v.len, var.len);
            assert_eq!(var.unit.as_deref().unwrap_or(""), s.unit, "{}", s.name);
            // Arrays are arrays (`z[1]`..), a scalar is named as it is.
            assert_eq!(var.array, s.length != Length::One, "{}", s.name);
        }
        assert_eq!(Length::Actuators.of(&layout), 108);
        assert_eq!(Length::Sensors.of(&layout), layout.n_sensors());
    }
}
