//! The variable table: every variable of a model declared once, with everything the rest of the
//! runtime derives from it (value references, start values, get/set dispatch, checks on set, the
//! generated modelDescription.xml and documentation).
//!
//! Arrays are declared as one entry of length n; FMI 2.0 sees them as the scalars `z[1]`..`z[n]`
//! (structured naming) with contiguous value references. Value references are unique across
//! types: Reals take 0..nR, then Integers, Booleans and Strings follow, so a Real's value
//! reference is also its index in the value store.

use serde::{Deserialize, Serialize};
use std::ffi::CString;

use crate::error::FmuError;

/// The FMI base type of a variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum VarType {
    /// fmi2Real (f64).
    Real,
    /// fmi2Integer (i32).
    Integer,
    /// fmi2Boolean.
    Boolean,
    /// fmi2String.
    String,
}

impl VarType {
    /// The XML element name.
    pub fn xml(self) -> &'static str {
        match self {
            VarType::Real => "Real",
            VarType::Integer => "Integer",
            VarType::Boolean => "Boolean",
            VarType::String => "String",
        }
    }
    fn index(self) -> usize {
        match self {
            VarType::Real => 0,
            VarType::Integer => 1,
            VarType::Boolean => 2,
            VarType::String => 3,
        }
    }
}

pub use fmi_sys::fmi2::{Causality, Initial, Variability};

/// A start value.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Start {
    /// Real start (every element of an array).
    Real(f64),
    /// Integer start.
    Integer(i32),
    /// Boolean start.
    Boolean(bool),
    /// String start.
    String(String),
}

/// A constraint checked whenever a value is set; a violation rejects the whole call.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Check {
    /// Any finite value (the default for Reals: NaN and infinities are always rejected).
    Finite,
    /// > 0.
    Positive,
    /// >= 0.
    NonNegative,
    /// Within [min, max].
    Range(f64, f64),
    /// Must equal the packaged value: structural parameters such as sizes and layout names.
    Packaged,
}

/// How an output depends on the inputs (FMI ModelStructure dependencies).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Dependencies {
    /// Depends on no input (only on states and parameters).
    None,
    /// Element i depends on element i of the named input array (same length).
    Elementwise(String),
    /// Every element depends on every element of the named inputs.
    All(Vec<String>),
}

/// One variable (scalar, or array of `len` scalars).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Variable {
    /// Base name (`z`), scalars are `z[1]`..`z[len]` when `array` is true.
    pub name: String,
    /// FMI type.
    pub ty: VarType,
    /// First value reference.
    pub vr: u32,
    /// Number of scalars.
    pub len: usize,
    /// Declared as an array (even of length 1).
    pub array: bool,
    /// Causality.
    pub causality: Causality,
    /// Variability.
    pub variability: Variability,
    /// Initial, if stated.
    pub initial: Option<Initial>,
    /// Start value (required for inputs and exact/approx variables).
    pub start: Option<Start>,
    /// Unit name (must be known to [`crate::units`]).
    pub unit: Option<String>,
    /// Description.
    pub description: String,
    /// Check on set.
    pub check: Check,
    /// Output dependencies.
    pub dependencies: Dependencies,
    /// Index of the first scalar in the store of its type.
    pub slot: usize,
}

impl Variable {
    /// Name of scalar `i` (0-based).
    pub fn scalar_name(&self, i: usize) -> String {
        if self.array {
            format!("{}[{}]", self.name, i + 1)
        } else {
            self.name.clone()
        }
    }

    /// Whether `vr` belongs to this variable.
    pub fn contains(&self, vr: u32) -> bool {
        vr >= self.vr && ((vr - self.vr) as usize) < self.len
    }

    /// The check applied when setting this variable, as text.
    pub fn check_text(&self) -> String {
        match &self.check {
            Check::Finite => String::new(),
            Check::Positive => "> 0".into(),
            Check::NonNegative => ">= 0".into(),
            Check::Range(a, b) => format!("in [{a}, {b}]"),
            Check::Packaged => "fixed by the packaged layout".into(),
        }
    }
}

/// A handle to a Real variable in the store.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RealVar {
    /// First slot (= value reference for Reals).
    pub slot: usize,
    /// Number of scalars.
    pub len: usize,
}

