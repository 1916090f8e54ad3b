//! One FMU instance: the FMI 2.0 co-simulation state machine around a [`Model`], in safe Rust.
//!
//! Every method returns `Result`; the C shims in [`crate::ffi`] turn it into a status and a
//! logged message. A rejected call leaves the instance as it was.

use serde::{Deserialize, Serialize};
use std::ffi::{CStr, CString};

use fmi_sys::fmi2::{fmi2CallbackFunctions, fmi2Status};

use crate::calls::Call;
use crate::error::FmuError;
use crate::model::{Model, Running};
use crate::variables::{Causality, Values, VarType, Variability, Variable, VariableTable};

/// Tag at the start of every live instance, checked before any use of an instance pointer.
pub(crate) const MAGIC: u64 = 0x4d31_4353_464d_5532; // "M1CSFMU2"
/// Tag at the start of every serialised FMU state. Its digits change whenever a model's saved
/// state changes its layout (the format records no field names): a state from another layout is
/// then refused instead of misread. 03: the mirror's running state lost its displacement buffer
/// (and every change to the coupled solver's fields since 02). 04: the segments' running state
/// lost its two output buffers.
const STATE_MAGIC: &[u8; 8] = b"M1CSST04";

/// The FMI 2.0 co-simulation states.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum State {
    /// After fmi2Instantiate or fmi2Reset.
    Instantiated,
    /// Between fmi2EnterInitializationMode and fmi2ExitInitializationMode.
    InitializationMode,
    /// Ready for fmi2DoStep.
    StepComplete,
    /// A step failed; outputs may be read.
    StepFailed,
    /// After fmi2Terminate.
    Terminated,
    /// After fmi2Error: only reset, free, get and FMU-state calls.
    Error,
    /// After fmi2Fatal: only free.
    Fatal,
}

impl State {
    /// Name used in messages.
    pub fn name(self) -> &'static str {
        match self {
            State::Instantiated => "instantiated",
            State::InitializationMode => "initializationMode",
            State::StepComplete => "stepComplete",
            State::StepFailed => "stepFailed",
            State::Terminated => "terminated",
            State::Error => "error",
            State::Fatal => "fatal",
        }
    }
}

use State::*;

/// A saved FMU state (fmi2GetFMUstate), also the unit of serialisation.
#[derive(Clone, Serialize, Deserialize)]
#[serde(bound = "")]
pub struct Snapshot<M: Model> {
    pub(crate) magic: u64,
    guid: String,
    state: State,
    time: f64,
    start_time: f64,
    stop_time: Option<f64>,
    outputs_stale: bool,
    on_demand_stale: bool,
    values: Values,
    running: Option<M::Running>,
}

/// An instance of model `M`.
pub struct Instance<M: Model> {
    pub(crate) magic: u64,
    name: CString,
    callbacks: Option<fmi2CallbackFunctions>,
    logging_on: bool,
    log_calls: bool,
    state: State,
    guid: String,
    variant: String,
    table: VariableTable,
    pristine: Values,
    values: Values,
    /// The model as configured at instantiation.
    model: M,
    /// The initialised model, from fmi2ExitInitializationMode until fmi2Reset.
    running: Option<M::Running>,
    time: f64,
    start_time: f64,
    stop_time: Option<f64>,
    outputs_stale: bool,
    /// The running model's on-demand outputs ([`crate::Running::on_demand`]) were not written
    /// since its last step.
    on_demand_stale: bool,
}

fn resource_dir(location: &str) -> Option<std::path::PathBuf> {
    // file:///abs/path, file://localhost/abs/path, or file:/abs/path (some importers).
    let rest = location.strip_prefix("file:")?;
    let rest = rest
        .strip_prefix("//localhost")
        .or_else(|| rest.strip_prefix("//"))
        .unwrap_or(rest);
    Some(std::path::PathBuf::from(percent_decode(rest)))
}

fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'a'..=b'f' => Some(b - b'a' + 10),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

