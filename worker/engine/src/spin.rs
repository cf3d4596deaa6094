//! Spin-waiting between searches (ARCHITECTURE §6): the active wait policy
//! of OpenMP runtimes, for rayon.
//!
//! A level searches thousands of small batches, each a few parallel sections
//! of well under a millisecond, with the caller's serial work (building the
//! next queries, copying the answers) in between. Rayon's idle threads sleep
//! after a few dozen yields, so every batch began by waking them one by one,
//! and on 16 threads that wake-up was a large part of a batch's time. After
//! each search the engine leaves up to `threads − 1` tasks on its pool that
//! take the pool's work as it comes ([`rayon::yield_now`]) and otherwise spin,
//! for at most the engine's spin time after the last search ends. They run
//! search work only as rayon would have run it, so answers do not change.
//! A library engine starts with no spin; `texsyn` and `texsyn-worker` give
//! theirs [`crate::search::DEFAULT_SPIN`] (`--spin-us`).

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// Spinning tasks alive in this process.
static ACTIVE: AtomicUsize = AtomicUsize::new(0);
/// Searches running in this process.
static IN_FLIGHT: AtomicUsize = AtomicUsize::new(0);
/// When the last search ended, in nanoseconds after [`origin`].
static LAST_END: AtomicU64 = AtomicU64::new(0);

/// Spinning tasks alive now, over every pool of the process.
pub fn spinning() -> usize {
    ACTIVE.load(Ordering::Acquire)
}

fn origin() -> Instant {
    static ORIGIN: OnceLock<Instant> = OnceLock::new();
    *ORIGIN.get_or_init(Instant::now)
}

fn now() -> u64 {
    u64::try_from(origin().elapsed().as_nanos()).unwrap_or(u64::MAX)
}

/// Held for one search; on drop, tops up the spinning tasks of the current
/// pool for `spin` after it.
pub(crate) struct Searching {
    spin: Duration,
}

impl Searching {
    pub(crate) fn start(spin: Duration) -> Self {
        IN_FLIGHT.fetch_add(1, Ordering::AcqRel);
        Self { spin }
    }
}

impl Drop for Searching {
    fn drop(&mut self) {
        IN_FLIGHT.fetch_sub(1, Ordering::AcqRel);
        if self.spin.is_zero() {
            return;
        }
        LAST_END.store(now(), Ordering::Release);
        if rayon::current_thread_index().is_none() {
            return;
        }
        let want = rayon::current_num_threads().saturating_sub(1);
        let spin = u64::try_from(self.spin.as_nanos()).unwrap_or(u64::MAX);
        while ACTIVE
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |a| {
                (a < want).then_some(a + 1)
            })
            .is_ok()
        {
            rayon::spawn(move || linger(spin));
        }
    }
}

/// Takes the pool's work as it comes until no search has run for `spin`
/// nanoseconds. A task that starts while a search is running ends at once:
/// it may have been taken by a thread that waits inside that search, which
/// must not be held up.
fn linger(spin: u64) {
    struct Leave;
    impl Drop for Leave {
        fn drop(&mut self) {
            ACTIVE.fetch_sub(1, Ordering::AcqRel);
        }
    }
    let _leave = Leave;
    if IN_FLIGHT.load(Ordering::Acquire) > 0 {
        return;
    }
    loop {
        match rayon::yield_now() {
            Some(rayon::Yield::Executed) => continue,
            None => return,
            Some(rayon::Yield::Idle) => {}
        }
        if IN_FLIGHT.load(Ordering::Acquire) == 0
            && now().saturating_sub(LAST_END.load(Ordering::Acquire)) > spin
        {
            return;
        }
        std::hint::spin_loop();
    }
}