/// A handle to an Integer variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct IntVar {
    /// Slot in the integer store.
    pub slot: usize,
}

/// A handle to a Boolean variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct BoolVar {
    /// Slot in the boolean store.
    pub slot: usize,
}

/// A handle to a String variable.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct StrVar {
    /// Slot in the string store.
    pub slot: usize,
}

/// The current values of every variable, by type.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Values {
    /// Reals, indexed by value reference.
    pub reals: Vec<f64>,
    /// Integers.
    pub integers: Vec<i32>,
    /// Booleans.
    pub booleans: Vec<bool>,
    /// Strings (NUL-free; kept as C strings so fmi2GetString can hand out pointers).
    #[serde(with = "cstrings")]
    pub strings: Vec<CString>,
}

mod cstrings {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use std::ffi::CString;

    pub fn serialize<S: Serializer>(v: &[CString], s: S) -> Result<S::Ok, S::Error> {
        let strs: Vec<&[u8]> = v.iter().map(|c| c.as_bytes()).collect();
        strs.serialize(s)
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<CString>, D::Error> {
        let raw: Vec<Vec<u8>> = Vec::deserialize(d)?;
        raw.into_iter()
            .map(|b| CString::new(b).map_err(serde::de::Error::custom))
            .collect()
    }
}

impl Values {
    /// The scalars of a Real variable.
    #[inline]
    pub fn real(&self, v: RealVar) -> &[f64] {
        &self.reals[v.slot..v.slot + v.len]
    }
    /// The scalars of a Real variable, mutable.
    #[inline]
    pub fn real_mut(&mut self, v: RealVar) -> &mut [f64] {
        &mut self.reals[v.slot..v.slot + v.len]
    }
    /// The scalars of several Real variables at once, each mutable (a model that reads some
    /// and writes others in one call, with no copy in between); `None` if two overlap or one
    /// lies outside the values.
    #[inline]
    pub fn reals_mut<const N: usize>(&mut self, vars: [RealVar; N]) -> Option<[&mut [f64]; N]> {
        self.reals
            .get_disjoint_mut(vars.map(|v| v.slot..v.slot + v.len))
            .ok()
    }
    /// A scalar Real.
    #[inline]
    pub fn scalar(&self, v: RealVar) -> f64 {
        self.reals[v.slot]
    }
    /// An Integer.
    #[inline]
    pub fn integer(&self, v: IntVar) -> i32 {
        self.integers[v.slot]
    }
    /// A Boolean.
    #[inline]
    pub fn boolean(&self, v: BoolVar) -> bool {
        self.booleans[v.slot]
    }
    /// A Boolean, mutable.
    #[inline]
    pub fn boolean_mut(&mut self, v: BoolVar) -> &mut bool {
        &mut self.booleans[v.slot]
    }
    /// A String.
    pub fn string(&self, v: StrVar) -> &str {
        self.strings[v.slot].to_str().unwrap_or("")
    }
}

/// All variables of one packaged model.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct VariableTable {
    vars: Vec<Variable>,
    counts: [usize; 4],
    bases: [u32; 4],
}

impl VariableTable {
    /// The variables in declaration order.
    pub fn variables(&self) -> &[Variable] {
        &self.vars
    }

    /// Number of scalars of each type (Real, Integer, Boolean, String).
    pub fn counts(&self) -> [usize; 4] {
        self.counts
    }

    /// Looks a variable up by base name.
    pub fn by_name(&self, name: &str) -> Option<&Variable> {
        self.vars.iter().find(|v| v.name == name)
    }

    /// The variable holding value reference `vr`, with its element index.
    pub fn lookup(&self, vr: u32) -> Option<(&Variable, usize)> {
        // Variables are sorted by value reference within the table (assigned in order per
        // type, types in fixed order), so a binary search over a sorted index would work; the
        // tables are small (tens of entries), so a scan is as fast.
        self.vars
            .iter()
            .find(|v| v.contains(vr))
            .map(|v| (v, (vr - v.vr) as usize))
    }

