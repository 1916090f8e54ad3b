//! The units the models may use, with their SI base-unit exponents for the UnitDefinitions of
//! modelDescription.xml.

/// Base-unit exponents (kg, m, s, A, K, mol, cd, rad) of a unit, or None if unknown.
pub fn base_units(unit: &str) -> Option<[i32; 8]> {
    // kg m s A K mol cd rad
    Some(match unit {
        "1" => [0; 8],
        "m" => [0, 1, 0, 0, 0, 0, 0, 0],
        "m/s" => [0, 1, -1, 0, 0, 0, 0, 0],
        "kg" => [1, 0, 0, 0, 0, 0, 0, 0],
        "kg.m2" => [1, 2, 0, 0, 0, 0, 0, 0],
        "s" => [0, 0, 1, 0, 0, 0, 0, 0],
        "Hz" => [0, 0, -1, 0, 0, 0, 0, 0],
        "1/s" => [0, 0, -1, 0, 0, 0, 0, 0],
        "N" => [1, 1, -2, 0, 0, 0, 0, 0],
        "N/m" => [1, 0, -2, 0, 0, 0, 0, 0],
        "N.s/m" => [1, 0, -1, 0, 0, 0, 0, 0],
        "N/(m.s)" => [1, 0, -3, 0, 0, 0, 0, 0],
        "Pa" => [1, -1, -2, 0, 0, 0, 0, 0],
        "rad" => [0, 0, 0, 0, 0, 0, 0, 1],
        "m.s" => [0, 1, 1, 0, 0, 0, 0, 0],
        "kg/m3" => [1, -3, 0, 0, 0, 0, 0, 0],
        "deg" => [0, 0, 0, 0, 0, 0, 0, 1],
        "K" => [0, 0, 0, 0, 1, 0, 0, 0],
        "1/K" => [0, 0, 0, 0, -1, 0, 0, 0],
        "m/K" => [0, 1, 0, 0, -1, 0, 0, 0],
        "1/m" => [0, -1, 0, 0, 0, 0, 0, 0],
        "d" => [0, 0, 1, 0, 0, 0, 0, 0],
        _ => return None,
    })
}

/// Factor from a unit to its base units (`deg` -> rad: pi / 180; 1 for the others).
pub fn factor(unit: &str) -> f64 {
    match unit {
        "deg" => std::f64::consts::PI / 180.0,
        "d" => 86400.0,
        _ => 1.0,
    }
}

/// Names of the base units in the order of [`base_units`], as FMI attribute names.
pub const BASE_NAMES: [&str; 8] = ["kg", "m", "s", "A", "K", "mol", "cd", "rad"];
