//! The control cascade's inner loop ([`Cascade`]: the plan in force, τ_ext conditioning, the safety stage
//! and the low-level joint velocity controller), and the command shaping for a robot's command interface.

pub mod articulation;
pub mod cascade;
pub mod command_stream;
pub mod joint_merge;
pub mod low_level;
pub mod object_estimate;
pub mod plan;
pub mod rate_limit;
pub mod segment;
pub mod shaping;
pub mod tau_ext;
pub mod trajectory_stream;

pub use cascade::{Cascade, Shared, TickOutput, TrackTrace};
pub use low_level::{LowLevelConfig, LowLevelController};
pub use plan::Plan;
pub use rate_limit::RateLimiter;
pub use shaping::CommandShaping;
pub use tau_ext::{ExternalTorque, WrenchFrames};
