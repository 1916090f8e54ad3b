//! Shared by the integration tests of the `fmu` runtime: a small test model (a first-order lag
//! per element), an in-process FMI "importer" that drives the generic C shims of
//! [`fmu::ffi`] directly, a logger that captures the messages per instance, and a reader for
//! the generated modelDescription.xml.
//!
//! Every test binary includes this module, and none uses all of it.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::BTreeMap;
use std::ffi::{CStr, CString, c_char, c_int, c_void};
use std::sync::Mutex;

use fmu::fmi_sys::fmi2::*;
use fmu::{
    BoolVar, Check, Dependencies, FmuError, IntVar, Model, ModelInfo, RealVar, Running, StrVar,
    TableBuilder, Values, VariableTable, ffi,
};
use quick_xml::events::{BytesStart, Event};
use serde::{Deserialize, Serialize};

// ---------------------------------------------------------------------------------------------
// The test model
// ---------------------------------------------------------------------------------------------

/// The start value of the String parameter `label`: every character XML must escape.
pub const LABEL_START: &str = r#"lag <"1st order"> & 'friends'"#;

/// Array length of each variant. "tiny" is accepted by `Lag::new` but not listed by
/// `Lag::variants()`: it can only be found through `resources/variant.txt`.
pub fn variant_len(variant: &str) -> Option<usize> {
    match variant {
        "small" => Some(3),
        "big" => Some(5),
        "tiny" => Some(2),
        _ => None,
    }
}

/// Knobs to build slightly different tables (GUID tests).
#[derive(Debug, Clone, Copy)]
pub struct Options {
    /// Start value of `tau`.
    pub tau_start: f64,
    /// Declare one more parameter, `extra`.
    pub extra: bool,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            tau_start: 0.5,
            extra: false,
        }
    }
}

/// The handles of every variable of [`Lag`].
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct Vars {
    pub tau: RealVar,
    pub n: IntVar,
    pub gain: RealVar,
    pub enabled: BoolVar,
    pub y0: RealVar,
    pub bias: RealVar,
    pub panic_at: RealVar,
    pub substeps: IntVar,
    pub layout: StrVar,
    pub label: StrVar,
    pub u: RealVar,
    pub y: RealVar,
    pub yd: RealVar,
    pub total: RealVar,
    pub corner: RealVar,
    pub steps: IntVar,
}

/// The variable table of a variant. Types are declared interleaved on purpose, so that the
/// order in ModelVariables differs from the value-reference order (Reals first).
pub fn lag_table(variant: &str, opts: Options) -> Result<(VariableTable, Vars), FmuError> {
    let n = variant_len(variant)
        .ok_or_else(|| FmuError::Instantiate(format!("unknown variant {variant}")))?;
    type T = TableBuilder;
    let mut b = TableBuilder::new();
    let tau = b.add_real(
        T::real("tau")
            .parameter()
            .unit("s")
            .start(opts.tau_start)
            .positive()
            .describe("Time constant"),
    );
    let n_var = b.add_integer(
        T::integer("n")
            .structural()
            .start_int(n as i32)
            .describe("Number of elements"),
    );
    let gain = b.add_real(
        T::real("gain")
            .parameter()
            .unit("1")
            .start(2.0)
            .describe("Feed-through gain of yd"),
    );
    let enabled = b.add_boolean(
        T::boolean("enabled")
            .parameter()
            .start_bool(true)
            .describe("Integrate (false: hold y)"),
    );
    let y0 = b.add_real(
        T::real("y0")
            .parameter()
            .unit("m")
            .start(0.1)
            .describe("Initial state"),
    );
    let bias = b.add_real(
        T::real("bias")
            .tunable()
            .unit("m")
            .start(0.0)
            .describe("Offset added to yd"),
    );
    let panic_at = b.add_real(
        T::real("panic_at")
            .parameter()
            .unit("s")
            .start(0.0)
            .non_negative()
            .describe("> 0: do_step panics when the step would go past this time"),
    );
    let substeps = b.add_integer(
        T::integer("substeps")
            .parameter()
            .start_int(4)
            .positive()
            .describe("Exact sub-steps per communication step"),
    );
    let layout = b.add_string(T::string("layout").structural().start_str(variant));
    let label = b.add_string(T::string("label").parameter().start_str(LABEL_START));
    let u = b.add_real(
        T::real("u")
            .input()
            .len(n)
            .unit("m")
            .start(0.25)
            .check(Check::Range(-1000.0, 1000.0))
            .describe("Input"),
    );
    let y = b.add_real(
        T::real("y")
            .output()
            .len(n)
            .unit("m")
            .depends(Dependencies::None)
            .describe("State"),
    );
    let yd = b.add_real(
        T::real("yd")
            .output()
            .len(n)
            .unit("m")
            .depends(Dependencies::Elementwise("u".into()))
            .describe("y + gain u + bias"),
    );
    let total = b.add_real(
        T::real("total")
            .output()
            .unit("m")
            .describe("Sum of the states"),
    );
    let corner = b.add_real(
        T::real("corner")
            .calculated_parameter()
            .unit("Hz")
            .describe("1 / (2 pi tau)"),
    );
    let steps = b.add_integer(T::integer("steps").output().describe("Steps taken"));
    if opts.extra {
        b.add_real(T::real("extra").parameter().start(1.0));
    }
    let vars = Vars {
        tau,
        n: n_var,
        gain,
        enabled,
        y0,
        bias,
        panic_at,
        substeps,
        layout,
        label,
        u,
        y,
        yd,
        total,
        corner,
        steps,
    };
    Ok((b.build()?, vars))
}

