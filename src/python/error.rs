//! The error boundary of the bindings: core errors as `sabre.errors` exceptions, panics caught.

use std::cell::RefCell;
use std::panic::{catch_unwind, AssertUnwindSafe};

use pyo3::prelude::*;

use crate::error::SabreError;

// The classes are defined once, in Python (`python/sabre/errors.py`); the bindings raise those.
pyo3::import_exception!(sabre.errors, ShapeError);
pyo3::import_exception!(sabre.errors, InvalidValueError);
pyo3::import_exception!(sabre.errors, UnknownAssetError);
pyo3::import_exception!(sabre.errors, UrdfError);
pyo3::import_exception!(sabre.errors, UnknownFrameError);
pyo3::import_exception!(sabre.errors, SimulationError);

impl From<SabreError> for PyErr {
    fn from(error: SabreError) -> Self {
        let message = error.to_string();
        match error {
            SabreError::Shape { .. } => ShapeError::new_err(message),
            SabreError::InvalidValue { .. } => InvalidValueError::new_err(message),
            SabreError::UnknownAsset { .. } => UnknownAssetError::new_err(message),
            SabreError::Urdf { .. } => UrdfError::new_err(message),
            SabreError::UnknownFrame { .. } => UnknownFrameError::new_err(message),
            SabreError::Simulation(_) => SimulationError::new_err(message),
            SabreError::Interrupted => PENDING_SIGNAL
                .with(|p| p.borrow_mut().take())
                .unwrap_or_else(|| pyo3::exceptions::PyKeyboardInterrupt::new_err("interrupted")),
        }
    }
}

/// Runs `f` without the GIL; errors and panics come back as Python exceptions.
pub(crate) fn run_detached<T: Send, F: FnOnce() -> crate::Result<T> + Send>(py: Python<'_>, f: F) -> PyResult<T> {
    settle(py.detach(|| catch_unwind(AssertUnwindSafe(f))))
}

/// [`run_detached`] for cheap calls that keep the GIL.
pub(crate) fn run<T, F: FnOnce() -> crate::Result<T>>(f: F) -> PyResult<T> {
    settle(catch_unwind(AssertUnwindSafe(f)))
}

/// A panic in the core becomes a `SimulationError` naming it, so it never unwinds into Python.
fn settle<T>(outcome: std::thread::Result<crate::Result<T>>) -> PyResult<T> {
    match outcome {
        Ok(result) => result.map_err(PyErr::from),
        Err(panic) => {
            let detail = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            Err(SabreError::Simulation(format!("internal error: {detail}")).into())
        }
    }
}

thread_local! {
    /// The exception a signal handler raised while a core call ran (e.g. KeyboardInterrupt),
    /// re-raised when the call returns `SabreError::Interrupted`.
    static PENDING_SIGNAL: RefCell<Option<PyErr>> = const { RefCell::new(None) };
}

/// Lets Ctrl-C interrupt long core calls made from Python's main thread: the core polls this
/// watcher, which runs Python's signal handlers (re-acquiring the GIL for that moment).
struct SignalWatcher {
    main: std::thread::ThreadId,
}

impl crate::interrupt::Watcher for SignalWatcher {
    fn watches_current_thread(&self) -> bool {
        std::thread::current().id() == self.main
    }

    fn interrupted(&self) -> bool {
        Python::attach(|py| match py.check_signals() {
            Ok(()) => false,
            Err(e) => {
                PENDING_SIGNAL.with(|p| *p.borrow_mut() = Some(e));
                true
            }
        })
    }
}

/// Installs the [`SignalWatcher`] if the module is imported on Python's main thread.
pub(crate) fn watch_signals(py: Python<'_>) -> PyResult<()> {
    let threading = py.import("threading")?;
    let main = threading.call_method0("main_thread")?.getattr("ident")?;
    let current = threading.call_method0("get_ident")?;
    if main.eq(current)? {
        crate::interrupt::install(Box::new(SignalWatcher {
            main: std::thread::current().id(),
        }));
    }
    Ok(())
}
