//! Serialized messages taken from and published to rcl endpoints that another library (rclpy)
//! created, called without that library: a node's 1 kHz streams leave its executor and its lock.
//!
//! The crate does not link against ROS 2. The functions' addresses come from the process's loaded
//! `librcl` and `librcutils`, the endpoints' addresses from their owner; both stay valid while the
//! owner keeps the node and its endpoints alive. Every declaration used here is checked against the
//! headers of the ROS 2 the crate was built with (`build.rs` compiles `probe.c`, which fails on a
//! changed signature or field type, and generates the layouts asserted below), and
//! [`built_against`] names that ROS 2 so that the loader can refuse another one.

use std::fmt;

mod layout {
    include!(concat!(env!("OUT_DIR"), "/layout.rs"));
}

#[cfg(rcl_headers)]
mod endpoints;
#[cfg(not(rcl_headers))]
#[path = "absent.rs"]
mod endpoints;

pub use endpoints::{RclLibrary, RclPublisher, RclSubscription};

/// A failed rcl call, or rcl unusable in this build or process.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RclError(pub String);

impl fmt::Display for RclError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for RclError {}

pub type Result<T> = std::result::Result<T, RclError>;

/// The ROS 2 this crate's layouts were checked against: its install prefix and the versions of
/// rcl, rcutils and rmw there; an error saying why when it was built without headers.
pub fn built_against() -> Result<(&'static str, &'static [(&'static str, &'static str)])> {
    #[cfg(rcl_headers)]
    return Ok((layout::PREFIX, &layout::VERSIONS));
    #[cfg(not(rcl_headers))]
    Err(RclError(layout::MISSING.to_string()))
}

/// The functions' names, in the order [`RclLibrary::from_addresses`] takes their addresses.
pub const FUNCTION_NAMES: [&str; 5] = [
    "rcl_take_serialized_message",
    "rcl_publish_serialized_message",
    "rcutils_uint8_array_init",
    "rcutils_uint8_array_fini",
    "rcutils_get_default_allocator",
];