    /// Store with every start value (calculated variables start at zero / empty).
    pub fn initial_values(&self) -> Values {
        let mut vals = Values {
            reals: vec![0.0; self.counts[0]],
            integers: vec![0; self.counts[1]],
            booleans: vec![false; self.counts[2]],
            strings: vec![CString::default(); self.counts[3]],
        };
        for v in &self.vars {
            let r = v.slot..v.slot + v.len;
            match &v.start {
                Some(Start::Real(x)) => vals.reals[r].fill(*x),
                Some(Start::Integer(x)) => vals.integers[r].fill(*x),
                Some(Start::Boolean(x)) => vals.booleans[r].fill(*x),
                Some(Start::String(s)) => {
                    let c = CString::new(s.as_str()).unwrap_or_default();
                    for slot in r {
                        vals.strings[slot] = c.clone();
                    }
                }
                None => {}
            }
        }
        vals
    }

    /// Checks a Real value against the variable's constraint.
    pub fn check_real(&self, var: &Variable, i: usize, x: f64) -> Result<(), FmuError> {
        let bad = |reason: String| {
            Err(FmuError::BadValue {
                variable: var.scalar_name(i),
                value: x.to_string(),
                reason,
            })
        };
        if !x.is_finite() {
            return bad("must be a finite number".into());
        }
        match &var.check {
            Check::Finite => Ok(()),
            Check::Positive if x > 0.0 => Ok(()),
            Check::NonNegative if x >= 0.0 => Ok(()),
            Check::Range(a, b) if (*a..=*b).contains(&x) => Ok(()),
            Check::Packaged if Some(&Start::Real(x)) == var.start.as_ref() => Ok(()),
            Check::Packaged => bad(format!(
                "disagrees with the packaged value {}",
                start_text(var.start.as_ref())
            )),
            _ => bad(format!("must be {}", var.check_text())),
        }
    }

    /// Checks an Integer value against the variable's constraint.
    pub fn check_integer(&self, var: &Variable, i: usize, x: i32) -> Result<(), FmuError> {
        let ok = match &var.check {
            Check::Finite => true,
            Check::Positive => x > 0,
            Check::NonNegative => x >= 0,
            Check::Range(a, b) => (*a..=*b).contains(&f64::from(x)),
            Check::Packaged => Some(&Start::Integer(x)) == var.start.as_ref(),
        };
        if ok {
            Ok(())
        } else {
            Err(FmuError::BadValue {
                variable: var.scalar_name(i),
                value: x.to_string(),
                reason: match var.check {
                    Check::Packaged => format!(
                        "disagrees with the packaged value {}",
                        start_text(var.start.as_ref())
                    ),
                    _ => format!("must be {}", var.check_text()),
                },
            })
        }
    }

    /// Checks a String value against the variable's constraint.
    pub fn check_string(&self, var: &Variable, i: usize, x: &str) -> Result<(), FmuError> {
        if var.check == Check::Packaged && Some(&Start::String(x.to_string())) != var.start.as_ref()
        {
            return Err(FmuError::BadValue {
                variable: var.scalar_name(i),
                value: format!("\"{x}\""),
                reason: format!(
                    "disagrees with the packaged value {}",
                    start_text(var.start.as_ref())
                ),
            });
        }
        Ok(())
    }
}

/// A start value as text (XML and documentation).
pub fn start_text(s: Option<&Start>) -> String {
    match s {
        Some(Start::Real(x)) => format_real(*x),
        Some(Start::Integer(x)) => x.to_string(),
        Some(Start::Boolean(x)) => x.to_string(),
        Some(Start::String(x)) => x.clone(),
        None => String::new(),
    }
}

/// A Real printed so that it parses back to the same f64 (shortest round-trip form).
pub fn format_real(x: f64) -> String {
    let s = format!("{x:?}");
    // Rust's Debug form is round-trip exact; XML schema doubles accept it ("1e-5", "220.0").
    s
}

/// Builds a [`VariableTable`]: declare each variable once, get a typed handle back.
#[derive(Debug, Default)]
pub struct TableBuilder {
    vars: Vec<Variable>,
    errors: Vec<String>,
}

/// A variable being declared; finish with one of the `add` methods of the builder.
#[derive(Debug, Clone)]
pub struct Decl {
    v: Variable,
}

