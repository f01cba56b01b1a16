//! The robot bridge's 1 kHz path without ROS: its messages in their serialized form and the tick
//! that answers one joint state with one command (merge, object estimate, inner loop, rate limits),
//! the simulated robot's driver side (its middleware endpoints behind [`sim_driver::MessageSource`]
//! and [`sim_driver::MessageSink`]).

pub mod cycles;
pub mod jtc;
pub mod messages;
pub mod reflexes;
pub mod sim_driver;
pub mod tick;
