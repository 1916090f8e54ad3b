//! The connection checks and the layout of the shared output buffer. Every connection is
//! checked against the components' model descriptions (names, sizes, causality, type, units,
//! one source per input) and becomes, per scalar, an input fed from a slot of its source's
//! outputs; every recorded signal gets a slot too. A component's slots are its connected or
//! recorded outputs, each once, in the order first needed; the buffer holds them component
//! after component.

use std::collections::HashMap;

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

/// Checks one scalar of a connection, `o` of `conn.from` into `i` of `conn.to`: an output into
/// an input, both Real, and the same unit when both declare one. `what` names the connection.
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
    if o.var_type != VarType::Real || i.var_type != VarType::Real {
        return Err(mismatch(format!(
            "{} is {:?} and {} is {:?}; only Real signals are connected",
            o.name, o.var_type, i.name, i.var_type
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

/// Where every connected input comes from and which outputs each component publishes.
pub(super) struct Wiring {
    /// Per component, the value references of its connected or recorded outputs, in slot
    /// order.
    pub(super) out_vars: Vec<Vec<u32>>,
    /// Per component, the local slot of each of those value references.
    slot_of: Vec<HashMap<u32, usize>>,
    /// Per component, its connected inputs: (value reference, source component, local slot of
    /// the source's output).
    pub(super) in_conn: Vec<Vec<(u32, usize, usize)>>,
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
            out_vars: vec![Vec::new(); n],
            slot_of: vec![HashMap::new(); n],
            in_conn: vec![Vec::new(); n],
        };
        for conn in &system.connections {
            w.add_connection(system, fmus, fmu_of, conn)?;
        }
        Ok(w)
    }

    /// The local slot of output `vr` of component `c`, added if new.
    fn add_output(&mut self, c: usize, vr: u32) -> usize {
        let m = &mut self.slot_of[c];
        let len = m.len();
        *m.entry(vr).or_insert_with(|| {
            self.out_vars[c].push(vr);
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
            if self.in_conn[b].iter().any(|x| x.0 == i.value_reference) {
                return Err(CosimError::Mismatch {
                    what,
                    reason: format!("{} is already connected", i.name),
                });
            }
            let slot = self.add_output(a, o.value_reference);
            self.in_conn[b].push((i.value_reference, a, slot));
        }
        Ok(())
    }

    /// Slots for the signals to record ("component.signal" each, Real only): per scalar its
    /// column name, component and local slot.
    ///
    /// # Errors
    /// A malformed name, an unknown component or signal, or a signal that is not Real.
    pub(super) fn record(
        &mut self,
        system: &System,
        fmus: &[Fmu],
        fmu_of: &[usize],
        record: &[String],
    ) -> Result<Vec<(String, usize, usize)>> {
        let mut rec_local: Vec<(String, usize, usize)> = Vec::new(); // (column, comp, local slot)
        for r in record {
            let (cname, sig) = r.split_once('.').ok_or_else(|| {
                CosimError::Invalid(format!("record {r:?}: expected component.signal"))
            })?;
            let c = index_of(system, cname)?;
            let vars = signal_of(&fmus[fmu_of[c]], cname, sig)?;
            for v in vars {
                if v.var_type != VarType::Real {
                    return Err(CosimError::Invalid(format!(
                        "record {cname}.{}: only Real variables are recorded",
                        v.name
                    )));
                }
                let slot = self.add_output(c, v.value_reference);
                rec_local.push((format!("{cname}.{}", v.name), c, slot));
            }
        }
        Ok(rec_local)
    }

    /// Global slot offsets: component `c`'s outputs are `offset[c]..offset[c + 1]` of the
    /// shared buffer, which holds `offset[n]`.
    pub(super) fn offsets(&self) -> Vec<usize> {
        let n = self.out_vars.len();
        let mut offset = vec![0usize; n + 1];
        for c in 0..n {
            offset[c + 1] = offset[c] + self.out_vars[c].len();
        }
        offset
    }

    /// Per component, the components it reads from (sorted, without duplicates).
    pub(super) fn sources(&self) -> Vec<Vec<usize>> {
        self.in_conn
            .iter()
            .map(|v| {
                let mut s: Vec<usize> = v.iter().map(|x| x.1).collect();
                s.sort_unstable();
                s.dedup();
                s
            })
            .collect()
    }
}