/// Decodes %XX escapes (two hex digits) byte by byte; anything else is kept as it is.
fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && let (Some(hi), Some(lo)) = (
                b.get(i + 1).copied().and_then(hex_digit),
                b.get(i + 2).copied().and_then(hex_digit),
            )
        {
            out.push(hi * 16 + lo);
            i += 3;
            continue;
        }
        out.push(b[i]);
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Name of the resource file that records which variant an archive was packaged for.
pub const VARIANT_FILE: &str = "variant.txt";

impl<M: Model> Instance<M> {
    /// fmi2Instantiate: finds the packaged variant whose description has this GUID.
    pub fn new(
        name: &str,
        guid: &str,
        resource_location: Option<&str>,
        callbacks: Option<fmi2CallbackFunctions>,
        logging_on: bool,
    ) -> Result<Self, FmuError> {
        let dir = resource_location.and_then(resource_dir);
        let from_resources = dir
            .as_ref()
            .and_then(|d| std::fs::read_to_string(d.join(VARIANT_FILE)).ok())
            .map(|s| s.trim().to_string());
        let candidates = match &from_resources {
            Some(v) => vec![v.clone()],
            None => M::variants(),
        };
        let mut expected = Vec::new();
        for variant in candidates {
            let (table, mut model) = M::new(&variant)?;
            let g = crate::xml::guid(&M::INFO, &table);
            if g == guid {
                if let Some(d) = &dir {
                    model.set_resource_dir(d);
                }
                let values = table.initial_values();
                return Ok(Self {
                    magic: MAGIC,
                    name: CString::new(name.replace('\0', " ")).unwrap_or_default(),
                    callbacks,
                    logging_on,
                    log_calls: false,
                    state: Instantiated,
                    guid: g,
                    variant,
                    pristine: values.clone(),
                    table,
                    values,
                    model,
                    running: None,
                    time: 0.0,
                    start_time: 0.0,
                    stop_time: None,
                    outputs_stale: true,
                    on_demand_stale: false,
                });
            }
            expected.push(format!("{variant}: {g}"));
        }
        Err(FmuError::Instantiate(format!(
            "GUID {guid} matches no packaged variant of {} ({}); the modelDescription.xml and \
             the binary come from different builds or layouts",
            M::INFO.model_identifier,
            expected.join(", ")
        )))
    }

    /// The variant (layout) this instance was packaged for.
    pub fn variant(&self) -> &str {
        &self.variant
    }

    /// The variable table.
    pub fn table(&self) -> &VariableTable {
        &self.table
    }

    /// The current state.
    pub fn state(&self) -> State {
        self.state
    }

    /// The current time.
    pub fn time(&self) -> f64 {
        self.time
    }

    /// The model as configured, for in-process use.
    pub fn model(&self) -> &M {
        &self.model
    }

    /// The running model, once initialised (fmi2ExitInitializationMode) and until reset.
    pub fn running(&self) -> Option<&M::Running> {
        self.running.as_ref()
    }

    /// Sends a message through the importer's logger (errors always, others when logging is on).
    pub fn log(&self, status: fmi2Status, category: &CStr, msg: &str) {
        let is_error = matches!(status, fmi2Status::fmi2Error | fmi2Status::fmi2Fatal);
        if !is_error && !self.logging_on {
            return;
        }
        let Some(cb) = self.callbacks else { return };
        let Some(logger) = cb.logger else { return };
        let msg = CString::new(msg.replace('\0', " ")).unwrap_or_default();
        // SAFETY: the importer's logger, called with a "%s" format and a valid C string, and
        // a non-NULL category; the environment pointer is passed back as given.
        unsafe {
            logger(
                cb.componentEnvironment,
                self.name.as_ptr(),
                status,
                category.as_ptr(),
                c"%s".as_ptr(),
                msg.as_ptr(),
            );
        }
    }

    /// Logs a call when the `logCalls` category is enabled.
    pub fn trace(&self, what: impl FnOnce() -> String) {
        if self.log_calls {
            self.log(fmi2Status::fmi2OK, c"logCalls", &what());
        }
    }

