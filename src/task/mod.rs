//! The shipped tasks' per-iteration logic in the core: the open-object task's handle geometry, phase
//! switch, noise schedule and guides (the task itself, its phases and costs, is Python's `sabre.tasks`).

pub mod handle;
pub mod handle_fit;
pub mod open_object;
mod self_opening;

pub use handle::{HandAtHandle, HandleGeometry, ReleaseMove};
pub use handle_fit::{HandleClearance, HandleFit};
pub use open_object::{OpenObjectConfig, OpenObjectRules, OpenPhase};
