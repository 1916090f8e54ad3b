//! Initialisation through direct feedthrough: with every component in initialisation mode
//! (parameters and start values set), the master reads the outputs that feed an input on which
//! some output depends directly (the dependencies of ModelStructure/Outputs; an output without
//! a `dependencies` attribute depends on every input), in topological order, and sets those
//! inputs, before the components leave initialisation mode. So an output that passes an input
//! straight through (A -> B -> C) shows the propagated value at the start time, not its start
//! value. The outputs a chain needs are read component by component, level by level: at each
//! level every component with outputs whose inputs are all set gets its pending inputs set in
//! one call per kind, then those outputs are read one by one.
//!
//! Only what a direct dependency needs is evaluated here: inputs on which no output depends
//! directly receive their sources' initial outputs before the first step, as every input does
//! at every step (so a component whose outputs are not needed is built once, when it leaves
//! initialisation mode). A cycle of direct dependencies is an algebraic loop, which the master
//! does not solve: it is an error naming the connections around it.

use std::collections::HashMap;

use super::definition::System;
use super::step::Running;
use super::wiring::{Kind, Wiring};
use crate::description::{Causality, ModelDescription};
use crate::error::{CosimError, Result};
use crate::fmu::Fmu;

/// A scalar of one component: (component, kind, value reference).
type Scalar = (usize, Kind, u32);

/// Per output (kind, value reference), the inputs (kind, value reference) it depends on
/// directly (`None`: every input).
type Dependencies = HashMap<(Kind, u32), Option<Vec<(Kind, u32)>>>;

/// A value read in initialisation mode.
#[derive(Debug, Clone)]
enum Val {
    Real(f64),
    Integer(i32),
    Boolean(bool),
    String(String),
}

/// Per output (kind, value reference) of `md`, the inputs (kind, value reference) it depends on
/// directly; `None` for every input (no `dependencies` attribute, or not listed).
fn dependencies(md: &ModelDescription) -> Dependencies {
    let key = |i: usize| {
        let v = &md.variables[i];
        (Kind::of(v.var_type), v.value_reference)
    };
    md.outputs
        .iter()
        .filter(|u| u.variable < md.variables.len())
        .map(|u| {
            let deps = u.dependencies.as_ref().map(|d| {
                d.iter()
                    .filter(|&&i| {
                        md.variables
                            .get(i)
                            .is_some_and(|v| v.causality == Causality::Input)
                    })
                    .map(|&i| key(i))
                    .collect()
            });
            (key(u.variable), deps)
        })
        .collect()
}

/// The name of scalar `(c, kind, vr)` as `component.variable`.
fn name_of(system: &System, fmus: &[Fmu], fmu_of: &[usize], s: Scalar) -> String {
    let (c, k, vr) = s;
    let md = &fmus[fmu_of[c]].description;
    let v = md
        .variables
        .iter()
        .find(|v| v.value_reference == vr && Kind::of(v.var_type) == k)
        .map_or_else(|| format!("vr {vr}"), |v| v.name.clone());
    format!("{}.{v}", system.components[c].name)
}