/// y' = (u - y) / tau per element, integrated exactly over `substeps` sub-intervals; outputs
/// `y`, `yd = y + gain u + bias` (direct feed-through), `total = sum y` and the step count.
/// As configured: the handles and the length; [`LagRunning`] steps.
#[derive(Debug, Clone)]
pub struct Lag {
    vars: Vars,
    n: usize,
}

/// The initialised [`Lag`].
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LagRunning {
    vars: Vars,
    y: Vec<f64>,
    tau: f64,
    gain: f64,
    enabled: bool,
    substeps: i32,
    steps: i32,
}

impl LagRunning {
    fn write(&self, v: &mut Values) {
        let vars = self.vars;
        let bias = v.scalar(vars.bias);
        let u = v.real(vars.u).to_vec();
        v.real_mut(vars.y).copy_from_slice(&self.y);
        for (i, yd) in v.real_mut(vars.yd).iter_mut().enumerate() {
            *yd = self.y[i] + self.gain * u[i] + bias;
        }
        v.real_mut(vars.total)[0] = self.y.iter().sum();
        v.integers[vars.steps.slot] = self.steps;
    }
}

impl Model for Lag {
    const INFO: ModelInfo = ModelInfo {
        model_identifier: "lag_test",
        model_name: "First-order lag (fmu runtime tests)",
        description: "y' = (u - y)/tau per element",
        documentation: "<p>y' = (u - y)/tau</p>",
        default_stop_time: 1.0,
        default_step: 0.01,
    };

    type Running = LagRunning;

    fn variants() -> Vec<String> {
        vec!["small".into(), "big".into()]
    }

    fn new(variant: &str) -> Result<(VariableTable, Self), FmuError> {
        let (table, vars) = lag_table(variant, Options::default())?;
        let n = vars.u.len;
        Ok((table, Self { vars, n }))
    }

    fn initialize(&self, v: &mut Values, _start_time: f64) -> Result<LagRunning, FmuError> {
        let vars = self.vars;
        let running = LagRunning {
            vars,
            tau: v.scalar(vars.tau),
            gain: v.scalar(vars.gain),
            enabled: v.boolean(vars.enabled),
            substeps: v.integer(vars.substeps),
            y: vec![v.scalar(vars.y0); self.n],
            steps: 0,
        };
        v.real_mut(vars.corner)[0] = 1.0 / (2.0 * std::f64::consts::PI * running.tau);
        running.write(v);
        Ok(running)
    }
}

