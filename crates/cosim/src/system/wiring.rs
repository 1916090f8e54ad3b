//! The connection checks and the layout of the shared output buffer. Every connection is
//! checked against the components' model descriptions (names, sizes, causality, type, units,
//! one source per input) and becomes, per scalar, an input fed from a slot of its source's
//! outputs; every recorded signal gets a slot too. A component's slots are its connected or
//! recorded outputs, each once, in the order first needed; the buffer holds them component
//! after component.

use std::collections::{HashMap, HashSet};

use wildmatch::WildMatch;

use super::definition::{Connection, System};
use crate::description::{Causality, ScalarVariable, VarType};
use crate::error::{CosimError, Result};
use crate::fmu::Fmu;

/// Index of the component called `name`.
pub(super) fn index_of(system: &System, name: &str) -> Result<usize> {
    system
        .components
        .iter()
        .position(|c| c.name == name)
        .ok_or_else(|| CosimError::Invalid(format!("no component named {name}")))
}

/// The variable of `comp` called `name`.
pub(super) fn var_of<'a>(fmu: &'a Fmu, comp: &str, name: &str) -> Result<&'a ScalarVariable> {
    fmu.description
        .variable_by_name(name)
        .ok_or_else(|| CosimError::UnknownVariable {
            component: comp.into(),
            name: name.into(),
        })
}

/// The scalars of signal `name` of `comp` (a scalar, or an array by its base name).
fn signal_of<'a>(fmu: &'a Fmu, comp: &str, name: &str) -> Result<Vec<&'a ScalarVariable>> {
    fmu.description
        .signal(name)
        .ok_or_else(|| CosimError::UnknownVariable {
            component: comp.into(),
            name: name.into(),
        })
}

/// The declared unit of a variable, if it declares one (an empty unit declares none).
fn unit_of(v: &ScalarVariable) -> Option<&str> {
    v.unit.as_deref().filter(|u| !u.is_empty())
}

/// The four kinds of value the master moves, each through a shared buffer of its own (an
/// enumeration moves as an Integer).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) enum Kind {
    Real = 0,
    Integer = 1,
    Boolean = 2,
    String = 3,
}

impl Kind {
    /// Every kind, in buffer order.
    pub(super) const ALL: [Kind; 4] = [Kind::Real, Kind::Integer, Kind::Boolean, Kind::String];

    /// The kind a variable of type `t` moves as.
    pub(super) fn of(t: VarType) -> Self {
        match t {
            VarType::Real => Kind::Real,
            VarType::Integer | VarType::Enumeration => Kind::Integer,
            VarType::Boolean => Kind::Boolean,
            VarType::String => Kind::String,
        }
    }
}

/// Checks one scalar of a connection, `o` of `conn.from` into `i` of `conn.to`: an output into
/// an input, of one type (Real, Integer or enumeration, Boolean, String), and the same unit
/// when both declare one. `what` names the connection.
fn check_pair(what: &str, conn: &Connection, o: &ScalarVariable, i: &ScalarVariable) -> Result<()> {
    let mismatch = |reason: String| CosimError::Mismatch {
        what: what.into(),
        reason,
    };
    if o.causality != Causality::Output {
        return Err(mismatch(format!(
            "{} is not an output ({:?})",
            o.name, o.causality
        )));
    }
    if i.causality != Causality::Input {
        return Err(mismatch(format!(
            "{} is not an input ({:?})",
            i.name, i.causality
        )));
    }
    if Kind::of(o.var_type) != Kind::of(i.var_type) {
        return Err(mismatch(format!(
            "{}.{} is {:?} and {}.{} is {:?}; a connection joins two variables of one type",
            conn.from, o.name, o.var_type, conn.to, i.name, i.var_type
        )));
    }
    if let (Some(uo), Some(ui)) = (unit_of(o), unit_of(i))
        && uo != ui
    {
        return Err(mismatch(format!(
            "units differ: {}.{} is in {uo:?} but {}.{} is in {ui:?}",
            conn.from, o.name, conn.to, i.name
        )));
    }
    Ok(())
}

