//! One instance of an imported FMU: the safe layer over the C calls. Each call is one unsafe
//! line; its status becomes a `Result` in one place (`Instance::check`), with the messages the
//! FMU logged for it. The instance is freed in `Drop`; it holds the library (and the unpacked
//! files) alive.

use std::ffi::{CStr, CString, c_int};
use std::sync::Arc;

use fmi_sys::fmi2::callbacks::fmi2CallbackFunctions;
use fmi_sys::fmi2::enums::{fmi2Status, fmi2StatusKind, fmi2Type};
use fmi_sys::fmi2::types::{fmi2Component, fmi2String};

use crate::error::{CosimError, Result};
use crate::fmu::{Fmu, Shared};
use crate::logger::{LogSink, allocate, free, m1cs_cosim_logger};

/// A Co-Simulation slave.
pub struct Instance {
    comp: fmi2Component,
    shared: Arc<Shared>,
    /// Boxed so that its address (the FMU's componentEnvironment) is stable.
    sink: Box<LogSink>,
    /// Boxed: FMUs may keep the pointer to the callback struct.
    _callbacks: Box<fmi2CallbackFunctions>,
    name: String,
    /// Scratch for string values.
    strings: Vec<CString>,
}

// SAFETY: an FMI 2.0 component may be used from any thread as long as calls on it are not
// concurrent; `Instance` is not `Sync`, and every call takes `&mut self` or `&self` on one thread.
unsafe impl Send for Instance {}

fn status_name(raw: c_int) -> String {
    match fmi2Status::from_raw(raw) {
        Some(s) => format!("{s:?}"),
        None => format!("an invalid status ({raw})"),
    }
}

/// The status `raw` of FMI call `function` of component `component` as a `Result`: fmi2OK and
/// fmi2Warning pass; fmi2Discard is [`CosimError::Discarded`]; every other status (fmi2Error,
/// fmi2Fatal, fmi2Pending, an invalid value) is [`CosimError::Status`]. `log` takes the
/// messages the FMU logged for the call (only on failure).
fn check_status(
    component: &str,
    function: &'static str,
    raw: c_int,
    at: Option<f64>,
    log: impl FnOnce() -> String,
) -> Result<()> {
    let at = || at.map(|t| format!(" at t = {t} s")).unwrap_or_default();
    match fmi2Status::from_raw(raw) {
        Some(fmi2Status::fmi2OK | fmi2Status::fmi2Warning) => Ok(()),
        Some(fmi2Status::fmi2Discard) => Err(CosimError::Discarded {
            component: component.into(),
            function,
            at: at(),
            log: log(),
        }),
        _ => Err(CosimError::Status {
            component: component.into(),
            function,
            status: status_name(raw),
            at: at(),
            log: log(),
        }),
    }
}

impl Instance {
    pub(crate) fn new(
        fmu: &Fmu,
        shared: Arc<Shared>,
        name: &str,
        guid: &str,
        verbose: bool,
    ) -> Result<Self> {
        let invalid =
            |what: &str| CosimError::Invalid(format!("{name}: {what} contains a NUL byte"));
        let c_name = CString::new(name).map_err(|_| invalid("the instance name"))?;
        let c_guid = CString::new(guid).map_err(|_| invalid("the GUID"))?;
        let c_res = CString::new(fmu.resource_uri()).map_err(|_| invalid("the resource path"))?;
        let sink = Box::new(LogSink::new(verbose));
        let callbacks = Box::new(fmi2CallbackFunctions {
            logger: Some(m1cs_cosim_logger),
            allocateMemory: Some(allocate),
            freeMemory: Some(free),
            stepFinished: None,
            componentEnvironment: (&*sink as *const LogSink).cast_mut().cast(),
        });
        // SAFETY: valid C strings and callback struct, alive for the call (and the callbacks
        // and sink for the instance's life).
        let comp = unsafe {
            (shared.library.fns.instantiate)(
                c_name.as_ptr(),
                fmi2Type::fmi2CoSimulation,
                c_guid.as_ptr(),
                c_res.as_ptr(),
                &*callbacks,
                0,
                c_int::from(verbose),
            )
        };
        if comp.is_null() {
            return Err(CosimError::Instantiate {
                component: name.into(),
                guid: guid.into(),
                log: sink.drain_text(),
            });
        }
        Ok(Self {
            comp,
            shared,
            sink,
            _callbacks: callbacks,
            name: name.into(),
            strings: Vec::new(),
        })
    }

