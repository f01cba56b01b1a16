//! sabre: robust sampling-based control for mobile manipulators opening articulated objects — the Rust core.
//!
//! The core is plain Rust; the Python bindings live in `python` behind the `python` cargo feature.

pub mod bridge;
pub mod control;
pub mod cost;
pub mod error;
pub mod interrupt;
pub mod low_pass;
pub mod model;
pub mod mppi;
pub mod safety;
pub mod sim;
pub mod task;

#[cfg(feature = "python")]
mod python;

pub use error::{Result, SabreError};
pub use model::Scene;