/// Where every connected input comes from and which outputs each component publishes, per
/// kind of value ([`Kind`] as the index of the outer arrays).
pub(super) struct Wiring {
    /// Per kind and component, the value references of its connected or recorded outputs, in
    /// slot order.
    pub(super) out_vars: [Vec<Vec<u32>>; 4],
    /// Per kind and component, the local slot of each of those value references.
    slot_of: [Vec<HashMap<u32, usize>>; 4],
    /// Per kind and component, its connected inputs: (value reference, source component, local
    /// slot of the source's output).
    pub(super) in_conn: [Vec<Vec<(u32, usize, usize)>>; 4],
    /// Per kind and component, the value references of its connected inputs (to refuse a
    /// second connection into one in constant time: the TMT mirror has 2952 of them).
    connected: [Vec<HashSet<u32>>; 4],
    /// Every scalar connection: (source component, its output's value reference, destination
    /// component, its input's value reference, kind), in the order connected (initialisation
    /// walks these).
    pub(super) scalars: Vec<(usize, u32, usize, u32, Kind)>,
}

impl Wiring {
    /// Checks every connection of `system` (components' FMUs `fmus[fmu_of[c]]`) in order and
    /// lays out the slots they need.
    ///
    /// # Errors
    /// The first connection at fault, named, with the reason.
    pub(super) fn connect(system: &System, fmus: &[Fmu], fmu_of: &[usize]) -> Result<Self> {
        let n = system.components.len();
        let mut w = Self {
            out_vars: std::array::from_fn(|_| vec![Vec::new(); n]),
            slot_of: std::array::from_fn(|_| vec![HashMap::new(); n]),
            in_conn: std::array::from_fn(|_| vec![Vec::new(); n]),
            connected: std::array::from_fn(|_| vec![HashSet::new(); n]),
            scalars: Vec::new(),
        };
        for conn in &system.connections {
            w.add_connection(system, fmus, fmu_of, conn)?;
        }
        Ok(w)
    }

    /// The local slot of output `vr` (of kind `k`) of component `c`, added if new.
    fn add_output(&mut self, k: Kind, c: usize, vr: u32) -> usize {
        let m = &mut self.slot_of[k as usize][c];
        let len = m.len();
        *m.entry(vr).or_insert_with(|| {
            self.out_vars[k as usize][c].push(vr);
            len
        })
    }

    fn add_connection(
        &mut self,
        system: &System,
        fmus: &[Fmu],
        fmu_of: &[usize],
        conn: &Connection,
    ) -> Result<()> {
        let what = format!(
            "{}.{} -> {}.{}",
            conn.from, conn.output, conn.to, conn.input
        );
        let (a, b) = (index_of(system, &conn.from)?, index_of(system, &conn.to)?);
        let (fa, fb) = (&fmus[fmu_of[a]], &fmus[fmu_of[b]]);
        let outs = signal_of(fa, &conn.from, &conn.output)?;
        let ins = signal_of(fb, &conn.to, &conn.input)?;
        if outs.len() != ins.len() {
            return Err(CosimError::Mismatch {
                what,
                reason: format!("{} values into {}", outs.len(), ins.len()),
            });
        }
        for (o, i) in outs.iter().zip(&ins) {
            check_pair(&what, conn, o, i)?;
            let k = Kind::of(i.var_type);
            if !self.connected[k as usize][b].insert(i.value_reference) {
                return Err(CosimError::Mismatch {
                    what,
                    reason: format!("{} is already connected", i.name),
                });
            }
            let slot = self.add_output(k, a, o.value_reference);
            self.in_conn[k as usize][b].push((i.value_reference, a, slot));
            self.scalars
                .push((a, o.value_reference, b, i.value_reference, k));
        }
        Ok(())
    }

