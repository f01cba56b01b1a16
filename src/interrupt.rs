//! Interrupting long core calls: the embedding installs a watcher (the Python bindings: Ctrl-C),
//! and the core's long loops poll it on the calling thread every [`POLL_PERIOD`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use crate::error::{Result, SabreError};

/// How often a long call asks the watcher whether it was interrupted.
pub const POLL_PERIOD: Duration = Duration::from_millis(20);

/// What the embedding provides: which threads it can interrupt, and whether it wants to now.
pub trait Watcher: Send + Sync {
    /// True on a thread whose calls the watcher may interrupt (for Python: the main thread).
    fn watches_current_thread(&self) -> bool;
    /// Asked on a watched thread: true to abandon the running call.
    fn interrupted(&self) -> bool;
}

static WATCHER: OnceLock<Box<dyn Watcher>> = OnceLock::new();

/// Installs the process's watcher; false if one is already installed.
pub fn install(watcher: Box<dyn Watcher>) -> bool {
    WATCHER.set(watcher).is_ok()
}

/// True if a watcher may interrupt calls made on the current thread.
pub fn watched() -> bool {
    WATCHER.get().is_some_and(|w| w.watches_current_thread())
}

/// Asks the watcher now (false without one or on an unwatched thread).
pub fn interrupted_now() -> bool {
    WATCHER.get().is_some_and(|w| w.watches_current_thread() && w.interrupted())
}

/// A long loop's poller: cheap to call every iteration, asks the watcher at most every
/// [`POLL_PERIOD`], and only on a watched thread.
pub struct Poll {
    next: Instant,
    active: bool,
}

impl Default for Poll {
    fn default() -> Self {
        Self::new()
    }
}

impl Poll {
    pub fn new() -> Self {
        Self {
            next: Instant::now() + POLL_PERIOD,
            active: watched(),
        }
    }

    /// `Err(SabreError::Interrupted)` once the watcher asks to stop.
    pub fn check(&mut self) -> Result<()> {
        if !self.active {
            return Ok(());
        }
        let now = Instant::now();
        if now < self.next {
            return Ok(());
        }
        self.next = now + POLL_PERIOD;
        match WATCHER.get() {
            Some(w) if w.interrupted() => Err(SabreError::Interrupted),
            _ => Ok(()),
        }
    }
}

/// A flag that work running on other threads polls to stop early (set by the watched caller).
#[derive(Debug, Default)]
pub struct Cancel(AtomicBool);

impl Cancel {
    pub fn set(&self) {
        self.0.store(true, Ordering::Relaxed);
    }
    pub fn is_set(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_poll_without_a_watcher_never_interrupts() {
        let mut poll = Poll::new();
        std::thread::sleep(POLL_PERIOD * 2);
        assert!(poll.check().is_ok());
    }
}