impl Running for LagRunning {
    fn update_outputs(&mut self, v: &mut Values) -> Result<(), FmuError> {
        self.write(v);
        Ok(())
    }

    fn do_step(&mut self, t: f64, h: f64, v: &mut Values) -> Result<(), FmuError> {
        let vars = self.vars;
        let panic_at = v.scalar(vars.panic_at);
        if panic_at > 0.0 && t + h > panic_at {
            panic!("lag_test: deliberate failure in do_step from t = {t}");
        }
        if self.enabled {
            let dt = h / f64::from(self.substeps);
            let a = (-dt / self.tau).exp();
            let u = v.real(vars.u);
            for _ in 0..self.substeps {
                for (y, u) in self.y.iter_mut().zip(u) {
                    *y = u + (*y - u) * a;
                }
            }
        }
        self.steps += 1;
        self.write(v);
        Ok(())
    }
}

/// The description of a variant (table, GUID, XML).
pub fn describe(variant: &str) -> fmu::package::Description {
    fmu::package::describe::<Lag>(variant).expect("describe")
}

/// The value reference of scalar `i` (0-based) of the variable `name`.
pub fn vr(table: &VariableTable, name: &str, i: usize) -> u32 {
    let v = table
        .by_name(name)
        .unwrap_or_else(|| panic!("no variable {name}"));
    assert!(i < v.len, "{name}[{i}] out of range");
    v.vr + i as u32
}

/// The value references of every scalar of `name`.
pub fn vrs(table: &VariableTable, name: &str) -> Vec<u32> {
    let v = table
        .by_name(name)
        .unwrap_or_else(|| panic!("no variable {name}"));
    (0..v.len as u32).map(|i| v.vr + i).collect()
}

// ---------------------------------------------------------------------------------------------
// The logger
// ---------------------------------------------------------------------------------------------

/// One message received by the logger.
#[derive(Debug, Clone, PartialEq)]
pub struct Entry {
    pub instance: String,
    pub status: c_int,
    pub category: String,
    pub message: String,
}

/// The messages of one instance (the componentEnvironment of its callbacks).
#[derive(Debug, Default)]
pub struct Log {
    entries: Mutex<Vec<Entry>>,
}

impl Log {
    pub fn entries(&self) -> Vec<Entry> {
        self.entries.lock().unwrap().clone()
    }
    pub fn take(&self) -> Vec<Entry> {
        std::mem::take(&mut *self.entries.lock().unwrap())
    }
    /// Every message, one per line (for assertion messages).
    pub fn dump(&self) -> String {
        self.entries()
            .iter()
            .map(|e| format!("[{} {} {}] {}", e.instance, e.status, e.category, e.message))
            .collect::<Vec<_>>()
            .join("\n")
    }
}

