//! Serialized messages taken from and published to rcl endpoints that rclpy created, called from the
//! core without Python: the 1 kHz streams of a node leave its executor and its interpreter lock.
//!
//! The core does not link against ROS 2. The functions' addresses come from the process's already
//! loaded `librcl` and `librcutils` (looked up by `sabre.ros.direct`), the endpoints' addresses
//! from rclpy's handles; both stay valid while rclpy keeps the node and its endpoints alive, which
//! the owner of these values guarantees (the bindings hold the rclpy objects).

use std::ffi::c_void;

use crate::error::{Result, SabreError};

/// `rcutils_allocator_t`.
#[repr(C)]
#[derive(Clone, Copy)]
struct Allocator {
    allocate: *const c_void,
    deallocate: *const c_void,
    reallocate: *const c_void,
    zero_allocate: *const c_void,
    state: *mut c_void,
}

/// `rcl_serialized_message_t` (`rcutils_uint8_array_t`).
#[repr(C)]
struct SerializedMessage {
    buffer: *mut u8,
    buffer_length: usize,
    buffer_capacity: usize,
    allocator: Allocator,
}

/// `rmw_message_info_t`: its two leading timestamps (ns); the rest (sequence numbers, the
/// publisher's gid, whose storage size differs between distributions) fits in `rest`.
#[repr(C)]
struct MessageInfo {
    source_timestamp: i64,
    received_timestamp: i64,
    rest: [u64; 24],
}

type TakeFn = unsafe extern "C" fn(*const c_void, *mut SerializedMessage, *mut MessageInfo, *mut c_void) -> i32;
type PublishFn = unsafe extern "C" fn(*const c_void, *const SerializedMessage, *mut c_void) -> i32;
type ArrayInitFn = unsafe extern "C" fn(*mut SerializedMessage, usize, *const Allocator) -> i32;
type ArrayFiniFn = unsafe extern "C" fn(*mut SerializedMessage) -> i32;
type DefaultAllocatorFn = unsafe extern "C" fn() -> Allocator;

const RET_OK: i32 = 0;
/// `RCL_RET_SUBSCRIPTION_TAKE_FAILED`: nothing to take.
const RET_TAKE_FAILED: i32 = 401;

/// The five rcl and rcutils functions the endpoints call.
#[derive(Clone, Copy)]
pub struct RclLibrary {
    take: TakeFn,
    publish: PublishFn,
    array_init: ArrayInitFn,
    array_fini: ArrayFiniFn,
    default_allocator: DefaultAllocatorFn,
}

/// The functions' addresses, in the order [`RclLibrary::from_addresses`] takes them.
pub const FUNCTION_NAMES: [&str; 5] = [
    "rcl_take_serialized_message",
    "rcl_publish_serialized_message",
    "rcutils_uint8_array_init",
    "rcutils_uint8_array_fini",
    "rcutils_get_default_allocator",
];

impl RclLibrary {
    /// The functions at `addresses` (in the order of [`FUNCTION_NAMES`]).
    ///
    /// # Safety
    /// Each address must be that function of a loaded rcl / rcutils, which stays loaded.
    pub unsafe fn from_addresses(addresses: [usize; 5]) -> Result<Self> {
        if let Some(i) = addresses.iter().position(|&a| a == 0) {
            return Err(SabreError::invalid(
                "rcl functions",
                format!("{} has no address", FUNCTION_NAMES[i]),
            ));
        }
        Ok(Self {
            take: std::mem::transmute::<usize, TakeFn>(addresses[0]),
            publish: std::mem::transmute::<usize, PublishFn>(addresses[1]),
            array_init: std::mem::transmute::<usize, ArrayInitFn>(addresses[2]),
            array_fini: std::mem::transmute::<usize, ArrayFiniFn>(addresses[3]),
            default_allocator: std::mem::transmute::<usize, DefaultAllocatorFn>(addresses[4]),
        })
    }
}

