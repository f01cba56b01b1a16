//! The robot bridge's 1 kHz path without ROS: its messages in their serialized form and the tick
//! that answers one joint state with one command (merge, object estimate, inner loop, rate limits),
//! the simulated robot's driver side, and the rcl calls that carry both without Python.

pub mod messages;
pub mod rcl;
pub mod reflexes;
pub mod sim_driver;
pub mod tick;