    /// Marks the instance as failed fatally (after a caught panic).
    pub(crate) fn set_fatal(&mut self) {
        self.state = Fatal;
    }

    /// Refuses `call` unless the standard allows it in the current state ([`Call::allowed`]).
    fn require(&self, call: Call) -> Result<(), FmuError> {
        if call.allowed().contains(&self.state) {
            Ok(())
        } else {
            Err(FmuError::IllegalCall {
                function: call.name(),
                state: self.state.name(),
            })
        }
    }

    /// fmi2SetDebugLogging.
    pub fn set_debug_logging(&mut self, on: bool, categories: &[String]) -> Result<(), FmuError> {
        self.require(Call::SetDebugLogging)?;
        for c in categories {
            if !crate::xml::LOG_CATEGORIES.iter().any(|(n, _)| n == c) {
                return Err(FmuError::BadValue {
                    variable: "log category".into(),
                    value: c.clone(),
                    reason: format!(
                        "is not one of {}",
                        crate::xml::LOG_CATEGORIES.map(|(n, _)| n).join(", ")
                    ),
                });
            }
        }
        self.logging_on = on;
        self.log_calls =
            on && (categories.is_empty() || categories.iter().any(|c| c == "logCalls"));
        Ok(())
    }

    /// fmi2SetupExperiment.
    pub fn setup_experiment(&mut self, start: f64, stop: Option<f64>) -> Result<(), FmuError> {
        self.require(Call::SetupExperiment)?;
        if !start.is_finite() {
            return Err(FmuError::BadValue {
                variable: "startTime".into(),
                value: start.to_string(),
                reason: "must be finite".into(),
            });
        }
        if let Some(s) = stop
            && !(s.is_finite() && s >= start)
        {
            return Err(FmuError::BadValue {
                variable: "stopTime".into(),
                value: s.to_string(),
                reason: format!("must be finite and >= startTime {start}"),
            });
        }
        self.start_time = start;
        self.time = start;
        self.stop_time = stop;
        Ok(())
    }

    /// fmi2EnterInitializationMode.
    pub fn enter_initialization_mode(&mut self) -> Result<(), FmuError> {
        self.require(Call::EnterInitializationMode)?;
        self.state = InitializationMode;
        self.outputs_stale = true;
        Ok(())
    }

    /// fmi2ExitInitializationMode: the model checks its parameters; on failure the instance
    /// stays in initialisation mode so that parameters can be corrected.
    pub fn exit_initialization_mode(&mut self) -> Result<(), FmuError> {
        self.require(Call::ExitInitializationMode)?;
        // A model built when outputs were read in initialisation mode is kept if nothing was
        // set since (the master's propagation reads them): the same inputs give the same model.
        if self.outputs_stale || self.running.is_none() {
            self.running = Some(self.model.initialize(&mut self.values, self.start_time)?);
            self.on_demand_stale = false;
        }
        self.outputs_stale = false;
        self.time = self.start_time;
        self.state = StepComplete;
        Ok(())
    }

    /// fmi2Terminate.
    pub fn terminate(&mut self) -> Result<(), FmuError> {
        self.require(Call::Terminate)?;
        self.state = Terminated;
        Ok(())
    }

    /// fmi2Reset: back to the state after fmi2Instantiate.
    pub fn reset(&mut self) -> Result<(), FmuError> {
        self.require(Call::Reset)?;
        self.values = self.pristine.clone();
        self.running = None;
        self.state = Instantiated;
        self.time = 0.0;
        self.start_time = 0.0;
        self.stop_time = None;
        self.outputs_stale = true;
        self.on_demand_stale = false;
        Ok(())
    }

