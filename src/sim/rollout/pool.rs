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
    let caller_cpu = placement::current_cpu();
    helpers.in_place_scope(|scope| {
        for slot in 1..threads {
            scope.spawn(move |_| {
                placement::keep_off(caller_cpu);
                work(slot)
            });
        }
        work(0);
    });
    Ok(())
}

/// Where a pool worker runs: off the calling thread's CPU. A worker woken by the caller is
/// placed by Linux beside it when the other CPUs look busy, and a virtual machine's idle (halted)
/// vCPU counts as busy to the guest's scheduler (it is "preempted"): caller and worker then share
/// one CPU for up to a scheduler tick (4 ms) before the idle one takes the worker over, a batch of
/// two threads taking half again as long after the cores idled (a loop that re-plans at a fixed
/// rate). A worker whose CPUs exclude the caller's is moved (and, once excluded, woken) onto another.
#[cfg(target_os = "linux")]
mod placement {
    use std::cell::Cell;

    thread_local! {
        /// The CPUs the worker may run on when it started (its process's), and the CPU it keeps
        /// off now (-1: none).
        static ALLOWED: Option<libc::cpu_set_t> = allowed_cpus();
        static AVOIDED: Cell<i32> = const { Cell::new(-1) };
    }

    fn allowed_cpus() -> Option<libc::cpu_set_t> {
        // SAFETY: cpu_set_t is plain data (zeroed is the empty set), and the call writes at most
        // the size it is given into it.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            (libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) == 0).then_some(set)
        }
    }

    /// The CPU the calling thread runs on, if the kernel tells.
    pub(super) fn current_cpu() -> Option<usize> {
        // SAFETY: no arguments; -1 on failure.
        usize::try_from(unsafe { libc::sched_getcpu() }).ok()
    }

    /// Restricts the calling (worker) thread to its allowed CPUs but `cpu`, unless `cpu` is its
    /// only one; a no-op when already so (one system call when the caller moved).
    pub(super) fn keep_off(cpu: Option<usize>) {
        let Some(cpu) = cpu.filter(|&c| c < libc::CPU_SETSIZE as usize) else {
            return;
        };
        if AVOIDED.with(Cell::get) == cpu as i32 {
            return;
        }
        let Some(mut set) = ALLOWED.with(|a| *a) else { return };
        // SAFETY: `set` is a valid cpu_set_t and `cpu` is below CPU_SETSIZE.
        unsafe {
            if !libc::CPU_ISSET(cpu, &set) || libc::CPU_COUNT(&set) < 2 {
                return;
            }
            libc::CPU_CLR(cpu, &mut set);
            if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
                return;
            }
        }
        AVOIDED.with(|a| a.set(cpu as i32));
    }
}

#[cfg(not(target_os = "linux"))]
mod placement {
    pub(super) fn current_cpu() -> Option<usize> {
        None
    }
    pub(super) fn keep_off(_: Option<usize>) {}
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::placement::{current_cpu, keep_off};

    fn own_cpus() -> Vec<usize> {
        // SAFETY: as in `allowed_cpus`.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            assert_eq!(
                libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set),
                0
            );
            (0..libc::CPU_SETSIZE as usize)
                .filter(|&c| libc::CPU_ISSET(c, &set))
                .collect()
        }
    }

    fn restrict_to(cpus: &[usize]) {
        // SAFETY: as in `keep_off`.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            for &c in cpus {
                libc::CPU_SET(c, &mut set);
            }
            assert_eq!(libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set), 0);
        }
    }

    #[test]
    fn a_worker_keeps_off_the_callers_cpu_and_on_all_its_others() {
        let allowed = std::thread::spawn(own_cpus).join().unwrap();
        if allowed.len() < 2 {
            return; // one CPU: nothing to keep off
        }
        let avoided = allowed[0];
        let (cpus, now) = std::thread::spawn(move || {
            keep_off(Some(avoided));
            (own_cpus(), current_cpu())
        })
        .join()
        .unwrap();
        assert_eq!(cpus, allowed[1..]);
        assert_ne!(now, Some(avoided));
        // The caller moved: the worker keeps off its new CPU and may use the old one again.
        let (first, second) = (allowed[0], allowed[1]);
        let cpus = std::thread::spawn(move || {
            keep_off(Some(first));
            keep_off(Some(second));
            own_cpus()
        })
        .join()
        .unwrap();
        assert!(cpus.contains(&first) && !cpus.contains(&second), "{cpus:?}");
    }

    #[test]
    fn a_worker_allowed_one_cpu_or_told_no_cpu_stays_where_it_may_run() {
        let allowed = std::thread::spawn(own_cpus).join().unwrap();
        let only = allowed[0];
        let cpus = std::thread::spawn(move || {
            restrict_to(&[only]);
            keep_off(Some(only));
            own_cpus()
        })
        .join()
        .unwrap();
        assert_eq!(cpus, vec![only]);
        let cpus = std::thread::spawn(|| {
            keep_off(None);
            keep_off(Some(libc::CPU_SETSIZE as usize + 3));
            own_cpus()
        })
        .join()
        .unwrap();
        assert_eq!(cpus, allowed);
    }
}
