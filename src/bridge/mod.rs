//! The robot bridge's 1 kHz path without ROS: its messages in their serialized form and the tick
//! that answers one joint state with one command (merge, object estimate, inner loop, rate limits).

pub mod messages;
pub mod tick;
pub mod wrench;