    fn refresh_outputs(&mut self) -> Result<(), FmuError> {
        if self.outputs_stale {
            match self.state {
                InitializationMode => {
                    // Kept for fmi2ExitInitializationMode while nothing is set (a set makes
                    // the outputs stale, and the model is built again).
                    self.running = Some(self.model.initialize(&mut self.values, self.start_time)?);
                    self.on_demand_stale = false;
                }
                StepComplete => {
                    if let Some(r) = self.running.as_mut() {
                        r.update_outputs(&mut self.values)?;
                    }
                }
                _ => {}
            }
            self.outputs_stale = false;
        }
        Ok(())
    }

    /// Writes the running model's on-demand outputs if a step left them stale and `wanted`
    /// holds for one of their ranges (the Real value references a read asks for). They are
    /// checked as a step's outputs are: a non-finite value fails the read.
    fn refresh_on_demand(
        &mut self,
        wanted: impl Fn(&std::ops::Range<u32>) -> bool,
    ) -> Result<(), FmuError> {
        if !self.on_demand_stale {
            return Ok(());
        }
        let lo = self.type_range(VarType::Real).start;
        let Some(r) = self.running.as_mut() else {
            return Ok(());
        };
        if !r.on_demand().iter().any(wanted) {
            return Ok(());
        }
        r.write_on_demand(&mut self.values)?;
        self.on_demand_stale = false;
        for g in r.on_demand() {
            let slots = (g.start - lo) as usize..(g.end - lo) as usize;
            if !all_finite(&self.values.reals[slots]) {
                return Err(FmuError::Model(format!(
                    "fmi2GetReal: the model produced a non-finite output in the step to t = {}",
                    self.time
                )));
            }
        }
        Ok(())
    }

    fn type_range(&self, ty: VarType) -> std::ops::Range<u32> {
        let c = self.table.counts();
        let starts = [0, c[0], c[0] + c[1], c[0] + c[1] + c[2]];
        let i = match ty {
            VarType::Real => 0,
            VarType::Integer => 1,
            VarType::Boolean => 2,
            VarType::String => 3,
        };
        let lo = starts[i] as u32;
        lo..lo + c[i] as u32
    }

    fn slot(&self, ty: VarType, vr: u32, ty_name: &'static str) -> Result<usize, FmuError> {
        let r = self.type_range(ty);
        if r.contains(&vr) {
            Ok((vr - r.start) as usize)
        } else {
            Err(FmuError::UnknownReference { vr, ty: ty_name })
        }
    }

    /// fmi2GetReal.
    pub fn get_real(&mut self, vrs: &[u32], out: &mut [f64]) -> Result<(), FmuError> {
        self.require(Call::GetReal)?;
        self.refresh_outputs()?;
        // Fast path for the master's bulk output transfers: one contiguous run of Real value
        // references, copied in one go.
        if out.len() == vrs.len()
            && let Some((first, last)) = consecutive(vrs)
            && self.type_range(VarType::Real).contains(&first)
            && self.type_range(VarType::Real).contains(&last)
        {
            self.refresh_on_demand(|g| g.start <= last && first < g.end)?;
            let s = (first - self.type_range(VarType::Real).start) as usize;
            out.copy_from_slice(&self.values.reals[s..s + out.len()]);
            return Ok(());
        }
        self.refresh_on_demand(|g| vrs.iter().any(|vr| g.contains(vr)))?;
        for (vr, o) in vrs.iter().zip(out.iter_mut()) {
            *o = self.values.reals[self.slot(VarType::Real, *vr, "Real")?];
        }
        Ok(())
    }

    /// fmi2GetInteger.
    pub fn get_integer(&mut self, vrs: &[u32], out: &mut [i32]) -> Result<(), FmuError> {
        self.require(Call::GetInteger)?;
        self.refresh_outputs()?;
        for (vr, o) in vrs.iter().zip(out.iter_mut()) {
            *o = self.values.integers[self.slot(VarType::Integer, *vr, "Integer")?];
        }
        Ok(())
    }