impl Decl {
    fn new(name: &str, ty: VarType) -> Self {
        Self {
            v: Variable {
                name: name.to_string(),
                ty,
                vr: 0,
                len: 1,
                array: false,
                causality: Causality::Local,
                variability: if ty == VarType::Real {
                    Variability::Continuous
                } else {
                    Variability::Discrete
                },
                initial: None,
                start: None,
                unit: None,
                description: String::new(),
                check: Check::Finite,
                dependencies: Dependencies::None,
                slot: 0,
            },
        }
    }

    /// An input (continuous for Reals), with a start value.
    pub fn input(mut self) -> Self {
        self.v.causality = Causality::Input;
        self
    }
    /// An output computed by the model (initial="calculated").
    pub fn output(mut self) -> Self {
        self.v.causality = Causality::Output;
        self.v.initial = Some(Initial::Calculated);
        self
    }
    /// A fixed parameter (initial="exact").
    pub fn parameter(mut self) -> Self {
        self.v.causality = Causality::Parameter;
        self.v.variability = Variability::Fixed;
        self.v.initial = Some(Initial::Exact);
        self
    }
    /// A tunable parameter (initial="exact").
    pub fn tunable(mut self) -> Self {
        self.v.causality = Causality::Parameter;
        self.v.variability = Variability::Tunable;
        self.v.initial = Some(Initial::Exact);
        self
    }
    /// A parameter computed by the model during initialisation (initial="calculated").
    pub fn calculated_parameter(mut self) -> Self {
        self.v.causality = Causality::CalculatedParameter;
        self.v.variability = Variability::Fixed;
        self.v.initial = Some(Initial::Calculated);
        self.v.start = None;
        self
    }
    /// A structural parameter that must keep its packaged value (sizes, layout name).
    pub fn structural(mut self) -> Self {
        self = self.parameter();
        self.v.check = Check::Packaged;
        self
    }
    /// Discrete variability (Real outputs updated at communication points only).
    pub fn discrete(mut self) -> Self {
        self.v.variability = Variability::Discrete;
        self
    }
    /// An array of `n` scalars.
    pub fn len(mut self, n: usize) -> Self {
        self.v.len = n;
        self.v.array = true;
        self
    }
    /// Unit.
    pub fn unit(mut self, u: &str) -> Self {
        self.v.unit = Some(u.to_string());
        self
    }
    /// Description.
    pub fn describe(mut self, d: &str) -> Self {
        self.v.description = d.to_string();
        self
    }
    /// Real start value.
    pub fn start(mut self, x: f64) -> Self {
        self.v.start = Some(Start::Real(x));
        self
    }
    /// Integer start value.
    pub fn start_int(mut self, x: i32) -> Self {
        self.v.start = Some(Start::Integer(x));
        self
    }
    /// Boolean start value.
    pub fn start_bool(mut self, x: bool) -> Self {
        self.v.start = Some(Start::Boolean(x));
        self
    }
    /// String start value.
    pub fn start_str(mut self, x: &str) -> Self {
        self.v.start = Some(Start::String(x.to_string()));
        self
    }
    /// Value check on set.
    pub fn check(mut self, c: Check) -> Self {
        self.v.check = c;
        self
    }
    /// > 0.
    pub fn positive(self) -> Self {
        self.check(Check::Positive)
    }
    /// >= 0.
    pub fn non_negative(self) -> Self {
        self.check(Check::NonNegative)
    }
    /// Output dependencies on inputs.
    pub fn depends(mut self, d: Dependencies) -> Self {
        self.v.dependencies = d;
        self
    }
}

impl TableBuilder {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Starts a Real variable.
    pub fn real(name: &str) -> Decl {
        Decl::new(name, VarType::Real)
    }
    /// Starts an Integer variable.
    pub fn integer(name: &str) -> Decl {
        Decl::new(name, VarType::Integer)
    }
    /// Starts a Boolean variable.
    pub fn boolean(name: &str) -> Decl {
        Decl::new(name, VarType::Boolean)
    }
    /// Starts a String variable.
    pub fn string(name: &str) -> Decl {
        Decl::new(name, VarType::String)
    }

