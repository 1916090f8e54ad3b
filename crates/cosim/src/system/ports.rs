//! The values that move between components: one shared buffer per kind of value ([`Values`]:
//! Real, Integer (and enumeration), Boolean, String), and per component and kind a [`Port`]
//! that gathers its connected inputs out of the buffer and publishes its outputs into it, with
//! one bulk FMI call per kind and step and no allocation (Strings excepted: they are copied).
//! Real inputs connected as a few arrays are set straight from the buffer instead, one call
//! per array, when the component steps on the master's thread ([`Port::direct`]): the copy
//! into the port is the larger cost there (a TMT mirror's 2953 inputs).

use super::wiring::Kind;
use crate::error::Result;
use crate::instance::Instance;

/// The latest published outputs of every component, one buffer per kind, each laid out
/// component after component (`wiring.rs`).
#[derive(Debug, Clone, Default)]
pub(super) struct Values {
    pub(super) real: Vec<f64>,
    pub(super) integer: Vec<i32>,
    pub(super) boolean: Vec<bool>,
    pub(super) string: Vec<String>,
}

impl Values {
    /// Buffers of the given lengths (per [`Kind`]), zeroed.
    pub(super) fn zeroed(len: [usize; 4]) -> Self {
        Self {
            real: vec![0.0; len[Kind::Real as usize]],
            integer: vec![0; len[Kind::Integer as usize]],
            boolean: vec![false; len[Kind::Boolean as usize]],
            string: vec![String::new(); len[Kind::String as usize]],
        }
    }

    /// Copies `other` (of the same lengths) into these buffers without allocating (Strings
    /// reuse their capacity).
    pub(super) fn copy_from(&mut self, other: &Self) {
        self.real.copy_from_slice(&other.real);
        self.integer.copy_from_slice(&other.integer);
        self.boolean.copy_from_slice(&other.boolean);
        self.string.clone_from_slice(&other.string);
    }

    /// The value in slot `slot` of kind `kind` as a number (a Boolean as 0 or 1; a String has
    /// none: NaN).
    pub(super) fn number(&self, kind: Kind, slot: usize) -> f64 {
        match kind {
            Kind::Real => self.real[slot],
            Kind::Integer => f64::from(self.integer[slot]),
            Kind::Boolean => f64::from(u8::from(self.boolean[slot])),
            Kind::String => f64::NAN,
        }
    }
}

/// Most runs of consecutive input slots for which a port's Real inputs are set straight from
/// the shared buffer, a set call per run ([`Port::direct`]): a mirror's command, wind and pier
/// inputs are three runs, a scalar-wired component's inputs may be hundreds (there one copy
/// and one call is cheaper).
pub(super) const DIRECT_MAX_RUNS: usize = 8;

/// The values of one kind that a component exchanges: its connected inputs and where each
/// comes from in the shared buffer, and its outputs (connected or recorded) and where they go.
#[derive(Debug, Default)]
pub(super) struct Port<T> {
    /// Value references of its connected inputs and their values gathered for the next step.
    pub(super) in_vrs: Vec<u32>,
    pub(super) in_buf: Vec<T>,
    /// Where the inputs come from in the shared buffer, as runs of consecutive slots `(first
    /// source slot, first input, length)`: an array input connected to an array output is one
    /// copy instead of one per scalar.
    in_runs: Vec<(usize, usize, usize)>,
    /// Value references of its outputs, the first of their consecutive slots, and their latest
    /// values (published after its step, when they are due).
    pub(super) out_vrs: Vec<u32>,
    pub(super) out_slot: usize,
    pub(super) out_buf: Vec<T>,
}

impl<T: Clone + Default> Port<T> {
    /// A port for inputs `(value reference, global slot of the source)` and outputs `out_vrs`
    /// published from global slot `out_slot` on.
    pub(super) fn new(inputs: Vec<(u32, usize)>, out_vrs: Vec<u32>, out_slot: usize) -> Self {
        let (in_vrs, in_src): (Vec<u32>, Vec<usize>) = inputs.into_iter().unzip();
        let mut in_runs: Vec<(usize, usize, usize)> = Vec::new();
        for (k, &src) in in_src.iter().enumerate() {
            match in_runs.last_mut() {
                Some((s, d, n)) if *s + *n == src && *d + *n == k => *n += 1,
                _ => in_runs.push((src, k, 1)),
            }
        }
        Self {
            in_runs,
            in_buf: vec![T::default(); in_vrs.len()],
            in_vrs,
            out_buf: vec![T::default(); out_vrs.len()],
            out_vrs,
            out_slot,
        }
    }

