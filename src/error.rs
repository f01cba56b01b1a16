//! The crate's one error type; each variant maps to one Python exception class.

use thiserror::Error;

/// Everything that can go wrong in the core, by the kind of mistake the caller made.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SabreError {
    /// An array had the wrong number of elements or the wrong layout.
    #[error("{what}: expected shape {expected}, got {got}")]
    Shape { what: String, expected: String, got: String },
    /// A value was NaN, infinite or outside its admissible range.
    #[error("{what}: {detail}")]
    InvalidValue { what: String, detail: String },
    /// A built-in robot or object name that does not exist.
    #[error("unknown {kind} '{name}'; available: {available}")]
    UnknownAsset { kind: String, name: String, available: String },
    /// A URDF that is missing, unreadable, malformed or uses unsupported features.
    #[error("URDF {source_name}: {detail}")]
    Urdf { source_name: String, detail: String },
    /// A frame (link) name that the scene does not have.
    #[error("unknown frame '{name}'; the scene has: {available}")]
    UnknownFrame { name: String, available: String },
    /// The physics engine failed or produced non-finite numbers.
    #[error("simulation failed: {0}")]
    Simulation(String),
    /// The embedding's watcher interrupted a long call (for Python: Ctrl-C).
    #[error("interrupted")]
    Interrupted,
}

pub type Result<T> = std::result::Result<T, SabreError>;

impl SabreError {
    pub fn shape(what: impl Into<String>, expected: impl Into<String>, got: impl Into<String>) -> Self {
        SabreError::Shape {
            what: what.into(),
            expected: expected.into(),
            got: got.into(),
        }
    }

    pub fn invalid(what: impl Into<String>, detail: impl Into<String>) -> Self {
        SabreError::InvalidValue {
            what: what.into(),
            detail: detail.into(),
        }
    }

    pub fn urdf(source_name: impl Into<String>, detail: impl Into<String>) -> Self {
        SabreError::Urdf {
            source_name: source_name.into(),
            detail: detail.into(),
        }
    }
}

/// Rejects NaN and infinite entries, naming the first offending index.
pub fn ensure_finite(what: &str, values: &[f64]) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(SabreError::invalid(
            what,
            format!("entry {i} is {} (values must be finite)", values[i]),
        )),
    }
}

/// The largest magnitude a joint coordinate may have (m or rad): beyond it the kinematics lose
/// every significant digit (sin and cos of 1e16 rad are noise) and overflow to NaN near 1e155.
pub const MAX_COORDINATE: f64 = 1e6;

/// Checks that every coordinate is finite and within ±[`MAX_COORDINATE`].
pub fn ensure_coordinates(what: &str, values: &[f64]) -> Result<()> {
    ensure_finite(what, values)?;
    match values.iter().position(|v| v.abs() > MAX_COORDINATE) {
        None => Ok(()),
        Some(i) => Err(SabreError::invalid(
            what,
            format!("entry {i} is {:e}, outside the model's range ±{MAX_COORDINATE:e}", values[i]),
        )),
    }
}

/// Checks that a flat buffer has exactly `expected` elements.
pub fn ensure_len(what: &str, values: &[f64], expected: usize) -> Result<()> {
    if values.len() == expected {
        Ok(())
    } else {
        Err(SabreError::shape(
            what,
            format!("({expected},)"),
            format!("({},)", values.len()),
        ))
    }
}