    fn push(&mut self, d: Decl, ty: VarType) -> usize {
        let v = d.v;
        if v.ty != ty {
            self.errors.push(format!(
                "{}: declared as {:?}, added as {ty:?}",
                v.name, v.ty
            ));
        }
        if self.vars.iter().any(|o| o.name == v.name) {
            self.errors.push(format!("{}: declared twice", v.name));
        }
        if v.len == 0 {
            self.errors.push(format!("{}: array of length 0", v.name));
        }
        let slot = self
            .vars
            .iter()
            .filter(|o| o.ty == v.ty)
            .map(|o| o.len)
            .sum();
        self.vars.push(Variable { slot, ..v });
        slot
    }

    /// Adds a Real variable and returns its handle.
    pub fn add_real(&mut self, d: Decl) -> RealVar {
        let len = d.v.len;
        let slot = self.push(d, VarType::Real);
        RealVar { slot, len }
    }
    /// Adds an Integer variable.
    pub fn add_integer(&mut self, d: Decl) -> IntVar {
        IntVar {
            slot: self.push(d, VarType::Integer),
        }
    }
    /// Adds a Boolean variable.
    pub fn add_boolean(&mut self, d: Decl) -> BoolVar {
        BoolVar {
            slot: self.push(d, VarType::Boolean),
        }
    }
    /// Adds a String variable.
    pub fn add_string(&mut self, d: Decl) -> StrVar {
        StrVar {
            slot: self.push(d, VarType::String),
        }
    }

