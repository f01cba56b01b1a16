//! The rollouts' worker pools (one per thread count, kept alive between batches) and the calling
//! thread working beside one.

use std::sync::{Arc, Mutex, OnceLock};

use crate::error::{Result, SabreError};

/// Upper bound on worker threads per pool.
pub const MAX_THREADS: usize = 256;

/// Default worker count: every core the process may use.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
}

/// How many worker pools (of different sizes) stay alive: a process that asks for many thread
/// counts keeps the most recent ones and lets the others' threads exit.
pub const MAX_CACHED_POOLS: usize = 2;

/// Thread pools by size, most recently used last: rayon pools are costly to create and a rollout
/// is short, so they are reused; at most [`MAX_CACHED_POOLS`] are kept.
pub(super) fn pool(threads: usize) -> Result<Arc<rayon::ThreadPool>> {
    type Pools = Vec<(usize, Arc<rayon::ThreadPool>)>;
    static POOLS: OnceLock<Mutex<Pools>> = OnceLock::new();
    let pools = POOLS.get_or_init(|| Mutex::new(Vec::new()));
    let mut pools = pools.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(i) = pools.iter().position(|(n, _)| *n == threads) {
        let entry = pools.remove(i);
        let p = entry.1.clone();
        pools.push(entry);
        return Ok(p);
    }
    let p = Arc::new(
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("sabre-rollout-{i}"))
            .build()
            .map_err(|e| SabreError::Simulation(format!("cannot start {threads} worker threads: {e}")))?,
    );
    pools.push((threads, p.clone()));
    if pools.len() > MAX_CACHED_POOLS {
        pools.remove(0);
    }
    Ok(p)
}

/// Runs `work(slot)` on `threads` threads at once, slots 0..threads: slot 0 on the calling thread,
/// the others on a pool of `threads - 1` workers. The caller works instead of waiting for a pool to
/// wake, do the work and wake it back: a short batch saves both hand-offs, and one thread needs no
/// pool at all. Returns when every slot's call has returned.
pub(super) fn run_on_slots(threads: usize, work: &(dyn Fn(usize) + Sync)) -> Result<()> {
    if threads <= 1 {
        work(0);
        return Ok(());
    }
    let helpers = pool(threads - 1)?;
    helpers.in_place_scope(|scope| {
        for slot in 1..threads {
            scope.spawn(move |_| work(slot));
        }
        work(0);
    });
    Ok(())
}