    /// fmi2GetBoolean.
    pub fn get_boolean(&mut self, vrs: &[u32], out: &mut [bool]) -> Result<(), FmuError> {
        self.require(Call::GetBoolean)?;
        self.refresh_outputs()?;
        for (vr, o) in vrs.iter().zip(out.iter_mut()) {
            *o = self.values.booleans[self.slot(VarType::Boolean, *vr, "Boolean")?];
        }
        Ok(())
    }

    /// fmi2GetString: pointers valid until the string is set again or the instance is freed.
    pub fn get_string(
        &mut self,
        vrs: &[u32],
        out: &mut [*const std::ffi::c_char],
    ) -> Result<(), FmuError> {
        self.require(Call::GetString)?;
        self.refresh_outputs()?;
        for (vr, o) in vrs.iter().zip(out.iter_mut()) {
            *o = self.values.strings[self.slot(VarType::String, *vr, "String")?].as_ptr();
        }
        Ok(())
    }

    fn settable(&self, v: &Variable, i: usize) -> Result<(), FmuError> {
        let ok = match self.state {
            Instantiated | InitializationMode => {
                v.causality == Causality::Input
                    || (v.causality == Causality::Parameter
                        && v.variability != Variability::Constant)
            }
            StepComplete => {
                v.causality == Causality::Input
                    || (v.causality == Causality::Parameter
                        && v.variability == Variability::Tunable)
            }
            _ => false,
        };
        if ok {
            Ok(())
        } else {
            Err(FmuError::NotSettable {
                variable: v.scalar_name(i),
                causality: v.causality.xml(),
                variability: v.variability.xml(),
                state: self.state.name(),
            })
        }
    }

    /// Validates a batch of scalars of one type; returns their slots. Nothing is written.
    fn validate_set<T: Copy>(
        &self,
        call: Call,
        ty: VarType,
        ty_name: &'static str,
        vrs: &[u32],
        vals: &[T],
        check: impl Fn(&VariableTable, &Variable, usize, T) -> Result<(), FmuError>,
    ) -> Result<Vec<usize>, FmuError> {
        self.require(call)?;
        let mut slots = Vec::with_capacity(vrs.len());
        let mut current: Option<&Variable> = None;
        for (vr, x) in vrs.iter().zip(vals) {
            let slot = self.slot(ty, *vr, ty_name)?;
            let var = match current {
                Some(v) if v.contains(*vr) => v,
                _ => {
                    let (v, _) = self.table.lookup(*vr).ok_or(FmuError::UnknownReference {
                        vr: *vr,
                        ty: ty_name,
                    })?;
                    current = Some(v);
                    v
                }
            };
            let i = (*vr - var.vr) as usize;
            self.settable(var, i)?;
            check(&self.table, var, i, *x)?;
            slots.push(slot);
        }
        Ok(slots)
    }

    /// fmi2SetReal: all values are checked before any is written.
    pub fn set_real(&mut self, vrs: &[u32], vals: &[f64]) -> Result<(), FmuError> {
        // Fast path for the master's bulk input transfers: one contiguous run of value
        // references over one or more Real inputs, each value checked with its variable's
        // check, then copied in one go.
        if self.state == StepComplete
            && vals.len() == vrs.len()
            && let Some((first, last)) = consecutive(vrs)
            && self.type_range(VarType::Real).contains(&last)
        {
            let mut pos = 0;
            while pos < vals.len() {
                let vr = first + pos as u32;
                let (v, i) = self
                    .table
                    .lookup(vr)
                    .ok_or(FmuError::UnknownReference { vr, ty: "Real" })?;
                self.settable(v, i)?;
                let count = (v.len - i).min(vals.len() - pos);
                let run = &vals[pos..pos + count];
                // Most inputs only need to be finite: one vectorised pass, and the value by
                // value check (with its message) only if it fails.
                if !(matches!(v.check, crate::variables::Check::Finite) && all_finite(run)) {
                    for (k, x) in run.iter().enumerate() {
                        self.table.check_real(v, i + k, *x)?;
                    }
                }
                pos += count;
            }
            let s = first as usize;
            self.values.reals[s..s + vals.len()].copy_from_slice(vals);
            self.outputs_stale = true;
            return Ok(());
        }
        let slots = self.validate_set(
            Call::SetReal,
            VarType::Real,
            "Real",
            vrs,
            vals,
            |t, v, i, x| t.check_real(v, i, x),
        )?;
        for (s, x) in slots.into_iter().zip(vals) {
            self.values.reals[s] = *x;
        }
        self.outputs_stale = true;
        Ok(())
    }

