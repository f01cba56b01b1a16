//! The endpoints of a build without the ROS 2 headers: no layouts, so nothing can be constructed
//! ([`RclLibrary::from_addresses`] says why) and the types are uninhabited.

use std::convert::Infallible;

use crate::{built_against, Result};

/// The rcl and rcutils functions (none in this build).
#[derive(Clone, Copy)]
pub struct RclLibrary(Infallible);

impl RclLibrary {
    /// Always the error [`built_against`] gives.
    ///
    /// # Safety
    /// Nothing is called; unsafe for the same signature as with headers.
    pub unsafe fn from_addresses(_addresses: [usize; 5]) -> Result<Self> {
        built_against()?;
        unreachable!("built_against fails without headers")
    }
}

/// A subscription (none in this build).
pub struct RclSubscription(Infallible);

impl RclSubscription {
    /// # Safety
    /// Nothing is called: there is no [`RclLibrary`] in this build.
    pub unsafe fn new(library: RclLibrary, _subscription: usize) -> Result<Self> {
        match library.0 {}
    }

    pub fn take(&mut self) -> Result<Option<(&[u8], i64)>> {
        match self.0 {}
    }
}

/// A publisher (none in this build).
pub struct RclPublisher(Infallible);

impl RclPublisher {
    /// # Safety
    /// Nothing is called: there is no [`RclLibrary`] in this build.
    pub unsafe fn new(library: RclLibrary, _publisher: usize) -> Result<Self> {
        match library.0 {}
    }

    pub fn publish(&self, _bytes: &[u8]) -> Result<()> {
        match self.0 {}
    }
}