    /// The instance name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The messages logged so far (taken).
    pub fn take_log(&self) -> Vec<crate::logger::LogMessage> {
        self.sink.take()
    }

    fn check(&self, function: &'static str, raw: c_int, at: Option<f64>) -> Result<()> {
        check_status(&self.name, function, raw, at, || self.sink.drain_text())
    }

    fn lengths(&self, function: &'static str, a: usize, b: usize) -> Result<()> {
        if a == b {
            Ok(())
        } else {
            Err(CosimError::Invalid(format!(
                "{}: {function} with {a} value references and {b} values",
                self.name
            )))
        }
    }

    /// fmi2SetupExperiment.
    ///
    /// # Errors
    /// The FMU's error status with its log.
    pub fn setup_experiment(
        &mut self,
        tolerance: Option<f64>,
        start: f64,
        stop: Option<f64>,
    ) -> Result<()> {
        // SAFETY: valid component.
        let s = unsafe {
            (self.shared.library.fns.setup_experiment)(
                self.comp,
                c_int::from(tolerance.is_some()),
                tolerance.unwrap_or(0.0),
                start,
                c_int::from(stop.is_some()),
                stop.unwrap_or(0.0),
            )
        };
        self.check("fmi2SetupExperiment", s, Some(start))
    }

    /// fmi2EnterInitializationMode.
    ///
    /// # Errors
    /// The FMU's error status with its log.
    pub fn enter_initialization_mode(&mut self) -> Result<()> {
        // SAFETY: valid component.
        let s = unsafe { (self.shared.library.fns.enter_initialization_mode)(self.comp) };
        self.check("fmi2EnterInitializationMode", s, None)
    }

    /// fmi2ExitInitializationMode.
    ///
    /// # Errors
    /// The FMU's error status with its log.
    pub fn exit_initialization_mode(&mut self) -> Result<()> {
        // SAFETY: valid component.
        let s = unsafe { (self.shared.library.fns.exit_initialization_mode)(self.comp) };
        self.check("fmi2ExitInitializationMode", s, None)
    }

    /// fmi2Terminate.
    ///
    /// # Errors
    /// The FMU's error status with its log.
    pub fn terminate(&mut self) -> Result<()> {
        // SAFETY: valid component.
        let s = unsafe { (self.shared.library.fns.terminate)(self.comp) };
        self.check("fmi2Terminate", s, None)
    }

    /// fmi2Reset.
    ///
    /// # Errors
    /// The FMU's error status with its log.
    pub fn reset(&mut self) -> Result<()> {
        // SAFETY: valid component.
        let s = unsafe { (self.shared.library.fns.reset)(self.comp) };
        self.check("fmi2Reset", s, None)
    }

    /// fmi2DoStep from `t` over `h`.
    ///
    /// # Errors
    /// The FMU's error status with its log and the time.
    pub fn do_step(&mut self, t: f64, h: f64) -> Result<()> {
        // SAFETY: valid component.
        let s = unsafe { (self.shared.library.fns.do_step)(self.comp, t, h, 1) };
        self.check("fmi2DoStep", s, Some(t))
    }

    /// Whether the slave asks to end the simulation (fmi2GetBooleanStatus(fmi2Terminated), asked
    /// after a step returned fmi2Discard).
    ///
    /// # Errors
    /// The FMU's error status with its log (an FMU that does not answer this kind).
    pub fn terminated(&mut self) -> Result<bool> {
        let mut v: c_int = 0;
        // SAFETY: valid component and a live out-pointer.
        let s = unsafe {
            (self.shared.library.fns.get_boolean_status)(
                self.comp,
                fmi2StatusKind::fmi2Terminated as c_int,
                &raw mut v,
            )
        };
        self.check("fmi2GetBooleanStatus(fmi2Terminated)", s, None)?;
        Ok(v != 0)
    }