    /// fmi2SetInteger.
    pub fn set_integer(&mut self, vrs: &[u32], vals: &[i32]) -> Result<(), FmuError> {
        let slots = self.validate_set(
            Call::SetInteger,
            VarType::Integer,
            "Integer",
            vrs,
            vals,
            |t, v, i, x| t.check_integer(v, i, x),
        )?;
        for (s, x) in slots.into_iter().zip(vals) {
            self.values.integers[s] = *x;
        }
        self.outputs_stale = true;
        Ok(())
    }

    /// fmi2SetBoolean.
    pub fn set_boolean(&mut self, vrs: &[u32], vals: &[bool]) -> Result<(), FmuError> {
        let slots = self.validate_set(
            Call::SetBoolean,
            VarType::Boolean,
            "Boolean",
            vrs,
            vals,
            |_, _, _, _| Ok(()),
        )?;
        for (s, x) in slots.into_iter().zip(vals) {
            self.values.booleans[s] = *x;
        }
        self.outputs_stale = true;
        Ok(())
    }

    /// fmi2SetString.
    pub fn set_string(&mut self, vrs: &[u32], vals: &[&str]) -> Result<(), FmuError> {
        let slots = self.validate_set(
            Call::SetString,
            VarType::String,
            "String",
            vrs,
            vals,
            |t, v, i, x| t.check_string(v, i, x),
        )?;
        for (s, x) in slots.into_iter().zip(vals) {
            self.values.strings[s] = CString::new(x.replace('\0', " ")).unwrap_or_default();
        }
        self.outputs_stale = true;
        Ok(())
    }

    /// fmi2DoStep.
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<(), FmuError> {
        self.require(Call::DoStep)?;
        let tol = 1e-9 * self.time.abs().max(1.0);
        if !t.is_finite() || (t - self.time).abs() > tol {
            return Err(FmuError::TimeMismatch {
                given: t,
                expected: self.time,
            });
        }
        if !(h.is_finite() && h > 0.0) {
            return Err(FmuError::BadValue {
                variable: "communicationStepSize".into(),
                value: h.to_string(),
                reason: "must be a finite number > 0".into(),
            });
        }
        if let Some(stop) = self.stop_time
            && t + h > stop + tol
        {
            return Err(FmuError::Model(format!(
                "fmi2DoStep: step to {} goes past the stopTime {stop} given to fmi2SetupExperiment",
                t + h
            )));
        }
        let state = self.state.name();
        let running = self.running.as_mut().ok_or(FmuError::IllegalCall {
            function: Call::DoStep.name(),
            state,
        })?;
        running.do_step(self.time, h, &mut self.values)?;
        if !all_finite(&self.values.reals) {
            self.state = StepFailed;
            return Err(FmuError::Model(format!(
                "fmi2DoStep: the model produced a non-finite value in the step from t = {t}"
            )));
        }
        self.time = t + h;
        self.outputs_stale = false;
        self.on_demand_stale = self
            .running
            .as_ref()
            .is_some_and(|r| !r.on_demand().is_empty());
        Ok(())
    }

    /// fmi2GetFMUstate.
    pub fn get_state(&self) -> Result<Snapshot<M>, FmuError> {
        self.require(Call::GetFmuState)?;
        Ok(Snapshot {
            magic: MAGIC,
            guid: self.guid.clone(),
            state: self.state,
            time: self.time,
            start_time: self.start_time,
            stop_time: self.stop_time,
            outputs_stale: self.outputs_stale,
            on_demand_stale: self.on_demand_stale,
            values: self.values.clone(),
            running: self.running.clone(),
        })
    }

