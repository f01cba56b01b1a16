//! The engine clock: how many steps went through a world's contact engine and the wall time they
//! took, for both contact paths.

/// Work done inside a world's contact engine since it was built (Rapier's `PhysicsPipeline::step`,
/// or the reduced path's detection, solve and integration): what the physics itself costs, apart
/// from sabre's servo, interaction and cost work around it.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct EngineClock {
    /// Steps that went through the engine (steps skipped as quiescent are not counted).
    pub steps: u64,
    /// Wall time spent inside those steps (s).
    pub seconds: f64,
}