    /// Copies its inputs out of the shared buffer `shared`.
    pub(super) fn gather(&mut self, shared: &[T]) {
        for &(src, dst, n) in &self.in_runs {
            self.in_buf[dst..dst + n].clone_from_slice(&shared[src..src + n]);
        }
    }

    /// Whether its inputs are set straight from the shared buffer, one set call per run of
    /// consecutive slots, instead of gathered into `in_buf` and set in one call: when they form
    /// at most [`DIRECT_MAX_RUNS`] runs (array connections), so that the copy saved is larger
    /// than the calls added.
    pub(super) fn direct(&self) -> bool {
        !self.in_runs.is_empty() && self.in_runs.len() <= DIRECT_MAX_RUNS
    }

    /// Copies its outputs into the shared buffer `shared`.
    pub(super) fn publish(&self, shared: &mut [T]) {
        let dst = &mut shared[self.out_slot..self.out_slot + self.out_buf.len()];
        dst.clone_from_slice(&self.out_buf);
    }
}

/// A component's ports, one per kind.
#[derive(Debug, Default)]
pub(super) struct Ports {
    pub(super) real: Port<f64>,
    pub(super) integer: Port<i32>,
    pub(super) boolean: Port<bool>,
    pub(super) string: Port<String>,
}

impl Ports {
    /// Gathers every kind's inputs out of `shared`.
    pub(super) fn gather(&mut self, shared: &Values) {
        self.real.gather(&shared.real);
        self.integer.gather(&shared.integer);
        self.boolean.gather(&shared.boolean);
        self.string.gather(&shared.string);
    }

    /// Publishes every kind's outputs into `shared`.
    pub(super) fn publish(&self, shared: &mut Values) {
        self.real.publish(&mut shared.real);
        self.integer.publish(&mut shared.integer);
        self.boolean.publish(&mut shared.boolean);
        self.string.publish(&mut shared.string);
    }

    /// Sets the gathered inputs on `inst`: one call per kind that has any.
    pub(super) fn set_inputs(&self, inst: &mut Instance) -> Result<()> {
        if !self.real.in_vrs.is_empty() {
            inst.set_real(&self.real.in_vrs, &self.real.in_buf)?;
        }
        self.set_other_inputs(inst)
    }

    /// Sets its inputs on `inst` from `shared` (every kind's connected inputs): the Real ones
    /// straight from the shared buffer, one call per run of consecutive slots, when the port
    /// allows it ([`Port::direct`]); otherwise (and for the other kinds) gathered first and set
    /// with one call per kind. The FMU receives the same values either way, Real first.
    pub(super) fn set_inputs_from(&mut self, shared: &Values, inst: &mut Instance) -> Result<()> {
        let real = &mut self.real;
        if real.direct() {
            for &(src, dst, n) in &real.in_runs {
                inst.set_real(&real.in_vrs[dst..dst + n], &shared.real[src..src + n])?;
            }
        } else if !real.in_vrs.is_empty() {
            real.gather(&shared.real);
            inst.set_real(&real.in_vrs, &real.in_buf)?;
        }
        self.integer.gather(&shared.integer);
        self.boolean.gather(&shared.boolean);
        self.string.gather(&shared.string);
        self.set_other_inputs(inst)
    }

    /// Sets the gathered Integer, Boolean and String inputs: one call per kind that has any.
    fn set_other_inputs(&self, inst: &mut Instance) -> Result<()> {
        if !self.integer.in_vrs.is_empty() {
            inst.set_integer(&self.integer.in_vrs, &self.integer.in_buf)?;
        }
        if !self.boolean.in_vrs.is_empty() {
            inst.set_boolean(&self.boolean.in_vrs, &self.boolean.in_buf)?;
        }
        if !self.string.in_vrs.is_empty() {
            let values: Vec<&str> = self.string.in_buf.iter().map(String::as_str).collect();
            inst.set_string(&self.string.in_vrs, &values)?;
        }
        Ok(())
    }

    /// Reads its outputs from `inst` into the output buffers: one call per kind that has any.
    pub(super) fn get_outputs(&mut self, inst: &mut Instance) -> Result<()> {
        if !self.real.out_vrs.is_empty() {
            inst.get_real(&self.real.out_vrs, &mut self.real.out_buf)?;
        }
        if !self.integer.out_vrs.is_empty() {
            inst.get_integer(&self.integer.out_vrs, &mut self.integer.out_buf)?;
        }
        if !self.boolean.out_vrs.is_empty() {
            inst.get_boolean(&self.boolean.out_vrs, &mut self.boolean.out_buf)?;
        }
        if !self.string.out_vrs.is_empty() {
            self.string.out_buf = inst.get_string(&self.string.out_vrs)?;
        }
        Ok(())
    }
}