    /// fmi2SetFMUstate.
    pub fn set_state(&mut self, s: &Snapshot<M>) -> Result<(), FmuError> {
        self.require(Call::SetFmuState)?;
        if s.guid != self.guid {
            return Err(FmuError::State(format!(
                "the state was saved by an FMU with GUID {}, this one is {}",
                s.guid, self.guid
            )));
        }
        self.state = s.state;
        self.time = s.time;
        self.start_time = s.start_time;
        self.stop_time = s.stop_time;
        self.outputs_stale = s.outputs_stale;
        self.on_demand_stale = s.on_demand_stale;
        self.values = s.values.clone();
        self.running = s.running.clone();
        Ok(())
    }

    /// Serialises a snapshot (fmi2SerializeFMUstate).
    pub fn serialize(s: &Snapshot<M>) -> Result<Vec<u8>, FmuError> {
        let mut out = STATE_MAGIC.to_vec();
        let body = postcard::to_stdvec(s).map_err(|e| FmuError::State(e.to_string()))?;
        out.extend_from_slice(&body);
        Ok(out)
    }

    /// Reads a serialised snapshot back (fmi2DeSerializeFMUstate).
    pub fn deserialize(&self, bytes: &[u8]) -> Result<Snapshot<M>, FmuError> {
        let body = bytes
            .strip_prefix(STATE_MAGIC.as_slice())
            .ok_or_else(|| foreign_state(bytes))?;
        let s: Snapshot<M> =
            postcard::from_bytes(body).map_err(|e| FmuError::State(e.to_string()))?;
        if s.guid != self.guid || s.values.reals.len() != self.values.reals.len() {
            return Err(FmuError::State(format!(
                "the state belongs to an FMU with GUID {}, this one is {}",
                s.guid, self.guid
            )));
        }
        Ok(s)
    }

    /// fmi2GetRealStatus(fmi2LastSuccessfulTime).
    pub fn last_successful_time(&self) -> f64 {
        self.time
    }
}

/// Why `bytes` without this build's [`STATE_MAGIC`] is refused: a state of another layout of
/// these FMUs (named), or no state of ours at all.
fn foreign_state(bytes: &[u8]) -> FmuError {
    match bytes.get(..8) {
        Some(tag) if tag.starts_with(&STATE_MAGIC[..6]) => FmuError::State(format!(
            "the state was saved by another version of these FMUs (state layout {}, this one \
             reads {})",
            String::from_utf8_lossy(&tag[6..]),
            String::from_utf8_lossy(&STATE_MAGIC[6..])
        )),
        _ => FmuError::State("not a serialized state of this FMU".into()),
    }
}

/// The first and last of `vrs` if they are consecutive value references (`first`, `first +
/// 1`, ...), the form of the master's bulk transfers. Each reference is compared with its
/// position's in one pass that accumulates the differences, with no branch per value, so that
/// the loop vectorises (`pulp`'s runtime dispatch): 0.08-0.1 us for the TMT mirror's 1476
/// displacements and 0.2 us for the TMT edge sensors' 5544 outputs, where a pairwise
/// `windows(2).all(...)` took 0.66-0.90 and 2.6-3.3 us, more than the copies they guard
/// (BENCHMARKS.md, issue 18, seventeenth round).
fn consecutive(vrs: &[u32]) -> Option<(u32, u32)> {
    struct Check<'a>(&'a [u32], u32);
    impl pulp::WithSimd for Check<'_> {
        type Output = u32;
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) -> u32 {
            // Reference k must be first + k: `vr - k` (wrapping) equals `first` for all. The
            // positions count in a range that stops at the length (`u32` below).
            let (vrs, first) = (self.0, self.1);
            vrs.iter()
                .zip(0..vrs.len() as u32)
                .fold(0, |a, (v, k)| a | (v.wrapping_sub(k) ^ first))
        }
    }
    let (&first, &last) = (vrs.first()?, vrs.last()?);
    // The length first: `last - first + 1` references, none wrapping past u32::MAX, and
    // fewer than 2^32 of them (their positions are counted in u32).
    if last < first || (last - first) as usize + 1 != vrs.len() || u32::try_from(vrs.len()).is_err()
    {
        return None;
    }
    (pulp::Arch::new().dispatch(Check(vrs, first)) == 0).then_some((first, last))
}