unsafe fn text(p: *const c_char) -> String {
    if p.is_null() {
        "<NULL>".into()
    } else {
        // SAFETY: a C string from the FMU.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}

/// The logger, declared without the C variadic part. The FMU always logs with the format "%s"
/// and the message as the one variadic argument, which the x86_64 System V ABI passes exactly
/// like a sixth fixed pointer argument (in r9).
unsafe extern "C" fn capture(
    env: *mut c_void,
    instance: *const c_char,
    status: c_int,
    category: *const c_char,
    format: *const c_char,
    arg: *const c_char,
) {
    // SAFETY: `env` is the `Log` of the `Fmu` that owns the instance (it outlives it), and the
    // strings are C strings from the FMU.
    unsafe {
        let log = &*(env as *const Log);
        let format = text(format);
        let message = if format == "%s" {
            text(arg)
        } else {
            format!("<format {format}>")
        };
        let e = Entry {
            instance: text(instance),
            status,
            category: text(category),
            message,
        };
        log.entries.lock().unwrap().push(e);
    }
}

type Variadic = unsafe extern "C" fn(
    fmi2ComponentEnvironment,
    fmi2String,
    fmi2Status,
    fmi2String,
    fmi2String,
    ...
);

fn logger() -> fmi2CallbackLogger {
    type Fixed = unsafe extern "C" fn(
        *mut c_void,
        *const c_char,
        c_int,
        *const c_char,
        *const c_char,
        *const c_char,
    );
    let f: Fixed = capture;
    // SAFETY: same size (function pointers); the calling convention argument above explains
    // why calling it through the variadic type is sound on x86_64 Linux.
    Some(unsafe { std::mem::transmute::<Fixed, Variadic>(f) })
}

// ---------------------------------------------------------------------------------------------
// The importer
// ---------------------------------------------------------------------------------------------

/// An instance of [`Lag`] created through `ffi::instantiate`, freed on drop.
pub struct Fmu {
    pub c: fmi2Component,
    pub log: Box<Log>,
}

// SAFETY: the instance is only used through `&mut self`/`&self` of one owner at a time, the
// model is `Send` and the log is behind a mutex.
unsafe impl Send for Fmu {}

impl Drop for Fmu {
    fn drop(&mut self) {
        ffi::free_instance::<Lag>(self.c);
    }
}

pub const OK: fmi2Status = fmi2Status::fmi2OK;
pub const ERROR: fmi2Status = fmi2Status::fmi2Error;
pub const FATAL: fmi2Status = fmi2Status::fmi2Fatal;

/// fmi2Instantiate through the generic shim; on NULL, the log of the failed attempt.
pub fn instantiate(
    name: &str,
    guid: &str,
    resources: Option<&str>,
    logging_on: bool,
) -> Result<Fmu, Box<Log>> {
    let log = Box::new(Log::default());
    let callbacks = fmi2CallbackFunctions {
        logger: logger(),
        allocateMemory: None,
        freeMemory: None,
        stepFinished: None,
        componentEnvironment: &*log as *const Log as *mut c_void,
    };
    let name = CString::new(name).unwrap();
    let guid = CString::new(guid).unwrap();
    let res = resources.map(|r| CString::new(r).unwrap());
    // SAFETY: valid C strings or NULL, a valid callbacks struct.
    let c = unsafe {
        ffi::instantiate::<Lag>(
            name.as_ptr(),
            fmi2Type::fmi2CoSimulation as c_int,
            guid.as_ptr(),
            res.as_ref().map_or(std::ptr::null(), |r| r.as_ptr()),
            &callbacks,
            fmi2False,
            c_int::from(logging_on),
        )
    };
    if c.is_null() {
        Err(log)
    } else {
        Ok(Fmu { c, log })
    }
}

/// Instantiates a variant by its own GUID (NULL resource location: all variants are tried).
pub fn open(variant: &str) -> Fmu {
    let d = describe(variant);
    instantiate(variant, &d.guid, None, false)
        .unwrap_or_else(|log| panic!("instantiate {variant}: {}", log.dump()))
}

impl Fmu {
    pub fn setup(&mut self, start: f64, stop: Option<f64>) -> fmi2Status {
        ffi::setup_experiment::<Lag>(
            self.c,
            fmi2False,
            0.0,
            start,
            c_int::from(stop.is_some()),
            stop.unwrap_or(0.0),
        )
    }
    pub fn enter_init(&mut self) -> fmi2Status {
        ffi::enter_initialization_mode::<Lag>(self.c)
    }
    pub fn exit_init(&mut self) -> fmi2Status {
        ffi::exit_initialization_mode::<Lag>(self.c)
    }
    /// setup (t = 0), enter and exit initialisation mode, all asserted OK.
    pub fn init(&mut self) {
        assert_eq!(self.setup(0.0, None), OK, "{}", self.log.dump());
        assert_eq!(self.enter_init(), OK, "{}", self.log.dump());
        assert_eq!(self.exit_init(), OK, "{}", self.log.dump());
    }
    pub fn step(&mut self, t: f64, h: f64) -> fmi2Status {
        ffi::do_step::<Lag>(self.c, t, h, fmi2True)
    }
    pub fn terminate(&mut self) -> fmi2Status {
        ffi::terminate::<Lag>(self.c)
    }
    pub fn reset(&mut self) -> fmi2Status {
        ffi::reset::<Lag>(self.c)
    }

    pub fn get_real(&mut self, vrs: &[u32]) -> Result<Vec<f64>, fmi2Status> {
        let mut out = vec![f64::NAN; vrs.len()];
        // SAFETY: arrays of vrs.len() elements.
        let s = unsafe { ffi::get_real::<Lag>(self.c, vrs.as_ptr(), vrs.len(), out.as_mut_ptr()) };
        if s == OK { Ok(out) } else { Err(s) }
    }
    pub fn get_integer(&mut self, vrs: &[u32]) -> Result<Vec<i32>, fmi2Status> {
        let mut out = vec![i32::MIN; vrs.len()];
        // SAFETY: arrays of vrs.len() elements.
        let s =
            unsafe { ffi::get_integer::<Lag>(self.c, vrs.as_ptr(), vrs.len(), out.as_mut_ptr()) };
        if s == OK { Ok(out) } else { Err(s) }
    }
    pub fn get_boolean(&mut self, vrs: &[u32]) -> Result<Vec<bool>, fmi2Status> {
        let mut out: Vec<fmi2Boolean> = vec![-1; vrs.len()];
        // SAFETY: arrays of vrs.len() elements.
        let s =
            unsafe { ffi::get_boolean::<Lag>(self.c, vrs.as_ptr(), vrs.len(), out.as_mut_ptr()) };
        if s != OK {
            return Err(s);
        }
        Ok(out
            .into_iter()
            .map(|b| {
                assert!(b == fmi2True || b == fmi2False, "fmi2Boolean {b}");
                b == fmi2True
            })
            .collect())
    }
    pub fn get_string(&mut self, vrs: &[u32]) -> Result<Vec<String>, fmi2Status> {
        let mut out: Vec<fmi2String> = vec![std::ptr::null(); vrs.len()];
        // SAFETY: arrays of vrs.len() elements.
        let s =
            unsafe { ffi::get_string::<Lag>(self.c, vrs.as_ptr(), vrs.len(), out.as_mut_ptr()) };
        if s != OK {
            return Err(s);
        }
        Ok(out
            .into_iter()
            .map(|p| {
                assert!(!p.is_null(), "fmi2GetString gave NULL");
                // SAFETY: a C string owned by the instance, valid until the next set/free.
                unsafe { CStr::from_ptr(p) }.to_str().unwrap().to_string()
            })
            .collect())
    }
    pub fn get_reals_of(&mut self, table: &VariableTable, name: &str) -> Vec<f64> {
        self.get_real(&vrs(table, name))
            .unwrap_or_else(|s| panic!("get {name}: {s:?}\n{}", self.log.dump()))
    }

    pub fn set_real(&mut self, vrs: &[u32], vals: &[f64]) -> fmi2Status {
        assert_eq!(vrs.len(), vals.len());
        // SAFETY: arrays of vrs.len() elements.
        unsafe { ffi::set_real::<Lag>(self.c, vrs.as_ptr(), vrs.len(), vals.as_ptr()) }
    }
    pub fn set_integer(&mut self, vrs: &[u32], vals: &[i32]) -> fmi2Status {
        assert_eq!(vrs.len(), vals.len());
        // SAFETY: arrays of vrs.len() elements.
        unsafe { ffi::set_integer::<Lag>(self.c, vrs.as_ptr(), vrs.len(), vals.as_ptr()) }
    }
    pub fn set_boolean(&mut self, vrs: &[u32], vals: &[bool]) -> fmi2Status {
        assert_eq!(vrs.len(), vals.len());
        let b: Vec<fmi2Boolean> = vals.iter().map(|&x| c_int::from(x)).collect();
        // SAFETY: arrays of vrs.len() elements.
        unsafe { ffi::set_boolean::<Lag>(self.c, vrs.as_ptr(), vrs.len(), b.as_ptr()) }
    }
    pub fn set_string(&mut self, vrs: &[u32], vals: &[&str]) -> fmi2Status {
        assert_eq!(vrs.len(), vals.len());
        let owned: Vec<CString> = vals.iter().map(|s| CString::new(*s).unwrap()).collect();
        let ptrs: Vec<fmi2String> = owned.iter().map(|s| s.as_ptr()).collect();
        // SAFETY: arrays of vrs.len() elements, valid C strings.
        unsafe { ffi::set_string::<Lag>(self.c, vrs.as_ptr(), vrs.len(), ptrs.as_ptr()) }
    }

    /// fmi2GetRealStatus(fmi2LastSuccessfulTime).
    pub fn last_time(&mut self) -> f64 {
        let mut t = f64::NAN;
        // SAFETY: a writable f64.
        let s = unsafe {
            ffi::get_real_status::<Lag>(
                self.c,
                fmi2StatusKind::fmi2LastSuccessfulTime as c_int,
                &mut t,
            )
        };
        assert_eq!(s, OK, "{}", self.log.dump());
        t
    }

    /// fmi2GetFMUstate into `slot` (NULL: allocate).
    pub fn get_state(&mut self, slot: &mut fmi2FMUstate) -> fmi2Status {
        // SAFETY: a valid slot holding NULL or a state of this FMU.
        unsafe { ffi::get_fmu_state::<Lag>(self.c, slot) }
    }
    pub fn set_state(&mut self, s: fmi2FMUstate) -> fmi2Status {
        // SAFETY: a state of this FMU (or NULL).
        unsafe { ffi::set_fmu_state::<Lag>(self.c, s) }
    }
    pub fn free_state(&mut self, slot: &mut fmi2FMUstate) -> fmi2Status {
        // SAFETY: a valid slot holding NULL or a state of this FMU.
        unsafe { ffi::free_fmu_state::<Lag>(self.c, slot) }
    }
    /// fmi2SerializedFMUstateSize + fmi2SerializeFMUstate.
    pub fn serialize(&mut self, s: fmi2FMUstate) -> Result<Vec<u8>, fmi2Status> {
        let mut n = 0usize;
        // SAFETY: a state of this FMU; a writable size.
        let st = unsafe { ffi::serialized_size::<Lag>(self.c, s, &mut n) };
        if st != OK {
            return Err(st);
        }
        let mut buf = vec![0u8; n];
        // SAFETY: a buffer of n bytes.
        let st = unsafe { ffi::serialize::<Lag>(self.c, s, buf.as_mut_ptr() as *mut fmi2Byte, n) };
        if st == OK { Ok(buf) } else { Err(st) }
    }
    /// fmi2DeSerializeFMUstate into `slot`.
    pub fn deserialize(&mut self, bytes: &[u8], slot: &mut fmi2FMUstate) -> fmi2Status {
        // SAFETY: `bytes.len()` readable bytes; a valid slot.
        unsafe {
            ffi::deserialize::<Lag>(self.c, bytes.as_ptr() as *const fmi2Byte, bytes.len(), slot)
        }
    }

    /// Whether some logged message contains every one of `parts`.
    pub fn logged(&self, parts: &[&str]) -> bool {
        self.log
            .entries()
            .iter()
            .any(|e| parts.iter().all(|p| e.message.contains(p)))
    }
}

// ---------------------------------------------------------------------------------------------
// modelDescription.xml, read back
// ---------------------------------------------------------------------------------------------

/// One ScalarVariable as written in the XML.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct XmlScalar {
    pub name: String,
    pub vr: u32,
    pub description: Option<String>,
    pub causality: String,
    pub variability: String,
    pub initial: Option<String>,
    /// Real, Integer, Boolean or String.
    pub ty: String,
    pub unit: Option<String>,
    pub start: Option<String>,
}

/// The parts of modelDescription.xml the tests look at.
#[derive(Debug, Clone, Default)]
pub struct ParsedXml {
    pub attrs: BTreeMap<String, String>,
    pub cosim: BTreeMap<String, String>,
    /// (name, base-unit exponents).
    pub units: Vec<(String, BTreeMap<String, i32>)>,
    pub log_categories: Vec<String>,
    pub scalars: Vec<XmlScalar>,
    /// (1-based index, dependencies attribute).
    pub outputs: Vec<(usize, Option<String>)>,
    pub initial_unknowns: Vec<(usize, Option<String>)>,
    /// Elements seen, in document order, as paths ("fmiModelDescription/ModelVariables/...").
    pub paths: Vec<String>,
}

fn attributes(e: &BytesStart) -> BTreeMap<String, String> {
    let mut m = BTreeMap::new();
    for a in e.attributes() {
        let a = a.expect("well-formed attribute");
        let key: &str = a.key.as_ref();
        let value = a
            .normalized_value(quick_xml::XmlVersion::Explicit1_0)
            .expect("attribute value")
            .into_owned();
        assert!(
            m.insert(key.to_string(), value).is_none(),
            "duplicate attribute {key}"
        );
    }
    m
}

/// Parses modelDescription.xml (panics on malformed XML).
pub fn parse_xml(xml: &str) -> ParsedXml {
    let mut reader = quick_xml::Reader::from_str(xml);
    let mut out = ParsedXml::default();
    let mut stack: Vec<String> = Vec::new();
    let mut saw_decl = false;
    loop {
        let ev = reader.read_event().expect("well-formed XML");
        let (e, opens) = match &ev {
            Event::Start(e) => (e, true),
            Event::Empty(e) => (e, false),
            Event::End(_) => {
                stack.pop().expect("balanced tags");
                continue;
            }
            Event::Decl(_) => {
                saw_decl = true;
                continue;
            }
            Event::Eof => break,
            _ => continue,
        };
        let qname = e.name();
        let name: &str = qname.as_ref();
        let name = name.to_string();
        let a = attributes(e);
        let parent = stack.last().map(String::as_str);
        let mut path = stack.join("/");
        if !path.is_empty() {
            path.push('/');
        }
        path.push_str(&name);
        out.paths.push(path);
        match (parent, name.as_str()) {
            (None, "fmiModelDescription") => out.attrs = a,
            (Some("fmiModelDescription"), "CoSimulation") => out.cosim = a,
            (Some("UnitDefinitions"), "Unit") => {
                out.units.push((a["name"].clone(), BTreeMap::new()))
            }
            (Some("Unit"), "BaseUnit") => {
                let u = out.units.last_mut().expect("BaseUnit inside Unit");
                for (k, v) in a {
                    u.1.insert(k, v.parse().expect("integer exponent"));
                }
            }
            (Some("LogCategories"), "Category") => out.log_categories.push(a["name"].clone()),
            (Some("ModelVariables"), "ScalarVariable") => out.scalars.push(XmlScalar {
                name: a["name"].clone(),
                vr: a["valueReference"].parse().expect("valueReference"),
                description: a.get("description").cloned(),
                causality: a
                    .get("causality")
                    .cloned()
                    .unwrap_or_else(|| "local".into()),
                variability: a
                    .get("variability")
                    .cloned()
                    .unwrap_or_else(|| "continuous".into()),
                initial: a.get("initial").cloned(),
                ..XmlScalar::default()
            }),
            (Some("ScalarVariable"), ty @ ("Real" | "Integer" | "Boolean" | "String")) => {
                let s = out.scalars.last_mut().expect("type inside ScalarVariable");
                assert!(s.ty.is_empty(), "{}: two type elements", s.name);
                s.ty = ty.to_string();
                s.unit = a.get("unit").cloned();
                s.start = a.get("start").cloned();
            }
            (Some("Outputs"), "Unknown") => out.outputs.push((
                a["index"].parse().expect("index"),
                a.get("dependencies").cloned(),
            )),
            (Some("InitialUnknowns"), "Unknown") => out.initial_unknowns.push((
                a["index"].parse().expect("index"),
                a.get("dependencies").cloned(),
            )),
            _ => {}
        }
        if opens {
            stack.push(name);
        }
    }
    assert!(stack.is_empty(), "unclosed elements {stack:?}");
    assert!(saw_decl, "no XML declaration");
    out
}