    /// Checks the declarations against the FMI 2.0 rules and assigns value references.
    pub fn build(mut self) -> Result<VariableTable, FmuError> {
        let mut counts = [0usize; 4];
        for v in &self.vars {
            counts[v.ty.index()] += v.len;
        }
        let mut bases = [0u32; 4];
        let mut acc = 0u32;
        for (b, c) in bases.iter_mut().zip(counts) {
            *b = acc;
            acc += c as u32;
        }
        let names: Vec<(String, usize, Causality)> = self
            .vars
            .iter()
            .map(|v| (v.name.clone(), v.len, v.causality))
            .collect();
        for v in &mut self.vars {
            v.vr = bases[v.ty.index()] + v.slot as u32;
            let e = &mut self.errors;
            let n = &v.name;
            let has_start = v.start.is_some();
            match (v.causality, v.initial) {
                (Causality::Input, Some(_)) => e.push(format!("{n}: an input has no initial")),
                (Causality::Input, None) if !has_start => {
                    e.push(format!("{n}: an input needs a start value"))
                }
                (_, Some(Initial::Calculated)) if has_start => {
                    e.push(format!("{n}: initial=calculated forbids a start value"))
                }
                (_, Some(Initial::Exact | Initial::Approx)) if !has_start => {
                    e.push(format!("{n}: initial exact/approx needs a start value"))
                }
                _ => {}
            }
            if v.causality == Causality::Parameter
                && !matches!(v.variability, Variability::Fixed | Variability::Tunable)
            {
                e.push(format!("{n}: a parameter is fixed or tunable"));
            }
            if v.ty != VarType::Real && v.variability == Variability::Continuous {
                e.push(format!("{n}: only Reals may be continuous"));
            }
            if let Some(u) = &v.unit {
                if crate::units::base_units(u).is_none() {
                    e.push(format!("{n}: unknown unit {u}"));
                }
                if v.ty != VarType::Real {
                    e.push(format!("{n}: only Reals carry a unit"));
                }
            }
            let start_ok = matches!(
                (&v.start, v.ty),
                (None, _)
                    | (Some(Start::Real(_)), VarType::Real)
                    | (Some(Start::Integer(_)), VarType::Integer)
                    | (Some(Start::Boolean(_)), VarType::Boolean)
                    | (Some(Start::String(_)), VarType::String)
            );
            if !start_ok {
                e.push(format!("{n}: start value of the wrong type"));
            }
            if let Some(Start::Real(x)) = v.start
                && !x.is_finite()
            {
                e.push(format!("{n}: start value {x} is not finite"));
            }
            if v.causality != Causality::Output && v.dependencies != Dependencies::None {
                e.push(format!("{n}: only outputs have dependencies"));
            }
            let input = |name: &str| {
                names
                    .iter()
                    .find(|(m, _, c)| m == name && *c == Causality::Input)
            };
            match &v.dependencies {
                Dependencies::None => {}
                Dependencies::Elementwise(d) => match input(d) {
                    Some((_, len, _)) if *len == v.len => {}
                    _ => e.push(format!(
                        "{n}: elementwise dependency on {d}, not an input of the same length"
                    )),
                },
                Dependencies::All(ds) => {
                    for d in ds {
                        if input(d).is_none() {
                            e.push(format!("{n}: depends on {d}, which is not an input"));
                        }
                    }
                }
            }
        }
        if self.errors.is_empty() {
            Ok(VariableTable {
                vars: self.vars,
                counts,
                bases,
            })
        } else {
            Err(FmuError::Table(self.errors.join("; ")))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Disjoint variables come back as their own slices, in the order asked; the same one twice,
    /// or two that overlap, give None.
    #[test]
    fn reals_mut_gives_disjoint_variables_only() {
        let mut v = Values {
            reals: (0..10).map(f64::from).collect(),
            ..Values::default()
        };
        let (a, b, c) = (
            RealVar { slot: 0, len: 3 },
            RealVar { slot: 3, len: 4 },
            RealVar { slot: 7, len: 3 },
        );
        let [x, y, z] = v.reals_mut([c, a, b]).unwrap();
        assert_eq!((x[0], y[0], z[3]), (7.0, 0.0, 6.0));
        z[0] = -1.0;
        assert_eq!(v.real(b)[0], -1.0);
        assert!(v.reals_mut([a, a]).is_none());
        assert!(v.reals_mut([b, RealVar { slot: 6, len: 2 }]).is_none());
    }

    fn table() -> (VariableTable, RealVar, RealVar, IntVar) {
        let mut b = TableBuilder::new();
        let m = b.add_real(
            TableBuilder::real("mass")
                .parameter()
                .unit("kg")
                .start(2.0)
                .positive(),
        );
        let u = b.add_real(TableBuilder::real("u").input().len(3).unit("m").start(0.0));
        let n = b.add_integer(TableBuilder::integer("n").structural().start_int(3));
        let _y = b.add_real(
            TableBuilder::real("y")
                .output()
                .len(3)
                .unit("m")
                .depends(Dependencies::Elementwise("u".into())),
        );
        (b.build().expect("valid table"), m, u, n)
    }

    #[test]
    fn value_references_are_contiguous_and_unique() {
        let (t, m, u, n) = table();
        assert_eq!(t.counts(), [7, 1, 0, 0]);
        assert_eq!((m.slot, u.slot, u.len, n.slot), (0, 1, 3, 0));
        let y = t.by_name("y").expect("y");
        assert_eq!((y.vr, y.len), (4, 3));
        assert_eq!(t.by_name("n").expect("n").vr, 7);
        assert_eq!(
            t.lookup(5).map(|(v, i)| (v.name.as_str(), i)),
            Some(("y", 1))
        );
        assert!(t.lookup(8).is_none());
    }

    #[test]
    fn start_values_fill_the_store() {
        let (t, m, u, n) = table();
        let v = t.initial_values();
        assert_eq!(v.scalar(m), 2.0);
        assert_eq!(v.real(u), &[0.0; 3]);
        assert_eq!(v.integer(n), 3);
    }

    #[test]
    fn checks_name_the_variable() {
        let (t, ..) = table();
        let mass = t.by_name("mass").expect("mass");
        let e = t.check_real(mass, 0, -1.0).expect_err("negative mass");
        assert!(e.to_string().contains("mass"), "{e}");
        assert!(t.check_real(mass, 0, f64::NAN).is_err());
        let n = t.by_name("n").expect("n");
        let e = t.check_integer(n, 0, 36).expect_err("size");
        assert!(e.to_string().contains("packaged value 3"), "{e}");
    }

    #[test]
    fn fmi_rules_are_enforced() {
        let mut b = TableBuilder::new();
        b.add_real(TableBuilder::real("x").input());
        b.add_real(TableBuilder::real("y").output().start(1.0));
        b.add_real(TableBuilder::real("p").parameter());
        b.add_real(
            TableBuilder::real("q")
                .parameter()
                .start(1.0)
                .unit("furlong"),
        );
        let e = b.build().expect_err("invalid").to_string();
        for what in [
            "x: an input needs",
            "y: initial=calculated",
            "p: initial exact",
            "unknown unit furlong",
        ] {
            assert!(e.contains(what), "{what} missing from {e}");
        }
    }
}
