//! The control cascade's inner loop: the low-level joint velocity controller that drives the plant, with an optional safety stage,
//! and the rate limiter that shapes velocity commands for a robot's command interface.

pub mod command_stream;
pub mod inner_loop;
pub mod joint_merge;
pub mod low_level;
pub mod object_estimate;
pub mod rate_limit;

pub use inner_loop::{InnerLoop, Plan, TickOutput};
pub use low_level::{follow_reference_safe, InnerSafety, LowLevelConfig, LowLevelController, TrackTrace};
pub use rate_limit::RateLimiter;