    /// The end time of the last successful step after a discarded one
    /// (fmi2GetRealStatus(fmi2LastSuccessfulTime)).
    ///
    /// # Errors
    /// The FMU's error status with its log (an FMU that does not answer this kind).
    pub fn last_successful_time(&mut self) -> Result<f64> {
        let mut v = 0.0;
        // SAFETY: valid component and a live out-pointer.
        let s = unsafe {
            (self.shared.library.fns.get_real_status)(
                self.comp,
                fmi2StatusKind::fmi2LastSuccessfulTime as c_int,
                &raw mut v,
            )
        };
        self.check("fmi2GetRealStatus(fmi2LastSuccessfulTime)", s, None)?;
        Ok(v)
    }

    /// fmi2GetReal into `out` (one value per reference).
    ///
    /// # Errors
    /// Length mismatch, or the FMU's error status with its log.
    pub fn get_real(&mut self, vrs: &[u32], out: &mut [f64]) -> Result<()> {
        self.lengths("fmi2GetReal", vrs.len(), out.len())?;
        // SAFETY: valid component; both buffers hold vrs.len() elements.
        let s = unsafe {
            (self.shared.library.fns.get_real)(self.comp, vrs.as_ptr(), vrs.len(), out.as_mut_ptr())
        };
        self.check("fmi2GetReal", s, None)
    }

    /// fmi2SetReal from `values` (one per reference).
    ///
    /// # Errors
    /// Length mismatch, or the FMU's error status with its log.
    pub fn set_real(&mut self, vrs: &[u32], values: &[f64]) -> Result<()> {
        self.lengths("fmi2SetReal", vrs.len(), values.len())?;
        // SAFETY: valid component; both buffers hold vrs.len() elements.
        let s = unsafe {
            (self.shared.library.fns.set_real)(self.comp, vrs.as_ptr(), vrs.len(), values.as_ptr())
        };
        self.check("fmi2SetReal", s, None)
    }

    /// fmi2GetInteger (also for enumerations).
    ///
    /// # Errors
    /// Length mismatch, or the FMU's error status with its log.
    pub fn get_integer(&mut self, vrs: &[u32], out: &mut [i32]) -> Result<()> {
        self.lengths("fmi2GetInteger", vrs.len(), out.len())?;
        // SAFETY: as get_real.
        let s = unsafe {
            (self.shared.library.fns.get_integer)(
                self.comp,
                vrs.as_ptr(),
                vrs.len(),
                out.as_mut_ptr(),
            )
        };
        self.check("fmi2GetInteger", s, None)
    }

    /// fmi2SetInteger.
    ///
    /// # Errors
    /// Length mismatch, or the FMU's error status with its log.
    pub fn set_integer(&mut self, vrs: &[u32], values: &[i32]) -> Result<()> {
        self.lengths("fmi2SetInteger", vrs.len(), values.len())?;
        // SAFETY: as set_real.
        let s = unsafe {
            (self.shared.library.fns.set_integer)(
                self.comp,
                vrs.as_ptr(),
                vrs.len(),
                values.as_ptr(),
            )
        };
        self.check("fmi2SetInteger", s, None)
    }

    /// fmi2GetBoolean.
    ///
    /// # Errors
    /// Length mismatch, or the FMU's error status with its log.
    pub fn get_boolean(&mut self, vrs: &[u32], out: &mut [bool]) -> Result<()> {
        self.lengths("fmi2GetBoolean", vrs.len(), out.len())?;
        let mut raw = vec![0 as c_int; vrs.len()];
        // SAFETY: as get_real.
        let s = unsafe {
            (self.shared.library.fns.get_boolean)(
                self.comp,
                vrs.as_ptr(),
                vrs.len(),
                raw.as_mut_ptr(),
            )
        };
        self.check("fmi2GetBoolean", s, None)?;
        for (o, r) in out.iter_mut().zip(&raw) {
            *o = *r != 0;
        }
        Ok(())
    }

    /// fmi2SetBoolean.
    ///
    /// # Errors
    /// Length mismatch, or the FMU's error status with its log.
    pub fn set_boolean(&mut self, vrs: &[u32], values: &[bool]) -> Result<()> {
        self.lengths("fmi2SetBoolean", vrs.len(), values.len())?;
        let raw: Vec<c_int> = values.iter().map(|&b| c_int::from(b)).collect();
        // SAFETY: as set_real.
        let s = unsafe {
            (self.shared.library.fns.set_boolean)(self.comp, vrs.as_ptr(), vrs.len(), raw.as_ptr())
        };
        self.check("fmi2SetBoolean", s, None)
    }

