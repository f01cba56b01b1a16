//! PyO3 bindings (`sabre._core`): one submodule per domain of the core; this file only registers.
//!
//! Every call into the core goes through [`error::run`] or [`error::run_detached`] (the GIL
//! released around long calls), so core errors arrive as `sabre.errors` exceptions and a panic
//! never crosses into Python. Config objects (`RolloutConfig()`, `MppiConfig()`, …) hold the
//! core's defaults: Python reads its defaults from them.

mod articulation;
mod bridge;
mod bridge_tick;
mod cascade;
mod control;
mod convert;
mod cost;
mod error;
mod estimation;
mod low_pass;
mod messages;
mod mppi;
mod rate_limit;
mod robot;
mod safety;
mod scene;
mod sim;
mod sim_driver;
mod task;

use pyo3::prelude::*;
use pyo3::types::PyModule;

/// Number of worker threads used when `threads=None`.
#[pyfunction]
fn default_threads() -> usize {
    crate::sim::default_threads()
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    error::watch_signals(m.py())?;
    // Loads NumPy's C API now: its first load runs Python code, and a Ctrl-C landing there during an
    // argument's conversion would panic in rust-numpy, outside the calls that turn panics into errors.
    numpy::PyArray1::<f64>::from_slice(m.py(), &[]);
    m.add_class::<scene::PyScene>()?;
    m.add_class::<sim::PyRolloutConfig>()?;
    m.add_class::<sim::PyRolloutModel>()?;
    m.add_class::<sim::PyRolloutResult>()?;
    m.add_class::<sim::PyPlantConfig>()?;
    m.add_class::<sim::PyPlant>()?;
    m.add_class::<control::PyLowLevelConfig>()?;
    m.add_class::<control::PyLowLevelController>()?;
    m.add_class::<control::PyPlan>()?;
    m.add_class::<cascade::PyCascade>()?;
    m.add_class::<low_pass::PyLowPass>()?;
    m.add_function(wrap_pyfunction!(low_pass::low_pass_blend, m)?)?;
    m.add_class::<rate_limit::PyRateLimiter>()?;
    m.add_class::<bridge::PyCommandGate>()?;
    m.add_class::<sim_driver::PySimDriver>()?;
    m.add_class::<sim_driver::PyFrankaReflexes>()?;
    m.add_function(wrap_pyfunction!(sim_driver::rcl_function_names, m)?)?;
    m.add_function(wrap_pyfunction!(sim_driver::rcl_built_against, m)?)?;
    m.add_class::<bridge::PyJointMerge>()?;
    m.add_class::<bridge_tick::PyBridgeTick>()?;
    m.add_class::<bridge_tick::PyWrenchFrames>()?;
    m.add_class::<estimation::PyObjectStateEstimator>()?;
    m.add_class::<articulation::PyArticulationConfig>()?;
    m.add_class::<articulation::PyArticulationEstimator>()?;
    m.add_class::<cost::PyCost>()?;
    m.add_class::<mppi::PyMppiConfig>()?;
    m.add_class::<mppi::PyServoGuideConfig>()?;
    m.add_class::<mppi::PyServoGuidePlan>()?;
    m.add_class::<mppi::PyPlanner>()?;
    m.add_class::<safety::PySafetyConfig>()?;
    m.add_class::<safety::PyLimitBoundConfig>()?;
    m.add_class::<safety::PySafetyFilter>()?;
    m.add_class::<safety::PyFilterResult>()?;
    m.add_class::<safety::PyEnergyTankConfig>()?;
    m.add_class::<safety::PyEnergyTank>()?;
    m.add_class::<safety::PyTankRefillConfig>()?;
    m.add_class::<task::PyOpenObjectConfig>()?;
    m.add_class::<task::PyHandleGeometry>()?;
    m.add_class::<task::PyOpenObjectRules>()?;
    m.add_function(wrap_pyfunction!(default_threads, m)?)?;
    m.add_function(wrap_pyfunction!(scene::builtin_urdf, m)?)?;
    m.add_function(wrap_pyfunction!(mppi::likelihood_weights, m)?)?;
    m.add_function(wrap_pyfunction!(mppi::servo_guide, m)?)?;
    m.add_function(wrap_pyfunction!(mppi::servo_guide_plan, m)?)?;
    m.add_function(wrap_pyfunction!(robot::mesh_triangles, m)?)?;
    m.add_function(wrap_pyfunction!(messages::decode_joint_state, m)?)?;
    m.add_function(wrap_pyfunction!(messages::encode_joint_state, m)?)?;
    m.add_function(wrap_pyfunction!(messages::decode_float64_array, m)?)?;
    m.add_function(wrap_pyfunction!(messages::encode_float64_array, m)?)?;
    m.add_function(wrap_pyfunction!(messages::decode_twist, m)?)?;
    m.add_function(wrap_pyfunction!(messages::encode_twist, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("DEFAULT_TAU_EXT_CUTOFF", crate::sim::DEFAULT_TAU_EXT_CUTOFF)?;
    m.add("TAKEOVER_TOLERANCE", crate::control::cascade::TAKEOVER_TOLERANCE)?;
    let contact_models: Vec<&str> = crate::sim::ContactModel::ALL.iter().map(|m| m.name()).collect();
    m.add("CONTACT_MODELS", pyo3::types::PyTuple::new(m.py(), contact_models)?)?;
    Ok(())
}