fn handle(what: &str, address: usize) -> Result<*const c_void> {
    if address == 0 {
        return Err(SabreError::invalid(what, "a null rcl handle (the endpoint was destroyed?)"));
    }
    Ok(address as *const c_void)
}

/// A subscription taken from with `rcl_take_serialized_message`, its buffer reused.
pub struct RclSubscription {
    library: RclLibrary,
    handle: *const c_void,
    message: SerializedMessage,
    info: MessageInfo,
}

// The handle is used from one thread at a time (`&mut self`); rcl's take is safe from any thread.
unsafe impl Send for RclSubscription {}

impl RclSubscription {
    /// # Safety
    /// `subscription` must be the address of an `rcl_subscription_t` that outlives this value and
    /// that nothing else takes from (no executor waits on it).
    pub unsafe fn new(library: RclLibrary, subscription: usize) -> Result<Self> {
        let handle = handle("subscription", subscription)?;
        let allocator = (library.default_allocator)();
        let mut message = SerializedMessage {
            buffer: std::ptr::null_mut(),
            buffer_length: 0,
            buffer_capacity: 0,
            allocator,
        };
        let ret = (library.array_init)(&mut message, 256, &allocator);
        if ret != RET_OK {
            return Err(SabreError::Simulation(format!("rcutils_uint8_array_init failed ({ret})")));
        }
        Ok(Self {
            library,
            handle,
            message,
            info: MessageInfo {
                source_timestamp: 0,
                received_timestamp: 0,
                rest: [0; 24],
            },
        })
    }

    /// The next message waiting (its bytes and the time the middleware received it, ns since the
    /// epoch, 0 when it does not say), or None.
    pub fn take(&mut self) -> Result<Option<(&[u8], i64)>> {
        self.info.received_timestamp = 0;
        // SAFETY: the handle is valid (see `new`); rmw resizes the buffer with its own allocator.
        let ret = unsafe { (self.library.take)(self.handle, &mut self.message, &mut self.info, std::ptr::null_mut()) };
        match ret {
            RET_OK => {
                // SAFETY: rmw wrote `buffer_length` bytes into `buffer`.
                let bytes = unsafe { std::slice::from_raw_parts(self.message.buffer, self.message.buffer_length) };
                Ok(Some((bytes, self.info.received_timestamp)))
            }
            RET_TAKE_FAILED => Ok(None),
            other => Err(SabreError::Simulation(format!(
                "rcl_take_serialized_message failed ({other})"
            ))),
        }
    }
}

impl Drop for RclSubscription {
    fn drop(&mut self) {
        // SAFETY: the buffer was made by `array_init` with this allocator.
        unsafe { (self.library.array_fini)(&mut self.message) };
    }
}

/// A publisher of serialized messages (`rcl_publish_serialized_message`).
pub struct RclPublisher {
    library: RclLibrary,
    handle: *const c_void,
}

unsafe impl Send for RclPublisher {}

impl RclPublisher {
    /// # Safety
    /// `publisher` must be the address of an `rcl_publisher_t` that outlives this value.
    pub unsafe fn new(library: RclLibrary, publisher: usize) -> Result<Self> {
        Ok(Self {
            library,
            handle: handle("publisher", publisher)?,
        })
    }

    pub fn publish(&self, bytes: &[u8]) -> Result<()> {
        // SAFETY: rcl reads `buffer_length` bytes and never writes or frees the buffer.
        let message = SerializedMessage {
            buffer: bytes.as_ptr() as *mut u8,
            buffer_length: bytes.len(),
            buffer_capacity: bytes.len(),
            allocator: unsafe { (self.library.default_allocator)() },
        };
        let ret = unsafe { (self.library.publish)(self.handle, &message, std::ptr::null_mut()) };
        if ret != RET_OK {
            return Err(SabreError::Simulation(format!(
                "rcl_publish_serialized_message failed ({ret})"
            )));
        }
        Ok(())
    }
}