    /// fmi2GetString (copied out).
    ///
    /// # Errors
    /// The FMU's error status with its log.
    pub fn get_string(&mut self, vrs: &[u32]) -> Result<Vec<String>> {
        let mut raw: Vec<fmi2String> = vec![std::ptr::null(); vrs.len()];
        // SAFETY: as get_real.
        let s = unsafe {
            (self.shared.library.fns.get_string)(
                self.comp,
                vrs.as_ptr(),
                vrs.len(),
                raw.as_mut_ptr(),
            )
        };
        self.check("fmi2GetString", s, None)?;
        Ok(raw
            .iter()
            .map(|&p| {
                if p.is_null() {
                    String::new()
                } else {
                    // SAFETY: the FMU returns NUL-terminated strings valid until its next call.
                    unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
                }
            })
            .collect())
    }

    /// fmi2SetString.
    ///
    /// # Errors
    /// A value with a NUL byte, length mismatch, or the FMU's error status with its log.
    pub fn set_string(&mut self, vrs: &[u32], values: &[&str]) -> Result<()> {
        self.lengths("fmi2SetString", vrs.len(), values.len())?;
        self.strings.clear();
        for v in values {
            self.strings.push(CString::new(*v).map_err(|_| {
                CosimError::Invalid(format!(
                    "{}: string value {v:?} contains a NUL byte",
                    self.name
                ))
            })?);
        }
        let ptrs: Vec<fmi2String> = self.strings.iter().map(|c| c.as_ptr()).collect();
        // SAFETY: as set_real; the strings live in self.strings during the call.
        let s = unsafe {
            (self.shared.library.fns.set_string)(self.comp, vrs.as_ptr(), vrs.len(), ptrs.as_ptr())
        };
        self.check("fmi2SetString", s, None)
    }
}

impl Drop for Instance {
    fn drop(&mut self) {
        // SAFETY: the component came from fmi2Instantiate of this library and is freed once.
        unsafe { (self.shared.library.fns.free_instance)(self.comp) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The status mapping: OK and Warning pass, Discard has its own variant (with the message
    /// that the FMU discarded the step), Error, Fatal, Pending and invalid values stay
    /// `Status`; the log is taken on failure only.
    #[test]
    fn discard_is_distinct_from_error() {
        let raw = fmi2Status::to_raw;
        let no_log = || -> String { panic!("the log is taken on failure only") };
        assert!(check_status("a", "fmi2DoStep", raw(fmi2Status::fmi2OK), None, no_log).is_ok());
        assert!(
            check_status(
                "a",
                "fmi2DoStep",
                raw(fmi2Status::fmi2Warning),
                None,
                no_log
            )
            .is_ok()
        );
        let e = check_status(
            "a",
            "fmi2DoStep",
            raw(fmi2Status::fmi2Discard),
            Some(0.25),
            || "\n  [logError] stopped".into(),
        );
        match e {
            Err(
                ref d @ CosimError::Discarded {
                    ref component,
                    function,
                    ref at,
                    ref log,
                },
            ) => {
                assert_eq!((component.as_str(), function), ("a", "fmi2DoStep"));
                assert_eq!(at, " at t = 0.25 s");
                assert!(log.contains("stopped"));
                assert_eq!(
                    d.to_string(),
                    "a: fmi2DoStep returned fmi2Discard at t = 0.25 s: the FMU discarded the \
                     step\n  [logError] stopped"
                );
            }
            other => panic!("expected Discarded, got {other:?}"),
        }
        let e = check_status(
            "b",
            "fmi2SetReal",
            raw(fmi2Status::fmi2Discard),
            None,
            String::new,
        );
        assert_eq!(
            e.map_err(|e| e.to_string()),
            Err("b: fmi2SetReal returned fmi2Discard: the FMU discarded the call".into())
        );
        for (s, name) in [
            (raw(fmi2Status::fmi2Error), "fmi2Error"),
            (raw(fmi2Status::fmi2Fatal), "fmi2Fatal"),
            (raw(fmi2Status::fmi2Pending), "fmi2Pending"),
            (42, "an invalid status (42)"),
        ] {
            match check_status("a", "fmi2DoStep", s, None, String::new) {
                Err(CosimError::Status { status, .. }) => assert_eq!(status, name),
                other => panic!("expected Status for {name}, got {other:?}"),
            }
        }
    }
}
