//! The endpoints with the layouts `build.rs` generated from the ROS 2 headers (see the crate's notes).

use std::ffi::c_void;
use std::mem::{align_of, offset_of, size_of};

use crate::layout::{self, RCUTILS_RET_OK, RET_OK, RET_TAKE_FAILED};
use crate::{built_against, RclError, Result, FUNCTION_NAMES};

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

/// `rcl_serialized_message_t`, that is `rcutils_uint8_array_t`.
#[repr(C)]
struct SerializedMessage {
    buffer: *mut u8,
    buffer_length: usize,
    buffer_capacity: usize,
    allocator: Allocator,
}

const _: () = {
    use layout::*;
    assert!(size_of::<Allocator>() == ALLOCATOR_SIZE && align_of::<Allocator>() == ALLOCATOR_ALIGN);
    assert!(offset_of!(Allocator, allocate) == ALLOCATOR_ALLOCATE);
    assert!(offset_of!(Allocator, deallocate) == ALLOCATOR_DEALLOCATE);
    assert!(offset_of!(Allocator, reallocate) == ALLOCATOR_REALLOCATE);
    assert!(offset_of!(Allocator, zero_allocate) == ALLOCATOR_ZERO_ALLOCATE);
    assert!(offset_of!(Allocator, state) == ALLOCATOR_STATE);
    assert!(size_of::<SerializedMessage>() == ARRAY_SIZE && align_of::<SerializedMessage>() == ARRAY_ALIGN);
    assert!(offset_of!(SerializedMessage, buffer) == ARRAY_BUFFER);
    assert!(offset_of!(SerializedMessage, buffer_length) == ARRAY_BUFFER_LENGTH);
    assert!(offset_of!(SerializedMessage, buffer_capacity) == ARRAY_BUFFER_CAPACITY);
    assert!(offset_of!(SerializedMessage, allocator) == ARRAY_ALLOCATOR);
    assert!(MESSAGE_INFO_ALIGN <= align_of::<MessageInfo>() && MESSAGE_INFO_RECEIVED_TIMESTAMP + 8 <= MESSAGE_INFO_SIZE);
};

/// Storage for an `rmw_message_info_t` of the size and alignment the headers give; only its
/// `received_timestamp` (at the headers' offset) is read.
#[repr(C, align(16))]
struct MessageInfo([u8; MESSAGE_INFO_SIZE]);

const MESSAGE_INFO_SIZE: usize = layout::MESSAGE_INFO_SIZE;

impl MessageInfo {
    fn received_timestamp(&self) -> i64 {
        let at = layout::MESSAGE_INFO_RECEIVED_TIMESTAMP;
        let bytes: [u8; 8] = self.0[at..at + 8].try_into().expect("eight bytes");
        i64::from_ne_bytes(bytes)
    }
}

type TakeFn = unsafe extern "C" fn(*const c_void, *mut SerializedMessage, *mut MessageInfo, *mut c_void) -> i32;
type PublishFn = unsafe extern "C" fn(*const c_void, *const SerializedMessage, *mut c_void) -> i32;
type ArrayInitFn = unsafe extern "C" fn(*mut SerializedMessage, usize, *const Allocator) -> i32;
type ArrayFiniFn = unsafe extern "C" fn(*mut SerializedMessage) -> i32;
type DefaultAllocatorFn = unsafe extern "C" fn() -> Allocator;

/// The five rcl and rcutils functions the endpoints call.
#[derive(Clone, Copy)]
pub struct RclLibrary {
    take: TakeFn,
    publish: PublishFn,
    array_init: ArrayInitFn,
    array_fini: ArrayFiniFn,
    default_allocator: DefaultAllocatorFn,
}

impl RclLibrary {
    /// The functions at `addresses` (in the order of [`FUNCTION_NAMES`]); an error when this build
    /// has no layouts or an address is null.
    ///
    /// # Safety
    /// Each address must be that function of a loaded rcl / rcutils of the version
    /// [`built_against`] names, which stays loaded.
    pub unsafe fn from_addresses(addresses: [usize; 5]) -> Result<Self> {
        built_against()?;
        if let Some(i) = addresses.iter().position(|&a| a == 0) {
            return Err(RclError(format!("{} has no address", FUNCTION_NAMES[i])));
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
        return Err(RclError(format!("a null rcl {what} handle (the endpoint was destroyed?)")));
    }
    Ok(address as *const c_void)
}

/// A subscription taken from with `rcl_take_serialized_message`, its buffer reused.
pub struct RclSubscription {
    library: RclLibrary,
    handle: *const c_void,
    message: SerializedMessage,
    info: Box<MessageInfo>,
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
        if ret != RCUTILS_RET_OK {
            return Err(RclError(format!("rcutils_uint8_array_init failed ({ret})")));
        }
        Ok(Self {
            library,
            handle,
            message,
            info: Box::new(MessageInfo([0; MESSAGE_INFO_SIZE])),
        })
    }

    /// The next message waiting (its bytes and the time the middleware received it, ns since the
    /// epoch, 0 when it does not say), or None.
    pub fn take(&mut self) -> Result<Option<(&[u8], i64)>> {
        self.info.0.fill(0);
        // SAFETY: the handle is valid (see `new`); rmw resizes the buffer with its own allocator.
        let ret = unsafe { (self.library.take)(self.handle, &mut self.message, &mut *self.info, std::ptr::null_mut()) };
        match ret {
            RET_OK => {
                // SAFETY: rmw wrote `buffer_length` bytes into `buffer`.
                let bytes = unsafe { std::slice::from_raw_parts(self.message.buffer, self.message.buffer_length) };
                Ok(Some((bytes, self.info.received_timestamp())))
            }
            RET_TAKE_FAILED => Ok(None),
            other => Err(RclError(format!("rcl_take_serialized_message failed ({other})"))),
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

    /// Publishes one serialized message.
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
            return Err(RclError(format!("rcl_publish_serialized_message failed ({ret})")));
        }
        Ok(())
    }
}