    /// Slots for the signals to record, per scalar its column name, component, kind and local
    /// slot, each scalar once in the order first named. Each entry of `record` is
    /// `component.signal`: a scalar, or an array by its base name (`mirror.z`); or a pattern
    /// where `*` stands for any run of characters and `?` for one, in the component, the
    /// variable or both (`mirror.z[*]`, `*.rms_surface`, `optics.*`), matched against every
    /// output. Real, Integer, enumeration and Boolean values are recorded (as numbers; a
    /// Boolean as 0 or 1).
    ///
    /// # Errors
    /// A malformed entry, an unknown component or signal, a pattern that matches no output, or
    /// a String variable named.
    pub(super) fn record(
        &mut self,
        system: &System,
        fmus: &[Fmu],
        fmu_of: &[usize],
        record: &[String],
    ) -> Result<Vec<Recording>> {
        let mut out: Vec<Recording> = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for r in record {
            let (cname, sig) = r.split_once('.').ok_or_else(|| {
                CosimError::Invalid(format!(
                    "record {r:?}: expected component.signal (a pattern may use * and ?)"
                ))
            })?;
            let mut picked: Vec<(usize, &ScalarVariable)> = Vec::new();
            if r.contains(['*', '?']) {
                let (cpat, vpat) = (WildMatch::new(cname), WildMatch::new(sig));
                for (c, comp) in system.components.iter().enumerate() {
                    if !cpat.matches(&comp.name) {
                        continue;
                    }
                    let md = &fmus[fmu_of[c]].description;
                    // A pattern leaves String outputs out (a name asks for one and is refused).
                    picked.extend(
                        md.variables
                            .iter()
                            .filter(|v| {
                                v.causality == Causality::Output
                                    && v.var_type != VarType::String
                                    && vpat.matches(&v.name)
                            })
                            .map(|v| (c, v)),
                    );
                }
                if picked.is_empty() {
                    return Err(CosimError::Invalid(format!(
                        "record {r:?}: the pattern matches no output of any component"
                    )));
                }
            } else {
                let c = index_of(system, cname)?;
                picked.extend(
                    signal_of(&fmus[fmu_of[c]], cname, sig)?
                        .into_iter()
                        .map(|v| (c, v)),
                );
            }
            for (c, v) in picked {
                let column = format!("{}.{}", system.components[c].name, v.name);
                if v.var_type == VarType::String {
                    return Err(CosimError::Invalid(format!(
                        "record {column}: a String is not recorded (columns hold numbers)"
                    )));
                }
                if !seen.insert(column.clone()) {
                    continue;
                }
                let kind = Kind::of(v.var_type);
                let slot = self.add_output(kind, c, v.value_reference);
                out.push(Recording {
                    column,
                    component: c,
                    kind,
                    slot,
                });
            }
        }
        Ok(out)
    }

    /// Global slot offsets of kind `k`: component `c`'s outputs are `offset[c]..offset[c + 1]`
    /// of that kind's shared buffer, which holds `offset[n]`.
    pub(super) fn offsets(&self, k: Kind) -> Vec<usize> {
        let vars = &self.out_vars[k as usize];
        let n = vars.len();
        let mut offset = vec![0usize; n + 1];
        for c in 0..n {
            offset[c + 1] = offset[c] + vars[c].len();
        }
        offset
    }

    /// Per component, the components it reads from, values of any kind (sorted, without
    /// duplicates).
    pub(super) fn sources(&self) -> Vec<Vec<usize>> {
        let n = self.in_conn[0].len();
        (0..n)
            .map(|c| {
                let mut s: Vec<usize> = self
                    .in_conn
                    .iter()
                    .flat_map(|k| k[c].iter().map(|x| x.1))
                    .collect();
                s.sort_unstable();
                s.dedup();
                s
            })
            .collect()
    }
}

/// Whether the record entry `entry` (a `component.signal` name or a pattern, as
/// [`super::Simulation::new`] takes them) selects the recorded column `column`
/// (`component.variable`): the scalar itself, an element of the array named by its base name,
/// or a match of the pattern (component and variable matched apart, at the first dot).
pub fn record_selects(entry: &str, column: &str) -> bool {
    let (Some((ec, ev)), Some((cc, cv))) = (entry.split_once('.'), column.split_once('.')) else {
        return false;
    };
    if entry.contains(['*', '?']) {
        return WildMatch::new(ec).matches(cc) && WildMatch::new(ev).matches(cv);
    }
    ec == cc
        && (ev == cv
            || cv
                .strip_prefix(ev)
                .and_then(|r| r.strip_prefix('['))
                .and_then(|r| r.strip_suffix(']'))
                .is_some_and(|i| !i.is_empty() && i.bytes().all(|b| b.is_ascii_digit())))
}

/// A recorded scalar: its column name (`"comp.z[1]"`), component, kind and local slot.
pub(super) struct Recording {
    pub(super) column: String,
    pub(super) component: usize,
    pub(super) kind: Kind,
    pub(super) slot: usize,
}

#[cfg(test)]
mod tests {
    use super::record_selects;

    #[test]
    fn record_entries_select_their_columns() {
        assert!(record_selects("mirror.z", "mirror.z[12]"));
        assert!(record_selects("mirror.z", "mirror.z"));
        assert!(!record_selects("mirror.z", "mirror.z_cell[1]"));
        assert!(!record_selects("mirror.z", "mirror.zz"));
        assert!(record_selects("mirror.z[*]", "mirror.z[3]"));
        assert!(!record_selects("mirror.z[*]", "mirror.z_cell[3]"));
        assert!(record_selects("*.rms_surface", "optics.rms_surface"));
        assert!(!record_selects(
            "*.rms_surface",
            "optics.rms_surface_without_focus"
        ));
        assert!(record_selects("opt?cs.*", "optics.pssn"));
        assert!(!record_selects("optics.*", "mirror.z[1]"));
    }
}
