//! The logger passed to FMUs: the C shim (csrc/logger.c) formats the variadic message and calls
//! [`m1cs_cosim_log_sink`], which stores it in the instance's [`LogSink`] and, for warnings and
//! errors (or everything when verbose), prints it to stderr.

use std::ffi::{CStr, c_char, c_int, c_void};
use std::sync::Mutex;

use fmi_sys::fmi2::enums::fmi2Status;
use fmi_sys::fmi2::types::{fmi2ComponentEnvironment, fmi2String};

unsafe extern "C" {
    /// The variadic logger (csrc/logger.c).
    pub(crate) fn m1cs_cosim_logger(
        env: fmi2ComponentEnvironment,
        instance: fmi2String,
        status: fmi2Status,
        category: fmi2String,
        message: fmi2String,
        ...
    );
}

/// One logged message.
#[derive(Debug, Clone, PartialEq)]
pub struct LogMessage {
    /// fmi2Status as an integer (0 OK .. 4 Fatal).
    pub status: i32,
    /// The category.
    pub category: String,
    /// The formatted message.
    pub message: String,
}

/// Where an instance's messages go (the FMU's componentEnvironment points at it).
#[derive(Debug, Default)]
pub struct LogSink {
    messages: Mutex<Vec<LogMessage>>,
    /// Print every message to stderr (else only warnings and worse).
    pub verbose: bool,
}

/// Most messages kept per instance (older ones are dropped).
const KEEP: usize = 200;

impl LogSink {
    /// A sink; `verbose` prints every message, not only warnings and errors.
    pub fn new(verbose: bool) -> Self {
        Self {
            messages: Mutex::new(Vec::new()),
            verbose,
        }
    }

    /// Takes the messages logged so far.
    pub fn take(&self) -> Vec<LogMessage> {
        self.messages
            .lock()
            .map(|mut m| std::mem::take(&mut *m))
            .unwrap_or_default()
    }

    /// The messages joined as ": msg1; msg2" (empty if none), and cleared.
    pub fn drain_text(&self) -> String {
        let m = self.take();
        if m.is_empty() {
            String::new()
        } else {
            format!(
                ": {}",
                m.iter()
                    .map(|x| x.message.as_str())
                    .collect::<Vec<_>>()
                    .join("; ")
            )
        }
    }

    fn push(&self, m: LogMessage) {
        if let Ok(mut v) = self.messages.lock() {
            if v.len() >= KEEP {
                v.remove(0);
            }
            v.push(m);
        }
    }
}

fn text(p: *const c_char) -> String {
    if p.is_null() {
        String::new()
    } else {
        // SAFETY: the FMU passes NUL-terminated strings valid for the call.
        unsafe { CStr::from_ptr(p) }.to_string_lossy().into_owned()
    }
}

/// Called by the C shim with the formatted message.
#[unsafe(no_mangle)]
pub extern "C" fn m1cs_cosim_log_sink(
    env: *mut c_void,
    instance: *const c_char,
    status: c_int,
    category: *const c_char,
    message: *const c_char,
) {
    let _ = std::panic::catch_unwind(|| {
        let m = LogMessage {
            status,
            category: text(category),
            message: text(message),
        };
        if env.is_null() {
            eprintln!("[{}] {}", text(instance), m.message);
            return;
        }
        // SAFETY: env is the LogSink boxed by the instance, alive until fmi2FreeInstance.
        let sink = unsafe { &*(env as *const LogSink) };
        if sink.verbose || status >= 1 {
            eprintln!("[{} {}] {}", text(instance), m.category, m.message);
        }
        sink.push(m);
    });
}

/// calloc for the FMU.
pub(crate) extern "C" fn allocate(n: usize, size: usize) -> *mut c_void {
    // SAFETY: plain libc calloc.
    unsafe { libc::calloc(n, size) }
}

/// free for the FMU.
pub(crate) extern "C" fn free(p: *mut c_void) {
    // SAFETY: p came from `allocate` (or is null).
    unsafe { libc::free(p) }
}