/// Propagates values through the direct-feedthrough chains of `system` while its components
/// (`comps`, in initialisation mode) have not yet left it (module docs).
///
/// # Errors
/// An algebraic loop (named), or a component's error on a get or set.
pub(super) fn propagate(
    system: &System,
    fmus: &[Fmu],
    fmu_of: &[usize],
    wiring: &Wiring,
    comps: &mut [Running],
) -> Result<()> {
    let n = comps.len();
    let deps: Vec<_> = (0..n)
        .map(|c| dependencies(&fmus[fmu_of[c]].description))
        .collect();
    // The source of every connected input.
    let mut source: HashMap<Scalar, Scalar> = HashMap::new();
    let mut inputs_of: Vec<Vec<(Kind, u32)>> = vec![Vec::new(); n];
    for &(a, o, b, i, k) in &wiring.scalars {
        source.insert((b, k, i), (a, k, o));
        inputs_of[b].push((k, i));
    }
    // The connected inputs an output of component c depends on directly.
    let direct = |c: usize, k: Kind, vr: u32| -> Vec<(Kind, u32)> {
        match deps[c].get(&(k, vr)) {
            Some(Some(d)) => d
                .iter()
                .copied()
                .filter(|&(dk, dvr)| source.contains_key(&(c, dk, dvr)))
                .collect(),
            _ => inputs_of[c].clone(),
        }
    };
    // Feedthrough inputs: the connected inputs some published output depends on directly.
    let mut feed: Vec<Scalar> = Vec::new();
    for (c, r) in comps.iter().enumerate() {
        for k in Kind::ALL {
            for &vr in out_vrs(r, k) {
                for (dk, dvr) in direct(c, k, vr) {
                    feed.push((c, dk, dvr));
                }
            }
        }
    }
    feed.sort_unstable_by_key(|s| (s.0, s.1 as u8, s.2));
    feed.dedup();
    if feed.is_empty() {
        return Ok(());
    }
    // The outputs to read: the sources of those inputs, and what they depend on, recursively.
    let mut needed: Vec<Scalar> = Vec::new();
    let mut index: HashMap<Scalar, usize> = HashMap::new();
    let mut preds: Vec<Vec<usize>> = Vec::new();
    let mut stack: Vec<Scalar> = feed.iter().map(|i| source[i]).collect();
    while let Some(o) = stack.pop() {
        if index.contains_key(&o) {
            continue;
        }
        index.insert(o, needed.len());
        needed.push(o);
        preds.push(Vec::new());
        for (dk, dvr) in direct(o.0, o.1, o.2) {
            stack.push(source[&(o.0, dk, dvr)]);
        }
    }
    for (j, &o) in needed.iter().enumerate() {
        preds[j] = direct(o.0, o.1, o.2)
            .into_iter()
            .map(|(dk, dvr)| index[&source[&(o.0, dk, dvr)]])
            .collect();
    }
    // Level by level (Kahn).
    let mut value: Vec<Option<Val>> = vec![None; needed.len()];
    let mut set_done: std::collections::HashSet<Scalar> = std::collections::HashSet::new();
    loop {
        let ready: Vec<usize> = (0..needed.len())
            .filter(|&j| value[j].is_none() && preds[j].iter().all(|&p| value[p].is_some()))
            .collect();
        if ready.is_empty() {
            break;
        }
        for (c, r) in comps.iter_mut().enumerate() {
            let mine: Vec<usize> = ready
                .iter()
                .copied()
                .filter(|&j| needed[j].0 == c)
                .collect();
            if mine.is_empty() {
                continue;
            }
            set_inputs(c, &feed, &source, &index, &value, &mut set_done, r)?;
            for j in mine {
                let (_, k, vr) = needed[j];
                value[j] = Some(get_one(r, k, vr)?);
            }
        }
    }
    if let Some(j) = (0..needed.len()).find(|&j| value[j].is_none()) {
        return Err(algebraic_loop(
            system, fmus, fmu_of, &needed, &preds, &value, j,
        ));
    }
    for (c, r) in comps.iter_mut().enumerate() {
        set_inputs(c, &feed, &source, &index, &value, &mut set_done, r)?;
    }
    Ok(())
}

/// The value references of `r`'s published outputs of kind `k`.
fn out_vrs(r: &Running, k: Kind) -> &[u32] {
    match k {
        Kind::Real => &r.ports.real.out_vrs,
        Kind::Integer => &r.ports.integer.out_vrs,
        Kind::Boolean => &r.ports.boolean.out_vrs,
        Kind::String => &r.ports.string.out_vrs,
    }
}