/// Whether every value is finite: `0 * v` is 0 for a finite `v` and NaN otherwise, summed in
/// sixteen independent lanes so that the loop vectorises, compiled for the processor's widest
/// vectors (`pulp`'s runtime dispatch). The master sets thousands of inputs per step, and every
/// Real is checked after each step: the TMT edge sensors' 5000-odd took about 1.7 us per step
/// with a value-by-value loop, a tenth of their step (BENCHMARKS.md, issue 18, thirteenth
/// round).
fn all_finite(x: &[f64]) -> bool {
    struct Check<'a>(&'a [f64]);
    impl pulp::WithSimd for Check<'_> {
        type Output = bool;
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _simd: S) -> bool {
            let mut lanes = [0.0f64; 16];
            let chunks = self.0.chunks_exact(16);
            let tail = chunks.remainder();
            for c in chunks {
                for (l, v) in lanes.iter_mut().zip(c) {
                    *l += 0.0 * v;
                }
            }
            let rest: f64 = tail.iter().map(|v| 0.0 * v).sum();
            (lanes.iter().sum::<f64>() + rest) == 0.0
        }
    }
    pulp::Arch::new().dispatch(Check(x))
}

#[cfg(test)]
mod tests {
    use super::{all_finite, consecutive};

    /// Consecutive references of every length around the vector widths are found, from 0 and
    /// up to `u32::MAX`; one reference out of place anywhere (a swap with the next, a repeat of
    /// a neighbour) is not.
    #[test]
    fn consecutive_references_are_found_and_others_are_not() {
        assert_eq!(consecutive(&[]), None);
        for n in [1u32, 2, 15, 16, 17, 31, 32, 33, 70] {
            for first in [0u32, 7, u32::MAX - n + 1] {
                let vrs: Vec<u32> = (0..n).map(|k| first + k).collect();
                assert_eq!(
                    consecutive(&vrs),
                    Some((first, first + (n - 1))),
                    "{n} {first}"
                );
                for at in 0..n as usize {
                    // Swapped with the next (the ends and the length stay right inside).
                    if at + 2 < n as usize && at > 0 {
                        let mut v = vrs.clone();
                        v.swap(at, at + 1);
                        assert_eq!(consecutive(&v), None, "swap {n} {first} {at}");
                    }
                    // One reference replaced by its neighbour's.
                    if n > 1 {
                        let mut v = vrs.clone();
                        v[at] = if at == 0 { v[1] } else { v[at - 1] };
                        assert_eq!(consecutive(&v), None, "repeat {n} {first} {at}");
                    }
                }
            }
        }
        // The ends right, the middle not: 0, 2, 1, 3.
        assert_eq!(consecutive(&[0, 2, 1, 3]), None);
        assert_eq!(consecutive(&[5, 4]), None);
    }

    /// Finite runs of every length around the vector widths pass, with the extremes of the
    /// finite values among them; one NaN or infinity anywhere fails.
    #[test]
    fn every_non_finite_value_is_found() {
        let finite = [
            0.0,
            -0.0,
            1.5,
            f64::MAX,
            f64::MIN,
            5e-324,
            f64::MIN_POSITIVE,
        ];
        for n in [0usize, 1, 15, 16, 17, 31, 32, 33, 70] {
            let x: Vec<f64> = (0..n).map(|k| finite[k % finite.len()]).collect();
            assert!(all_finite(&x), "{n}");
            for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                for at in 0..n {
                    let mut y = x.clone();
                    y[at] = bad;
                    assert!(!all_finite(&y), "{n} {at} {bad}");
                }
            }
        }
    }
}