/// Sets the feedthrough inputs of component `c` whose sources have been read and that are not
/// set yet: one call per kind.
fn set_inputs(
    c: usize,
    feed: &[Scalar],
    source: &HashMap<Scalar, Scalar>,
    index: &HashMap<Scalar, usize>,
    value: &[Option<Val>],
    set_done: &mut std::collections::HashSet<Scalar>,
    r: &mut Running,
) -> Result<()> {
    let mut reals = (Vec::new(), Vec::new());
    let mut ints = (Vec::new(), Vec::new());
    let mut bools = (Vec::new(), Vec::new());
    let mut strs: (Vec<u32>, Vec<String>) = (Vec::new(), Vec::new());
    for &i in feed.iter().filter(|i| i.0 == c) {
        if set_done.contains(&i) {
            continue;
        }
        let Some(v) = index.get(&source[&i]).and_then(|&j| value[j].clone()) else {
            continue;
        };
        set_done.insert(i);
        match v {
            Val::Real(x) => (reals.0.push(i.2), reals.1.push(x)),
            Val::Integer(x) => (ints.0.push(i.2), ints.1.push(x)),
            Val::Boolean(x) => (bools.0.push(i.2), bools.1.push(x)),
            Val::String(x) => (strs.0.push(i.2), strs.1.push(x)),
        };
    }
    let inst = &mut r.instance;
    if !reals.0.is_empty() {
        inst.set_real(&reals.0, &reals.1)?;
    }
    if !ints.0.is_empty() {
        inst.set_integer(&ints.0, &ints.1)?;
    }
    if !bools.0.is_empty() {
        inst.set_boolean(&bools.0, &bools.1)?;
    }
    if !strs.0.is_empty() {
        let v: Vec<&str> = strs.1.iter().map(String::as_str).collect();
        inst.set_string(&strs.0, &v)?;
    }
    Ok(())
}

/// Reads one output in initialisation mode.
fn get_one(r: &mut Running, k: Kind, vr: u32) -> Result<Val> {
    let inst = &mut r.instance;
    Ok(match k {
        Kind::Real => {
            let mut x = [0.0];
            inst.get_real(&[vr], &mut x)?;
            Val::Real(x[0])
        }
        Kind::Integer => {
            let mut x = [0];
            inst.get_integer(&[vr], &mut x)?;
            Val::Integer(x[0])
        }
        Kind::Boolean => {
            let mut x = [false];
            inst.get_boolean(&[vr], &mut x)?;
            Val::Boolean(x[0])
        }
        Kind::String => Val::String(inst.get_string(&[vr])?.pop().unwrap_or_default()),
    })
}

/// The error for an algebraic loop through unread output `start`: the cycle it sits on (or
/// leads to), as its outputs in feeding order (`a.y -> b.y -> a.y`).
fn algebraic_loop(
    system: &System,
    fmus: &[Fmu],
    fmu_of: &[usize],
    needed: &[Scalar],
    preds: &[Vec<usize>],
    value: &[Option<Val>],
    start: usize,
) -> CosimError {
    // Walk back through unread predecessors until a node repeats: that is the cycle.
    let mut path = vec![start];
    let mut at = start;
    let cycle = loop {
        let Some(&p) = preds[at].iter().find(|&&p| value[p].is_none()) else {
            break vec![at];
        };
        if let Some(pos) = path.iter().position(|&x| x == p) {
            let mut c: Vec<usize> = path[pos..].to_vec();
            c.reverse();
            break c;
        }
        path.push(p);
        at = p;
    };
    let names: Vec<String> = cycle
        .iter()
        .map(|&j| name_of(system, fmus, fmu_of, needed[j]))
        .collect();
    let mut text = names.join(" -> ");
    if let Some(first) = names.first() {
        text.push_str(&format!(" -> {first}"));
    }
    CosimError::Invalid(format!(
        "algebraic loop at initialisation: {text} (each output depends directly on an input \
         fed by the one before, by the FMUs' ModelStructure); the master does not solve \
         algebraic loops: break one with a component that has no direct feedthrough"
    ))
}
